/*
 * runner-check.c: clients of a server that runs itself (c-tests/runner/runner-server.c),
 * for c-tests/suites/runner.sh. Built against Debian's <modbus.h> and libmodbus, so
 * that the clients are Debian's libmodbus (or ours, by LD_LIBRARY_PATH), beside raw
 * sockets that misbehave.
 *
 *   runner-check <port> <scenario> [args]
 *   runner-check <device> rtu       (a serial server with callbacks, on a pty pair)
 *
 * scenarios (the server's data: see runner-server.c):
 *   basic [k]       every function code of libmodbus from one client, values checked
 *                   (k: the table's number: 0 for the mapping, 1, 2, 3 for units 1, 2, 7's
 *                   callbacks); the other scenarios talk to unit 1 and check values
 *                   modulo 1000
 *   many N          N clients connected at once, each reads and writes its own register
 *   pipelined       20 requests in one write on a raw socket: 20 answers, in order
 *   slow            a client sending a request a byte every 200 ms, one that stalls half
 *                   a request, one that sends garbage (closed at once), one half-open: another client's
 *                   100 reads meanwhile, none slower than 200 ms
 *   full            a raw client that writes requests and never reads: another client's
 *                   reads go on
 *   idle MS         a raw client that sends nothing is closed by the server after about
 *                   MS (and not before MS / 2)
 *   units           units 1, 2 and 7 answer with their own values, unit 5 gets exception
 *                   0B (TCP, callbacks)
 *   stop            writes 0xDEAD to register 999: the server stops (callbacks)
 *   status V        FC 07 (read exception status) on a raw socket, twice on each of two
 *                   connections: V each time (a server configured beyond libmodbus
 *                   serves its clients with that configuration)
 *   later           against runner-server --later: 3 reads in one write answered last
 *                   first, each with its transaction id and value; an unknown function
 *                   code's exception; a request never answered (the next one is); a
 *                   client that leaves with its request unanswered (the server goes on)
 *   rtu             over RTU: units 1, 2 and 7 answer with their own values (a read and
 *                   a write each), unit 5 is silent (timeout), and the next request
 *                   is answered; a broadcast write reaches every unit served
 *   hold N S        N raw clients that send the first 3 bytes of a TLS record (a
 *                   handshake that stalls) and hold for S seconds; prints HOLDING
 *                   once they are connected
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbtest.h"

static int port;

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

static modbus_t *client(void)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    if (ctx == NULL || modbus_connect(ctx) != 0) {
        EXPECT(0, "connect: %s", modbus_strerror(errno));
        if (ctx != NULL) {
            modbus_free(ctx);
        }
        return NULL;
    }
    modbus_set_response_timeout(ctx, 5, 0);
    /* Unit 1: every unit of a mapping, unit 1's data with callbacks. */
    modbus_set_slave(ctx, 1);
    return ctx;
}

static int raw_connect(void)
{
    struct sockaddr_in a;
    int s = socket(AF_INET, SOCK_STREAM, 0), one = 1;
    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    a.sin_port = htons((uint16_t) port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(s, (struct sockaddr *) &a, sizeof a) != 0) {
        close(s);
        return -1;
    }
    setsockopt(s, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    return s;
}

/* A read-holding-registers request (TCP) of 1 register at `addr`. */
static void read_request(uint8_t *q, int tid, int addr)
{
    uint8_t r[12] = {(uint8_t) (tid >> 8), (uint8_t) tid, 0, 0, 0, 6, 1, 3, (uint8_t) (addr >> 8), (uint8_t) addr, 0, 1};
    memcpy(q, r, 12);
}

/* Waits up to ms for the peer to close `s` (reads and drops what comes): 1 if it did. */
static int closed_within(int s, int ms)
{
    double end = now_ms() + ms;
    uint8_t buf[4096];
    for (;;) {
        struct pollfd p = {s, POLLIN, 0};
        int left = (int) (end - now_ms());
        ssize_t n;
        if (poll(&p, 1, left > 0 ? left : 0) <= 0) {
            return 0;
        }
        n = recv(s, buf, sizeof buf, 0);
        if (n == 0 || (n < 0 && errno == ECONNRESET)) {
            return 1;
        }
    }
}

static void basic(int k)
{
    modbus_t *ctx = client();
    uint16_t regs[125], regs2[125];
    uint8_t bits[100];
    int rc, i, ok;
    if (ctx == NULL) {
        return;
    }
    if (k > 0) {
        modbus_set_slave(ctx, k == 3 ? 7 : k);
    }
    rc = modbus_read_registers(ctx, 10, 125, regs);
    ok = rc == 125;
    for (i = 0; ok && i < 125; i++) {
        ok = regs[i] == 1000 * k + 10 + i;
    }
    EXPECT(ok, "read 125 holding registers: rc %d, values of the table", rc);
    rc = modbus_read_input_registers(ctx, 500, 10, regs);
    EXPECT(rc == 10 && regs[0] == 1000 * k + 500 && regs[9] == 1000 * k + 509, "read 10 input registers");
    rc = modbus_read_bits(ctx, 0, 100, bits);
    ok = rc == 100;
    for (i = 0; ok && i < 100; i++) {
        ok = bits[i] == (i % 3 == 0);
    }
    EXPECT(ok, "read 100 coils");
    rc = modbus_read_input_bits(ctx, 3, 4, bits);
    EXPECT(rc == 4 && bits[0] == 1 && bits[1] == 0 && bits[3] == 1, "read 4 discrete inputs");
    EXPECT(modbus_write_register(ctx, 620, 0x1234) == 1, "write register 620");
    EXPECT(modbus_read_registers(ctx, 620, 1, regs) == 1 && regs[0] == 0x1234, "read it back");
    for (i = 0; i < 50; i++) {
        regs[i] = (uint16_t) (0xA000 + i);
    }
    EXPECT(modbus_write_registers(ctx, 650, 50, regs) == 50, "write 50 registers");
    EXPECT(modbus_read_registers(ctx, 650, 50, regs2) == 50 && memcmp(regs, regs2, 100) == 0, "read them back");
    EXPECT(modbus_write_bit(ctx, 501, 1) == 1, "write coil 501");
    memset(bits, 1, 10);
    EXPECT(modbus_write_bits(ctx, 530, 10, bits) == 10, "write 10 coils");
    EXPECT(modbus_read_bits(ctx, 500, 40, bits) == 40 && bits[1] == 1 && bits[30] == 1 && bits[39] == 1 &&
               bits[2] == 0,
           "read the coils back");
    EXPECT(modbus_mask_write_register(ctx, 620, 0x00FF, 0x0100) == 1, "mask write register 620");
    EXPECT(modbus_read_registers(ctx, 620, 1, regs) == 1 && regs[0] == ((0x1234 & 0x00FF) | (0x0100 & ~0x00FF)),
           "the mask applied");
    regs[0] = 7;
    regs[1] = 8;
    rc = modbus_write_and_read_registers(ctx, 640, 2, regs, 640, 3, regs2);
    EXPECT(rc == 3 && regs2[0] == 7 && regs2[1] == 8 && regs2[2] == 1000 * k + 642, "write and read registers");
    errno = 0;
    rc = modbus_read_registers(ctx, 990, 20, regs);
    EXPECT(rc == -1 && errno == EMBXILADD, "a read past the table: exception 02 (errno %d)", errno);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void many(int n)
{
    modbus_t **c = calloc((size_t) n, sizeof *c);
    int i, connected = 0, read_ok = 0, write_ok = 0, back_ok = 0;
    uint16_t v;
    double t0 = now_ms();
    for (i = 0; i < n; i++) {
        c[i] = modbus_new_tcp("127.0.0.1", port);
        if (c[i] != NULL && modbus_connect(c[i]) == 0) {
            modbus_set_response_timeout(c[i], 10, 0);
            modbus_set_slave(c[i], 1);
            connected++;
        }
    }
    EXPECT(connected == n, "%d clients connected at once (%d)", n, connected);
    for (i = 0; i < n; i++) {
        if (modbus_read_input_registers(c[i], i % 900, 1, &v) == 1 && v % 1000 == i % 900) {
            read_ok++;
        }
    }
    EXPECT(read_ok == n, "each read its register (%d of %d)", read_ok, n);
    for (i = 0; i < n; i++) {
        if (modbus_write_register(c[i], 900 + i % 90, (uint16_t) i) == 1) {
            write_ok++;
        }
    }
    EXPECT(write_ok == n, "each wrote a register (%d of %d)", write_ok, n);
    for (i = 0; i < n; i++) {
        if (modbus_read_registers(c[i], 900 + i % 90, 1, &v) == 1 && v < n) {
            back_ok++;
        }
    }
    EXPECT(back_ok == n, "each read a written register back (%d of %d)", back_ok, n);
    for (i = 0; i < n; i++) {
        if (c[i] != NULL) {
            modbus_close(c[i]);
            modbus_free(c[i]);
        }
    }
    free(c);
    printf("# %d clients: %.0f ms\n", n, now_ms() - t0);
}

static void pipelined(void)
{
    uint8_t q[20 * 12], a[20 * 11];
    int s = raw_connect(), i, got = 0, ok = 1;
    if (!EXPECT(s >= 0, "raw connect")) {
        return;
    }
    for (i = 0; i < 20; i++) {
        read_request(q + 12 * i, 100 + i, 200 + i);
    }
    EXPECT(send(s, q, sizeof q, 0) == (ssize_t) sizeof q, "20 requests in one write");
    while (got < (int) sizeof a) {
        struct pollfd p = {s, POLLIN, 0};
        ssize_t n;
        if (poll(&p, 1, 5000) <= 0) {
            break;
        }
        n = recv(s, a + got, sizeof a - (size_t) got, 0);
        if (n <= 0) {
            break;
        }
        got += (int) n;
    }
    EXPECT(got == (int) sizeof a, "20 answers (%d bytes)", got);
    for (i = 0; ok && i < 20 && got == (int) sizeof a; i++) {
        const uint8_t *r = a + 11 * i;
        ok = r[0] == 0 && r[1] == 100 + i && r[7] == 3 && r[8] == 2 && ((r[9] << 8) | r[10]) % 1000 == 200 + i;
    }
    EXPECT(ok, "in order, each with its transaction id and value");
    close(s);
}

static void slow(void)
{
    uint8_t q[12];
    int trickle = raw_connect(), stalled = raw_connect(), garbage = raw_connect(), half = raw_connect();
    modbus_t *ctx = client();
    double worst = 0, next_byte = now_ms();
    int i, sent = 0, ok = 0;
    uint16_t v;
    /* A browser pointed at the port: an MBAP header that announces 12064 bytes. */
    static const char junk[] = "GET / HTTP/1.1\r\nHost: plc\r\n\r\n";
    if (!EXPECT(trickle >= 0 && stalled >= 0 && garbage >= 0 && half >= 0 && ctx != NULL, "misbehaving clients connected")) {
        return;
    }
    read_request(q, 1, 0);
    EXPECT(send(stalled, q, 5, 0) == 5, "a client stalls in the middle of a request");
    EXPECT(send(garbage, junk, strlen(junk), 0) == (ssize_t) strlen(junk), "a client sends garbage (an HTTP request)");
    shutdown(half, SHUT_WR);
    for (i = 0; i < 100; i++) {
        double t = now_ms(), d;
        if (sent < 12 && t >= next_byte) {
            if (send(trickle, q + sent, 1, 0) == 1) {
                sent++;
            }
            next_byte = t + 200;
        }
        t = now_ms();
        if (modbus_read_registers(ctx, 7, 1, &v) == 1 && v % 1000 == 7) {
            ok++;
        }
        d = now_ms() - t;
        if (d > worst) {
            worst = d;
        }
        usleep(20000);
    }
    EXPECT(ok == 100, "100 reads of a well-behaved client answered (%d)", ok);
    EXPECT(worst < 200, "none slower than 200 ms (worst %.1f ms)", worst);
    while (sent < 12) {
        send(trickle, q + sent, 1, 0);
        sent++;
        usleep(100000);
    }
    {
        uint8_t a[11];
        struct pollfd p = {trickle, POLLIN, 0};
        int n = poll(&p, 1, 5000) > 0 ? (int) recv(trickle, a, sizeof a, 0) : -1;
        EXPECT(n == 11 && a[1] == 1 && a[7] == 3, "the request sent a byte at a time is answered (%d bytes)", n);
    }
    EXPECT(closed_within(garbage, 5000), "the garbage client is closed");
    EXPECT(closed_within(half, 5000), "the half-open client is closed");
    close(trickle);
    close(stalled);
    close(garbage);
    close(half);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void full(void)
{
    int s = raw_connect(), rcvbuf = 4096, i, ok = 0, blocked = 0;
    modbus_t *ctx;
    uint8_t q[12 * 100];
    uint16_t v[125];
    if (!EXPECT(s >= 0, "raw connect")) {
        return;
    }
    setsockopt(s, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
    for (i = 0; i < 100; i++) {
        uint8_t *r = q + 12 * i;
        read_request(r, i, 0);
        r[11] = 125; /* 250-byte answers */
    }
    /* Write until the server stops reading (its answers fill this socket). */
    for (i = 0; i < 100000; i++) {
        struct pollfd p = {s, POLLOUT, 0};
        if (poll(&p, 1, 200) <= 0) {
            blocked = 1;
            break;
        }
        if (send(s, q, sizeof q, MSG_DONTWAIT) <= 0) {
            blocked = 1;
            break;
        }
    }
    EXPECT(blocked, "a client that never reads fills its sockets (after %d writes)", i);
    ctx = client();
    for (i = 0; ctx != NULL && i < 50; i++) {
        if (modbus_read_registers(ctx, 0, 125, v) == 125 && v[124] % 1000 == 124) {
            ok++;
        }
    }
    EXPECT(ok == 50, "another client's 50 reads answered meanwhile (%d)", ok);
    close(s);
    if (ctx != NULL) {
        modbus_close(ctx);
        modbus_free(ctx);
    }
}

static void idle(int ms)
{
    int s = raw_connect();
    double t0 = now_ms(), t;
    int closed;
    if (!EXPECT(s >= 0, "raw connect")) {
        return;
    }
    closed = closed_within(s, ms * 4 + 2000);
    t = now_ms() - t0;
    EXPECT(closed, "an idle client is closed (after %.0f ms)", t);
    EXPECT(t >= ms / 2, "not before half the idle timeout (%.0f ms, timeout %d ms)", t, ms);
    close(s);
}

static void units(void)
{
    modbus_t *ctx = client();
    uint16_t v;
    int u;
    static const int ids[3] = {1, 2, 7};
    if (ctx == NULL) {
        return;
    }
    for (u = 0; u < 3; u++) {
        modbus_set_slave(ctx, ids[u]);
        EXPECT(modbus_read_registers(ctx, 5, 1, &v) == 1 && v == 1000 * (u + 1) + 5, "unit %d: its own value (%d)",
               ids[u], v);
    }
    modbus_set_slave(ctx, 5);
    errno = 0;
    EXPECT(modbus_read_registers(ctx, 5, 1, &v) == -1 && errno == EMBXGTAR,
           "unit 5: exception 0B, gateway target failed to respond (errno %d)", errno);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void hold(int n, int secs)
{
    int *s = calloc((size_t) n, sizeof *s), i, connected = 0, closed = 0;
    static const uint8_t start[3] = {0x16, 0x03, 0x01};
    for (i = 0; i < n; i++) {
        s[i] = raw_connect();
        if (s[i] >= 0 && send(s[i], start, sizeof start, 0) == 3) {
            connected++;
        }
    }
    EXPECT(connected == n, "%d stalled handshakes (%d)", n, connected);
    printf("HOLDING\n");
    fflush(stdout);
    sleep((unsigned) secs);
    for (i = 0; i < n; i++) {
        if (s[i] >= 0) {
            closed += closed_within(s[i], 0);
            close(s[i]);
        }
    }
    printf("# %d of %d closed by the server\n", closed, n);
    free(s);
}

static void status(int want)
{
    int k, j;
    for (k = 0; k < 2; k++) {
        int s = raw_connect();
        if (!EXPECT(s >= 0, "raw connect %d", k)) {
            return;
        }
        for (j = 0; j < 2; j++) {
            uint8_t q[8] = {0, (uint8_t) (j + 1), 0, 0, 0, 2, 1, 0x07}, a[16];
            struct pollfd p = {s, POLLIN, 0};
            int n = -1;
            send(s, q, sizeof q, 0);
            if (poll(&p, 1, 5000) > 0) {
                n = (int) recv(s, a, sizeof a, 0);
            }
            EXPECT(n == 9 && a[1] == j + 1 && a[7] == 0x07 && a[8] == want,
                   "connection %d, request %d: read exception status answers 0x%02X (%d bytes, 0x%02X)", k, j, want,
                   n, n == 9 ? a[8] : 0);
        }
        close(s);
    }
}

/* Reads what comes on `s` for up to `ms` into buf (at most max): the bytes read. */
static int read_for(int s, uint8_t *buf, int max, int want, int ms)
{
    int got = 0;
    double end = now_ms() + ms;
    while (got < want) {
        struct pollfd p = {s, POLLIN, 0};
        int left = (int) (end - now_ms());
        ssize_t n;
        if (left <= 0 || poll(&p, 1, left) <= 0) {
            break;
        }
        n = recv(s, buf + got, (size_t) (max - got), 0);
        if (n <= 0) {
            break;
        }
        got += (int) n;
    }
    return got;
}

static void later_scenario(void)
{
    uint8_t q[36], a[64];
    int s = raw_connect(), got, i, order_ok = 1, values_ok = 1;
    if (!EXPECT(s >= 0, "raw connect")) {
        return;
    }
    for (i = 0; i < 3; i++) {
        read_request(q + 12 * i, i + 1, 10 * (i + 1));
    }
    send(s, q, 36, 0);
    got = read_for(s, a, sizeof a, 33, 3000);
    EXPECT(got == 33, "three reads in one write: three answers (%d bytes)", got);
    for (i = 0; got == 33 && i < 3; i++) {
        const uint8_t *r = a + 11 * i;
        int tid = r[1], value = (r[9] << 8) | r[10];
        order_ok &= tid == 3 - i;
        values_ok &= r[7] == 3 && value % 1000 == 10 * tid;
    }
    EXPECT(order_ok, "answered later, last first (by transaction id)");
    EXPECT(values_ok, "each answer with its own value");
    {
        uint8_t u[8] = {0, 9, 0, 0, 0, 2, 1, 0x41};
        send(s, u, sizeof u, 0);
        got = read_for(s, a, sizeof a, 9, 3000);
        EXPECT(got == 9 && a[1] == 9 && a[7] == 0xC1 && a[8] == 1, "an unknown function code: exception 01, later");
    }
    read_request(q, 20, 999);
    send(s, q, 12, 0);
    got = read_for(s, a, sizeof a, 1, 500);
    EXPECT(got == 0, "a request answered with MODBUS_REPLY_NONE: nothing in 500 ms");
    read_request(q, 21, 5);
    send(s, q, 12, 0);
    got = read_for(s, a, sizeof a, 11, 3000);
    EXPECT(got == 11 && a[1] == 21, "the next request is answered");
    close(s);
    s = raw_connect();
    read_request(q, 30, 7);
    send(s, q, 12, 0);
    close(s);
    usleep(200000);
    s = raw_connect();
    read_request(q, 31, 8);
    send(s, q, 12, 0);
    got = read_for(s, a, sizeof a, 11, 3000);
    EXPECT(got == 11 && a[1] == 31, "after a client left with its request unanswered, another is served");
    close(s);
}

static void rtu(const char *device)
{
    modbus_t *ctx = modbus_new_rtu(device, 115200, 'N', 8, 1);
    static const int ids[3] = {1, 2, 7};
    uint16_t v;
    int u;
    if (!EXPECT(ctx != NULL && modbus_connect(ctx) == 0, "open %s", device)) {
        return;
    }
    modbus_set_response_timeout(ctx, 1, 0);
    for (u = 0; u < 3; u++) {
        modbus_set_slave(ctx, ids[u]);
        EXPECT(modbus_read_registers(ctx, 5, 1, &v) == 1 && v == 1000 * (u + 1) + 5, "unit %d: its own value (%d)",
               ids[u], v);
        EXPECT(modbus_write_register(ctx, 6, (uint16_t) (100 + u)) == 1 && modbus_read_registers(ctx, 6, 1, &v) == 1 &&
                   v == 100 + u,
               "unit %d: a write read back", ids[u]);
    }
    modbus_set_slave(ctx, 5);
    errno = 0;
    EXPECT(modbus_read_registers(ctx, 5, 1, &v) == -1 && errno == ETIMEDOUT, "unit 5: silence (errno %d)", errno);
    modbus_set_slave(ctx, 2);
    EXPECT(modbus_read_registers(ctx, 5, 1, &v) == 1 && v == 2005, "then unit 2 again");
    modbus_set_slave(ctx, 0);
    {
        int rc = modbus_write_register(ctx, 8, 4242), e = errno;
        /* libmodbus waits for an answer no one sends (ETIMEDOUT); ours returns 1. */
        EXPECT(rc == 1 || (rc == -1 && e == ETIMEDOUT), "a broadcast write goes out (rc %d)", rc);
    }
    usleep(100000);
    for (u = 0; u < 3; u++) {
        modbus_set_slave(ctx, ids[u]);
        EXPECT(modbus_read_registers(ctx, 8, 1, &v) == 1 && v == 4242, "unit %d got the broadcast", ids[u]);
    }
    modbus_close(ctx);
    modbus_free(ctx);
}

static void stop(void)
{
    modbus_t *ctx = client();
    if (ctx == NULL) {
        return;
    }
    modbus_set_slave(ctx, 1);
    EXPECT(modbus_write_register(ctx, 999, 0xDEAD) == 1, "the write that stops the server is answered");
    modbus_close(ctx);
    modbus_free(ctx);
}

int main(int argc, char **argv)
{
    const char *what;
    struct rlimit rl;
    if (argc < 3) {
        fprintf(stderr, "usage: runner-check PORT SCENARIO [ARG]\n");
        return 2;
    }
    print_loaded_libmodbus();
    port = atoi(argv[1]);
    what = argv[2];
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < rl.rlim_max) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
    if (strcmp(what, "basic") == 0) {
        basic(argc > 3 ? atoi(argv[3]) : 0);
    } else if (strcmp(what, "many") == 0 && argc > 3) {
        many(atoi(argv[3]));
    } else if (strcmp(what, "pipelined") == 0) {
        pipelined();
    } else if (strcmp(what, "slow") == 0) {
        slow();
    } else if (strcmp(what, "full") == 0) {
        full();
    } else if (strcmp(what, "idle") == 0 && argc > 3) {
        idle(atoi(argv[3]));
    } else if (strcmp(what, "units") == 0) {
        units();
    } else if (strcmp(what, "hold") == 0 && argc > 4) {
        hold(atoi(argv[3]), atoi(argv[4]));
    } else if (strcmp(what, "status") == 0 && argc > 3) {
        status(atoi(argv[3]));
    } else if (strcmp(what, "later") == 0) {
        later_scenario();
    } else if (strcmp(what, "rtu") == 0) {
        rtu(argv[1]);
    } else if (strcmp(what, "stop") == 0) {
        stop();
    } else {
        fprintf(stderr, "unknown scenario %s\n", what);
        return 2;
    }
    return chk_summary();
}
