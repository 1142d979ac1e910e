/*
 * stop: stopping a context from a signal handler or from another thread must never
 * deadlock (issue 19). One test per run: `stop run CASE ROLE TRANSPORT A B` is the
 * harness; it plays the peer (silent, then answering where a case needs it), starts
 * `stop child ...` (this same program, under valgrind when STOP_VALGRIND=1) as the
 * process under test, sends signals, watches the termios of the serial line, kills the
 * child by its PID when it hangs, and judges the outcome. The child judges what only
 * it can see (return values, errno, timings, descriptors) and prints "ok - ..." or
 * "FAIL - ..." lines, then "DONE passed failed".
 *
 * CASE (c-tests/stop/README.md has the expectations):
 *   term-parent     SIGTERM from the harness, handler modbus_close + _exit(0)
 *   term-thread     the same, SIGTERM sent by a helper thread with kill(getpid())
 *   free-exit       SIGTERM from the harness, handler modbus_close + modbus_free + _exit(0)
 *   close-return    SIGUSR1 handler modbus_close and returns: -1 EBADF, no descriptor
 *                   left, termios back, the context connects and works again
 *   client-timeout-{restart,norestart}   flag-only handler, response timeout 1 s
 *   server-timeout-{restart,norestart}   flag-only handler, indication timeout 1 s
 *   server-forever-{restart,norestart}   flag-only handler, indication timeout 0
 *   accept-{restart,norestart}           flag-only handler during modbus_tcp_accept
 *   thread-close    another thread calls modbus_close while this one waits
 *   thread-free     another thread calls modbus_free while this one waits
 *   handler-call    the handler calls modbus_get_socket, modbus_set_slave,
 *                   modbus_read_registers on the context its signal interrupted
 *   fork-thread     another thread forks while this one waits in the call; the child
 *                   uses the context (calls return at once, as with libmodbus, which
 *                   has no lock), the waiting call is not disturbed
 *   cancel          a worker thread waits in the call (1 s timeout), the main thread
 *                   cancels it (pthread_cancel) at 0.3 s: ours defers the cancellation
 *                   over the call (it returns at its timeout) and acts at the start of
 *                   the worker's next call; then the context works from the main thread
 *   cancel-close    the same with no timeout: the main thread closes the context at
 *                   0.6 s, which ends the call (EBADF), then the cancellation acts
 * ROLE: client (modbus_read_registers to a silent peer) | server (modbus_receive with a
 * connected peer that sends nothing). TRANSPORT: tcp | rtu | rtutcp | ascii (the last
 * two are rsmodbus extensions, looked up with dlsym). A B: the two ends of a pty pair
 * (serial; the context opens A, the harness answers on B), "-" otherwise.
 *
 * Debian's libmodbus 3.1.6 has known behaviours where it differs; the harness expects
 * them exactly and names them "DIFF <name>: ...".
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <arpa/inet.h>
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbt-fds.h"

int mbt_is_rsmodbus(void); /* ../common/libinfo.c */

/* ------------------------------------------------------------------ common */

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec + (double) ts.tv_nsec / 1e9;
}

static void sleep_s(double s)
{
    struct timespec ts = {(time_t) s, (long) ((s - (double) (time_t) s) * 1e9)};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

static const char *ename(int e)
{
    switch (e) {
    case 0: return "0";
    case EBADF: return "EBADF";
    case EINTR: return "EINTR";
    case ETIMEDOUT: return "ETIMEDOUT";
    case EDEADLK: return "EDEADLK";
    case ECONNRESET: return "ECONNRESET";
    case EINVAL: return "EINVAL";
    case EPIPE: return "EPIPE";
    case EAGAIN: return "EAGAIN";
    case EIO: return "EIO";
    default: {
        static char buf[32];
        snprintf(buf, sizeof(buf), "errno %d", e);
        return buf;
    }
    }
}

static int streq(const char *a, const char *b) { return strcmp(a, b) == 0; }
static int starts(const char *s, const char *p) { return strncmp(s, p, strlen(p)) == 0; }

static int is_serial(const char *tr) { return streq(tr, "rtu") || streq(tr, "ascii"); }

static int valgrind_mode(void)
{
    const char *v = getenv("STOP_VALGRIND");
    return v != NULL && streq(v, "1");
}

/* ---- frames: read holding register 0, one register, slave/unit 1 ---- */

static uint16_t crc16(const uint8_t *b, int n)
{
    uint16_t crc = 0xFFFF;
    for (int i = 0; i < n; i++) {
        crc ^= b[i];
        for (int k = 0; k < 8; k++) {
            crc = (crc & 1) ? (uint16_t) ((crc >> 1) ^ 0xA001) : (uint16_t) (crc >> 1);
        }
    }
    return crc;
}

static int ascii_frame(const uint8_t *pdu, int n, uint8_t *out)
{
    static const char hex[] = "0123456789ABCDEF";
    uint8_t lrc = 0;
    int k = 0;
    out[k++] = ':';
    for (int i = 0; i < n; i++) {
        out[k++] = (uint8_t) hex[pdu[i] >> 4];
        out[k++] = (uint8_t) hex[pdu[i] & 15];
        lrc = (uint8_t) (lrc + pdu[i]);
    }
    lrc = (uint8_t) (-lrc);
    out[k++] = (uint8_t) hex[lrc >> 4];
    out[k++] = (uint8_t) hex[lrc & 15];
    out[k++] = '\r';
    out[k++] = '\n';
    return k;
}

/* slave + PDU -> the frame of the transport (tid for TCP) */
static int frame(const char *tr, const uint8_t *body, int n, int tid, uint8_t *out)
{
    if (streq(tr, "tcp")) {
        out[0] = (uint8_t) (tid >> 8);
        out[1] = (uint8_t) tid;
        out[2] = 0;
        out[3] = 0;
        out[4] = 0;
        out[5] = (uint8_t) n;
        memcpy(out + 6, body, (size_t) n);
        return 6 + n;
    }
    if (streq(tr, "ascii")) {
        return ascii_frame(body, n, out);
    }
    {
        uint16_t crc = crc16(body, n);
        memcpy(out, body, (size_t) n);
        out[n] = (uint8_t) (crc & 0xFF);
        out[n + 1] = (uint8_t) (crc >> 8);
        return n + 2;
    }
}

static int build_request(const char *tr, uint8_t *out)
{
    static const uint8_t body[] = {0x01, 0x03, 0x00, 0x00, 0x00, 0x01};
    return frame(tr, body, (int) sizeof(body), 1, out);
}

static int build_response(const char *tr, const uint8_t *req, uint8_t *out)
{
    static const uint8_t body[] = {0x01, 0x03, 0x02, 0x00, 0x2A};
    int tid = streq(tr, "tcp") ? (req[0] << 8) | req[1] : 0;
    return frame(tr, body, (int) sizeof(body), tid, out);
}

static int request_complete(const char *tr, const uint8_t *b, int n)
{
    if (streq(tr, "tcp")) {
        return n >= 12;
    }
    if (streq(tr, "ascii")) {
        return memchr(b, '\n', (size_t) n) != NULL;
    }
    return n >= 8;
}

/* ---- termios ---- */

static int tios_equal(const struct termios *a, const struct termios *b)
{
    return a->c_iflag == b->c_iflag && a->c_oflag == b->c_oflag && a->c_cflag == b->c_cflag &&
           a->c_lflag == b->c_lflag && memcmp(a->c_cc, b->c_cc, sizeof(a->c_cc)) == 0 &&
           cfgetispeed(a) == cfgetispeed(b) && cfgetospeed(a) == cfgetospeed(b);
}

static const char *tios_str(const struct termios *t)
{
    static char buf[4][160];
    static int k;
    char *s = buf[k++ & 3];
    snprintf(s, sizeof(buf[0]), "iflag=%#x oflag=%#x cflag=%#x lflag=%#x ispeed=%u ospeed=%u",
             (unsigned) t->c_iflag, (unsigned) t->c_oflag, (unsigned) t->c_cflag,
             (unsigned) t->c_lflag, (unsigned) cfgetispeed(t), (unsigned) cfgetospeed(t));
    return s;
}

/* The checks of this process, child or harness (each is its own process: the child
 * is exec'd), are check.h's. */

/* After a close: the descriptors of the context's line are all gone (as many as
   before it connected, its wake-up eventfd aside: rsmodbus makes it at the first
   wait that watches it and closes it in modbus_free, checked at the end) and, on a
   serial line, the terminal settings are back. */
static void check_line_released(const char *when, int fds_before, int serial, int obs_fd,
                                const struct termios *before)
{
    EXPECT(mbt_count_fds_but_eventfds() == fds_before, "descriptors: %d before connect, %d %s",
           fds_before, mbt_count_fds_but_eventfds(), when);
    if (serial) {
        struct termios after;
        tcgetattr(obs_fd, &after);
        EXPECT(tios_equal(&after, before), "termios back (%s; before %s)", tios_str(&after),
              tios_str(before));
    }
}

/* ------------------------------------------------------------------ child */

static void say(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void say(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vprintf(fmt, ap);
    va_end(ap);
    printf("\n");
    fflush(stdout);
}

static modbus_t *volatile g_ctx;
static volatile sig_atomic_t g_flag;
static volatile double g_t_signal; /* when the helper thread signalled / closed */
static volatile double g_helper_call_s = -1; /* how long modbus_close/free took in the helper */

/* handler-call results */
static volatile int h_sock = -2, h_rc_slave = -2, h_errno_slave, h_rc_read = -2, h_errno_read;
static volatile double h_slave_s, h_read_s;

static void h_close_exit(int sig)
{
    (void) sig;
    modbus_close(g_ctx);
    _exit(0);
}

static void h_close_free_exit(int sig)
{
    (void) sig;
    modbus_close(g_ctx);
    modbus_free(g_ctx);
    _exit(0);
}

static void h_close_return(int sig)
{
    int e = errno;
    (void) sig;
    modbus_close(g_ctx);
    errno = e;
}

static void h_flag(int sig)
{
    (void) sig;
    g_flag = 1;
}

static void h_calls(int sig)
{
    int e = errno;
    uint16_t reg;
    double t0;
    (void) sig;
    g_flag = 1;
    h_sock = modbus_get_socket(g_ctx);
    t0 = now();
    errno = 0;
    h_rc_slave = modbus_set_slave(g_ctx, 1);
    h_errno_slave = errno;
    h_slave_s = now() - t0;
    t0 = now();
    errno = 0;
    h_rc_read = modbus_read_registers(g_ctx, 0, 1, &reg);
    h_errno_read = errno;
    h_read_s = now() - t0;
    errno = e;
}

/* fork-thread: the fork child's exit code (bits of its failed steps; 100 + signal if
 * it died; -1 when it hung and was killed) and how long it took */
static volatile int g_fork_status = -3;
static volatile double g_fork_s = -1;

/* fork-thread: called by the helper thread while the main thread waits in a call on
 * g_ctx. The child (a copy of this thread, its only thread) uses the context: each
 * call must return at once and succeed. Waits up to `limit` seconds for the child. */
static void fork_and_use(double limit)
{
    int sock = modbus_get_socket(g_ctx), st = 0;
    double t0 = now();
    pid_t pid = fork();
    if (pid == 0) {
        int bad = 0;
        if (modbus_set_slave(g_ctx, 1) != 0) {
            bad |= 1;
        }
        if (modbus_get_socket(g_ctx) != sock) {
            bad |= 2;
        }
        if (modbus_flush(g_ctx) < 0) {
            bad |= 4;
        }
        if (modbus_set_response_timeout(g_ctx, 0, 200000) != 0) {
            bad |= 8;
        }
        modbus_free(g_ctx);
        _exit(bad);
    }
    if (pid < 0) {
        g_fork_status = -2;
        return;
    }
    for (;;) {
        if (waitpid(pid, &st, WNOHANG) == pid) {
            g_fork_s = now() - t0;
            g_fork_status = WIFEXITED(st) ? WEXITSTATUS(st) : 100 + WTERMSIG(st);
            return;
        }
        if (now() - t0 > limit) {
            kill(pid, SIGKILL);
            waitpid(pid, &st, 0);
            g_fork_s = now() - t0;
            g_fork_status = -1;
            return;
        }
        sleep_s(0.005);
    }
}

/* cancel, cancel-close: the thread that waits in the call */
struct worker {
    int client;
    uint8_t *req;
    uint16_t *regs;
    volatile int rc, e, returned, second_returned;
    volatile double t_returned;
};

static void *worker_main(void *arg)
{
    struct worker *w = arg;
    int rc = w->client ? modbus_read_registers(g_ctx, 0, 1, w->regs) : modbus_receive(g_ctx, w->req);
    /* no cancellation point from here to the next call (clock_gettime is none) */
    w->e = errno;
    w->rc = rc;
    w->t_returned = now();
    w->returned = 1;
    modbus_set_slave(g_ctx, 1);
    w->second_returned = 1;
    return NULL;
}

enum helper_kind { HELP_SIGNAL, HELP_CLOSE, HELP_FREE, HELP_FORK };
struct helper {
    enum helper_kind kind;
    double delay;
    int sig;
};

static void *helper_main(void *arg)
{
    struct helper *h = arg;
    sigset_t all;
    double t0;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    sleep_s(h->delay);
    t0 = now();
    g_t_signal = t0;
    switch (h->kind) {
    case HELP_SIGNAL:
        say("SIGNAL %.6f", t0);
        kill(getpid(), h->sig);
        say("SIGNALED");
        break;
    case HELP_CLOSE:
        modbus_close(g_ctx);
        g_helper_call_s = now() - t0;
        say("NOTE modbus_close from another thread returned in %.3f ms", g_helper_call_s * 1e3);
        break;
    case HELP_FREE:
        modbus_free(g_ctx);
        g_helper_call_s = now() - t0;
        say("NOTE modbus_free from another thread returned in %.3f ms", g_helper_call_s * 1e3);
        break;
    case HELP_FORK:
        fork_and_use(3.0);
        say("NOTE fork child: status %d after %.3f ms", g_fork_status, g_fork_s * 1e3);
        break;
    }
    return NULL;
}

typedef modbus_t *(*new_rtu_tcp_fn)(const char *, int);
typedef modbus_t *(*new_ascii_fn)(const char *, int, char, int, int);

static modbus_t *make_ctx(const char *tr, const char *dev, int port)
{
    if (streq(tr, "tcp")) {
        return modbus_new_tcp("127.0.0.1", port);
    }
    if (streq(tr, "rtu")) {
        return modbus_new_rtu(dev, 115200, 'N', 8, 1);
    }
    if (streq(tr, "rtutcp")) {
        void *sym = dlsym(RTLD_DEFAULT, "modbus_new_rtu_tcp");
        new_rtu_tcp_fn fn;
        if (sym == NULL) {
            say("NOTE this libmodbus has no modbus_new_rtu_tcp");
            return NULL;
        }
        memcpy(&fn, &sym, sizeof(fn));
        return fn("127.0.0.1", port);
    }
    if (streq(tr, "ascii")) {
        void *sym = dlsym(RTLD_DEFAULT, "modbus_new_ascii");
        new_ascii_fn fn;
        if (sym == NULL) {
            say("NOTE this libmodbus has no modbus_new_ascii");
            return NULL;
        }
        memcpy(&fn, &sym, sizeof(fn));
        return fn(dev, 115200, 'N', 8, 1);
    }
    return NULL;
}

static int wait_go(void)
{
    char line[64];
    say("PHASE2");
    if (fgets(line, sizeof(line), stdin) == NULL || !starts(line, "GO")) {
        say("NOTE no GO from the harness");
        return -1;
    }
    return 0;
}

static int child_done(void)
{
    say("DONE %d %d", chk_passed(), chk_failed());
    return chk_failed() == 0 ? 0 : 1;
}

static int child_main(const char *cs, const char *role, const char *tr, const char *dev, int port)
{
    const int ours = mbt_is_rsmodbus();
    const int client = streq(role, "client");
    const int serial = is_serial(tr);
    const int vg = valgrind_mode();
    const double slack = vg ? 5.0 : 1.0; /* valgrind runs threads one at a time, slowly */
    struct sigaction sa;
    struct termios tios_before;
    struct helper help;
    pthread_t helper_tid;
    int have_helper = 0, obs_fd = -1, listen_s = -1, fds_before, fds_all_before, rc, e;
    int restart = strstr(cs, "norestart") == NULL;
    uint16_t regs[4];
    uint8_t req[MODBUS_MAX_ADU_LENGTH];
    double t0, t1;
    modbus_t *ctx;

    setvbuf(stdout, NULL, _IOLBF, 0);
    memset(&sa, 0, sizeof(sa));
    sigemptyset(&sa.sa_mask);

    ctx = make_ctx(tr, dev, client ? port : 0);
    if (ctx == NULL) {
        EXPECT(0, "new context for %s: %s", tr, modbus_strerror(errno));
        return child_done();
    }
    g_ctx = ctx;
    modbus_set_slave(ctx, 1);
    /* default: client waits 10 s for a response, server forever for a request */
    modbus_set_response_timeout(ctx, 10, 0);
    modbus_set_indication_timeout(ctx, 0, 0);
    if (starts(cs, "client-timeout") || streq(cs, "handler-call") || streq(cs, "fork-thread") ||
        streq(cs, "cancel")) {
        modbus_set_response_timeout(ctx, 1, 0);
    }
    if (starts(cs, "server-timeout") || streq(cs, "handler-call") || streq(cs, "fork-thread") ||
        streq(cs, "cancel")) {
        modbus_set_indication_timeout(ctx, 1, 0);
    }

    /* the handler */
    if (starts(cs, "term-")) {
        sa.sa_handler = h_close_exit;
        sigaction(SIGTERM, &sa, NULL);
    } else if (streq(cs, "free-exit")) {
        sa.sa_handler = h_close_free_exit;
        sigaction(SIGTERM, &sa, NULL);
    } else if (streq(cs, "close-return")) {
        sa.sa_handler = h_close_return;
        sigaction(SIGUSR1, &sa, NULL);
    } else if (streq(cs, "handler-call")) {
        sa.sa_handler = h_calls;
        sigaction(SIGUSR1, &sa, NULL);
    } else if (strstr(cs, "restart") != NULL) {
        sa.sa_handler = h_flag;
        sa.sa_flags = restart ? SA_RESTART : 0;
        sigaction(SIGUSR1, &sa, NULL);
    }

    if (serial) {
        obs_fd = open(dev, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
        if (obs_fd < 0 || tcgetattr(obs_fd, &tios_before) != 0) {
            EXPECT(0, "open/tcgetattr %s: %s", dev, strerror(errno));
            return child_done();
        }
    }
    if (!client && !serial) {
        struct sockaddr_in a;
        socklen_t alen = sizeof(a);
        listen_s = modbus_tcp_listen(ctx, 1);
        if (listen_s < 0 || getsockname(listen_s, (struct sockaddr *) &a, &alen) != 0) {
            EXPECT(0, "modbus_tcp_listen: %s", modbus_strerror(errno));
            return child_done();
        }
        say("PORT %d", ntohs(a.sin_port));
    }
    fds_before = mbt_count_fds_but_eventfds();
    fds_all_before = mbt_count_fds();

    /* ---- 4: modbus_tcp_accept interrupted by a flag-only signal */
    if (starts(cs, "accept-")) {
        help = (struct helper){HELP_SIGNAL, 0.3, SIGUSR1};
        pthread_create(&helper_tid, NULL, helper_main, &help);
        say("BLOCKING");
        t0 = now();
        errno = 0;
        rc = modbus_tcp_accept(ctx, &listen_s);
        e = errno;
        t1 = now();
        pthread_join(helper_tid, NULL);
        say("RETURNED rc=%d errno=%s after %.3f s", rc, ename(rc == -1 ? e : 0), t1 - t0);
        if (!ours && !restart) {
            EXPECT(rc == -1 && e == EINTR && t1 - g_t_signal < 0.5,
                    "accept without SA_RESTART: -1 EINTR at the signal (rc %d, %s)", rc, ename(e));
            if (rc == -1 && e == EINTR) {
                say("DIFF debian-accept-eintr: modbus_tcp_accept returns -1 EINTR at a "
                    "flag-only signal without SA_RESTART (ours keeps waiting)");
            }
        } else {
            EXPECT(rc >= 0, "accept keeps waiting through the signal and accepts (rc %d, %s)", rc,
                    ename(rc == -1 ? e : 0));
            EXPECT(g_flag && t1 > g_t_signal + 0.1,
                    "accept returned %.3f s after the signal (the client connects ~0.3 s after it)",
                    t1 - g_t_signal);
        }
        if (rc >= 0) {
            close(rc);
        }
        close(listen_s);
        modbus_free(ctx);
        return child_done();
    }

    /* ---- connect (client, serial server) or accept (TCP server) */
    if (client || serial) {
        rc = modbus_connect(ctx);
    } else {
        rc = modbus_tcp_accept(ctx, &listen_s);
    }
    if (rc < 0) {
        EXPECT(0, "connect/accept: %s", modbus_strerror(errno));
        return child_done();
    }
    say("CONNECTED");
    if (serial) {
        struct termios during;
        tcgetattr(obs_fd, &during);
        EXPECT(!tios_equal(&during, &tios_before),
                "modbus_connect changed the line's termios (so restoring it can be checked)");
    }
    {
        int sock_before = modbus_get_socket(ctx);
        say("NOTE socket %d", sock_before);

        if (streq(cs, "term-thread")) {
            help = (struct helper){HELP_SIGNAL, 0.2, SIGTERM};
            have_helper = 1;
        } else if (streq(cs, "close-return") || streq(cs, "handler-call") ||
                   strstr(cs, "restart") != NULL) {
            help = (struct helper){HELP_SIGNAL, 0.3, SIGUSR1};
            have_helper = 1;
        } else if (streq(cs, "thread-close")) {
            help = (struct helper){HELP_CLOSE, vg ? 1.0 : 0.3, 0};
            have_helper = 1;
        } else if (streq(cs, "thread-free")) {
            help = (struct helper){HELP_FREE, vg ? 1.0 : 0.3, 0};
            have_helper = 1;
        } else if (streq(cs, "fork-thread")) {
            help = (struct helper){HELP_FORK, 0.3, 0};
            have_helper = 1;
        }
        if (have_helper) {
            pthread_create(&helper_tid, NULL, helper_main, &help);
        }

        if (starts(cs, "cancel")) {
            struct worker w = {client, req, regs, -2, 0, 0, 0, 0};
            pthread_t wt;
            void *res = NULL;
            double t_cancel, t_close = 0, t_set;
            int closing = streq(cs, "cancel-close");
            say("BLOCKING");
            t0 = now();
            pthread_create(&wt, NULL, worker_main, &w);
            sleep_s(vg ? 1.0 : 0.3);
            t_cancel = g_t_signal = now();
            pthread_cancel(wt);
            if (closing) {
                sleep_s(0.3);
                t_close = now();
                modbus_close(ctx);
            }
            pthread_join(wt, &res);
            t1 = now();
            say("RETURNED joined after %.3f s (%.3f s after pthread_cancel); the call %s", t1 - t0,
                t1 - t_cancel, w.returned ? "returned" : "never returned");
            EXPECT(res == PTHREAD_CANCELED, "the worker thread was cancelled");
            if (ours) {
                EXPECT(w.returned, "the call was not cut short: it returned (rc %d, %s)", w.rc,
                        ename(w.rc == -1 ? w.e : 0));
                if (closing) {
                    EXPECT(w.rc == -1 && w.e == EBADF && w.t_returned - t_close < slack,
                            "it ended with the main thread's modbus_close: -1 EBADF %.3f s "
                            "after it (rc %d, %s)",
                            w.t_returned - t_close, w.rc, ename(w.rc == -1 ? w.e : 0));
                } else {
                    EXPECT(w.rc == -1 && w.e == ETIMEDOUT && w.t_returned - t0 >= 0.9 &&
                                  w.t_returned - t0 <= 1.5 + (vg ? 3.0 : 0.0),
                            "it ended at its timeout: -1 ETIMEDOUT after %.3f s (rc %d, %s)",
                            w.t_returned - t0, w.rc, ename(w.rc == -1 ? w.e : 0));
                }
                EXPECT(!w.second_returned && t1 - w.t_returned < slack,
                        "the cancellation acted at the start of the next call, %.3f s after "
                        "the first returned",
                        t1 - w.t_returned);
            } else {
                EXPECT(!w.returned && t1 - t_cancel < slack,
                        "cancelled inside the call: never returned, joined %.3f s after "
                        "pthread_cancel",
                        t1 - t_cancel);
                say("DIFF debian-cancel-in-call: pthread_cancel acts inside the waiting call "
                    "(select is a cancellation point); ours lets the call end and cancels at "
                    "the next call");
            }
            t_set = now();
            rc = modbus_set_slave(ctx, 1);
            t_set = now() - t_set;
            EXPECT(rc == 0 && t_set < 0.1,
                    "then the main thread uses the context: modbus_set_slave %d after %.3f ms", rc,
                    t_set * 1e3);
            modbus_close(ctx);
            check_line_released("after close", fds_before, serial, obs_fd, &tios_before);
            modbus_free(ctx);
            ctx = NULL;
            goto done;
        }

        say("BLOCKING");
        t0 = now();
        errno = 0;
        rc = client ? modbus_read_registers(ctx, 0, 1, regs) : modbus_receive(ctx, req);
        e = errno;
        t1 = now();
        if (have_helper) {
            pthread_join(helper_tid, NULL);
        }
        say("RETURNED rc=%d errno=%s after %.3f s (%.3f s after the %s)", rc,
            ename(rc == -1 ? e : 0), t1 - t0, t1 - g_t_signal,
            streq(cs, "thread-close") ? "modbus_close"
            : streq(cs, "thread-free") ? "modbus_free"
            : streq(cs, "fork-thread") ? "fork" : "signal");

        if (starts(cs, "term-") || streq(cs, "free-exit")) {
            EXPECT(0, "the handler should have ended the process; the call returned instead");
            return child_done();
        }

        if (streq(cs, "close-return")) {
            EXPECT(rc == -1 && e == EBADF, "interrupted call: -1 EBADF (rc %d, %s)", rc,
                    ename(rc == -1 ? e : 0));
            EXPECT(t1 - g_t_signal < 1.0, "returned %.3f s after the signal (< 1 s)",
                    t1 - g_t_signal);
            check_line_released("now", fds_before, serial, obs_fd, &tios_before);
            /* phase 2: the same context connects again and works */
            if (client) {
                rc = modbus_connect(ctx);
                EXPECT(rc == 0, "modbus_connect again (rc %d%s%s)", rc, rc == -1 ? ", " : "",
                        rc == -1 ? modbus_strerror(errno) : "");
                if (rc == 0 && wait_go() == 0) {
                    memset(regs, 0, sizeof(regs));
                    rc = modbus_read_registers(ctx, 0, 1, regs);
                    EXPECT(rc == 1 && regs[0] == 0x2A,
                            "then a transaction with an answering peer (rc %d%s%s, value %#x)", rc,
                            rc == -1 ? ", " : "", rc == -1 ? modbus_strerror(errno) : "", regs[0]);
                }
            } else {
                rc = 0;
                if (serial) {
                    rc = modbus_connect(ctx);
                    EXPECT(rc == 0, "modbus_connect again (rc %d%s%s)", rc, rc == -1 ? ", " : "",
                            rc == -1 ? modbus_strerror(errno) : "");
                }
                if (rc == 0 && wait_go() == 0) {
                    if (!serial) {
                        rc = modbus_tcp_accept(ctx, &listen_s);
                        EXPECT(rc >= 0, "modbus_tcp_accept again (rc %d%s%s)", rc, rc == -1 ? ", " : "",
                                rc == -1 ? modbus_strerror(errno) : "");
                    }
                    if (rc >= 0) {
                        rc = modbus_receive(ctx, req);
                        EXPECT(rc > 0, "then a request from the peer is received (rc %d%s%s)", rc,
                                rc == -1 ? ", " : "", rc == -1 ? modbus_strerror(errno) : "");
                    }
                }
            }
            modbus_close(ctx);
        } else if (starts(cs, "client-timeout") || starts(cs, "server-timeout")) {
            EXPECT(g_flag, "the flag-only handler ran during the call");
            EXPECT(rc == -1 && e == ETIMEDOUT, "-1 ETIMEDOUT (rc %d, %s)", rc,
                    ename(rc == -1 ? e : 0));
            EXPECT(t1 - t0 >= 0.9 && t1 - t0 <= 1.5,
                    "after %.3f s: the timeout budget of 1 s, not restarted (0.9-1.5 s)", t1 - t0);
            modbus_close(ctx);
        } else if (starts(cs, "server-forever")) {
            EXPECT(g_flag, "the flag-only handler ran during the call");
            EXPECT(rc > 0, "still waiting after the signal, then the peer's request (rc %d, %s)",
                    rc, ename(rc == -1 ? e : 0));
            EXPECT(t1 - g_t_signal > 0.1, "returned %.3f s after the signal (the request comes "
                    "~0.3 s after it)", t1 - g_t_signal);
            modbus_close(ctx);
        } else if (streq(cs, "thread-close")) {
            double limit = vg ? 2.0 : 0.1;
            EXPECT(g_helper_call_s >= 0 && g_helper_call_s < limit,
                    "modbus_close from another thread returned in %.3f ms (< %.0f ms)",
                    g_helper_call_s * 1e3, limit * 1e3);
            if (!ours && rc == -1 && e == ECONNRESET) {
                EXPECT(1, "blocked call: -1 ECONNRESET (Debian: woken by shutdown(), recv "
                        "read the EOF before the descriptor was closed)");
                say("DIFF debian-close-econnreset: the waiting call saw the shutdown's EOF "
                    "(ECONNRESET) before the close");
            } else {
                EXPECT(rc == -1 && e == EBADF, "blocked call: -1 EBADF (rc %d, %s)", rc,
                        ename(rc == -1 ? e : 0));
            }
            EXPECT(t1 - g_t_signal < slack, "it returned %.3f s after modbus_close (< %.0f s)",
                    t1 - g_t_signal, slack);
            check_line_released("now", fds_before, serial, obs_fd, &tios_before);
        } else if (streq(cs, "thread-free")) {
            double limit = vg ? 2.0 : 0.1;
            EXPECT(g_helper_call_s >= 0 && g_helper_call_s < limit,
                    "modbus_free from another thread returned in %.3f ms (< %.0f ms)",
                    g_helper_call_s * 1e3, limit * 1e3);
            EXPECT(rc == -1 && e == EBADF, "blocked call: -1 EBADF (rc %d, %s)", rc,
                    ename(rc == -1 ? e : 0));
            EXPECT(t1 - g_t_signal < slack, "it returned %.3f s after modbus_free (< %.0f s)",
                    t1 - g_t_signal, slack);
            say("NOTE descriptors: %d before connect, %d after modbus_free", fds_before,
                mbt_count_fds());
            /* ctx is gone: never touched again */
            ctx = NULL;
        } else if (streq(cs, "handler-call")) {
            EXPECT(h_sock == sock_before, "modbus_get_socket in the handler: %d (before: %d)",
                    h_sock, sock_before);
            if (ours) {
                EXPECT(h_rc_slave == -1 && h_errno_slave == EDEADLK && h_slave_s < 0.1,
                        "modbus_set_slave in the handler: -1 EDEADLK at once (rc %d, %s, %.3f ms)",
                        h_rc_slave, ename(h_errno_slave), h_slave_s * 1e3);
                EXPECT(h_rc_read == -1 && h_errno_read == EDEADLK && h_read_s < 0.1,
                        "modbus_read_registers in the handler: -1 EDEADLK at once (rc %d, %s, "
                        "%.3f ms)",
                        h_rc_read, ename(h_errno_read), h_read_s * 1e3);
                EXPECT(rc == -1 && e == ETIMEDOUT && t1 - t0 >= 0.9 && t1 - t0 <= 1.5,
                        "the interrupted call goes on: -1 ETIMEDOUT after %.3f s (rc %d, %s; "
                        "0.9-1.5 s)",
                        t1 - t0, rc, ename(rc == -1 ? e : 0));
            } else {
                EXPECT(h_rc_slave == 0, "modbus_set_slave in the handler: runs, rc %d (%s)",
                        h_rc_slave, ename(h_errno_slave));
                EXPECT(h_rc_read == -1 && h_errno_read == ETIMEDOUT && h_read_s >= 0.9,
                        "modbus_read_registers in the handler: runs, -1 ETIMEDOUT after the "
                        "response timeout (rc %d, %s, %.3f s)",
                        h_rc_read, ename(h_errno_read), h_read_s);
                EXPECT(rc == -1 && e == ETIMEDOUT && t1 - t0 >= 1.5 && t1 - t0 <= 3.0,
                        "the interrupted call: -1 ETIMEDOUT after %.3f s (its 1 s plus the "
                        "handler's; 1.5-3 s) (rc %d, %s)",
                        t1 - t0, rc, ename(rc == -1 ? e : 0));
                say("DIFF debian-no-lock: calls made by the handler on the interrupted "
                    "context just run (set_slave %d, nested read_registers waited %.3f s); "
                    "ours: -1 EDEADLK at once",
                    h_rc_slave, h_read_s);
            }
            modbus_close(ctx);
        } else if (streq(cs, "fork-thread")) {
            EXPECT(g_fork_status == 0 && g_fork_s < 1.0,
                    "the fork child's calls on the context (set_slave, get_socket, flush, "
                    "set_response_timeout, free) returned at once and succeeded: status %d "
                    "(-1: hung, killed; else bits of the failed steps) after %.3f ms",
                    g_fork_status, g_fork_s * 1e3);
            EXPECT(rc == -1 && e == ETIMEDOUT && t1 - t0 >= 0.9 && t1 - t0 <= 1.5,
                    "the waiting call is not disturbed: -1 ETIMEDOUT after %.3f s (rc %d, %s; "
                    "0.9-1.5 s)",
                    t1 - t0, rc, ename(rc == -1 ? e : 0));
            modbus_close(ctx);
        } else {
            EXPECT(0, "unknown case %s", cs);
        }
    }
done:
    if (ctx != NULL) {
        modbus_free(ctx);
        EXPECT(mbt_count_fds() <= fds_all_before, "after modbus_free: %d descriptors, %d before connect",
               mbt_count_fds(), fds_all_before);
    }
    if (listen_s >= 0) {
        close(listen_s);
    }
    if (obs_fd >= 0) {
        close(obs_fd);
    }
    return child_done();
}

/* ------------------------------------------------------------------ harness */

static char h_summary[4096];
static char h_test[256];

static void note(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void note(const char *fmt, ...)
{
    va_list ap;
    size_t n = strlen(h_summary);
    if (n + 4 >= sizeof(h_summary)) {
        return;
    }
    if (n > 0) {
        strcat(h_summary, "; ");
        n += 2;
    }
    va_start(ap, fmt);
    vsnprintf(h_summary + n, sizeof(h_summary) - n, fmt, ap);
    va_end(ap);
}

static int tcp_listen_any(int *port)
{
    struct sockaddr_in a;
    socklen_t alen = sizeof(a);
    int one = 1;
    int s = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    memset(&a, 0, sizeof(a));
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    setsockopt(s, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    if (bind(s, (struct sockaddr *) &a, sizeof(a)) != 0 || listen(s, 8) != 0 ||
        getsockname(s, (struct sockaddr *) &a, &alen) != 0) {
        close(s);
        return -1;
    }
    *port = ntohs(a.sin_port);
    return s;
}

static int tcp_connect(int port)
{
    struct sockaddr_in a;
    int s = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    memset(&a, 0, sizeof(a));
    a.sin_family = AF_INET;
    a.sin_port = htons((uint16_t) port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(s, (struct sockaddr *) &a, sizeof(a)) != 0) {
        close(s);
        return -1;
    }
    return s;
}

static int wait_fd(int fd, double secs)
{
    struct pollfd p = {fd, POLLIN, 0};
    return poll(&p, 1, (int) (secs * 1000)) == 1;
}

static int accept_within(int ls, double secs)
{
    if (!wait_fd(ls, secs)) {
        return -1;
    }
    return accept4(ls, NULL, NULL, SOCK_CLOEXEC);
}

/* reads one request of the transport from fd within secs; returns its length */
static int read_request(const char *tr, int fd, uint8_t *buf, int cap, double secs)
{
    int n = 0;
    double end = now() + secs;
    while (n < cap && !request_complete(tr, buf, n)) {
        double left = end - now();
        ssize_t r;
        if (left <= 0 || !wait_fd(fd, left)) {
            return -1;
        }
        r = read(fd, buf + n, (size_t) (cap - n));
        if (r <= 0) {
            if (r < 0 && (errno == EAGAIN || errno == EINTR)) {
                continue;
            }
            return -1;
        }
        n += (int) r;
    }
    if (streq(tr, "ascii")) {
        /* the request starts at its ':' */
        uint8_t *colon = memchr(buf, ':', (size_t) n);
        if (colon != NULL && colon != buf) {
            n -= (int) (colon - buf);
            memmove(buf, colon, (size_t) n);
        }
    }
    return n;
}

static void drain(int fd)
{
    uint8_t junk[512];
    while (wait_fd(fd, 0.05) && read(fd, junk, sizeof(junk)) > 0) {
    }
    tcflush(fd, TCIFLUSH);
}

static void write_all(int fd, const uint8_t *b, int n)
{
    while (n > 0) {
        ssize_t w = write(fd, b, (size_t) n);
        if (w < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                wait_fd(fd, 0.01);
                continue;
            }
            return;
        }
        b += w;
        n -= (int) w;
    }
}

enum outcome { OUT_EXIT0, OUT_ABORT, OUT_HANG };
static const char *outcome_name[] = {"exit 0", "SIGABRT", "hang"};

struct reader {
    int fd;
    char buf[1 << 16];
    size_t len;
    int eof;
};

static int next_line(struct reader *r, char *out, size_t cap)
{
    char *nl = memchr(r->buf, '\n', r->len);
    size_t n;
    if (nl == NULL) {
        if (!r->eof || r->len == 0) {
            return 0;
        }
        nl = r->buf + r->len; /* a last line without newline */
    }
    n = (size_t) (nl - r->buf);
    snprintf(out, cap, "%.*s", (int) n, r->buf);
    if (n < r->len) {
        n++;
    }
    memmove(r->buf, r->buf + n, r->len - n);
    r->len -= n;
    return 1;
}

static void fill(struct reader *r)
{
    ssize_t n;
    if (r->len == sizeof(r->buf)) {
        r->len = 0; /* runaway output: drop it */
    }
    n = read(r->fd, r->buf + r->len, sizeof(r->buf) - r->len);
    if (n > 0) {
        r->len += (size_t) n;
    } else if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
        r->eof = 1;
    }
}

static int harness_main(const char *self, const char *cs, const char *role, const char *tr,
                        const char *dev_a, const char *dev_b)
{
    const int ours = mbt_is_rsmodbus();
    const int client = streq(role, "client");
    const int serial = is_serial(tr);
    const int vg = valgrind_mode();
    const int parent_signal = streq(cs, "term-parent") || streq(cs, "free-exit");
    const int exit_in_handler = starts(cs, "term-") || streq(cs, "free-exit");
    unsigned expected = 1u << OUT_EXIT0; /* the outcomes accepted */
    char expected_str[64];
    const char *diff_name = NULL, *diff_what = NULL;
    int lis = -1, lport = 0, conn = -1, a_fd = -1, b_fd = -1, child_port = 0;
    int to_child[2], from_child[2], status = 0, reaped = 0, killed = 0, done_seen = 0;
    int child_failed = 0, child_passed = 0;
    struct termios t_before, t_during, t_after;
    int have_during = 0;
    double t_start = now(), t_blocking = 0, t_signal = 0, t_exit = 0, kill_at = 0,
           request_at = 0, connect_at = 0, deadline, hang_s;
    pid_t pid;
    struct reader *rd;
    char line[4096];
    FILE *errf = tmpfile(); /* the child's stderr (valgrind's report, libc's abort message) */
    int fortify_msg = 0, phase2_seen = 0;

    snprintf(h_test, sizeof(h_test), "%s %s/%s/%s%s", ours ? "ours" : "debian", cs, role, tr,
             vg ? " (valgrind)" : "");
    signal(SIGPIPE, SIG_IGN);

    /* Debian 3.1.6's known behaviours where it differs */
    if (!ours) {
        if (streq(cs, "close-return")) {
            expected = 1u << OUT_ABORT;
            diff_name = "debian-fortify-abort";
            diff_what = "after the handler's modbus_close the EINTR retry does FD_SET(-1) and "
                        "_FORTIFY_SOURCE aborts the process (SIGABRT)";
        } else if (streq(cs, "thread-close") && serial) {
            /* _modbus_rtu_close: tcsetattr() wakes the select() (n_tty_set_termios
             * wakes read_wait), then close(). Usually the close comes first: the rescan
             * reports the closed descriptor ready and the read(-1) fails with EBADF, as
             * ours. If the waiting thread rescans first, select() sleeps on: a close()
             * alone wakes nothing (server: forever; client: until its 10 s timeout). */
            expected = (1u << OUT_EXIT0) | (1u << OUT_HANG);
            diff_name = "debian-close-tty-race";
            diff_what = "modbus_close from another thread: tcsetattr() woke select() but it "
                        "rescanned before the close(), and closing a descriptor wakes no "
                        "select(): still blocked, killed (usually close() wins: -1 EBADF)";
        } else if (streq(cs, "thread-free")) {
            expected = 1u << OUT_HANG;
            diff_name = "debian-free-no-wake";
            diff_what = "modbus_free from another thread neither closes nor wakes: the waiting "
                        "thread stays in select() on the freed context, killed";
        }
    }
    hang_s = (expected & (1u << OUT_HANG)) ? 3.0 : 5.0;
    snprintf(expected_str, sizeof(expected_str), "%s%s%s%s%s",
             (expected & 1u << OUT_EXIT0) ? outcome_name[OUT_EXIT0] : "",
             (expected & 1u << OUT_EXIT0) && (expected & ~(1u << OUT_EXIT0)) ? " or " : "",
             (expected & 1u << OUT_ABORT) ? outcome_name[OUT_ABORT] : "",
             (expected & 1u << OUT_ABORT) && (expected & 1u << OUT_HANG) ? " or " : "",
             (expected & 1u << OUT_HANG) ? outcome_name[OUT_HANG] : "");
    if (vg) {
        hang_s = 12.0;
    }

    /* the peer */
    if (serial) {
        struct termios raw;
        a_fd = open(dev_a, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
        b_fd = open(dev_b, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
        if (a_fd < 0 || b_fd < 0 || tcgetattr(a_fd, &raw) != 0) {
            EXPECT(0, "%s: open the pty pair %s %s: %s", h_test, dev_a, dev_b, strerror(errno));
            goto out;
        }
        /* the line's state before modbus_connect: raw at 9600 baud, surely not what
         * the library sets (115200), so that a restore can be told from no change */
        cfmakeraw(&raw);
        cfsetispeed(&raw, B9600);
        cfsetospeed(&raw, B9600);
        tcsetattr(a_fd, TCSANOW, &raw);
        tcgetattr(a_fd, &t_before);
        tcgetattr(b_fd, &raw);
        cfmakeraw(&raw);
        tcsetattr(b_fd, TCSANOW, &raw);
    } else if (client) {
        lis = tcp_listen_any(&lport);
        if (lis < 0) {
            EXPECT(0, "%s: listen on 127.0.0.1: %s", h_test, strerror(errno));
            goto out;
        }
    }

    if (pipe2(to_child, O_CLOEXEC) != 0 || pipe2(from_child, O_CLOEXEC) != 0) {
        EXPECT(0, "pipe: %s", strerror(errno));
        goto out;
    }
    {
        pid_t harness = getpid();
        pid = fork();
        if (pid < 0) {
            EXPECT(0, "fork: %s", strerror(errno));
            goto out;
        }
        if (pid == 0) {
            /* the child dies with the harness, whatever ends it */
            prctl(PR_SET_PDEATHSIG, SIGKILL);
            if (getppid() != harness) {
                _exit(1);
            }
        }
    }
    if (pid == 0) {
        char portbuf[16];
        const char *argv[32];
        int k = 0;
        dup2(to_child[0], 0);
        dup2(from_child[1], 1);
        if (errf != NULL) {
            dup2(fileno(errf), 2);
            close(fileno(errf));
        }
        snprintf(portbuf, sizeof(portbuf), "%d", lport);
        if (vg) {
            argv[k++] = "valgrind";
            argv[k++] = "-q";
            argv[k++] = "--error-exitcode=99";
            argv[k++] = "--leak-check=full";
            argv[k++] = "--show-leak-kinds=definite";
            argv[k++] = "--errors-for-leak-kinds=definite";
            argv[k++] = "--log-fd=2";
        }
        argv[k++] = self;
        argv[k++] = "child";
        argv[k++] = cs;
        argv[k++] = role;
        argv[k++] = tr;
        argv[k++] = serial ? dev_a : "-";
        argv[k++] = portbuf;
        argv[k] = NULL;
        execvp(argv[0], (char *const *) argv);
        fprintf(stderr, "exec %s: %s\n", argv[0], strerror(errno));
        _exit(127);
    }
    close(to_child[0]);
    close(from_child[1]);
    printf("CHILD pid %d\n", (int) pid);
    fflush(stdout);

    rd = calloc(1, sizeof(*rd));
    rd->fd = from_child[0];
    fcntl(rd->fd, F_SETFL, O_NONBLOCK);
    deadline = t_start + (vg ? 30.0 : 15.0); /* until BLOCKING */

    while (!reaped) {
        double t, wait_s;
        struct pollfd p;
        while (next_line(rd, line, sizeof(line))) {
            printf("  child| %s\n", line);
            fflush(stdout);
            if (starts(line, "BLOCKING")) {
                t_blocking = now();
                deadline = t_blocking + hang_s;
                if (parent_signal) {
                    kill_at = t_blocking + (vg ? 1.5 : 0.2);
                }
                if (serial) {
                    have_during = tcgetattr(a_fd, &t_during) == 0;
                }
            } else if (starts(line, "SIGNAL ")) {
                t_signal = atof(line + 7);
            } else if (starts(line, "SIGNALED")) {
                if (starts(cs, "server-forever")) {
                    request_at = now() + 0.3;
                } else if (starts(cs, "accept-")) {
                    connect_at = now() + 0.3;
                }
            } else if (starts(line, "PORT ")) {
                child_port = atoi(line + 5);
                if (!starts(cs, "accept-")) {
                    conn = tcp_connect(child_port); /* the silent peer */
                }
            } else if (starts(line, "CONNECTED")) {
                if (client && !serial) {
                    conn = accept_within(lis, 3.0);
                }
            } else if (starts(line, "RETURNED")) {
                deadline = now() + 5.0 + (vg ? 15.0 : 0.0);
                note("%s", line + 9);
            } else if (starts(line, "PHASE2")) {
                uint8_t buf[512], rsp[512];
                int n;
                phase2_seen = 1;
                if (client) {
                    int fd = b_fd;
                    if (!serial) {
                        if (conn >= 0) {
                            close(conn);
                        }
                        conn = accept_within(lis, 3.0);
                        fd = conn;
                    } else {
                        drain(b_fd);
                    }
                    write_all(to_child[1], (const uint8_t *) "GO\n", 3);
                    n = fd >= 0 ? read_request(tr, fd, buf, sizeof(buf), 3.0) : -1;
                    if (n > 0) {
                        write_all(fd, rsp, build_response(tr, buf, rsp));
                    } else {
                        printf("harness: no request from the reconnected client\n");
                    }
                } else {
                    write_all(to_child[1], (const uint8_t *) "GO\n", 3);
                    n = build_request(tr, buf);
                    if (serial) {
                        write_all(b_fd, buf, n);
                    } else {
                        if (conn >= 0) {
                            close(conn);
                        }
                        conn = tcp_connect(child_port);
                        if (conn >= 0) {
                            write_all(conn, buf, n);
                        }
                    }
                }
            } else if (starts(line, "DONE ")) {
                done_seen = 1;
            } else if (starts(line, "ok   - ")) {
                child_passed++;
            } else if (starts(line, "FAIL - ")) {
                child_failed++;
                note("child: %s", line + 7);
            } else if (starts(line, "DIFF ")) {
                note("%s", line);
            } else if (starts(line, "NOTE modbus_close") || starts(line, "NOTE modbus_free")) {
                note("%s", line + 5);
            }
        }
        if (rd->eof) {
            pid_t w = waitpid(pid, &status, WNOHANG);
            if (w == pid) {
                reaped = 1;
                t_exit = now();
                break;
            }
        }
        t = now();
        if (kill_at > 0 && t >= kill_at) {
            kill_at = 0;
            t_signal = now();
            kill(pid, SIGTERM);
        }
        if (request_at > 0 && t >= request_at) {
            uint8_t buf[64];
            int n = build_request(tr, buf);
            request_at = 0;
            write_all(serial ? b_fd : conn, buf, n);
        }
        if (connect_at > 0 && t >= connect_at) {
            connect_at = 0;
            conn = tcp_connect(child_port);
        }
        if (t >= deadline) {
            kill(pid, SIGKILL);
            waitpid(pid, &status, 0);
            reaped = 1;
            killed = 1;
            t_exit = now();
            break;
        }
        wait_s = 0.005;
        if (!rd->eof) {
            wait_s = 0.02;
        }
        p.fd = rd->fd;
        p.events = POLLIN;
        p.revents = 0;
        if (!rd->eof) {
            poll(&p, 1, (int) (wait_s * 1000));
            if (p.revents != 0) {
                fill(rd);
            }
        } else {
            sleep_s(wait_s);
        }
    }
    /* what the child printed last */
    if (!rd->eof) {
        fcntl(rd->fd, F_SETFL, 0);
    }
    while (!rd->eof) {
        fill(rd);
    }
    while (next_line(rd, line, sizeof(line))) {
        printf("  child| %s\n", line);
        if (starts(line, "DONE ")) {
            done_seen = 1;
        } else if (starts(line, "ok   - ")) {
            child_passed++;
        } else if (starts(line, "FAIL - ")) {
            child_failed++;
            note("child: %s", line + 7);
        } else if (starts(line, "DIFF ")) {
            note("%s", line);
        } else if (starts(line, "NOTE modbus_close") || starts(line, "NOTE modbus_free")) {
            note("%s", line + 5);
        }
    }

    if (errf != NULL) {
        rewind(errf);
        while (fgets(line, sizeof(line), errf) != NULL) {
            line[strcspn(line, "\n")] = '\0';
            printf("  child(stderr)| %s\n", line);
            if (strstr(line, "bit out of range 0 - FD_SETSIZE") != NULL) {
                fortify_msg = 1;
            }
        }
        fclose(errf);
    }

    /* ---- judge */
    {
        int got;
        char what[128];
        if (killed) {
            got = OUT_HANG;
            snprintf(what, sizeof(what), "still running %.1f s after it blocked: killed (SIGKILL)",
                     t_exit - t_blocking);
        } else if (WIFSIGNALED(status)) {
            got = WTERMSIG(status) == SIGABRT ? OUT_ABORT : 31;
            snprintf(what, sizeof(what), "killed by signal %d (%s)", WTERMSIG(status),
                     strsignal(WTERMSIG(status)));
        } else {
            got = WEXITSTATUS(status) == 0 ? OUT_EXIT0 : 31;
            snprintf(what, sizeof(what), "exit status %d%s", WEXITSTATUS(status),
                     WEXITSTATUS(status) == 99 && vg ? " (valgrind found errors)" : "");
        }
        if (t_blocking == 0 && !killed) {
            EXPECT(0, "%s: the child ended before it blocked: %s", h_test, what);
            note("ended before blocking: %s", what);
            goto out;
        }
        if (t_blocking == 0) {
            EXPECT(0, "%s: the child never reached the blocking call (killed)", h_test);
            note("never blocked");
            goto out;
        }
        EXPECT((expected >> got) & 1u, "%s: %s (expected: %s)", h_test, what, expected_str);
        if (!((expected >> got) & 1u)) {
            note("%s, expected %s", what, expected_str);
        } else if (got == OUT_ABORT && !fortify_msg) {
            EXPECT(0, "%s: the abort is not glibc's \"bit out of range 0 - FD_SETSIZE on "
                    "fd_set\"", h_test);
        } else if (diff_name != NULL && got != OUT_EXIT0) {
            printf("DIFF %s: %s\n", diff_name, diff_what);
            note("DIFF %s: %s", diff_name, what);
        }
        if (got == OUT_EXIT0 && !exit_in_handler) {
            EXPECT(done_seen, "%s: the child's own checks ran to the end", h_test);
        }
        if (got == OUT_EXIT0 && streq(cs, "close-return")) {
            EXPECT(phase2_seen, "%s: the context was used again after the close", h_test);
        }
        if (child_passed + child_failed > 0 || (got == OUT_EXIT0 && !exit_in_handler)) {
            EXPECT(child_failed == 0 && child_passed > 0,
                    "%s: the child's checks: %d passed, %d failed", h_test, child_passed,
                    child_failed);
        }
        if (exit_in_handler) {
            double dt = t_exit - t_signal, limit = vg ? 5.0 : 1.0;
            if (killed) {
                /* already failed as a hang */
            } else if (t_signal > 0) {
                EXPECT(got == OUT_EXIT0 && dt < limit,
                        "%s: exited %.3f s after the SIGTERM (< %.0f s)", h_test, dt, limit);
                note("exit %.3f s after SIGTERM", dt);
            } else {
                EXPECT(0, "%s: no SIGTERM was sent", h_test);
            }
            if (serial) {
                tcgetattr(a_fd, &t_after);
                EXPECT(have_during && !tios_equal(&t_during, &t_before),
                        "%s: modbus_connect changed the line's termios (%s)", h_test,
                        have_during ? tios_str(&t_during) : "?");
                EXPECT(tios_equal(&t_after, &t_before),
                        "%s: termios after the exit equals termios before connect (%s; before %s)",
                        h_test, tios_str(&t_after), tios_str(&t_before));
            }
        }
    }
out:
    if (lis >= 0) {
        close(lis);
    }
    if (conn >= 0) {
        close(conn);
    }
    if (a_fd >= 0) {
        close(a_fd);
    }
    if (b_fd >= 0) {
        close(b_fd);
    }
    printf("RESULT %s %s%s%s%s\n", chk_failed() == 0 && chk_passed() > 0 ? "PASS" : "FAIL", h_test,
           h_summary[0] ? "  (" : "", h_summary, h_summary[0] ? ")" : "");
    return chk_summary();
}

int main(int argc, char **argv)
{
    if (argc == 7 && streq(argv[1], "child")) {
        return child_main(argv[2], argv[3], argv[4], argv[5], atoi(argv[6]));
    }
    if (argc == 7 && streq(argv[1], "run")) {
        char self[4096];
        ssize_t n = readlink("/proc/self/exe", self, sizeof(self) - 1);
        if (n <= 0) {
            perror("readlink /proc/self/exe");
            return 2;
        }
        self[n] = '\0';
        setvbuf(stdout, NULL, _IOLBF, 0);
        return harness_main(self, argv[2], argv[3], argv[4], argv[5], argv[6]);
    }
    fprintf(stderr, "usage: %s run CASE client|server tcp|rtu|rtutcp|ascii DEV_A|- DEV_B|-\n",
            argv[0]);
    return 2;
}
