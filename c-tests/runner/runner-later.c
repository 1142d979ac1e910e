/*
 * runner-later.c: a server that runs itself (modbus_server_new(3)) with callbacks,
 * in this process, checked by clients of the same library (c-tests/suites/runner.sh):
 * what a callback learns of the request and of its client (modbus_request_info_t),
 * and the answers given later.
 *
 *   runner-later tcp      connection ids: two clients one after the other (most
 *                         likely on the same descriptor number on the server) get
 *                         two ids; accept_unit sees the request info; a deferred
 *                         read answered with modbus_server_answer_registers (and
 *                         refused answers that do not fit it), a deferred write
 *                         answered with rc 0, FC 17 deferred by its write half (the
 *                         read callback not called), the typed exception
 *   runner-later udp      ri->peer is the datagram's sender (the client's own
 *                         address); each sender has its own connection id, the
 *                         same one for each of its requests
 *
 * The server's register i holds 1000 + i. Address 100 (read), 200 (write) and 300
 * (FC 17's write) answer later: the callback hands the request's id to a thread
 * that answers it.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"

static modbus_server_t *server;

/* What the callbacks saw of the last request. */
static struct {
    pthread_mutex_t lock;
    int accept_calls, accept_function;
    uint64_t accept_conn;
    uint64_t conn;
    int socket;
    struct sockaddr_storage peer;
    uint32_t peer_length;
    int reads; /* read_registers calls */
    /* the request waiting for its answer: its id and its PDU's start */
    int id;
    uint8_t pdu[8];
} R = {.lock = PTHREAD_MUTEX_INITIALIZER};

static void saw(const modbus_request_info_t *ri)
{
    R.conn = ri->connection_id;
    R.socket = ri->socket;
    R.peer_length = 0;
    if (ri->struct_size > offsetof(modbus_request_info_t, peer_length) && ri->peer != NULL &&
        ri->peer_length <= sizeof R.peer) {
        memcpy(&R.peer, ri->peer, ri->peer_length);
        R.peer_length = ri->peer_length;
    }
}

static int defer(const modbus_request_info_t *ri)
{
    pthread_mutex_lock(&R.lock);
    R.id = ri->request_id;
    memcpy(R.pdu, ri->pdu, (size_t) (ri->pdu_length < 8 ? ri->pdu_length : 8));
    pthread_mutex_unlock(&R.lock);
    return MODBUS_REPLY_LATER;
}

static int accept_unit(const modbus_request_info_t *ri, int unit_id, void *user_data)
{
    (void) user_data;
    R.accept_calls++;
    R.accept_function = ri->function;
    R.accept_conn = ri->connection_id;
    return unit_id == 1;
}

static int read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *user_data)
{
    int i;
    (void) user_data;
    saw(ri);
    R.reads++;
    if (addr == 100) {
        return defer(ri);
    }
    if (addr + nb > 500) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    for (i = 0; i < nb; i++) {
        dest[i] = (uint16_t) (1000 + addr + i);
    }
    return 0;
}

static int write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src, void *user_data)
{
    (void) user_data;
    (void) nb;
    (void) src;
    saw(ri);
    if (addr == 200 || addr == 300) {
        return defer(ri);
    }
    return 0;
}

static const modbus_server_callbacks_t CB = {
    .struct_size = sizeof(modbus_server_callbacks_t),
    .accept_unit = accept_unit,
    .read_registers = read_registers,
    .write_registers = write_registers,
};

static void *run(void *arg)
{
    (void) arg;
    modbus_server_run(server, -1);
    return NULL;
}

/* The id of the request waiting, once its callback has run (0: none came). */
static int waiting(void)
{
    int i, id = 0;
    for (i = 0; i < 200 && id == 0; i++) {
        pthread_mutex_lock(&R.lock);
        id = R.id;
        R.id = 0;
        pthread_mutex_unlock(&R.lock);
        if (id == 0) {
            usleep(5000);
        }
    }
    return id;
}

/* A client's request answered later, by this thread, with `how`. */
struct later {
    modbus_t *ctx;
    int kind; /* 0: read 100, 1: write 200, 2: FC 17 writing 300 */
    int rc, error;
    uint16_t values[4];
};

static void *ask(void *arg)
{
    struct later *l = arg;
    uint16_t v[2] = {7, 8};
    errno = 0;
    if (l->kind == 0) {
        l->rc = modbus_read_registers(l->ctx, 100, 3, l->values);
    } else if (l->kind == 1) {
        l->rc = modbus_write_register(l->ctx, 200, 0x1234);
    } else {
        l->rc = modbus_write_and_read_registers(l->ctx, 300, 2, v, 10, 4, l->values);
    }
    l->error = errno;
    return NULL;
}

static modbus_t *client(const char *mode, int port)
{
    modbus_t *c = strcmp(mode, "udp") == 0 ? modbus_new_udp("127.0.0.1", port) : modbus_new_tcp("127.0.0.1", port);
    if (c == NULL || modbus_connect(c) < 0) {
        fprintf(stderr, "client: %s\n", modbus_strerror(errno));
        exit(2);
    }
    modbus_set_slave(c, 1);
    modbus_set_response_timeout(c, 2, 0);
    return c;
}

static void later_answers(modbus_t *c)
{
    pthread_t t;
    struct later l = {c, 0, 0, 0, {0}};
    uint16_t want[3] = {41, 42, 43}, bits_wrong[2] = {1, 2};
    int id;

    /* A deferred read, answered with the typed call. */
    pthread_create(&t, NULL, ask, &l);
    id = waiting();
    EXPECT(id > 0, "a deferred read: its id (%d)", id);
    errno = 0;
    EXPECT(modbus_server_answer_registers(server, id, bits_wrong, 2) == -1 && errno == EINVAL,
           "modbus_server_answer_registers with 2 values for a read of 3: EINVAL");
    errno = 0;
    EXPECT(modbus_server_answer(server, id, NULL, 0) == -1 && errno == EINVAL,
           "modbus_server_answer rc 0 (a write done) for a read: EINVAL");
    errno = 0;
    EXPECT(modbus_server_answer_bits(server, id, (const uint8_t *) "\1\0\1", 3) == -1 && errno == EINVAL,
           "modbus_server_answer_bits for a register read: EINVAL");
    EXPECT(modbus_server_answer_registers(server, id, want, 3) == 0, "modbus_server_answer_registers: 0");
    pthread_join(t, NULL);
    EXPECT(l.rc == 3 && memcmp(l.values, want, sizeof want) == 0,
           "the deferred read gets the values given later (rc %d: %u %u %u)", l.rc, l.values[0], l.values[1],
           l.values[2]);
    errno = 0;
    EXPECT(modbus_server_answer_registers(server, id, want, 3) == -1 && errno == EINVAL,
           "a second answer for the same id: EINVAL");

    /* A deferred write, answered with rc 0. */
    l.kind = 1;
    pthread_create(&t, NULL, ask, &l);
    id = waiting();
    EXPECT(id > 0 && R.pdu[0] == MODBUS_FC_WRITE_SINGLE_REGISTER, "a deferred write: its id (%d)", id);
    EXPECT(modbus_server_answer(server, id, NULL, 0) == 0, "modbus_server_answer rc 0: the write is done");
    pthread_join(t, NULL);
    EXPECT(l.rc == 1, "the deferred write is answered as done (rc %d, %s)", l.rc, modbus_strerror(l.error));

    /* FC 17: "later" from its write half defers the whole request. */
    l.kind = 2;
    R.reads = 0;
    pthread_create(&t, NULL, ask, &l);
    id = waiting();
    EXPECT(id > 0 && R.pdu[0] == 0x17, "FC 17 deferred by its write callback (id %d)", id);
    {
        /* The read range is in the request's PDU: address 10, 4 registers. */
        int addr = (R.pdu[1] << 8) | R.pdu[2], nb = (R.pdu[3] << 8) | R.pdu[4];
        uint16_t v[4] = {1, 2, 3, 4};
        EXPECT(addr == 10 && nb == 4, "ri->pdu tells its read range (%d, %d)", addr, nb);
        EXPECT(modbus_server_answer_registers(server, id, v, 4) == 0, "answered with its read's values");
        pthread_join(t, NULL);
        EXPECT(l.rc == 4 && memcmp(l.values, v, sizeof v) == 0 && R.reads == 0,
               "FC 17 gets the values given later, and read_registers was not called (rc %d, %d reads)", l.rc,
               R.reads);
    }

    /* The typed exception. */
    l.kind = 0;
    pthread_create(&t, NULL, ask, &l);
    id = waiting();
    errno = 0;
    EXPECT(modbus_server_answer_exception(server, id, 0) == -1 && errno == EINVAL,
           "modbus_server_answer_exception with code 0: EINVAL");
    EXPECT(modbus_server_answer_exception(server, id, MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY) == 0,
           "modbus_server_answer_exception: 0");
    pthread_join(t, NULL);
    EXPECT(l.rc == -1 && l.error == EMBXSBUSY, "the deferred read gets exception 06 (%s)", modbus_strerror(l.error));
}

int main(int argc, char **argv)
{
    modbus_t *ctx, *a, *b;
    pthread_t t;
    uint16_t regs[4];
    int udp, port, s, rc;
    struct sockaddr_in sin;
    socklen_t len = sizeof sin;

    if (argc < 2) {
        fprintf(stderr, "usage: %s tcp|udp\n", argv[0]);
        return 2;
    }
    udp = strcmp(argv[1], "udp") == 0;
    chk_set_prefix(udp ? "udp: " : "tcp: ");
    ctx = udp ? modbus_new_udp("127.0.0.1", 0) : modbus_new_tcp("127.0.0.1", 0);
    s = ctx == NULL ? -1 : modbus_tcp_listen(ctx, 4);
    if (s < 0 || getsockname(s, (struct sockaddr *) &sin, &len) < 0) {
        fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
        return 2;
    }
    port = ntohs(sin.sin_port);
    modbus_set_socket(ctx, s);
    if (getenv("RUNNER_DEBUG") != NULL) {
        modbus_set_debug(ctx, TRUE);
    }
    server = modbus_server_new(ctx, 8);
    if (server != NULL) {
        /* struct_size: too small, in the middle of a member, larger with a member
         * this library does not know set: EINVAL; larger with a zero tail: taken. */
        struct {
            modbus_server_callbacks_t cb;
            void *future[2];
        } big;
        modbus_server_callbacks_t small = CB;
        small.struct_size = offsetof(modbus_server_callbacks_t, other);
        errno = 0;
        EXPECT(modbus_server_set_callbacks(server, &small, NULL) == -1 && errno == EINVAL,
               "modbus_server_set_callbacks: struct_size below the first published size, EINVAL");
        small.struct_size = sizeof small - 2;
        errno = 0;
        EXPECT(modbus_server_set_callbacks(server, &small, NULL) == -1 && errno == EINVAL,
               "modbus_server_set_callbacks: struct_size in the middle of a member, EINVAL");
        memset(&big, 0, sizeof big);
        big.cb = CB;
        big.cb.struct_size = sizeof big;
        big.future[0] = &big;
        errno = 0;
        EXPECT(modbus_server_set_callbacks(server, &big.cb, NULL) == -1 && errno == EINVAL,
               "modbus_server_set_callbacks: a member this library does not know set, EINVAL");
        big.future[0] = NULL;
        EXPECT(modbus_server_set_callbacks(server, &big.cb, NULL) == 0,
               "modbus_server_set_callbacks: a larger struct with a zero tail is taken");
    }
    if (server == NULL || modbus_server_set_callbacks(server, &CB, NULL) != 0) {
        fprintf(stderr, "server: %s\n", modbus_strerror(errno));
        return 2;
    }
    pthread_create(&t, NULL, run, NULL);

    a = client(argv[1], port);
    rc = modbus_read_registers(a, 5, 2, regs);
    EXPECT(rc == 2 && regs[0] == 1005, "a read");
    EXPECT(R.accept_calls > 0 && R.accept_function == 3 && R.accept_conn == R.conn && R.conn != 0,
           "accept_unit sees the request info: FC %d, connection %llu", R.accept_function,
           (unsigned long long) R.accept_conn);
    if (!udp) {
        uint64_t first = R.conn;
        int first_socket = R.socket;
        EXPECT(R.peer_length > 0 && R.peer.ss_family == AF_INET, "ri->peer: the TCP client's address");
        later_answers(a);
        modbus_close(a);
        modbus_free(a);
        usleep(200000); /* the server sees the first client leave */
        b = client(argv[1], port);
        rc = modbus_read_registers(b, 5, 2, regs);
        EXPECT(rc == 2 && R.conn != 0 && R.conn != first,
               "a second client, after the first left: another connection id (%llu after %llu)",
               (unsigned long long) R.conn, (unsigned long long) first);
        EXPECT(R.socket == first_socket, "(on the server, the same descriptor number: %d, %d)", R.socket,
               first_socket);
        modbus_close(b);
        modbus_free(b);
    } else {
        struct sockaddr_in mine;
        socklen_t mlen = sizeof mine;
        uint64_t first = R.conn;
        getsockname(modbus_get_socket(a), (struct sockaddr *) &mine, &mlen);
        EXPECT(R.peer_length >= sizeof(struct sockaddr_in) && R.peer.ss_family == AF_INET &&
                   ((struct sockaddr_in *) &R.peer)->sin_port == mine.sin_port,
               "ri->peer is the datagram's sender (port %d, the client's %d)",
               ntohs(((struct sockaddr_in *) &R.peer)->sin_port), ntohs(mine.sin_port));
        b = client(argv[1], port);
        rc = modbus_read_registers(b, 5, 2, regs);
        EXPECT(rc == 2 && R.conn != 0 && R.conn != first,
               "another sender on the one socket: another connection id (%llu, %llu)", (unsigned long long) R.conn,
               (unsigned long long) first);
        rc = modbus_read_registers(a, 5, 2, regs);
        EXPECT(rc == 2 && R.conn == first,
               "the first sender again: its own id again (%llu)", (unsigned long long) R.conn);
        later_answers(b);
        modbus_close(a);
        modbus_free(a);
        modbus_close(b);
        modbus_free(b);
    }
    modbus_server_stop(server);
    pthread_join(t, NULL);
    modbus_server_free(server);
    close(s);
    modbus_free(ctx);
    chk_set_prefix("");
    return chk_summary();
}
