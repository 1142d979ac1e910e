/*
 * server-setup.c: the ways a server starts and answers on its own socket, in one
 * process on loopback (c-tests/suites/runner.sh):
 *
 *   server-setup listen tcp|tcppi|udp|udpbind
 *       the libmodbus habit: modbus_tcp_listen (tcppi: modbus_tcp_pi_listen; udp:
 *       modbus_tcp_listen on a Modbus/UDP context; udpbind: modbus_udp_bind) first,
 *       then the context handed to modbus_server_new, which serves on that socket
 *       (it does not bind again: EADDRINUSE); a client reads; the application still
 *       owns the socket it was given and closes it
 *   server-setup udp-loop listen|bind
 *       a hand-written Modbus/UDP server loop (socket from modbus_tcp_listen and
 *       modbus_set_socket, or from modbus_udp_bind): two peers send a request each
 *       (the same transaction id and unit), the server receives both, then answers
 *       the first (and in a second round the second first, and in a third one with
 *       modbus_reply_exception): each peer gets the answer to its own request
 *
 * Register i holds 1000 + i. One line per check (c-tests/common/check.h).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbt-loopback.h"

#define NB 100

/* A port free now on 127.0.0.1 (`type`: SOCK_STREAM or SOCK_DGRAM). */
static int free_port(int type)
{
    struct sockaddr_in a = {.sin_family = AF_INET};
    socklen_t len = sizeof a;
    int s = socket(AF_INET, type, 0), port = -1;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(s, (struct sockaddr *) &a, sizeof a) == 0 && getsockname(s, (struct sockaddr *) &a, &len) == 0) {
        port = ntohs(a.sin_port);
    }
    close(s);
    return port;
}

static modbus_mapping_t *new_mapping(void)
{
    modbus_mapping_t *m = modbus_mapping_new(NB, NB, NB, NB);
    for (int i = 0; m != NULL && i < NB; i++) {
        m->tab_registers[i] = (uint16_t) (1000 + i);
    }
    return m;
}

static void *run(void *arg)
{
    modbus_server_run(arg, -1);
    return NULL;
}

static void listen_case(const char *how)
{
    int udp = strncmp(how, "udp", 3) == 0;
    int port = free_port(udp ? SOCK_DGRAM : SOCK_STREAM), s;
    char service[16];
    modbus_t *ctx, *client;
    snprintf(service, sizeof service, "%d", port);
    if (strcmp(how, "tcp") == 0) {
        ctx = modbus_new_tcp("127.0.0.1", port);
        s = modbus_tcp_listen(ctx, 5);
    } else if (strcmp(how, "tcppi") == 0) {
        ctx = modbus_new_tcp_pi("127.0.0.1", service);
        s = modbus_tcp_pi_listen(ctx, 5);
    } else if (strcmp(how, "udp") == 0) {
        ctx = modbus_new_udp("127.0.0.1", port);
        s = modbus_tcp_listen(ctx, 5);
    } else {
        ctx = modbus_new_udp("127.0.0.1", port);
        s = modbus_udp_bind(ctx);
    }
    if (!EXPECT(s >= 0, "%s: the socket (port %d)%s%s", how, port, s < 0 ? ": " : "", s < 0 ? modbus_strerror(errno) : "")) {
        return;
    }
    modbus_server_t *server = modbus_server_new(ctx, 4);
    int e = errno;
    if (!EXPECT(server != NULL, "%s: modbus_server_new after the listen (%s)", how,
                server == NULL ? modbus_strerror(e) : "served on that socket")) {
        close(s);
        modbus_free(ctx);
        return;
    }
    modbus_mapping_t *m = new_mapping();
    modbus_server_set_mapping(server, m);
    pthread_t t;
    pthread_create(&t, NULL, run, server);
    client = udp ? modbus_new_udp("127.0.0.1", port) : modbus_new_tcp("127.0.0.1", port);
    uint16_t v[3] = {0, 0, 0};
    modbus_set_response_timeout(client, 2, 0);
    int rc = modbus_connect(client) == 0 ? modbus_read_registers(client, 10, 3, v) : -1;
    EXPECT(rc == 3 && v[0] == 1010 && v[2] == 1012, "%s: a client reads 3 registers (rc %d%s%s: %u %u %u)", how, rc,
           rc == -1 ? ", " : "", rc == -1 ? modbus_strerror(errno) : "", v[0], v[1], v[2]);
    modbus_close(client);
    modbus_free(client);
    modbus_server_stop(server);
    pthread_join(t, NULL);
    modbus_server_free(server);
    /* The socket made by the listen stays the application's, open, for it to close
     * (modbus_udp_bind's is the context's, closed by modbus_close). */
    if (strcmp(how, "udpbind") != 0) {
        EXPECT(close(s) == 0, "%s: the socket is still open for the application to close", how);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    modbus_mapping_free(m);
}

/* Sends a read of one register at `addr` (unit 1, transaction id `tid`). */
static void send_read(int fd, int tid, int addr)
{
    uint8_t q[12] = {(uint8_t) (tid >> 8), (uint8_t) tid, 0, 0, 0, 6, 1, 3, (uint8_t) (addr >> 8), (uint8_t) addr,
                     0, 1};
    if (send(fd, q, sizeof q, 0) != (ssize_t) sizeof q) {
        perror("send");
    }
}

/* The answer `fd` got within 2 s: the register's value, -(exception code), or
 * -1000 for none or a wrong transaction id. */
static int answer_of(int fd, int tid)
{
    uint8_t a[260];
    struct pollfd p = {.fd = fd, .events = POLLIN};
    if (poll(&p, 1, 2000) != 1) {
        return -1000;
    }
    ssize_t n = recv(fd, a, sizeof a, 0);
    if (n < 9 || ((a[0] << 8) | a[1]) != tid) {
        return -1000;
    }
    if (a[7] == 0x83) {
        return -a[8];
    }
    return n == 11 ? (a[9] << 8) | a[10] : -1000;
}

static void udp_loop(const char *how)
{
    int port = free_port(SOCK_DGRAM), s;
    modbus_t *ctx = modbus_new_udp("127.0.0.1", port);
    modbus_mapping_t *m = new_mapping();
    uint8_t qa[MODBUS_TCP_MAX_ADU_LENGTH], qb[MODBUS_TCP_MAX_ADU_LENGTH];
    if (strcmp(how, "bind") == 0) {
        s = modbus_udp_bind(ctx);
    } else {
        s = modbus_tcp_listen(ctx, 1);
        if (s >= 0) {
            modbus_set_socket(ctx, s);
        }
    }
    if (!EXPECT(s >= 0 && modbus_get_socket(ctx) == s, "udp-loop %s: the server's socket", how)) {
        return;
    }
    modbus_set_indication_timeout(ctx, 2, 0);
    int a = mbt_loopback_connect(SOCK_DGRAM, port), b = mbt_loopback_connect(SOCK_DGRAM, port);
    for (int round = 0; round < 3; round++) {
        /* Round 0 and 1: the same transaction id and unit from both peers, the
         * reads differ by their address; round 2: the ids differ (an exception's
         * answer sees only the header and function code). */
        int tid_a = 7 + round, tid_b = round == 2 ? 99 : tid_a, addr_a = 1 + 2 * round, addr_b = 2 + 2 * round;
        send_read(a, tid_a, addr_a);
        usleep(20000);
        send_read(b, tid_b, addr_b);
        int la = modbus_receive(ctx, qa), lb = modbus_receive(ctx, qb);
        if (!EXPECT(la > 0 && lb > 0, "udp-loop %s round %d: both requests received (%d, %d)", how, round, la, lb)) {
            break;
        }
        int ra, rb;
        if (round == 0) {
            ra = modbus_reply(ctx, qa, la, m);
            rb = modbus_reply(ctx, qb, lb, m);
        } else if (round == 1) {
            rb = modbus_reply(ctx, qb, lb, m);
            ra = modbus_reply(ctx, qa, la, m);
        } else {
            rb = modbus_reply_exception(ctx, qb, MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
            ra = modbus_reply(ctx, qa, la, m);
        }
        int va = answer_of(a, tid_a), vb = answer_of(b, tid_b);
        int want_b = round == 2 ? -MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS : 1000 + addr_b;
        EXPECT(ra > 0 && va == 1000 + addr_a, "udp-loop %s round %d: the first peer gets its own answer (%d, want %d)",
               how, round, va, 1000 + addr_a);
        EXPECT(rb > 0 && vb == want_b, "udp-loop %s round %d: the second peer gets its own answer (%d, want %d)", how,
               round, vb, want_b);
    }
    close(a);
    close(b);
    modbus_close(ctx);
    modbus_free(ctx);
    modbus_mapping_free(m);
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: server-setup listen tcp|tcppi|udp|udpbind | udp-loop listen|bind\n");
        return 2;
    }
    /* The LIBINFO line: printed before main by ../common/libinfo.c. */
    if (strcmp(argv[1], "listen") == 0) {
        listen_case(argv[2]);
    } else if (strcmp(argv[1], "udp-loop") == 0) {
        udp_loop(argv[2]);
    } else {
        fprintf(stderr, "unknown scenario %s\n", argv[1]);
        return 2;
    }
    return chk_summary();
}
