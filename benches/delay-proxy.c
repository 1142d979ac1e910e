/*
 * delay-proxy: a TCP proxy on 127.0.0.1 that delays every byte by a fixed time, to
 * measure a client over a long round trip on one machine (benches/pipeline.sh).
 *
 *   delay-proxy LISTEN_PORT TARGET_PORT DELAY_MS
 *
 * LISTEN_PORT 0: the kernel picks a free port. Prints "READY <port>" once it listens,
 * then accepts any number of connections, connects each to 127.0.0.1:TARGET_PORT and
 * forwards the bytes of both directions. Each chunk read from one side is written to
 * the other DELAY_MS after it was read, in the order it was read: DELAY_MS each way,
 * so a round trip through the proxy takes 2 x DELAY_MS more than without it. Runs
 * until killed (SIGTERM).
 *
 * How: one thread, one epoll set, level-triggered. Each direction of a connection
 * has a queue of chunks (what one read returned), each stamped with the time it is
 * due: the time it was read plus the delay (CLOCK_MONOTONIC). A timerfd armed at an
 * absolute time (nanosecond resolution, where epoll_wait's timeout has milliseconds)
 * wakes the loop when the earliest chunk not yet written is due. A due chunk is
 * written at once, as one write; what the destination's socket does not take waits
 * for EPOLLOUT, and the chunks behind it wait with it, so the order is kept. A
 * direction holding more than QUEUE_LIMIT bytes stops reading its source until it
 * drains (back-pressure). An end of stream is passed on (shutdown of writing on the
 * other side) once the data read before it is delivered; an error on either side
 * closes the connection. Every socket has TCP_NODELAY: a chunk goes out when it is
 * written, not when Nagle's algorithm would let it.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#define CHUNK_MAX 65536               /* the most one read takes */
#define QUEUE_LIMIT (4 * 1024 * 1024) /* bytes queued per direction before reading stops */

/* The bytes of one read, to be written when `due` comes. */
struct chunk {
    struct chunk *next;
    uint64_t due; /* CLOCK_MONOTONIC, ns */
    size_t len;   /* bytes in data */
    size_t off;   /* bytes of data already written */
    char data[];
};

/* One direction of a connection: read from fd[d], written to fd[1 - d]. */
struct direction {
    struct chunk *head, *tail;
    size_t queued; /* bytes queued and not written yet */
    int eof;       /* the source reached its end: pass it on once the queue is empty */
    int shut;      /* passed on (shutdown(SHUT_WR) of the destination) */
    int blocked;   /* the destination took no more: wait for EPOLLOUT */
};

/* What an epoll event points to: socket `side` of a connection (the listener and
 * the timer have conn NULL and a negative side). */
struct endpoint {
    struct conn *conn;
    int side;
};

/* A proxied connection: fd[0] the accepted client, fd[1] the connection to the
 * target; dir[0] client to target, dir[1] target to client. */
struct conn {
    int fd[2];
    int watched[2]; /* fd[side] is in the epoll set */
    int failed;     /* a read or write failed: close it after this batch of events */
    struct direction dir[2];
    struct endpoint ep[2];
    struct conn *prev, *next;
};

enum { TAG_LISTEN = -1, TAG_TIMER = -2 };

static int epfd, timer_fd, listen_fd, target_port;
static uint64_t delay_ns;
static struct conn *conns; /* every open connection */

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t) ts.tv_sec * 1000000000u + (uint64_t) ts.tv_nsec;
}

static void die(const char *what)
{
    fprintf(stderr, "delay-proxy: %s: %s\n", what, strerror(errno));
    exit(1);
}

static void set_nodelay(int fd)
{
    int one = 1;
    if (setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one)) != 0) {
        die("TCP_NODELAY");
    }
}

static void epoll_set(int op, int fd, uint32_t events, void *tag)
{
    struct epoll_event ev = {.events = events, .data.ptr = tag};
    if (epoll_ctl(epfd, op, fd, &ev) != 0) {
        die("epoll_ctl");
    }
}

/* Closes both sockets of `c` (which also takes them out of the epoll set) and frees
 * it with whatever it still held. */
static void conn_close(struct conn *c)
{
    for (int d = 0; d < 2; d++) {
        struct chunk *k = c->dir[d].head;
        while (k != NULL) {
            struct chunk *next = k->next;
            free(k);
            k = next;
        }
        close(c->fd[d]);
    }
    if (c->prev != NULL) {
        c->prev->next = c->next;
    } else {
        conns = c->next;
    }
    if (c->next != NULL) {
        c->next->prev = c->prev;
    }
    free(c);
}

/* Sets the events watched on fd[side]: readable while its own direction (the one
 * it is the source of) takes more, writable while the other direction is blocked
 * on it. A socket with nothing more to do in either way leaves the set, so that its
 * hang-up (always reported) does not wake the loop again and again. */
static void watch(struct conn *c, int side)
{
    const struct direction *src = &c->dir[side], *dst = &c->dir[1 - side];
    uint32_t events = 0;
    if (!src->eof && src->queued < QUEUE_LIMIT) {
        events |= EPOLLIN;
    }
    if (dst->blocked) {
        events |= EPOLLOUT;
    }
    if (events == 0 && src->eof && dst->shut) {
        if (c->watched[side]) {
            epoll_set(EPOLL_CTL_DEL, c->fd[side], 0, NULL);
            c->watched[side] = 0;
        }
        return;
    }
    epoll_set(c->watched[side] ? EPOLL_CTL_MOD : EPOLL_CTL_ADD, c->fd[side], events, &c->ep[side]);
    c->watched[side] = 1;
}

/* Accepts the clients waiting and connects each to the target; a failure drops
 * that client only. */
static void accept_all(void)
{
    for (;;) {
        int cfd = accept4(listen_fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (cfd < 0) {
            if (errno != EAGAIN && errno != EINTR && errno != ECONNABORTED) {
                perror("delay-proxy: accept");
            }
            return;
        }
        /* A blocking connect: on loopback it completes, or is refused, at once. */
        struct sockaddr_in sa = {.sin_family = AF_INET,
                                 .sin_port = htons((uint16_t) target_port),
                                 .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
        int tfd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (tfd < 0 || connect(tfd, (struct sockaddr *) &sa, sizeof(sa)) != 0 ||
            fcntl(tfd, F_SETFL, fcntl(tfd, F_GETFL) | O_NONBLOCK) != 0) {
            perror("delay-proxy: connect to the target");
            close(cfd);
            if (tfd >= 0) {
                close(tfd);
            }
            continue;
        }
        set_nodelay(cfd);
        set_nodelay(tfd);
        struct conn *c = calloc(1, sizeof(*c));
        if (c == NULL) {
            die("calloc");
        }
        c->fd[0] = cfd;
        c->fd[1] = tfd;
        for (int s = 0; s < 2; s++) {
            c->ep[s].conn = c;
            c->ep[s].side = s;
        }
        c->next = conns;
        if (conns != NULL) {
            conns->prev = c;
        }
        conns = c;
        watch(c, 0);
        watch(c, 1);
    }
}

/* Reads what fd[side] has into the queue of its direction, each read one chunk due
 * `delay_ns` later. Returns -1 when the connection failed. */
static int take_in(struct conn *c, int side)
{
    struct direction *d = &c->dir[side];
    static char buf[CHUNK_MAX];
    while (!d->eof && d->queued < QUEUE_LIMIT) {
        ssize_t n = read(c->fd[side], buf, sizeof(buf));
        if (n < 0) {
            return errno == EAGAIN || errno == EINTR ? 0 : -1;
        }
        if (n == 0) {
            d->eof = 1;
            return 0;
        }
        struct chunk *k = malloc(sizeof(*k) + (size_t) n);
        if (k == NULL) {
            die("malloc");
        }
        k->next = NULL;
        k->due = now_ns() + delay_ns;
        k->len = (size_t) n;
        k->off = 0;
        memcpy(k->data, buf, (size_t) n);
        if (d->tail != NULL) {
            d->tail->next = k;
        } else {
            d->head = k;
        }
        d->tail = k;
        d->queued += (size_t) n;
    }
    return 0;
}

/* Writes the chunks of direction `dir` that are due, in order, one write each, and
 * passes an end of stream on once they are all out. Returns -1 when the connection
 * failed. */
static int deliver(struct conn *c, int dir, uint64_t now)
{
    struct direction *d = &c->dir[dir];
    int to = c->fd[1 - dir];
    d->blocked = 0;
    while (d->head != NULL && d->head->due <= now) {
        struct chunk *k = d->head;
        ssize_t n = send(to, k->data + k->off, k->len - k->off, MSG_NOSIGNAL);
        if (n < 0) {
            if (errno == EAGAIN || errno == EINTR) {
                d->blocked = 1;
                return 0;
            }
            return -1;
        }
        k->off += (size_t) n;
        d->queued -= (size_t) n;
        if (k->off < k->len) {
            d->blocked = 1; /* the socket's buffer is full: the rest waits for room */
            return 0;
        }
        d->head = k->next;
        if (d->head == NULL) {
            d->tail = NULL;
        }
        free(k);
    }
    if (d->head == NULL && d->eof && !d->shut) {
        shutdown(to, SHUT_WR);
        d->shut = 1;
    }
    return 0;
}

/* After the events of one wait: delivers what is due on every connection, updates
 * what each socket is watched for, closes the connections that are done or failed,
 * and arms the timer for the earliest chunk still to come (disarms it if none). */
static void service(void)
{
    uint64_t now = now_ns(), next = 0;
    struct conn *c = conns;
    while (c != NULL) {
        struct conn *after = c->next;
        for (int d = 0; d < 2 && !c->failed; d++) {
            if (!c->dir[d].blocked && deliver(c, d, now) != 0) {
                c->failed = 1;
            }
        }
        if (c->failed || (c->dir[0].shut && c->dir[1].shut)) {
            conn_close(c);
            c = after;
            continue;
        }
        for (int d = 0; d < 2; d++) {
            const struct chunk *k = c->dir[d].head;
            if (k != NULL && k->due > now && (next == 0 || k->due < next)) {
                next = k->due;
            }
        }
        watch(c, 0);
        watch(c, 1);
        c = after;
    }
    struct itimerspec its = {0};
    if (next != 0) {
        its.it_value.tv_sec = (time_t) (next / 1000000000u);
        its.it_value.tv_nsec = (long) (next % 1000000000u);
    }
    if (timerfd_settime(timer_fd, TFD_TIMER_ABSTIME, &its, NULL) != 0) {
        die("timerfd_settime");
    }
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: %s LISTEN_PORT(0=any) TARGET_PORT DELAY_MS\n", argv[0]);
        return 2;
    }
    int port = atoi(argv[1]);
    target_port = atoi(argv[2]);
    delay_ns = (uint64_t) atol(argv[3]) * 1000000u;
    signal(SIGPIPE, SIG_IGN);

    listen_fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    int one = 1;
    struct sockaddr_in sa = {.sin_family = AF_INET,
                             .sin_port = htons((uint16_t) port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t sl = sizeof(sa);
    if (listen_fd < 0 || setsockopt(listen_fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) != 0 ||
        bind(listen_fd, (struct sockaddr *) &sa, sizeof(sa)) != 0 || listen(listen_fd, 64) != 0 ||
        getsockname(listen_fd, (struct sockaddr *) &sa, &sl) != 0) {
        die("listen");
    }
    epfd = epoll_create1(EPOLL_CLOEXEC);
    timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    if (epfd < 0 || timer_fd < 0) {
        die("epoll/timerfd");
    }
    static struct endpoint listen_tag = {NULL, TAG_LISTEN}, timer_tag = {NULL, TAG_TIMER};
    epoll_set(EPOLL_CTL_ADD, listen_fd, EPOLLIN, &listen_tag);
    epoll_set(EPOLL_CTL_ADD, timer_fd, EPOLLIN, &timer_tag);
    printf("READY %d\n", ntohs(sa.sin_port));
    fflush(stdout);

    for (;;) {
        struct epoll_event evs[64];
        int n = epoll_wait(epfd, evs, 64, -1);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            die("epoll_wait");
        }
        for (int i = 0; i < n; i++) {
            struct endpoint *ep = evs[i].data.ptr;
            if (ep->side == TAG_LISTEN) {
                accept_all();
                continue;
            }
            if (ep->side == TAG_TIMER) {
                uint64_t expirations;
                /* Drains the timer's count; service() below does the work. */
                if (read(timer_fd, &expirations, sizeof(expirations)) < 0 && errno != EAGAIN) {
                    die("read timerfd");
                }
                continue;
            }
            /* A socket of a connection (connections are closed only in service(),
             * after the batch: every tag of this batch is still valid). */
            struct conn *c = ep->conn;
            int side = ep->side;
            uint32_t e = evs[i].events;
            if (e & EPOLLOUT) {
                c->dir[1 - side].blocked = 0; /* room again: service() writes */
            }
            if ((e & (EPOLLIN | EPOLLHUP | EPOLLERR)) && take_in(c, side) != 0) {
                c->failed = 1; /* a reset: the connection is dropped */
            }
            /* An error, or a hang-up (both ways shut) while this side still has to
             * be written to: the peer is gone, nothing more can be delivered. */
            if ((e & EPOLLERR) || ((e & EPOLLHUP) && !c->dir[1 - side].shut)) {
                c->failed = 1;
            }
        }
        service();
    }
}
