/*
 * bench-floor: the bare floor of a Modbus benchmark case. A request/response
 * ping-pong of the case's exact ADU sizes with one send (write) and one recv (read)
 * per side per transaction (a read is repeated only if the kernel delivers a message
 * in pieces, which loopback TCP does not), no framing logic, no timeouts.
 *
 *   bench-floor server tcp PORT | server pty DEVICE
 *   bench-floor client tcp PORT CASE SECONDS | client pty DEVICE CASE SECONDS
 *
 * With FLOOR_WAIT=1 in the environment it makes the waits a library with libmodbus's
 * semantics cannot do without: on TCP the server peeks before its exact read (so that
 * bytes past the request stay in the kernel for the application's own poll loop),
 * while the client needs no wait of its own: its read blocks, bounded by SO_RCVTIMEO
 * (a timeout has to be armed somewhere, and this one costs a kernel timer per wait);
 * on a pty both sides poll (with a timeout) before each read, termios having no finer
 * read timeout than tenths of a second. On TCP, FLOOR_WAIT=peek makes only the server's
 * peek and FLOOR_WAIT=timeout only the client's SO_RCVTIMEO, to price each on its own.
 *
 * With FLOOR_DATA=1 as well (TCP or pty) it is the *data floor*: both sides also
 * convert the case's values between arrays and the wire, the least any library has
 * to do with them (client: 121/123 registers out, 125/1 in, or 2000 coils unpacked;
 * server: the registers written into and read out of a table, or 2000 coils packed),
 * in plain C that the compiler vectorises, and SSE2 for packing coils.
 *
 * The server learns the sizes and the case from a 3-byte hello (request size,
 * response size, case number).
 * Prints "READY <port>" (server) and "RESULT case=... tx=N secs=S tps=T" (client).
 * With BENCH_COUNTER set, a client takes part in an interleaved measurement
 * (bench-counter.h).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <emmintrin.h>

#include "bench-counter.h"

/* The environment variable `name`, or `fallback` when it is not set. */
static const char *env_or(const char *name, const char *fallback)
{
    const char *v = getenv(name);
    return v != NULL ? v : fallback;
}

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

static int wait_mode;           /* FLOOR_WAIT=1, peek or timeout */
static int server_peeks = 1;     /* TCP: not with FLOOR_WAIT=timeout */
static int client_times_out = 1; /* TCP: not with FLOOR_WAIT=peek */

/* FLOOR_WAIT: the wait before a read (see the top). */
static int wait_before_read(int fd, int tcp, int server)
{
    if (!wait_mode || (tcp && (!server || !server_peeks))) {
        return 0;
    }
    if (tcp) {
        unsigned char peek[512];
        return recv(fd, peek, sizeof(peek), MSG_PEEK) > 0 ? 0 : -1;
    } else {
        struct pollfd p = {fd, POLLIN, 0};
        return poll(&p, 1, 5000) == 1 ? 0 : -1;
    }
}

/* Reads exactly n bytes (one read unless the kernel splits the message). */
static int read_full(int fd, unsigned char *b, int n, int tcp)
{
    int got = 0;
    while (got < n) {
        ssize_t r = tcp ? recv(fd, b + got, (size_t) (n - got), 0) : read(fd, b + got, (size_t) (n - got));
        if (r <= 0) {
            if (r < 0 && errno == EINTR) {
                continue;
            }
            return -1;
        }
        got += (int) r;
    }
    return 0;
}

static int write_full(int fd, const unsigned char *b, int n, int tcp)
{
    ssize_t w = tcp ? send(fd, b, (size_t) n, MSG_NOSIGNAL) : write(fd, b, (size_t) n);
    return w == n ? 0 : -1;
}

static int open_pty(const char *dev)
{
    struct termios t;
    int fd = open(dev, O_RDWR | O_NOCTTY);
    if (fd < 0 || tcgetattr(fd, &t) != 0) {
        return -1;
    }
    cfmakeraw(&t);
    tcsetattr(fd, TCSANOW, &t);
    tcflush(fd, TCIOFLUSH);
    return fd;
}

/* ---- the data floor's conversions (FLOOR_DATA=1) ---- */
enum { NO_DATA, R125, C2000, W123, WR121, R1 };
static uint16_t values[256], table[256];
static uint8_t coils[2048], coil_table[2048];
static uint64_t spread_bits[256]; /* byte i of spread_bits[b] = bit i of b */

static void registers_out(const uint16_t *v, unsigned char *wire, int n)
{
    for (int i = 0; i < n; i++) {
        uint16_t be = __builtin_bswap16(v[i]);
        memcpy(wire + 2 * i, &be, 2);
    }
}

static void registers_in(const unsigned char *wire, uint16_t *v, int n)
{
    for (int i = 0; i < n; i++) {
        uint16_t be;
        memcpy(&be, wire + 2 * i, 2);
        v[i] = __builtin_bswap16(be);
    }
}

/* n a multiple of 16: bit 0 of each value to one bit, 16 values per step. */
static void coils_packed(const uint8_t *bits, unsigned char *out, int n)
{
    for (int i = 0; i < n; i += 16) {
        int m = _mm_movemask_epi8(_mm_slli_epi16(_mm_loadu_si128((const __m128i *) (bits + i)), 7));
        out[i / 8] = (unsigned char) m;
        out[i / 8 + 1] = (unsigned char) (m >> 8);
    }
}

static void coils_unpacked(const unsigned char *packed, uint8_t *bits, int n)
{
    for (int i = 0; i < n / 8; i++) {
        memcpy(bits + 8 * i, &spread_bits[packed[i]], 8);
    }
}

static void data_init(void)
{
    for (int b = 0; b < 256; b++) {
        for (int k = 0; k < 8; k++) {
            spread_bits[b] |= (uint64_t) ((b >> k) & 1) << (8 * k);
        }
        values[b] = (uint16_t) (b * 3);
    }
    for (int k = 0; k < 2048; k++) {
        coil_table[k] = (uint8_t) (k % 3 == 0);
    }
}

/* Server, between reading the request and sending the response; h: header length. */
static void server_data(int c, unsigned char *b, int h)
{
    switch (c) {
    case R125: registers_out(table, b + h + 2, 125); break;
    case C2000: coils_packed(coil_table, b + h + 2, 2000); break;
    case W123: registers_in(b + h + 6, table, 123); break;
    case WR121: registers_in(b + h + 10, table, 121); registers_out(table, b + h + 2, 125); break;
    case R1: registers_out(table, b + h + 2, 1); break;
    }
}

static void client_request_data(int c, unsigned char *b, int h)
{
    if (c == W123) {
        registers_out(values, b + h + 6, 123);
    } else if (c == WR121) {
        registers_out(values, b + h + 10, 121);
    }
}

static void client_response_data(int c, const unsigned char *b, int h)
{
    switch (c) {
    case R125: case WR121: registers_in(b + h + 2, values, 125); break;
    case C2000: coils_unpacked(b + h + 2, coils, 2000); break;
    case R1: registers_in(b + h + 2, values, 1); break;
    }
}

/* Case sizes (request, response) for TCP (MBAP) and RTU (CRC); returns the case. */
static int sizes(const char *c, int tcp, int *req, int *rsp)
{
    int h = tcp ? 7 : 1, cs = tcp ? 0 : 2;
    if (strcmp(c, "r125") == 0) { *req = h + 5 + cs; *rsp = h + 2 + 250 + cs; return R125; }
    if (strcmp(c, "c2000") == 0) { *req = h + 5 + cs; *rsp = h + 2 + 250 + cs; return C2000; }
    if (strcmp(c, "w123") == 0) { *req = h + 6 + 246 + cs; *rsp = h + 5 + cs; return W123; }
    if (strcmp(c, "wr121") == 0) { *req = h + 10 + 242 + cs; *rsp = h + 2 + 250 + cs; return WR121; }
    if (strcmp(c, "r1") == 0) { *req = h + 5 + cs; *rsp = h + 2 + 2 + cs; return R1; }
    fprintf(stderr, "unknown case %s\n", c);
    exit(2);
}

int main(int argc, char **argv)
{
    unsigned char buf[512];
    int tcp, fd;

    signal(SIGPIPE, SIG_IGN);
    if (argc < 4) {
        fprintf(stderr, "usage: see the comment at the top of bench-floor.c\n");
        return 2;
    }
    tcp = strcmp(argv[2], "tcp") == 0;
    const char *waits = env_or("FLOOR_WAIT", "0");
    if (strcmp(waits, "peek") == 0 || strcmp(waits, "timeout") == 0) {
        if (!tcp) {
            fprintf(stderr, "bench-floor: FLOOR_WAIT=%s is for TCP only\n", waits);
            return 2;
        }
        server_peeks = strcmp(waits, "peek") == 0;
        client_times_out = !server_peeks;
    } else if (strcmp(waits, "0") != 0 && strcmp(waits, "1") != 0) {
        fprintf(stderr, "bench-floor: FLOOR_WAIT must be 0, 1, peek or timeout\n");
        return 2;
    }
    wait_mode = strcmp(waits, "0") != 0;
    const char *data = env_or("FLOOR_DATA", "0");
    if (strcmp(data, "0") != 0 && strcmp(data, "1") != 0) {
        fprintf(stderr, "bench-floor: FLOOR_DATA must be 0 or 1\n");
        return 2;
    }
    data_init();
    memset(buf, 0x5A, sizeof(buf));
    if (strcmp(argv[1], "server") == 0) {
        int req, rsp, one = 1;
        if (tcp) {
            struct sockaddr_in sa;
            socklen_t sl = sizeof(sa);
            int ls = socket(AF_INET, SOCK_STREAM, 0);
            setsockopt(ls, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
            memset(&sa, 0, sizeof(sa));
            sa.sin_family = AF_INET;
            sa.sin_port = htons((uint16_t) atoi(argv[3]));
            sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
            if (bind(ls, (struct sockaddr *) &sa, sizeof(sa)) != 0 || listen(ls, 4) != 0 ||
                getsockname(ls, (struct sockaddr *) &sa, &sl) != 0) {
                perror("bench-floor: listen");
                return 1;
            }
            printf("READY %d\n", ntohs(sa.sin_port));
            fflush(stdout);
            fd = accept(ls, NULL, NULL);
            close(ls);
            setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
        } else {
            fd = open_pty(argv[3]);
            printf("READY %s\n", argv[3]);
            fflush(stdout);
        }
        if (fd < 0 || read_full(fd, buf, 3, tcp) != 0) {
            return 1;
        }
        req = buf[0];
        rsp = buf[1];
        int data_case = buf[2], h = tcp ? 7 : 1;
        while (wait_before_read(fd, tcp, 1) == 0 && read_full(fd, buf, req + 4, tcp) == 0) {
            server_data(data_case, buf, h);
            if (write_full(fd, buf, rsp + 4, tcp) != 0) {
                break;
            }
        }
        return 0;
    } else {
        int req, rsp, one = 1;
        long tx = 0;
        volatile uint64_t *counter = bench_counter_open();
        double t0, t1, secs;
        if (argc < 6) {
            return 2;
        }
        int data_case = sizes(argv[4], tcp, &req, &rsp), h = tcp ? 7 : 1;
        if (strcmp(data, "1") != 0) {
            data_case = NO_DATA;
        }
        secs = atof(argv[5]);
        if (tcp) {
            struct sockaddr_in sa;
            fd = socket(AF_INET, SOCK_STREAM, 0);
            memset(&sa, 0, sizeof(sa));
            sa.sin_family = AF_INET;
            sa.sin_port = htons((uint16_t) atoi(argv[3]));
            sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
            if (connect(fd, (struct sockaddr *) &sa, sizeof(sa)) != 0) {
                perror("bench-floor: connect");
                return 1;
            }
            setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
            if (wait_mode && client_times_out) {
                struct timeval limit = {5, 0};
                setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &limit, sizeof(limit));
            }
        } else {
            fd = open_pty(argv[3]);
        }
        /* Sizes are sent minus 4 so that 259 fits a byte. */
        buf[0] = (unsigned char) (req - 4);
        buf[1] = (unsigned char) (rsp - 4);
        buf[2] = (unsigned char) data_case;
        if (fd < 0 || write_full(fd, buf, 3, tcp) != 0) {
            return 1;
        }
        memset(buf, 0x5A, sizeof(buf));
        for (int i = 0; i < 100; i++) {
            if (write_full(fd, buf, req, tcp) != 0 || read_full(fd, buf, rsp, tcp) != 0) {
                return 1;
            }
        }
        t0 = now();
        t1 = t0;
        while (t1 - t0 < secs) {
            client_request_data(data_case, buf, h);
            if (write_full(fd, buf, req, tcp) != 0 || wait_before_read(fd, tcp, 0) != 0 ||
                read_full(fd, buf, rsp, tcp) != 0) {
                fprintf(stderr, "bench-floor: transaction failed\n");
                return 1;
            }
            client_response_data(data_case, buf, h);
            tx++;
            if (counter != NULL) {
                bench_counter_publish(counter, tx);
            }
            if ((tx & 31) == 0) {
                t1 = now();
                if (counter != NULL && bench_counter_stop_requested(counter)) {
                    break;
                }
            }
        }
        t1 = now();
        printf("RESULT case=%s tx=%ld secs=%.4f tps=%.1f errors=0\n", argv[4], tx, t1 - t0, (double) tx / (t1 - t0));
        close(fd);
        return 0;
    }
}
