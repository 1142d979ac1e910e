/* A plain Modbus TCP server for thousands of clients from one thread: the server that
 * runs itself (modbus_server_new(3)) answering from one shared register map, the map
 * of tcp-server.c (holding register i starts at 1000 + i, input register i at
 * 2000 + i, input bit i at i % 2, coils at 0; 100 of each). tcp-client and
 * poll-many (1,000 devices) are pointed at it by default.
 *
 * Usage: runner-server [port [max_clients [address]]]
 *        (default 1502, 10000 clients, 127.0.0.1; 0.0.0.0: every address).
 *        Serves until SIGINT or SIGTERM.
 *
 * Build: make -C examples, or
 *        gcc runner-server.c -o runner-server $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/resource.h>

#include <modbus.h>

static modbus_server_t *server;

static void on_signal(int sig)
{
    (void)sig;
    modbus_server_stop(server); /* async-signal-safe */
}

int main(int argc, char *argv[])
{
    int port = argc > 1 ? atoi(argv[1]) : 1502;
    int max_clients = argc > 2 ? atoi(argv[2]) : 10000;
    const char *address = argc > 3 ? argv[3] : "127.0.0.1";

    /* One descriptor per client: take the hard limit (often 1,024 soft). */
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < rl.rlim_max) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }

    modbus_t *ctx = modbus_new_tcp(address, port);
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
    /* Listen first (a backlog for many clients connecting at once), then hand over. */
    if (modbus_tcp_listen(ctx, 1024) == -1) {
        fprintf(stderr, "listen on %s:%d: %s\n", address, port, modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    server = modbus_server_new(ctx, max_clients);
    if (server == NULL || modbus_server_set_mapping(server, map) == -1) {
        fprintf(stderr, "modbus_server_new: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    modbus_server_set_idle_timeout(server, 60, 0); /* a silent client is closed */

    struct sigaction sa = {.sa_handler = on_signal};
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    printf("serving on %s:%d, up to %d clients\n", address, port, max_clients);
    fflush(stdout);
    int rc = modbus_server_run(server, -1); /* until modbus_server_stop */
    if (rc == -1) {
        fprintf(stderr, "modbus_server_run: %s\n", modbus_strerror(errno));
    }
    printf("server stopped\n");

    modbus_server_free(server);
    modbus_mapping_free(map);
    modbus_free(ctx); /* closes the listening socket */
    return rc == -1 ? EXIT_FAILURE : EXIT_SUCCESS;
}
