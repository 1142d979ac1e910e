/*
 * mutex_cost: what the per-context mutex costs a single-threaded program. A measurement
 * to report, not a pass/fail test. Run it once with our library and once with Debian's
 * (whose contexts have no lock); the difference is our lock plus our call shim.
 *
 *   1. ns per modbus_get_slave() call (ours: lock, read a field, unlock), best of 5
 *      rounds of 5,000,000 calls;
 *   2. us per modbus_read_registers() transaction over loopback TCP against a server
 *      (our_server), best of 3 rounds of NTX transactions, one thread.
 *
 * usage: mutex_cost PORT [NTX]   (server on 127.0.0.1:PORT; NTX default 20000)
 * Prints "LOADED ..." and "RESULT lib=<ours|debian> call_ns=<..> txn_us=<..>".
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include "../interop/interop.h"

#include <time.h>

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

int main(int argc, char **argv)
{
    int ours, ntx;
    modbus_t *ctx;
    double best_call = 1e9, best_txn = 1e9;
    volatile int sink = 0;
    uint16_t reg[1];

    if (argc < 2) {
        fprintf(stderr, "usage: %s PORT [NTX]\n", argv[0]);
        return 2;
    }
    ntx = argc > 2 ? atoi(argv[2]) : 20000;
    ours = io_print_loaded();
    ctx = modbus_new_tcp("127.0.0.1", atoi(argv[1]));
    if (ctx == NULL) {
        return 2;
    }
    modbus_set_slave(ctx, IO_SLAVE);
    for (int round = 0; round < 5; round++) {
        const int n = 5000000;
        double t0 = now_s(), dt;
        for (int i = 0; i < n; i++) {
            sink += modbus_get_slave(ctx);
        }
        dt = (now_s() - t0) * 1e9 / n;
        best_call = dt < best_call ? dt : best_call;
    }
    if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "connect: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (int round = 0; round < 3; round++) {
        double t0 = now_s(), dt;
        for (int i = 0; i < ntx; i++) {
            if (modbus_read_registers(ctx, 150, 1, reg) != 1 || reg[0] != io_holding(150)) {
                fprintf(stderr, "transaction %d failed: %s\n", i, modbus_strerror(errno));
                return 1;
            }
        }
        dt = (now_s() - t0) * 1e6 / ntx;
        best_txn = dt < best_txn ? dt : best_txn;
    }
    printf("RESULT lib=%s call_ns=%.1f txn_us=%.2f\n", ours ? "ours" : "debian", best_call,
           best_txn);
    modbus_close(ctx);
    modbus_free(ctx);
    return sink == -1;
}
