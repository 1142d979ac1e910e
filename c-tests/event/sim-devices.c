/*
 * sim-devices: many simulated Modbus TCP devices behind one port, for the event-driven
 * client's tests and benchmark. Each accepted connection is one device; a read of
 * holding or input registers (FC 03, 04) is answered DELAY_MS after it arrived, with
 * every value the device's number (its connection's order, from 0). Every
 * DEAD_EVERY-th device (0: none) accepts and never answers.
 *
 *   sim-devices PORT DELAY_MS DEAD_EVERY      PORT 0: the kernel picks one
 *
 * Prints "READY <port>", then serves until killed (SIGTERM). No libmodbus: the
 * devices are the test's, not a library under test.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MAX_DEV 20000
#define QUEUE (1 << 16)

struct device {
    int fd;
    int number;
    int dead;
    uint8_t in[260];
    int have;
};

struct pending {
    double due;
    int fd;
    int number;
    uint8_t rsp[9 + 250];
    int len;
};

static struct pending queue[QUEUE];
static unsigned head, tail;

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

int main(int argc, char **argv)
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s PORT DELAY_MS DEAD_EVERY\n", argv[0]);
        return 2;
    }
    int port = atoi(argv[1]), dead_every = atoi(argv[3]);
    double delay = atof(argv[2]);
    int lf = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0), one = 1;
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t) port),
                            .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t alen = sizeof(a);
    setsockopt(lf, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    if (bind(lf, (struct sockaddr *) &a, sizeof(a)) != 0 || listen(lf, 4096) != 0 ||
        getsockname(lf, (struct sockaddr *) &a, &alen) != 0) {
        perror("sim-devices: listen");
        return 1;
    }
    int ep = epoll_create1(0);
    struct epoll_event ev = {.events = EPOLLIN, .data.ptr = NULL};
    epoll_ctl(ep, EPOLL_CTL_ADD, lf, &ev);
    static struct device dev[MAX_DEV];
    int ndev = 0;
    printf("READY %d\n", ntohs(a.sin_port));
    fflush(stdout);

    for (;;) {
        int timeout = -1;
        if (head != tail) {
            double left = queue[head % QUEUE].due - now_ms();
            timeout = left <= 0 ? 0 : (int) left + 1;
        }
        struct epoll_event evs[256];
        int n = epoll_wait(ep, evs, 256, timeout);
        for (int i = 0; i < n; i++) {
            struct device *d = evs[i].data.ptr;
            if (d == NULL) {
                int c;
                while (ndev < MAX_DEV && (c = accept4(lf, NULL, NULL, SOCK_NONBLOCK)) >= 0) {
                    setsockopt(c, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
                    d = &dev[ndev];
                    d->fd = c;
                    d->number = ndev;
                    d->dead = dead_every > 0 && ndev % dead_every == dead_every - 1;
                    d->have = 0;
                    ndev++;
                    struct epoll_event e = {.events = EPOLLIN, .data.ptr = d};
                    epoll_ctl(ep, EPOLL_CTL_ADD, c, &e);
                }
                continue;
            }
            ssize_t k = recv(d->fd, d->in + d->have, sizeof(d->in) - (size_t) d->have, 0);
            if (k <= 0) {
                epoll_ctl(ep, EPOLL_CTL_DEL, d->fd, NULL);
                close(d->fd);
                d->fd = -1;
                continue;
            }
            d->have += (int) k;
            /* Whole requests (MBAP length), one after the other. */
            while (d->have >= 7) {
                int len = 6 + ((d->in[4] << 8) | d->in[5]);
                if (len > (int) sizeof(d->in) || len < 8) {
                    d->have = 0;
                    break;
                }
                if (d->have < len) {
                    break;
                }
                uint8_t *r = d->in;
                int nb = len >= 12 ? (r[10] << 8) | r[11] : 1;
                if (!d->dead && (r[7] == 3 || r[7] == 4) && nb >= 1 && nb <= 125 && tail - head < QUEUE) {
                    struct pending *p = &queue[tail++ % QUEUE];
                    p->due = now_ms() + delay;
                    p->fd = d->fd;
                    p->number = d->number;
                    memcpy(p->rsp, r, 4);
                    p->rsp[4] = (uint8_t) ((3 + 2 * nb) >> 8);
                    p->rsp[5] = (uint8_t) (3 + 2 * nb);
                    p->rsp[6] = r[6];
                    p->rsp[7] = r[7];
                    p->rsp[8] = (uint8_t) (2 * nb);
                    for (int j = 0; j < nb; j++) {
                        p->rsp[9 + 2 * j] = (uint8_t) (d->number >> 8);
                        p->rsp[10 + 2 * j] = (uint8_t) d->number;
                    }
                    p->len = 9 + 2 * nb;
                }
                memmove(d->in, d->in + len, (size_t) (d->have - len));
                d->have -= len;
            }
        }
        double t = now_ms();
        while (head != tail && queue[head % QUEUE].due <= t) {
            struct pending *p = &queue[head++ % QUEUE];
            if (p->fd >= 0) {
                (void) !send(p->fd, p->rsp, (size_t) p->len, MSG_NOSIGNAL);
            }
        }
    }
}
