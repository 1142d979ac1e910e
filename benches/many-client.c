/*
 * many-client: polls N Modbus TCP devices (c-tests/event/sim-devices.c, each answering
 * a read of 10 registers after its delay) with one read per device and cycle, three
 * ways, and prints the median cycle time and the memory the process used:
 *
 *   many-client async   PORT N CYCLES   rsmodbus' event-driven client, one thread,
 *                                       one multi handle (needs rsmodbus)
 *   many-client serial  PORT N CYCLES   libmodbus' blocking calls, one thread, the
 *                                       devices in turn
 *   many-client threads PORT N CYCLES   libmodbus' blocking calls, one thread per
 *                                       device (a barrier per cycle)
 *
 * Output: "RESULT mode=... n=... cycles=... median_ms=... max_ms=... rss_kb=...
 * ok=... failed=... cpu_ms=..." (rss_kb: VmHWM, the peak resident set; cpu_ms: the
 * user and system CPU time of the process, all its threads, over the measured cycles
 * only). The library is whichever libmodbus.so.5 the loader finds (LIBINFO line
 * first); async looks its functions up with dlsym, so that the same binary runs on
 * Debian's libmodbus for the other modes.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <dlfcn.h>
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include <modbus.h>

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

static long peak_rss_kb(void)
{
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    long kb = -1;
    while (f != NULL && fgets(line, sizeof(line), f) != NULL) {
        if (strncmp(line, "VmHWM:", 6) == 0) {
            kb = atol(line + 6);
        }
    }
    if (f != NULL) {
        fclose(f);
    }
    return kb;
}

/* User plus system CPU time of the process (every thread) so far, in ms. */
static double cpu_now_ms(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) != 0) {
        return -1;
    }
    return (double) (ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) * 1e3 +
           (double) (ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) / 1e3;
}

/* The CPU time of the measured cycles: cpu_now_ms() before the first, after the last. */
static double cpu_ms;

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *) a, y = *(const double *) b;
    return (x > y) - (x < y);
}

static int ok_count, failed_count;

/* Device i's context, connected (2 s response timeout); NULL after printing why. */
static modbus_t *device(int port, int i)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    if (ctx != NULL) {
        modbus_set_response_timeout(ctx, 2, 0);
        if (modbus_connect(ctx) == 0) {
            return ctx;
        }
    }
    fprintf(stderr, "device %d: %s\n", i, modbus_strerror(errno));
    return NULL;
}

/* ---------------------------------------------------------------- async (rsmodbus) */
typedef void (*cb_t)(modbus_t *, int, int, int, void *);
static int left;
static void done(modbus_t *ctx, int id, int rc, int error, void *user)
{
    (void) ctx;
    (void) id;
    (void) error;
    (void) user;
    if (rc == 10) {
        ok_count++;
    } else {
        failed_count++;
    }
    left--;
}

static int run_async(int port, int n, int cycles, double *times)
{
    void *(*multi_new)(void) = (void *(*) (void)) dlsym(RTLD_DEFAULT, "modbus_multi_new");
    int (*multi_add)(void *, modbus_t *) = (int (*)(void *, modbus_t *)) dlsym(RTLD_DEFAULT, "modbus_multi_add");
    int (*multi_perform)(void *, int) = (int (*)(void *, int)) dlsym(RTLD_DEFAULT, "modbus_multi_perform");
    int (*read_async)(modbus_t *, int, int, uint16_t *, cb_t, void *) =
        (int (*)(modbus_t *, int, int, uint16_t *, cb_t, void *)) dlsym(RTLD_DEFAULT, "modbus_read_registers_async");
    if (multi_new == NULL || multi_add == NULL || multi_perform == NULL || read_async == NULL) {
        fprintf(stderr, "async needs rsmodbus\n");
        return 1;
    }
    void *m = multi_new();
    modbus_t **ctx = calloc((size_t) n, sizeof(*ctx));
    uint16_t(*regs)[10] = calloc((size_t) n, sizeof(*regs));
    for (int i = 0; i < n; i++) {
        if ((ctx[i] = device(port, i)) == NULL) {
            return 1;
        }
        if (multi_add(m, ctx[i]) != 0) {
            fprintf(stderr, "device %d: modbus_multi_add: %s\n", i, modbus_strerror(errno));
            return 1;
        }
    }
    cpu_ms = cpu_now_ms();
    for (int c = 0; c < cycles; c++) {
        double t0 = now_ms();
        for (int i = 0; i < n; i++) {
            if (read_async(ctx[i], 0, 10, regs[i], done, NULL) >= 0) {
                left++;
            }
        }
        while (left > 0) {
            multi_perform(m, -1);
        }
        times[c] = now_ms() - t0;
    }
    cpu_ms = cpu_now_ms() - cpu_ms;
    return 0;
}

/* ---------------------------------------------------------------- serial (libmodbus) */
static int run_serial(int port, int n, int cycles, double *times)
{
    modbus_t **ctx = calloc((size_t) n, sizeof(*ctx));
    uint16_t regs[10];
    for (int i = 0; i < n; i++) {
        if ((ctx[i] = device(port, i)) == NULL) {
            return 1;
        }
    }
    cpu_ms = cpu_now_ms();
    for (int c = 0; c < cycles; c++) {
        double t0 = now_ms();
        for (int i = 0; i < n; i++) {
            if (modbus_read_registers(ctx[i], 0, 10, regs) == 10) {
                ok_count++;
            } else {
                failed_count++;
            }
        }
        times[c] = now_ms() - t0;
    }
    cpu_ms = cpu_now_ms() - cpu_ms;
    return 0;
}

/* ---------------------------------------------------------------- threads (libmodbus) */
static pthread_barrier_t start_b, end_b;
static int cycles_g;
static pthread_mutex_t count_lock = PTHREAD_MUTEX_INITIALIZER;

static void *device_thread(void *arg)
{
    modbus_t *ctx = arg;
    uint16_t regs[10];
    for (int c = 0; c < cycles_g; c++) {
        pthread_barrier_wait(&start_b);
        int rc = modbus_read_registers(ctx, 0, 10, regs);
        pthread_mutex_lock(&count_lock);
        if (rc == 10) {
            ok_count++;
        } else {
            failed_count++;
        }
        pthread_mutex_unlock(&count_lock);
        pthread_barrier_wait(&end_b);
    }
    return NULL;
}

static int run_threads(int port, int n, int cycles, double *times)
{
    pthread_t *th = calloc((size_t) n, sizeof(*th));
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    /* 64 KiB stacks: what a careful thread-per-device poller would use. */
    pthread_attr_setstacksize(&attr, 64 * 1024);
    cycles_g = cycles;
    pthread_barrier_init(&start_b, NULL, (unsigned) n + 1);
    pthread_barrier_init(&end_b, NULL, (unsigned) n + 1);
    for (int i = 0; i < n; i++) {
        modbus_t *ctx = device(port, i);
        if (ctx == NULL) {
            return 1;
        }
        if (pthread_create(&th[i], &attr, device_thread, ctx) != 0) {
            fprintf(stderr, "device %d: pthread_create failed\n", i);
            return 1;
        }
    }
    cpu_ms = cpu_now_ms();
    for (int c = 0; c < cycles; c++) {
        double t0 = now_ms();
        pthread_barrier_wait(&start_b);
        pthread_barrier_wait(&end_b);
        times[c] = now_ms() - t0;
    }
    cpu_ms = cpu_now_ms() - cpu_ms;
    for (int i = 0; i < n; i++) {
        pthread_join(th[i], NULL);
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: %s async|serial|threads PORT N CYCLES\n", argv[0]);
        return 2;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);
    int port = atoi(argv[2]), n = atoi(argv[3]), cycles = atoi(argv[4]);
    double *times = calloc((size_t) cycles, sizeof(double));
    int rc = strcmp(argv[1], "async") == 0     ? run_async(port, n, cycles, times)
             : strcmp(argv[1], "serial") == 0  ? run_serial(port, n, cycles, times)
             : strcmp(argv[1], "threads") == 0 ? run_threads(port, n, cycles, times)
                                               : 2;
    if (rc != 0) {
        return rc;
    }
    double max = 0;
    for (int c = 0; c < cycles; c++) {
        max = times[c] > max ? times[c] : max;
    }
    qsort(times, (size_t) cycles, sizeof(double), cmp_double);
    printf("RESULT mode=%s n=%d cycles=%d median_ms=%.2f max_ms=%.2f rss_kb=%ld ok=%d failed=%d cpu_ms=%.0f\n", argv[1], n,
           cycles, times[cycles / 2], max, peak_rss_kb(), ok_count, failed_count, cpu_ms);
    return failed_count == 0 ? 0 : 1;
}
