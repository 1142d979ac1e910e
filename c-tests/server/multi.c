/*
 * multi.c: the multi-client server pattern of libmodbus users (bandwidth-server-many-up
 * style, with poll instead of select): one context, the application's own loop over
 * the accepted sockets, modbus_set_socket() before each modbus_receive()/modbus_reply().
 *
 * 50 forked clients connect at once; each writes and reads back its own range of
 * registers and coils many times and checks every value. Two more clients misbehave:
 * one disconnects in the middle of a request, one sends a request in two pieces with a
 * pause between them. No state of one client may leak into another's exchange.
 * Prints "MULTI PASS ..." and exits 0 when every client succeeded.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <modbus.h>

#include "loaded.h"

#define NB_GOOD 50
#define ROUNDS 20
#define REGS_PER_CLIENT 8

static int port;

static int good_client(int id)
{
    modbus_t *c = modbus_new_tcp("127.0.0.1", port);
    uint16_t want[REGS_PER_CLIENT], got[REGS_PER_CLIENT];
    uint8_t bits[4];
    int r, i;

    if (c == NULL || modbus_connect(c) == -1) {
        fprintf(stderr, "client %d: connect: %s\n", id, modbus_strerror(errno));
        return 1;
    }
    modbus_set_response_timeout(c, 5, 0);
    for (r = 0; r < ROUNDS; r++) {
        for (i = 0; i < REGS_PER_CLIENT; i++) {
            want[i] = (uint16_t) (id * 1000 + r * 10 + i);
        }
        if (modbus_write_registers(c, id * REGS_PER_CLIENT, REGS_PER_CLIENT, want) != REGS_PER_CLIENT ||
            modbus_read_registers(c, id * REGS_PER_CLIENT, REGS_PER_CLIENT, got) != REGS_PER_CLIENT ||
            memcmp(want, got, sizeof(want)) != 0) {
            fprintf(stderr, "client %d round %d: registers: %s\n", id, r, modbus_strerror(errno));
            return 1;
        }
        if (modbus_write_bit(c, id * 4 + (r % 4), 1) != 1 || modbus_write_bit(c, id * 4 + ((r + 1) % 4), 0) != 1 ||
            modbus_read_bits(c, id * 4, 4, bits) != 4 || bits[r % 4] != 1 || bits[(r + 1) % 4] != 0) {
            fprintf(stderr, "client %d round %d: bits: %s\n", id, r, modbus_strerror(errno));
            return 1;
        }
    }
    modbus_close(c);
    modbus_free(c);
    return 0;
}

static int raw_connect(void)
{
    struct sockaddr_in sa;
    int s = socket(AF_INET, SOCK_STREAM, 0);
    memset(&sa, 0, sizeof(sa));
    sa.sin_family = AF_INET;
    sa.sin_port = htons((uint16_t) port);
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(s, (struct sockaddr *) &sa, sizeof(sa)) != 0) {
        return -1;
    }
    return s;
}

/* Sends half a write-registers request and disconnects. */
static int rude_client(void)
{
    static const uint8_t half[] = {0x00, 0x01, 0x00, 0x00, 0x00, 0x0B, 0xFF, 0x10, 0x00, 0x00};
    int s = raw_connect();
    if (s < 0 || write(s, half, sizeof(half)) != (ssize_t) sizeof(half)) {
        return 1;
    }
    usleep(20000);
    close(s);
    return 0;
}

/* Sends a read request in two pieces 100 ms apart (within the byte timeout). */
static int slow_client(void)
{
    static const uint8_t req[] = {0x00, 0x07, 0x00, 0x00, 0x00, 0x06, 0xFF, 0x03, 0x01, 0xF0, 0x00, 0x01};
    uint8_t rsp[32];
    int s = raw_connect(), n = 0;
    if (s < 0 || write(s, req, 5) != 5) {
        return 1;
    }
    usleep(100000);
    if (write(s, req + 5, sizeof(req) - 5) != (ssize_t) (sizeof(req) - 5)) {
        return 1;
    }
    while (n < 11) {
        ssize_t r = read(s, rsp + n, sizeof(rsp) - (size_t) n);
        if (r <= 0) {
            break;
        }
        n += (int) r;
    }
    close(s);
    /* Register 0x1F0 was never written: 0. TID 7 echoed. */
    return !(n == 11 && rsp[1] == 0x07 && rsp[7] == 0x03 && rsp[8] == 2 && rsp[9] == 0 && rsp[10] == 0);
}

int main(void)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", 0);
    modbus_mapping_t *map = modbus_mapping_new(NB_GOOD * 4, 0, 0x200, 0);
    struct pollfd fds[128];
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    pid_t pids[NB_GOOD + 2];
    struct sockaddr_in sa;
    socklen_t len = sizeof(sa);
    int nfds = 1, s, i, closed = 0, served = 0, failed = 0, reset = 0;

    setvbuf(stdout, NULL, _IONBF, 0);
    s = modbus_tcp_listen(ctx, NB_GOOD + 2);
    if (s < 0 || map == NULL) {
        printf("MULTI FAIL listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    getsockname(s, (struct sockaddr *) &sa, &len);
    port = ntohs(sa.sin_port);
    for (i = 0; i < NB_GOOD + 2; i++) {
        pids[i] = fork();
        if (pids[i] == 0) {
            close(s);
            _exit(i < NB_GOOD ? good_client(i) : i == NB_GOOD ? rude_client() : slow_client());
        }
    }
    fds[0].fd = s;
    fds[0].events = POLLIN;
    while (closed < NB_GOOD + 2) {
        if (poll(fds, (nfds_t) nfds, 20000) <= 0) {
            printf("MULTI FAIL poll timed out (%d clients done)\n", closed);
            break;
        }
        if (fds[0].revents & POLLIN) {
            int fd = modbus_tcp_accept(ctx, &s);
            if (fd >= 0) {
                fds[nfds].fd = fd;
                fds[nfds].events = POLLIN;
                fds[nfds].revents = 0;
                nfds++;
            }
        }
        for (i = 1; i < nfds; i++) {
            int rc;
            if (!(fds[i].revents & (POLLIN | POLLHUP | POLLERR))) {
                continue;
            }
            modbus_set_socket(ctx, fds[i].fd);
            rc = modbus_receive(ctx, query);
            if (rc > 0) {
                if (modbus_reply(ctx, query, rc, map) > 0) {
                    served++;
                }
            } else if (rc == -1) {
                if (errno != ECONNRESET) {
                    reset++;
                }
                close(fds[i].fd);
                fds[i] = fds[nfds - 1];
                nfds--;
                i--;
                closed++;
            }
        }
    }
    for (i = 0; i < NB_GOOD + 2; i++) {
        int status;
        waitpid(pids[i], &status, 0);
        if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
            printf("MULTI client %d failed (status 0x%X)\n", i, (unsigned) status);
            failed++;
        }
    }
    close(s);
    modbus_mapping_free(map);
    modbus_free(ctx);
    /* Each good client: ROUNDS x (write, read, 2 x write bit, read bits); the slow one 1. */
    if (failed == 0 && served == NB_GOOD * ROUNDS * 5 + 1) {
        printf("MULTI PASS %d clients, %d requests served, %d closed with another error than ECONNRESET, "
               "with %s\n",
               NB_GOOD + 2, served, reset, srvtest_loaded_path());
        return 0;
    }
    printf("MULTI FAIL %d clients failed, %d requests served\n", failed, served);
    return 1;
}
