/*
 * gw-ours.c: masters of rsmodbus-gateway's fronts that only rsmodbus speaks
 * (c-tests/suites/gateway.sh); the line's device is benches/mb-server.c (holding
 * register i holds 3 * i):
 *
 *   gw-ours tls CERTDIR PORT   Modbus/TCP Security, with the certificates of
 *                              c-tests/tls/make-certs.sh and the policy
 *                              tls_role.Operator = rw 1-3, tls_role.Reader = r 1-247:
 *                              Operator reads and writes unit 1 and is refused unit
 *                              5; Reader reads and is refused a write; a certificate
 *                              without a role is refused (exception 01)
 *   gw-ours rtutcp PORT        RTU frames over TCP: unit 1 read, written, read back
 *   gw-ours udp PORT           Modbus/UDP: the same
 *   gw-ours tlsloop CERTDIR PORT S   an Operator master reading one register in a
 *                              closed loop for S seconds: prints its answers/s
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

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

static void plain(const char *what, modbus_t *ctx)
{
    uint16_t v[2];
    int rc;
    if (!EXPECT(ctx != NULL && modbus_set_slave(ctx, 1) == 0 && modbus_connect(ctx) == 0, "%s: connect", what)) {
        return;
    }
    modbus_set_response_timeout(ctx, 5, 0);
    rc = modbus_read_registers(ctx, 10, 2, v);
    EXPECT(rc == 2 && v[0] == 30 && v[1] == 33, "%s: reads unit 1 through the line (rc %d)", what, rc);
    EXPECT(modbus_write_register(ctx, 61, 6161) == 1 && modbus_read_registers(ctx, 61, 1, v) == 1 && v[0] == 6161,
           "%s: writes and reads back", what);
    done(ctx);
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    uint16_t v[2];
    int rc;
    if (argc < 3) {
        fprintf(stderr, "usage: gw-ours tls CERTDIR PORT | rtutcp PORT | udp PORT\n");
        return 2;
    }
    print_loaded_libmodbus();
    if (strcmp(argv[1], "rtutcp") == 0) {
        plain("RTU over TCP", modbus_new_rtu_tcp("127.0.0.1", atoi(argv[2])));
        return chk_summary();
    }
    if (strcmp(argv[1], "udp") == 0) {
        plain("Modbus/UDP", modbus_new_udp("127.0.0.1", atoi(argv[2])));
        return chk_summary();
    }
    if (strcmp(argv[1], "tlsloop") == 0 && argc > 4) {
        time_t end;
        long n = 0;
        dir = argv[2];
        port = atoi(argv[3]);
        if ((ctx = master("operator", 1)) == NULL) {
            return chk_summary();
        }
        end = time(NULL) + atoi(argv[4]);
        while (time(NULL) < end) {
            n += modbus_read_registers(ctx, 5, 1, v) == 1;
        }
        printf("# tls loop: %ld answers in %d s (%.1f/s)\n", n, atoi(argv[4]), (double) n / atoi(argv[4]));
        done(ctx);
        EXPECT(n > 0, "answers through the TLS front");
        return chk_summary();
    }
    if (strcmp(argv[1], "tls") != 0 || argc < 4) {
        fprintf(stderr, "usage: gw-ours tls CERTDIR PORT | rtutcp PORT | udp PORT\n");
        return 2;
    }
    dir = argv[2];
    port = atoi(argv[3]);
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
