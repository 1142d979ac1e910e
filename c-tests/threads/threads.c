/*
 * threads: N threads share ONE modbus_t (rsmodbus contexts lock a mutex per call, so
 * each transaction is atomic) and run M transactions each against our_server (the data
 * of c-tests/interop/pm_model.py). Every result is checked:
 *
 *   thread t owns holding registers 8t..8t+7 (t < 16) and nobody else writes them;
 *   cycle of 7 transactions, i = transaction number:
 *     0: write_and_read_registers: write 8t..8t+3 with values made of (t, i), read them
 *        back in the same transaction -> must equal what this thread wrote;
 *     1: read_registers at 130 + (3t + i) % 60, 1 + i % 5 values -> the model's values
 *        (each thread reads different addresses, so a response delivered to the wrong
 *        thread shows);
 *     2: write_register 8t + 4 + i % 4 with a value made of (t, i);
 *     3: read_registers 8t + 4 + i % 4 -> the value written by transaction 2;
 *     4: read_input_bits at 5t, 1 + i % 16 bits -> the model's values;
 *     5: diagnostics 00 (return query data) of one word made of (t, i) -> the same word;
 *     6: read_file_record of file 1 + t % 3 at a record made of (t, i), 1 + i % 8
 *        registers -> the model's values (the server runs with --configure).
 *
 * usage: threads TRANSPORT WHERE NTHREADS NTX [--race-selftest]   (TRANSPORT as in
 * io_new_ctx; --race-selftest: see race_selftest())
 * Prints "LOADED ...", per-thread errors, a summary line with transactions, seconds and
 * transactions per second, and "N passed, M failed" (one check per thread plus one for
 * the totals). A watchdog fails the run (exit 3) if no transaction completes for 30 s
 * (a deadlock or a lost response).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include "../interop/interop.h"

#include <pthread.h>
#include <stdatomic.h>
#include <time.h>
#include <unistd.h>

#define MAX_THREADS 16

static modbus_t *ctx;
static int ntx;
static atomic_long done_tx;
static atomic_int stop_watchdog;

struct worker {
    pthread_t tid;
    int t;
    long errors;
    long ok;
    double start, end;
    char first_error[256];
};

static double now_s(void);

static void note(struct worker *w, int i, const char *what, int rc)
{
    int e = errno;
    if (w->errors++ == 0) {
        snprintf(w->first_error, sizeof(w->first_error), "transaction %d (%s): rc %d errno %d (%s)",
                 i, what, rc, rc == -1 ? e : 0, rc == -1 ? modbus_strerror(e) : "wrong values");
    }
}

static void *work(void *arg)
{
    struct worker *w = arg;
    const int t = w->t;
    uint16_t regs[8], back[8];
    uint8_t bits[16];
    uint16_t last_written = 0;
    int last_addr = 0;

    w->start = now_s();
    for (int i = 0; i < ntx; i++) {
        int rc, good = 1;
        switch (i % 7) {
        case 0:
            for (int k = 0; k < 4; k++) {
                regs[k] = (uint16_t) ((t << 12) ^ (i * 4 + k));
            }
            rc = modbus_write_and_read_registers(ctx, 8 * t, 4, regs, 8 * t, 4, back);
            good = rc == 4 && memcmp(regs, back, 4 * sizeof(uint16_t)) == 0;
            if (!good) {
                note(w, i, "write_and_read_registers", rc);
            }
            break;
        case 1: {
            int at = 130 + (3 * t + i) % 60, nb = 1 + i % 5;
            rc = modbus_read_registers(ctx, at, nb, back);
            good = rc == nb;
            for (int k = 0; good && k < nb; k++) {
                good = back[k] == io_holding(at + k);
            }
            if (!good) {
                note(w, i, "read_registers", rc);
            }
            break;
        }
        case 2:
            last_addr = 8 * t + 4 + i % 4;
            last_written = (uint16_t) (0x8000 | (t << 10) | (i & 0x3FF));
            rc = modbus_write_register(ctx, last_addr, last_written);
            good = rc == 1;
            if (!good) {
                note(w, i, "write_register", rc);
            }
            break;
        case 3:
            rc = modbus_read_registers(ctx, last_addr, 1, back);
            good = rc == 1 && back[0] == last_written;
            if (!good) {
                note(w, i, "read back write_register", rc);
            }
            break;
        case 5: {
            uint16_t word = (uint16_t) ((t << 11) ^ i), echo = 0;
            rc = modbus_diagnostics(ctx, 0x00, &word, 1, &echo, 1);
            good = rc == 1 && echo == word;
            if (!good) {
                note(w, i, "diagnostics 00", rc);
            }
            break;
        }
        case 6: {
            int file = 1 + t % 3, record = (t * 500 + i) % 9000, nb = 1 + i % 8;
            rc = modbus_read_file_record(ctx, file, record, nb, back);
            good = rc == nb;
            for (int k = 0; good && k < nb; k++) {
                good = back[k] == io_file_reg(file, record + k);
            }
            if (!good) {
                note(w, i, "read_file_record", rc);
            }
            break;
        }
        default: {
            int nb = 1 + i % 16;
            rc = modbus_read_input_bits(ctx, 5 * t, nb, bits);
            good = rc == nb;
            for (int k = 0; good && k < nb; k++) {
                good = bits[k] == io_discrete(5 * t + k);
            }
            if (!good) {
                note(w, i, "read_input_bits", rc);
            }
            break;
        }
        }
        if (good) {
            w->ok++;
        }
        atomic_fetch_add(&done_tx, 1);
    }
    w->end = now_s();
    return NULL;
}

static void *watchdog(void *arg)
{
    long last = -1;
    int idle = 0;
    (void) arg;
    while (!atomic_load(&stop_watchdog)) {
        long now = atomic_load(&done_tx);
        idle = now == last ? idle + 1 : 0;
        last = now;
        if (idle >= 300) { /* 30 s */
            io_fail("watchdog", "no transaction completed for 30 s after %ld (deadlock or lost response)", now);
            io_summary();
            _exit(3);
        }
        usleep(100000);
    }
    return NULL;
}

/* --race-selftest: a race the USER makes on purpose (one thread rewrites the buffer that
 * another passes to modbus_write_registers). Under ThreadSanitizer it must be reported
 * with a frame inside libmodbus.so: proof that the library's accesses are instrumented,
 * so that silence in the real run means something. */
static uint16_t shared_src[4];
static atomic_int race_stop;

static void *race_writer(void *arg)
{
    (void) arg;
    for (unsigned v = 0; !atomic_load(&race_stop); v++) {
        for (int k = 0; k < 4; k++) {
            shared_src[k] = (uint16_t) (v + k); /* unsynchronised on purpose */
        }
    }
    return NULL;
}

static int race_selftest(void)
{
    pthread_t wr;
    pthread_create(&wr, NULL, race_writer, NULL);
    for (int i = 0; i < 200; i++) {
        modbus_write_registers(ctx, 0, 4, shared_src);
    }
    atomic_store(&race_stop, 1);
    pthread_join(wr, NULL);
    printf("race selftest done\n");
    return 0;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

int main(int argc, char **argv)
{
    static struct worker w[MAX_THREADS];
    pthread_t wd;
    int nthreads;
    long total_ok = 0, total_err = 0;
    double t0, secs;

    if (argc < 5) {
        fprintf(stderr, "usage: %s TRANSPORT WHERE NTHREADS NTX\n", argv[0]);
        return 2;
    }
    if (!io_print_loaded()) {
        fprintf(stderr, "not rsmodbus: contexts of other libraries are not thread-safe\n");
        return 97;
    }
    nthreads = atoi(argv[3]);
    ntx = atoi(argv[4]);
    if (nthreads < 1 || nthreads > MAX_THREADS || ntx < 1) {
        fprintf(stderr, "1 <= NTHREADS <= %d, NTX >= 1\n", MAX_THREADS);
        return 2;
    }
    ctx = io_new_ctx(argv[1], argv[2]);
    if (ctx == NULL) {
        return 2;
    }
    modbus_set_slave(ctx, IO_SLAVE);
    modbus_set_response_timeout(ctx, 5, 0);
    if (modbus_connect(ctx) == -1) {
        io_fail("connect", "%s", modbus_strerror(errno));
        return io_summary();
    }
    if (io_is_serial(argv[1])) {
        usleep(200000);
        modbus_flush(ctx);
    }
    if (argc > 5 && strcmp(argv[5], "--race-selftest") == 0) {
        return race_selftest();
    }
    pthread_create(&wd, NULL, watchdog, NULL);
    t0 = now_s();
    for (int t = 0; t < nthreads; t++) {
        w[t].t = t;
        if (pthread_create(&w[t].tid, NULL, work, &w[t]) != 0) {
            fprintf(stderr, "pthread_create failed\n");
            return 2;
        }
    }
    for (int t = 0; t < nthreads; t++) {
        pthread_join(w[t].tid, NULL);
    }
    secs = now_s() - t0;
    atomic_store(&stop_watchdog, 1);
    pthread_join(wd, NULL);

    for (int t = 0; t < nthreads; t++) {
        total_ok += w[t].ok;
        total_err += w[t].errors;
        if (w[t].errors == 0 && w[t].ok == ntx) {
            io_ok("thread results");
        } else {
            io_fail("thread results", "thread %d: %ld of %d wrong; first: %s", t, w[t].errors,
                    ntx, w[t].first_error);
        }
    }
    printf("%s: %d threads x %d transactions on one context: %ld correct, %ld wrong, "
           "%.2f s, %.0f transactions/s\n",
           argv[1], nthreads, ntx, total_ok, total_err, secs, (double) (total_ok + total_err) / secs);
    {
        /* the test means something only if the threads really ran at the same time:
         * the last one to start began before the first one to finish was done */
        double last_start = 0, first_end = 1e300;
        for (int t = 0; t < nthreads; t++) {
            last_start = w[t].start > last_start ? w[t].start : last_start;
            first_end = w[t].end < first_end ? w[t].end : first_end;
        }
        if (nthreads == 1 || last_start < first_end) {
            io_ok("all threads were running at the same time");
        } else {
            io_fail("all threads were running at the same time",
                    "a thread finished %.3f s before the last one started", last_start - first_end);
        }
    }
    if (total_ok == (long) nthreads * ntx && atomic_load(&done_tx) == total_ok) {
        io_ok("all transactions correct");
    } else {
        io_fail("all transactions correct", "%ld of %ld", total_ok, (long) nthreads * ntx);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    return io_summary();
}
