/*
 * mbt-connect.h: the client context of the benchmark, fault and soak programs:
 * "tcp PORT" on 127.0.0.1 or "rtu DEVICE" at 115200 8N1 to slave 1, connected.
 * Header-only, so that no build line needs another source file; include it after
 * the program's own <modbus.h> (the programs reach it by different paths).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef MBT_CONNECT_H
#define MBT_CONNECT_H

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A connected context for `transport` ("tcp" or "rtu") and `where` (port or device),
 * or NULL after printing "<prog>: connect: <reason>" on stderr. */
static inline modbus_t *mbt_connect(const char *prog, const char *transport, const char *where)
{
    modbus_t *ctx;
    if (strcmp(transport, "tcp") == 0) {
        ctx = modbus_new_tcp("127.0.0.1", atoi(where));
    } else {
        ctx = modbus_new_rtu(where, 115200, 'N', 8, 1);
        if (ctx != NULL) {
            modbus_set_slave(ctx, 1);
        }
    }
    if (ctx == NULL || modbus_connect(ctx) != 0) {
        fprintf(stderr, "%s: connect: %s\n", prog, modbus_strerror(errno));
        return NULL;
    }
    return ctx;
}

#endif
