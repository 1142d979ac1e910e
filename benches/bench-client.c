/*
 * bench-client: runs one benchmark case against a Modbus server.
 *
 *   bench-client tcp PORT CASE (-n COUNT | -t SECONDS) [-w WARMUP]
 *   bench-client rtu DEVICE CASE (-n COUNT | -t SECONDS) [-w WARMUP]
 *
 * CASE: r125 (read 125 registers), c2000 (read 2000 coils), w123 (write 123
 * registers), wr121 (write 121 and read 125 registers, FC 23), r1 (read 1 register).
 * Prints "RESULT case=... tx=N secs=S tps=T errors=E max_ms=M" (M: the slowest
 * transaction of a timed run). Exits 1 on any failed
 * transaction (a benchmark that fails is not a result).
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

int print_loaded_libmodbus(void);

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

static uint16_t regs[256], wregs[256];
static uint8_t bits[2048];

static int one(modbus_t *ctx, const char *c)
{
    if (strcmp(c, "r125") == 0) {
        return modbus_read_registers(ctx, 0, 125, regs) == 125 ? 0 : -1;
    }
    if (strcmp(c, "c2000") == 0) {
        return modbus_read_bits(ctx, 0, 2000, bits) == 2000 ? 0 : -1;
    }
    if (strcmp(c, "w123") == 0) {
        return modbus_write_registers(ctx, 0, 123, wregs) == 123 ? 0 : -1;
    }
    if (strcmp(c, "wr121") == 0) {
        return modbus_write_and_read_registers(ctx, 0, 121, wregs, 0, 125, regs) == 125 ? 0 : -1;
    }
    if (strcmp(c, "r1") == 0) {
        return modbus_read_registers(ctx, 0, 1, regs) == 1 ? 0 : -1;
    }
    fprintf(stderr, "unknown case %s\n", c);
    exit(2);
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    long count = 0, warmup = 100, tx = 0, i;
    double seconds = 0, t0, t1, max_lat = 0;
    const char *cs;
    int opt;

    if (argc < 4) {
        fprintf(stderr, "usage: %s tcp PORT|rtu DEVICE CASE (-n COUNT | -t SECONDS) [-w WARMUP]\n", argv[0]);
        return 2;
    }
    cs = argv[3];
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
    ctx = mbt_connect("bench-client", argv[1], argv[2]);
    if (ctx == NULL) {
        return 1;
    }
    modbus_set_response_timeout(ctx, 2, 0);
    for (i = 0; i < warmup; i++) {
        if (one(ctx, cs) != 0) {
            fprintf(stderr, "bench-client: warm-up transaction %ld: %s\n", i, modbus_strerror(errno));
            return 1;
        }
    }
    t0 = now();
    t1 = t0;
    if (count > 0) {
        /* Fixed count (syscall, instruction and allocation counts): no clock reads. */
        for (tx = 0; tx < count; tx++) {
            if (one(ctx, cs) != 0) {
                fprintf(stderr, "bench-client: transaction %ld: %s\n", tx, modbus_strerror(errno));
                return 1;
            }
        }
    } else {
        double prev = t0;
        while (t1 - t0 < seconds) {
            if (one(ctx, cs) != 0) {
                fprintf(stderr, "bench-client: transaction %ld: %s\n", tx, modbus_strerror(errno));
                return 1;
            }
            tx++;
            t1 = now();
            if (t1 - prev > max_lat) {
                max_lat = t1 - prev;
            }
            prev = t1;
        }
    }
    t1 = now();
    printf("RESULT case=%s tx=%ld secs=%.4f tps=%.1f errors=0 max_ms=%.3f\n", cs, tx, t1 - t0, (double) tx / (t1 - t0),
           max_lat * 1e3);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
