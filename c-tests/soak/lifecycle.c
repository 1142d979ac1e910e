/*
 * lifecycle: context and mapping life cycles that must not leak, run under valgrind
 * memcheck (and with the descriptor count checked).
 *
 *   lifecycle CYCLES
 *
 * Each cycle: modbus_new_tcp/new_tcp_pi/new_rtu + settings + modbus_free; a mapping
 * (with and without start addresses) allocated and freed; a failed TCP connect (a
 * closed port: ECONNREFUSED) and a failed RTU connect (no such device), each followed
 * by modbus_close and modbus_free; a connect to a listening socket, closed and freed;
 * modbus_tcp_listen + modbus_free. Prints "FDS before=<n> after=<n>".
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/mbt-fds.h"

int print_loaded_libmodbus(void);

/* A listening socket on a free port (returned in *port). */
static int listener(int *port)
{
    struct sockaddr_in sa;
    socklen_t sl = sizeof(sa);
    int s = socket(AF_INET, SOCK_STREAM, 0);
    memset(&sa, 0, sizeof(sa));
    sa.sin_family = AF_INET;
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (s < 0 || bind(s, (struct sockaddr *) &sa, sizeof(sa)) != 0 || listen(s, 8) != 0 ||
        getsockname(s, (struct sockaddr *) &sa, &sl) != 0) {
        perror("lifecycle: listener");
        exit(1);
    }
    *port = ntohs(sa.sin_port);
    return s;
}

int main(int argc, char **argv)
{
    int cycles = argc > 1 ? atoi(argv[1]) : 100, before, after, i, closed_port, open_port, ls, ls2;
    char port_s[16];

    before = mbt_count_fds();
    /* A port known to be closed: bind, read it back, close. */
    ls = listener(&closed_port);
    close(ls);
    ls2 = listener(&open_port);
    snprintf(port_s, sizeof(port_s), "%d", closed_port);
    for (i = 0; i < cycles; i++) {
        modbus_t *ctx;
        modbus_mapping_t *m;

        ctx = modbus_new_tcp("127.0.0.1", 1502);
        modbus_set_slave(ctx, 3);
        modbus_set_response_timeout(ctx, 0, 200000);
        modbus_set_debug(ctx, FALSE);
        modbus_free(ctx);

        ctx = modbus_new_tcp_pi("localhost", "1502");
        modbus_free(ctx);

        ctx = modbus_new_rtu("/dev/null-no-such-device", 19200, 'E', 8, 1);
        modbus_set_slave(ctx, 1);
        if (modbus_connect(ctx) == 0) {
            fprintf(stderr, "lifecycle: connect to a missing device succeeded\n");
            return 1;
        }
        modbus_close(ctx);
        modbus_free(ctx);

        m = modbus_mapping_new(100, 100, 100, 100);
        modbus_mapping_free(m);
        m = modbus_mapping_new_start_address(10, 20, 30, 0, 50, 60, 70, 80);
        modbus_mapping_free(m);
        modbus_mapping_free(NULL);

        ctx = modbus_new_tcp("127.0.0.1", closed_port);
        if (modbus_connect(ctx) == 0) {
            fprintf(stderr, "lifecycle: connect to a closed port succeeded\n");
            return 1;
        }
        modbus_close(ctx);
        modbus_free(ctx);

        ctx = modbus_new_tcp_pi("127.0.0.1", port_s);
        if (modbus_connect(ctx) == 0) {
            fprintf(stderr, "lifecycle: connect (pi) to a closed port succeeded\n");
            return 1;
        }
        modbus_free(ctx);

        ctx = modbus_new_tcp("127.0.0.1", open_port);
        if (modbus_connect(ctx) != 0) {
            fprintf(stderr, "lifecycle: connect: %s\n", modbus_strerror(errno));
            return 1;
        }
        modbus_close(ctx);
        modbus_free(ctx);
        {
            int c = accept(ls2, NULL, NULL);
            if (c >= 0) {
                close(c);
            }
        }

        ctx = modbus_new_tcp("127.0.0.1", 0);
        {
            int s = modbus_tcp_listen(ctx, 1);
            if (s >= 0) {
                close(s);
            }
        }
        modbus_free(ctx);
    }
    close(ls2);
    after = mbt_count_fds();
    printf("FDS before=%d after=%d cycles=%d\n", before, after, cycles);
    return before == after ? 0 : 1;
}
