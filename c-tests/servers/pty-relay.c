/*
 * pty-relay: a null-modem cable made of two pseudo-terminals.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 *
 * usage: pty-relay <link0> <link1> <readyfile>
 * Opens two pty pairs in raw mode, makes <link0> and <link1> symlinks to their slave
 * devices, and copies every byte written on one slave to the other. Unlike a socat pty
 * pair it keeps both slaves open itself, so that a client closing its end (and the next
 * one opening it) never makes the relay see EIO/hang-up and exit: one relay serves many
 * client runs. It is a plain byte pipe; all faults are produced by the test server.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../common/mbtest.h"

static const char *links[2];

static void on_term(int sig)
{
    (void) sig;
    unlink(links[0]);
    unlink(links[1]);
    _exit(0);
}

static int copy(int from, int to)
{
    unsigned char buf[512];
    ssize_t n = read(from, buf, sizeof(buf));
    ssize_t done = 0;
    if (n <= 0) {
        return (n < 0 && (errno == EINTR || errno == EAGAIN)) ? 0 : -1;
    }
    while (done < n) {
        ssize_t w = write(to, buf + done, (size_t) (n - done));
        if (w < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            return -1;
        }
        done += w;
    }
    return 0;
}

int main(int argc, char **argv)
{
    int m[2], s[2], i;
    char name[2][256];
    FILE *f;

    if (argc != 4) {
        fprintf(stderr, "usage: %s <link0> <link1> <readyfile>\n", argv[0]);
        return 1;
    }
    links[0] = argv[1];
    links[1] = argv[2];
    for (i = 0; i < 2; i++) {
        if (mbt_openpty_raw(&m[i], &s[i], name[i], sizeof(name[i])) != 0) {
            perror("openpty");
            return 1;
        }
        unlink(links[i]);
        if (symlink(name[i], links[i]) != 0) {
            perror("symlink");
            return 1;
        }
    }
    signal(SIGTERM, on_term);
    signal(SIGINT, on_term);
    f = fopen(argv[3], "w");
    if (f != NULL) {
        fprintf(f, "%s %s\n", name[0], name[1]);
        fclose(f);
    }
    for (;;) {
        struct pollfd p[2];
        p[0].fd = m[0];
        p[0].events = POLLIN;
        p[1].fd = m[1];
        p[1].events = POLLIN;
        if (poll(p, 2, -1) < 0) {
            if (errno == EINTR) {
                continue;
            }
            perror("poll");
            return 1;
        }
        for (i = 0; i < 2; i++) {
            if (p[i].revents & POLLIN) {
                if (copy(m[i], m[1 - i]) < 0) {
                    perror("relay");
                    on_term(0);
                }
            } else if (p[i].revents & (POLLHUP | POLLERR)) {
                /* Cannot happen while we hold the slave open; avoid a busy loop. */
                mbt_msleep(10);
            }
        }
    }
}
