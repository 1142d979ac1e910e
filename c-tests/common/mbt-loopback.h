/*
 * mbt-loopback.h: a socket of the given type (SOCK_STREAM, SOCK_DGRAM) connected to
 * 127.0.0.1:port, for the test programs that play a raw peer. Header-only.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef MBT_LOOPBACK_H
#define MBT_LOOPBACK_H

#include <arpa/inet.h>
#include <netinet/in.h>
#include <stdint.h>
#include <sys/socket.h>
#include <unistd.h>

/* The connected socket, or -1 (errno from socket or connect). */
static inline int mbt_loopback_connect(int type, int port)
{
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t) port)};
    int s = socket(AF_INET, type, 0);
    if (s < 0) {
        return -1;
    }
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(s, (struct sockaddr *) &a, sizeof a) != 0) {
        close(s);
        return -1;
    }
    return s;
}

#endif
