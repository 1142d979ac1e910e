/*
 * select-server.c: libmodbus' own way of serving many TCP clients, as its test
 * program for many clients (tests/bandwidth-server-many-up.c) describes it, written
 * here from that description for benches/server-many.sh: one thread, select() over
 * the listening socket and every client socket; a new connection is accepted and
 * added to the set; a client socket that is ready gets modbus_receive() and
 * modbus_reply() on the one context (modbus_set_socket() first); a client whose
 * receive fails is closed and leaves the set.
 *
 *   select-server [PORT]     (0 or none: a port the kernel chooses)
 *
 * Built against Debian's <modbus.h>, run with Debian's libmodbus.so.5 or ours
 * (LD_LIBRARY_PATH). Holding register i holds i (100 of each table). Prints the
 * library it loaded (LIBINFO), READY <port> once it listens, and on SIGTERM the
 * requests it answered.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

int print_loaded_libmodbus(void);

static volatile sig_atomic_t stopping;

static void on_term(int sig)
{
    (void) sig;
    stopping = 1;
}

int main(int argc, char **argv)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", argc > 1 ? atoi(argv[1]) : 0);
    modbus_mapping_t *map = modbus_mapping_new(100, 100, 100, 100);
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    struct sockaddr_in a;
    socklen_t alen = sizeof a;
    struct sigaction act;
    fd_set all;
    int listener, fdmax, i;
    long answered = 0;

    print_loaded_libmodbus();
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "setup: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (i = 0; i < 100; i++) {
        map->tab_registers[i] = (uint16_t) i;
        map->tab_input_registers[i] = (uint16_t) i;
    }
    listener = modbus_tcp_listen(ctx, 1000);
    if (listener < 0 || getsockname(listener, (struct sockaddr *) &a, &alen) != 0) {
        fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    memset(&act, 0, sizeof act);
    act.sa_handler = on_term;
    sigaction(SIGTERM, &act, NULL);
    sigaction(SIGINT, &act, NULL);
    printf("READY %d\n", ntohs(a.sin_port));
    fflush(stdout);

    FD_ZERO(&all);
    FD_SET(listener, &all);
    fdmax = listener;
    while (!stopping) {
        fd_set ready = all;
        int fd;
        if (select(fdmax + 1, &ready, NULL, NULL, NULL) < 0) {
            if (errno == EINTR) {
                continue;
            }
            perror("select");
            return 1;
        }
        for (fd = 0; fd <= fdmax; fd++) {
            if (!FD_ISSET(fd, &ready)) {
                continue;
            }
            if (fd == listener) {
                int s = accept(listener, NULL, NULL);
                if (s < 0) {
                    continue;
                }
                if (s >= FD_SETSIZE) {
                    close(s); /* select() cannot watch it */
                    continue;
                }
                FD_SET(s, &all);
                if (s > fdmax) {
                    fdmax = s;
                }
            } else {
                int rc;
                modbus_set_socket(ctx, fd);
                rc = modbus_receive(ctx, query);
                if (rc > 0) {
                    modbus_reply(ctx, query, rc, map);
                    answered++;
                } else if (rc < 0) {
                    close(fd);
                    FD_CLR(fd, &all);
                    while (fdmax > listener && !FD_ISSET(fdmax, &all)) {
                        fdmax--;
                    }
                }
            }
        }
    }
    printf("stopped, %ld requests answered\n", answered);
    modbus_set_socket(ctx, -1);
    close(listener);
    modbus_mapping_free(map);
    modbus_free(ctx);
    return 0;
}
