/*
 * highfd.c: a server whose descriptors are all above FD_SETSIZE (1024).
 *
 * libmodbus 3.1.6 passes such descriptors to FD_SET (memory corruption, or an abort
 * under _FORTIFY_SOURCE); 3.1.12 refuses them with EINVAL. rsmodbus waits with poll(),
 * so they must simply work. The program raises RLIMIT_NOFILE, fills the descriptors
 * below 1100, then:
 *  - TCP: modbus_tcp_listen (descriptor >= 1100), moved to 1500 with dup2;
 *    modbus_tcp_accept (>= 1100), moved to 1600 and set with modbus_set_socket; a
 *    forked client (whose own socket is >= 1100 too) runs write/read transactions;
 *  - RTU: a server context on a pty (descriptor >= 1100) answers a raw request.
 * Prints "HIGHFD PASS ..." and exits 0 when everything worked.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

#include <modbus.h>

#include "loaded.h"

#define LOW_FDS_UNTIL 1100

static int fail(const char *what)
{
    printf("HIGHFD FAIL %s: %s\n", what, modbus_strerror(errno));
    return 1;
}

static int client(int port)
{
    modbus_t *c = modbus_new_tcp("127.0.0.1", port);
    uint16_t regs[4] = {0}, want[4] = {0x1111, 0x2222, 0x3333, 0x4444};
    uint8_t bits[10] = {0};
    int i;

    if (c == NULL || modbus_connect(c) == -1) {
        return fail("client connect");
    }
    if (modbus_get_socket(c) < LOW_FDS_UNTIL) {
        printf("HIGHFD FAIL client socket %d is low\n", modbus_get_socket(c));
        return 1;
    }
    for (i = 0; i < 20; i++) {
        want[0] = (uint16_t) i;
        if (modbus_write_registers(c, 0x10, 4, want) != 4) {
            return fail("write_registers");
        }
        if (modbus_read_registers(c, 0x10, 4, regs) != 4 || memcmp(regs, want, sizeof(regs)) != 0) {
            return fail("read_registers");
        }
        if (modbus_write_bit(c, 3, i & 1) != 1 || modbus_read_bits(c, 0, 10, bits) != 10 || bits[3] != (i & 1)) {
            return fail("bits");
        }
    }
    modbus_close(c);
    modbus_free(c);
    return 0;
}

static int tcp_part(modbus_mapping_t *map, int *listen_fd, int *accepted_fd)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", 0);
    struct sockaddr_in sa;
    socklen_t len = sizeof(sa);
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    int s, fd, port, status, served = 0;
    pid_t pid;

    s = modbus_tcp_listen(ctx, 4);
    if (s < 0) {
        return fail("modbus_tcp_listen");
    }
    *listen_fd = s;
    if (s < LOW_FDS_UNTIL) {
        printf("HIGHFD FAIL listening socket %d is low\n", s);
        return 1;
    }
    if (dup2(s, 1500) != 1500) {
        return fail("dup2");
    }
    close(s);
    s = 1500;
    getsockname(s, (struct sockaddr *) &sa, &len);
    port = ntohs(sa.sin_port);
    fflush(stdout);
    pid = fork();
    if (pid == 0) {
        _exit(client(port));
    }
    fd = modbus_tcp_accept(ctx, &s);
    if (fd < LOW_FDS_UNTIL) {
        printf("HIGHFD FAIL accept returned %d\n", fd);
        kill(pid, SIGKILL);
        return 1;
    }
    *accepted_fd = fd;
    if (dup3(fd, 1600, O_CLOEXEC) != 1600) {
        return fail("dup3");
    }
    close(fd);
    modbus_set_socket(ctx, 1600);
    for (;;) {
        int rc = modbus_receive(ctx, query);
        if (rc > 0) {
            if (modbus_reply(ctx, query, rc, map) == -1) {
                break;
            }
            served++;
        } else if (rc == -1) {
            break;
        }
    }
    waitpid(pid, &status, 0);
    modbus_close(ctx);
    modbus_free(ctx);
    close(s);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || served != 80) {
        printf("HIGHFD FAIL tcp: client status 0x%X, %d requests served\n", (unsigned) status, served);
        return 1;
    }
    return 0;
}

static int rtu_part(modbus_mapping_t *map, int *rtu_fd)
{
    static const uint8_t req[] = {0x01, 0x03, 0x00, 0x10, 0x00, 0x01, 0x85, 0xCF};
    uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH], rsp[16];
    struct termios t;
    modbus_t *ctx;
    struct pollfd p;
    int master, n = 0, rc;

    master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) {
        return fail("pty");
    }
    tcgetattr(master, &t);
    cfmakeraw(&t);
    tcsetattr(master, TCSANOW, &t);
    ctx = modbus_new_rtu(ptsname(master), 115200, 'N', 8, 1);
    modbus_set_slave(ctx, 1);
    if (modbus_connect(ctx) == -1) {
        return fail("rtu connect");
    }
    *rtu_fd = modbus_get_socket(ctx);
    if (*rtu_fd < LOW_FDS_UNTIL) {
        printf("HIGHFD FAIL rtu descriptor %d is low\n", *rtu_fd);
        return 1;
    }
    if (write(master, req, sizeof(req)) != (ssize_t) sizeof(req)) {
        return fail("pty write");
    }
    rc = modbus_receive(ctx, query);
    if (rc != (int) sizeof(req) || modbus_reply(ctx, query, rc, map) != 7) {
        return fail("rtu receive/reply");
    }
    p.fd = master;
    p.events = POLLIN;
    while (n < 7 && poll(&p, 1, 1000) > 0) {
        ssize_t r = read(master, rsp + n, sizeof(rsp) - (size_t) n);
        if (r <= 0) {
            break;
        }
        n += (int) r;
    }
    /* Register 0x10 holds 0x0013 (the last value the TCP client wrote). */
    if (n != 7 || rsp[0] != 1 || rsp[1] != 3 || rsp[2] != 2 || rsp[3] != 0x00 || rsp[4] != 0x13) {
        printf("HIGHFD FAIL rtu response (%d bytes)\n", n);
        return 1;
    }
    modbus_close(ctx);
    modbus_free(ctx);
    close(master);
    return 0;
}

int main(void)
{
    struct rlimit lim;
    modbus_mapping_t *map;
    int fd, listen_fd = -1, accepted_fd = -1, rtu_fd = -1;

    setvbuf(stdout, NULL, _IONBF, 0);
    getrlimit(RLIMIT_NOFILE, &lim);
    if (lim.rlim_cur < 4096) {
        lim.rlim_cur = lim.rlim_max < 4096 ? lim.rlim_max : 4096;
        setrlimit(RLIMIT_NOFILE, &lim);
    }
    if (lim.rlim_cur < 2048) {
        printf("HIGHFD SKIP RLIMIT_NOFILE is %ld\n", (long) lim.rlim_cur);
        return 77;
    }
    /* Occupy every descriptor below LOW_FDS_UNTIL. */
    do {
        fd = open("/dev/null", O_RDONLY);
    } while (fd >= 0 && fd < LOW_FDS_UNTIL - 1);
    if (fd < 0) {
        return fail("open /dev/null");
    }
    map = modbus_mapping_new(16, 0, 32, 0);
    if (map == NULL) {
        return fail("mapping");
    }
    if (tcp_part(map, &listen_fd, &accepted_fd) != 0 || rtu_part(map, &rtu_fd) != 0) {
        return 1;
    }
    modbus_mapping_free(map);
    printf("HIGHFD PASS listen fd %d (moved to 1500), accepted fd %d (moved to 1600), rtu fd %d, with %s\n",
           listen_fd, accepted_fd, rtu_fd, srvtest_loaded_path());
    return 0;
}
