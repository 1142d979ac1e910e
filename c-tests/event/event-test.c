/*
 * event-test: the event-driven client (modbus_*_async, modbus_get_pollfd,
 * modbus_process, modbus_pending, modbus_cancel, modbus_set_max_in_flight) against
 * a server no one here wrote (benches/mb-server.c on Debian's libmodbus, or on ours),
 * and against servers of its own for what a real one does not do (never answer,
 * answer late).
 *
 *   event-test tcp PORT       mb-server on 127.0.0.1:PORT, then the in-process cases
 *   event-test rtu DEVICE     mb-server rtu on the other end of a pty pair (slave 1,
 *                             115200 8N1)
 *   event-test rtu-late A B   a late device of its own on end A of a pty pair, the
 *                             client on B: the serial late-answer rule
 *   event-test many PORT N    N devices of c-tests/event/sim-devices.c (every 10th
 *                             dead), one multi handle, two cycles
 *   event-test tls PORT       mb-server tls (Modbus/TCP Security; certificates from
 *                             MB_TLS_CA, MB_TLS_CERT, MB_TLS_KEY), then a peer that
 *                             stalls its handshake
 *   event-test fc41 MODE ADDR a user-defined function code (0x41) whose answer libmodbus
 *                             cannot size: c-tests/event/fc41_device.py on MODE rtu|ascii
 *                             (pty end ADDR) or tcp|rtutcp (port ADDR), or a gateway
 *                             in front of it (tcp); the whole answer must come back
 *   event-test wake           lost wake-ups (servers of its own): a request given while
 *                             a loop or another thread waits, a deadline and
 *                             modbus_multi_wakeup end the wait (issue 39)
 *   event-test threads PORT N mb-server tcp: two threads per context, one giving
 *                             requests, one processing them (N), on a context and
 *                             on a context of a multi handle (also run by "tcp"; the
 *                             ThreadSanitizer build of the event suite runs this)
 *
 * Every asynchronous result is compared with the blocking call's on the same context
 * and server: rc, errno and the values. One line per check (c-tests/common/check.h);
 * the library in use first (LIBINFO).
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
#include <signal.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbt-connect.h"

int mbt_is_rsmodbus(void); /* c-tests/common/libinfo.c, which prints LIBINFO first */
static void chain_cb(modbus_t *ctx, int id, int rc, int error, void *user);
static void on_done(modbus_t *ctx, int id, int rc, int error, void *user);
/* The RTS hook's calls, as "0"/"1" characters; with rts_probe set, what calls on
 * the context give from inside the hook of an asynchronous request. */
static char rts_calls[64];
static int rts_probe, rts_pending = -2, rts_submit = -2, rts_submit_errno, rts_blocking = -2, rts_blocking_errno;
static void rts_hook(modbus_t *ctx, int on)
{
    size_t n = strlen(rts_calls);
    if (rts_probe && on) {
        uint16_t v;
        rts_probe = 0;
        rts_pending = modbus_pending(ctx);
        rts_submit = modbus_read_registers_async(ctx, 50, 1, &v, on_done, NULL);
        rts_submit_errno = errno;
        rts_blocking = modbus_read_registers(ctx, 50, 1, &v);
        rts_blocking_errno = errno;
    }
    if (n + 1 < sizeof rts_calls) {
        rts_calls[n] = on ? '1' : '0';
        rts_calls[n + 1] = '\0';
    }
}
static void free_cb(modbus_t *ctx, int id, int rc, int error, void *user);
static int freed_flag;

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

/* ---------------------------------------------------------------- completions */
#define MAX_REQ 4096

struct result {
    int done; /* times its callback ran */
    int rc;
    int error;
};
static struct result results[MAX_REQ];
static int completed;

static void on_done(modbus_t *ctx, int id, int rc, int error, void *user)
{
    (void) ctx;
    struct result *r = user != NULL ? user : (id >= 0 && id < MAX_REQ ? &results[id] : NULL);
    completed++;
    if (r != NULL) {
        r->done++;
        r->rc = rc;
        r->error = error;
    }
}

static void reset(void)
{
    memset(results, 0, sizeof(results));
    completed = 0;
}

/* Runs the loop until nothing is pending or `limit_s` passed; returns the seconds it took. */
static double drive(modbus_t *ctx, double limit_s)
{
    double t0 = now_s();
    while (modbus_pending(ctx) > 0 && now_s() - t0 < limit_s) {
        struct pollfd pfd;
        int timeout = -1;
        if (modbus_get_pollfd(ctx, &pfd, &timeout) < 0) {
            EXPECT(0, "modbus_get_pollfd: %s", modbus_strerror(errno));
            break;
        }
        if (timeout < 0 || timeout > 1000) {
            timeout = 1000;
        }
        int n = pfd.fd >= 0 && pfd.events != 0 ? poll(&pfd, 1, timeout) : (usleep((unsigned) timeout * 1000), 0);
        if (modbus_process(ctx, n > 0 ? pfd.revents : 0) < 0) {
            EXPECT(0, "modbus_process: %s", modbus_strerror(errno));
            break;
        }
    }
    return now_s() - t0;
}

/* One request, to its end: the callback's (rc, error). */
static struct result one(modbus_t *ctx, int id)
{
    struct result r = {0, -2, -2};
    if (id < 0) {
        r.rc = -1;
        r.error = errno;
        r.done = 1;
        return r;
    }
    drive(ctx, 10);
    if (id < MAX_REQ) {
        r = results[id];
    }
    return r;
}

static int same_result(const char *what, int brc, int berr, struct result a)
{
    return EXPECT(a.done == 1 && a.rc == brc && (brc != -1 || a.error == berr),
                  "%s: async rc %d error %d (%s), blocking rc %d errno %d (callbacks: %d)", what, a.rc, a.error,
                  a.rc == -1 ? modbus_strerror(a.error) : "ok", brc, brc == -1 ? berr : 0, a.done);
}

/* ---------------------------------------------------------------- against a real server */
/* modbus_send_raw_request_async: the answer's whole ADU, as the blocking calls see
 * it; an exception answer handed over as it came. (First on the context: a case of
 * compare_calls leaves an answer on a serial line.) */
static void raw_calls(modbus_t *ctx, int serial)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH], bad[MODBUS_MAX_ADU_LENGTH];
    /* The context's unit (pymodbus answers only its own), else TCP's 0xFF. */
    uint8_t unit = modbus_get_slave(ctx) > 0 ? (uint8_t) modbus_get_slave(ctx) : 0xFF;
    uint8_t req[6] = {unit, 0x03, 0x00, 0x05, 0x00, 0x02}, past[6] = {unit, 0x03, 0x7F, 0x00, 0x00, 0x01};
    uint16_t v[2] = {0, 0};
    int h = serial ? 1 : 7, crc = serial ? 2 : 0;
    struct result a;
    int brc;
    reset();
    memset(rsp, 0, sizeof rsp);
    a = one(ctx, modbus_send_raw_request_async(ctx, req, 6, rsp, on_done, NULL));
    brc = modbus_read_registers(ctx, 5, 2, v);
    EXPECT(brc == 2 && a.done == 1 && a.rc == h + 6 + crc && rsp[h] == 0x03 && rsp[h + 1] == 4 &&
               ((rsp[h + 2] << 8) | rsp[h + 3]) == v[0] && ((rsp[h + 4] << 8) | rsp[h + 5]) == v[1] &&
               rsp[h - 1] == unit,
           "raw async read of 2 registers: the whole answer (rc %d, unit %d, %d %d), the blocking call's values (rc %d: %d %d)",
           a.rc, rsp[h - 1], (rsp[h + 2] << 8) | rsp[h + 3], (rsp[h + 4] << 8) | rsp[h + 5], brc, v[0], v[1]);
    reset();
    memset(bad, 0, sizeof bad);
    a = one(ctx, modbus_send_raw_request_async(ctx, past, 6, bad, on_done, NULL));
    EXPECT(a.done == 1 && a.rc == h + 2 + crc && bad[h] == 0x83 && bad[h + 1] == 2,
           "raw async read past the table: the exception answer as it came (rc %d, 0x%02X 0x%02X)", a.rc, bad[h],
           bad[h + 1]);
    errno = 0;
    EXPECT(modbus_send_raw_request_async(ctx, req, 1, rsp, on_done, NULL) == -1 && errno == EINVAL,
           "raw async request of one byte: EINVAL");
}

static void compare_calls(modbus_t *ctx, int serial)
{
    uint16_t regs_b[64], regs_a[64], src[8] = {11, 22, 33, 44, 55, 66, 77, 88};
    uint8_t bits_b[64], bits_a[64], id_b[64], id_a[64];
    uint8_t coils[10] = {1, 0, 1, 1, 0, 0, 1, 0, 1, 1};
    int brc, berr;
    struct result a;

    reset();
    /* Writes first: each call's result, blocking then asynchronous. */
    brc = modbus_write_registers(ctx, 0, 8, src);
    berr = errno;
    a = one(ctx, modbus_write_registers_async(ctx, 8, 8, src, on_done, NULL));
    same_result("write_registers (FC 10)", brc, berr, a);

    brc = modbus_write_bits(ctx, 0, 10, coils);
    berr = errno;
    a = one(ctx, modbus_write_bits_async(ctx, 10, 10, coils, on_done, NULL));
    same_result("write_bits (FC 0F)", brc, berr, a);

    brc = modbus_write_bit(ctx, 30, 1);
    berr = errno;
    a = one(ctx, modbus_write_bit_async(ctx, 31, 1, on_done, NULL));
    same_result("write_bit (FC 05)", brc, berr, a);

    brc = modbus_write_register(ctx, 20, 0x1234);
    berr = errno;
    a = one(ctx, modbus_write_register_async(ctx, 21, 0x1234, on_done, NULL));
    same_result("write_register (FC 06)", brc, berr, a);

    brc = modbus_mask_write_register(ctx, 20, 0x00F2, 0x0025);
    berr = errno;
    a = one(ctx, modbus_mask_write_register_async(ctx, 21, 0x00F2, 0x0025, on_done, NULL));
    same_result("mask_write_register (FC 16)", brc, berr, a);

    /* Reads: the same values both ways. */
    memset(regs_b, 0, sizeof(regs_b));
    memset(regs_a, 0xFF, sizeof(regs_a));
    brc = modbus_read_registers(ctx, 0, 22, regs_b);
    berr = errno;
    a = one(ctx, modbus_read_registers_async(ctx, 0, 22, regs_a, on_done, NULL));
    if (same_result("read_registers (FC 03)", brc, berr, a)) {
        EXPECT(memcmp(regs_a, regs_b, 22 * sizeof(uint16_t)) == 0 && regs_a[8] == 11 && regs_a[21] == regs_b[20],
               "read_registers: the same 22 values (reg 8 = %u, reg 21 = 0x%04X)", regs_a[8], regs_a[21]);
    }

    memset(regs_a, 0xFF, sizeof(regs_a));
    brc = modbus_read_input_registers(ctx, 0, 5, regs_b);
    berr = errno;
    a = one(ctx, modbus_read_input_registers_async(ctx, 0, 5, regs_a, on_done, NULL));
    if (same_result("read_input_registers (FC 04)", brc, berr, a)) {
        EXPECT(memcmp(regs_a, regs_b, 5 * sizeof(uint16_t)) == 0, "read_input_registers: the same values");
    }

    memset(bits_a, 0x55, sizeof(bits_a));
    brc = modbus_read_bits(ctx, 0, 32, bits_b);
    berr = errno;
    a = one(ctx, modbus_read_bits_async(ctx, 0, 32, bits_a, on_done, NULL));
    if (same_result("read_bits (FC 01)", brc, berr, a)) {
        EXPECT(memcmp(bits_a, bits_b, 32) == 0 && bits_a[10] == 1 && bits_a[31] == 1 && bits_a[11] == 0,
               "read_bits: the same 32 values");
    }

    memset(bits_a, 0x55, sizeof(bits_a));
    brc = modbus_read_input_bits(ctx, 0, 16, bits_b);
    berr = errno;
    a = one(ctx, modbus_read_input_bits_async(ctx, 0, 16, bits_a, on_done, NULL));
    if (same_result("read_input_bits (FC 02)", brc, berr, a)) {
        EXPECT(memcmp(bits_a, bits_b, 16) == 0, "read_input_bits: the same values");
    }

    memset(regs_a, 0xFF, sizeof(regs_a));
    brc = modbus_write_and_read_registers(ctx, 40, 3, src, 40, 4, regs_b);
    berr = errno;
    a = one(ctx, modbus_write_and_read_registers_async(ctx, 40, 3, src + 3, 40, 4, regs_a, on_done, NULL));
    if (same_result("write_and_read_registers (FC 17)", brc, berr, a)) {
        EXPECT(regs_a[0] == 44 && regs_a[2] == 66 && regs_a[3] == regs_b[3], "write_and_read_registers: %u %u %u",
               regs_a[0], regs_a[1], regs_a[2]);
    }

    memset(id_a, 0, sizeof(id_a));
    memset(id_b, 0, sizeof(id_b));
    brc = modbus_report_slave_id(ctx, sizeof(id_b), id_b);
    berr = errno;
    a = one(ctx, modbus_report_slave_id_async(ctx, sizeof(id_a), id_a, on_done, NULL));
    if (same_result("report_slave_id (FC 11)", brc, berr, a)) {
        EXPECT(brc > 0 && memcmp(id_a, id_b, (size_t) brc) == 0, "report_slave_id: the same %d bytes", brc);
    }

    /* An exception answer: the same errno. */
    brc = modbus_read_registers(ctx, 60000, 2, regs_b);
    berr = errno;
    a = one(ctx, modbus_read_registers_async(ctx, 60000, 2, regs_a, on_done, NULL));
    same_result("exception (illegal data address)", brc, berr, a);

    /* Arguments the blocking call refuses, refused at once. */
    errno = 0;
    int id = modbus_read_registers_async(ctx, 0, 200, regs_a, on_done, NULL);
    EXPECT(id == -1 && errno == EMBMDATA, "too many registers: -1 EMBMDATA at once (got %d, %s)", id,
           modbus_strerror(errno));
    id = modbus_read_bits_async(ctx, 0, 4, NULL, on_done, NULL);
    EXPECT(id == -1 && errno == EINVAL, "NULL destination: -1 EINVAL (got %d)", id);
    EXPECT(modbus_pending(ctx) == 0, "nothing pending after refused requests (%d)", modbus_pending(ctx));

    /* A blocking call while requests are pending: EBUSY. */
    reset();
    id = modbus_read_registers_async(ctx, 0, 1, regs_a, on_done, NULL);
    errno = 0;
    brc = modbus_read_registers(ctx, 0, 1, regs_b);
    EXPECT(brc == -1 && errno == EBUSY, "a blocking call with a request pending: -1 EBUSY (got %d, %s)", brc,
           modbus_strerror(errno));
    a = one(ctx, id);
    EXPECT(a.done == 1 && a.rc == 1, "the pending request completes (rc %d)", a.rc);

    /* Cancel: the callback runs inside modbus_cancel, with ECANCELED. */
    reset();
    id = modbus_read_registers_async(ctx, 0, 1, regs_a, on_done, NULL);
    int rc = modbus_cancel(ctx, id);
    EXPECT(rc == 0 && results[id].done == 1 && results[id].rc == -1 && results[id].error == ECANCELED,
           "modbus_cancel: 0, the callback ran with ECANCELED (rc %d, done %d, error %d)", rc, results[id].done,
           results[id].error);
    EXPECT(modbus_cancel(ctx, id) == -1 && errno == EINVAL, "cancel of a completed request: -1 EINVAL");
    EXPECT(modbus_pending(ctx) == 0, "nothing pending after the cancel");
    if (serial) {
        /* The cancelled request may have gone out: its answer is still on the line. */
        usleep(100000);
        modbus_flush(ctx);
    }

    /* Many requests queued at once: each gets its own answer, in order of their ids. */
    reset();
    /* EVENT_DEPTH: the pipelining depth (pymodbus 3.16.1 answers only the first of
     * the requests one read brings it: 1 there). */
    int depth = getenv("EVENT_DEPTH") != NULL ? atoi(getenv("EVENT_DEPTH")) : 16;
    if (!serial) {
        EXPECT(modbus_set_max_in_flight(ctx, depth) == 0, "modbus_set_max_in_flight(%d)", depth);
    }
    EXPECT(modbus_set_max_in_flight(ctx, 0) == -1 && errno == EINVAL, "modbus_set_max_in_flight(0): EINVAL");
    EXPECT(modbus_set_max_in_flight(ctx, 257) == -1 && errno == EINVAL, "modbus_set_max_in_flight(257): EINVAL");
    static uint16_t many[200][1];
    int n = serial ? 20 : 200, ok = 0, first = -1;
    for (int i = 0; i < n; i++) {
        int k = modbus_read_registers_async(ctx, i % 22, 1, many[i], on_done, NULL);
        if (first < 0) {
            first = k;
        }
    }
    EXPECT(modbus_pending(ctx) == n, "%d requests pending (%d)", n, modbus_pending(ctx));
    double took = drive(ctx, 30);
    for (int i = 0; i < n; i++) {
        ok += results[first + i].done == 1 && results[first + i].rc == 1;
    }
    int right = 0;
    uint16_t ref[22];
    modbus_read_registers(ctx, 0, 22, ref);
    for (int i = 0; i < n; i++) {
        right += many[i][0] == ref[i % 22];
    }
    EXPECT(ok == n && right == n && completed == n, "%d requests, %d deep: %d completed once with rc 1, %d right values (%.3f s)",
           n, serial ? 1 : depth, ok, right, took);
    modbus_set_max_in_flight(ctx, 1);

    /* A callback that submits the next request. */
    reset();
    static int chain_left;
    chain_left = 5;
    modbus_read_registers_async(ctx, 0, 1, regs_a, chain_cb, &chain_left);
    drive(ctx, 10);
    EXPECT(chain_left == 0 && modbus_pending(ctx) == 0, "five requests, each submitted by the last one's callback");

    /* Close with requests pending: no callback runs inside modbus_close; the next
     * modbus_process completes each with ESHUTDOWN. */
    reset();
    int ids[3];
    for (int i = 0; i < 3; i++) {
        ids[i] = modbus_read_registers_async(ctx, 0, 1, regs_a, on_done, NULL);
    }
    modbus_process(ctx, 0); /* the first goes out */
    modbus_close(ctx);
    int inside = completed;
    rc = modbus_process(ctx, 0);
    int shut = 0;
    for (int i = 0; i < 3; i++) {
        shut += results[ids[i]].done == 1 && results[ids[i]].error == ESHUTDOWN;
    }
    EXPECT(inside == 0 && rc == 3 && shut == 3 && modbus_pending(ctx) == 0,
           "modbus_close: no callback inside it (%d), the next modbus_process completed %d, %d with ESHUTDOWN", inside,
           rc, shut);
}

static uint16_t chain_regs[1];
static void chain_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    int *left = user;
    (void) id;
    (void) error;
    if (rc == 1 && --*left > 0) {
        modbus_read_registers_async(ctx, 0, 1, chain_regs, chain_cb, left);
    }
}

/* ---------------------------------------------------------------- servers of our own */
static int listen_any(int *port)
{
    int s = socket(AF_INET, SOCK_STREAM, 0), one_ = 1;
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof(a);
    setsockopt(s, SOL_SOCKET, SO_REUSEADDR, &one_, sizeof(one_));
    if (bind(s, (struct sockaddr *) &a, sizeof(a)) != 0 || listen(s, 512) != 0 ||
        getsockname(s, (struct sockaddr *) &a, &len) != 0) {
        return -1;
    }
    *port = ntohs(a.sin_port);
    return s;
}

/* A server that answers each read of holding registers with its transaction id as
 * the value, `delay_ms[i]` after the i-th request (then as fast as it can). */
struct late_server {
    int listen_fd;
    int delay_ms[4];
};

static int read_full(int fd, uint8_t *b, size_t n)
{
    size_t got = 0;
    while (got < n) {
        ssize_t k = recv(fd, b + got, n - got, 0);
        if (k <= 0) {
            return -1;
        }
        got += (size_t) k;
    }
    return 0;
}

static void *late_server_main(void *arg)
{
    struct late_server *s = arg;
    int c = accept(s->listen_fd, NULL, NULL);
    uint8_t req[12], rsp[11];
    for (int i = 0; c >= 0; i++) {
        if (read_full(c, req, 12) != 0) {
            break;
        }
        if (i < 4 && s->delay_ms[i] > 0) {
            usleep((unsigned) s->delay_ms[i] * 1000);
        }
        memcpy(rsp, req, 4);
        rsp[4] = 0;
        rsp[5] = 5;
        rsp[6] = req[6];
        rsp[7] = 3;
        rsp[8] = 2;
        rsp[9] = req[0];
        rsp[10] = req[1];
        if (send(c, rsp, sizeof(rsp), MSG_NOSIGNAL) != (ssize_t) sizeof(rsp)) {
            break;
        }
    }
    if (c >= 0) {
        close(c);
    }
    return NULL;
}

/* A server for many clients at once: each read of holding registers is answered at
 * once with its transaction id as every value. Ends when `stop` is set. */
struct many_server {
    int listen_fd;
    volatile int stop;
    int served;
};

static void *many_server_main(void *arg)
{
    struct many_server *s = arg;
    struct pollfd pfd[256];
    int n = 1;
    pfd[0].fd = s->listen_fd;
    pfd[0].events = POLLIN;
    while (!__atomic_load_n(&s->stop, __ATOMIC_SEQ_CST)) {
        if (poll(pfd, (nfds_t) n, 50) <= 0) {
            continue;
        }
        while ((pfd[0].revents & POLLIN) && n < 256) {
            int c = accept4(s->listen_fd, NULL, NULL, SOCK_NONBLOCK);
            if (c < 0) {
                break;
            }
            int off = 0;
            ioctl(c, FIONBIO, &off);
            pfd[n].fd = c;
            pfd[n].events = POLLIN;
            pfd[n].revents = 0;
            n++;
        }
        for (int i = 1; i < n; i++) {
            if (!(pfd[i].revents & (POLLIN | POLLHUP | POLLERR))) {
                continue;
            }
            uint8_t req[12], rsp[9 + 2 * 125];
            if (read_full(pfd[i].fd, req, 12) != 0) {
                close(pfd[i].fd);
                pfd[i--] = pfd[--n];
                continue;
            }
            int nb = (req[10] << 8) | req[11];
            if (nb < 1 || nb > 125) {
                nb = 1;
            }
            memcpy(rsp, req, 4);
            rsp[4] = 0;
            rsp[5] = (uint8_t) (3 + 2 * nb);
            rsp[6] = req[6];
            rsp[7] = 3;
            rsp[8] = (uint8_t) (2 * nb);
            for (int k = 0; k < nb; k++) {
                rsp[9 + 2 * k] = req[0];
                rsp[10 + 2 * k] = req[1];
            }
            if (send(pfd[i].fd, rsp, (size_t) (9 + 2 * nb), MSG_NOSIGNAL) > 0) {
                s->served++;
            }
        }
    }
    for (int i = 1; i < n; i++) {
        close(pfd[i].fd);
    }
    return NULL;
}

/* A scripted server for the faults of a pipeline: it reads `batch` requests (reads
 * of holding registers), then, by `mode`:
 *   REVERSE  answers them in reverse order (value: the transaction id)
 *   RESET    closes the connection with a reset, unanswered
 *   GARBAGE  sends 7 bytes that are no answer, then closes
 * and answers every request in order from then on, and on the next connections. */
enum script_mode { REVERSE, RESET, GARBAGE };
struct script_server {
    int listen_fd;
    enum script_mode mode;
    int batch;
    int connections; /* to serve */
};

static void answer_tid(int c, const uint8_t *req)
{
    uint8_t rsp[11];
    memcpy(rsp, req, 4);
    rsp[4] = 0;
    rsp[5] = 5;
    rsp[6] = req[6];
    rsp[7] = 3;
    rsp[8] = 2;
    rsp[9] = req[0];
    rsp[10] = req[1];
    (void) !send(c, rsp, sizeof(rsp), MSG_NOSIGNAL);
}

static void *script_server_main(void *arg)
{
    struct script_server *s = arg;
    for (int k = 0; k < s->connections; k++) {
        int c = accept(s->listen_fd, NULL, NULL);
        if (c < 0) {
            return NULL;
        }
        uint8_t req[64][12];
        int got = 0;
        while (k == 0 && got < s->batch && read_full(c, req[got], 12) == 0) {
            got++;
        }
        if (s->mode == REVERSE || k > 0) {
            for (int i = got - 1; i >= 0; i--) {
                answer_tid(c, req[i]);
            }
            uint8_t r[12];
            while (read_full(c, r, 12) == 0) {
                answer_tid(c, r);
            }
        } else if (s->mode == RESET) {
            struct linger lg = {1, 0};
            setsockopt(c, SOL_SOCKET, SO_LINGER, &lg, sizeof(lg));
        } else {
            (void) !send(c, "\x00\x01garbage", 9, MSG_NOSIGNAL);
        }
        close(c);
    }
    return NULL;
}

static void pipeline_faults(void)
{
    int port;
    uint16_t v[8][1];
    pthread_t th;

    /* Answers in reverse order: each request still gets its own answer. */
    struct script_server s = {.mode = REVERSE, .batch = 8, .connections = 1};
    s.listen_fd = listen_any(&port);
    pthread_create(&th, NULL, script_server_main, &s);
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_max_in_flight(ctx, 8);
    reset();
    int first = -1;
    for (int i = 0; i < 8; i++) {
        int id = modbus_read_registers_async(ctx, 0, 1, v[i], on_done, NULL);
        first = first < 0 ? id : first;
    }
    drive(ctx, 5);
    int right = 0;
    for (int i = 0; i < 8; i++) {
        right += results[first + i].rc == 1 && v[i][0] == i + 1;
    }
    EXPECT(right == 8, "8 answers in reverse order: each request its own (%d of 8)", right);
    modbus_close(ctx);
    modbus_free(ctx);
    pthread_join(th, NULL);
    close(s.listen_fd);

    /* A reset with 4 requests in flight and 2 queued: all 6 fail with the reset; the
     * next request connects again. */
    struct script_server r = {.mode = RESET, .batch = 4, .connections = 2};
    r.listen_fd = listen_any(&port);
    pthread_create(&th, NULL, script_server_main, &r);
    ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_max_in_flight(ctx, 4);
    reset();
    first = -1;
    for (int i = 0; i < 6; i++) {
        int id = modbus_read_registers_async(ctx, 0, 1, v[i], on_done, NULL);
        first = first < 0 ? id : first;
    }
    drive(ctx, 5);
    int reset_seen = 0;
    for (int i = 0; i < 6; i++) {
        reset_seen += results[first + i].done == 1 && results[first + i].rc == -1 &&
                      (results[first + i].error == ECONNRESET || results[first + i].error == EPIPE);
    }
    EXPECT(reset_seen == 6, "a reset with 4 requests in flight and 2 queued: all 6 fail with ECONNRESET (%d, first: %s)",
           reset_seen, modbus_strerror(results[first].error));
    int again = modbus_read_registers_async(ctx, 0, 1, v[0], on_done, NULL);
    drive(ctx, 5);
    EXPECT(results[again].done == 1 && results[again].rc == 1 && v[0][0] == 7,
           "the next request connects again and gets its own answer (rc %d, tid %u of 7)", results[again].rc, v[0][0]);
    modbus_close(ctx);
    modbus_free(ctx);
    pthread_join(th, NULL);
    close(r.listen_fd);

    /* Garbage instead of an answer: the request fails, nothing is taken for another. */
    struct script_server gsrv = {.mode = GARBAGE, .batch = 1, .connections = 1};
    gsrv.listen_fd = listen_any(&port);
    pthread_create(&th, NULL, script_server_main, &gsrv);
    ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, 0, 300000);
    reset();
    int g = modbus_read_registers_async(ctx, 0, 1, v[0], on_done, NULL);
    drive(ctx, 5);
    EXPECT(results[g].done == 1 && results[g].rc == -1, "garbage then a close: the request fails (%s)",
           modbus_strerror(results[g].error));
    modbus_close(ctx);
    modbus_free(ctx);
    pthread_join(th, NULL);
    close(gsrv.listen_fd);
}

/* The multi handle: many contexts, one descriptor. */
#define MULTI_N 100
static int multi_left;
static void multi_done(modbus_t *ctx, int id, int rc, int error, void *user)
{
    struct result *r = user;
    (void) ctx;
    (void) id;
    r->done++;
    r->rc = rc;
    r->error = error;
    multi_left--;
}

static void multi_free_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    multi_done(ctx, id, rc, error, user);
    modbus_free(ctx);
}

static void multi_case(void)
{
    static struct result res[MULTI_N][3];
    static uint16_t vals[MULTI_N][3][4];
    struct many_server s = {0};
    int port, dead_port, on = 1;
    s.listen_fd = listen_any(&port);
    ioctl(s.listen_fd, FIONBIO, &on);
    int dead = listen_any(&dead_port);
    close(dead);
    pthread_t th;
    pthread_create(&th, NULL, many_server_main, &s);

    modbus_multi_t *m = modbus_multi_new();
    EXPECT(m != NULL, "modbus_multi_new");
    modbus_t *ctx[MULTI_N];
    memset(res, 0, sizeof(res));
    multi_left = 0;
    for (int i = 0; i < MULTI_N; i++) {
        /* Device 7 has nothing listening; device 9's first callback frees it. */
        ctx[i] = modbus_new_tcp("127.0.0.1", i == 7 ? dead_port : port);
        modbus_set_response_timeout(ctx[i], 2, 0);
        if (modbus_multi_add(m, ctx[i]) != 0) {
            EXPECT(0, "modbus_multi_add %d: %s", i, modbus_strerror(errno));
        }
        for (int k = 0; k < 3; k++) {
            modbus_callback_t cb = (i == 9 && k == 0) ? multi_free_cb : multi_done;
            if (modbus_read_registers_async(ctx[i], 0, 4, vals[i][k], cb, &res[i][k]) >= 0) {
                multi_left++;
            }
        }
    }
    EXPECT(modbus_multi_add(m, ctx[0]) == -1 && errno == EBUSY, "a context is in one multi handle at most (EBUSY)");
    EXPECT(modbus_multi_get_fd(m) >= 0, "modbus_multi_get_fd: a descriptor");
    double t0 = now_s();
    int completed = 0, rounds = 0;
    while (multi_left > 0 && now_s() - t0 < 20) {
        int c = modbus_multi_perform(m, 1000);
        if (c < 0) {
            EXPECT(0, "modbus_multi_perform: %s", modbus_strerror(errno));
            break;
        }
        completed += c;
        rounds++;
    }
    double took = now_s() - t0;
    int right = 0, refused = 0, freed_ok = 0;
    for (int i = 0; i < MULTI_N; i++) {
        for (int k = 0; k < 3; k++) {
            struct result r = res[i][k];
            if (i == 7) {
                refused += r.done == 1 && r.rc == -1 && r.error == ECONNREFUSED;
            } else if (i == 9) {
                freed_ok += r.done == 1 && (k == 0 ? r.rc == 4 : r.error == EIDRM);
            } else {
                /* Each context numbers its own transactions 1, 2, 3. */
                right += r.done == 1 && r.rc == 4 && vals[i][k][0] == k + 1 && vals[i][k][3] == k + 1;
            }
        }
    }
    EXPECT(right == 3 * (MULTI_N - 2), "multi: %d contexts x 3 requests, each its own answer: %d of %d (%.3f s, %d rounds)",
           MULTI_N - 2, right, 3 * (MULTI_N - 2), took, rounds);
    EXPECT(refused == 3, "multi: the device with nothing listening: its 3 requests fail with ECONNREFUSED (%d)", refused);
    EXPECT(freed_ok == 3, "multi: a callback freed its context: its others completed with EIDRM, none after (%d)",
           freed_ok);
    EXPECT(multi_left == 0 && completed == 3 * MULTI_N - 2,
           "multi: every callback ran once (left %d; perform counted %d: the 2 cancelled by the free run inside it)",
           multi_left, completed);
    /* Remove, then a request on a removed context is the application's to drive. */
    EXPECT(modbus_multi_remove(m, ctx[0]) == 0, "modbus_multi_remove");
    EXPECT(modbus_multi_remove(m, ctx[0]) == -1 && errno == EINVAL, "modbus_multi_remove again: EINVAL");
    uint16_t v[4];
    reset();
    int id = modbus_read_registers_async(ctx[0], 0, 4, v, on_done, NULL);
    EXPECT(modbus_multi_perform(m, 100) == 0 && results[id].done == 0, "a removed context is not processed");
    {
        /* Nothing pending: -1 waits for a request or a wake-up (see wake_cases). */
        double p0 = now_s();
        modbus_multi_wakeup(m);
        int c = modbus_multi_perform(m, -1);
        EXPECT(c == 0 && now_s() - p0 < 0.5, "modbus_multi_perform(-1) with nothing pending, after modbus_multi_wakeup: 0 at once (%d)", c);
    }
    drive(ctx[0], 5);
    EXPECT(results[id].done == 1 && results[id].rc == 4, "it completes through its own modbus_process");
    for (int i = 0; i < MULTI_N; i++) {
        if (i != 9) {
            modbus_free(ctx[i]);
        }
    }
    modbus_multi_free(m);
    __atomic_store_n(&s.stop, 1, __ATOMIC_SEQ_CST);
    pthread_join(th, NULL);
    close(s.listen_fd);
}

static void own_servers(void)
{
    int port, lf;
    uint16_t v[4] = {0};

    /* 1. A server that accepts and never answers: the response timeout, from the send. */
    lf = listen_any(&port);
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, 0, 200000);
    reset();
    double t0 = now_s();
    int id = modbus_read_registers_async(ctx, 0, 1, v, on_done, NULL);
    EXPECT(id >= 0 && modbus_pending(ctx) == 1, "queued on a context not connected yet (id %d)", id);
    drive(ctx, 5);
    double t = now_s() - t0;
    EXPECT(results[id].done == 1 && results[id].rc == -1 && results[id].error == ETIMEDOUT && t >= 0.19 && t < 1.5,
           "a server that never answers: ETIMEDOUT after %.3f s (response timeout 0.2 s)", t);

    /* 1b. Nothing listens: the connect, started by modbus_process without waiting,
     *     fails, and the request with it (ECONNREFUSED). */
    {
        int dead_port, dead = listen_any(&dead_port);
        close(dead);
        modbus_t *c2 = modbus_new_tcp("127.0.0.1", dead_port);
        reset();
        int id2 = modbus_read_registers_async(c2, 0, 1, v, on_done, NULL);
        struct pollfd pfd;
        int timeout = -2;
        modbus_get_pollfd(c2, &pfd, &timeout);
        EXPECT(pfd.fd >= 0 && pfd.events == POLLIN && timeout == 0,
               "not connected: the context's wake descriptor (POLLIN), process at once (fd %d, timeout %d)", pfd.fd,
               timeout);
        drive(c2, 5);
        EXPECT(results[id2].done == 1 && results[id2].rc == -1 && results[id2].error == ECONNREFUSED,
               "nothing listens: the request fails with ECONNREFUSED (%s)", modbus_strerror(results[id2].error));
        modbus_free(c2);
    }

    /* 2. A callback that frees its context: the request behind it completes inside
     *    modbus_free (EIDRM), and no callback runs after. */
    reset();
    freed_flag = 0;
    modbus_read_registers_async(ctx, 0, 1, v, free_cb, NULL);
    int behind = modbus_read_registers_async(ctx, 0, 1, v, on_done, NULL);
    for (int loops = 0; !freed_flag && loops < 100; loops++) {
        struct pollfd pfd;
        int timeout;
        modbus_get_pollfd(ctx, &pfd, &timeout);
        poll(&pfd, pfd.fd >= 0 ? 1 : 0, timeout < 0 ? 100 : timeout);
        modbus_process(ctx, pfd.revents);
    }
    EXPECT(freed_flag && results[behind].done == 1 && results[behind].error == EIDRM && completed == 1,
           "a callback freed its context: the request behind it completed inside modbus_free (EIDRM), once");
    close(lf);

    /* 2b. (issue 39, item 8) A request keeps the response timeout of its submit;
     *     modbus_set_request_timeout gives one its own, counted from its send. */
    {
        int p2, l2 = listen_any(&p2);
        modbus_t *c = modbus_new_tcp("127.0.0.1", p2);
        modbus_set_max_in_flight(c, 4);
        modbus_set_response_timeout(c, 1, 0);
        reset();
        double s0 = now_s();
        int a = modbus_read_registers_async(c, 0, 1, v, on_done, NULL);
        int b = modbus_read_registers_async(c, 0, 1, v, on_done, NULL);
        int rb = modbus_set_request_timeout(c, b, 0, 200000);
        EXPECT(rb == 0, "modbus_set_request_timeout(b, 0.2 s): %d (%s)", rb, rb == -1 ? modbus_strerror(errno) : "ok");
        /* Changed after the submit: not a's timeout. */
        modbus_set_response_timeout(c, 0, 100000);
        errno = 0;
        EXPECT(modbus_set_request_timeout(c, a, 0, 1000000) == -1 && errno == EINVAL,
               "modbus_set_request_timeout with usec 1000000: -1 EINVAL");
        errno = 0;
        EXPECT(modbus_set_request_timeout(c, 9999, 1, 0) == -1 && errno == EINVAL,
               "modbus_set_request_timeout of an unknown id: -1 EINVAL");
        while (results[b].done == 0 && results[a].done == 0 && now_s() - s0 < 5) {
            struct pollfd pfd;
            int timeout;
            modbus_get_pollfd(c, &pfd, &timeout);
            int n = poll(&pfd, pfd.fd >= 0 && pfd.events ? 1 : 0, timeout < 0 || timeout > 1000 ? 1000 : timeout);
            modbus_process(c, n > 0 ? pfd.revents : 0);
        }
        double tb = now_s() - s0;
        EXPECT(results[b].done == 1 && results[b].error == ETIMEDOUT && results[a].done == 0 && tb >= 0.19 && tb < 0.6,
               "a request with its own timeout (0.2 s) timed out after %.3f s, the one with the context's (1 s, "
               "changed to 0.1 s after its submit) has not (done %d)",
               tb, results[a].done);
        errno = 0;
        EXPECT(modbus_set_request_timeout(c, b, 1, 0) == -1 && errno == EINVAL,
               "modbus_set_request_timeout of a finished request: -1 EINVAL");
        drive(c, 5);
        double ta = now_s() - s0;
        EXPECT(results[a].done == 1 && results[a].error == ETIMEDOUT && ta >= 0.99 && ta < 1.6,
               "the other times out at the timeout of its submit: %.3f s (1 s)", ta);
        modbus_close(c);
        modbus_free(c);
        close(l2);
    }

    /* 3. Late answers: request 1 times out, its answer comes while request 2 waits;
     *    request 2 gets its own answer (the value is the transaction id). */
    struct late_server s = {.delay_ms = {700, 0, 0, 0}};
    s.listen_fd = listen_any(&port);
    pthread_t th;
    pthread_create(&th, NULL, late_server_main, &s);
    ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, 0, 500000);
    reset();
    uint16_t v1[1] = {0}, v2[1] = {0}, v3[1] = {0};
    int r1 = modbus_read_registers_async(ctx, 0, 1, v1, on_done, NULL);
    drive(ctx, 5);
    EXPECT(results[r1].error == ETIMEDOUT, "late server: the first request times out (%s)",
           modbus_strerror(results[r1].error));
    int r2 = modbus_read_registers_async(ctx, 0, 1, v2, on_done, NULL);
    int r3 = modbus_read_registers_async(ctx, 0, 1, v3, on_done, NULL);
    drive(ctx, 5);
    EXPECT(results[r2].rc == 1 && results[r3].rc == 1 && v2[0] == 2 && v3[0] == 3,
           "late server: the next requests get their own answers (tids %u, %u; the late answer to tid 1 dropped)",
           v2[0], v3[0]);
    modbus_close(ctx);
    modbus_free(ctx);
    pthread_join(th, NULL);
    close(s.listen_fd);

    /* 4. The same with the blocking calls: libmodbus 3.1.6 and 3.1.12 take the late
     *    answer as the next request's and fail it (EMBBADDATA); rsmodbus drops it. */
    struct late_server s2 = {.delay_ms = {700, 0, 0, 0}};
    s2.listen_fd = listen_any(&port);
    pthread_create(&th, NULL, late_server_main, &s2);
    ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, 0, 500000);
    modbus_connect(ctx);
    int rc1 = modbus_read_registers(ctx, 0, 1, v1);
    int e1 = errno;
    int rc2 = modbus_read_registers(ctx, 0, 1, v2);
    int e2 = errno;
    EXPECT(rc1 == -1 && e1 == ETIMEDOUT, "blocking, late server: the first call times out (%s)", modbus_strerror(e1));
    EXPECT(rc2 == 1 && v2[0] == 2,
           "blocking, late server: the next call gets its own answer, tid %u (libmodbus: -1 EMBBADDATA; got %d %s)",
           v2[0], rc2, rc2 == -1 ? modbus_strerror(e2) : "");
    modbus_close(ctx);
    modbus_free(ctx);
    pthread_join(th, NULL);
    close(s2.listen_fd);
}

static void free_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    (void) id;
    (void) rc;
    (void) error;
    (void) user;
    modbus_free(ctx);
    freed_flag = 1;
}

/* A TLS peer that accepts and never speaks: the handshake, under way without
 * waiting, times out after the response timeout; no modbus_process call waits. */
static void stalled_handshake(void)
{
    int port, lf = listen_any(&port);
    modbus_t *ctx = mbt_new_tls("event-test", port);
    uint16_t v[1];
    modbus_set_response_timeout(ctx, 0, 300000);
    reset();
    int id = modbus_read_registers_async(ctx, 0, 1, v, on_done, NULL);
    double t0 = now_s(), longest = 0;
    while (modbus_pending(ctx) > 0 && now_s() - t0 < 5) {
        struct pollfd pfd;
        int timeout;
        modbus_get_pollfd(ctx, &pfd, &timeout);
        int n = poll(&pfd, pfd.fd >= 0 ? 1 : 0, timeout < 0 ? 100 : timeout);
        double c0 = now_s();
        modbus_process(ctx, n > 0 ? pfd.revents : 0);
        if (now_s() - c0 > longest) {
            longest = now_s() - c0;
        }
    }
    double t = now_s() - t0;
    EXPECT(results[id].done == 1 && results[id].error == ETIMEDOUT && t >= 0.29 && t < 2.0 && longest < 0.25,
           "a TLS peer that stalls its handshake: ETIMEDOUT after %.3f s (timeout 0.3 s), the longest "
           "modbus_process %.1f ms",
           t, longest * 1e3);
    modbus_free(ctx);
    close(lf);
}

/* `event-test rtu-late DEVICE_END CLIENT_END`: a device (a server context of this
 * library, in a thread) that answers its first request 700 ms late; the client's
 * response timeout is 500 ms. With LINK recovery (libmodbus sleeps a response
 * timeout and flushes after a timeout) the next request waits a response timeout,
 * the line is flushed, and it gets its own answer; without it, the
 * late answer (same function, same length) is taken for the next request's. */
struct late_device {
    const char *device;
    volatile int stop;
};

static void *late_device_main(void *arg)
{
    struct late_device *d = arg;
    modbus_t *srv = modbus_new_rtu(d->device, 115200, 'N', 8, 1);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 4, 0);
    uint8_t req[MODBUS_RTU_MAX_ADU_LENGTH];
    modbus_set_slave(srv, 1);
    modbus_set_indication_timeout(srv, 0, 100000);
    map->tab_registers[0] = 111;
    map->tab_registers[1] = 222;
    map->tab_registers[2] = 333;
    modbus_connect(srv);
    for (int n = 0; !d->stop;) {
        int rc = modbus_receive(srv, req);
        if (rc <= 0) {
            continue;
        }
        if (n++ == 0) {
            usleep(700000);
        }
        modbus_reply(srv, req, rc, map);
    }
    modbus_close(srv);
    modbus_free(srv);
    modbus_mapping_free(map);
    return NULL;
}

static int rtu_late(const char *device_end, const char *client_end)
{
    chk_set_prefix("rtu late: ");
    for (int recovery = 1; recovery >= 0; recovery--) {
        struct late_device d = {.device = device_end};
        pthread_t th;
        pthread_create(&th, NULL, late_device_main, &d);
        usleep(100000);
        modbus_t *ctx = modbus_new_rtu(client_end, 115200, 'N', 8, 1);
        modbus_set_slave(ctx, 1);
        modbus_set_response_timeout(ctx, 0, 500000);
        modbus_set_error_recovery(ctx, recovery ? MODBUS_ERROR_RECOVERY_LINK : MODBUS_ERROR_RECOVERY_NONE);
        modbus_connect(ctx);
        uint16_t v1[1] = {0}, v2[1] = {0};
        reset();
        int r1 = modbus_read_registers_async(ctx, 0, 1, v1, on_done, NULL);
        int r2 = modbus_read_registers_async(ctx, 1, 1, v2, on_done, NULL);
        double t0 = now_s();
        drive(ctx, 10);
        double t = now_s() - t0;
        EXPECT(results[r1].error == ETIMEDOUT, "%s: the first request times out (%s)",
               recovery ? "LINK recovery" : "no recovery", modbus_strerror(results[r1].error));
        if (recovery) {
            EXPECT(results[r2].rc == 1 && v2[0] == 222 && t >= 0.99,
                   "LINK recovery (libmodbus: sleep and flush after a timeout): the line stays quiet a response timeout and is flushed; the next request "
                   "gets its own answer (%u, want 222) after %.3f s",
                   v2[0], t);
        } else {
            EXPECT(results[r2].rc == 1 && v2[0] == 111,
                   "no recovery: the late answer is taken for the next request (%u: the first one's 111), as "
                   "with libmodbus' blocking calls (RTU has no transaction id)",
                   v2[0]);
        }
        d.stop = 1;
        pthread_join(th, NULL);
        modbus_close(ctx);
        modbus_free(ctx);
        usleep(100000);
    }
    chk_set_prefix("");
    return chk_summary();
}

/* `event-test many PORT N`: N devices of sim-devices (every 10th dead: it never
 * answers), one multi handle, one thread, two cycles of one read each. The live
 * devices' cycle does not wait for the dead ones' timeouts. */
static int many_left, many_live_left;
static double many_t0, many_live_done;
struct many_dev {
    modbus_t *ctx;
    uint16_t regs[10];
    int number, dead, rc, error;
};

static void many_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    struct many_dev *d = user;
    (void) ctx;
    (void) id;
    d->rc = rc;
    d->error = error;
    many_left--;
    if (!d->dead && --many_live_left == 0) {
        many_live_done = now_s() - many_t0;
    }
}

static int many_devices(int port, int n)
{
    struct many_dev *dev = calloc((size_t) n, sizeof(*dev));
    modbus_multi_t *m = modbus_multi_new();
    if (dev == NULL || m == NULL) {
        return 1;
    }
    chk_set_prefix("many: ");
    /* Connect one at a time so that device i is sim-devices' connection i. */
    for (int i = 0; i < n; i++) {
        dev[i].ctx = modbus_new_tcp("127.0.0.1", port);
        dev[i].dead = i % 10 == 9;
        modbus_set_response_timeout(dev[i].ctx, 1, 0);
        if (modbus_connect(dev[i].ctx) != 0 || modbus_multi_add(m, dev[i].ctx) != 0) {
            EXPECT(0, "device %d: %s", i, modbus_strerror(errno));
            return chk_summary();
        }
        usleep(200);
    }
    int dead = n / 10;
    for (int cycle = 1; cycle <= 2; cycle++) {
        many_left = n;
        many_live_left = n - dead;
        many_t0 = now_s();
        for (int i = 0; i < n; i++) {
            dev[i].rc = -2;
            if (modbus_read_registers_async(dev[i].ctx, 0, 10, dev[i].regs, many_cb, &dev[i]) < 0) {
                many_left--;
            }
        }
        while (many_left > 0 && now_s() - many_t0 < 30) {
            modbus_multi_perform(m, -1);
        }
        double all = now_s() - many_t0;
        int live_ok = 0, dead_to = 0;
        for (int i = 0; i < n; i++) {
            if (dev[i].dead) {
                dead_to += dev[i].rc == -1 && dev[i].error == ETIMEDOUT;
            } else {
                live_ok += dev[i].rc == 10 && dev[i].regs[0] == i && dev[i].regs[9] == i;
            }
        }
        EXPECT(live_ok == n - dead && dead_to == dead,
               "cycle %d: %d live devices answered with their own values (%d), %d dead timed out (%d)", cycle,
               n - dead, live_ok, dead, dead_to);
        EXPECT(many_live_done < 0.5 && all >= 0.99,
               "cycle %d: the live devices done in %.1f ms (each answers after 5 ms), the dead ones' timeouts "
               "after %.0f ms",
               cycle, many_live_done * 1e3, all * 1e3);
    }
    for (int i = 0; i < n; i++) {
        modbus_close(dev[i].ctx);
        modbus_free(dev[i].ctx);
    }
    modbus_multi_free(m);
    free(dev);
    chk_set_prefix("");
    return chk_summary();
}

/* ---------------------------------------------------------------- two threads
 * One thread gives requests (modbus_read_registers_async) while another processes
 * (modbus_process, modbus_multi_perform): each call locks the context, so the two
 * may run at once. The processing thread waits at most 10 ms at a time: a request
 * given by another thread does not wake a wait already under way. */
struct tt {
    modbus_t **ctx;
    int nctx, n, done, bad;
    int stop; /* the processing thread gave up: the giver stops retrying (atomic) */
    uint16_t want[4];
    uint16_t (*regs)[4];
    pthread_mutex_t lock;
};

static void tt_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    struct tt *t = user;
    (void) ctx;
    (void) error;
    (void) id;
    pthread_mutex_lock(&t->lock);
    t->done++;
    if (rc != 4) {
        t->bad++;
    }
    pthread_mutex_unlock(&t->lock);
}

static void *tt_giver(void *arg)
{
    struct tt *t = arg;
    for (int i = 0; i < t->n; i++) {
        modbus_t *ctx = t->ctx[i % t->nctx];
        while (modbus_read_registers_async(ctx, 0, 4, t->regs[i], tt_cb, t) < 0) {
            if (errno != EAGAIN) {
                pthread_mutex_lock(&t->lock);
                t->bad++;
                t->done++;
                pthread_mutex_unlock(&t->lock);
                break;
            }
            if (__atomic_load_n(&t->stop, __ATOMIC_SEQ_CST)) {
                return NULL;
            }
            usleep(100);
        }
    }
    return NULL;
}

static int tt_finished(struct tt *t)
{
    pthread_mutex_lock(&t->lock);
    int f = t->done == t->n;
    pthread_mutex_unlock(&t->lock);
    return f;
}

static void two_threads(int port, int n)
{
    for (int multi = 0; multi <= 1; multi++) {
        /* (One context in the multi handle too: mb-server serves one client at a time.) */
        struct tt t = {.nctx = 1, .n = n};
        modbus_multi_t *m = multi ? modbus_multi_new() : NULL;
        pthread_t giver;
        int ok = 1;
        pthread_mutex_init(&t.lock, NULL);
        t.ctx = calloc((size_t) t.nctx, sizeof(*t.ctx));
        t.regs = calloc((size_t) n, sizeof(*t.regs));
        for (int c = 0; c < t.nctx; c++) {
            t.ctx[c] = modbus_new_tcp("127.0.0.1", port);
            modbus_set_response_timeout(t.ctx[c], 5, 0);
            modbus_set_max_in_flight(t.ctx[c], 4);
            if (modbus_connect(t.ctx[c]) != 0 || (m != NULL && modbus_multi_add(m, t.ctx[c]) != 0)) {
                ok = 0;
            }
        }
        ok = ok && modbus_read_registers(t.ctx[0], 0, 4, t.want) == 4;
        double t0 = now_s();
        pthread_create(&giver, NULL, tt_giver, &t);
        while (ok && !tt_finished(&t) && now_s() - t0 < 60) {
            if (m != NULL) {
                modbus_multi_perform(m, 10);
                continue;
            }
            struct pollfd pfd;
            int timeout;
            modbus_get_pollfd(t.ctx[0], &pfd, &timeout);
            int k = poll(&pfd, pfd.fd >= 0 ? 1 : 0, timeout < 0 || timeout > 10 ? 10 : timeout);
            modbus_process(t.ctx[0], k > 0 ? pfd.revents : 0);
        }
        __atomic_store_n(&t.stop, 1, __ATOMIC_SEQ_CST);
        pthread_join(giver, NULL);
        int same = 0;
        for (int i = 0; i < n; i++) {
            same += memcmp(t.regs[i], t.want, sizeof(t.want)) == 0;
        }
        EXPECT(ok && t.done == n && t.bad == 0 && same == n,
               "two threads on %s: %d requests given by one, processed by the other: %d completed, %d failed, "
               "%d with the blocking call's values (%.2f s)",
               multi ? "a context of a multi handle (depth 4)" : "one context (depth 4)", n, t.done, t.bad, same,
               now_s() - t0);
        for (int c = 0; c < t.nctx; c++) {
            modbus_close(t.ctx[c]); /* (modbus_free leaves the socket open, as libmodbus') */
            modbus_free(t.ctx[c]);
        }
        modbus_multi_free(m);
        free(t.ctx);
        free(t.regs);
        pthread_mutex_destroy(&t.lock);
    }
}

/* ---------------------------------------------------------------- close and free with requests pending
 * (issue 39, item 2) A close, from a signal handler too, runs no callback: the
 * requests it leaves complete with ESHUTDOWN on the loop's thread (the next
 * modbus_process or modbus_multi_perform, or modbus_free); a submission while that
 * close is being completed fails with ESHUTDOWN, one from a callback run by
 * modbus_free with EIDRM. Cancel, close and free are told apart by the error:
 * ECANCELED, ESHUTDOWN, EIDRM. Each callback records whether a handler was active
 * (a flag the handler sets on entry and clears on exit); every id completes once. */
#define SIG_N 100
static modbus_t *volatile sig_ctx;
static volatile sig_atomic_t in_handler, handler_ran;
static int sig_in_handler, sig_calls, sig_resubmit, sig_resubmits, sig_resubmit_ok, sig_resubmit_errno;
static uint16_t sig_vals[SIG_N];

static void on_term(int sig)
{
    int saved = errno;
    (void) sig;
    in_handler = 1;
    modbus_close(sig_ctx);
    handler_ran = 1;
    in_handler = 0;
    errno = saved;
}

static void sig_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    struct result *r = user;
    (void) id;
    sig_calls++;
    if (in_handler) {
        sig_in_handler++;
    }
    r->done++;
    r->rc = rc;
    r->error = error;
    if (sig_resubmit) {
        static uint16_t v;
        int k = modbus_read_registers_async(ctx, 0, 1, &v, on_done, NULL);
        sig_resubmits++;
        if (k >= 0) {
            sig_resubmit_ok++;
        } else {
            sig_resubmit_errno = errno;
        }
    }
}

/* A context to a peer that accepts (the kernel's backlog) and never answers, with n
 * requests of sig_cb pending, some of them on the wire. */
static modbus_t *sig_setup(int port, struct result *res, int n)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, 10, 0);
    modbus_set_max_in_flight(ctx, 16);
    memset(res, 0, sizeof(*res) * (size_t) n);
    sig_in_handler = sig_calls = sig_resubmit = sig_resubmits = sig_resubmit_ok = sig_resubmit_errno = 0;
    int queued = 0;
    for (int i = 0; i < n; i++) {
        queued += modbus_read_registers_async(ctx, 0, 1, &sig_vals[i], sig_cb, &res[i]) >= 0;
    }
    if (queued != n) {
        EXPECT(0, "%d requests queued (%d)", n, queued);
    }
    /* Connect, and the first 16 go out. */
    for (int i = 0; i < 20; i++) {
        struct pollfd pfd;
        int timeout;
        modbus_get_pollfd(ctx, &pfd, &timeout);
        poll(&pfd, pfd.fd >= 0 && pfd.events ? 1 : 0, timeout < 0 || timeout > 20 ? 20 : timeout);
        modbus_process(ctx, pfd.revents);
    }
    return ctx;
}

/* Each of res[0..n) completed once with `error`: how many did. */
static int sig_count(const struct result *res, int n, int error)
{
    int k = 0;
    for (int i = 0; i < n; i++) {
        k += res[i].done == 1 && res[i].rc == -1 && res[i].error == error;
    }
    return k;
}

/* modbus_free from another thread while a call holds the context (serial case). */
static modbus_t *ot_ctx;
static pthread_t ot_freer;
static uint16_t ot_vals[3];
static int ot_calls, ot_eidrm, ot_on_freer, ot_rc, ot_error;
static void ot_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    (void) ctx;
    (void) id;
    (void) user;
    ot_calls++;
    ot_rc = rc;
    ot_error = error;
    ot_eidrm += rc == -1 && error == EIDRM;
    ot_on_freer += pthread_equal(pthread_self(), ot_freer);
}

static void *ot_free_main(void *arg)
{
    (void) arg;
    ot_freer = pthread_self();
    usleep(100000);
    modbus_free(ot_ctx);
    return NULL;
}

static pthread_t sig_main;
/* A handler that frees the context, when it interrupted a call on it (a call then
 * gives -1 EDEADLK in the handler). */
static volatile sig_atomic_t free_done;
static void on_term_free(int sig)
{
    int saved = errno;
    (void) sig;
    in_handler = 1;
    if (!free_done && modbus_pending(sig_ctx) == -1 && errno == EDEADLK) {
        modbus_free(sig_ctx);
        free_done = 1;
    }
    in_handler = 0;
    errno = saved;
}

static void *sig_free_killer(void *arg)
{
    (void) arg;
    double t0 = now_s();
    while (!free_done && now_s() - t0 < 20) {
        pthread_kill(sig_main, SIGTERM);
        usleep(200);
    }
    return NULL;
}

static volatile int sig_delay_us;
static void *sig_killer(void *arg)
{
    (void) arg;
    usleep((unsigned) sig_delay_us);
    pthread_kill(sig_main, SIGTERM);
    return NULL;
}

static void close_and_free(void)
{
    static struct result res[SIG_N];
    int port, lf = listen_any(&port);
    struct sigaction sa, old;
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_term;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, &old);

    /* 1. SIGTERM in the loop's thread, between two library calls (where a loop
     *    spends its time: in poll). */
    modbus_t *ctx = sig_setup(port, res, SIG_N);
    sig_ctx = ctx;
    handler_ran = 0;
    raise(SIGTERM);
    EXPECT(handler_ran && sig_in_handler == 0 && sig_calls == 0,
           "SIGTERM handler calling modbus_close with %d requests pending: no callback ran inside the handler "
           "(%d did, %d callbacks in all)",
           SIG_N, sig_in_handler, sig_calls);
    uint16_t v;
    errno = 0;
    int k = modbus_read_registers_async(ctx, 0, 1, &v, on_done, NULL);
    EXPECT(k == -1 && errno == ESHUTDOWN, "a submission before the close is completed: -1 ESHUTDOWN (%d, %s)", k,
           modbus_strerror(errno));
    struct pollfd pfd;
    int timeout = -2;
    int pending = modbus_get_pollfd(ctx, &pfd, &timeout);
    EXPECT(pending == SIG_N && timeout == 0, "modbus_get_pollfd after the close: %d pending, process at once (%d ms)",
           pending, timeout);
    sig_resubmit = 1;
    int c = modbus_process(ctx, 0);
    sig_resubmit = 0;
    EXPECT(c == SIG_N && sig_count(res, SIG_N, ESHUTDOWN) == SIG_N && sig_calls == SIG_N,
           "the next modbus_process completes them: returns %d, %d of %d completed once with ESHUTDOWN (%d callbacks)",
           c, sig_count(res, SIG_N, ESHUTDOWN), SIG_N, sig_calls);
    EXPECT(sig_resubmits == SIG_N && sig_resubmit_ok == 0 && sig_resubmit_errno == ESHUTDOWN,
           "a submission from those callbacks: -1 ESHUTDOWN (%d of %d accepted; %s)", sig_resubmit_ok, sig_resubmits,
           modbus_strerror(sig_resubmit_errno));
    EXPECT(modbus_pending(ctx) == 0, "nothing pending after the close completed (%d)", modbus_pending(ctx));
    reset();
    k = modbus_read_registers_async(ctx, 0, 1, &v, on_done, NULL);
    EXPECT(k >= 0, "after it, a submission is accepted again (id %d)", k);
    EXPECT(k >= 0 && modbus_cancel(ctx, k) == 0 && results[k].done == 1 && results[k].error == ECANCELED,
           "and a cancel completes it with ECANCELED");

    /* 2. modbus_free with requests pending: each completes with EIDRM, its callback
     *    run by modbus_free; a submission from it: -1 EIDRM. */
    sig_resubmit = 1;
    int n = 10;
    for (int i = 0; i < n; i++) {
        memset(&res[i], 0, sizeof(res[i]));
        modbus_read_registers_async(ctx, 0, 1, &sig_vals[i], sig_cb, &res[i]);
    }
    sig_calls = sig_resubmits = sig_resubmit_ok = sig_resubmit_errno = 0;
    reset();
    modbus_free(ctx);
    sig_resubmit = 0;
    EXPECT(sig_count(res, n, EIDRM) == n && sig_calls == n,
           "modbus_free: %d of %d pending requests completed once with EIDRM (%d callbacks)", sig_count(res, n, EIDRM),
           n, sig_calls);
    EXPECT(sig_resubmits == n && sig_resubmit_ok == 0 && sig_resubmit_errno == EIDRM && completed == 0,
           "a submission from a callback run by modbus_free: -1 EIDRM (%d of %d accepted, %s; %d other callbacks)",
           sig_resubmit_ok, sig_resubmits, modbus_strerror(sig_resubmit_errno), completed);

    /* 3. A close, then modbus_free before any modbus_process: the close's ESHUTDOWN. */
    ctx = sig_setup(port, res, 10);
    modbus_close(ctx);
    EXPECT(sig_calls == 0, "modbus_close runs no callback (%d ran)", sig_calls);
    modbus_free(ctx);
    EXPECT(sig_count(res, 10, ESHUTDOWN) == 10 && sig_calls == 10,
           "a close then modbus_free: 10 completed once with ESHUTDOWN (%d, %d callbacks)", sig_count(res, 10, ESHUTDOWN),
           sig_calls);

    /* 4. SIGTERM from another thread at any time while the loop's thread spins on
     *    modbus_process and modbus_get_pollfd: the handler interrupts a call on the
     *    context or lands between two. */
    sig_main = pthread_self();
    int rounds = 20, good = 0, none_inside = 1, late = 0, interrupted = 0;
    for (int r = 0; r < rounds; r++) {
        ctx = sig_setup(port, res, SIG_N);
        sig_ctx = ctx;
        handler_ran = 0;
        sig_delay_us = 200 + r * 150;
        pthread_t th;
        pthread_create(&th, NULL, sig_killer, NULL);
        double t0 = now_s();
        int ebadf = 0;
        while (!handler_ran && now_s() - t0 < 2) {
            /* -1 EBADF: the handler closed the context under this call. */
            ebadf |= modbus_process(ctx, 0) == -1 && errno == EBADF;
            ebadf |= modbus_get_pollfd(ctx, &pfd, &timeout) == -1 && errno == EBADF;
        }
        interrupted += ebadf;
        pthread_join(th, NULL);
        t0 = now_s();
        while (modbus_pending(ctx) > 0 && now_s() - t0 < 2) {
            modbus_get_pollfd(ctx, &pfd, &timeout);
            if (timeout != 0) {
                late++;
            }
            poll(&pfd, pfd.fd >= 0 && pfd.events ? 1 : 0, timeout < 0 || timeout > 20 ? 20 : timeout);
            modbus_process(ctx, pfd.revents);
        }
        none_inside = none_inside && sig_in_handler == 0;
        good += sig_in_handler == 0 && sig_count(res, SIG_N, ESHUTDOWN) == SIG_N && sig_calls == SIG_N;
        modbus_free(ctx);
    }
    EXPECT(none_inside && good == rounds && late == 0,
           "SIGTERM from another thread at any time, %d rounds: no callback inside the handler, all %d requests "
           "completed once with ESHUTDOWN by the next modbus_process: %d rounds right (%d waits not at once; "
           "the handler interrupted a call in %d rounds)",
           rounds, SIG_N, good, late, interrupted);

    /* 5. In a multi handle: modbus_multi_perform completes them. */
    modbus_multi_t *m = modbus_multi_new();
    ctx = sig_setup(port, res, SIG_N);
    modbus_multi_add(m, ctx);
    modbus_multi_perform(m, 0);
    sig_ctx = ctx;
    raise(SIGTERM);
    double t0 = now_s();
    int c5 = 0;
    while (sig_calls < SIG_N && now_s() - t0 < 2) {
        c5 += modbus_multi_perform(m, 1000);
    }
    EXPECT(sig_in_handler == 0 && sig_count(res, SIG_N, ESHUTDOWN) == SIG_N && c5 == SIG_N && now_s() - t0 < 0.5,
           "in a multi handle: none inside the handler (%d), modbus_multi_perform completed %d (%d with ESHUTDOWN) "
           "in %.3f s",
           sig_in_handler, c5, sig_count(res, SIG_N, ESHUTDOWN), now_s() - t0);
    modbus_free(ctx);
    modbus_multi_free(m);

    /* 6. modbus_free from a SIGTERM handler that interrupted a call on the context:
     *    the interrupted call, as it ends (after the handler), completes the requests
     *    with EIDRM; a submission from those callbacks: -1 EIDRM. */
    sa.sa_handler = on_term_free;
    sigaction(SIGTERM, &sa, NULL);
    ctx = sig_setup(port, res, SIG_N);
    sig_ctx = ctx;
    sig_resubmit = 1;
    free_done = 0;
    {
        pthread_t th;
        pthread_create(&th, NULL, sig_free_killer, NULL);
        double f0 = now_s();
        while (!free_done && now_s() - f0 < 20) {
            modbus_process(ctx, 0);
            if (!free_done) {
                modbus_get_pollfd(ctx, &pfd, &timeout);
            }
            /* A call that makes a system call with the context locked (a recv that
             * finds nothing): modbus_process and modbus_get_pollfd make none on this
             * path, and under valgrind a signal waits for a system call or the end
             * of a time slice, so that the handler seldom found a call to interrupt
             * before the requests' 10 s timeout. */
            if (!free_done) {
                modbus_flush(ctx);
            }
        }
        pthread_join(th, NULL);
    }
    sig_resubmit = 0;
    EXPECT(free_done && sig_in_handler == 0 && sig_count(res, SIG_N, EIDRM) == SIG_N && sig_calls == SIG_N &&
               sig_resubmit_ok == 0 && sig_resubmit_errno == EIDRM,
           "modbus_free from a handler that interrupted a call (%s): none inside the handler (%d), %d of %d "
           "completed once with EIDRM when the call ended (%d callbacks; submissions from them %s)",
           free_done ? "it did" : "never happened", sig_in_handler, sig_count(res, SIG_N, EIDRM), SIG_N, sig_calls,
           sig_resubmit_ok == 0 ? modbus_strerror(sig_resubmit_errno) : "accepted");

    sigaction(SIGTERM, &old, NULL);
    sig_ctx = NULL;
    close(lf);
}

/* ---------------------------------------------------------------- pull-style completions
 * (issue 39, item 9) A request given with a NULL callback: its completion waits for
 * modbus_completion_read (or modbus_multi_completion_read for a context of a multi
 * handle), struct_size checked by the one rule. And modbus_get_max_in_flight. */
static int read_all(modbus_t *ctx, modbus_completion_t *got, int max)
{
    int n = 0;
    modbus_completion_t c;
    for (;;) {
        memset(&c, 0, sizeof(c));
        c.struct_size = sizeof(c);
        int r = modbus_completion_read(ctx, &c);
        if (r != 1) {
            if (r != 0) {
                EXPECT(0, "modbus_completion_read: %d (%s)", r, modbus_strerror(errno));
            }
            return n;
        }
        if (n < max) {
            got[n] = c;
        }
        n++;
    }
}

/* Against the real server: the values, then the completion. */
static void pull_values(modbus_t *ctx)
{
    uint16_t a[4] = {0}, b[4] = {0};
    static int marker;
    int id = modbus_read_registers_async(ctx, 0, 4, a, NULL, &marker);
    drive(ctx, 5);
    modbus_completion_t got[4];
    int n = read_all(ctx, got, 4);
    int brc = modbus_read_registers(ctx, 0, 4, b);
    EXPECT(id >= 0 && n == 1 && got[0].ctx == ctx && got[0].request_id == id && got[0].rc == 4 &&
               got[0].user_data == &marker && got[0].struct_size == sizeof(modbus_completion_t) && brc == 4 &&
               memcmp(a, b, sizeof(a)) == 0,
           "a read with a NULL callback: one completion read (rc %d, id %d of %d, user_data %s), the values as the "
           "blocking call's",
           n == 1 ? got[0].rc : -9, n == 1 ? got[0].request_id : -9, id,
           n == 1 && got[0].user_data == &marker ? "kept" : "wrong");
}

static void pull_calls(void)
{
    int port, lf = listen_any(&port);
    uint16_t v[8];
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    EXPECT(modbus_get_max_in_flight(ctx) == 1, "modbus_get_max_in_flight: 1 by default (%d)",
           modbus_get_max_in_flight(ctx));
    modbus_set_max_in_flight(ctx, 16);
    EXPECT(modbus_get_max_in_flight(ctx) == 16, "modbus_get_max_in_flight after setting 16: %d",
           modbus_get_max_in_flight(ctx));
    errno = 0;
    EXPECT(modbus_get_max_in_flight(NULL) == -1 && errno == EINVAL, "modbus_get_max_in_flight(NULL): -1 EINVAL");
    modbus_t *rtu = modbus_new_rtu("/dev/null", 9600, 'N', 8, 1);
    modbus_set_max_in_flight(rtu, 8);
    EXPECT(modbus_get_max_in_flight(rtu) == 1, "on a serial line: 1 whatever was set (%d)",
           modbus_get_max_in_flight(rtu));
    modbus_free(rtu);

    /* struct_size: the first size, a larger one with a zero tail; not others. */
    struct {
        modbus_completion_t c;
        uint64_t tail;
    } big;
    modbus_completion_t c;
    memset(&c, 0, sizeof(c));
    c.struct_size = sizeof(c);
    EXPECT(modbus_completion_read(ctx, &c) == 0, "nothing to read: 0");
    size_t bad[] = {0, sizeof(size_t), offsetof(modbus_completion_t, error) + sizeof(int), sizeof(c) - 1};
    int refused = 0;
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        c.struct_size = bad[i];
        errno = 0;
        refused += modbus_completion_read(ctx, &c) == -1 && errno == EINVAL;
    }
    EXPECT(refused == 4, "struct_size 0, 8, 28, 39: -1 EINVAL (%d of 4)", refused);
    memset(&big, 0, sizeof(big));
    big.c.struct_size = sizeof(big);
    EXPECT(modbus_completion_read(ctx, &big.c) == 0, "a larger struct_size with a zero tail: taken");
    big.tail = 1;
    errno = 0;
    EXPECT(modbus_completion_read(ctx, &big.c) == -1 && errno == EINVAL,
           "a larger struct_size with a member this library does not know set: -1 EINVAL");
    big.c.struct_size = sizeof(big.c) + 1;
    big.tail = 0;
    ((unsigned char *) &big)[sizeof(big.c)] = 1;
    errno = 0;
    EXPECT(modbus_completion_read(ctx, &big.c) == -1 && errno == EINVAL,
           "struct_size one past with that byte set: -1 EINVAL");
    errno = 0;
    EXPECT(modbus_completion_read(ctx, NULL) == -1 && errno == EINVAL, "modbus_completion_read(ctx, NULL): -1 EINVAL");

    /* Three requests without a callback, one with: three completions to read, in
     * the order they completed, each once; the callback's runs as before. */
    reset();
    int ids[3];
    static int tags[3];
    for (int i = 0; i < 3; i++) {
        ids[i] = modbus_read_registers_async(ctx, 0, 1, &v[i], NULL, &tags[i]);
        modbus_set_request_timeout(ctx, ids[i], 0, 100000 * (unsigned) (i + 1));
    }
    int cbid = modbus_read_registers_async(ctx, 0, 1, &v[3], on_done, NULL);
    modbus_set_request_timeout(ctx, cbid, 0, 50000);
    drive(ctx, 5);
    modbus_completion_t got[8];
    int n = read_all(ctx, got, 8);
    int right = 0;
    for (int i = 0; i < 3 && i < n; i++) {
        right += got[i].ctx == ctx && got[i].request_id == ids[i] && got[i].rc == -1 && got[i].error == ETIMEDOUT &&
                 got[i].user_data == &tags[i];
    }
    EXPECT(n == 3 && right == 3 && results[cbid].done == 1 && completed == 1,
           "3 requests without a callback: %d completions read, %d right (id, rc -1, ETIMEDOUT, user_data); the "
           "one with a callback called back (%d)",
           n, right, completed);

    /* A multi handle: its contexts' completions are read from it. */
    modbus_multi_t *m = modbus_multi_new();
    modbus_t *c2 = modbus_new_tcp("127.0.0.1", port);
    modbus_multi_add(m, ctx);
    modbus_multi_add(m, c2);
    int mids[4];
    for (int i = 0; i < 4; i++) {
        modbus_t *x = i % 2 ? c2 : ctx;
        mids[i] = modbus_read_registers_async(x, 0, 1, &v[i], NULL, &tags[i % 3]);
        modbus_set_request_timeout(x, mids[i], 0, 100000);
    }
    double t0 = now_s();
    int done = 0;
    while (done < 4 && now_s() - t0 < 3) {
        done += modbus_multi_perform(m, 200);
    }
    memset(&c, 0, sizeof(c));
    c.struct_size = sizeof(c);
    EXPECT(modbus_completion_read(ctx, &c) == 0, "a context of a multi handle: nothing on the context itself");
    int mn = 0, mright = 0, own[2] = {0, 0};
    for (;;) {
        memset(&c, 0, sizeof(c));
        c.struct_size = sizeof(c);
        if (modbus_multi_completion_read(m, &c) != 1) {
            break;
        }
        mn++;
        for (int i = 0; i < 4; i++) {
            if (c.request_id == mids[i] && c.ctx == (i % 2 ? c2 : ctx) && c.error == ETIMEDOUT) {
                mright++;
                own[i % 2]++;
            }
        }
    }
    EXPECT(done == 4 && mn == 4 && mright == 4 && own[0] == 2 && own[1] == 2,
           "modbus_multi_completion_read: %d completions of 2 contexts (%d right, %d and %d), perform counted %d", mn,
           mright, own[0], own[1], done);
    /* One left unread when its context leaves the handle: it goes with it. */
    int last = modbus_read_registers_async(c2, 0, 1, &v[0], NULL, NULL);
    modbus_set_request_timeout(c2, last, 0, 50000);
    t0 = now_s();
    while (modbus_pending(c2) > 0 && now_s() - t0 < 3) {
        modbus_multi_perform(m, 200);
    }
    modbus_multi_remove(m, c2);
    memset(&c, 0, sizeof(c));
    c.struct_size = sizeof(c);
    int from_multi = modbus_multi_completion_read(m, &c);
    memset(&c, 0, sizeof(c));
    c.struct_size = sizeof(c);
    int from_ctx = modbus_completion_read(c2, &c);
    EXPECT(from_multi == 0 && from_ctx == 1 && c.request_id == last && c.ctx == c2,
           "a completion not read when its context left the handle: read from the context (%d, %d)", from_multi,
           from_ctx);
    modbus_free(c2);
    modbus_free(ctx);
    modbus_multi_free(m);
    close(lf);
}

/* ---------------------------------------------------------------- lost wake-ups (issue 39) */
/* A request given while a loop or another thread waits on what modbus_get_pollfd,
 * modbus_multi_get_fd or modbus_multi_perform(m, -1) waits on must end that wait;
 * so must a deadline, and modbus_multi_wakeup. A wait that does not end is ended by
 * a watchdog (SIGUSR1 to the waiting thread after a few seconds: poll and
 * epoll_wait return EINTR) and reported as a failure instead of hanging. */
static void on_usr1(int sig)
{
    (void) sig;
}

struct dog {
    pthread_t target, th;
    double until;
    int stop, fired; /* atomics */
};

static void *dog_main(void *arg)
{
    struct dog *d = arg;
    while (!__atomic_load_n(&d->stop, __ATOMIC_SEQ_CST)) {
        if (now_s() >= d->until) {
            __atomic_store_n(&d->fired, 1, __ATOMIC_SEQ_CST);
            pthread_kill(d->target, SIGUSR1);
            usleep(100000);
            continue;
        }
        usleep(2000);
    }
    return NULL;
}

static void dog_start(struct dog *d, double secs)
{
    d->target = pthread_self();
    d->until = now_s() + secs;
    d->stop = 0;
    d->fired = 0;
    pthread_create(&d->th, NULL, dog_main, d);
}

static int dog_fired(struct dog *d)
{
    return __atomic_load_n(&d->fired, __ATOMIC_SEQ_CST);
}

/* Stops the watchdog; whether it had to end a wait. */
static int dog_stop(struct dog *d)
{
    __atomic_store_n(&d->stop, 1, __ATOMIC_SEQ_CST);
    pthread_join(d->th, NULL);
    return dog_fired(d);
}

/* A thread that gives one request (or wakes a multi handle) after a pause. */
struct giver {
    modbus_t *ctx;
    modbus_multi_t *m; /* non-NULL: modbus_multi_wakeup(m) instead of a request */
    uint16_t *dest;
    int delay_ms;
    int id;
    double at; /* when it gave it */
    pthread_t th;
};

static void *giver_main(void *arg)
{
    struct giver *g = arg;
    usleep((unsigned) g->delay_ms * 1000);
    g->at = now_s();
    int id = g->m != NULL ? modbus_multi_wakeup(g->m) : modbus_read_registers_async(g->ctx, 0, 4, g->dest, on_done, NULL);
    __atomic_store_n(&g->id, id, __ATOMIC_SEQ_CST);
    return NULL;
}

static void giver_start(struct giver *g)
{
    g->id = -2;
    pthread_create(&g->th, NULL, giver_main, g);
}

/* A thread that closes a context after a pause. */
struct closer {
    modbus_t *ctx;
    int delay_ms;
    int done;
};

static void *closer_main(void *arg)
{
    struct closer *c = arg;
    usleep((unsigned) c->delay_ms * 1000);
    modbus_close(c->ctx);
    __atomic_store_n(&c->done, 1, __ATOMIC_SEQ_CST);
    return NULL;
}

/* A context on 127.0.0.1:port with that response timeout; added to *m (made when
 * NULL) when m is not NULL. */
static modbus_t *wake_ctx(int port, uint32_t sec, uint32_t usec, modbus_multi_t **m)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(ctx, sec, usec);
    if (m != NULL) {
        if (*m == NULL) {
            *m = modbus_multi_new();
        }
        modbus_multi_add(*m, ctx);
    }
    return ctx;
}

/* Until request `id` completes (or the watchdog fires): waits with -1 on the
 * modbus_get_pollfd descriptor (honouring its timeout 0: process now), or in
 * modbus_multi_perform(m, -1) when m is not NULL. */
static void wait_forever(modbus_t *ctx, modbus_multi_t *m, int id, struct dog *d)
{
    struct pollfd pfd;
    int t;
    while (id >= 0 && results[id].done == 0 && !dog_fired(d)) {
        if (m != NULL) {
            modbus_multi_perform(m, -1);
            continue;
        }
        if (modbus_get_pollfd(ctx, &pfd, &t) < 0) {
            break;
        }
        int n = t == 0 ? 0 : poll(&pfd, 1, -1);
        modbus_process(ctx, n > 0 ? pfd.revents : 0);
    }
}

static int wake_cases(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_usr1; /* no SA_RESTART: a wait it interrupts returns */
    sigaction(SIGUSR1, &sa, NULL);
    struct many_server s = {0};
    int port, dead_port, on = 1;
    s.listen_fd = listen_any(&port);
    ioctl(s.listen_fd, FIONBIO, &on);
    /* A device that never answers: connects are taken by the backlog, nothing more. */
    int dead = listen_any(&dead_port);
    pthread_t th;
    pthread_create(&th, NULL, many_server_main, &s);
    chk_set_prefix("wake: ");
    uint16_t v[4], w[4];
    struct dog d;
    struct pollfd pfd;
    int t, id;
    double t0;

    /* (a) One thread: the loop reads the timeout (-1: nothing pending, not connected),
     * then gives a request, then waits as it was told. */
    {
        modbus_t *ctx = wake_ctx(port, 1, 0, NULL);
        reset();
        dog_start(&d, 3);
        int n0 = modbus_get_pollfd(ctx, &pfd, &t);
        int t_first = t;
        t0 = now_s();
        id = modbus_read_registers_async(ctx, 0, 4, v, on_done, NULL);
        while (id >= 0 && results[id].done == 0 && !dog_fired(&d)) {
            int n = poll(&pfd, 1, t);
            modbus_process(ctx, n > 0 ? pfd.revents : 0);
            if (modbus_get_pollfd(ctx, &pfd, &t) < 0) {
                break;
            }
        }
        double took = now_s() - t0;
        int fired = dog_stop(&d);
        EXPECT(n0 == 0 && t_first == -1 && !fired && id >= 0 && results[id].done == 1 && results[id].rc == 4 && took < 1.0,
               "(a) context: a request given after modbus_get_pollfd said -1 (nothing pending): the wait it was told "
               "ends, the request completes in %.3f s (response timeout 1 s; %s, rc %d)",
               took, fired ? "the watchdog had to end the wait" : "no watchdog", id >= 0 ? results[id].rc : -9);
        modbus_close(ctx);
        modbus_free(ctx);
    }
    {
        modbus_multi_t *m = NULL;
        modbus_t *ctx = wake_ctx(port, 1, 0, &m);
        reset();
        dog_start(&d, 3);
        t = modbus_multi_timeout(m);
        int t_first = t;
        pfd.fd = modbus_multi_get_fd(m);
        pfd.events = POLLIN;
        t0 = now_s();
        id = modbus_read_registers_async(ctx, 0, 4, v, on_done, NULL);
        while (id >= 0 && results[id].done == 0 && !dog_fired(&d)) {
            poll(&pfd, 1, t);
            modbus_multi_perform(m, 0);
            t = modbus_multi_timeout(m);
        }
        double took = now_s() - t0;
        int fired = dog_stop(&d);
        EXPECT(t_first == -1 && !fired && id >= 0 && results[id].done == 1 && results[id].rc == 4 && took < 1.0,
               "(a) multi: a request given after modbus_multi_timeout said -1: the wait on modbus_multi_get_fd ends, "
               "the request completes in %.3f s (response timeout 1 s; %s)",
               took, fired ? "the watchdog had to end the wait" : "no watchdog");
        modbus_multi_free(m);
        modbus_close(ctx);
        modbus_free(ctx);
    }

    /* (b) A thread in modbus_multi_perform(m, -1), waiting on a device that never
     * answers (response timeout 10 s), while another thread gives a request to a
     * second context of the handle. */
    {
        modbus_multi_t *m = NULL;
        modbus_t *slow = wake_ctx(dead_port, 10, 0, &m), *ctx = wake_ctx(port, 1, 0, &m);
        reset();
        modbus_read_registers_async(slow, 0, 4, w, on_done, NULL);
        struct giver g = {.ctx = ctx, .dest = v, .delay_ms = 300};
        dog_start(&d, 3);
        giver_start(&g);
        int calls = 0;
        for (;;) {
            int gid = __atomic_load_n(&g.id, __ATOMIC_SEQ_CST);
            if (dog_fired(&d) || (gid >= 0 && results[gid].done) || gid == -1) {
                break;
            }
            modbus_multi_perform(m, -1);
            calls++;
        }
        double end = now_s();
        int fired = dog_stop(&d);
        pthread_join(g.th, NULL);
        double took = end - g.at;
        EXPECT(!fired && g.id >= 0 && results[g.id].done == 1 && results[g.id].rc == 4 && took < 1.0,
               "(b) another thread gives a request while modbus_multi_perform(m, -1) waits: it completes %.3f s after "
               "it was given (response timeout 1 s; %s; %d calls)",
               took, fired ? "the watchdog had to end the wait" : "no watchdog", calls);
        modbus_multi_free(m);
        modbus_free(slow);
        modbus_close(ctx);
        modbus_free(ctx);
    }

    /* (c) The same on one context: a thread waits on the descriptor of
     * modbus_get_pollfd as it was told (-1: nothing pending) while another gives a
     * request. */
    {
        modbus_t *ctx = wake_ctx(port, 1, 0, NULL);
        reset();
        struct giver g = {.ctx = ctx, .dest = v, .delay_ms = 300};
        dog_start(&d, 3);
        giver_start(&g);
        for (;;) {
            int gid = __atomic_load_n(&g.id, __ATOMIC_SEQ_CST);
            if (dog_fired(&d) || (gid >= 0 && results[gid].done) || gid == -1) {
                break;
            }
            if (modbus_get_pollfd(ctx, &pfd, &t) < 0) {
                break;
            }
            int n = poll(&pfd, 1, t);
            modbus_process(ctx, n > 0 ? pfd.revents : 0);
        }
        double end = now_s();
        int fired = dog_stop(&d);
        pthread_join(g.th, NULL);
        double took = end - g.at;
        EXPECT(!fired && g.id >= 0 && results[g.id].done == 1 && results[g.id].rc == 4 && took < 1.0,
               "(c) another thread gives a request while a thread polls the modbus_get_pollfd descriptor: it completes "
               "%.3f s after it was given (response timeout 1 s; %s)",
               took, fired ? "the watchdog had to end the wait" : "no watchdog");
        modbus_close(ctx);
        modbus_free(ctx);
    }

    /* (d) modbus_multi_wakeup: a modbus_multi_perform(m, -1) that waits (nothing
     * pending) returns early; a wake-up given while none waits ends the next wait at
     * once. */
    {
        modbus_multi_t *m = NULL;
        modbus_t *ctx = wake_ctx(port, 1, 0, &m);
        struct giver g = {.m = m, .delay_ms = 300};
        dog_start(&d, 3);
        giver_start(&g);
        t0 = now_s();
        int rc = modbus_multi_perform(m, -1);
        double took = now_s() - t0;
        int fired = dog_stop(&d);
        pthread_join(g.th, NULL);
        EXPECT(rc == 0 && g.id == 0 && !fired && took >= 0.25 && took < 1.0,
               "(d) modbus_multi_wakeup from another thread: modbus_multi_perform(m, -1) (nothing pending) returned %d "
               "after %.3f s (woken at 0.3 s; %s)",
               rc, took, fired ? "the watchdog had to end the wait" : "no watchdog");
        dog_start(&d, 3);
        int wrc = modbus_multi_wakeup(m);
        t0 = now_s();
        rc = modbus_multi_perform(m, -1);
        took = now_s() - t0;
        fired = dog_stop(&d);
        EXPECT(wrc == 0 && rc == 0 && !fired && took < 0.2,
               "(d) a wake-up given before the wait: the next modbus_multi_perform(m, -1) returns at once (%.3f s)", took);
        errno = 0;
        EXPECT(modbus_multi_wakeup(NULL) == -1 && errno == EINVAL, "(d) modbus_multi_wakeup(NULL): -1 EINVAL");
        modbus_multi_free(m);
        modbus_free(ctx);
    }

    /* (e) A deadline wakes the descriptor: a device that never answers, response
     * timeout 0.3 s, waited for with poll(-1) on modbus_multi_get_fd (each wait after
     * modbus_multi_timeout, whose value is only looked at for 0: call now) and on
     * modbus_get_pollfd's. */
    {
        modbus_multi_t *m = NULL;
        modbus_t *ctx = wake_ctx(dead_port, 0, 300000, &m);
        reset();
        dog_start(&d, 3);
        t0 = now_s();
        id = modbus_read_registers_async(ctx, 0, 4, v, on_done, NULL);
        pfd.fd = modbus_multi_get_fd(m);
        pfd.events = POLLIN;
        while (id >= 0 && results[id].done == 0 && !dog_fired(&d)) {
            if (modbus_multi_timeout(m) != 0) {
                poll(&pfd, 1, -1);
            }
            modbus_multi_perform(m, 0);
        }
        double took = now_s() - t0;
        int fired = dog_stop(&d);
        EXPECT(!fired && id >= 0 && results[id].done == 1 && results[id].error == ETIMEDOUT && took >= 0.29 &&
                   took < 1.0,
               "(e) multi: poll(-1) on modbus_multi_get_fd wakes for the deadline: ETIMEDOUT after %.3f s (response "
               "timeout 0.3 s; %s)",
               took, fired ? "the watchdog had to end the wait" : "no watchdog");
        modbus_multi_free(m);
        modbus_free(ctx);
    }
    {
        modbus_t *ctx = wake_ctx(dead_port, 0, 300000, NULL);
        reset();
        dog_start(&d, 3);
        t0 = now_s();
        id = modbus_read_registers_async(ctx, 0, 4, v, on_done, NULL);
        wait_forever(ctx, NULL, id, &d);
        double took = now_s() - t0;
        int fired = dog_stop(&d);
        EXPECT(!fired && id >= 0 && results[id].done == 1 && results[id].error == ETIMEDOUT && took >= 0.29 &&
                   took < 1.0,
               "(e) context: poll(-1) on the modbus_get_pollfd descriptor wakes for the deadline: ETIMEDOUT after "
               "%.3f s (response timeout 0.3 s; %s)",
               took, fired ? "the watchdog had to end the wait" : "no watchdog");
        modbus_free(ctx);
    }

    /* (f) A close from another thread (a signal handler's would do the same: one
     * write) wakes a wait on either descriptor: the request to a device that never
     * answers, response timeout 10 s, completes with ESHUTDOWN at once. */
    for (int multi = 0; multi < 2; multi++) {
        modbus_multi_t *m = NULL;
        modbus_t *ctx = wake_ctx(dead_port, 10, 0, multi ? &m : NULL);
        reset();
        id = modbus_read_registers_async(ctx, 0, 4, v, on_done, NULL);
        /* Connected and sent first: then the wait has nothing but the deadline. */
        for (int i = 0; i < 20 && id >= 0; i++) {
            if (multi) {
                modbus_multi_perform(m, 10);
            } else if (modbus_get_pollfd(ctx, &pfd, &t) >= 0) {
                int n = poll(&pfd, 1, 10);
                modbus_process(ctx, n > 0 ? pfd.revents : 0);
            }
        }
        struct closer c = {ctx, 300, 0};
        pthread_t cth;
        dog_start(&d, 3);
        t0 = now_s();
        pthread_create(&cth, NULL, closer_main, &c);
        wait_forever(ctx, m, id, &d);
        double took = now_s() - t0;
        int fired = dog_stop(&d);
        pthread_join(cth, NULL);
        EXPECT(!fired && id >= 0 && results[id].done == 1 && results[id].error == ESHUTDOWN && took < 1.5,
               "(f) %s: a modbus_close from another thread wakes a wait with -1: ESHUTDOWN after %.3f s (closed at "
               "0.3 s, response timeout 10 s; %s)",
               multi ? "multi: modbus_multi_perform(m, -1)" : "context: poll(-1) on the modbus_get_pollfd descriptor",
               took, fired ? "the watchdog had to end the wait" : "no watchdog");
        if (m != NULL) {
            modbus_multi_free(m);
        }
        modbus_free(ctx);
    }

    chk_set_prefix("");
    __atomic_store_n(&s.stop, 1, __ATOMIC_SEQ_CST);
    pthread_join(th, NULL);
    close(s.listen_fd);
    close(dead);
    return chk_summary();
}

/* ---------------------------------------------------------------- a user-defined function code */
/* fc41 MODE ADDR: c-tests/event/fc41_device.py (MODE rtu|ascii on the pty end ADDR,
 * tcp|rtutcp on 127.0.0.1 port ADDR; or a gateway in front of it, MODE tcp) answers
 * the request PDU 41 00 08 to unit 1 with the 9-byte PDU 41 01 02 03 04 05 06 07 08.
 * The whole answer's ADU, byte for byte, must come from modbus_send_raw_request +
 * modbus_receive_confirmation and from modbus_send_raw_request_async: RTU and RTU
 * over TCP 01 41 01 .. 08 + CRC (12 bytes), ASCII 01 41 01 .. 08 + LRC (11 bytes:
 * the ADU decoded), TCP the MBAP header (transaction id, 00 00, length 00 0A, unit
 * 01) + the PDU (16 bytes; the transaction id is not compared). Each call on a line
 * flushed first, so that one failure does not make the next. */
static void hex(char *out, size_t max, const uint8_t *p, int n)
{
    size_t len = 0;
    out[0] = '\0';
    for (int i = 0; i < n && len + 4 < max; i++) {
        len += (size_t) snprintf(out + len, max - len, "%s%02X", i ? " " : "", p[i]);
    }
}

static int fc41(const char *mode, const char *addr)
{
    static const uint8_t pdu[9] = {0x41, 1, 2, 3, 4, 5, 6, 7, 8};
    const uint8_t req[4] = {1, 0x41, 0x00, 0x08};
    uint8_t want[32], rsp[1024];
    char got_hex[3200], want_hex[128];
    int rtu = strcmp(mode, "rtu") == 0, ascii = strcmp(mode, "ascii") == 0, tcp = strcmp(mode, "tcp") == 0;
    int rtutcp = strcmp(mode, "rtutcp") == 0, n = 0, skip = 0, rc, round;
    modbus_t *ctx = rtu      ? modbus_new_rtu(addr, 115200, 'N', 8, 1)
                    : ascii  ? modbus_new_ascii(addr, 115200, 'N', 8, 1)
                    : rtutcp ? modbus_new_rtu_tcp("127.0.0.1", atoi(addr))
                    : tcp    ? modbus_new_tcp("127.0.0.1", atoi(addr))
                             : NULL;
    chk_set_prefix(rtu ? "fc41 rtu: " : ascii ? "fc41 ascii: " : rtutcp ? "fc41 rtutcp: " : "fc41 tcp: ");
    if (!EXPECT(ctx != NULL && modbus_set_slave(ctx, 1) == 0 && modbus_connect(ctx) == 0, "connect to %s",
                addr)) {
        chk_set_prefix("");
        return chk_summary();
    }
    modbus_set_response_timeout(ctx, 2, 0);
    if (tcp) {
        const uint8_t mbap[7] = {0, 0, 0, 0, 0, 10, 1};
        memcpy(want, mbap, 7);
        n = 7;
        skip = 2;
    } else {
        want[n++] = 1;
    }
    memcpy(want + n, pdu, 9);
    n += 9;
    if (rtu || rtutcp) {
        uint16_t crc = 0xFFFF;
        for (int i = 0; i < n; i++) {
            crc ^= want[i];
            for (int b = 0; b < 8; b++) {
                crc = (crc & 1) ? (uint16_t) ((crc >> 1) ^ 0xA001) : (uint16_t) (crc >> 1);
            }
        }
        want[n++] = (uint8_t) (crc & 0xFF);
        want[n++] = (uint8_t) (crc >> 8);
    } else if (ascii) {
        uint8_t lrc = 0;
        for (int i = 0; i < n; i++) {
            lrc = (uint8_t) (lrc + want[i]);
        }
        want[n++] = (uint8_t) -lrc;
    }
    hex(want_hex, sizeof want_hex, want + skip, n - skip);
    for (round = 0; round < 2; round++) {
        /* Blocking: modbus_send_raw_request + modbus_receive_confirmation. */
        memset(rsp, 0, sizeof rsp);
        errno = 0;
        rc = modbus_send_raw_request(ctx, req, 4);
        if (rc > 0) {
            rc = modbus_receive_confirmation(ctx, rsp);
        }
        hex(got_hex, sizeof got_hex, rsp + skip, rc > skip ? rc - skip : 0);
        EXPECT(rc == n && memcmp(rsp + skip, want + skip, (size_t) (n - skip)) == 0,
               "modbus_send_raw_request + modbus_receive_confirmation (%d): the whole answer to FC 0x41, %d bytes "
               "(rc %d%s%s; got %s; expected %s)",
               round + 1, n, rc, rc == -1 ? ", " : "", rc == -1 ? modbus_strerror(errno) : "", got_hex, want_hex);
        usleep(300000);
        modbus_flush(ctx);
        /* Without waiting: modbus_send_raw_request_async + modbus_process. */
        memset(rsp, 0, sizeof rsp);
        reset();
        struct result a = one(ctx, modbus_send_raw_request_async(ctx, req, 4, rsp, on_done, NULL));
        hex(got_hex, sizeof got_hex, rsp + skip, a.rc > skip ? a.rc - skip : 0);
        EXPECT(a.done == 1 && a.rc == n && memcmp(rsp + skip, want + skip, (size_t) (n - skip)) == 0,
               "modbus_send_raw_request_async (%d): the whole answer to FC 0x41, %d bytes (rc %d%s%s; got %s; "
               "expected %s)",
               round + 1, n, a.rc, a.rc == -1 ? ", " : "", a.rc == -1 ? modbus_strerror(a.error) : "", got_hex,
               want_hex);
        usleep(300000);
        modbus_flush(ctx);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    chk_set_prefix("");
    return chk_summary();
}

int main(int argc, char **argv)
{
    if (argc == 2 && strcmp(argv[1], "wake") == 0) {
        setvbuf(stdout, NULL, _IOLBF, 0);
        if (!mbt_is_rsmodbus()) {
            fprintf(stderr, "the event-driven client is rsmodbus': this is not it\n");
            return 97;
        }
        return wake_cases();
    }
    if (argc < 3) {
        fprintf(stderr, "usage: %s tcp PORT | rtu DEVICE | tls PORT\n", argv[0]);
        return 2;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);
    if (strcmp(argv[1], "rtu-late") == 0 && argc > 3) {
        return rtu_late(argv[2], argv[3]);
    }
    if (strcmp(argv[1], "many") == 0) {
        return many_devices(atoi(argv[2]), argc > 3 ? atoi(argv[3]) : 1000);
    }
    if (!mbt_is_rsmodbus()) {
        fprintf(stderr, "the event-driven client is rsmodbus': this is not it\n");
        return 97;
    }
    if (strcmp(argv[1], "fc41") == 0 && argc > 3) {
        return fc41(argv[2], argv[3]);
    }
    if (strcmp(argv[1], "threads") == 0) {
        two_threads(atoi(argv[2]), argc > 3 ? atoi(argv[3]) : 2000);
        return chk_summary();
    }
    int serial = strcmp(argv[1], "rtu") == 0, tls = strcmp(argv[1], "tls") == 0;
    modbus_t *ctx = serial ? modbus_new_rtu(argv[2], 115200, 'N', 8, 1)
                    : tls  ? mbt_new_tls("event-test", atoi(argv[2]))
                           : modbus_new_tcp("127.0.0.1", atoi(argv[2]));
    /* EVENT_SLAVE: the unit id of a server that answers only its own (pymodbus). */
    int slave = getenv("EVENT_SLAVE") != NULL ? atoi(getenv("EVENT_SLAVE")) : (serial ? 1 : -1);
    if (ctx == NULL || (slave >= 0 && modbus_set_slave(ctx, slave) != 0) || modbus_connect(ctx) != 0) {
        EXPECT(0, "connect to the server: %s", modbus_strerror(errno));
        return chk_summary();
    }
    modbus_set_response_timeout(ctx, 2, 0);
    chk_set_prefix(serial ? "rtu: " : tls ? "tls: " : "tcp: ");
    raw_calls(ctx, serial);
    pull_values(ctx);
    compare_calls(ctx, serial);
    if (tls) {
        /* The same calls, the handshake too without waiting: a new context, not
         * connected, whose first request connects. */
        modbus_free(ctx);
        ctx = mbt_new_tls("event-test", atoi(argv[2]));
        uint16_t v[4] = {0};
        reset();
        int id = modbus_read_registers_async(ctx, 0, 4, v, on_done, NULL);
        drive(ctx, 10);
        EXPECT(results[id].done == 1 && results[id].rc == 4,
               "a request on a context not connected: connect and handshake without waiting, then the answer "
               "(rc %d, %s)",
               results[id].rc, results[id].rc == -1 ? modbus_strerror(results[id].error) : "ok");
        stalled_handshake();
        modbus_close(ctx);
        modbus_free(ctx);
        chk_set_prefix("");
        return chk_summary();
    }
    if (serial) {
        /* A broadcast: completes without an answer, after the turnaround, rc as a write's. */
        reset();
        modbus_connect(ctx);
        /* The answer to the request that was on the line when it closed. */
        usleep(100000);
        modbus_flush(ctx);
        modbus_set_slave(ctx, 0);
        double t0 = now_s();
        struct result a = one(ctx, modbus_write_register_async(ctx, 50, 7, on_done, NULL));
        double t = now_s() - t0;
        EXPECT(a.done == 1 && a.rc == 1 && t >= 0.09 && t < 1.0,
               "broadcast write_register: rc 1 after %.3f s without an answer (turnaround 0.1 s)", t);
        modbus_set_slave(ctx, 1);
        uint16_t v = 0;
        int rc = modbus_read_registers(ctx, 50, 1, &v);
        EXPECT(rc == 1 && v == 7, "the broadcast reached the server (register 50 = %u)", v);
        /* RS-485 direction by the application's hook: an asynchronous request runs
         * the blocking call's sequence (up before the frame, down after it). */
        rts_calls[0] = '\0';
        modbus_rtu_set_custom_rts(ctx, rts_hook);
        modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_UP);
        rc = modbus_read_registers(ctx, 50, 1, &v);
        EXPECT(rc == 1 && strcmp(rts_calls, "010") == 0, "blocking read with RTS up: the hook's calls %s (010)",
               rts_calls);
        rts_calls[0] = '\0';
        a = one(ctx, modbus_read_registers_async(ctx, 50, 1, &v, on_done, NULL));
        EXPECT(a.done == 1 && a.rc == 1 && strcmp(rts_calls, "10") == 0,
               "asynchronous read with RTS up: rc %d, the hook's calls %s (10, as the blocking call's)", a.rc,
               rts_calls);
        /* Inside the hook the request is pending; what would change the requests
         * waits for modbus_process to return (EBUSY). */
        rts_calls[0] = '\0';
        rts_probe = 1;
        a = one(ctx, modbus_read_registers_async(ctx, 50, 1, &v, on_done, NULL));
        EXPECT(a.done == 1 && a.rc == 1 && rts_pending == 1 && rts_submit == -1 && rts_submit_errno == EBUSY &&
                   rts_blocking == -1 && rts_blocking_errno == EBUSY && modbus_pending(ctx) == 0,
               "calls from the RTS hook of an asynchronous request: pending %d, a submit %d (%s), a blocking call "
               "%d (%s); the request rc %d",
               rts_pending, rts_submit, modbus_strerror(rts_submit_errno), rts_blocking,
               modbus_strerror(rts_blocking_errno), a.rc);
        /* The answer's timeout starts when the frame has left: a sequence of 2 x 150 ms
         * around it (modbus_rtu_set_rts_delay) with a response timeout of 100 ms. */
        modbus_rtu_set_rts_delay(ctx, 150000);
        modbus_set_response_timeout(ctx, 0, 100000);
        rc = modbus_read_registers(ctx, 50, 1, &v);
        EXPECT(rc == 1, "blocking read, RTS delay 150 ms, response timeout 100 ms: rc %d (%s)", rc,
               rc == -1 ? modbus_strerror(errno) : "ok");
        a = one(ctx, modbus_read_registers_async(ctx, 50, 1, &v, on_done, NULL));
        EXPECT(a.done == 1 && a.rc == 1, "the same asynchronous read: rc %d (%s)", a.rc,
               a.rc == -1 ? modbus_strerror(a.error) : "ok");
        modbus_set_response_timeout(ctx, 2, 0);
        /* (issue 39, item 2) modbus_free from another thread while modbus_process
         * holds the context (in the RTS sequence's 300 ms): the requests (to a unit
         * that does not answer) complete with EIDRM on the freeing thread once the
         * call let go, each once. */
        modbus_rtu_set_rts_delay(ctx, 300000);
        modbus_set_slave(ctx, 99); /* a unit no one answers for: they stay pending */
        ot_calls = ot_on_freer = 0;
        int queued = 0;
        for (int i = 0; i < 3; i++) {
            queued += modbus_read_registers_async(ctx, 50, 1, &ot_vals[i], ot_cb, NULL) >= 0;
        }
        pthread_t freer;
        ot_ctx = ctx;
        pthread_create(&freer, NULL, ot_free_main, NULL);
        modbus_process(ctx, 0); /* its write's RTS sequence: 300 ms, then more */
        pthread_join(freer, NULL);
        ctx = NULL; /* freed */
        EXPECT(queued == 3 && ot_calls == 3 && ot_eidrm == 3,
               "modbus_free from another thread during modbus_process: %d callbacks, %d with EIDRM (%d on the "
               "freeing thread, the others as modbus_process ended; the last: rc %d, %s)",
               ot_calls, ot_eidrm, ot_on_freer, ot_rc, ot_rc == -1 ? modbus_strerror(ot_error) : "ok");
    } else {
        chk_set_prefix("own servers: ");
        own_servers();
        pipeline_faults();
        multi_case();
        chk_set_prefix("close and free: ");
        close_and_free();
        chk_set_prefix("pull: ");
        pull_calls();
        chk_set_prefix("");
    }
    modbus_close(ctx);
    modbus_free(ctx);
    if (!serial && getenv("EVENT_SLAVE") == NULL) {
        /* Two threads (mb-server serves one client at a time: after this one closed).
         * Not against pymodbus: it takes no pipelining, see EVENT_DEPTH. */
        chk_set_prefix("tcp: ");
        two_threads(atoi(argv[2]), getenv("EVENT_THREADS_N") != NULL ? atoi(getenv("EVENT_THREADS_N")) : 2000);
        chk_set_prefix("");
    }
    chk_set_prefix("");
    return chk_summary();
}
