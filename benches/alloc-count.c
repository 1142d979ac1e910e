/*
 * alloc-count: an LD_PRELOAD object that counts heap allocations (malloc, calloc,
 * realloc, posix_memalign, aligned_alloc, memalign) and writes the totals at exit to
 * the file named by $ALLOC_COUNT_OUT (appended): "ALLOCS pid=P allocs=N frees=F".
 * The benchmark runs a program for N and 2N transactions: allocations per transaction
 * in steady state = (allocs(2N) - allocs(N)) / N.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <fcntl.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

extern void *__libc_malloc(size_t);
extern void *__libc_calloc(size_t, size_t);
extern void *__libc_realloc(void *, size_t);
extern void __libc_free(void *);
extern void *__libc_memalign(size_t, size_t);

static unsigned long n_alloc, n_free;

void *malloc(size_t n)
{
    __atomic_add_fetch(&n_alloc, 1, __ATOMIC_RELAXED);
    return __libc_malloc(n);
}

void *calloc(size_t a, size_t b)
{
    __atomic_add_fetch(&n_alloc, 1, __ATOMIC_RELAXED);
    return __libc_calloc(a, b);
}

void *realloc(void *p, size_t n)
{
    __atomic_add_fetch(&n_alloc, 1, __ATOMIC_RELAXED);
    return __libc_realloc(p, n);
}

void free(void *p)
{
    if (p != NULL) {
        __atomic_add_fetch(&n_free, 1, __ATOMIC_RELAXED);
    }
    __libc_free(p);
}

void *memalign(size_t al, size_t n)
{
    __atomic_add_fetch(&n_alloc, 1, __ATOMIC_RELAXED);
    return __libc_memalign(al, n);
}

void *aligned_alloc(size_t al, size_t n)
{
    return memalign(al, n);
}

int posix_memalign(void **out, size_t al, size_t n)
{
    void *p = memalign(al, n);
    if (p == NULL) {
        return 12; /* ENOMEM */
    }
    *out = p;
    return 0;
}

__attribute__((destructor)) static void report(void)
{
    const char *name = getenv("ALLOC_COUNT_OUT");
    char line[128];
    int fd, n;
    if (name == NULL) {
        return;
    }
    n = snprintf(line, sizeof(line), "ALLOCS pid=%d allocs=%lu frees=%lu\n", (int) getpid(), n_alloc, n_free);
    fd = open(name, O_WRONLY | O_APPEND | O_CREAT, 0644);
    if (fd >= 0) {
        if (write(fd, line, (size_t) n) < 0) {
            n = 0;
        }
        close(fd);
    }
}
