/*
 * mbt-connect.h: the client context of the benchmark, fault and soak programs:
 * "tcp PORT" on 127.0.0.1, "rtu DEVICE" at 115200 8N1 to slave 1, or "tls PORT"
 * (Modbus/TCP Security on 127.0.0.1, rsmodbus only), connected.
 * Header-only, so that no build line needs another source file; include it after
 * the program's own <modbus.h> (the programs reach it by different paths).
 *
 * TLS: the programs are built against Debian's <modbus.h>, which has no TLS call, and
 * must still load Debian's library; so the TLS calls are looked up at run time
 * (dlsym), and a "tls" run with Debian's library fails cleanly. The certificates come
 * from MB_TLS_CA, MB_TLS_CERT and MB_TLS_KEY (PEM files).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef MBT_CONNECT_H
#define MBT_CONNECT_H

#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The rsmodbus TLS calls the programs use (<modbus-tls.h>), found at run time. */
struct mbt_tls_api {
    modbus_t *(*new_tcp_tls)(const char *ip, int port);
    int (*set_certificate)(modbus_t *ctx, const char *chain_file, const char *key_file);
    int (*set_ca)(modbus_t *ctx, const char *ca_file);
    int (*set_min_version)(modbus_t *ctx, int version);
};

/* The loaded library's TLS calls, or NULL (with a message) when it has none. */
static inline const struct mbt_tls_api *mbt_tls_api(const char *prog)
{
    static struct mbt_tls_api api;
    if (api.new_tcp_tls == NULL) {
        *(void **) &api.new_tcp_tls = dlsym(RTLD_DEFAULT, "modbus_new_tcp_tls");
        *(void **) &api.set_certificate = dlsym(RTLD_DEFAULT, "modbus_set_tls_certificate");
        *(void **) &api.set_ca = dlsym(RTLD_DEFAULT, "modbus_set_tls_ca");
        *(void **) &api.set_min_version = dlsym(RTLD_DEFAULT, "modbus_set_tls_min_version");
        if (api.new_tcp_tls == NULL || api.set_certificate == NULL ||
            api.set_ca == NULL || api.set_min_version == NULL) {
            fprintf(stderr, "%s: this libmodbus.so.5 has no TLS (Modbus/TCP Security)\n", prog);
            api.new_tcp_tls = NULL;
            return NULL;
        }
    }
    return &api;
}

/* A TLS context on 127.0.0.1:port with the certificates of MB_TLS_CA, MB_TLS_CERT
 * and MB_TLS_KEY, or NULL after printing why. */
static inline modbus_t *mbt_new_tls(const char *prog, int port)
{
    const struct mbt_tls_api *tls = mbt_tls_api(prog);
    const char *ca = getenv("MB_TLS_CA"), *cert = getenv("MB_TLS_CERT"), *key = getenv("MB_TLS_KEY");
    modbus_t *ctx;
    if (tls == NULL) {
        return NULL;
    }
    if (ca == NULL || cert == NULL || key == NULL) {
        fprintf(stderr, "%s: tls needs MB_TLS_CA, MB_TLS_CERT and MB_TLS_KEY\n", prog);
        return NULL;
    }
    ctx = tls->new_tcp_tls("127.0.0.1", port);
    if (ctx == NULL || tls->set_certificate(ctx, cert, key) != 0 || tls->set_ca(ctx, ca) != 0) {
        fprintf(stderr, "%s: TLS settings: %s\n", prog, modbus_strerror(errno));
        if (ctx != NULL) {
            modbus_free(ctx);
        }
        return NULL;
    }
    return ctx;
}

/* A connected context for `transport` ("tcp", "rtu" or "tls") and `where` (port or
 * device), or NULL after printing "<prog>: connect: <reason>" on stderr. With
 * `seconds` > 0 the response timeout is set to it before the connection (which a
 * TLS handshake waits within: a peer under valgrind can take longer than 0.5 s). */
static inline modbus_t *mbt_connect_within(const char *prog, const char *transport, const char *where,
                                           long seconds)
{
    modbus_t *ctx;
    if (strcmp(transport, "tcp") == 0) {
        ctx = modbus_new_tcp("127.0.0.1", atoi(where));
    } else if (strcmp(transport, "tls") == 0) {
        ctx = mbt_new_tls(prog, atoi(where));
        if (ctx == NULL) {
            return NULL;
        }
    } else {
        ctx = modbus_new_rtu(where, 115200, 'N', 8, 1);
        if (ctx != NULL) {
            modbus_set_slave(ctx, 1);
        }
    }
    if (ctx != NULL && seconds > 0) {
        modbus_set_response_timeout(ctx, (uint32_t) seconds, 0);
    }
    if (ctx == NULL || modbus_connect(ctx) != 0) {
        fprintf(stderr, "%s: connect: %s\n", prog, modbus_strerror(errno));
        return NULL;
    }
    return ctx;
}

static inline modbus_t *mbt_connect(const char *prog, const char *transport, const char *where)
{
    return mbt_connect_within(prog, transport, where, 0);
}

#endif
