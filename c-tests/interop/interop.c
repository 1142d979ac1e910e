/*
 * interop.c: see interop.h.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include "interop.h"

#include <dlfcn.h>
#include <stdarg.h>

#include "../common/check.h"
#include "../common/libpath.h"

/* The counters and the line format are c-tests/common/check.h's; they live in this
 * file, which is why every program of the folder counts through io_ok/io_fail. */
void io_ok(const char *name)
{
    chk_report(1, NULL, "%s", name);
}

void io_fail(const char *name, const char *fmt, ...)
{
    char why[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(why, sizeof(why), fmt, ap);
    va_end(ap);
    chk_report(0, NULL, "%s: %s", name, why);
}

int io_rc(const char *name, int rc, int want)
{
    if (rc == want) {
        return 1;
    }
    if (rc == -1) {
        int e = errno;
        io_fail(name, "returned -1, errno %d (%s), expected %d", e, modbus_strerror(e), want);
    } else {
        io_fail(name, "returned %d, expected %d", rc, want);
    }
    return 0;
}

int io_err(const char *name, int rc, int want_errno)
{
    int e = errno;
    if (rc == -1 && e == want_errno) {
        io_ok(name);
        return 1;
    }
    if (rc == -1) {
        io_fail(name, "errno %d (%s), expected %d (%s)", e, modbus_strerror(e), want_errno,
                modbus_strerror(want_errno));
    } else {
        io_fail(name, "returned %d, expected -1 with errno %d (%s)", rc, want_errno,
                modbus_strerror(want_errno));
    }
    return 0;
}

const char *io_hex(const uint8_t *b, int n)
{
    static char out[300 * 3 + 8];
    int at = 0;
    out[0] = '\0';
    for (int i = 0; i < n && i < 300; i++) {
        at += snprintf(out + at, sizeof(out) - (size_t) at, i ? " %02X" : "%02X", b[i]);
    }
    return out;
}

int io_summary(void)
{
    return chk_summary();
}

const char *io_loaded_path(void)
{
    return mbt_mapped_libmodbus("(libmodbus not mapped)");
}

typedef const char *(*version_fn)(void);

int io_print_loaded(void)
{
    void *sym = dlsym(RTLD_DEFAULT, "rsmodbus_version");
    if (sym != NULL) {
        version_fn fn;
        memcpy(&fn, &sym, sizeof(fn));
        printf("LOADED %s (rsmodbus %s)\n", io_loaded_path(), fn());
    } else {
        printf("LOADED %s (not rsmodbus)\n", io_loaded_path());
    }
    fflush(stdout);
    return sym != NULL;
}

int io_is_serial(const char *transport)
{
    return strcmp(transport, "rtu") == 0 || strncmp(transport, "ascii", 5) == 0;
}

modbus_t *io_new_ctx(const char *transport, const char *where)
{
    modbus_t *ctx = NULL;
    if (strcmp(transport, "tcp") == 0) {
        ctx = modbus_new_tcp("127.0.0.1", atoi(where));
    } else if (strcmp(transport, "tcppi") == 0) {
        ctx = modbus_new_tcp_pi("::1", where);
    } else if (strcmp(transport, "rtutcp") == 0) {
        ctx = modbus_new_rtu_tcp("127.0.0.1", atoi(where));
    } else if (strcmp(transport, "rtutcppi") == 0) {
        ctx = modbus_new_rtu_tcp_pi("::1", where);
    } else if (strcmp(transport, "ascii") == 0) {
        ctx = modbus_new_ascii(where, 115200, 'N', 8, 1);
    } else if (strcmp(transport, "ascii7") == 0) {
        ctx = modbus_new_ascii(where, 115200, 'E', 7, 1);
    } else if (strcmp(transport, "rtu") == 0) {
        ctx = modbus_new_rtu(where, 115200, 'N', 8, 1);
    } else {
        fprintf(stderr, "unknown transport %s\n", transport);
        return NULL;
    }
    if (ctx == NULL) {
        fprintf(stderr, "creating the %s context failed: %s\n", transport,
                modbus_strerror(errno));
    }
    return ctx;
}
