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

/* Open descriptors, counted in /proc/self/fd, or -1 if it cannot be read. */
static inline int mbt_count_fds(void)
{
    int n = 0;
    DIR *d = opendir("/proc/self/fd");
    struct dirent *e;
    if (d == NULL) {
        return -1;
    }
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] != '.') {
            n++;
        }
    }
    closedir(d);
    return n - 1; /* not the descriptor of the directory stream itself */
}

#endif
