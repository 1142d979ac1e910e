/*
 * The Rust library instrumented with -Zsanitizer=thread (LLVM 22) calls __tsan_memcpy,
 * __tsan_memmove and __tsan_memset, which gcc 12's libtsan (an older copy of the same
 * runtime) does not export. They mean "memcpy/memmove/memset with the accesses checked":
 * forwarding to the libc functions, which libtsan intercepts and checks, is the same.
 * Linked into the TSan build of threads only (with -rdynamic so libmodbus.so finds them).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <string.h>

void *__tsan_memcpy(void *dst, const void *src, size_t n);
void *__tsan_memmove(void *dst, const void *src, size_t n);
void *__tsan_memset(void *dst, int c, size_t n);

void *__tsan_memcpy(void *dst, const void *src, size_t n)
{
    return memcpy(dst, src, n);
}

void *__tsan_memmove(void *dst, const void *src, size_t n)
{
    return memmove(dst, src, n);
}

void *__tsan_memset(void *dst, int c, size_t n)
{
    return memset(dst, c, n);
}
