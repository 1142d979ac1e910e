/*
 * line-pace: a serial line that takes the time a real one does, for
 * benches/gateway.sh.
 *
 *   line-pace BAUD BITS LINK_A LINK_B
 *
 * A pty pair passes bytes as fast as the kernel copies them, so a gateway on one is
 * never limited by the baud rate. line-pace makes two ptys (their terminal ends
 * linked at LINK_A and LINK_B) and relays the bytes written to one to the other at
 * the time they would have finished on the wire: BITS bits per character (a start
 * bit, the data, the parity, the stop bits) at BAUD, one direction at a time (RS-485
 * is half duplex: a frame waits until the line is free). A chunk is delivered whole
 * when its last byte ends, which a Modbus RTU reader sees as one frame. The waits are
 * absolute clock_nanosleep()s with a timer slack of 1 ns (the default 50 us would be
 * a few percent of a frame at 115200 baud); the relay uses almost no CPU, which the
 * programs measured beside it on two CPUs need. Prints READY when both links exist;
 * runs until killed.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define SPIN_NS 50000

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t) ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* A pty whose terminal end is linked at `link` (and kept open: the master end then
 * never reads EIO between the programs that open the link); returns the master. */
static int make_pty(const char *link)
{
    int m = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC), s;
    struct termios t;
    const char *name;
    if (m < 0 || grantpt(m) != 0 || unlockpt(m) != 0 || (name = ptsname(m)) == NULL) {
        perror("line-pace: pty");
        exit(1);
    }
    s = open(name, O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (s < 0 || tcgetattr(s, &t) != 0) {
        perror("line-pace: pty terminal end");
        exit(1);
    }
    cfmakeraw(&t);
    tcsetattr(s, TCSANOW, &t);
    unlink(link);
    if (symlink(name, link) != 0) {
        perror("line-pace: symlink");
        exit(1);
    }
    return m;
}

int main(int argc, char **argv)
{
    struct pollfd p[2];
    unsigned char buf[4096];
    int64_t per_char, free_at = 0;
    int i;
    if (argc != 5 || atoi(argv[1]) <= 0 || atoi(argv[2]) <= 0) {
        fprintf(stderr, "usage: %s BAUD BITS LINK_A LINK_B\n", argv[0]);
        return 2;
    }
    per_char = (int64_t) atoi(argv[2]) * 1000000000 / atoi(argv[1]);
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
    for (i = 0; i < 2; i++) {
        p[i].fd = make_pty(argv[3 + i]);
        p[i].events = POLLIN;
    }
    printf("READY\n");
    fflush(stdout);
    for (;;) {
        if (poll(p, 2, -1) < 0) {
            if (errno == EINTR) {
                continue;
            }
            perror("line-pace: poll");
            return 1;
        }
        for (i = 0; i < 2; i++) {
            ssize_t n, off;
            int64_t t;
            struct timespec until;
            if (!(p[i].revents & POLLIN)) {
                continue;
            }
            n = read(p[i].fd, buf, sizeof buf);
            if (n <= 0) {
                continue;
            }
            t = now_ns();
            free_at = (free_at > t ? free_at : t) + n * per_char;
            /* Asleep until SPIN_NS before the time, then on the clock: waking from
             * sleep takes tens of microseconds on a virtual machine. */
            t = free_at - SPIN_NS;
            until.tv_sec = t / 1000000000;
            until.tv_nsec = t % 1000000000;
            while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, NULL) == EINTR) {
            }
            while (now_ns() < free_at) {
            }
            for (off = 0; off < n;) {
                ssize_t w = write(p[1 - i].fd, buf + off, (size_t) (n - off));
                if (w <= 0) {
                    break;
                }
                off += w;
            }
        }
    }
}
