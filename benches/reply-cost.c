/*
 * reply-cost.c: what modbus_reply_dispatch costs against modbus_reply on the same
 * mapping (scripts/bench.sh --callbacks). One server context answers prepared
 * requests onto one end of an AF_UNIX socket pair (drained between slices), in
 * slices of SLICE replies; in every cycle modbus_reply (A) and modbus_reply_dispatch
 * over a callback set serving the same mapping (B, c-tests/common/mapping-callbacks.h)
 * take one slice each, in a random order. The figure is the thread CPU time per
 * reply; B/A is the median of the per-cycle ratios with its 95% confidence interval
 * (order statistics), per case.
 *
 *   reply-cost [CYCLES]        (default 300)
 *
 * Built against our include/ by benches/reply-cost.sh, which runs it.
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "../c-tests/common/mapping-callbacks.h"

#define SLICE 400

static double cpu_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *) a, y = *(const double *) b;
    return (x > y) - (x < y);
}

static void drain(int fd)
{
    char buf[65536];
    while (recv(fd, buf, sizeof buf, MSG_DONTWAIT) > 0) {
    }
}

/* One slice of replies: the CPU nanoseconds each took. */
static double slice(modbus_t *ctx, int sink, const uint8_t *req, int len, modbus_mapping_t *map, int callbacks)
{
    double t0 = cpu_ns();
    for (int i = 0; i < SLICE; i++) {
        int rc = callbacks ? modbus_reply_dispatch(ctx, req, len, &MAPPING_CALLBACKS, map)
                           : modbus_reply(ctx, req, len, map);
        if (rc <= 0) {
            fprintf(stderr, "reply: %d %s\n", rc, modbus_strerror(errno));
            exit(1);
        }
    }
    double t = (cpu_ns() - t0) / SLICE;
    drain(sink);
    return t;
}

int main(int argc, char **argv)
{
    int cycles = argc > 1 ? atoi(argv[1]) : 300, sv[2];
    struct {
        const char *name;
        uint8_t pdu[260];
        int n;
    } cases[4] = {
        {"r10 (read 10 registers)", {0x03, 0x00, 0x00, 0x00, 10}, 5},
        {"r125 (read 125 registers)", {0x03, 0x00, 0x00, 0x00, 125}, 5},
        {"c2000 (read 2000 coils)", {0x01, 0x00, 0x00, 0x07, 0xD0}, 5},
        {"w123 (write 123 registers)", {0x10, 0x00, 0x00, 0x00, 123, 246}, 6 + 246},
    };
    modbus_mapping_t *map = modbus_mapping_new(2000, 2000, 256, 256);
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", 1502);
    if (map == NULL || ctx == NULL || socketpair(AF_UNIX, SOCK_STREAM, 0, sv) == -1) {
        perror("setup");
        return 1;
    }
    int size = 1 << 20;
    setsockopt(sv[0], SOL_SOCKET, SO_SNDBUF, &size, sizeof size);
    setsockopt(sv[1], SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
    modbus_set_socket(ctx, sv[0]);
    srand(1);
    printf("| case | modbus_reply (ns CPU/reply) | modbus_reply_dispatch | B/A (95%% CI) |\n|---|---:|---:|---|\n");
    for (int c = 0; c < 4; c++) {
        uint8_t req[300] = {0x00, 0x01, 0x00, 0x00, 0x00, 0x00, 0x01};
        int len = 7 + cases[c].n;
        memcpy(req + 7, cases[c].pdu, (size_t) cases[c].n);
        req[4] = (uint8_t) ((cases[c].n + 1) >> 8);
        req[5] = (uint8_t) (cases[c].n + 1);
        double *a = calloc((size_t) cycles, sizeof *a), *b = calloc((size_t) cycles, sizeof *b),
               *r = calloc((size_t) cycles, sizeof *r);
        /* Warm-up: both paths, caches and branch predictors. */
        slice(ctx, sv[1], req, len, map, 0);
        slice(ctx, sv[1], req, len, map, 1);
        for (int k = 0; k < cycles; k++) {
            if (rand() & 1) {
                a[k] = slice(ctx, sv[1], req, len, map, 0);
                b[k] = slice(ctx, sv[1], req, len, map, 1);
            } else {
                b[k] = slice(ctx, sv[1], req, len, map, 1);
                a[k] = slice(ctx, sv[1], req, len, map, 0);
            }
            r[k] = b[k] / a[k];
        }
        qsort(a, (size_t) cycles, sizeof *a, cmp);
        qsort(b, (size_t) cycles, sizeof *b, cmp);
        qsort(r, (size_t) cycles, sizeof *r, cmp);
        int half = (int) (1.96 * sqrt(cycles) / 2), mid = cycles / 2;
        int lo = mid - half < 0 ? 0 : mid - half, hi = mid + half >= cycles ? cycles - 1 : mid + half;
        printf("| %s | %.0f | %.0f | %.3f (%.3f-%.3f) |\n", cases[c].name, a[mid], b[mid], r[mid], r[lo], r[hi]);
        fflush(stdout);
        free(a);
        free(b);
        free(r);
    }
    modbus_mapping_free(map);
    modbus_free(ctx);
    close(sv[0]);
    close(sv[1]);
    return 0;
}
