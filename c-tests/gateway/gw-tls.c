/*
 * gw-tls.c: Modbus/TCP Security masters of rsmodbus-gateway's TLS front
 * (c-tests/suites/gateway.sh), with the certificates of c-tests/tls/make-certs.sh
 * and the policy tls_role.Operator = rw 1-3, tls_role.Reader = r 1-247:
 *
 *   gw-tls CERTDIR PORT
 *
 * Operator reads and writes unit 1 and is refused unit 5; Reader reads and is
 * refused a write; a certificate without a role is refused (exception 01).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbtest.h"

static const char *dir;
static int port;

static modbus_t *master(const char *who, int unit)
{
    char cert[512], key[512], ca[512];
    modbus_t *ctx = modbus_new_tcp_tls("127.0.0.1", port);
    snprintf(cert, sizeof cert, "%s/%s.pem", dir, who);
    snprintf(key, sizeof key, "%s/%s.key", dir, who);
    snprintf(ca, sizeof ca, "%s/ca.pem", dir);
    if (ctx == NULL || modbus_set_tls_certificate(ctx, cert, key) != 0 || modbus_set_tls_ca(ctx, ca) != 0 ||
        modbus_connect(ctx) != 0) {
        EXPECT(0, "%s: connect: %s", who, modbus_strerror(errno));
        if (ctx != NULL) {
            modbus_free(ctx);
        }
        return NULL;
    }
    modbus_set_slave(ctx, unit);
    modbus_set_response_timeout(ctx, 5, 0);
    return ctx;
}

static void done(modbus_t *ctx)
{
    modbus_close(ctx);
    modbus_free(ctx);
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    uint16_t v[2];
    int rc;
    if (argc < 3) {
        fprintf(stderr, "usage: gw-tls CERTDIR PORT\n");
        return 2;
    }
    print_loaded_libmodbus();
    dir = argv[1];
    port = atoi(argv[2]);
    if ((ctx = master("operator", 1)) != NULL) {
        rc = modbus_read_registers(ctx, 10, 2, v);
        EXPECT(rc == 2 && v[0] == 30 && v[1] == 33, "Operator: reads unit 1 through the line (rc %d)", rc);
        EXPECT(modbus_write_register(ctx, 60, 6060) == 1 && modbus_read_registers(ctx, 60, 1, v) == 1 && v[0] == 6060,
               "Operator: writes unit 1 and reads it back");
        modbus_set_slave(ctx, 5);
        errno = 0;
        rc = modbus_read_registers(ctx, 10, 1, v);
        EXPECT(rc == -1 && errno == EMBXILFUN, "Operator: unit 5 is outside its units: exception 01 (%s)",
               modbus_strerror(errno));
        done(ctx);
    }
    if ((ctx = master("reader", 1)) != NULL) {
        EXPECT(modbus_read_registers(ctx, 10, 2, v) == 2 && v[0] == 30, "Reader: reads");
        errno = 0;
        rc = modbus_write_register(ctx, 60, 1);
        EXPECT(rc == -1 && errno == EMBXILFUN, "Reader: a write is refused, exception 01 (%s)", modbus_strerror(errno));
        EXPECT(modbus_read_registers(ctx, 60, 1, v) == 1 && v[0] == 6060, "Reader: the register is unchanged");
        done(ctx);
    }
    if ((ctx = master("norole", 1)) != NULL) {
        errno = 0;
        rc = modbus_read_registers(ctx, 10, 1, v);
        EXPECT(rc == -1 && errno == EMBXILFUN, "no role: refused, exception 01 (%s)", modbus_strerror(errno));
        done(ctx);
    }
    return chk_summary();
}
