/*
 * mb-server: a plain libmodbus server for the benchmarks, the fault-injection and the
 * soak tests (the same binary runs with Debian's libmodbus.so.5 or with rsmodbus).
 *
 *   mb-server tcp PORT [MAX_TX]     PORT 0: the kernel picks a free port
 *   mb-server rtu DEVICE [MAX_TX]   slave 1, 115200 8N1
 *   mb-server tls PORT [MAX_TX]     Modbus/TCP Security (rsmodbus only; certificates
 *                                   from MB_TLS_CA, MB_TLS_CERT, MB_TLS_KEY)
 *
 * Mapping (start 0): 2000 coils, 2000 discrete inputs, 256 holding and 256 input
 * registers. Prints "READY <port|device>" once it listens, then answers requests one
 * at a time. TCP: one client at a time, accepting the next when one goes away. Bad
 * frames (CRC, too many data) are skipped, as a robust server does. Exits after MAX_TX
 * replies (0 = never), when killed (SIGTERM), or, with MB_EXIT_ON_CLOSE set, when
 * the TCP client goes away.
 * With MB_MARK_SETUP set, it calls getppid() once, when its first connection is set
 * up (accepted, TLS handshake included; RTU: the device opened): the mark after which
 * benches/bench.py counts the system calls of the transactions.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "../c-tests/common/mbt-connect.h"

int print_loaded_libmodbus(void);

int main(int argc, char **argv)
{
    modbus_t *ctx;
    modbus_mapping_t *map;
    uint8_t req[MODBUS_TCP_MAX_ADU_LENGTH];
    long max_tx, served = 0;
    int tcp, listen_fd = -1, i, mark;

    if (argc < 3) {
        fprintf(stderr, "usage: %s tcp|tls PORT [MAX_TX] | rtu DEVICE [MAX_TX]\n", argv[0]);
        return 2;
    }
    /* SIGTERM keeps its default action: libmodbus retries select() on EINTR, so a
     * handler setting a flag would not end a server blocked in modbus_receive. */
    signal(SIGPIPE, SIG_IGN);
    tcp = strcmp(argv[1], "tcp") == 0 || strcmp(argv[1], "tls") == 0; /* TLS: TCP underneath */
    max_tx = argc > 3 ? atol(argv[3]) : 0;
    if (strcmp(argv[1], "tls") == 0) {
        ctx = mbt_new_tls("mb-server", atoi(argv[2]));
        if (ctx == NULL) {
            return 1;
        }
        /* The handshake in modbus_tcp_accept is bounded by the response timeout: long
         * enough for a client paused by an interleaved measurement in the middle of it. */
        modbus_set_response_timeout(ctx, 10, 0);
    } else {
        ctx = tcp ? modbus_new_tcp("127.0.0.1", atoi(argv[2])) : modbus_new_rtu(argv[2], 115200, 'N', 8, 1);
    }
    if (ctx == NULL) {
        fprintf(stderr, "mb-server: new context: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (getenv("MB_DEBUG") != NULL) {
        modbus_set_debug(ctx, TRUE);
    }
    map = modbus_mapping_new(2000, 2000, 256, 256);
    if (map == NULL) {
        fprintf(stderr, "mb-server: mapping: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (i = 0; i < 256; i++) {
        map->tab_registers[i] = (uint16_t) (i * 3);
        map->tab_input_registers[i] = (uint16_t) (i * 7);
    }
    for (i = 0; i < 2000; i++) {
        map->tab_bits[i] = (uint8_t) (i % 3 == 0);
        map->tab_input_bits[i] = (uint8_t) (i % 5 == 0);
    }
    if (tcp) {
        struct sockaddr_in sa;
        socklen_t sl = sizeof(sa);
        listen_fd = modbus_tcp_listen(ctx, 4);
        if (listen_fd < 0 || getsockname(listen_fd, (struct sockaddr *) &sa, &sl) != 0) {
            fprintf(stderr, "mb-server: listen: %s\n", modbus_strerror(errno));
            return 1;
        }
        printf("READY %d\n", ntohs(sa.sin_port));
    } else {
        modbus_set_slave(ctx, 1);
        if (modbus_connect(ctx) != 0) {
            fprintf(stderr, "mb-server: open %s: %s\n", argv[2], modbus_strerror(errno));
            return 1;
        }
        printf("READY %s\n", argv[2]);
    }
    fflush(stdout);

    mark = getenv("MB_MARK_SETUP") != NULL;
    while (max_tx == 0 || served < max_tx) {
        int rc;
        if (tcp && modbus_get_socket(ctx) < 0) {
            if (modbus_tcp_accept(ctx, &listen_fd) < 0) {
                /* A failed TLS handshake (a client that went away, or was refused)
                 * refuses that client, not the next ones. */
                if (errno == EINTR || errno == ECONNRESET || errno == ETIMEDOUT ||
                    (errno >= MODBUS_ENOBASE + 64 && errno <= MODBUS_ENOBASE + 71)) {
                    if (errno != EINTR) {
                        fprintf(stderr, "mb-server: client refused: %s\n", modbus_strerror(errno));
                    }
                    continue;
                }
                fprintf(stderr, "mb-server: accept: %s\n", modbus_strerror(errno));
                break;
            }
        }
        if (mark) {
            mark = 0;
            (void) getppid();
        }
        rc = modbus_receive(ctx, req);
        if (rc > 0) {
            if (modbus_reply(ctx, req, rc, map) >= 0) {
                served++;
            }
        } else if (rc < 0) {
            if (errno == EMBBADCRC || errno == EMBBADDATA || errno == EINTR) {
                continue;
            }
            if (tcp && getenv("MB_EXIT_ON_CLOSE") != NULL && errno == ECONNRESET) {
                break; /* the soak's memcheck runs end with the client */
            }
            if (tcp) {
                modbus_close(ctx); /* peer gone: wait for the next client */
                modbus_set_socket(ctx, -1);
                continue;
            }
            if (errno == ETIMEDOUT) {
                continue;
            }
            fprintf(stderr, "mb-server: receive: %s\n", modbus_strerror(errno));
            break;
        }
    }
    printf("SERVED %ld\n", served);
    if (listen_fd >= 0) {
        close(listen_fd);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    modbus_mapping_free(map);
    return 0;
}
