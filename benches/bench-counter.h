/*
 * The shared counter of an interleaved measurement (benches/bench.py). With
 * BENCH_COUNTER=FILE in the environment, a timed client maps FILE (two 64-bit words),
 * publishes its transaction count in word 0 after every transaction, and ends its run
 * once word 1 is non-zero (checked every 32 transactions). The runner pauses and
 * resumes the clients of several pairings (SIGSTOP/SIGCONT) so that they take turns
 * every fraction of a second, and reads word 0 while a client is paused. Memory
 * accesses only: the timed loop makes no more system calls than without it.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef BENCH_COUNTER_H
#define BENCH_COUNTER_H

#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/mman.h>
#include <unistd.h>

/* NULL without BENCH_COUNTER; exits the process if FILE cannot be mapped. */
static volatile uint64_t *bench_counter_open(void)
{
    const char *path = getenv("BENCH_COUNTER");
    void *map;
    int fd;
    if (path == NULL || *path == '\0') {
        return NULL;
    }
    fd = open(path, O_RDWR);
    map = fd < 0 ? MAP_FAILED : mmap(NULL, 2 * sizeof(uint64_t), PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    if (map == MAP_FAILED) {
        perror("bench: BENCH_COUNTER");
        exit(2);
    }
    close(fd);
    return (volatile uint64_t *) map;
}

static inline void bench_counter_publish(volatile uint64_t *counter, long tx)
{
    counter[0] = (uint64_t) tx;
}

static inline int bench_counter_stop_requested(volatile uint64_t *counter)
{
    return counter[1] != 0;
}

#endif
