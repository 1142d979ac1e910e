/*
 * tls-load.c: well-behaved Modbus/TCP Security clients for benches/server-many.sh:
 * N clients, each its own rsmodbus context (modbus_new_tcp_tls, the client
 * certificate given), all driven from one thread by the event-driven client (a
 * multi handle, modbus_multi_new(3)), each reading 10 holding registers from address
 * 0 in a closed loop: the next request is submitted from the callback of the last.
 * One thread, so that the latency measured is the server's and the wire's, not the
 * wait of one of N client threads for a CPU (on 2 CPUs shared with the server, a
 * thread per client made p99 move by 20-40% from one second to the next).
 *
 *   tls-load [-n N] [-d SECS] [-w SECS] [-b BASE] [-o FILE] CA CERT KEY PORT
 *     -n N      clients (20)
 *     -d SECS   measured duration (2.5)
 *     -w SECS   warm-up before it, not counted (0.5): the handshakes happen there
 *     -b BASE   holding register i holds BASE + i (0; examples/tls-server.c: 1000)
 *     -o FILE   also write the latency histogram there ("µs count" lines)
 *
 * A context connects (and does its handshake) when its first request waits; the
 * response timeout is 2 s, so that a server that stalls shows as errors and long
 * latencies rather than as a hang; a failed request counts an error and the next
 * one is submitted (the context connects again if it must). Latency: from the
 * submission of each read to its callback with the right values, CLOCK_MONOTONIC, in
 * a histogram (1 µs steps up to 100 ms, 1 ms steps above). Prints
 *   RESULT clients=N connected=C tx=T seconds=S tps=R p50_us=.. p99_us=.. max_us=..
 *          errors=E connect_max_ms=M
 * connected: the clients that had an answer during the measurement; connect_max_ms:
 * the longest wait for a client's first answer (its connect and handshake
 * included). The program ends when the measurement does, whatever is in flight.
 *
 * Prints the library it loaded first (LIBINFO). Built against our include/ and
 * linked to our library (Debian's has neither TLS nor the event-driven client).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

int print_loaded_libmodbus(void); /* c-tests/common/libinfo.c: the LIBINFO line */

#include "latency-hist.h"

struct client {
    modbus_t *ctx;
    uint16_t regs[10];
    uint64_t sent_ns;
    uint64_t first_ns; /* when its first request was submitted */
    int answered;      /* answers during the measurement */
    int got_first;
};

static uint64_t errors, connect_max_ns;
static uint64_t t_start, t_end;
static int base;

static uint64_t now_ns(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t) t.tv_sec * 1000000000u + (uint64_t) t.tv_nsec;
}

static void done(modbus_t *ctx, int id, int rc, int error, void *user_data);

static void submit(struct client *c)
{
    c->sent_ns = now_ns();
    if (modbus_read_registers_async(c->ctx, 0, 10, c->regs, done, c) == -1) {
        fprintf(stderr, "tls-load: submit: %s\n", modbus_strerror(errno));
        exit(1);
    }
}

static void done(modbus_t *ctx, int id, int rc, int error, void *user_data)
{
    struct client *c = user_data;
    uint64_t t = now_ns();
    int i, ok = rc == 10;
    (void) ctx;
    (void) id;
    (void) error;
    for (i = 0; ok && i < 10; i++) {
        ok = c->regs[i] == base + i;
    }
    if (!ok) {
        errors++;
    } else {
        if (!c->got_first) {
            c->got_first = 1;
            if (t - c->first_ns > connect_max_ns) {
                connect_max_ns = t - c->first_ns;
            }
        }
        if (c->sent_ns >= t_start && t < t_end) {
            record(t - c->sent_ns);
            c->answered++;
        }
    }
    if (t < t_end) {
        submit(c);
    }
}

int main(int argc, char **argv)
{
    const char *hist_file = NULL;
    int n = 20, opt, i, connected = 0;
    double secs = 2.5, warm = 0.5;
    struct client *c;
    modbus_multi_t *m;

    while ((opt = getopt(argc, argv, "n:d:w:b:o:")) != -1) {
        switch (opt) {
        case 'n': n = atoi(optarg); break;
        case 'd': secs = atof(optarg); break;
        case 'w': warm = atof(optarg); break;
        case 'b': base = atoi(optarg); break;
        case 'o': hist_file = optarg; break;
        default: n = 0;
        }
    }
    if (argc - optind != 4 || n < 1) {
        fprintf(stderr, "usage: tls-load [-n N] [-d SECS] [-w SECS] [-b BASE] [-o FILE] CA CERT KEY PORT\n");
        return 2;
    }
    print_loaded_libmodbus();
    c = calloc((size_t) n, sizeof *c);
    m = modbus_multi_new();
    if (c == NULL || m == NULL) {
        fprintf(stderr, "tls-load: setup: %s\n", modbus_strerror(errno));
        return 1;
    }
    t_start = now_ns() + (uint64_t) (warm * 1e9);
    t_end = t_start + (uint64_t) (secs * 1e9);
    for (i = 0; i < n; i++) {
        c[i].ctx = modbus_new_tcp_tls("127.0.0.1", atoi(argv[optind + 3]));
        if (c[i].ctx == NULL || modbus_set_tls_ca(c[i].ctx, argv[optind]) != 0 ||
            modbus_set_tls_certificate(c[i].ctx, argv[optind + 1], argv[optind + 2]) != 0 ||
            modbus_set_response_timeout(c[i].ctx, 2, 0) != 0 || modbus_multi_add(m, c[i].ctx) != 0) {
            fprintf(stderr, "tls-load: context: %s\n", modbus_strerror(errno));
            return 1;
        }
        c[i].first_ns = now_ns();
        submit(&c[i]);
    }
    for (;;) {
        uint64_t now = now_ns();
        int wait_ms;
        if (now >= t_end) {
            break;
        }
        wait_ms = (int) ((t_end - now + 999999) / 1000000);
        if (modbus_multi_perform(m, wait_ms < 100 ? wait_ms : 100) == -1 && errno != EINTR) {
            fprintf(stderr, "tls-load: modbus_multi_perform: %s\n", modbus_strerror(errno));
            return 1;
        }
    }
    for (i = 0; i < n; i++) {
        connected += c[i].answered > 0;
    }
    printf("RESULT clients=%d connected=%d tx=%llu seconds=%.3f tps=%.0f p50_us=%llu p99_us=%llu max_us=%llu "
           "errors=%llu connect_max_ms=%.1f\n",
           n, connected, (unsigned long long) counted, secs, (double) counted / secs,
           (unsigned long long) quantile(0.5), (unsigned long long) quantile(0.99),
           (unsigned long long) (max_ns / 1000), (unsigned long long) errors, (double) connect_max_ns / 1e6);
    fflush(stdout);
    if (hist_file != NULL) {
        write_hist(hist_file);
    }
    /* Requests may be in flight, handshakes under way: end without them. */
    _exit(0);
}
