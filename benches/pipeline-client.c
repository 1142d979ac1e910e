/*
 * pipeline-client: reads 10 holding registers from a Modbus TCP server (benches/
 * mb-server.c) over one connection, as fast as it answers, two ways:
 *
 *   pipeline-client [-n COUNT] [-w WARMUP] HOST PORT async DEPTH [SECONDS]
 *       rsmodbus' event-driven client: one context, modbus_set_max_in_flight(DEPTH),
 *       DEPTH requests outstanding at all times (each callback submits the next
 *       one), driven by poll() on what modbus_get_pollfd() names (needs rsmodbus)
 *   pipeline-client [-n COUNT] [-w WARMUP] HOST PORT blocking [SECONDS]
 *       modbus_read_registers() in a loop (any libmodbus)
 *
 * First WARMUP transactions (default 20), then the measured ones: for SECONDS
 * (default 5) or, with -n, exactly COUNT of them (for counts per transaction: two
 * runs of COUNT and 2 x COUNT differ by COUNT transactions and nothing else).
 * Request k reads 10 registers at address k mod 247; each answer is checked against
 * mb-server's map (holding register i holds 3 x i), so that an answer matched to the
 * wrong request of a pipeline counts as failed. Prints the LIBINFO line (which
 * libmodbus.so.5 was loaded, c-tests/common/libinfo.c) and
 *
 *   RESULT mode=M depth=D tx=N seconds=S tx_per_s=T failed=F polls=P processes=Q batches=B
 *
 * tx: transactions answered correctly in the measured part (timed async: those
 * completed when the time was up, over that time; the requests then outstanding
 * are still checked, not counted); failed: the others (errors, wrong values);
 * polls: poll() calls; processes: modbus_process() calls; batches: the calls that
 * completed at least one request (these three for the whole measured part;
 * blocking: 0). Exits 1 if any transaction failed. The async functions are not in Debian's
 * libmodbus: they are looked up with dlsym, so that one binary runs on both.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#define NB 10          /* registers per read */
#define ADDRESSES 247  /* request k reads at k mod 247: the last one ends at 256 */

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

/* mb-server's holding register i holds 3 x i. */
static int values_ok(const uint16_t *regs, int addr)
{
    for (int i = 0; i < NB; i++) {
        if (regs[i] != (uint16_t) ((addr + i) * 3)) {
            return 0;
        }
    }
    return 1;
}

static long ok_count, failed_count;
static long next_seq; /* the sequence number of the next request */

static void report_failure(int addr, int rc, int error, const uint16_t *regs)
{
    if (failed_count <= 5) {
        if (rc == -1) {
            fprintf(stderr, "pipeline-client: read at %d: %s\n", addr, modbus_strerror(error));
        } else {
            fprintf(stderr, "pipeline-client: read at %d: rc %d, first value %u (expected %u)\n", addr, rc,
                    regs[0], (unsigned) (addr * 3));
        }
    }
}

/* ------------------------------------------------------------------ async (rsmodbus) */
typedef void (*callback_fn)(modbus_t *, int, int, int, void *);
static int (*read_async)(modbus_t *, int, int, uint16_t *, callback_fn, void *);
static int (*get_pollfd)(modbus_t *, struct pollfd *, int *);
static int (*process)(modbus_t *, short);
static int (*set_max_in_flight)(modbus_t *, int);

/* One outstanding request: where its answer goes and what it asked. */
struct slot {
    uint16_t regs[NB];
    int addr;
};

static long submit_limit;  /* submit no more than this many in the current part */
static long submitted;     /* submitted in the current part */
static int stopping;       /* timed part over: submit nothing more */
static int outstanding;    /* submitted, callback not run yet */

static void done(modbus_t *ctx, int id, int rc, int error, void *user);

/* Submits the next request into slot `s`, unless the part is over. */
static void submit(modbus_t *ctx, struct slot *s)
{
    if (stopping || submitted >= submit_limit) {
        return;
    }
    s->addr = (int) (next_seq++ % ADDRESSES);
    /* No valid answer holds 0xffff: stale values cannot pass the check. */
    memset(s->regs, 0xff, sizeof(s->regs));
    if (read_async(ctx, s->addr, NB, s->regs, done, s) < 0) {
        fprintf(stderr, "pipeline-client: modbus_read_registers_async: %s\n", modbus_strerror(errno));
        exit(1);
    }
    submitted++;
    outstanding++;
}

/* A request completed: check it, count it, and put the next one in its place. */
static void done(modbus_t *ctx, int id, int rc, int error, void *user)
{
    struct slot *s = user;
    (void) id;
    outstanding--;
    if (rc == NB && values_ok(s->regs, s->addr)) {
        ok_count++;
    } else {
        failed_count++;
        report_failure(s->addr, rc, error, s->regs);
    }
    submit(ctx, s);
}

struct loop_counts {
    long polls, processes, batches;
    long stop_ok;     /* timed part: transactions answered correctly when time was up */
    double stop_time; /* and that time */
};

/* One part: `limit` requests (LONG_MAX: until `end`), `depth` outstanding, run
 * until every one has completed. */
static void run_async_part(modbus_t *ctx, struct slot *slots, int depth, long limit, double end,
                           struct loop_counts *n)
{
    submit_limit = limit;
    submitted = 0;
    stopping = 0;
    for (int i = 0; i < depth; i++) {
        submit(ctx, &slots[i]);
    }
    while (outstanding > 0) {
        struct pollfd pfd;
        int timeout, ready = 0;
        if (get_pollfd(ctx, &pfd, &timeout) < 0) {
            fprintf(stderr, "pipeline-client: modbus_get_pollfd: %s\n", modbus_strerror(errno));
            exit(1);
        }
        /* timeout 0: modbus_process is due now (e.g. requests queued by the
         * callbacks wait to be written, or answers already read wait): no wait. */
        if (timeout != 0) {
            n->polls++;
            ready = poll(&pfd, pfd.fd >= 0 ? 1 : 0, timeout);
            if (ready < 0 && errno != EINTR) {
                perror("pipeline-client: poll");
                exit(1);
            }
        }
        n->processes++;
        int completed = process(ctx, ready > 0 ? pfd.revents : 0);
        if (completed < 0) {
            fprintf(stderr, "pipeline-client: modbus_process: %s\n", modbus_strerror(errno));
            exit(1);
        }
        if (completed > 0) {
            n->batches++;
        }
        if (!stopping && limit == LONG_MAX) {
            double t = now_s();
            if (t >= end) {
                /* Time is up: what completed so far is the result; the requests
                 * still outstanding are checked as they complete, not counted (the
                 * end of a pipeline that is no longer refilled is not its rate). */
                stopping = 1;
                n->stop_ok = ok_count;
                n->stop_time = t;
            }
        }
    }
}

static int run_async(modbus_t *ctx, int depth, long count, long warmup, double seconds, double *elapsed,
                     struct loop_counts *n)
{
    read_async = (int (*)(modbus_t *, int, int, uint16_t *, callback_fn, void *)) dlsym(
        RTLD_DEFAULT, "modbus_read_registers_async");
    get_pollfd = (int (*)(modbus_t *, struct pollfd *, int *)) dlsym(RTLD_DEFAULT, "modbus_get_pollfd");
    process = (int (*)(modbus_t *, short)) dlsym(RTLD_DEFAULT, "modbus_process");
    set_max_in_flight = (int (*)(modbus_t *, int)) dlsym(RTLD_DEFAULT, "modbus_set_max_in_flight");
    if (read_async == NULL || get_pollfd == NULL || process == NULL || set_max_in_flight == NULL) {
        fprintf(stderr, "pipeline-client: async needs rsmodbus (its functions are not in this library)\n");
        return 2;
    }
    if (set_max_in_flight(ctx, depth) != 0) {
        fprintf(stderr, "pipeline-client: modbus_set_max_in_flight(%d): %s\n", depth, modbus_strerror(errno));
        return 1;
    }
    struct slot *slots = calloc((size_t) depth, sizeof(*slots));
    struct loop_counts warm = {0, 0, 0, 0, 0};
    if (slots == NULL) {
        return 1;
    }
    run_async_part(ctx, slots, depth, warmup, 0, &warm);
    ok_count = failed_count = 0;
    double t0 = now_s();
    run_async_part(ctx, slots, depth, count > 0 ? count : LONG_MAX, t0 + seconds, n);
    *elapsed = now_s() - t0;
    if (count <= 0) {
        ok_count = n->stop_ok;
        *elapsed = n->stop_time - t0;
    }
    free(slots);
    return 0;
}

/* ------------------------------------------------------------ blocking (any libmodbus) */
static void blocking_one(modbus_t *ctx)
{
    uint16_t regs[NB];
    int addr = (int) (next_seq++ % ADDRESSES);
    memset(regs, 0xff, sizeof(regs));
    int rc = modbus_read_registers(ctx, addr, NB, regs);
    if (rc == NB && values_ok(regs, addr)) {
        ok_count++;
    } else {
        failed_count++;
        report_failure(addr, rc, errno, regs);
    }
}

static int run_blocking(modbus_t *ctx, long count, long warmup, double seconds, double *elapsed)
{
    for (long i = 0; i < warmup; i++) {
        blocking_one(ctx);
    }
    ok_count = failed_count = 0;
    double t0 = now_s(), end = t0 + seconds;
    if (count > 0) {
        for (long i = 0; i < count; i++) {
            blocking_one(ctx);
        }
    } else {
        /* The clock is read every 16 transactions. */
        for (long i = 1;; i++) {
            blocking_one(ctx);
            if ((i & 15) == 0 && now_s() >= end) {
                break;
            }
        }
    }
    *elapsed = now_s() - t0;
    return 0;
}

static int usage(const char *argv0)
{
    fprintf(stderr,
            "usage: %s [-n COUNT] [-w WARMUP] HOST PORT async DEPTH [SECONDS]\n"
            "       %s [-n COUNT] [-w WARMUP] HOST PORT blocking [SECONDS]\n",
            argv0, argv0);
    return 2;
}

int main(int argc, char **argv)
{
    const char *prog = argv[0];
    long count = 0, warmup = 20;
    int opt;
    /* '+': options only before HOST. */
    while ((opt = getopt(argc, argv, "+n:w:")) != -1) {
        switch (opt) {
        case 'n': count = atol(optarg); break;
        case 'w': warmup = atol(optarg); break;
        default: return usage(prog);
        }
    }
    argv += optind;
    argc -= optind;
    if (argc < 3) {
        return usage(prog);
    }
    const char *host = argv[0], *mode = argv[2];
    int port = atoi(argv[1]), is_async = strcmp(mode, "async") == 0, depth = 1;
    if (is_async) {
        if (argc < 4 || (depth = atoi(argv[3])) < 1) {
            return usage(prog);
        }
    } else if (strcmp(mode, "blocking") != 0) {
        return usage(prog);
    }
    int secs_arg = is_async ? 4 : 3;
    double seconds = argc > secs_arg ? atof(argv[secs_arg]) : 5.0;
    setvbuf(stdout, NULL, _IOLBF, 0);

    modbus_t *ctx = modbus_new_tcp(host, port);
    if (ctx == NULL) {
        fprintf(stderr, "pipeline-client: modbus_new_tcp: %s\n", modbus_strerror(errno));
        return 1;
    }
    /* Long enough for a loaded machine and the delay proxy. */
    modbus_set_response_timeout(ctx, 5, 0);
    if (modbus_connect(ctx) != 0) {
        fprintf(stderr, "pipeline-client: connect %s:%d: %s\n", host, port, modbus_strerror(errno));
        return 1;
    }
    double elapsed = 0;
    struct loop_counts n = {0, 0, 0, 0, 0};
    int rc = is_async ? run_async(ctx, depth, count, warmup, seconds, &elapsed, &n)
                      : run_blocking(ctx, count, warmup, seconds, &elapsed);
    if (rc != 0) {
        return rc;
    }
    printf("RESULT mode=%s depth=%d tx=%ld seconds=%.4f tx_per_s=%.1f failed=%ld polls=%ld processes=%ld "
           "batches=%ld\n",
           mode, depth, ok_count, elapsed, (double) ok_count / elapsed, failed_count, n.polls, n.processes,
           n.batches);
    modbus_close(ctx);
    modbus_free(ctx);
    return failed_count == 0 ? 0 : 1;
}
