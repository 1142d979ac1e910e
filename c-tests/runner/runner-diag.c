/*
 * runner-diag.c: the server runner (modbus_server_new(3)) against the blocking server
 * (modbus_receive + modbus_reply) of the same library, on the same traffic, for what
 * the runner must do as the blocking server does (c-tests/suites/runner.sh):
 *
 *   runner-diag counters rtu|ascii|tcp
 *       the diagnostics counters (modbus_enable_diagnostics): the same requests, a
 *       frame with a bad CRC (RTU) or LRC (ASCII) and a frame announcing more bytes
 *       than an ADU holds, to a blocking server, then to a runner; the runner's bus
 *       message (0x0B), bus communication error (0x0C) and bus character overrun
 *       (0x12) counts must be the blocking server's
 *   runner-diag delimiter
 *       ASCII: FC 08 sub-function 03 (Change ASCII Input Delimiter) to '!', then a
 *       request ended by CR '!': answered by the blocking server, and by the runner
 *   runner-diag stop rtu|udp
 *       a runner on its own line (RTU on a pty pair, Modbus/UDP) with a response
 *       timeout of 3 s gets a request whose answer libmodbus sends after sleeping the
 *       response timeout and flushing (FC 03 for 0 registers: "Illegal nb of values");
 *       modbus_server_stop (from another thread, from a signal handler) must end the
 *       run at once (within 500 ms); on UDP, another peer's request sent right after
 *       must be answered within 1 s
 *
 * The servers run in threads of this process, on a pty pair (openpty: the test writes
 * and reads the raw bytes on the master) or on loopback (port 0, or a port just found
 * free for UDP). Register i holds i. One line per check (c-tests/common/check.h);
 * the library in use first (LIBINFO, c-tests/common/libinfo.c). Lines starting with
 * '#' are the numbers measured.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbt-loopback.h"

int mbt_is_rsmodbus(void); /* c-tests/common/libinfo.c, which prints LIBINFO first */

enum kind { RTU, ASCII, TCP, UDP };
static const char *const KIND_NAME[] = {"rtu", "ascii", "tcp", "udp"};

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

static void sleep_ms(int ms)
{
    usleep((useconds_t) ms * 1000);
}

/* ---------------------------------------------------------------- frames */
static uint16_t crc16(const uint8_t *p, int n)
{
    uint16_t crc = 0xFFFF;
    int i, b;
    for (i = 0; i < n; i++) {
        crc ^= p[i];
        for (b = 0; b < 8; b++) {
            crc = (crc & 1) ? (uint16_t) ((crc >> 1) ^ 0xA001) : (uint16_t) (crc >> 1);
        }
    }
    return crc;
}

/* RTU: unit + PDU, then the CRC (low byte first; `bad`: the CRC spoiled). */
static int rtu_frame(uint8_t *out, const uint8_t *body, int n, int bad)
{
    uint16_t c = crc16(body, n);
    memcpy(out, body, (size_t) n);
    out[n] = (uint8_t) (c & 0xFF);
    out[n + 1] = (uint8_t) (c >> 8);
    if (bad) {
        out[n + 1] ^= 0x55;
    }
    return n + 2;
}

/* ASCII: ':', the hexadecimal digits of unit + PDU and of the LRC (`bad`: spoiled),
 * then `end` (CR LF, CR '!', or nothing). */
static int ascii_frame(char *out, const uint8_t *body, int n, int bad, const char *end)
{
    uint8_t lrc = 0;
    int i, len = 0;
    out[len++] = ':';
    for (i = 0; i < n; i++) {
        lrc = (uint8_t) (lrc + body[i]);
        len += sprintf(out + len, "%02X", body[i]);
    }
    lrc = (uint8_t) -lrc;
    if (bad) {
        lrc ^= 0x5A;
    }
    len += sprintf(out + len, "%02X%s", lrc, end);
    return len;
}

/* ---------------------------------------------------------------- the test's end of a line */
struct line {
    enum kind kind;
    int fd;          /* pty master, or the client socket */
    int slave_fd;    /* pty slave, held open so that the server's close does not hang up */
    char path[256];  /* pty slave's name */
    int port;        /* TCP, UDP */
};

static int open_pty(struct line *l)
{
    struct termios t;
    if (openpty(&l->fd, &l->slave_fd, l->path, NULL, NULL) != 0) {
        return -1;
    }
    tcgetattr(l->slave_fd, &t);
    cfmakeraw(&t);
    cfsetispeed(&t, B115200);
    cfsetospeed(&t, B115200);
    tcsetattr(l->slave_fd, TCSANOW, &t);
    return 0;
}

/* A UDP port free now on 127.0.0.1. */
static int free_udp_port(void)
{
    struct sockaddr_in a = {.sin_family = AF_INET};
    socklen_t len = sizeof a;
    int s = socket(AF_INET, SOCK_DGRAM, 0), port = -1;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(s, (struct sockaddr *) &a, sizeof a) == 0 && getsockname(s, (struct sockaddr *) &a, &len) == 0) {
        port = ntohs(a.sin_port);
    }
    close(s);
    return port;
}

static void write_all(int fd, const void *p, size_t n)
{
    const uint8_t *b = p;
    while (n > 0) {
        ssize_t k = write(fd, b, n);
        if (k <= 0) {
            if (k < 0 && errno == EINTR) {
                continue;
            }
            return;
        }
        b += k;
        n -= (size_t) k;
    }
}

/* Reads an answer: up to `first_ms` for its first byte, then until `gap_ms` of
 * silence (or, on ASCII, its LF; on a datagram socket, one datagram). Returns its
 * length (0: nothing came). */
static int read_answer(int fd, enum kind kind, uint8_t *buf, int max, int first_ms, int gap_ms)
{
    int len = 0;
    for (;;) {
        struct pollfd p = {fd, POLLIN, 0};
        int n = poll(&p, 1, len == 0 ? first_ms : gap_ms);
        ssize_t k;
        if (n <= 0) {
            return len;
        }
        k = read(fd, buf + len, (size_t) (max - len));
        if (k <= 0) {
            return len;
        }
        len += (int) k;
        if (kind == UDP || (kind == ASCII && buf[len - 1] == '\n') || len == max) {
            return len;
        }
    }
}

/* Drops whatever is waiting on `fd` now. */
static void drain(int fd)
{
    uint8_t junk[1024];
    struct pollfd p = {fd, POLLIN, 0};
    while (poll(&p, 1, 0) > 0 && (p.revents & POLLIN) && read(fd, junk, sizeof junk) > 0) {
    }
}

/* ---------------------------------------------------------------- servers in threads */
#define NB 100

struct server {
    enum kind kind;
    int runner;
    modbus_t *ctx;
    modbus_mapping_t *map;
    modbus_server_t *s;
    int listen_fd;
    int port;
    volatile int quit;
    pthread_t th;
    int run_rc;
    int running;
};

static modbus_t *server_context(enum kind kind, const char *path, int port)
{
    modbus_t *ctx;
    switch (kind) {
    case RTU:
        ctx = modbus_new_rtu(path, 115200, 'N', 8, 1);
        break;
    case ASCII:
        ctx = modbus_new_ascii(path, 115200, 'N', 8, 1);
        break;
    case UDP:
        ctx = modbus_new_udp("127.0.0.1", port);
        break;
    default:
        ctx = modbus_new_tcp("127.0.0.1", 0);
        break;
    }
    if (ctx != NULL && kind != TCP && kind != UDP) {
        modbus_set_slave(ctx, 1);
    }
    if (ctx != NULL && getenv("RUNNER_DEBUG") != NULL) {
        modbus_set_debug(ctx, TRUE);
    }
    return ctx;
}

static void *blocking_main(void *arg)
{
    struct server *sv = arg;
    uint8_t q[1024];
    int connected = sv->kind != TCP;
    modbus_set_indication_timeout(sv->ctx, 0, 100000);
    while (!sv->quit) {
        int rc;
        if (!connected) {
            if (modbus_tcp_accept(sv->ctx, &sv->listen_fd) < 0) {
                break;
            }
            connected = 1;
            continue;
        }
        rc = modbus_receive(sv->ctx, q);
        if (rc > 0) {
            modbus_reply(sv->ctx, q, rc, sv->map);
        } else if (rc < 0 && sv->kind == TCP && errno != ETIMEDOUT && errno != EMBBADDATA && errno != EMBBADCRC) {
            /* The client left: the next one. */
            modbus_close(sv->ctx);
            connected = 0;
        }
    }
    return NULL;
}

static void *runner_main(void *arg)
{
    struct server *sv = arg;
    sv->run_rc = modbus_server_run(sv->s, -1);
    sv->running = 0;
    return NULL;
}

/* Starts a server on `ctx` (made by server_context): blocking (runner 0) or a runner,
 * with diagnostics when `diag`. Returns 0, or -1 (said). */
static int server_start(struct server *sv, enum kind kind, modbus_t *ctx, int runner, int diag)
{
    int i;
    memset(sv, 0, sizeof *sv);
    sv->kind = kind;
    sv->runner = runner;
    sv->ctx = ctx;
    sv->listen_fd = -1;
    sv->map = modbus_mapping_new(NB, NB, NB, NB);
    for (i = 0; i < NB; i++) {
        sv->map->tab_registers[i] = (uint16_t) i;
    }
    if (diag && modbus_enable_diagnostics(ctx, 1) != 0) {
        EXPECT(0, "modbus_enable_diagnostics: %s", modbus_strerror(errno));
        return -1;
    }
    if (kind == TCP) {
        struct sockaddr_in a;
        socklen_t len = sizeof a;
        sv->listen_fd = modbus_tcp_listen(ctx, 8);
        if (sv->listen_fd < 0 || getsockname(sv->listen_fd, (struct sockaddr *) &a, &len) != 0) {
            EXPECT(0, "modbus_tcp_listen: %s", modbus_strerror(errno));
            return -1;
        }
        sv->port = ntohs(a.sin_port);
        if (runner) {
            modbus_set_socket(ctx, sv->listen_fd);
        }
    } else if (!runner && modbus_connect(ctx) != 0) {
        EXPECT(0, "modbus_connect (server): %s", modbus_strerror(errno));
        return -1;
    }
    if (runner) {
        sv->s = modbus_server_new(ctx, 8);
        if (sv->s == NULL) {
            EXPECT(0, "modbus_server_new: %s", modbus_strerror(errno));
            return -1;
        }
        modbus_server_set_mapping(sv->s, sv->map);
        sv->running = 1;
        pthread_create(&sv->th, NULL, runner_main, sv);
    } else {
        pthread_create(&sv->th, NULL, blocking_main, sv);
    }
    return 0;
}

/* Joins the server's thread within `limit_s`; returns 0, or -1 (still running). */
static int join_within(struct server *sv, double limit_s)
{
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += (time_t) limit_s;
    return pthread_timedjoin_np(sv->th, NULL, &until) == 0 ? 0 : -1;
}

/* Stops the server (its thread joined); its context stays for reading. */
static int server_stop(struct server *sv)
{
    if (sv->runner) {
        modbus_server_stop(sv->s);
    } else {
        sv->quit = 1;
        if (sv->kind == TCP) {
            /* (modbus_tcp_accept waits for a client: one that leaves at once.) */
            int c = mbt_loopback_connect(SOCK_STREAM, sv->port);
            if (c >= 0) {
                close(c);
            }
        }
    }
    if (join_within(sv, 20) != 0) {
        EXPECT(0, "%s server: its thread ends within 20 s", sv->runner ? "runner" : "blocking");
        return -1;
    }
    return 0;
}

static void server_free(struct server *sv)
{
    if (sv->s != NULL) {
        modbus_server_free(sv->s);
    }
    if (sv->kind == TCP && sv->listen_fd >= 0 && !sv->runner) {
        close(sv->listen_fd);
    }
    modbus_close(sv->ctx);
    modbus_free(sv->ctx);
    modbus_mapping_free(sv->map);
}

/* ---------------------------------------------------------------- 1. the counters */
static const int SUBS[8] = {0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x10, 0x11, 0x12};
static const char *const SUB_NAME[8] = {"bus message",    "bus communication error", "bus exception error",
                                        "server message", "server no response",      "server NAK",
                                        "server busy",    "bus character overrun"};

struct traffic {
    int reads, answered;
};

/* One request of the traffic (unit 1, FC 03 at `addr`, 2 registers): its answer must
 * come. */
static void send_read(struct line *l, struct traffic *t, int addr, uint16_t tid)
{
    uint8_t body[6] = {1, 3, 0, (uint8_t) addr, 0, 2}, out[64], ans[600];
    char text[64];
    int n, k;
    t->reads++;
    if (l->kind == RTU) {
        n = rtu_frame(out, body, 6, 0);
        write_all(l->fd, out, (size_t) n);
    } else if (l->kind == ASCII) {
        n = ascii_frame(text, body, 6, 0, "\r\n");
        write_all(l->fd, text, (size_t) n);
    } else {
        uint8_t mbap[12] = {(uint8_t) (tid >> 8), (uint8_t) tid, 0, 0, 0, 6};
        memcpy(mbap + 6, body, 6);
        write_all(l->fd, mbap, 12);
    }
    k = read_answer(l->fd, l->kind, ans, sizeof ans, 2000, 50);
    /* RTU 01 03 04 ..: 9 bytes; ASCII ":010304" + 8 digits + LRC + CRLF: 19; TCP 7 + 6: 13. */
    if ((l->kind == RTU && k == 9 && ans[1] == 3 && ans[3] == 0 && ans[4] == addr) ||
        (l->kind == ASCII && k == 19 && memcmp(ans, ":010304", 7) == 0) ||
        (l->kind == TCP && k == 13 && ans[7] == 3 && ans[10] == addr)) {
        t->answered++;
    }
}

/* A frame with a bad CRC (RTU) or LRC (ASCII): no answer. */
static void send_bad_checksum(struct line *l)
{
    uint8_t body[6] = {1, 3, 0, 0, 0, 2}, out[16], ans[600];
    char text[64];
    int n;
    if (l->kind == RTU) {
        n = rtu_frame(out, body, 6, 1);
        write_all(l->fd, out, (size_t) n);
    } else {
        n = ascii_frame(text, body, 6, 1, "\r\n");
        write_all(l->fd, text, (size_t) n);
    }
    /* (nothing must come; the server has time to drop it) */
    EXPECT(read_answer(l->fd, l->kind, ans, sizeof ans, 500, 50) == 0, "%s: no answer to a frame with a bad %s",
           KIND_NAME[l->kind], l->kind == RTU ? "CRC" : "LRC");
}

/* A frame that announces more bytes than an ADU holds: FC 16 (write multiple
 * registers) of 127 registers, byte count 254; only its header is sent (the server
 * stops at the byte count). */
static void send_overrun(struct line *l, uint16_t tid)
{
    uint8_t body[7] = {1, 0x10, 0, 0, 0, 0x7F, 0xFE}, ans[600];
    char text[64];
    if (l->kind == RTU) {
        write_all(l->fd, body, 7);
    } else if (l->kind == ASCII) {
        /* (a whole line: its LRC and CR LF come where 254 bytes were announced) */
        int n = ascii_frame(text, body, 7, 0, "\r\n");
        write_all(l->fd, text, (size_t) n);
    } else {
        /* MBAP length: unit + FC + 5 + 254 bytes = 261. */
        uint8_t mbap[13] = {(uint8_t) (tid >> 8), (uint8_t) tid, 0, 0, 0x01, 0x05};
        memcpy(mbap + 6, body, 7);
        write_all(l->fd, mbap, 13);
    }
    /* (ASCII: past the server's byte timeout, 1 s, in case it waits for the rest) */
    EXPECT(read_answer(l->fd, l->kind, ans, sizeof ans, l->kind == ASCII ? 1500 : 500, 50) == 0,
           "%s: no answer to a frame announcing 254 bytes of data", KIND_NAME[l->kind]);
}

/* The traffic: 3 reads, a bad checksum (serial), a read, an overrun, 1 read (TCP: a
 * new connection after the overrun, and 2 reads on it). */
static void traffic(struct server *sv, struct line *l, struct traffic *t)
{
    int i;
    uint16_t tid = 1;
    memset(t, 0, sizeof *t);
    if (l->kind == TCP) {
        l->fd = mbt_loopback_connect(SOCK_STREAM, sv->port);
        if (!EXPECT(l->fd >= 0, "tcp: connect to the server")) {
            return;
        }
    }
    for (i = 0; i < 3; i++) {
        send_read(l, t, 10 + i, tid++);
    }
    if (l->kind != TCP) {
        send_bad_checksum(l);
    }
    send_read(l, t, 20, tid++);
    send_overrun(l, tid++);
    if (l->kind == TCP) {
        close(l->fd);
        sleep_ms(200);
        l->fd = mbt_loopback_connect(SOCK_STREAM, sv->port);
        if (!EXPECT(l->fd >= 0, "tcp: connect again")) {
            return;
        }
        send_read(l, t, 30, tid++);
    }
    send_read(l, t, 31, tid++);
    if (l->kind == TCP) {
        close(l->fd);
        l->fd = -1;
        /* (the server sees the connection end before it is stopped) */
        sleep_ms(300);
    }
}

static int counters(enum kind kind)
{
    struct line l;
    uint16_t got[2][8];
    int which, i;
    const char *what[2] = {"blocking server (modbus_receive + modbus_reply)", "runner (modbus_server_run)"};
    memset(&l, 0, sizeof l);
    l.kind = kind;
    l.fd = -1;
    if (kind != TCP && !EXPECT(open_pty(&l) == 0, "openpty")) {
        return chk_summary();
    }
    for (which = 0; which < 2; which++) {
        struct server sv;
        struct traffic t;
        modbus_t *ctx = server_context(kind, l.path, 0);
        if (!EXPECT(ctx != NULL, "%s: the server's context", KIND_NAME[kind]) ||
            server_start(&sv, kind, ctx, which, 1) != 0) {
            return chk_summary();
        }
        if (kind != TCP) {
            sleep_ms(200);
            drain(l.fd);
        }
        traffic(&sv, &l, &t);
        EXPECT(t.answered == t.reads, "%s: %s: every read answered (%d of %d)", KIND_NAME[kind], what[which],
               t.answered, t.reads);
        if (server_stop(&sv) != 0) {
            return chk_summary();
        }
        for (i = 0; i < 8; i++) {
            got[which][i] = 0xFFFF;
            if (modbus_get_diagnostics(ctx, SUBS[i], &got[which][i]) != 0) {
                EXPECT(0, "%s: modbus_get_diagnostics(0x%02X): %s", KIND_NAME[kind], SUBS[i], modbus_strerror(errno));
            }
        }
        printf("# %s %s:", KIND_NAME[kind], which ? "runner" : "blocking");
        for (i = 0; i < 8; i++) {
            printf(" 0x%02X=%u", SUBS[i], got[which][i]);
        }
        printf("\n");
        server_free(&sv);
    }
    /* The blocking server's counts, as measured (the traffic's: every frame read whole
     * is a bus message, the request for a counter not included since none is sent):
     * RTU 5 reads + 1 bad CRC + 1 overrun = 7 messages, 1 error, 1 overrun;
     * ASCII 5 reads + 1 bad LRC + 1 frame too short for its byte count = 7, 2 errors
     * (a frame that cannot be decoded is a communication error on ASCII), 0 overruns;
     * TCP 6 reads + 1 overrun = 7 messages, 0 errors, 1 overrun. */
    {
        static const int want[3][3] = {{7, 1, 1}, {7, 2, 0}, {7, 0, 1}};
        const int *w = want[kind == RTU ? 0 : kind == ASCII ? 1 : 2];
        EXPECT(got[0][0] == w[0] && got[0][1] == w[1] && got[0][7] == w[2],
               "%s: the blocking server's counts: bus messages %u, bus communication errors %u, bus character "
               "overruns %u (expected %d, %d, %d)",
               KIND_NAME[kind], got[0][0], got[0][1], got[0][7], w[0], w[1], w[2]);
    }
    for (i = 0; i < 8; i++) {
        if (SUBS[i] == 0x0B || SUBS[i] == 0x0C || SUBS[i] == 0x12) {
            EXPECT(got[1][i] == got[0][i], "%s: runner's %s count (0x%02X) = the blocking server's: %u (blocking %u)",
                   KIND_NAME[kind], SUB_NAME[i], SUBS[i], got[1][i], got[0][i]);
        }
    }
    if (kind != TCP) {
        close(l.fd);
        close(l.slave_fd);
    }
    return chk_summary();
}

/* ---------------------------------------------------------------- 2. the ASCII delimiter */
static int delimiter(void)
{
    struct line l;
    int which;
    const char *what[2] = {"blocking server", "runner"};
    memset(&l, 0, sizeof l);
    l.kind = ASCII;
    if (!EXPECT(open_pty(&l) == 0, "openpty")) {
        return chk_summary();
    }
    for (which = 0; which < 2; which++) {
        struct server sv;
        uint8_t change[6] = {1, 8, 0, 3, '!', 0}, read[6] = {1, 3, 0, 7, 0, 2}, ans[600];
        char text[64], expect[64];
        uint16_t value = 0;
        int n, k;
        modbus_t *ctx = server_context(ASCII, l.path, 0);
        if (!EXPECT(ctx != NULL, "ascii: the server's context") || server_start(&sv, ASCII, ctx, which, 1) != 0) {
            return chk_summary();
        }
        sleep_ms(200);
        drain(l.fd);
        /* Change ASCII Input Delimiter to '!': the request echoed. */
        n = ascii_frame(text, change, 6, 0, "\r\n");
        write_all(l.fd, text, (size_t) n);
        k = read_answer(l.fd, ASCII, ans, sizeof ans - 1, 2000, 50);
        ans[k] = 0;
        text[n - 2] = 0;
        EXPECT(k == n && memcmp(ans, text, (size_t) n - 2) == 0,
               "ascii %s: FC 08/03 (change the input delimiter to '!') echoed (%d bytes: %.*s)", what[which], k,
               k > 2 ? k - 2 : 0, (const char *) ans);
        /* A read ended by CR '!': answered. */
        n = ascii_frame(text, read, 6, 0, "\r!");
        write_all(l.fd, text, (size_t) n);
        k = read_answer(l.fd, ASCII, ans, sizeof ans - 1, 2000, 50);
        ans[k] = 0;
        {
            uint8_t body[7] = {1, 3, 4, 0, 7, 0, 8};
            ascii_frame(expect, body, 7, 0, "\r\n");
        }
        EXPECT(k == (int) strlen(expect) && memcmp(ans, expect, (size_t) k) == 0,
               "ascii %s: a read of registers 7 and 8 ended by CR '!' after the change: answered (%d bytes: %.*s; "
               "expected %.*s)",
               what[which], k, k > 2 ? k - 2 : 0, (const char *) ans, (int) strlen(expect) - 2, expect);
        if (server_stop(&sv) != 0) {
            return chk_summary();
        }
        k = modbus_get_diagnostics(ctx, 0x03, &value);
        EXPECT(k == 0 && value == '!',
               "ascii %s: modbus_get_diagnostics(0x03) says the delimiter is '!' (rc %d, 0x%02X)", what[which], k,
               value);
        server_free(&sv);
    }
    close(l.fd);
    close(l.slave_fd);
    return chk_summary();
}

/* ---------------------------------------------------------------- 3. the stop */
static modbus_server_t *signalled_server;
static void on_usr1(int sig)
{
    (void) sig;
    modbus_server_stop(signalled_server);
}

/* The request libmodbus answers after the response timeout and a flush: FC 03 for 0
 * registers (exception 03 once flushed), unit 1. */
static void send_flush_request(struct line *l, int peer_fd, uint16_t tid)
{
    uint8_t body[6] = {1, 3, 0, 0, 0, 0}, out[16];
    if (l->kind == RTU) {
        int n = rtu_frame(out, body, 6, 0);
        write_all(l->fd, out, (size_t) n);
    } else {
        uint8_t mbap[12] = {(uint8_t) (tid >> 8), (uint8_t) tid, 0, 0, 0, 6};
        memcpy(mbap + 6, body, 6);
        (void) !send(peer_fd, mbap, 12, 0);
    }
}

/* A good read (unit 1, FC 03, register 5) from `fd` (pty master or UDP peer). */
static void send_good_read(enum kind kind, int fd, uint16_t tid)
{
    uint8_t body[6] = {1, 3, 0, 5, 0, 1}, out[16];
    if (kind == RTU) {
        int n = rtu_frame(out, body, 6, 0);
        write_all(fd, out, (size_t) n);
    } else {
        uint8_t mbap[12] = {(uint8_t) (tid >> 8), (uint8_t) tid, 0, 0, 0, 6};
        memcpy(mbap + 6, body, 6);
        (void) !send(fd, mbap, 12, 0);
    }
}

static int good_answer(enum kind kind, const uint8_t *a, int k)
{
    return kind == RTU ? k == 7 && a[1] == 3 && a[4] == 5 : k == 11 && a[7] == 3 && a[10] == 5;
}

/* One stop while the runner handles the request of send_flush_request; `how`: 0 from
 * this thread, 1 from a signal handler (SIGUSR1 to the runner's thread). */
static void stop_during_recovery(struct server *sv, struct line *l, int peer_fd, int how)
{
    const char *name = KIND_NAME[l->kind];
    const char *from = how ? "a signal handler" : "another thread";
    double t0, t;
    /* Running, and answering. */
    uint8_t ans[64];
    int k, fd = l->kind == RTU ? l->fd : peer_fd;
    send_good_read(l->kind, fd, 1);
    k = read_answer(fd, l->kind, ans, sizeof ans, 2000, 50);
    EXPECT(good_answer(l->kind, ans, k), "%s: the runner answers a read (%d bytes)", name, k);
    send_flush_request(l, peer_fd, 2);
    /* (the request is in the runner's hands: it sleeps now, on main) */
    sleep_ms(300);
    t0 = now_s();
    if (how) {
        signalled_server = sv->s;
        pthread_kill(sv->th, SIGUSR1);
    } else {
        modbus_server_stop(sv->s);
    }
    if (join_within(sv, 20) != 0) {
        EXPECT(0, "%s: modbus_server_run returns within 20 s of modbus_server_stop", name);
        exit(chk_summary());
    }
    t = now_s() - t0;
    printf("# %s: modbus_server_run returned %.3f s after modbus_server_stop from %s (response timeout 3 s, "
           "request 0.3 s before)\n",
           name, t, from);
    EXPECT(t < 0.5,
           "%s: modbus_server_stop from %s during a request answered after a flush (FC 03 for 0 registers): the run "
           "ends within 0.5 s (%.3f s; response timeout 3 s)",
           name, from, t);
}

static int stop_case(enum kind kind)
{
    struct line l;
    struct server sv;
    struct sigaction sa;
    int how, peer = -1, other = -1;
    memset(&l, 0, sizeof l);
    l.kind = kind;
    l.fd = -1;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_usr1;
    sigaction(SIGUSR1, &sa, NULL);
    if (kind == RTU && !EXPECT(open_pty(&l) == 0, "openpty")) {
        return chk_summary();
    }
    if (kind == UDP) {
        l.port = free_udp_port();
    }
    for (how = 0; how < 2; how++) {
        modbus_t *ctx = server_context(kind, l.path, l.port);
        if (!EXPECT(ctx != NULL, "%s: the server's context", KIND_NAME[kind])) {
            return chk_summary();
        }
        modbus_set_response_timeout(ctx, 3, 0);
        if (server_start(&sv, kind, ctx, 1, 0) != 0) {
            return chk_summary();
        }
        if (kind == UDP) {
            peer = mbt_loopback_connect(SOCK_DGRAM, l.port);
            other = mbt_loopback_connect(SOCK_DGRAM, l.port);
            if (!EXPECT(peer >= 0 && other >= 0, "udp: two peers")) {
                return chk_summary();
            }
        } else {
            sleep_ms(200);
            drain(l.fd);
        }
        if (kind == UDP && how == 0) {
            /* Another peer's request, right after the one that needs a flush. */
            uint8_t ans[64];
            double t0, t = -1;
            int k;
            send_good_read(UDP, peer, 1);
            k = read_answer(peer, UDP, ans, sizeof ans, 2000, 50);
            EXPECT(good_answer(UDP, ans, k), "udp: the runner answers a read (%d bytes)", k);
            send_flush_request(&l, peer, 2);
            sleep_ms(100);
            t0 = now_s();
            send_good_read(UDP, other, 3);
            k = read_answer(other, UDP, ans, sizeof ans, 5000, 50);
            if (k > 0) {
                t = now_s() - t0;
            }
            printf("# udp: another peer's read sent 0.1 s after the request that needs a flush: %s after %.3f s "
                   "(response timeout 3 s)\n",
                   k > 0 ? "answered" : "not answered", k > 0 ? t : now_s() - t0);
            EXPECT(good_answer(UDP, ans, k) && t >= 0 && t < 1.0,
                   "udp: another peer's read sent right after a request answered after a flush: answered within "
                   "1 s (%s; response timeout 3 s)",
                   k > 0 ? "answered" : "no answer within 5 s");
            /* (what the first peer gets, whenever: dropped) */
            sleep_ms(3500);
            drain(peer);
            drain(other);
        }
        stop_during_recovery(&sv, &l, peer, how);
        server_free(&sv);
        if (kind == UDP) {
            close(peer);
            close(other);
        } else {
            sleep_ms(200);
            drain(l.fd);
        }
    }
    if (kind == RTU) {
        close(l.fd);
        close(l.slave_fd);
    }
    return chk_summary();
}

int main(int argc, char **argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    signal(SIGPIPE, SIG_IGN);
    if (argc < 2) {
        fprintf(stderr, "usage: runner-diag counters rtu|ascii|tcp | delimiter | stop rtu|udp\n");
        return 2;
    }
    if (!mbt_is_rsmodbus()) {
        fprintf(stderr, "the runner is rsmodbus': this is not it\n");
        return 97;
    }
    if (strcmp(argv[1], "counters") == 0 && argc > 2) {
        if (strcmp(argv[2], "rtu") == 0) {
            return counters(RTU);
        } else if (strcmp(argv[2], "ascii") == 0) {
            return counters(ASCII);
        } else if (strcmp(argv[2], "tcp") == 0) {
            return counters(TCP);
        }
    } else if (strcmp(argv[1], "delimiter") == 0) {
        return delimiter();
    } else if (strcmp(argv[1], "stop") == 0 && argc > 2) {
        if (strcmp(argv[2], "rtu") == 0) {
            return stop_case(RTU);
        } else if (strcmp(argv[2], "udp") == 0) {
            return stop_case(UDP);
        }
    }
    fprintf(stderr, "unknown scenario\n");
    return 2;
}
