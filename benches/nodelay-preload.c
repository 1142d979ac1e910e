/*
 * nodelay-preload.so: an LD_PRELOAD object that sets TCP_NODELAY on every socket a
 * server accepts (accept, accept4), for the diagnostic rows of benches/pipeline.sh.
 *
 * libmodbus leaves Nagle's algorithm on for the sockets modbus_tcp_accept returns
 * (it sets TCP_NODELAY on client sockets only), and rsmodbus does the same. A server
 * answering pipelined requests one by one then sends the first answer at once and
 * holds the next ones until the first is acknowledged: over a long round trip that
 * delays them by about a round trip. With this object preloaded, the same server
 * binary answers each request at once, which shows what the pipelined client gets
 * when the server does not wait.
 *
 *   gcc -shared -fPIC benches/nodelay-preload.c -o nodelay-preload.so -ldl
 *   LD_PRELOAD=./nodelay-preload.so mb-server tcp 0
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stddef.h>
#include <sys/socket.h>

/* TCP_NODELAY on `fd` if it is a TCP socket (setsockopt fails harmlessly on others). */
static int nodelay(int fd)
{
    if (fd >= 0) {
        int one = 1;
        (void) setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    }
    return fd;
}

int accept(int s, struct sockaddr *addr, socklen_t *len)
{
    static int (*real)(int, struct sockaddr *, socklen_t *);
    if (real == NULL) {
        real = (int (*)(int, struct sockaddr *, socklen_t *)) dlsym(RTLD_NEXT, "accept");
    }
    return nodelay(real(s, addr, len));
}

int accept4(int s, struct sockaddr *addr, socklen_t *len, int flags)
{
    static int (*real)(int, struct sockaddr *, socklen_t *, int);
    if (real == NULL) {
        real = (int (*)(int, struct sockaddr *, socklen_t *, int)) dlsym(RTLD_NEXT, "accept4");
    }
    return nodelay(real(s, addr, len, flags));
}
