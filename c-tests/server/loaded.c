/*
 * loaded.c: reports which libmodbus.so.5 the dynamic loader mapped into this process,
 * read from /proc/self/maps. Linked into every program of c-tests/server, and built
 * alone as an LD_PRELOAD object for Debian's unmodified unit-test programs.
 *
 * At start-up it writes "LOADED <pid> <path>\n" to the file named by
 * $SRVTEST_LOADED_FILE (appending), or to stderr when that is unset. The runner
 * compares <path> with the library it meant to load.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../common/libpath.h"
#include "loaded.h"

const char *srvtest_loaded_path(void)
{
    return mbt_mapped_libmodbus("(libmodbus not mapped)");
}

__attribute__((constructor)) static void srvtest_report_loaded(void)
{
    const char *name = getenv("SRVTEST_LOADED_FILE");
    FILE *out = NULL;

    if (name != NULL && name[0] != '\0') {
        out = fopen(name, "a");
    }
    fprintf(out ? out : stderr, "LOADED %d %s\n", (int) getpid(), srvtest_loaded_path());
    if (out != NULL) {
        fclose(out);
    }
}
