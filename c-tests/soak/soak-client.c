/*
 * soak-client: many verified transactions against mb-server.
 *
 *   soak-client tcp PORT COUNT | rtu DEVICE COUNT
 *
 * Cycles through write registers, read registers, write and read registers (FC 23),
 * write coils, read coils, read input registers and write one register, each checked
 * against what was written (or against mb-server's fixed input values). Prints
 * "PROGRESS <n>" every COUNT/50 transactions, and "DONE tx=<n> errors=<e>" at the end.
 * Exits 1 on the first failure.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <modbus.h>

#include "../common/mbt-connect.h"

int print_loaded_libmodbus(void);

static int fail(long i, const char *what)
{
    fprintf(stderr, "soak-client: transaction %ld (%s): %s\n", i, what, modbus_strerror(errno));
    return 1;
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    long count, i, step;
    uint16_t w[128], r[128];
    uint8_t wb[256], rb[256];

    if (argc < 4) {
        fprintf(stderr, "usage: %s tcp PORT COUNT | rtu DEVICE COUNT\n", argv[0]);
        return 2;
    }
    count = atol(argv[3]);
    step = count / 50 > 0 ? count / 50 : 1;
    ctx = mbt_connect("soak-client", argv[1], argv[2]);
    if (ctx == NULL) {
        return 1;
    }
    modbus_set_response_timeout(ctx, 2, 0);
    for (i = 0; i < count; i++) {
        int k = (int) (i % 7), addr = (int) (i % 100), n = 1 + (int) (i % 120), j;
        for (j = 0; j < n; j++) {
            w[j] = (uint16_t) (i * 31 + j);
            wb[j] = (uint8_t) ((i + j) % 3 == 0);
        }
        switch (k) {
        case 0:
            if (modbus_write_registers(ctx, addr, n, w) != n) return fail(i, "write registers");
            break;
        case 1:
            if (modbus_write_registers(ctx, addr, n, w) != n) return fail(i, "write registers");
            if (modbus_read_registers(ctx, addr, n, r) != n) return fail(i, "read registers");
            if (memcmp(w, r, (size_t) n * 2) != 0) { errno = EMBBADDATA; return fail(i, "read back registers"); }
            break;
        case 2:
            if (n > 121) n = 121;
            if (modbus_write_and_read_registers(ctx, addr, n, w, addr, n, r) != n) return fail(i, "write and read");
            if (memcmp(w, r, (size_t) n * 2) != 0) { errno = EMBBADDATA; return fail(i, "write and read data"); }
            break;
        case 3:
            if (modbus_write_bits(ctx, addr, n, wb) != n) return fail(i, "write bits");
            if (modbus_read_bits(ctx, addr, n, rb) != n) return fail(i, "read bits");
            if (memcmp(wb, rb, (size_t) n) != 0) { errno = EMBBADDATA; return fail(i, "read back bits"); }
            break;
        case 4:
            if (modbus_read_input_registers(ctx, addr, n, r) != n) return fail(i, "read input registers");
            for (j = 0; j < n; j++) {
                if (r[j] != (uint16_t) ((addr + j) * 7)) { errno = EMBBADDATA; return fail(i, "input register value"); }
            }
            break;
        case 5:
            if (modbus_write_register(ctx, addr, (uint16_t) i) != 1) return fail(i, "write register");
            break;
        default:
            if (modbus_read_input_bits(ctx, addr, 2 * n, rb) != 2 * n) return fail(i, "read input bits");
            for (j = 0; j < 2 * n; j++) {
                if (rb[j] != ((addr + j) % 5 == 0)) { errno = EMBBADDATA; return fail(i, "input bit value"); }
            }
            break;
        }
        if ((i + 1) % step == 0) {
            printf("PROGRESS %ld\n", i + 1);
            fflush(stdout);
        }
    }
    printf("DONE tx=%ld errors=0\n", count);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
