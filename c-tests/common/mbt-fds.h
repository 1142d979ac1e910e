/*
 * mbt-fds.h: the number of descriptors this process has open, for the leak checks of
 * the fault and soak programs ("FDS before=<n> after=<n>"). Header-only, so that no
 * build line needs another source file.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef MBT_FDS_H
#define MBT_FDS_H

#include <dirent.h>
#include <string.h>
#include <unistd.h>

/* Open descriptors, counted in /proc/self/fd (eventfds too unless `skip_eventfds`),
 * or -1 if it cannot be read. */
static inline int mbt_count_fds_of(int skip_eventfds)
{
    int n = 0;
    DIR *d = opendir("/proc/self/fd");
    struct dirent *e;
    if (d == NULL) {
        return -1;
    }
    while ((e = readdir(d)) != NULL) {
        char link[64];
        ssize_t k;
        if (e->d_name[0] == '.') {
            continue;
        }
        if (skip_eventfds) {
            k = readlinkat(dirfd(d), e->d_name, link, sizeof(link) - 1);
            link[k > 0 ? k : 0] = '\0';
            if (strcmp(link, "anon_inode:[eventfd]") == 0) {
                continue;
            }
        }
        n++;
    }
    closedir(d);
    return n - 1; /* not the descriptor of the directory stream itself */
}

/* Open descriptors. */
static inline int mbt_count_fds(void)
{
    return mbt_count_fds_of(0);
}

/* Open descriptors but eventfds: a context's line (sockets, terminals), without the
 * wake-up descriptor rsmodbus makes for a context the first time a wait needs it
 * and keeps until modbus_free. */
static inline int mbt_count_fds_but_eventfds(void)
{
    return mbt_count_fds_of(1);
}

#endif
