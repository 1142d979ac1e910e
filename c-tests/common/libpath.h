/*
 * libpath.h: the path of the libmodbus.so.5 the dynamic loader mapped into this process,
 * read from /proc/self/maps. Used by libinfo.c, c-tests/interop/interop.c and
 * c-tests/server/loaded.c. Header-only, so that no build line needs another source file
 * and no program gets libinfo.c's start-up LIBINFO report with it.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef MBT_LIBPATH_H
#define MBT_LIBPATH_H

#include <stdio.h>
#include <string.h>

/* Real path of the first mapped libmodbus.so* (static buffer), or `missing` if none is. */
static inline const char *mbt_mapped_libmodbus(const char *missing)
{
    static char path[4096];
    char line[4096 + 256];
    FILE *f = fopen("/proc/self/maps", "r");

    snprintf(path, sizeof(path), "%s", missing);
    if (f == NULL) {
        return path;
    }
    while (fgets(line, sizeof(line), f) != NULL) {
        char *p = strchr(line, '/');
        const char *base;
        if (p == NULL) {
            continue;
        }
        p[strcspn(p, "\n")] = '\0';
        base = strrchr(p, '/') + 1;
        if (strncmp(base, "libmodbus.so", 12) == 0) {
            snprintf(path, sizeof(path), "%s", p);
            break;
        }
    }
    fclose(f);
    return path;
}

#endif
