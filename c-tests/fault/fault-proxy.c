/*
 * fault-proxy: a man in the middle between a Modbus client and server that injects
 * one fault into one message.
 *
 *   fault-proxy tcp UPSTREAM_PORT FAULT K RSP_LEN REQ_LEN
 *   fault-proxy pty CLIENT_LINK SERVER_LINK FAULT K RSP_LEN REQ_LEN
 *
 * TCP: listens on 127.0.0.1 (a free port chosen by the kernel), prints "READY <port>",
 * and for each client connection opens one to 127.0.0.1:UPSTREAM_PORT. PTY: opens two
 * pty pairs in raw mode, symlinks CLIENT_LINK and SERVER_LINK to their slave devices
 * (keeping the slaves open itself, so no side ever sees a hang-up), prints
 * "READY <CLIENT_LINK>", and relays between the masters.
 *
 * Messages are cut by length: every request is REQ_LEN bytes and every response
 * RSP_LEN bytes (the scenario uses one request shape). The fault applies to
 * response number K (1-based, counted over the proxy's life) or, for req-* faults, to
 * request number K:
 *
 *   none         relay unchanged
 *   split        the response one byte at a time, 2 ms apart
 *   pause-below  5 bytes, a 40 ms pause (below a 100 ms byte timeout), the rest
 *   pause-past   5 bytes, a 250 ms pause (past the byte timeout), the rest
 *   drop         one byte in the middle is dropped
 *   dup          one byte in the middle is sent twice
 *   corrupt      one byte in the middle has its bits flipped
 *   corrupt-head the first byte (TCP: transaction id; RTU: slave) has its bits flipped
 *   close        half of the response, then the client connection is closed (TCP)
 *   late         the response is held until the client's next request arrives (the
 *                client has timed out by then), then sent just before that request
 *                goes to the server
 *   req-split    the request one byte at a time, 2 ms apart
 *   req-corrupt  one byte in the middle of the request has its bits flipped
 *
 * Prints "FAULT <name> applied" on stderr when it does. Stops on SIGTERM.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define MAXQ 4096

/* One scheduled write: `len` bytes to `fd` not before `due` (ms, monotonic). */
struct out {
    int to_client;
    double due;
    int len;
    unsigned char b[300];
};

static struct out q[MAXQ];
static int qhead, qtail;
static const char *fault;
static int fault_k, rsp_len, req_len;
static int n_rsp, n_req;
static int cfd = -1, sfd = -1, is_tcp;
static unsigned char rbuf[600], qbuf[600];
static int rfill, qfill;
static unsigned char held[300];
static int held_len; /* "late": the response waiting for the next request */
static int close_after_queue;
static const char *links[2];

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

static double last_due(void)
{
    double t = now_ms();
    if (qtail != qhead) {
        double d = q[(qtail + MAXQ - 1) % MAXQ].due;
        if (d > t) {
            return d;
        }
    }
    return t;
}

static void push(int to_client, double delay, const unsigned char *b, int len)
{
    struct out *o = &q[qtail];
    if ((qtail + 1) % MAXQ == qhead || len > (int) sizeof(o->b)) {
        fprintf(stderr, "fault-proxy: queue overflow\n");
        exit(1);
    }
    o->to_client = to_client;
    o->due = last_due() + delay;
    o->len = len;
    memcpy(o->b, b, (size_t) len);
    qtail = (qtail + 1) % MAXQ;
}

static int is(const char *name)
{
    return strcmp(fault, name) == 0;
}

static void applied(void)
{
    fprintf(stderr, "FAULT %s applied\n", fault);
}

/* A complete response from the server: relay it, or the faulted version. */
static void on_response(unsigned char *b, int len)
{
    int mid = len / 2;
    n_rsp++;
    if (n_rsp != fault_k || strncmp(fault, "req-", 4) == 0 || is("none")) {
        push(1, 0, b, len);
        return;
    }
    applied();
    if (is("split")) {
        for (int i = 0; i < len; i++) {
            push(1, i ? 2 : 0, b + i, 1);
        }
    } else if (is("pause-below") || is("pause-past")) {
        push(1, 0, b, 5);
        push(1, is("pause-below") ? 40 : 250, b + 5, len - 5);
    } else if (is("drop")) {
        push(1, 0, b, mid);
        push(1, 0, b + mid + 1, len - mid - 1);
    } else if (is("dup")) {
        push(1, 0, b, mid + 1);
        push(1, 0, b + mid, len - mid);
    } else if (is("corrupt")) {
        b[mid] ^= 0x5A;
        push(1, 0, b, len);
    } else if (is("corrupt-head")) {
        b[0] ^= 0x5A;
        push(1, 0, b, len);
    } else if (is("close")) {
        push(1, 0, b, mid);
        close_after_queue = 1;
    } else if (is("late")) {
        memcpy(held, b, (size_t) len);
        held_len = len;
    } else {
        fprintf(stderr, "fault-proxy: unknown fault %s\n", fault);
        exit(2);
    }
}

static void on_request(unsigned char *b, int len)
{
    n_req++;
    if (held_len > 0) {
        /* The late response overtakes the new request's answer. */
        push(1, 0, held, held_len);
        held_len = 0;
    }
    if (n_req == fault_k && is("req-split")) {
        applied();
        for (int i = 0; i < len; i++) {
            push(0, i ? 2 : 0, b + i, 1);
        }
        return;
    }
    if (n_req == fault_k && is("req-corrupt")) {
        applied();
        b[len / 2] ^= 0x5A;
    }
    push(0, 0, b, len);
}

static void reset_stream(void)
{
    rfill = qfill = 0;
    qhead = qtail = 0;
    held_len = 0;
    close_after_queue = 0;
}

static void drop_client(void)
{
    if (cfd >= 0) {
        close(cfd);
    }
    if (sfd >= 0) {
        close(sfd);
    }
    cfd = sfd = -1;
    reset_stream();
}

static int flush_queue(void)
{
    while (qhead != qtail && q[qhead].due <= now_ms()) {
        struct out *o = &q[qhead];
        int fd = o->to_client ? cfd : sfd;
        if (fd >= 0 && write(fd, o->b, (size_t) o->len) != o->len) {
            return -1;
        }
        qhead = (qhead + 1) % MAXQ;
    }
    if (qhead == qtail && close_after_queue) {
        applied();
        drop_client();
    }
    return 0;
}

static int open_master(const char *link)
{
    int m, s;
    char name[256];
    struct termios t;
    if (openpty(&m, &s, name, NULL, NULL) != 0) {
        return -1;
    }
    tcgetattr(s, &t);
    cfmakeraw(&t);
    tcsetattr(s, TCSANOW, &t);
    unlink(link);
    if (symlink(name, link) != 0) {
        return -1;
    }
    /* The slave stays open here (never closed) so that the master never sees EIO. */
    return m;
}

static void on_term(int sig)
{
    (void) sig;
    if (links[0]) {
        unlink(links[0]);
        unlink(links[1]);
    }
    _exit(0);
}

int main(int argc, char **argv)
{
    int lfd = -1, upstream = 0, one = 1;
    if (argc < 7) {
        fprintf(stderr, "usage: see the comment at the top of fault-proxy.c\n");
        return 2;
    }
    signal(SIGPIPE, SIG_IGN);
    signal(SIGTERM, on_term);
    is_tcp = strcmp(argv[1], "tcp") == 0;
    if (is_tcp) {
        struct sockaddr_in sa;
        socklen_t sl = sizeof(sa);
        upstream = atoi(argv[2]);
        fault = argv[3];
        fault_k = atoi(argv[4]);
        rsp_len = atoi(argv[5]);
        req_len = atoi(argv[6]);
        lfd = socket(AF_INET, SOCK_STREAM, 0);
        setsockopt(lfd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
        memset(&sa, 0, sizeof(sa));
        sa.sin_family = AF_INET;
        sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        if (bind(lfd, (struct sockaddr *) &sa, sizeof(sa)) != 0 || listen(lfd, 4) != 0 ||
            getsockname(lfd, (struct sockaddr *) &sa, &sl) != 0) {
            perror("fault-proxy: listen");
            return 1;
        }
        printf("READY %d\n", ntohs(sa.sin_port));
    } else {
        if (argc < 8) {
            return 2;
        }
        links[0] = argv[2];
        links[1] = argv[3];
        fault = argv[4];
        fault_k = atoi(argv[5]);
        rsp_len = atoi(argv[6]);
        req_len = atoi(argv[7]);
        cfd = open_master(links[0]);
        sfd = open_master(links[1]);
        if (cfd < 0 || sfd < 0) {
            perror("fault-proxy: openpty");
            return 1;
        }
        printf("READY %s\n", links[0]);
    }
    fflush(stdout);
    if (rsp_len <= 0 || rsp_len > 260 || req_len <= 0 || req_len > 260) {
        return 2;
    }

    for (;;) {
        struct pollfd p[3];
        int np = 0, timeout = -1;
        if (is_tcp && cfd < 0) {
            struct sockaddr_in sa;
            cfd = accept(lfd, NULL, NULL);
            if (cfd < 0) {
                continue;
            }
            sfd = socket(AF_INET, SOCK_STREAM, 0);
            memset(&sa, 0, sizeof(sa));
            sa.sin_family = AF_INET;
            sa.sin_port = htons((uint16_t) upstream);
            sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
            if (connect(sfd, (struct sockaddr *) &sa, sizeof(sa)) != 0) {
                perror("fault-proxy: upstream");
                drop_client();
                continue;
            }
            setsockopt(cfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
            setsockopt(sfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
        }
        p[0].fd = cfd;
        p[0].events = POLLIN;
        p[1].fd = sfd;
        p[1].events = POLLIN;
        np = 2;
        if (qhead != qtail) {
            double d = q[qhead].due - now_ms();
            timeout = d < 0 ? 0 : (int) d + 1;
        }
        if (poll(p, (nfds_t) np, timeout) < 0) {
            if (errno == EINTR) {
                continue;
            }
            return 1;
        }
        if (p[0].revents & (POLLIN | POLLHUP | POLLERR)) {
            ssize_t n = read(cfd, qbuf + qfill, (size_t) (req_len - qfill));
            if (n <= 0) {
                if (is_tcp) {
                    drop_client();
                    continue;
                }
            } else {
                qfill += (int) n;
                if (qfill == req_len) {
                    qfill = 0;
                    on_request(qbuf, req_len);
                }
            }
        }
        if (p[1].revents & (POLLIN | POLLHUP | POLLERR)) {
            ssize_t n = read(sfd, rbuf + rfill, (size_t) (rsp_len - rfill));
            if (n <= 0) {
                if (is_tcp) {
                    drop_client();
                    continue;
                }
            } else {
                rfill += (int) n;
                if (rfill == rsp_len) {
                    rfill = 0;
                    on_response(rbuf, rsp_len);
                }
            }
        }
        if (flush_queue() != 0 && is_tcp) {
            drop_client();
        }
    }
}
