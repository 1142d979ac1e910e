/* A Modbus/TCP Security server (TLS, mutual authentication, roles) for many clients
 * at once: a poll() loop over the listening socket and every accepted connection, one
 * shared register map, and a role policy:
 *   - "Operator" may read and write everything;
 *   - "Reader" may only read (FC 01-04);
 *   - any other role, or none, is refused (exception 01, ILLEGAL FUNCTION).
 *
 * Usage: tls-server CA_PEM CERT_PEM KEY_PEM [port [max_requests [address]]]
 *        (default port 8802; max_requests 0 = serve forever; address 127.0.0.1, or
 *        any IPv4 or IPv6 address such as ::1)
 *
 * The map holds 100 of each table; holding register i starts at 1000 + i.
 *
 * Build: gcc tls-server.c -o tls-server $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <modbus.h>

#define MAX_CLIENTS 128

/* The role policy: 1 allows the request, 0 refuses it. */
static int authorize(modbus_t *ctx, const char *role, int unit_id, int function, int address, int nb,
                     void *user_data)
{
    (void)ctx;
    (void)unit_id;
    (void)address;
    (void)nb;
    (void)user_data;
    if (role == NULL)
        return 0;
    if (strcmp(role, "Operator") == 0)
        return 1;
    if (strcmp(role, "Reader") == 0)
        return function >= MODBUS_FC_READ_COILS && function <= MODBUS_FC_READ_INPUT_REGISTERS;
    return 0;
}

int main(int argc, char *argv[])
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s CA_PEM CERT_PEM KEY_PEM [port [max_requests [address]]]\n", argv[0]);
        return EXIT_FAILURE;
    }
    const char *port = argc > 4 ? argv[4] : "8802";
    long max_requests = argc > 5 ? atol(argv[5]) : 0;
    const char *address = argc > 6 ? argv[6] : "127.0.0.1";
    long served = 0;
    struct pollfd fds[MAX_CLIENTS + 1];
    int nfds = 1;
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];

    modbus_t *ctx = modbus_new_tcp_tls_pi(address, port);
    modbus_mapping_t *map = modbus_mapping_new(100, 100, 100, 100);
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "setup failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    if (modbus_set_tls_ca(ctx, argv[1]) == -1 || modbus_set_tls_certificate(ctx, argv[2], argv[3]) == -1 ||
        modbus_set_tls_authorization(ctx, authorize, NULL) == -1) {
        fprintf(stderr, "TLS setup failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    for (int i = 0; i < 100; i++)
        map->tab_registers[i] = (uint16_t)(1000 + i);
    int listener = modbus_tcp_pi_listen(ctx, MAX_CLIENTS);
    if (listener == -1) {
        fprintf(stderr, "listen failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    printf("serving Modbus/TCP Security on %s port %s\n", address, port);
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
                /* The handshake runs here, bounded by the response timeout: a client
                 * that fails to authenticate is refused and never served. */
                int s = modbus_tcp_pi_accept(ctx, &listener);
                if (s == -1) {
                    fprintf(stderr, "client refused: %s\n", modbus_strerror(errno));
                } else if (nfds <= MAX_CLIENTS) {
                    fds[nfds].fd = s;
                    fds[nfds].events = POLLIN;
                    nfds++;
                } else {
                    close(s);
                }
                continue;
            }
            /* A request from this client, answered on its own TLS session, and any
             * others that came in the same TLS record: the context holds those, and
             * poll() would not report them. */
            modbus_set_socket(ctx, fds[i].fd);
            int rc;
            do {
                rc = modbus_receive(ctx, query);
                if (rc > 0) {
                    modbus_reply(ctx, query, rc, map);
                    served++;
                }
            } while (rc > 0 && modbus_get_tls_pending(ctx) > 0);
            if (rc == -1) {
                close(fds[i].fd);
                fds[i] = fds[--nfds];
            }
        }
    }
    for (int i = 1; i < nfds; i++)
        close(fds[i].fd);
    close(listener);
    modbus_mapping_free(map);
    modbus_free(ctx);
    printf("server done after %ld requests\n", served);
    return EXIT_SUCCESS;
}
