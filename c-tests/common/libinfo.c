/*
 * Which libmodbus.so.5 did the dynamic loader pick? Compiled into every test program
 * (through mbtest.c's users) and also built alone as an LD_PRELOAD object
 * (libmbtest-libinfo.so) for programs we do not build ourselves (mbpoll) or do not
 * modify (Debian's unit-test-client/server). It has no libmodbus dependency.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "libpath.h"

const char *mbt_libmodbus_path(void);
int mbt_is_rsmodbus(void);
int print_loaded_libmodbus(void);

/* ---- which libmodbus.so.5 is loaded ---------------------------------------------- */

const char *mbt_libmodbus_path(void)
{
    return mbt_mapped_libmodbus("(not mapped)");
}

typedef const char *(*rsmodbus_version_fn)(void);

int mbt_is_rsmodbus(void)
{
    return dlsym(RTLD_DEFAULT, "rsmodbus_version") != NULL;
}

int print_loaded_libmodbus(void)
{
    void *sym = dlsym(RTLD_DEFAULT, "rsmodbus_version");
    const char *path = mbt_libmodbus_path();
    const char *expect = getenv("EXPECT_LIB");
    const char *out_name = getenv("MBTEST_LIBINFO");
    char info[4096 + 256];
    int ours = sym != NULL;

    if (ours) {
        rsmodbus_version_fn fn;
        /* dlsym returns void *; the cast to a function pointer is the POSIX idiom. */
        memcpy(&fn, &sym, sizeof(fn));
        snprintf(info, sizeof(info), "LIBINFO: pid %d libmodbus.so.5 = %s (rsmodbus %s)\n",
                 (int) getpid(), path, fn());
    } else {
        snprintf(info, sizeof(info),
                 "LIBINFO: pid %d libmodbus.so.5 = %s (debian libmodbus, no rsmodbus_version)\n",
                 (int) getpid(), path);
    }
    if (out_name != NULL && out_name[0] != '\0') {
        FILE *o = fopen(out_name, "a");
        if (o != NULL) {
            fputs(info, o);
            fclose(o);
        }
    } else {
        fputs(info, stdout);
        fflush(stdout);
    }

    if (expect != NULL && expect[0] != '\0') {
        int want_ours;
        if (strcmp(expect, "ours") == 0) {
            want_ours = 1;
        } else if (strcmp(expect, "debian") == 0) {
            want_ours = 0;
        } else {
            fprintf(stderr, "EXPECT_LIB must be 'ours' or 'debian', not '%s'\n", expect);
            exit(97);
        }
        if (want_ours != ours) {
            fprintf(stderr,
                    "WRONG LIBRARY LOADED: EXPECT_LIB=%s but libmodbus.so.5 is %s (%s)\n",
                    expect, path, ours ? "rsmodbus" : "not rsmodbus");
            fflush(stderr);
            _exit(97);
        }
    }
    return ours;
}

/* Every test program reports its library before main() runs. */
__attribute__((constructor)) static void mbt_libinfo_ctor(void)
{
    if (getenv("MBTEST_NO_LIBINFO") == NULL) {
        print_loaded_libmodbus();
    }
}

