/*
 * tls-test: the client side of the Modbus/TCP Security tests (c-tests/suites/tls.sh),
 * against examples/tls-server.c and its role policy (Operator: everything; Reader:
 * reads; anything else: refused with exception 01).
 *
 *   tls-test CERTDIR HOST PORT SCENARIO [N]
 *
 * Scenarios (each prints LIBINFO, then "ok   - ..." or "FAIL - ..." lines and
 * "N passed, M failed" (c-tests/common/check.h); exit 0 when every check passed):
 *   operator   reads registers 0-4 (1000..1004 or what a write left), writes one and
 *              reads it back; the server's certificate has no role (ENOENT)
 *   reader     reads; a write gets EMBXILFUN and changes nothing
 *   norole     a read gets EMBXILFUN
 *   nocert     no client certificate: EMBTLSNOCERT (at connect or at the first request:
 *              with TLS 1.3 the client's handshake ends before the server's verdict)
 *   rogue      a client of another CA: EMBTLSUNKNOWNCA
 *   alert N    against c-tests/tls/alert_server.py, which refuses the client's
 *              certificate while the client is still writing its flight (TLS 1.2; the
 *              client certificate "bulky": a chain of megabytes) and resets the
 *              connection: each of N connects fails with EMBTLSUNKNOWNCA, the alert
 *              the server sent, not with the failed write's ECONNRESET or EPIPE
 *   expired    an expired client certificate: EMBTLSEXPIRED
 *   wrongname  the server's certificate is for another name: modbus_connect fails
 *              with EMBTLSNAME
 *   noca       no CA set: modbus_connect fails with EMBTLSCONFIG
 *   resume     connects twice with the same context; the debug trace of the second
 *              handshake says "resumed"
 *   many N     N clients at once (processes), each writing and reading back its own
 *              register 10 + i
 *   reconnect  cut: connect, read, then the next connect after a peer's reset works
 *   halfrecord against c-tests/tls/cut.py's server, which sends half of the answer's
 *              record and closes: the read fails (ECONNRESET, as when a TCP peer goes
 *              away) at once, not at the timeout; the next connect and read work
 *   stop       issue 19's rules on TLS contexts, in this one process (HOST and PORT
 *              unused): another thread's modbus_close, or a signal handler's, ends a
 *              client's read from a silent TLS server, a client's handshake with a
 *              server that never answers it, a server's accept whose client stalls
 *              in the handshake, and a server's receive from a silent client: -1
 *              EBADF within 1.5 s (timeouts are 10 s)
 *   callback   (in this process) an authorization callback that makes another
 *              socket current gets modbus_reply -1 EINVAL and nothing sent (the
 *              client times out); one that closes the context gets -1 EBADF
 *   sessions   (in this process) one server context, two clients (Operator, Reader):
 *              modbus_set_socket brings each client's session back (its role);
 *              a number the application closed and that now names another socket
 *              never meets the old session (role ENOENT, receive -1 EMBTLS); the
 *              session of a client that went is dropped once its socket stops being
 *              current (role ENOENT; receive -1 ECONNRESET, as on a TCP socket)
 *   later      (in this process) a server answering through modbus_reply_dispatch:
 *              the request info names the client's role (Operator); of two requests
 *              in flight from the event-driven client, the first is answered after
 *              the second, and each gets its own values
 *   caaspeer   (in this process) a server presenting its CA's certificate as its
 *              own: the client's connect fails with EMBTLSCACERT, and its debug trace
 *              says why
 *   threads N  N threads share one client context, 300 write/read-back pairs each on
 *              their own register (80 + i): every answer right
 *   password   keys encrypted with a password (make-certs.sh): without it or with a
 *              wrong one EMBTLSPASSWORD; with it (PBES2 with PBKDF2 or scrypt) the
 *              client connects and writes as Operator; PBES1 and OpenSSL's older
 *              encrypted PEM are refused with EINVAL; a password given for a key that
 *              is not encrypted is not used
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"

static const char *dir;

static char *path(const char *name, const char *ext)
{
    static char buf[4][512];
    static int i;
    char *p = buf[i++ % 4];
    snprintf(p, 512, "%s/%s.%s", dir, name, ext);
    return p;
}

/* A TLS client context with the client certificate `who` (NULL: none). */
static modbus_t *client(const char *host, const char *port, const char *who, int with_ca)
{
    modbus_t *ctx = modbus_new_tcp_tls_pi(host, port);
    if (ctx == NULL) {
        EXPECT_DETAIL(0, "modbus_new_tcp_tls_pi", modbus_strerror(errno));
        exit(1);
    }
    if (with_ca && modbus_set_tls_ca(ctx, path("ca", "pem")) == -1)
        EXPECT_DETAIL(0, "modbus_set_tls_ca", modbus_strerror(errno));
    if (who != NULL && modbus_set_tls_certificate(ctx, path(who, "pem"), path(who, "key")) == -1)
        EXPECT_DETAIL(0, "modbus_set_tls_certificate", modbus_strerror(errno));
    return ctx;
}

/* Connects and reads: the errno of the first failure, 0 if both worked. */
static int connect_and_read(modbus_t *ctx, uint16_t *regs)
{
    if (modbus_connect(ctx) == -1)
        return errno;
    if (modbus_read_registers(ctx, 0, 5, regs) != 5)
        return errno;
    return 0;
}

static void expect_refusal(const char *host, const char *port, const char *who, int want, const char *what)
{
    uint16_t regs[5];
    modbus_t *ctx = client(host, port, who, 1);
    int e = connect_and_read(ctx, regs);
    char detail[200];
    snprintf(detail, sizeof detail, "errno %d (%s), want %d (%s)", e, e ? modbus_strerror(e) : "none", want,
             modbus_strerror(want));
    EXPECT_DETAIL(e == want, what, detail);
    modbus_close(ctx);
    modbus_free(ctx);
}

/* ---- stop: issue 19's rules on TLS contexts ---- */

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static void pause_s(double s)
{
    struct timespec ts = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

static modbus_t *volatile stop_target; /* what the closer thread or the handler closes */
static volatile int peer_done;         /* tells a peer thread to go */
static volatile int call_done;         /* the stopped call has returned */
static pthread_t main_thread;

/* Closes 0.3 s after it starts, and again every 0.1 s until the call has returned:
 * on a loaded machine a close may land before the call has started (and then
 * closes nothing it waits on). */
static void *closer(void *arg)
{
    (void)arg;
    pause_s(0.3);
    while (!call_done) {
        modbus_close(stop_target);
        pause_s(0.1);
    }
    return NULL;
}

static void on_usr1(int sig)
{
    (void)sig;
    modbus_close(stop_target);
}

static void *signaller(void *arg)
{
    (void)arg;
    pause_s(0.3);
    while (!call_done) {
        pthread_kill(main_thread, SIGUSR1);
        pause_s(0.1);
    }
    return NULL;
}

/* A TLS server context listening on a port of 127.0.0.1 the kernel picks. */
static modbus_t *listening_server(int *listener, int *port)
{
    modbus_t *ctx = modbus_new_tcp_tls("127.0.0.1", 0);
    struct sockaddr_in sa;
    socklen_t sl = sizeof sa;
    if (ctx == NULL || modbus_set_tls_certificate(ctx, path("server", "pem"), path("server", "key")) == -1 ||
        modbus_set_tls_ca(ctx, path("ca", "pem")) == -1) {
        fprintf(stderr, "server context: %s\n", modbus_strerror(errno));
        exit(1);
    }
    modbus_set_response_timeout(ctx, 10, 0);
    *listener = modbus_tcp_listen(ctx, 4);
    if (*listener == -1 || getsockname(*listener, (struct sockaddr *)&sa, &sl) == -1) {
        fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
        exit(1);
    }
    *port = ntohs(sa.sin_port);
    return ctx;
}

struct peer {
    modbus_t *ctx;
    int listener, port, raw;
};

/* Accepts one TLS client, then stays silent until told to go. */
static void *silent_server(void *arg)
{
    struct peer *p = arg;
    modbus_tcp_accept(p->ctx, &p->listener);
    while (!peer_done)
        pause_s(0.01);
    return NULL;
}

/* Accepts a TCP connection and never answers the handshake. */
static void *mute_listener(void *arg)
{
    struct peer *p = arg;
    p->raw = accept(p->listener, NULL, NULL);
    while (!peer_done)
        pause_s(0.01);
    return NULL;
}

/* A TLS client (operator) that connects, then stays silent until told to go. */
static void *silent_client(void *arg)
{
    struct peer *p = arg;
    char port[16];
    snprintf(port, sizeof port, "%d", p->port);
    p->ctx = client("127.0.0.1", port, "operator", 1);
    modbus_connect(p->ctx);
    while (!peer_done)
        pause_s(0.01);
    return NULL;
}

/* Connects over plain TCP and sends nothing. */
static void *mute_client(void *arg)
{
    struct peer *p = arg;
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons((uint16_t)p->port)};
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    p->raw = socket(AF_INET, SOCK_STREAM, 0);
    connect(p->raw, (struct sockaddr *)&sa, sizeof sa);
    while (!peer_done)
        pause_s(0.01);
    return NULL;
}

/* Starts the stopper: another thread's modbus_close, or a signal whose handler calls it. */
static pthread_t start_stopper(modbus_t *target, int by_signal)
{
    pthread_t t;
    stop_target = target;
    call_done = 0;
    pthread_create(&t, NULL, by_signal ? signaller : closer, NULL);
    return t;
}

static void stop_scenario(void)
{
    char detail[200];
    uint16_t regs[1];
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_usr1; /* no SA_RESTART */
    sigaction(SIGUSR1, &sa, NULL);
    main_thread = pthread_self();

    for (int by_signal = 0; by_signal < 2; by_signal++) {
        const char *how = by_signal ? "a signal handler's modbus_close" : "another thread's modbus_close";
        char port[16];

        /* A client reading from a server that never answers. */
        struct peer srv = {0};
        srv.ctx = listening_server(&srv.listener, &srv.port);
        peer_done = 0;
        pthread_t peer, stopper;
        pthread_create(&peer, NULL, silent_server, &srv);
        snprintf(port, sizeof port, "%d", srv.port);
        modbus_t *ctx = client("127.0.0.1", port, "operator", 1);
        modbus_set_response_timeout(ctx, 10, 0);
        int rc = modbus_connect(ctx);
        EXPECT_DETAIL(rc == 0, "stop: connect to the silent server", rc ? modbus_strerror(errno) : NULL);
        stopper = start_stopper(ctx, by_signal);
        double t0 = now();
        rc = modbus_read_registers(ctx, 0, 1, regs);
        int e = errno;
        double took = now() - t0;
        call_done = 1;
        pthread_join(stopper, NULL);
        snprintf(detail, sizeof detail, "%s: rc %d errno %d (%s) after %.2f s", how, rc, e, modbus_strerror(e), took);
        EXPECT_DETAIL(rc == -1 && e == EBADF && took < 1.5, "stop: a client's TLS read ends with EBADF", detail);
        EXPECT_DETAIL(modbus_get_socket(ctx) == -1, "stop: the client's socket is closed", detail);
        peer_done = 1;
        pthread_join(peer, NULL);
        modbus_free(ctx);
        modbus_close(srv.ctx);
        close(srv.listener);
        modbus_free(srv.ctx);

        /* A client whose handshake the server never answers. */
        struct peer mute = {0};
        mute.ctx = listening_server(&mute.listener, &mute.port);
        peer_done = 0;
        pthread_create(&peer, NULL, mute_listener, &mute);
        snprintf(port, sizeof port, "%d", mute.port);
        ctx = client("127.0.0.1", port, "operator", 1);
        modbus_set_response_timeout(ctx, 10, 0);
        stopper = start_stopper(ctx, by_signal);
        t0 = now();
        rc = modbus_connect(ctx);
        e = errno;
        took = now() - t0;
        call_done = 1;
        pthread_join(stopper, NULL);
        snprintf(detail, sizeof detail, "%s: rc %d errno %d (%s) after %.2f s", how, rc, e, modbus_strerror(e), took);
        EXPECT_DETAIL(rc == -1 && e == EBADF && took < 1.5 && modbus_get_socket(ctx) == -1,
                      "stop: a client's stalled handshake ends with EBADF", detail);
        peer_done = 1;
        pthread_join(peer, NULL);
        close(mute.raw);
        modbus_free(ctx);
        close(mute.listener);
        modbus_free(mute.ctx);

        /* A server accepting a client that stalls in the handshake. */
        struct peer stall = {0};
        modbus_t *server = listening_server(&stall.listener, &stall.port);
        peer_done = 0;
        pthread_create(&peer, NULL, mute_client, &stall);
        stopper = start_stopper(server, by_signal);
        t0 = now();
        rc = modbus_tcp_accept(server, &stall.listener);
        e = errno;
        took = now() - t0;
        call_done = 1;
        pthread_join(stopper, NULL);
        snprintf(detail, sizeof detail, "%s: rc %d errno %d (%s) after %.2f s", how, rc, e, modbus_strerror(e), took);
        EXPECT_DETAIL(rc == -1 && e == EBADF && took < 1.5,
                      "stop: a server's accept with a stalled handshake ends with EBADF", detail);
        peer_done = 1;
        pthread_join(peer, NULL);
        close(stall.raw);
        close(stall.listener);
        modbus_free(server);

        /* A server receiving from a client that sends nothing. */
        struct peer quiet = {0};
        server = listening_server(&quiet.listener, &quiet.port);
        modbus_set_indication_timeout(server, 0, 0); /* wait forever */
        peer_done = 0;
        pthread_create(&peer, NULL, silent_client, &quiet);
        rc = modbus_tcp_accept(server, &quiet.listener);
        EXPECT_DETAIL(rc >= 0, "stop: the server accepts the silent client", rc < 0 ? modbus_strerror(errno) : NULL);
        uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
        stopper = start_stopper(server, by_signal);
        t0 = now();
        rc = modbus_receive(server, query);
        e = errno;
        took = now() - t0;
        call_done = 1;
        pthread_join(stopper, NULL);
        snprintf(detail, sizeof detail, "%s: rc %d errno %d (%s) after %.2f s", how, rc, e, modbus_strerror(e), took);
        EXPECT_DETAIL(rc == -1 && e == EBADF && took < 1.5, "stop: a server's TLS receive ends with EBADF", detail);
        peer_done = 1;
        pthread_join(peer, NULL);
        modbus_close(quiet.ctx);
        modbus_free(quiet.ctx);
        close(quiet.listener);
        modbus_free(server);
    }
}

/* ---- callback: what modbus_reply does when the callback switches or closes ---- */

static int switch_to; /* the socket the callback makes current; -1: it closes the context */

static int meddling(modbus_t *ctx, const char *role, int unit_id, int function, int address, int nb, void *data)
{
    (void)role, (void)unit_id, (void)function, (void)address, (void)nb, (void)data;
    if (switch_to >= 0)
        modbus_set_socket(ctx, switch_to);
    else
        modbus_close(ctx);
    return 1;
}

/* A client that sends one read and waits up to 1 s for its answer. */
static void *asking_client(void *arg)
{
    struct peer *p = arg;
    char port[16];
    uint16_t v;
    snprintf(port, sizeof port, "%d", p->port);
    p->ctx = client("127.0.0.1", port, "operator", 1);
    modbus_set_response_timeout(p->ctx, 1, 0);
    p->raw = modbus_connect(p->ctx) == 0 && modbus_read_registers(p->ctx, 0, 1, &v) == 1 ? 0 : errno;
    return NULL;
}

static void callback_scenario(void)
{
    char detail[200];
    for (int closes = 0; closes < 2; closes++) {
        struct peer c = {0};
        uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
        modbus_mapping_t *map = modbus_mapping_new(10, 10, 10, 10);
        modbus_t *server = listening_server(&c.listener, &c.port);
        modbus_set_tls_authorization(server, meddling, NULL);
        pthread_t t;
        pthread_create(&t, NULL, asking_client, &c);
        int rc = modbus_tcp_accept(server, &c.listener);
        EXPECT_DETAIL(rc >= 0, "callback: accept", rc < 0 ? modbus_strerror(errno) : NULL);
        rc = modbus_receive(server, query);
        EXPECT_DETAIL(rc > 0, "callback: the request is received", rc < 0 ? modbus_strerror(errno) : NULL);
        int accepted = modbus_get_socket(server);
        switch_to = closes ? -1 : c.listener;
        errno = 0;
        int sent = modbus_reply(server, query, rc, map);
        int e = errno;
        pthread_join(t, NULL);
        snprintf(detail, sizeof detail, "modbus_reply %d errno %d (%s); the client: %s", sent, e, modbus_strerror(e),
                 c.raw ? modbus_strerror(c.raw) : "answered");
        if (closes)
            EXPECT_DETAIL(sent == -1 && e == EBADF && c.raw != 0,
                          "callback: a callback that closes the context: modbus_reply -1 EBADF, no answer", detail);
        else
            EXPECT_DETAIL(sent == -1 && e == EINVAL && c.raw == ETIMEDOUT,
                          "callback: a callback that switches sockets: modbus_reply -1 EINVAL, nothing sent", detail);
        if (!closes)
            close(accepted);
        modbus_close(c.ctx);
        modbus_free(c.ctx);
        close(c.listener);
        modbus_free(server);
        modbus_mapping_free(map);
    }
}

/* ---- sessions: TLS sessions belong to their socket ---- */

struct holder {
    int port;
    const char *who;
    modbus_t *ctx;
    volatile int go;
};

/* A TLS client that connects, then waits until told to close. */
static void *holding_client(void *arg)
{
    struct holder *h = arg;
    char port[16];
    snprintf(port, sizeof port, "%d", h->port);
    h->ctx = client("127.0.0.1", port, h->who, 1);
    if (modbus_connect(h->ctx) == -1)
        EXPECT_DETAIL(0, "sessions: a client connects", modbus_strerror(errno));
    while (!h->go)
        pause_s(0.01);
    modbus_close(h->ctx);
    return NULL;
}

/* The peer's role on the server's current socket ("ENOENT" when it has none). */
static const char *role_of(modbus_t *server, char *buf, size_t size)
{
    if (modbus_get_tls_peer_role(server, buf, size) == -1)
        snprintf(buf, size, "%s", errno == ENOENT ? "ENOENT" : modbus_strerror(errno));
    return buf;
}

static void sessions_scenario(void)
{
    char detail[200], role[64];
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    int listener, port, fds[2];
    modbus_t *server = listening_server(&listener, &port);
    modbus_set_response_timeout(server, 2, 0);
    struct holder a = {.port = port, .who = "operator"}, b = {.port = port, .who = "reader"};
    pthread_t ta, tb;
    pthread_create(&ta, NULL, holding_client, &a);
    int fa = modbus_tcp_accept(server, &listener);
    pthread_create(&tb, NULL, holding_client, &b);
    int fb = modbus_tcp_accept(server, &listener);
    EXPECT_DETAIL(fa >= 0 && fb >= 0, "sessions: two clients accepted",
                  fa < 0 || fb < 0 ? modbus_strerror(errno) : NULL);

    modbus_set_socket(server, fa);
    EXPECT_DETAIL(strcmp(role_of(server, role, sizeof role), "Operator") == 0,
                  "sessions: modbus_set_socket brings the first client's session back", role);
    modbus_set_socket(server, fb);
    EXPECT_DETAIL(strcmp(role_of(server, role, sizeof role), "Reader") == 0,
                  "sessions: and the second client's", role);
    modbus_set_socket(server, fa);
    EXPECT_DETAIL(strcmp(role_of(server, role, sizeof role), "Operator") == 0, "sessions: and the first again", role);

    /* The application closes the first client's socket itself (as a poll loop does),
       and the number comes back as another socket. */
    modbus_set_socket(server, fb);
    close(fa);
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, fds) == -1 || dup2(fds[0], fa) != fa) {
        EXPECT_DETAIL(0, "sessions: the number is reused", strerror(errno));
        exit(1);
    }
    close(fds[0]);
    modbus_set_socket(server, fa);
    EXPECT_DETAIL(strcmp(role_of(server, role, sizeof role), "ENOENT") == 0,
                  "sessions: a reused number does not meet the old session (role)", role);
    errno = 0;
    int rc = modbus_receive(server, query);
    snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
    EXPECT_DETAIL(rc == -1 && errno == EMBTLS, "sessions: a reused number: receive -1 EMBTLS", detail);

    /* The second client goes: its session ends with its socket's turn. */
    b.go = 1;
    pthread_join(tb, NULL);
    modbus_set_socket(server, fb);
    errno = 0;
    rc = modbus_receive(server, query);
    snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
    EXPECT_DETAIL(rc == -1 && errno == ECONNRESET, "sessions: a client that went: receive -1 ECONNRESET", detail);
    modbus_set_socket(server, fa);
    modbus_set_socket(server, fb);
    EXPECT_DETAIL(strcmp(role_of(server, role, sizeof role), "ENOENT") == 0,
                  "sessions: its session is dropped once its socket is no longer current", role);
    errno = 0;
    rc = modbus_receive(server, query);
    snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
    EXPECT_DETAIL(rc == -1 && errno == ECONNRESET, "sessions: then its receive still says ECONNRESET", detail);

    a.go = 1;
    pthread_join(ta, NULL);
    modbus_free(a.ctx);
    modbus_free(b.ctx);
    close(fa);
    close(fds[1]);
    close(fb);
    close(listener);
    modbus_free(server);
}

/* ---- later: callbacks over TLS, a request answered after the next one ---- */

static char later_role[64];

static int later_read(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *user_data)
{
    (void) user_data;
    snprintf(later_role, sizeof later_role, "%s", ri->tls_role != NULL ? ri->tls_role : "(null)");
    for (int i = 0; i < nb; i++)
        dest[i] = (uint16_t) (addr + i);
    return 0;
}

static const modbus_server_callbacks_t LATER_CB = {
    .struct_size = sizeof(modbus_server_callbacks_t),
    .read_registers = later_read,
};

struct later_server {
    modbus_t *ctx;
    int listener;
};

/* Serves one client: a read at 150 waits for the next request, answered first. */
static void *later_serve(void *arg)
{
    struct later_server *ls = arg;
    uint8_t req[MODBUS_TCP_MAX_ADU_LENGTH], held[MODBUS_TCP_MAX_ADU_LENGTH];
    int held_len = 0;
    if (modbus_tcp_accept(ls->ctx, &ls->listener) < 0)
        return NULL;
    for (;;) {
        int rc = modbus_receive_dispatch(ls->ctx, req, &LATER_CB, NULL);
        if (rc < 0)
            break;
        if (req[7] == MODBUS_FC_READ_HOLDING_REGISTERS && req[8] == 0 && req[9] == 150 && held_len == 0) {
            memcpy(held, req, (size_t) rc);
            held_len = rc;
            continue;
        }
        modbus_reply_dispatch(ls->ctx, req, rc, &LATER_CB, NULL);
        if (held_len > 0) {
            modbus_reply_dispatch(ls->ctx, held, held_len, &LATER_CB, NULL);
            held_len = 0;
        }
    }
    modbus_close(ls->ctx);
    return NULL;
}

static int later_order;
static void later_done(modbus_t *ctx, int id, int rc, int error, void *user_data)
{
    (void) ctx;
    (void) id;
    (void) error;
    ((int *) user_data)[0] = rc;
    ((int *) user_data)[1] = later_order++;
}

static void later_scenario(void)
{
    struct later_server ls;
    int port, a[2] = {-2, -1}, b[2] = {-2, -1};
    uint16_t ra[4], rb[4], regs[2];
    char portstr[16], detail[160];
    pthread_t t;
    ls.ctx = listening_server(&ls.listener, &port);
    pthread_create(&t, NULL, later_serve, &ls);
    snprintf(portstr, sizeof portstr, "%d", port);
    modbus_t *ctx = client("127.0.0.1", portstr, "operator", 1);
    int rc = modbus_connect(ctx);
    EXPECT_DETAIL(rc == 0, "later: connects", rc ? modbus_strerror(errno) : NULL);
    rc = modbus_read_registers(ctx, 7, 2, regs);
    EXPECT_DETAIL(rc == 2 && regs[0] == 7 && strcmp(later_role, "Operator") == 0,
                  "later: the callback's request info names the client's role", later_role);
    EXPECT(modbus_set_max_in_flight(ctx, 2) == 0, "later: two requests in flight");
    EXPECT(modbus_read_registers_async(ctx, 150, 4, ra, later_done, a) >= 0 &&
               modbus_read_registers_async(ctx, 160, 4, rb, later_done, b) >= 0,
           "later: two reads submitted");
    for (int i = 0; i < 200 && modbus_pending(ctx) > 0; i++) {
        struct pollfd pfd;
        int to;
        modbus_get_pollfd(ctx, &pfd, &to);
        pfd.revents = 0;
        poll(&pfd, 1, to < 0 || to > 50 ? 50 : to);
        modbus_process(ctx, pfd.revents);
    }
    snprintf(detail, sizeof detail, "rc %d, %d; order %d, %d", a[0], b[0], a[1], b[1]);
    EXPECT_DETAIL(a[0] == 4 && b[0] == 4 && ra[0] == 150 && ra[3] == 153 && rb[0] == 160 && rb[3] == 163 &&
                      b[1] == 0 && a[1] == 1,
                  "later: over TLS, the read at 150 answered after the read at 160, each with its values", detail);
    modbus_close(ctx);
    pthread_join(t, NULL);
    modbus_free(ctx);
    close(ls.listener);
    modbus_free(ls.ctx);
}

/* ---- caaspeer: a server that presents its CA's certificate as its own ---- */

static void *caaspeer_serve(void *arg)
{
    struct later_server *ls = arg;
    modbus_tcp_accept(ls->ctx, &ls->listener); /* fails: the client refuses */
    return NULL;
}

static void caaspeer_scenario(void)
{
    struct later_server ls;
    int port;
    char portstr[16], detail[200];
    pthread_t t;
    ls.ctx = listening_server(&ls.listener, &port);
    if (modbus_set_tls_certificate(ls.ctx, path("ca", "pem"), path("ca", "key")) == -1) {
        EXPECT_DETAIL(0, "caaspeer: the server takes the CA's certificate and key", modbus_strerror(errno));
        exit(1);
    }
    modbus_set_response_timeout(ls.ctx, 2, 0);
    pthread_create(&t, NULL, caaspeer_serve, &ls);
    snprintf(portstr, sizeof portstr, "%d", port);
    modbus_t *ctx = client("127.0.0.1", portstr, "operator", 1);
    modbus_set_debug(ctx, TRUE); /* the trace names the reason (checked by tls.sh) */
    errno = 0;
    int rc = modbus_connect(ctx);
    int e = errno;
    snprintf(detail, sizeof detail, "rc %d, errno %d (%s)", rc, e, modbus_strerror(e));
    EXPECT_DETAIL(rc == -1 && e == EMBTLSCACERT && strstr(modbus_strerror(e), "CA certificate") != NULL,
                  "caaspeer: the client refuses a CA certificate as the server's own: EMBTLSCACERT", detail);
    modbus_close(ctx);
    pthread_join(t, NULL);
    modbus_free(ctx);
    close(ls.listener);
    modbus_free(ls.ctx);
}

/* ---- threads: one client context shared by N threads ---- */

static modbus_t *shared;

static void *worker(void *arg)
{
    int i = (int)(intptr_t)arg, bad = 0;
    for (int k = 0; k < 300; k++) {
        uint16_t v = (uint16_t)(i * 1000 + k), got = 0;
        if (modbus_write_register(shared, 80 + i, v) != 1 || modbus_read_registers(shared, 80 + i, 1, &got) != 1 ||
            got != v)
            bad++;
    }
    return (void *)(intptr_t)bad;
}

int main(int argc, char *argv[])
{
    if (argc < 5) {
        fprintf(stderr, "usage: %s CERTDIR HOST PORT SCENARIO [N]\n", argv[0]);
        return 2;
    }
    /* The LIBINFO line: printed before main by ../common/libinfo.c. */
    dir = argv[1];
    const char *host = argv[2], *port = argv[3], *scenario = argv[4];
    uint16_t regs[5];
    char detail[256];

    if (strcmp(scenario, "operator") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        int e = connect_and_read(ctx, regs);
        EXPECT_DETAIL(e == 0, "operator: connect and read 5 registers", e ? modbus_strerror(e) : NULL);
        snprintf(detail, sizeof detail, "%u %u %u %u %u", regs[0], regs[1], regs[2], regs[3], regs[4]);
        EXPECT_DETAIL(e == 0 && regs[1] == 1001 && regs[4] == 1004, "operator: values", detail);
        EXPECT_DETAIL(modbus_write_register(ctx, 3, 4242) == 1, "operator: write allowed", modbus_strerror(errno));
        EXPECT_DETAIL(modbus_read_registers(ctx, 3, 1, regs) == 1 && regs[0] == 4242,
                      "operator: written value read back", NULL);
        char role[64];
        int rc = modbus_get_tls_peer_role(ctx, role, sizeof role);
        EXPECT_DETAIL(rc == -1 && errno == ENOENT, "operator: the server's certificate has no role (ENOENT)", NULL);
        EXPECT_DETAIL(modbus_write_register(ctx, 3, 1003) == 1, "operator: value restored", NULL);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "reader") == 0) {
        modbus_t *ctx = client(host, port, "reader", 1);
        int e = connect_and_read(ctx, regs);
        EXPECT_DETAIL(e == 0, "reader: connect and read", e ? modbus_strerror(e) : NULL);
        int rc = modbus_write_register(ctx, 2, 7);
        snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
        EXPECT_DETAIL(rc == -1 && errno == EMBXILFUN, "reader: write refused with exception 01", detail);
        uint16_t before = regs[2];
        EXPECT_DETAIL(modbus_read_registers(ctx, 2, 1, regs) == 1 && regs[0] == before, "reader: register unchanged",
                      NULL);
        rc = modbus_write_registers(ctx, 0, 2, regs);
        EXPECT_DETAIL(rc == -1 && errno == EMBXILFUN, "reader: FC 16 refused too", NULL);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "norole") == 0) {
        modbus_t *ctx = client(host, port, "norole", 1);
        int e = connect_and_read(ctx, regs);
        snprintf(detail, sizeof detail, "errno %d (%s)", e, modbus_strerror(e));
        EXPECT_DETAIL(e == EMBXILFUN, "norole: a read is refused with exception 01", detail);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "nocert") == 0) {
        expect_refusal(host, port, NULL, EMBTLSNOCERT, "nocert: refused, EMBTLSNOCERT");
    } else if (strcmp(scenario, "rogue") == 0) {
        expect_refusal(host, port, "rogue", EMBTLSUNKNOWNCA, "rogue: refused, EMBTLSUNKNOWNCA");
    } else if (strcmp(scenario, "alert") == 0) {
        int n = argc > 5 ? atoi(argv[5]) : 1, right = 0;
        for (int i = 0; i < n; i++) {
            modbus_t *ctx = client(host, port, "bulky", 1);
            int rc = modbus_connect(ctx), e = errno;
            printf("# connect %d: rc %d errno %d (%s)\n", i, rc, e, rc == -1 ? modbus_strerror(e) : "none");
            right += rc == -1 && e == EMBTLSUNKNOWNCA;
            modbus_close(ctx);
            modbus_free(ctx);
        }
        snprintf(detail, sizeof detail, "%d of %d", right, n);
        EXPECT_DETAIL(n > 0 && right == n, "alert: a refusal while the client writes is EMBTLSUNKNOWNCA every time",
                      detail);
    } else if (strcmp(scenario, "expired") == 0) {
        expect_refusal(host, port, "expired", EMBTLSEXPIRED, "expired: refused, EMBTLSEXPIRED");
    } else if (strcmp(scenario, "wrongname") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        int rc = modbus_connect(ctx);
        snprintf(detail, sizeof detail, "rc %d errno %d (%s), socket %d", rc, errno, modbus_strerror(errno),
                 modbus_get_socket(ctx));
        EXPECT_DETAIL(rc == -1 && errno == EMBTLSNAME && modbus_get_socket(ctx) == -1,
                      "wrongname: connect fails with EMBTLSNAME, no socket left", detail);
        modbus_free(ctx);
    } else if (strcmp(scenario, "noca") == 0) {
        modbus_t *ctx = client(host, port, "operator", 0);
        int rc = modbus_connect(ctx);
        EXPECT_DETAIL(rc == -1 && errno == EMBTLSCONFIG, "noca: connect fails with EMBTLSCONFIG",
                      modbus_strerror(errno));
        modbus_free(ctx);
    } else if (strcmp(scenario, "resume") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        modbus_set_debug(ctx, TRUE);
        int e1 = connect_and_read(ctx, regs);
        modbus_close(ctx);
        int e2 = connect_and_read(ctx, regs);
        modbus_close(ctx);
        modbus_free(ctx);
        fflush(stdout);
        EXPECT_DETAIL(e1 == 0 && e2 == 0, "resume: two connections on one context", NULL);
    } else if (strcmp(scenario, "many") == 0) {
        int n = argc > 5 ? atoi(argv[5]) : 64;
        pid_t pids[256];
        fflush(stdout);
        for (int i = 0; i < n && i < 256; i++) {
            pids[i] = fork();
            if (pids[i] == 0) {
                uint16_t v = 0;
                modbus_t *ctx = client(host, port, "operator", 1);
                int ok = connect_and_read(ctx, regs) == 0 && modbus_write_register(ctx, 10 + i, 5000 + i) == 1 &&
                         modbus_read_registers(ctx, 10 + i, 1, &v) == 1 && v == 5000 + i;
                modbus_close(ctx);
                modbus_free(ctx);
                _exit(ok ? 0 : 1);
            }
        }
        int good = 0;
        for (int i = 0; i < n && i < 256; i++) {
            int st;
            if (waitpid(pids[i], &st, 0) == pids[i] && WIFEXITED(st) && WEXITSTATUS(st) == 0)
                good++;
        }
        snprintf(detail, sizeof detail, "%d of %d clients right", good, n);
        EXPECT_DETAIL(good == n, "many: every client reads back its own register", detail);
    } else if (strcmp(scenario, "reconnect") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        int e = connect_and_read(ctx, regs);
        EXPECT_DETAIL(e == 0, "reconnect: first connection", e ? modbus_strerror(e) : NULL);
        /* The peer resets the connection under us (the test's server is killed and
         * restarted by the caller between the two halves: see tls.sh). */
        printf("WAITING\n");
        fflush(stdout);
        char line[16];
        if (fgets(line, sizeof line, stdin) == NULL)
            return 2;
        int rc = modbus_read_registers(ctx, 0, 5, regs);
        snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
        EXPECT_DETAIL(rc == -1, "reconnect: a read on the cut connection fails", detail);
        modbus_close(ctx);
        e = connect_and_read(ctx, regs);
        EXPECT_DETAIL(e == 0, "reconnect: the next connect works", e ? modbus_strerror(e) : NULL);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "stop") == 0) {
        stop_scenario();
    } else if (strcmp(scenario, "callback") == 0) {
        callback_scenario();
    } else if (strcmp(scenario, "sessions") == 0) {
        sessions_scenario();
    } else if (strcmp(scenario, "later") == 0) {
        later_scenario();
    } else if (strcmp(scenario, "caaspeer") == 0) {
        caaspeer_scenario();
    } else if (strcmp(scenario, "threads") == 0) {
        int n = argc > 5 ? atoi(argv[5]) : 8, bad = 0;
        pthread_t t[16];
        shared = client(host, port, "operator", 1);
        int e = connect_and_read(shared, regs);
        EXPECT_DETAIL(e == 0, "threads: connect", e ? modbus_strerror(e) : NULL);
        for (int i = 0; i < n && i < 16; i++)
            pthread_create(&t[i], NULL, worker, (void *)(intptr_t)i);
        for (int i = 0; i < n && i < 16; i++) {
            void *r;
            pthread_join(t[i], &r);
            bad += (int)(intptr_t)r;
        }
        snprintf(detail, sizeof detail, "%d threads x 300 write/read-back pairs, %d wrong", n, bad);
        EXPECT_DETAIL(bad == 0, "threads: one TLS context shared by threads, every answer right", detail);
        modbus_close(shared);
        modbus_free(shared);
    } else if (strcmp(scenario, "halfrecord") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        modbus_set_response_timeout(ctx, 5, 0);
        int rc = modbus_connect(ctx);
        EXPECT_DETAIL(rc == 0, "halfrecord: connect", rc ? modbus_strerror(errno) : NULL);
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        rc = modbus_read_registers(ctx, 5, 1, regs);
        int e = errno;
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double took = (double)(t1.tv_sec - t0.tv_sec) + (double)(t1.tv_nsec - t0.tv_nsec) / 1e9;
        snprintf(detail, sizeof detail, "rc %d errno %d (%s) after %.2f s", rc, e, modbus_strerror(e), took);
        EXPECT_DETAIL(rc == -1 && e == ECONNRESET && took < 4.0,
                      "halfrecord: a read cut in the middle of the answer's record fails with ECONNRESET, "
                      "before the timeout",
                      detail);
        modbus_close(ctx);
        rc = modbus_connect(ctx) == 0 && modbus_read_registers(ctx, 5, 1, regs) == 1 ? 0 : errno;
        snprintf(detail, sizeof detail, "%s, value %u", rc ? modbus_strerror(rc) : "ok", regs[0]);
        EXPECT_DETAIL(rc == 0 && regs[0] == 1005, "halfrecord: the next connect and read work", detail);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "password") == 0) {
        static const struct {
            const char *key, *password, *what;
            int want; /* 0: accepted, else the errno */
        } keys[] = {
            {"operator-aes", NULL, "PBES2/AES key without a password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-aes", "wrong", "PBES2/AES key, wrong password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-aes", "", "PBES2/AES key, empty password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-scrypt", "Secret", "scrypt key, wrong password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-pbes1", "secret", "PBES1 (3DES) key: EINVAL, not supported", EINVAL},
            {"operator-sha1", "secret", "PBES2 with PBKDF2-HMAC-SHA-1: EINVAL, not supported", EINVAL},
            {"operator-legacy", "secret", "OpenSSL's older encrypted PEM: EINVAL, not supported", EINVAL},
            {"operator", "unused", "a key that is not encrypted, with a password: accepted", 0},
            {"operator-aes", "secret", "PBES2/AES key, right password: accepted", 0},
            {"operator-scrypt", "secret", "scrypt key, right password: accepted", 0},
        };
        for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
            modbus_t *ctx = client(host, port, NULL, 1);
            errno = 0;
            int rc = modbus_set_tls_certificate_with_password(ctx, path("operator", "pem"), path(keys[i].key, "key"),
                                                              keys[i].password);
            int e = errno;
            snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, e, modbus_strerror(e));
            EXPECT_DETAIL(keys[i].want ? rc == -1 && e == keys[i].want : rc == 0, keys[i].what, detail);
            if (keys[i].want == 0 && rc == 0) {
                /* The decrypted key signs the handshake: the server accepts the Operator. */
                int ce = connect_and_read(ctx, regs);
                snprintf(detail, sizeof detail, "%s with %s", ce ? modbus_strerror(ce) : "ok", keys[i].key);
                EXPECT_DETAIL(ce == 0 && modbus_write_register(ctx, 3, 1003) == 1, "password: connect, read and write",
                              detail);
                modbus_close(ctx);
            }
            modbus_free(ctx);
        }
        /* The plain call on an encrypted key says a password is needed. */
        modbus_t *ctx = client(host, port, NULL, 1);
        int rc = modbus_set_tls_certificate(ctx, path("operator", "pem"), path("operator-aes", "key"));
        snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
        EXPECT_DETAIL(rc == -1 && errno == EMBTLSPASSWORD &&
                          strstr(modbus_strerror(EMBTLSPASSWORD), "password") != NULL,
                      "modbus_set_tls_certificate on an encrypted key: EMBTLSPASSWORD, named by modbus_strerror",
                      detail);
        modbus_free(ctx);
    } else {
        fprintf(stderr, "unknown scenario %s\n", scenario);
        return 2;
    }
    return chk_summary();
}
