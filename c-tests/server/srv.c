/*
 * srv.c: the server under test of the raw-frame differential (c-tests/server/driver.c).
 * Built once against Debian's <modbus.h>, run with Debian's libmodbus.so.5 and with
 * rsmodbus. It behaves like libmodbus's unit-test-server without the special cases:
 * every request is answered with modbus_reply(), a request with a bad CRC too (with
 * req_length -1, as unit-test-server does), and it keeps serving after any receive
 * error. Debug output is on; stdout and stderr are unbuffered so that the log the
 * driver reads is complete at every moment. Each receive and reply result is logged.
 *
 * usage: srv tcp <port> | tcppi <port> | rtu <device>
 * A request with function code 0x65 and nothing else makes it free everything and exit 0.
 * A read of holding registers at SRVTEST_EXCEPTION_ADDRESS is answered with
 * modbus_reply_exception(), the exception code being the low byte of the quantity.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <modbus.h>

#include "loaded.h"
#include "srvtest.h"

static void log_rc(const char *what, int rc)
{
    if (rc >= 0 && strcmp(what, "accept") == 0) {
        /* The descriptor number depends on the environment (valgrind keeps some). */
        printf("== accept ok\n");
        return;
    }
    if (rc == -1) {
        int e = errno;
        printf("== %s -1 errno %d (%s)\n", what, e, modbus_strerror(e));
    } else {
        printf("== %s %d\n", what, rc);
    }
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    modbus_mapping_t *map;
    uint8_t *query;
    int tcp, header, listen_s = -1, rc, i;

    setvbuf(stdout, NULL, _IONBF, 0);
    setvbuf(stderr, NULL, _IONBF, 0);
    if (argc != 3) {
        fprintf(stderr, "usage: %s tcp|tcppi <port> | rtu <device>\n", argv[0]);
        return 2;
    }
    tcp = strcmp(argv[1], "rtu") != 0;
    if (strcmp(argv[1], "tcp") == 0) {
        ctx = modbus_new_tcp("127.0.0.1", atoi(argv[2]));
    } else if (strcmp(argv[1], "tcppi") == 0) {
        ctx = modbus_new_tcp_pi("::1", argv[2]);
    } else {
        ctx = modbus_new_rtu(argv[2], 115200, 'N', 8, 1);
    }
    if (ctx == NULL) {
        fprintf(stderr, "context: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (!tcp) {
        modbus_set_slave(ctx, SRVTEST_SLAVE);
    }
    modbus_set_debug(ctx, TRUE);
    modbus_set_response_timeout(ctx, 0, SRVTEST_RESPONSE_TIMEOUT_US);
    modbus_set_byte_timeout(ctx, 0, SRVTEST_BYTE_TIMEOUT_US);
    header = modbus_get_header_length(ctx);

    map = modbus_mapping_new_start_address(SRVTEST_BITS_START, SRVTEST_BITS_NB, SRVTEST_IBITS_START,
                                           SRVTEST_IBITS_NB, SRVTEST_REGS_START, SRVTEST_REGS_NB,
                                           SRVTEST_IREGS_START, SRVTEST_IREGS_NB);
    if (map == NULL) {
        fprintf(stderr, "mapping: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (i = 0; i < SRVTEST_BITS_NB; i++) {
        map->tab_bits[i] = SRVTEST_BIT(i);
    }
    for (i = 0; i < SRVTEST_IBITS_NB; i++) {
        map->tab_input_bits[i] = SRVTEST_IBIT(i);
    }
    for (i = 0; i < SRVTEST_REGS_NB; i++) {
        map->tab_registers[i] = SRVTEST_REG(i);
    }
    for (i = 0; i < SRVTEST_IREGS_NB; i++) {
        map->tab_input_registers[i] = SRVTEST_IREG(i);
    }
    /* The library allocated the struct; this program reads it through Debian's header. */
    if (map->nb_bits != SRVTEST_BITS_NB || map->start_bits != SRVTEST_BITS_START ||
        map->nb_input_bits != SRVTEST_IBITS_NB || map->start_input_bits != SRVTEST_IBITS_START ||
        map->nb_registers != SRVTEST_REGS_NB || map->start_registers != SRVTEST_REGS_START ||
        map->nb_input_registers != SRVTEST_IREGS_NB || map->start_input_registers != SRVTEST_IREGS_START) {
        fprintf(stderr, "modbus_mapping_t fields do not match the header's layout\n");
        return 1;
    }
    query = malloc(MODBUS_TCP_MAX_ADU_LENGTH);
    if (query == NULL) {
        return 1;
    }

    if (strcmp(argv[1], "tcp") == 0) {
        listen_s = modbus_tcp_listen(ctx, 1);
    } else if (strcmp(argv[1], "tcppi") == 0) {
        listen_s = modbus_tcp_pi_listen(ctx, 1);
    } else if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "connect: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (tcp && listen_s == -1) {
        fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    printf("== ready\n");
    if (tcp) {
        log_rc("accept", strcmp(argv[1], "tcp") == 0 ? modbus_tcp_accept(ctx, &listen_s)
                                                    : modbus_tcp_pi_accept(ctx, &listen_s));
    }

    for (;;) {
        rc = modbus_receive(ctx, query);
        log_rc("receive", rc);
        if (rc == -1) {
            if (errno == EMBBADCRC) {
                log_rc("reply", modbus_reply(ctx, query, -1, map));
            } else if (tcp && errno == ECONNRESET) {
                modbus_close(ctx);
                log_rc("accept", strcmp(argv[1], "tcp") == 0 ? modbus_tcp_accept(ctx, &listen_s)
                                                            : modbus_tcp_pi_accept(ctx, &listen_s));
            }
            continue;
        }
        if (rc == 0) {
            continue;
        }
        if (query[header] == SRVTEST_QUIT_FC && rc == header + 1 + (tcp ? 0 : 2)) {
            printf("== quit\n");
            break;
        }
        if (query[header] == MODBUS_FC_READ_HOLDING_REGISTERS && rc >= header + 5 &&
            MODBUS_GET_INT16_FROM_INT8(query, header + 1) == SRVTEST_EXCEPTION_ADDRESS) {
            /* The low byte of the quantity is the exception code to send. */
            log_rc("reply_exception", modbus_reply_exception(ctx, query, query[header + 4]));
            continue;
        }
        log_rc("reply", modbus_reply(ctx, query, rc, map));
    }

    modbus_mapping_free(map);
    free(query);
    if (listen_s != -1) {
        close(listen_s);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
