/*
 * fault-client: the client scenario of the fault-injection tests.
 *
 *   fault-client tcp PORT | rtu DEVICE
 *
 * Response timeout 300 ms, byte timeout 100 ms. Reads 10 holding registers four
 * times, at addresses 0 (tx 0, clean), 20 (tx A: the one the proxy faults), 40 (tx B)
 * and 60 (tx C). mb-server holds register i = 3*i, so every answer is checked: a stale
 * answer taken for the next one shows as data=WRONG. After a failure with ECONNRESET,
 * EPIPE or EBADF the client reconnects (modbus_close + modbus_connect), as an
 * application would. Prints one line per transaction:
 *
 *   TX <name> rc=<rc> errno=<NAME> ms=<elapsed> data=<ok|WRONG|->
 *
 * and "FDS before=<n> after=<n>" (open descriptors before modbus_new_* and after
 * modbus_free).
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

#include "../common/mbt-connect.h"
#include "../common/mbt-fds.h"

int print_loaded_libmodbus(void);

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

static const char *errname(int e)
{
    switch (e) {
    case 0: return "0";
    case ETIMEDOUT: return "ETIMEDOUT";
    case ECONNRESET: return "ECONNRESET";
    case EPIPE: return "EPIPE";
    case EBADF: return "EBADF";
    case EIO: return "EIO";
    case EMBBADCRC: return "EMBBADCRC";
    case EMBBADDATA: return "EMBBADDATA";
    case EMBBADEXC: return "EMBBADEXC";
    case EMBMDATA: return "EMBMDATA";
    case EMBBADSLAVE: return "EMBBADSLAVE";
    case EMBXILFUN: return "EMBXILFUN";
    case EMBXILADD: return "EMBXILADD";
    case EMBXILVAL: return "EMBXILVAL";
    default: {
        static char buf[32];
        snprintf(buf, sizeof(buf), "E%d", e);
        return buf;
    }
    }
}

static void tx(modbus_t *ctx, const char *name, int addr)
{
    uint16_t v[10];
    double t0 = now_ms();
    int rc, e, ok = 1;
    memset(v, 0xEE, sizeof(v));
    errno = 0;
    rc = modbus_read_registers(ctx, addr, 10, v);
    e = rc < 0 ? errno : 0;
    if (rc == 10) {
        for (int i = 0; i < 10; i++) {
            ok &= v[i] == (uint16_t) (3 * (addr + i));
        }
    }
    printf("TX %s rc=%d errno=%s ms=%.0f data=%s\n", name, rc, errname(e), now_ms() - t0,
           rc == 10 ? (ok ? "ok" : "WRONG") : "-");
    fflush(stdout);
    if (rc < 0 && (e == ECONNRESET || e == EPIPE || e == EBADF)) {
        modbus_close(ctx);
        if (modbus_connect(ctx) != 0) {
            printf("RECONNECT failed errno=%s\n", errname(errno));
        }
    }
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    int before, after;
    if (argc < 3) {
        fprintf(stderr, "usage: %s tcp PORT | rtu DEVICE\n", argv[0]);
        return 2;
    }
    before = mbt_count_fds();
    ctx = mbt_connect("fault-client", argv[1], argv[2]);
    if (ctx == NULL) {
        return 1;
    }
    modbus_set_response_timeout(ctx, 0, 300000);
    modbus_set_byte_timeout(ctx, 0, 100000);
    tx(ctx, "0", 0);
    tx(ctx, "A", 20);
    tx(ctx, "B", 40);
    tx(ctx, "C", 60);
    modbus_close(ctx);
    modbus_free(ctx);
    after = mbt_count_fds();
    printf("FDS before=%d after=%d\n", before, after);
    return 0;
}
