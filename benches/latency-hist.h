/*
 * latency-hist.h: the latency histogram of the load generators of
 * benches/server-many.sh (load-client.c, tls-load.c): 1 µs buckets below 100 ms,
 * then 1 ms buckets up to 100 s; quantiles from it, and the histogram written as
 * "MICROSECONDS COUNT" lines. Header-only: each program includes it once.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef LATENCY_HIST_H
#define LATENCY_HIST_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#define FINE 100000   /* 1 µs buckets below 100 ms */
#define COARSE 100000 /* then 1 ms buckets up to 100 s */

static uint32_t hist[FINE + COARSE];
/* Latencies recorded, and the largest (ns). */
static uint64_t counted, max_ns;

static void record(uint64_t ns)
{
    uint64_t us = ns / 1000;
    if (us < FINE) {
        hist[us]++;
    } else {
        uint64_t ms = us / 1000;
        hist[FINE + (ms < COARSE ? ms : COARSE - 1)]++;
    }
    if (ns > max_ns) {
        max_ns = ns;
    }
    counted++;
}

/* The latency (µs) below which a share q of the requests fall. */
static uint64_t quantile(double q)
{
    uint64_t want = (uint64_t) (q * (double) counted), seen = 0;
    int i;
    if (counted == 0) {
        return 0;
    }
    if (want >= counted) {
        want = counted - 1;
    }
    for (i = 0; i < FINE + COARSE; i++) {
        seen += hist[i];
        if (seen > want) {
            return i < FINE ? (uint64_t) i : (uint64_t) (i - FINE) * 1000;
        }
    }
    return max_ns / 1000;
}

/* The histogram to file `name` (exits 1 when it cannot be written). */
static void write_hist(const char *name)
{
    FILE *f = fopen(name, "w");
    int i;
    if (f == NULL) {
        perror(name);
        exit(1);
    }
    for (i = 0; i < FINE + COARSE; i++) {
        if (hist[i] != 0) {
            fprintf(f, "%llu %u\n", i < FINE ? (unsigned long long) i : (unsigned long long) (i - FINE) * 1000, hist[i]);
        }
    }
    fclose(f);
}

#endif
