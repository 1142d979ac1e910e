/*
 * gw-check.c: Modbus/TCP masters of a gateway (rsmodbus-gateway or mbusd) in front
 * of an RTU line whose device is benches/mb-server.c (slave 1: holding register i
 * holds 3 * i, input register i 7 * i, coil i is i % 3 == 0), for
 * c-tests/suites/gateway.sh. Built against Debian's <modbus.h> and libmodbus.
 *
 *   gw-check PORT calls          every function code mbusd handles, on unit 1 and on
 *                                unit 9 (no device): one line per call, rc, errno and
 *                                the values, for the suite to compare between the
 *                                two gateways (no check of its own)
 *   gw-check PORT fair N SECS    N masters (threads) in tight loops reading one
 *                                register for SECS seconds: each one's count, and
 *                                the spread (most / fewest)
 *   gw-check PORT leave          a master sends a read of 125 registers and leaves
 *                                while it is on the line (its answer is dropped);
 *                                another master's read is answered, right
 *   gw-check PORT unit U EXC     a read of unit U fails with exception EXC (hex)
 *   gw-check PORT held N         N masters connected at once, each reading once
 *   gw-check PORT across U S     one connection: a read of unit U gets exception 0x0A
 *                                (no route), then, S seconds later (the suite
 *                                changes the routes and sends SIGHUP meanwhile), the
 *                                same read on the same connection is answered
 *   gw-check PORT broadcast ECHO a write to unit 0: no answer (a timeout), or, with
 *                                ECHO 1 (-b), the request echoed; unit 1 got it
 *   gw-check PORT busy           40 requests for unit 9 (no device) in one write: the
 *                                first 16 wait, the others get exception 0x06 at once
 *   gw-check PORT hold N S       N masters connected, each reading once (latencies:
 *                                p50, p99, max), then held S seconds (HOLDING)
 *   gw-check PORT reads U        unit U: registers 10 and 11 read (30, 33), register 62
 *                                written and read back
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbtest.h"

static int port;

static modbus_t *master(int unit)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    if (ctx == NULL || modbus_connect(ctx) != 0) {
        if (ctx != NULL) {
            modbus_free(ctx);
        }
        return NULL;
    }
    modbus_set_slave(ctx, unit);
    modbus_set_response_timeout(ctx, 5, 0);
    return ctx;
}

static void show(const char *what, int rc, int err, const uint16_t *regs, const uint8_t *bits, int n)
{
    int i;
    printf("%s: rc=%d", what, rc);
    if (rc < 0) {
        printf(" errno=%s", mbt_errname(err));
    }
    for (i = 0; rc > 0 && i < n && i < rc; i++) {
        printf(" %d", regs != NULL ? regs[i] : bits[i]);
    }
    printf("\n");
}

static void calls(void)
{
    /* GW_UNIT: the unit of the line's device (1: mb-server; 17: pymodbus'). */
    int first = getenv("GW_UNIT") != NULL ? atoi(getenv("GW_UNIT")) : 1, units[2] = {first, 9}, k;
    for (k = 0; k < 2; k++) {
        int unit = units[k];
        modbus_t *ctx = master(unit);
        uint16_t regs[20], w[3] = {111, 222, 333};
        uint8_t bits[20], wb[5] = {1, 0, 1, 1, 0};
        char what[64];
        int rc;
        if (ctx == NULL) {
            printf("unit %d: no connection\n", unit);
            continue;
        }
#define GWCALL(name, expr, r, b, n)                                                                                       \
    do {                                                                                                               \
        errno = 0;                                                                                                     \
        rc = (expr);                                                                                                   \
        snprintf(what, sizeof what, "unit %d %s", unit, name);                                                         \
        show(what, rc, errno, r, b, n);                                                                                \
    } while (0)
        GWCALL("FC03 read 10 registers at 4", modbus_read_registers(ctx, 4, 10, regs), regs, NULL, 10);
        GWCALL("FC04 read 5 input registers", modbus_read_input_registers(ctx, 0, 5, regs), regs, NULL, 5);
        GWCALL("FC01 read 12 coils", modbus_read_bits(ctx, 0, 12, bits), NULL, bits, 12);
        GWCALL("FC02 read 9 discrete inputs", modbus_read_input_bits(ctx, 3, 9, bits), NULL, bits, 9);
        GWCALL("FC06 write register 30", modbus_write_register(ctx, 30, 4321), NULL, NULL, 0);
        GWCALL("FC03 read it back", modbus_read_registers(ctx, 30, 1, regs), regs, NULL, 1);
        GWCALL("FC10 write 3 registers at 40", modbus_write_registers(ctx, 40, 3, w), NULL, NULL, 0);
        GWCALL("FC03 read them back", modbus_read_registers(ctx, 40, 3, regs), regs, NULL, 3);
        GWCALL("FC05 write coil 7", modbus_write_bit(ctx, 7, 1), NULL, NULL, 0);
        GWCALL("FC0F write 5 coils at 20", modbus_write_bits(ctx, 20, 5, wb), NULL, NULL, 0);
        GWCALL("FC01 read them back", modbus_read_bits(ctx, 20, 5, bits), NULL, bits, 5);
        GWCALL("FC03 read past the table", modbus_read_registers(ctx, 30000, 2, regs), regs, NULL, 2);
        modbus_close(ctx);
        modbus_free(ctx);
    }
}

struct fair_arg {
    int secs;
    long count;
    long errors;
};

static void *fair_master(void *p)
{
    struct fair_arg *a = p;
    modbus_t *ctx = master(1);
    time_t end = time(NULL) + a->secs;
    uint16_t v;
    if (ctx == NULL) {
        a->errors = -1;
        return NULL;
    }
    while (time(NULL) < end) {
        if (modbus_read_registers(ctx, 5, 1, &v) == 1 && v == 15) {
            a->count++;
        } else {
            a->errors++;
        }
    }
    modbus_close(ctx);
    modbus_free(ctx);
    return NULL;
}

static void fair(int n, int secs)
{
    pthread_t *t = calloc((size_t) n, sizeof *t);
    struct fair_arg *a = calloc((size_t) n, sizeof *a);
    long most = 0, fewest = -1, total = 0, errors = 0;
    int i, unserved = 0, unconnected = 0;
    for (i = 0; i < n; i++) {
        a[i].secs = secs;
        pthread_create(&t[i], NULL, fair_master, &a[i]);
    }
    for (i = 0; i < n; i++) {
        pthread_join(t[i], NULL);
        total += a[i].count;
        unserved += a[i].count == 0;
        /* (-1: it could not connect) */
        unconnected += a[i].errors < 0;
        errors += a[i].errors > 0 ? a[i].errors : 0;
        most = a[i].count > most ? a[i].count : most;
        fewest = fewest < 0 || a[i].count < fewest ? a[i].count : fewest;
    }
    printf("# fair: %d masters, %ld answers in %d s (%.1f/s), %ld errors, most %ld, fewest %ld, spread %.2f, "
           "unserved %d, not connected %d\n",
           n, total, secs, (double) total / secs, errors, most, fewest, fewest > 0 ? (double) most / fewest : 0.0,
           unserved, unconnected);
    EXPECT(unconnected == 0, "every master connected (%d not)", unconnected);
    EXPECT(fewest > 0, "every master served (fewest %ld)", fewest);
    EXPECT(errors == 0, "no errors (%ld)", errors);
    EXPECT(fewest > 0 && (double) most / fewest <= 1.2, "the busiest within 1.2x of the least served (%.2f)",
           fewest > 0 ? (double) most / fewest : 0.0);
    free(t);
    free(a);
}

static void leave(void)
{
    struct sockaddr_in sa;
    uint8_t q[12] = {0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 125};
    int s = socket(AF_INET, SOCK_STREAM, 0);
    modbus_t *ctx;
    uint16_t v[2];
    memset(&sa, 0, sizeof sa);
    sa.sin_family = AF_INET;
    sa.sin_port = htons((uint16_t) port);
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT(connect(s, (struct sockaddr *) &sa, sizeof sa) == 0 && send(s, q, sizeof q, 0) == 12,
           "a master sends a read of 125 registers");
    usleep(2000);
    close(s);
    ctx = master(1);
    EXPECT(ctx != NULL && modbus_read_registers(ctx, 10, 2, v) == 2 && v[0] == 30 && v[1] == 33,
           "it leaves while the request is on the line; another master's read is answered, right");
    if (ctx != NULL) {
        modbus_close(ctx);
        modbus_free(ctx);
    }
}

static void unit_exception(int unit, int exc)
{
    modbus_t *ctx = master(unit);
    uint16_t v;
    int rc;
    if (!EXPECT(ctx != NULL, "connect")) {
        return;
    }
    errno = 0;
    rc = modbus_read_registers(ctx, 0, 1, &v);
    EXPECT(rc == -1 && errno == MODBUS_ENOBASE + exc, "unit %d: exception 0x%02X (rc %d, %s)", unit, exc, rc,
           mbt_errname(errno));
    modbus_close(ctx);
    modbus_free(ctx);
}

static void held(int n)
{
    modbus_t **c = calloc((size_t) n, sizeof *c);
    int i, connected = 0, answered = 0;
    uint16_t v;
    for (i = 0; i < n; i++) {
        c[i] = master(1);
        connected += c[i] != NULL;
    }
    EXPECT(connected == n, "%d masters connected at once (%d)", n, connected);
    for (i = 0; i < n; i++) {
        if (c[i] != NULL && modbus_read_registers(c[i], i % 100, 1, &v) == 1 && v == 3 * (i % 100)) {
            answered++;
        }
    }
    EXPECT(answered == n, "each answered, right (%d)", answered);
    for (i = 0; i < n; i++) {
        if (c[i] != NULL) {
            modbus_close(c[i]);
            modbus_free(c[i]);
        }
    }
    free(c);
}

static void reads(int unit)
{
    modbus_t *ctx = master(unit);
    uint16_t v[2];
    int rc;
    if (!EXPECT(ctx != NULL, "connect")) {
        return;
    }
    rc = modbus_read_registers(ctx, 10, 2, v);
    EXPECT(rc == 2 && v[0] == 30 && v[1] == 33, "unit %d: registers 10 and 11 (rc %d)", unit, rc);
    EXPECT(modbus_write_register(ctx, 62, (uint16_t) (6200 + unit)) == 1 && modbus_read_registers(ctx, 62, 1, v) == 1 &&
               v[0] == 6200 + unit,
           "unit %d: a write read back", unit);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void across(int unit, int secs)
{
    modbus_t *ctx = master(unit);
    uint16_t v[2];
    int rc;
    if (!EXPECT(ctx != NULL, "connect")) {
        return;
    }
    errno = 0;
    rc = modbus_read_registers(ctx, 10, 2, v);
    EXPECT(rc == -1 && errno == MODBUS_ENOBASE + MODBUS_EXCEPTION_GATEWAY_PATH,
           "before the reload: unit %d has no route, exception 0x0A (%s)", unit, mbt_errname(errno));
    printf("WAITING\n");
    fflush(stdout);
    sleep((unsigned) secs);
    rc = modbus_read_registers(ctx, 10, 2, v);
    EXPECT(rc == 2 && v[0] == 30 && v[1] == 33, "after the reload, on the same connection: unit %d answered (rc %d)",
           unit, rc);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void broadcast(int echo)
{
    modbus_t *ctx = master(0);
    uint16_t v = 0;
    int rc;
    if (!EXPECT(ctx != NULL, "connect")) {
        return;
    }
    modbus_set_response_timeout(ctx, 1, 0);
    errno = 0;
    rc = modbus_write_register(ctx, 200, (uint16_t) (777 + echo));
    if (echo) {
        EXPECT(rc == 1, "broadcast write with -b: the request echoed (rc %d, %s)", rc, mbt_errname(errno));
    } else {
        EXPECT(rc == -1 && errno == ETIMEDOUT, "broadcast write: no answer (rc %d, %s)", rc, mbt_errname(errno));
    }
    usleep(200000);
    modbus_set_slave(ctx, 1);
    modbus_flush(ctx);
    modbus_set_response_timeout(ctx, 5, 0);
    rc = modbus_read_registers(ctx, 200, 1, &v);
    EXPECT(rc == 1 && v == 777 + echo, "the device got the broadcast (register 200 = %d)", v);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void busy(void)
{
    struct sockaddr_in sa;
    uint8_t q[40 * 12], a[40 * 9];
    int s = socket(AF_INET, SOCK_STREAM, 0), i, got = 0, busy_n = 0;
    double t0;
    memset(&sa, 0, sizeof sa);
    sa.sin_family = AF_INET;
    sa.sin_port = htons((uint16_t) port);
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    for (i = 0; i < 40; i++) {
        uint8_t r[12] = {0, (uint8_t) i, 0, 0, 0, 6, 9, 3, 0, 0, 0, 1};
        memcpy(q + 12 * i, r, 12);
    }
    if (!EXPECT(connect(s, (struct sockaddr *) &sa, sizeof sa) == 0, "connect")) {
        close(s);
        return;
    }
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    t0 = ts.tv_sec + ts.tv_nsec / 1e9;
    send(s, q, sizeof q, 0);
    /* The refusals come before any answer of the line (each takes its timeouts). */
    for (;;) {
        struct pollfd p = {s, POLLIN, 0};
        ssize_t n;
        if (poll(&p, 1, 300) <= 0 || (n = recv(s, a + got, sizeof a - (size_t) got, 0)) <= 0) {
            break;
        }
        got += (int) n;
    }
    for (i = 0; i + 9 <= got; i += 9) {
        busy_n += a[i + 7] == 0x83 && a[i + 8] == MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY;
    }
    clock_gettime(CLOCK_MONOTONIC, &ts);
    EXPECT(busy_n == 24, "40 requests at once: 16 wait, 24 refused as busy (exception 0x06) at once (%d in %.2f s)",
           busy_n, ts.tv_sec + ts.tv_nsec / 1e9 - t0);
    close(s);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *) a, y = *(const double *) b;
    return (x > y) - (x < y);
}

static void hold(int n, int secs)
{
    modbus_t **c = calloc((size_t) n, sizeof *c);
    double *lat = calloc((size_t) n, sizeof *lat);
    int i, ok = 0;
    uint16_t v;
    for (i = 0; i < n; i++) {
        c[i] = master(1);
    }
    for (i = 0; i < n; i++) {
        struct timespec a, b;
        clock_gettime(CLOCK_MONOTONIC, &a);
        if (c[i] != NULL && modbus_read_registers(c[i], i % 100, 1, &v) == 1) {
            ok++;
        }
        clock_gettime(CLOCK_MONOTONIC, &b);
        lat[i] = (b.tv_sec - a.tv_sec) * 1e3 + (b.tv_nsec - a.tv_nsec) / 1e6;
    }
    qsort(lat, (size_t) n, sizeof *lat, cmp_double);
    printf("# hold: %d masters, %d answered, latency p50 %.2f ms, p99 %.2f ms, max %.2f ms\n", n, ok, lat[n / 2],
           lat[n * 99 / 100], lat[n - 1]);
    printf("HOLDING\n");
    fflush(stdout);
    sleep((unsigned) secs);
    for (i = 0; i < n; i++) {
        if (c[i] != NULL) {
            modbus_close(c[i]);
            modbus_free(c[i]);
        }
    }
    free(c);
    free(lat);
    EXPECT(ok == n, "%d masters answered (%d)", n, ok);
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: gw-check PORT calls|fair N SECS|leave|unit U EXC|held N\n");
        return 2;
    }
    print_loaded_libmodbus();
    port = atoi(argv[1]);
    if (strcmp(argv[2], "calls") == 0) {
        calls();
        return 0;
    } else if (strcmp(argv[2], "fair") == 0 && argc > 4) {
        fair(atoi(argv[3]), atoi(argv[4]));
    } else if (strcmp(argv[2], "leave") == 0) {
        leave();
    } else if (strcmp(argv[2], "unit") == 0 && argc > 4) {
        unit_exception(atoi(argv[3]), (int) strtol(argv[4], NULL, 16));
    } else if (strcmp(argv[2], "across") == 0 && argc > 4) {
        across(atoi(argv[3]), atoi(argv[4]));
    } else if (strcmp(argv[2], "broadcast") == 0 && argc > 3) {
        broadcast(atoi(argv[3]));
    } else if (strcmp(argv[2], "busy") == 0) {
        busy();
    } else if (strcmp(argv[2], "hold") == 0 && argc > 4) {
        hold(atoi(argv[3]), atoi(argv[4]));
    } else if (strcmp(argv[2], "reads") == 0 && argc > 3) {
        reads(atoi(argv[3]));
    } else if (strcmp(argv[2], "held") == 0 && argc > 3) {
        held(atoi(argv[3]));
    } else {
        fprintf(stderr, "unknown scenario %s\n", argv[2]);
        return 2;
    }
    return chk_summary();
}
