/*
 * mbtest: helpers shared by the rsmodbus C test programs (see mbtest.h).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include "mbtest.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pty.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

/* ---- tracing -------------------------------------------------------------------- */

const char *mbt_errname(int e)
{
    static char buf[32];
    switch (e) {
    case 0: return "0";
    case EPERM: return "EPERM";
    case ENOENT: return "ENOENT";
    case EINTR: return "EINTR";
    case EIO: return "EIO";
    case EBADF: return "EBADF";
    case EAGAIN: return "EAGAIN";
    case ENOMEM: return "ENOMEM";
    case EACCES: return "EACCES";
    case EBUSY: return "EBUSY";
    case EEXIST: return "EEXIST";
    case ENODEV: return "ENODEV";
    case EINVAL: return "EINVAL";
    case ENOTTY: return "ENOTTY";
    case EPIPE: return "EPIPE";
    case ENOPROTOOPT: return "ENOPROTOOPT";
    case ENOTSUP: return "ENOTSUP";
    case EOVERFLOW: return "EOVERFLOW";
    case EADDRINUSE: return "EADDRINUSE";
    case EADDRNOTAVAIL: return "EADDRNOTAVAIL";
    case ENETUNREACH: return "ENETUNREACH";
    case ECONNRESET: return "ECONNRESET";
    case ENOTCONN: return "ENOTCONN";
    case ETIMEDOUT: return "ETIMEDOUT";
    case ECONNREFUSED: return "ECONNREFUSED";
    case EHOSTUNREACH: return "EHOSTUNREACH";
    case EINPROGRESS: return "EINPROGRESS";
    case EAFNOSUPPORT: return "EAFNOSUPPORT";
    case ENOTSOCK: return "ENOTSOCK";
    case EMBXILFUN: return "EMBXILFUN";
    case EMBXILADD: return "EMBXILADD";
    case EMBXILVAL: return "EMBXILVAL";
    case EMBXSFAIL: return "EMBXSFAIL";
    case EMBXACK: return "EMBXACK";
    case EMBXSBUSY: return "EMBXSBUSY";
    case EMBXNACK: return "EMBXNACK";
    case EMBXMEMPAR: return "EMBXMEMPAR";
    case EMBXGPATH: return "EMBXGPATH";
    case EMBXGTAR: return "EMBXGTAR";
    case EMBBADCRC: return "EMBBADCRC";
    case EMBBADDATA: return "EMBBADDATA";
    case EMBBADEXC: return "EMBBADEXC";
    case EMBUNKEXC: return "EMBUNKEXC";
    case EMBMDATA: return "EMBMDATA";
    case EMBBADSLAVE: return "EMBBADSLAVE";
    default:
        if (e >= MODBUS_ENOBASE && e < MODBUS_ENOBASE + 64) {
            snprintf(buf, sizeof(buf), "ENOBASE+%d", e - MODBUS_ENOBASE);
        } else {
            snprintf(buf, sizeof(buf), "E#%d", e);
        }
        return buf;
    }
}

static void print_errno(int err)
{
    printf(" errno=%d %s \"%s\"", err, mbt_errname(err), modbus_strerror(err));
}

void mbt_report_int(const char *what, int rc, int err)
{
    printf("%s = %d", what, rc);
    if (rc == -1) {
        print_errno(err);
    }
    printf("\n");
}

void mbt_report_int_errno(const char *what, int rc, int err)
{
    printf("%s = %d", what, rc);
    print_errno(err);
    printf("\n");
}

void mbt_report_ptr(const char *what, const void *p, int err)
{
    if (p == NULL) {
        printf("%s = NULL", what);
        print_errno(err);
        printf("\n");
    } else {
        printf("%s = ctx\n", what);
    }
}

void mbt_dump_u8(const char *label, const uint8_t *v, int n)
{
    int i;
    printf("%s (%d):", label, n);
    for (i = 0; i < n; i++) {
        printf(" %02X", v[i]);
    }
    printf("\n");
}

void mbt_dump_u16(const char *label, const uint16_t *v, int n)
{
    int i;
    printf("%s (%d):", label, n);
    for (i = 0; i < n; i++) {
        printf(" %04X", v[i]);
    }
    printf("\n");
}

void mbt_dump_bits(const char *label, const uint8_t *v, int n)
{
    int i;
    printf("%s (%d): ", label, n);
    for (i = 0; i < n; i++) {
        if (v[i] <= 1) {
            printf("%d", v[i]);
        } else {
            printf("[%02X]", v[i]);
        }
    }
    printf("\n");
}

void mbt_print_float(const char *label, float f)
{
    uint32_t bits;
    memcpy(&bits, &f, sizeof(bits));
    printf("%s = %.6f (0x%08X)\n", label, (double) f, bits);
}

void mbt_section(const char *title)
{
    printf("\n==== %s ====\n", title);
}

/* ---- named, allowed differences ------------------------------------------------- */

static int value_in_list(const char *got, const char *list)
{
    size_t glen = strlen(got);
    const char *p = list;
    while (p != NULL && *p != '\0') {
        const char *bar = strchr(p, '|');
        size_t len = bar ? (size_t) (bar - p) : strlen(p);
        if (len == glen && strncmp(p, got, len) == 0) {
            return 1;
        }
        p = bar ? bar + 1 : NULL;
    }
    return 0;
}

void mbt_diff_value(const char *name, const char *got, const char *deb, const char *ours)
{
    int is_ours = mbt_is_rsmodbus();
    const char *expected = is_ours ? ours : deb;
    if (value_in_list(got, expected)) {
        printf("DIFF-OK %s: %s\n", name, got);
    } else {
        printf("DIFF-UNEXPECTED %s: %s (expected for %s: %s)\n", name, got,
               is_ours ? "rsmodbus" : "debian", expected);
    }
}

const char *mbt_fmt_rc(char *buf, size_t len, int rc, int err)
{
    if (rc == -1) {
        snprintf(buf, len, "rc=-1 errno=%s", mbt_errname(err));
    } else {
        snprintf(buf, len, "rc=%d", rc);
    }
    return buf;
}

/* Marker request understood by mbtest-server: FC16 at 0xFF00, registers carry text. */
static void send_marker(modbus_t *ctx, const char *kind, const char *name)
{
    char text[128];
    uint16_t regs[64];
    int n, i, len;
    int saved_errno = errno;

    len = snprintf(text, sizeof(text), "%s %s", kind, name);
    if (len >= (int) sizeof(text)) {
        len = sizeof(text) - 1;
    }
    n = (len + 1) / 2;
    if (n > 60) {
        n = 60;
    }
    for (i = 0; i < n; i++) {
        uint8_t hi = (uint8_t) text[2 * i];
        uint8_t lo = (2 * i + 1 < len) ? (uint8_t) text[2 * i + 1] : 0;
        regs[i] = (uint16_t) ((hi << 8) | lo);
    }
    if (modbus_write_registers(ctx, 0xFF00, n, regs) != n) {
        printf("marker %s %s not acknowledged\n", kind, name);
    }
    errno = saved_errno;
}

void mbt_diff_begin(modbus_t *ctx, const char *name)
{
    printf("DIFF-OK-BEGIN %s\n", name);
    fprintf(stderr, "DIFF-OK-BEGIN %s\n", name);
    if (ctx != NULL) {
        send_marker(ctx, "BEGIN", name);
    }
}

void mbt_diff_end(modbus_t *ctx, const char *name)
{
    if (ctx != NULL) {
        send_marker(ctx, "END", name);
    }
    printf("DIFF-OK-END %s\n", name);
    fprintf(stderr, "DIFF-OK-END %s\n", name);
}

/* ---- crash isolation ------------------------------------------------------------ */

int mbt_in_child(const char *what, void (*fn)(void *), void *arg)
{
    pid_t pid;
    int status = 0;

    fflush(stdout);
    fflush(stderr);
    pid = fork();
    if (pid == 0) {
        /* Unbuffered in the child, so that output written before a crash is kept. */
        setvbuf(stdout, NULL, _IONBF, 0);
        fn(arg);
        fflush(stdout);
        fflush(stderr);
        _exit(0);
    }
    if (pid < 0) {
        printf("%s: fork failed\n", what);
        return -1;
    }
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    if (WIFSIGNALED(status)) {
        printf("%s: child killed by signal %d\n", what, WTERMSIG(status));
    } else {
        printf("%s: child exit %d\n", what, WEXITSTATUS(status));
    }
    return status;
}

/* ---- connection set-up from argv ------------------------------------------------ */

modbus_t *mbt_ctx_from_args(int argc, char **argv, char *backend)
{
    modbus_t *ctx = NULL;

    if (argc < 4) {
        fprintf(stderr,
                "usage: %s tcp <ip> <port> | tcppi <node> <service> | rtu <device> <slave> "
                "[extra...]\n",
                argv[0]);
        return NULL;
    }
    if (strcmp(argv[1], "tcp") == 0) {
        *backend = 't';
        printf("modbus_new_tcp(\"%s\", port)", argv[2]);
        errno = 0;
        ctx = modbus_new_tcp(argv[2], atoi(argv[3]));
        mbt_report_ptr("", ctx, errno);
    } else if (strcmp(argv[1], "tcppi") == 0) {
        *backend = 'p';
        printf("modbus_new_tcp_pi(\"%s\", service)", argv[2]);
        errno = 0;
        ctx = modbus_new_tcp_pi(argv[2], argv[3]);
        mbt_report_ptr("", ctx, errno);
    } else if (strcmp(argv[1], "rtu") == 0) {
        *backend = 'r';
        printf("modbus_new_rtu(device, 115200, 'N', 8, 1)");
        errno = 0;
        ctx = modbus_new_rtu(argv[2], 115200, 'N', 8, 1);
        mbt_report_ptr("", ctx, errno);
        if (ctx != NULL) {
            CHECK(modbus_set_slave(ctx, atoi(argv[3])));
        }
    } else {
        fprintf(stderr, "unknown backend %s\n", argv[1]);
    }
    return ctx;
}

void mbt_connect_or_die(modbus_t *ctx)
{
    int rc;
    CHECK_RC(rc, modbus_connect(ctx));
    if (rc == -1) {
        fflush(stdout);
        fprintf(stderr, "FATAL: cannot connect to the test server\n");
        exit(2);
    }
}

modbus_t *mbt_open_scenario(int argc, char **argv, char *backend, uint32_t response_us)
{
    modbus_t *ctx = mbt_ctx_from_args(argc, argv, backend);
    if (ctx == NULL) {
        return NULL;
    }
    CHECK(modbus_set_debug(ctx, TRUE));
    if (response_us > 0) {
        /* The expression CHECK would print for the literal call, value included, so that
         * the scenario's output does not depend on this being a helper. */
        char what[64];
        int rc;
        snprintf(what, sizeof(what), "modbus_set_response_timeout(ctx, 0, %u)",
                 (unsigned int) response_us);
        errno = 0;
        rc = modbus_set_response_timeout(ctx, 0, response_us);
        mbt_report_int(what, rc, errno);
    }
    mbt_connect_or_die(ctx);
    return ctx;
}

void mbt_read_two(modbus_t *ctx)
{
    uint16_t regs[2] = {0, 0};
    int rc;
    CHECK_RC(rc, modbus_read_registers(ctx, 0, 2, regs));
    mbt_dump_u16("registers 0..1", regs, rc > 0 ? rc : 0);
}

/* ---- pty and loopback helpers --------------------------------------------------- */

int mbt_openpty_raw(int *master, int *slave, char *name, size_t len)
{
    struct termios tios;
    char buf[256];

    if (openpty(master, slave, buf, NULL, NULL) != 0) {
        return -1;
    }
    if (tcgetattr(*slave, &tios) == 0) {
        cfmakeraw(&tios);
        tcsetattr(*slave, TCSANOW, &tios);
    }
    if (name != NULL && len > 0) {
        snprintf(name, len, "%s", buf);
    }
    return 0;
}

int mbt_tcp_listen(int port, int backlog, int *bound_port)
{
    struct sockaddr_in addr;
    socklen_t alen = sizeof(addr);
    int one = 1;
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0) {
        return -1;
    }
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    memset(&addr, 0, sizeof(addr));
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t) port);
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(fd, (struct sockaddr *) &addr, sizeof(addr)) < 0 || listen(fd, backlog) < 0) {
        close(fd);
        return -1;
    }
    if (bound_port != NULL) {
        getsockname(fd, (struct sockaddr *) &addr, &alen);
        *bound_port = ntohs(addr.sin_port);
    }
    return fd;
}

int mbt_tcp6_listen(const char *node, int port, int backlog, int *bound_port)
{
    struct sockaddr_in6 addr;
    socklen_t alen = sizeof(addr);
    int one = 1, zero = 0;
    int fd = socket(AF_INET6, SOCK_STREAM, 0);
    if (fd < 0) {
        return -1;
    }
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &zero, sizeof(zero));
    memset(&addr, 0, sizeof(addr));
    addr.sin6_family = AF_INET6;
    addr.sin6_port = htons((uint16_t) port);
    if (inet_pton(AF_INET6, node, &addr.sin6_addr) != 1) {
        close(fd);
        errno = EINVAL;
        return -1;
    }
    if (bind(fd, (struct sockaddr *) &addr, sizeof(addr)) < 0 || listen(fd, backlog) < 0) {
        close(fd);
        return -1;
    }
    if (bound_port != NULL) {
        getsockname(fd, (struct sockaddr *) &addr, &alen);
        *bound_port = ntohs(addr.sin6_port);
    }
    return fd;
}

int mbt_tcp_connect(int port)
{
    struct sockaddr_in addr;
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0) {
        return -1;
    }
    memset(&addr, 0, sizeof(addr));
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t) port);
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(fd, (struct sockaddr *) &addr, sizeof(addr)) < 0) {
        close(fd);
        return -1;
    }
    return fd;
}

int mbt_fill_backlog(int port, int *fds, int nfds)
{
    struct sockaddr_in addr;
    int i;

    memset(&addr, 0, sizeof(addr));
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t) port);
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    for (i = 0; i < nfds; i++) {
        fds[i] = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);
        if (fds[i] < 0) {
            return -1;
        }
        connect(fds[i], (struct sockaddr *) &addr, sizeof(addr));
    }
    mbt_msleep(100);
    return 0;
}

uint16_t mbt_crc16(const uint8_t *buf, int len)
{
    uint16_t crc = 0xFFFF;
    int i, b;
    for (i = 0; i < len; i++) {
        crc ^= buf[i];
        for (b = 0; b < 8; b++) {
            if (crc & 1) {
                crc = (uint16_t) ((crc >> 1) ^ 0xA001);
            } else {
                crc >>= 1;
            }
        }
    }
    return crc;
}

void mbt_msleep(int ms)
{
    struct timespec ts;
    ts.tv_sec = ms / 1000;
    ts.tv_nsec = (long) (ms % 1000) * 1000000L;
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
    }
}
