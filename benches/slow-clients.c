/*
 * slow-clients.c: misbehaving clients for benches/server-many.sh, from one thread:
 *
 *   slow-clients [-t] HOST PORT STALLED TRICKLE
 *
 * STALLED connections each send the first 3 bytes of a TLS record (0x16 0x03 0x01,
 * a handshake that has begun) and nothing more. TRICKLE connections each send a
 * valid Modbus/TCP request (read 10 holding registers) one byte a second, request
 * after request, their bytes spread over the second; to a TLS server these are
 * bytes that are no TLS, sent as slowly. With -t they send instead, one byte a
 * second, the start of a TLS handshake record that announces 512 bytes (a
 * ClientHello's header, then zeros): a handshake a TLS server can only wait for.
 * Whatever comes back is read and dropped. A connection the server closes is
 * counted and made again (a stalled one after 100 ms, a trickling one at its next
 * byte's time): the pressure stays for as long as the program runs. Every
 * connection is made at the start; prints READY once each has been made at least
 * once, and on SIGTERM or SIGINT:
 *   SLOW stalled=S trickle=T stalled_closed=A trickle_closed=B bytes=N
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

struct slow {
    int fd;      /* -1: to connect at next_ms */
    int trickle; /* 0: stalled handshake */
    int pos;     /* trickle: the next byte of the request */
    uint16_t tid;
    int64_t next_ms;
};

static volatile sig_atomic_t stopping;
static struct sockaddr_in sa;
static int tls_trickle;

static void on_term(int sig)
{
    (void) sig;
    stopping = 1;
}

static int64_t now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t) t.tv_sec * 1000 + t.tv_nsec / 1000000;
}

static int open_conn(struct slow *s)
{
    static const uint8_t hello[3] = {0x16, 0x03, 0x01};
    int one = 1;
    s->fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (s->fd < 0) {
        return -1;
    }
    setsockopt(s->fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (connect(s->fd, (struct sockaddr *) &sa, sizeof sa) != 0 ||
        (!s->trickle && send(s->fd, hello, sizeof hello, MSG_NOSIGNAL) != (ssize_t) sizeof hello)) {
        close(s->fd);
        s->fd = -1;
        return -1;
    }
    s->pos = 0;
    return 0;
}

int main(int argc, char **argv)
{
    int stalled, trickle, n, i, ready = 0;
    long stalled_closed = 0, trickle_closed = 0, bytes = 0;
    struct slow *c;
    struct pollfd *pfd;
    char *made;
    struct sigaction act;
    int64_t t0;

    if (argc > 1 && strcmp(argv[1], "-t") == 0) {
        tls_trickle = 1;
        argc--;
        argv++;
    }
    if (argc != 5) {
        fprintf(stderr, "usage: slow-clients [-t] HOST PORT STALLED TRICKLE\n");
        return 2;
    }
    memset(&sa, 0, sizeof sa);
    sa.sin_family = AF_INET;
    sa.sin_port = htons((uint16_t) atoi(argv[2]));
    if (inet_pton(AF_INET, argv[1], &sa.sin_addr) != 1) {
        return 2;
    }
    stalled = atoi(argv[3]);
    trickle = atoi(argv[4]);
    n = stalled + trickle;
    c = calloc((size_t) n + 1, sizeof *c);
    pfd = calloc((size_t) n + 1, sizeof *pfd);
    made = calloc((size_t) n + 1, 1);
    if (c == NULL || pfd == NULL || made == NULL) {
        return 1;
    }
    memset(&act, 0, sizeof act);
    act.sa_handler = on_term;
    sigaction(SIGTERM, &act, NULL);
    sigaction(SIGINT, &act, NULL);
    t0 = now_ms();
    for (i = 0; i < n; i++) {
        c[i].fd = -1;
        c[i].trickle = i >= stalled;
        /* The trickling ones' bytes spread evenly over each second. */
        c[i].next_ms = c[i].trickle ? t0 + (int64_t) (i - stalled) * 1000 / (trickle > 0 ? trickle : 1) : t0;
        /* Every connection at once; the first bytes of the trickling ones follow. */
        if (open_conn(&c[i]) != 0) {
            c[i].next_ms = t0 + 100;
        }
    }
    while (!stopping) {
        int64_t now = now_ms(), wake = now + 1000;
        int up = 0;
        for (i = 0; i < n; i++) {
            struct slow *s = &c[i];
            if (s->fd < 0 && now >= s->next_ms && open_conn(s) != 0) {
                s->next_ms = now + 100; /* refused: try again soon */
            }
            if (s->fd >= 0 && s->trickle && now >= s->next_ms) {
                uint8_t req[12] = {(uint8_t) (s->tid >> 8), (uint8_t) s->tid, 0, 0, 0, 6, 1, 3, 0, 0, 0, 10};
                /* -t: record header (handshake, 512 bytes), ClientHello header (508
                 * bytes, TLS 1.2 legacy version), then zeros. */
                static const uint8_t hello[11] = {0x16, 0x03, 0x01, 0x02, 0x00, 0x01, 0x00, 0x01, 0xfc, 0x03, 0x03};
                uint8_t byte = tls_trickle ? (s->pos < (int) sizeof hello ? hello[s->pos] : 0) : req[s->pos];
                if (send(s->fd, &byte, 1, MSG_NOSIGNAL) == 1) {
                    bytes++;
                    if (++s->pos == (tls_trickle ? 517 : (int) sizeof req)) {
                        s->pos = 0;
                        s->tid++;
                    }
                } else {
                    close(s->fd);
                    s->fd = -1;
                    trickle_closed++;
                }
                s->next_ms += 1000;
                if (s->next_ms <= now) {
                    s->next_ms = now + 1000;
                }
            }
            if (s->fd >= 0) {
                made[i] = 1;
            }
            up += made[i];
            if ((s->fd < 0 || s->trickle) && s->next_ms < wake) {
                wake = s->next_ms;
            }
            pfd[i].fd = s->fd;
            pfd[i].events = POLLIN;
            pfd[i].revents = 0;
        }
        if (!ready && up == n) {
            printf("READY\n");
            fflush(stdout);
            ready = 1;
        }
        if (poll(pfd, (nfds_t) n, (int) (wake > now ? wake - now : 0)) <= 0) {
            continue;
        }
        for (i = 0; i < n; i++) {
            struct slow *s = &c[i];
            uint8_t buf[512];
            ssize_t r;
            if (s->fd < 0 || pfd[i].revents == 0) {
                continue;
            }
            r = recv(s->fd, buf, sizeof buf, MSG_DONTWAIT);
            if (r > 0 || (r < 0 && (errno == EAGAIN || errno == EINTR))) {
                continue; /* an answer or an alert: dropped */
            }
            /* Closed by the server: again, later. */
            close(s->fd);
            s->fd = -1;
            if (s->trickle) {
                trickle_closed++;
            } else {
                stalled_closed++;
                s->next_ms = now_ms() + 100;
            }
        }
    }
    printf("SLOW stalled=%d trickle=%d stalled_closed=%ld trickle_closed=%ld bytes=%ld\n", stalled, trickle,
           stalled_closed, trickle_closed, bytes);
    fflush(stdout);
    return 0;
}
