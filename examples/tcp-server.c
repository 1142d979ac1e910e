/* A Modbus TCP server for several clients at once: a poll() loop over the listening
 * socket and every accepted connection, one shared register map.
 * Usage: tcp-server [port [max_requests]] (default 1502; 0 = serve forever).
 *
 * The map holds 100 of each table. Holding register i starts at 1000 + i, input
 * register i at 2000 + i, input bit i at i % 2; coils start at 0.
 *
 * Build: gcc tcp-server.c -o tcp-server $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include <modbus.h>

#define MAX_CLIENTS 16

int main(int argc, char *argv[])
{
    int port = argc > 1 ? atoi(argv[1]) : 1502;
    long max_requests = argc > 2 ? atol(argv[2]) : 0;
    long served = 0;
    struct pollfd fds[MAX_CLIENTS + 1];
    int nfds = 1;
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];

    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_mapping_t *map = modbus_mapping_new(100, 100, 100, 100);
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "setup failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    for (int i = 0; i < 100; i++) {
        map->tab_registers[i] = (uint16_t)(1000 + i);
        map->tab_input_registers[i] = (uint16_t)(2000 + i);
        map->tab_input_bits[i] = (uint8_t)(i % 2);
    }
    int listener = modbus_tcp_listen(ctx, MAX_CLIENTS);
    if (listener == -1) {
        fprintf(stderr, "listen failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    printf("serving on 127.0.0.1:%d\n", port);
    fflush(stdout);
    fds[0].fd = listener;
    fds[0].events = POLLIN;

    while (max_requests == 0 || served < max_requests) {
        if (poll(fds, nfds, -1) == -1) {
            if (errno == EINTR)
                continue;
            perror("poll");
            break;
        }
        for (int i = nfds - 1; i >= 0; i--) {
            if (!(fds[i].revents & (POLLIN | POLLHUP | POLLERR)))
                continue;
            if (fds[i].fd == listener) {
                int s = modbus_tcp_accept(ctx, &listener);
                if (s != -1 && nfds <= MAX_CLIENTS) {
                    fds[nfds].fd = s;
                    fds[nfds].events = POLLIN;
                    nfds++;
                } else if (s != -1) {
                    close(s);
                }
                continue;
            }
            /* One request from this client, answered on its own socket. */
            modbus_set_socket(ctx, fds[i].fd);
            int rc = modbus_receive(ctx, query);
            if (rc > 0) {
                modbus_reply(ctx, query, rc, map);
                served++;
            } else if (rc == -1) {
                close(fds[i].fd);
                fds[i] = fds[--nfds];
            }
        }
    }
    for (int i = 0; i < nfds; i++)
        close(fds[i].fd);
    modbus_mapping_free(map);
    modbus_free(ctx);
    printf("server done after %ld requests\n", served);
    return EXIT_SUCCESS;
}
