/*
 * load-client.c: the load generator of benches/server-many.sh. Many Modbus/TCP
 * connections from one process and one thread, raw sockets and epoll, no Modbus
 * library: what the servers are measured with must not depend on either library.
 *
 *   load-client [options] HOST PORT
 *     -n N      connections (100)
 *     -d SECS   measured duration (5)
 *     -w SECS   warm-up before it, not counted (0.5)
 *     -p        paced: each connection sends one request a second, the N
 *               connections spread evenly over the second (connection i at
 *               i/N s, then every second); without it, closed loop: each
 *               connection sends its next request as soon as its answer came
 *     -i        idle afterwards: keep every connection open, print IDLE, and wait
 *               for SIGTERM (the script reads the server's memory meanwhile)
 *     -r REGS   registers read by each request (FC 03 from address 0; 10)
 *     -c K      connects in flight at once while connecting (256)
 *     -o FILE   also write the latency histogram there ("µs count" lines, the
 *               bucket's lower bound), for the script to merge several runs
 *
 * Every answer is checked: its transaction id, function code, byte count and
 * values (holding register i holds i). A connection that gets a wrong answer or is
 * closed is counted (errors) and not used again.
 *
 * Latency is per request: from just before its send() to the end of the read that
 * completed its answer (CLOCK_MONOTONIC), kept in a histogram (1 µs steps up to
 * 100 ms, 1 ms steps above). Prints:
 *   CONNECTED n=N ms=MS failed=F
 *   RESULT mode=closed|paced conns=N tx=T seconds=S tps=R p50_us=.. p99_us=..
 *          max_us=.. errors=E late=L cpu_ms=C cpu_pct=P all_tx=A
 * late (paced): sends skipped because the connection's last request had not been
 * answered when its next second came. cpu_ms: this process's user + system time
 * over the measured seconds; cpu_pct near 100 means the generator saturated its
 * core, and the tps it measured is its own limit as much as the server's. all_tx:
 * every answer, those of the warm-up too (for the server's CPU time per answer).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <arpa/inet.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "latency-hist.h"

enum state { UNUSED, CONNECTING, IDLE, WAITING, DEAD };

struct conn {
    int fd;
    enum state st;
    uint16_t tid;
    uint16_t got;
    uint64_t sent_ns;
    uint8_t buf[264];
};

static struct conn *conns;
static int nconns, regs = 10;
static uint64_t errors, late, all_tx;
static int counting;
static volatile sig_atomic_t stop_idle;

static uint64_t now_ns(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t) t.tv_sec * 1000000000u + (uint64_t) t.tv_nsec;
}

static uint64_t cpu_ns(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return ((uint64_t) ru.ru_utime.tv_sec + (uint64_t) ru.ru_stime.tv_sec) * 1000000000u +
           ((uint64_t) ru.ru_utime.tv_usec + (uint64_t) ru.ru_stime.tv_usec) * 1000u;
}

static void kill_conn(struct conn *c, int ep)
{
    epoll_ctl(ep, EPOLL_CTL_DEL, c->fd, NULL);
    close(c->fd);
    c->st = DEAD;
    errors++;
}

static int send_request(struct conn *c, int ep)
{
    uint8_t q[12];
    c->tid++;
    q[0] = (uint8_t) (c->tid >> 8);
    q[1] = (uint8_t) c->tid;
    q[2] = 0;
    q[3] = 0;
    q[4] = 0;
    q[5] = 6;
    q[6] = 1;    /* unit */
    q[7] = 0x03; /* read holding registers */
    q[8] = 0;
    q[9] = 0;
    q[10] = (uint8_t) (regs >> 8);
    q[11] = (uint8_t) regs;
    c->sent_ns = now_ns();
    c->got = 0;
    if (send(c->fd, q, sizeof q, MSG_NOSIGNAL) != (ssize_t) sizeof q) {
        kill_conn(c, ep);
        return -1;
    }
    c->st = WAITING;
    return 0;
}

/* Reads what came for c; 1 when its answer is whole and right, 0 when more is to
 * come, -1 when the connection is dead. */
static int read_answer(struct conn *c, int ep)
{
    size_t want = 9 + 2 * (size_t) regs;
    ssize_t r = recv(c->fd, c->buf + c->got, sizeof c->buf - c->got, 0);
    int i;
    if (r <= 0) {
        if (r < 0 && (errno == EAGAIN || errno == EINTR)) {
            return 0;
        }
        kill_conn(c, ep);
        return -1;
    }
    if (c->st != WAITING) {
        kill_conn(c, ep); /* an answer nobody asked for */
        return -1;
    }
    c->got = (uint16_t) (c->got + r);
    if (c->got < want) {
        return 0;
    }
    if (c->got > want || c->buf[0] != (uint8_t) (c->tid >> 8) || c->buf[1] != (uint8_t) c->tid ||
        c->buf[7] != 0x03 || c->buf[8] != 2 * regs) {
        kill_conn(c, ep);
        return -1;
    }
    for (i = 0; i < regs; i++) {
        if (c->buf[9 + 2 * i] != (uint8_t) (i >> 8) || c->buf[10 + 2 * i] != (uint8_t) i) {
            kill_conn(c, ep);
            return -1;
        }
    }
    c->st = IDLE;
    return 1;
}

static void on_term(int sig)
{
    (void) sig;
    stop_idle = 1;
}

static void usage(void)
{
    fprintf(stderr, "usage: load-client [-n N] [-d SECS] [-w SECS] [-p] [-i] [-r REGS] [-c K] [-o FILE] HOST PORT\n");
    exit(2);
}

/* Waits for events, at most until deadline (ns, CLOCK_MONOTONIC; 0: 100 ms). */
static int wait_events(int ep, struct epoll_event *ev, int max, uint64_t deadline)
{
    struct timespec ts;
    uint64_t now = now_ns(), left = deadline == 0 ? 100000000u : deadline > now ? deadline - now : 0;
    int n;
    ts.tv_sec = (time_t) (left / 1000000000u);
    ts.tv_nsec = (long) (left % 1000000000u);
    n = epoll_pwait2(ep, ev, max, &ts, NULL);
    if (n < 0 && errno == ENOSYS) {
        n = epoll_wait(ep, ev, max, (int) ((left + 999999) / 1000000));
    }
    return n < 0 && errno == EINTR ? 0 : n;
}

int main(int argc, char **argv)
{
    double secs = 5, warm = 0.5;
    int paced = 0, idle = 0, window = 256, opt, ep, i, failed = 0, in_flight = 0, next = 0, done_connecting = 0;
    struct sockaddr_in sa;
    struct epoll_event ev[512];
    struct rlimit rl;
    uint64_t t0, start, end, cpu0 = 0, cpu1, pace0, issued = 0;
    struct sigaction act;
    const char *hist_file = NULL;

    nconns = 100;
    while ((opt = getopt(argc, argv, "n:d:w:pir:c:o:")) != -1) {
        switch (opt) {
        case 'n': nconns = atoi(optarg); break;
        case 'd': secs = atof(optarg); break;
        case 'w': warm = atof(optarg); break;
        case 'p': paced = 1; break;
        case 'i': idle = 1; break;
        case 'r': regs = atoi(optarg); break;
        case 'c': window = atoi(optarg); break;
        case 'o': hist_file = optarg; break;
        default: usage();
        }
    }
    if (argc - optind != 2 || nconns < 1 || regs < 1 || regs > 125 || window < 1) {
        usage();
    }
    memset(&sa, 0, sizeof sa);
    sa.sin_family = AF_INET;
    sa.sin_port = htons((uint16_t) atoi(argv[optind + 1]));
    if (inet_pton(AF_INET, argv[optind], &sa.sin_addr) != 1) {
        usage();
    }
    /* One descriptor per connection, and a few more. */
    getrlimit(RLIMIT_NOFILE, &rl);
    if (rl.rlim_cur < (rlim_t) nconns + 64) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
    memset(&act, 0, sizeof act);
    act.sa_handler = on_term;
    sigaction(SIGTERM, &act, NULL);
    sigaction(SIGINT, &act, NULL);
    conns = calloc((size_t) nconns, sizeof *conns);
    ep = epoll_create1(EPOLL_CLOEXEC);
    if (conns == NULL || ep < 0) {
        perror("setup");
        return 1;
    }

    /* Connect, K at a time (a burst of 10,000 SYNs would overflow the listen queue,
     * and a dropped SYN waits a second to be sent again). */
    t0 = now_ns();
    while (!done_connecting) {
        int n;
        while (in_flight < window && next < nconns) {
            struct conn *c = &conns[next];
            struct epoll_event e = {.events = EPOLLOUT, .data.u32 = (uint32_t) next};
            int one = 1;
            c->fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
            if (c->fd < 0) {
                perror("socket");
                return 1;
            }
            setsockopt(c->fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
            if (connect(c->fd, (struct sockaddr *) &sa, sizeof sa) != 0 && errno != EINPROGRESS) {
                close(c->fd);
                c->st = DEAD;
                failed++;
            } else {
                c->st = CONNECTING;
                epoll_ctl(ep, EPOLL_CTL_ADD, c->fd, &e);
                in_flight++;
            }
            next++;
        }
        if (in_flight == 0) {
            done_connecting = 1;
            break;
        }
        n = wait_events(ep, ev, 512, now_ns() + 10000000000u);
        if (n == 0 && now_ns() - t0 > 60000000000u) {
            fprintf(stderr, "load-client: connects still pending after 60 s\n");
            return 1;
        }
        for (i = 0; i < n; i++) {
            struct conn *c = &conns[ev[i].data.u32];
            int err = 0;
            socklen_t len = sizeof err;
            struct epoll_event e = {.events = EPOLLIN, .data.u32 = ev[i].data.u32};
            getsockopt(c->fd, SOL_SOCKET, SO_ERROR, &err, &len);
            in_flight--;
            if (err != 0) {
                epoll_ctl(ep, EPOLL_CTL_DEL, c->fd, NULL);
                close(c->fd);
                c->st = DEAD;
                failed++;
            } else {
                c->st = IDLE;
                epoll_ctl(ep, EPOLL_CTL_MOD, c->fd, &e);
            }
        }
    }
    printf("CONNECTED n=%d ms=%.0f failed=%d\n", nconns - failed, (double) (now_ns() - t0) / 1e6, failed);
    fflush(stdout);
    if (failed == nconns) {
        return 1;
    }

    pace0 = now_ns();
    start = pace0 + (uint64_t) (warm * 1e9);
    end = start + (uint64_t) (secs * 1e9);
    if (!paced) {
        for (i = 0; i < nconns; i++) {
            if (conns[i].st == IDLE) {
                send_request(&conns[i], ep);
            }
        }
    }
    for (;;) {
        uint64_t now = now_ns(), deadline;
        int n;
        if (!counting && now >= start) {
            /* The warm-up is over: count from here. */
            counting = 1;
            memset(hist, 0, sizeof hist);
            counted = 0;
            max_ns = 0;
            late = 0;
            cpu0 = cpu_ns();
            start = now;
            end = start + (uint64_t) (secs * 1e9);
        }
        if (counting && now >= end) {
            break;
        }
        if (paced) {
            /* Send every request due by now: request k at k/N s, connection k % N. */
            uint64_t due = (now - pace0) * (uint64_t) nconns / 1000000000u;
            while (issued < due) {
                struct conn *c = &conns[issued % (uint64_t) nconns];
                if (c->st == IDLE) {
                    send_request(c, ep);
                } else if (c->st == WAITING && counting) {
                    late++;
                }
                issued++;
            }
            deadline = pace0 + (issued + 1) * 1000000000u / (uint64_t) nconns;
        } else {
            deadline = counting ? end : start;
        }
        n = wait_events(ep, ev, 512, deadline);
        for (i = 0; i < n; i++) {
            struct conn *c = &conns[ev[i].data.u32];
            if (c->st == DEAD) {
                continue;
            }
            if (read_answer(c, ep) == 1) {
                uint64_t t = now_ns();
                all_tx++;
                if (counting && t < end) {
                    record(t - c->sent_ns);
                }
                if (!paced && (!counting || t < end)) {
                    send_request(c, ep);
                }
            }
        }
    }
    cpu1 = cpu_ns();
    {
        double s = (double) (end - start) / 1e9, cpu_ms = (double) (cpu1 - cpu0) / 1e6;
        printf("RESULT mode=%s conns=%d tx=%llu seconds=%.3f tps=%.0f p50_us=%llu p99_us=%llu max_us=%llu "
               "errors=%llu late=%llu cpu_ms=%.0f cpu_pct=%.0f all_tx=%llu\n",
               paced ? "paced" : "closed", nconns - failed, (unsigned long long) counted, s, (double) counted / s,
               (unsigned long long) quantile(0.5), (unsigned long long) quantile(0.99),
               (unsigned long long) (max_ns / 1000), (unsigned long long) errors, (unsigned long long) late, cpu_ms,
               cpu_ms / (s * 10), (unsigned long long) all_tx);
        fflush(stdout);
    }
    if (hist_file != NULL) {
        write_hist(hist_file);
    }
    if (idle) {
        /* Every answer still due is taken first, so that the server holds no request. */
        uint64_t until = now_ns() + 2000000000u;
        int waiting = 1;
        while (waiting && now_ns() < until) {
            int n = wait_events(ep, ev, 512, now_ns() + 50000000u);
            for (i = 0; i < n; i++) {
                struct conn *c = &conns[ev[i].data.u32];
                if (c->st != DEAD) {
                    read_answer(c, ep);
                }
            }
            waiting = 0;
            for (i = 0; i < nconns; i++) {
                waiting |= conns[i].st == WAITING;
            }
        }
        {
            int open = 0;
            for (i = 0; i < nconns; i++) {
                open += conns[i].st == IDLE;
            }
            printf("IDLE open=%d\n", open);
            fflush(stdout);
        }
        while (!stop_idle) {
            pause();
        }
    }
    return 0;
}
