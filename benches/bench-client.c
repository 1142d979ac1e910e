/*
 * bench-client: runs one benchmark case against a Modbus server.
 *
 *   bench-client tcp PORT CASE (-n COUNT | -t SECONDS) [-w WARMUP]
 *   bench-client rtu DEVICE CASE (-n COUNT | -t SECONDS) [-w WARMUP]
 *   bench-client tls PORT CASE ...  Modbus/TCP Security (rsmodbus only; certificates
 *                                   from MB_TLS_CA, MB_TLS_CERT, MB_TLS_KEY)
 *
 * CASE: r125 (read 125 registers), c2000 (read 2000 coils), w123 (write 123
 * registers), wr121 (write 121 and read 125 registers, FC 23), r1 (read 1 register);
 * conn: a new connection per transaction (close, connect, read 1 register; over TLS
 * the handshake resumes the session of the connection before), conn-full (TLS only):
 * the same with a full handshake every time (a TLS setting set again, to its own
 * value, drops the context's configurations and with them the session to resume).
 * Prints "RESULT case=... tx=N secs=S tps=T errors=0". Exits 1 on any failed
 * transaction (a benchmark that fails is not a result). With BENCH_COUNTER set, a
 * timed run takes part in an interleaved measurement (bench-counter.h).
 * With MB_MARK_SETUP set, it calls getppid() once its connection is set up and the
 * warm-up done: the mark after which benches/bench.py counts the system calls.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../c-tests/common/mbt-connect.h"
#include "bench-counter.h"

int print_loaded_libmodbus(void);

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

static uint16_t regs[256], wregs[256];
static uint8_t bits[2048];

/* One function per case, chosen once: the timed loop does per transaction only what
 * the floor's does (the transaction, a counter, a clock read every 32). */
typedef int (*case_fn)(modbus_t *ctx);

static int r125(modbus_t *ctx)
{
    return modbus_read_registers(ctx, 0, 125, regs) == 125 ? 0 : -1;
}

static int c2000(modbus_t *ctx)
{
    return modbus_read_bits(ctx, 0, 2000, bits) == 2000 ? 0 : -1;
}

static int w123(modbus_t *ctx)
{
    return modbus_write_registers(ctx, 0, 123, wregs) == 123 ? 0 : -1;
}

static int wr121(modbus_t *ctx)
{
    return modbus_write_and_read_registers(ctx, 0, 121, wregs, 0, 125, regs) == 125 ? 0 : -1;
}

static int r1(modbus_t *ctx)
{
    return modbus_read_registers(ctx, 0, 1, regs) == 1 ? 0 : -1;
}

/* A new connection for one transaction. */
static int conn(modbus_t *ctx)
{
    modbus_close(ctx);
    return modbus_connect(ctx) == 0 ? r1(ctx) : -1;
}

/* The same over TLS, with no session to resume. */
static int conn_full(modbus_t *ctx)
{
    static const struct mbt_tls_api *tls;
    if (tls == NULL && (tls = mbt_tls_api("bench-client")) == NULL) {
        return -1;
    }
    modbus_close(ctx);
    if (tls->set_min_version(ctx, 0x0303 /* MODBUS_TLS_1_2, the default */) != 0) {
        return -1;
    }
    return modbus_connect(ctx) == 0 ? r1(ctx) : -1;
}

static case_fn case_named(const char *c)
{
    static const struct {
        const char *name;
        case_fn fn;
    } cases[] = {{"r125", r125}, {"c2000", c2000}, {"w123", w123}, {"wr121", wr121}, {"r1", r1},
                 {"conn", conn}, {"conn-full", conn_full}};
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        if (strcmp(c, cases[i].name) == 0) {
            return cases[i].fn;
        }
    }
    return NULL;
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    long count = 0, warmup = 100, tx = 0, i;
    double seconds = 0, t0, t1;
    const char *cs;
    case_fn one;
    int opt;
    volatile uint64_t *counter = bench_counter_open();

    if (argc < 4) {
        fprintf(stderr, "usage: %s tcp|tls PORT|rtu DEVICE CASE (-n COUNT | -t SECONDS) [-w WARMUP]\n", argv[0]);
        return 2;
    }
    cs = argv[3];
    one = case_named(cs);
    if (one == NULL) {
        fprintf(stderr, "unknown case %s\n", cs);
        return 2;
    }
    optind = 4;
    while ((opt = getopt(argc, argv, "n:t:w:")) != -1) {
        switch (opt) {
        case 'n': count = atol(optarg); break;
        case 't': seconds = atof(optarg); break;
        case 'w': warmup = atol(optarg); break;
        default: return 2;
        }
    }
    for (i = 0; i < 256; i++) {
        wregs[i] = (uint16_t) (i * 3);
    }
    if (one == conn_full && strcmp(argv[1], "tls") != 0) {
        fprintf(stderr, "conn-full: TLS only\n");
        return 2;
    }
    /* Long enough for the pauses of an interleaved measurement, and for a TLS
     * handshake with a server under valgrind. */
    ctx = mbt_connect_within("bench-client", argv[1], argv[2], 10);
    if (ctx == NULL) {
        return 1;
    }
    if (getenv("MB_DEBUG") != NULL) {
        modbus_set_debug(ctx, TRUE);
    }
    for (i = 0; i < warmup; i++) {
        if (one(ctx) != 0) {
            fprintf(stderr, "bench-client: warm-up transaction %ld: %s\n", i, modbus_strerror(errno));
            return 1;
        }
    }
    if (getenv("MB_MARK_SETUP") != NULL) {
        /* Set up and warmed up: benches/bench.py counts the system calls after this mark
         * (the transactions and the exit). Over TLS, the first read also takes the
         * server's session tickets, in one recv or, when they came alone, two and a
         * wait: that is the warm-up's. */
        (void) getppid();
    }
    t0 = now();
    t1 = t0;
    if (count > 0) {
        /* Fixed count (syscall, instruction and allocation counts): no clock reads. */
        for (tx = 0; tx < count; tx++) {
            if (one(ctx) != 0) {
                fprintf(stderr, "bench-client: transaction %ld: %s\n", tx, modbus_strerror(errno));
                return 1;
            }
        }
    } else {
        /* The clock is read every 32 transactions, as in bench-floor. */
        while (t1 - t0 < seconds) {
            if (one(ctx) != 0) {
                fprintf(stderr, "bench-client: transaction %ld: %s\n", tx, modbus_strerror(errno));
                return 1;
            }
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
    }
    t1 = now();
    printf("RESULT case=%s tx=%ld secs=%.4f tps=%.1f errors=0\n", cs, tx, t1 - t0, (double) tx / (t1 - t0));
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
