/*
 * ext-test: rsmodbus' client calls for the function codes beyond libmodbus against
 * rsmodbus' server side of them, over one transport.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 *
 * usage: ext-test MODE TRANSPORT [SERVER_DEVICE CLIENT_DEVICE]
 *   MODE       full      server configured with everything (diagnostics, exception
 *                        status, report slave id, device identification, files, FIFO)
 *              fifo-only only a FIFO queue configured: the rest keeps libmodbus' answers
 *              plain     nothing configured: libmodbus' answers
 *   TRANSPORT  tcp | rtutcp (RTU frames over TCP) | rtu | ascii (the last two over the
 *              two ends of a pty pair, e.g. made by socat)
 *
 * The process forks: the child is the server (modbus_receive + modbus_reply, with
 * modbus_reply_exception for three special addresses), the parent the client. The
 * parent also asks the child, through a pipe and outside Modbus, for the server's own
 * view (modbus_get_diagnostics, modbus_get_event_log, modbus_get_file_record) so that
 * both sides of every counter are checked. Each check prints "ok   - ..." or
 * "FAIL - ..."; the last line is "N passed, M failed"; the exit status is 1 on
 * failure. The library in use is printed first (LIBINFO line, c-tests/common/libinfo.c).
 * The parent stops the child by its PID.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <netinet/in.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/check.h"

#define SLAVE 17
#define NB_REGISTERS 200
/* Reads of these holding registers are answered with modbus_reply_exception. */
#define ADDR_BUSY 150 /* SERVER DEVICE BUSY (6) */
#define ADDR_NAK 151  /* NEGATIVE ACKNOWLEDGE (7) */
#define ADDR_FAIL 152 /* SERVER DEVICE FAILURE (4) */

enum transport { T_TCP, T_RTUTCP, T_RTU, T_ASCII };
enum mode { M_FULL, M_FIFO_ONLY, M_PLAIN };

static enum transport transport;
static enum mode mode;
/* ------------------------------------------------------------------ reporting */

/* rc == want, or rc == -1 with errno == want_errno when want is -1. */
static void check_rc(int rc, int err, int want, int want_errno, const char *what)
{
    if (want == -1) {
        EXPECT(rc == -1 && err == want_errno, "%s: rc=%d errno=%d (%s), want -1 errno %d (%s)", what, rc, err,
               modbus_strerror(err), want_errno, modbus_strerror(want_errno));
    } else {
        EXPECT(rc == want, "%s: rc=%d%s%s, want %d", what, rc, rc == -1 ? " " : "",
               rc == -1 ? modbus_strerror(err) : "", want);
    }
}

static int serial(void)
{
    return transport != T_TCP;
}

static void msleep(int ms)
{
    struct timespec ts = {ms / 1000, (long) (ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

/* ------------------------------------------------------------------ server side */

/* What the server reports about itself (written whole on the result pipe). */
struct dump {
    int rc_diag;                /* modbus_get_diagnostics(0x0B) */
    uint16_t counters[8];       /* sub-functions 0x0B..0x12 */
    uint16_t reg, delim, lom;   /* sub-functions 0x02, 0x03, 0x04 */
    int nlog;                   /* modbus_get_event_log */
    uint16_t event_count, message_count;
    uint8_t log[64];
    int rc_file;                /* modbus_get_file_record(4, 0, 16) */
    uint16_t file4[16];
};

static const char *OBJ[7] = {"IFTOOLS", "SENSOR", "V1.01", "https://example.invalid/", "rsmodbus server",
                             "ext-test", "c-tests/extended"};
#define EXT_LEN 200 /* extended objects 0x80..0x82: 200 bytes each */

static void ext_value(int id, char *buf)
{
    int i;
    for (i = 0; i < EXT_LEN; i++) {
        buf[i] = (char) ('A' + (id + i) % 26);
    }
}

static void configure(modbus_t *ctx)
{
    static const uint16_t seed_fifo[2] = {0x01B8, 0x1204};
    static const char slave_data[] = "IFTOOLS,IF-Sensor,101305023";
    uint16_t v[32];
    char ext[EXT_LEN];
    int i, ok = 1;

    for (i = 0; i < 32; i++) {
        v[i] = (uint16_t) (i + 1);
    }
    if (mode == M_PLAIN) {
        return;
    }
    ok &= modbus_set_fifo_queue(ctx, 0x04DE, seed_fifo, 2) == 0;
    ok &= modbus_set_fifo_queue(ctx, 0x0100, v, 31) == 0;
    ok &= modbus_set_fifo_queue(ctx, 0x0200, v, 32) == 0;
    ok &= modbus_set_fifo_queue(ctx, 0x0300, NULL, 0) == 0;
    if (mode == M_FULL) {
        static const uint16_t f4[2] = {0x0DFE, 0x0020}, f3[2] = {0x33CD, 0x0040};
        ok &= modbus_enable_diagnostics(ctx, 1) == 0;
        ok &= modbus_set_diagnostic_register(ctx, 0x8000) == 0;
        ok &= modbus_set_exception_status(ctx, 0x6D) == 0;
        ok &= modbus_set_report_slave_id(ctx, 0x55, 1, (const uint8_t *) slave_data,
                                         (int) strlen(slave_data)) == 0;
        for (i = 0; i < 7; i++) {
            ok &= modbus_set_device_identification(ctx, i, OBJ[i], -1) == 0;
        }
        for (i = 0x80; i <= 0x82; i++) {
            ext_value(i, ext);
            ok &= modbus_set_device_identification(ctx, i, ext, EXT_LEN) == 0;
        }
        /* The seed's files: file 4 records 1-2, file 3 records 9-10. */
        ok &= modbus_set_file_record(ctx, 4, 0, 20, NULL) == 20;
        ok &= modbus_set_file_record(ctx, 4, 1, 2, f4) == 2;
        ok &= modbus_set_file_record(ctx, 3, 9, 2, f3) == 2;
        ok &= modbus_set_file_record(ctx, 10, 0, 10000, NULL) == 10000;
        v[0] = 0x9999;
        ok &= modbus_set_file_record(ctx, 10, 9999, 1, v) == 1;
    }
    if (!ok) {
        fprintf(stderr, "server: configuration failed: %s\n", modbus_strerror(errno));
        _exit(3);
    }
}

static void dump_state(modbus_t *ctx, int out)
{
    struct dump d;
    int i;
    memset(&d, 0, sizeof(d));
    d.rc_diag = modbus_get_diagnostics(ctx, 0x0B, &d.counters[0]);
    for (i = 1; i < 8; i++) {
        modbus_get_diagnostics(ctx, 0x0B + i, &d.counters[i]);
    }
    modbus_get_diagnostics(ctx, 0x02, &d.reg);
    modbus_get_diagnostics(ctx, 0x03, &d.delim);
    modbus_get_diagnostics(ctx, 0x04, &d.lom);
    d.nlog = modbus_get_event_log(ctx, &d.event_count, &d.message_count, d.log, 64);
    d.rc_file = modbus_get_file_record(ctx, 4, 0, 16, d.file4);
    if (write(out, &d, sizeof(d)) != (ssize_t) sizeof(d)) {
        _exit(4);
    }
}

static modbus_t *new_ctx(const char *device, int server)
{
    modbus_t *ctx = NULL;
    switch (transport) {
    case T_TCP:
        ctx = modbus_new_tcp("127.0.0.1", server ? 0 : atoi(device));
        break;
    case T_RTUTCP:
        ctx = modbus_new_rtu_tcp("127.0.0.1", server ? 0 : atoi(device));
        break;
    case T_RTU:
        ctx = modbus_new_rtu(device, 115200, 'N', 8, 1);
        break;
    case T_ASCII:
        ctx = modbus_new_ascii(device, 115200, 'E', 7, 1);
        break;
    }
    if (ctx != NULL && serial()) {
        modbus_set_slave(ctx, SLAVE);
    }
    return ctx;
}

static void server(const char *device, int cmd, int out)
{
    modbus_t *ctx = new_ctx(device, 1);
    modbus_mapping_t *map = modbus_mapping_new(16, 16, NB_REGISTERS, 16);
    uint8_t req[MODBUS_TCP_MAX_ADU_LENGTH];
    int s = -1, gone = 0;

    if (ctx == NULL || map == NULL) {
        _exit(2);
    }
    configure(ctx);
    if (transport == T_TCP || transport == T_RTUTCP) {
        struct sockaddr_in sa;
        socklen_t len = sizeof(sa);
        int port;
        s = modbus_tcp_listen(ctx, 1);
        if (s < 0 || getsockname(s, (struct sockaddr *) &sa, &len) != 0) {
            _exit(2);
        }
        port = ntohs(sa.sin_port);
        if (write(out, &port, sizeof(port)) != sizeof(port) || modbus_tcp_accept(ctx, &s) < 0) {
            _exit(2);
        }
    } else {
        int ready = 0;
        if (modbus_connect(ctx) != 0 || write(out, &ready, sizeof(ready)) != sizeof(ready)) {
            _exit(2);
        }
    }
    /* Short indication timeout: commands on the pipe are looked at between waits. */
    modbus_set_indication_timeout(ctx, 0, 50000);
    for (;;) {
        struct pollfd p = {cmd, POLLIN, 0};
        int rc;
        /* Once the client has gone, only commands are left to wait for. */
        if (poll(&p, 1, gone ? -1 : 0) == 1) {
            char c;
            if (read(cmd, &c, 1) != 1 || c == 'Q') {
                break;
            }
            if (c == 'D') {
                dump_state(ctx, out);
            } else if (c == 'G') {
                modbus_set_diagnostic_register(ctx, 0x8000);
            }
            continue;
        }
        if (gone) {
            continue;
        }
        rc = modbus_receive(ctx, req);
        if (rc == -1 && errno == ECONNRESET) {
            gone = 1;
            continue;
        }
        if (rc <= 0) {
            continue;
        }
        {
            int h = modbus_get_header_length(ctx);
            int addr = (req[h + 1] << 8) | req[h + 2];
            if (req[h] == 0x03 && addr >= ADDR_BUSY && addr <= ADDR_FAIL) {
                static const unsigned int code[3] = {MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY,
                                                     MODBUS_EXCEPTION_NEGATIVE_ACKNOWLEDGE,
                                                     MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE};
                modbus_reply_exception(ctx, req, code[addr - ADDR_BUSY]);
            } else {
                modbus_reply(ctx, req, rc, map);
            }
        }
    }
    if (s >= 0) {
        close(s);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    modbus_mapping_free(map);
    _exit(0);
}

/* ------------------------------------------------------------------ client helpers */

static int cmd_fd = -1, res_fd = -1;

static int read_pipe(void *buf, size_t n)
{
    size_t got = 0;
    while (got < n) {
        struct pollfd p = {res_fd, POLLIN, 0};
        ssize_t r;
        if (poll(&p, 1, 5000) != 1) {
            return -1;
        }
        r = read(res_fd, (char *) buf + got, n - got);
        if (r <= 0) {
            return -1;
        }
        got += (size_t) r;
    }
    return 0;
}

static int dump(struct dump *d)
{
    if (write(cmd_fd, "D", 1) != 1 || read_pipe(d, sizeof(*d)) != 0) {
        EXPECT(0, "the server reports its state");
        memset(d, 0, sizeof(*d));
        return -1;
    }
    return 0;
}

static void server_command(char c)
{
    if (write(cmd_fd, &c, 1) != 1) {
        EXPECT(0, "command to the server");
    }
}

static void set_timeout_ms(modbus_t *ctx, int ms)
{
    modbus_set_response_timeout(ctx, (uint32_t) (ms / 1000), (uint32_t) (ms % 1000) * 1000);
}

static void hex(char *out, size_t len, const uint8_t *v, int n)
{
    int i;
    size_t pos = 0;
    out[0] = '\0';
    for (i = 0; i < n && pos + 4 < len; i++) {
        pos += (size_t) snprintf(out + pos, len - pos, "%s%02X", i ? " " : "", v[i]);
    }
}

static void check_bytes(const uint8_t *got, int ngot, const uint8_t *want, int nwant, const char *what)
{
    char a[1024], b[1024];
    hex(a, sizeof(a), got, ngot);
    hex(b, sizeof(b), want, nwant);
    EXPECT(ngot == nwant && memcmp(got, want, (size_t) nwant) == 0, "%s: [%s], want [%s]", what, a, b);
}

/* Writes raw bytes on the client's line (frames libmodbus' API cannot send). */
static void write_line(modbus_t *ctx, const void *bytes, size_t n)
{
    if (write(modbus_get_socket(ctx), bytes, n) != (ssize_t) n) {
        EXPECT(0, "raw write");
    }
    msleep(100);
}

/* A serial frame of `body` (slave + PDU) with its checksum, as the context frames it. */
static void write_frame(modbus_t *ctx, const uint8_t *body, int n, int corrupt)
{
    uint8_t buf[600];
    if (transport == T_ASCII) {
        static const char digits[] = "0123456789ABCDEF";
        uint8_t lrc = 0;
        int i, pos = 0;
        buf[pos++] = ':';
        for (i = 0; i < n; i++) {
            lrc = (uint8_t) (lrc + body[i]);
            buf[pos++] = (uint8_t) digits[body[i] >> 4];
            buf[pos++] = (uint8_t) digits[body[i] & 15];
        }
        lrc = (uint8_t) (-lrc + corrupt);
        buf[pos++] = (uint8_t) digits[lrc >> 4];
        buf[pos++] = (uint8_t) digits[lrc & 15];
        buf[pos++] = '\r';
        buf[pos++] = '\n';
        write_line(ctx, buf, (size_t) pos);
    } else {
        uint16_t crc = 0xFFFF;
        int i, j;
        memcpy(buf, body, (size_t) n);
        for (i = 0; i < n; i++) {
            crc ^= body[i];
            for (j = 0; j < 8; j++) {
                crc = (crc & 1) ? (uint16_t) ((crc >> 1) ^ 0xA001) : (uint16_t) (crc >> 1);
            }
        }
        crc = (uint16_t) (crc ^ (corrupt ? 0x5A5A : 0));
        buf[n] = (uint8_t) (crc & 0xFF);
        buf[n + 1] = (uint8_t) (crc >> 8);
        write_line(ctx, buf, (size_t) n + 2);
    }
}

/* Sends a raw PDU to our slave and returns the response PDU length (0: none). */
static int raw(modbus_t *ctx, const uint8_t *pdu, int n, uint8_t *rsp_pdu)
{
    uint8_t req[MODBUS_MAX_PDU_LENGTH + 1];
    uint8_t rsp[MODBUS_TCP_MAX_ADU_LENGTH];
    int h = modbus_get_header_length(ctx), rc, tail;
    req[0] = serial() ? SLAVE : 0xFF;
    memcpy(req + 1, pdu, (size_t) n);
    if (modbus_send_raw_request(ctx, req, n + 1) == -1) {
        return -1;
    }
    rc = modbus_receive_confirmation(ctx, rsp);
    if (rc <= 0) {
        return rc;
    }
    tail = transport == T_ASCII ? 1 : (serial() ? 2 : 0);
    memcpy(rsp_pdu, rsp + h, (size_t) (rc - h - tail));
    return rc - h - tail;
}

static void check_exception(modbus_t *ctx, const uint8_t *pdu, int n, int code, const char *what)
{
    uint8_t rsp[MODBUS_MAX_PDU_LENGTH];
    uint8_t want[2];
    int len = raw(ctx, pdu, n, rsp);
    want[0] = (uint8_t) (pdu[0] | 0x80);
    want[1] = (uint8_t) code;
    check_bytes(rsp, len < 0 ? 0 : len, want, 2, what);
}

static void restart_clear(modbus_t *ctx)
{
    uint16_t d = 0xFF00, got = 0;
    int rc = modbus_diagnostics(ctx, 1, &d, 1, &got, 1);
    EXPECT(rc == 1 && got == 0xFF00, "08/01 restart communications (clear log): rc=%d echo 0x%04X", rc, got);
}

static uint16_t diag_value(modbus_t *ctx, int sub)
{
    uint16_t zero = 0, v = 0xDEAD;
    int rc = modbus_diagnostics(ctx, sub, &zero, 1, &v, 1);
    if (rc != 1) {
        EXPECT(0, "08/%02X: rc=%d %s", sub, rc, modbus_strerror(errno));
    }
    return v;
}

/* ------------------------------------------------------------------ the checks */

static void test_function_codes(modbus_t *ctx)
{
    uint8_t status = 0, id[64], rsp[MODBUS_MAX_PDU_LENGTH];
    uint16_t v[40], ev = 0, st = 0xFFFF;
    int rc, i;

    printf("# function codes 07, 11, 08/00, 0B, 0C, 14, 15, 18\n");
    rc = modbus_read_exception_status(ctx, &status);
    EXPECT(rc == 1 && status == 0x6D, "07 read exception status: rc=%d status 0x%02X", rc, status);
    rc = modbus_report_slave_id(ctx, (int) sizeof(id), id);
    EXPECT(rc == 29 && id[0] == 0x55 && id[1] == 0xFF && memcmp(id + 2, "IFTOOLS,IF-Sensor,101305023", 27) == 0,
           "11 report slave id as configured (the seed's example): rc=%d", rc);
    {
        uint16_t q[3] = {0xA537, 0x0001, 0xFFFF}, echo[3] = {0, 0, 0};
        int nb = (transport == T_TCP || transport == T_ASCII) ? 3 : 1;
        errno = 0;
        rc = modbus_diagnostics(ctx, 0, q, nb, echo, 3);
        EXPECT(rc == nb && memcmp(q, echo, sizeof(uint16_t) * (size_t) nb) == 0,
               "08/00 return query data, %d word(s): rc=%d %s", nb, rc, rc == -1 ? modbus_strerror(errno) : "");
    }
    rc = modbus_get_comm_event_counter(ctx, &st, &ev);
    EXPECT(rc == 1 && st == 0, "0B get comm event counter: rc=%d status 0x%04X", rc, st);
    rc = modbus_get_comm_event_log(ctx, &st, &ev, v, (uint8_t *) id, 64);
    EXPECT(rc >= 2 && st == 0 && id[0] == 0x80, "0C get comm event log: rc=%d, newest event 0x%02X", rc, id[0]);

    /* 14 / 15 */
    rc = modbus_read_file_record(ctx, 4, 1, 2, v);
    EXPECT(rc == 2 && v[0] == 0x0DFE && v[1] == 0x0020, "14 read file 4 records 1-2: rc=%d 0x%04X 0x%04X", rc, v[0],
           v[1]);
    rc = modbus_read_file_record(ctx, 10, 9999, 1, v);
    EXPECT(rc == 1 && v[0] == 0x9999, "14 read file 10 record 9999: rc=%d 0x%04X", rc, v[0]);
    {
        /* The seed's two sub-requests and its answer. */
        static const uint8_t req[] = {0x14, 0x0E, 0x06, 0x00, 0x04, 0x00, 0x01, 0x00, 0x02,
                                      0x06, 0x00, 0x03, 0x00, 0x09, 0x00, 0x02};
        static const uint8_t want[] = {0x14, 0x0C, 0x05, 0x06, 0x0D, 0xFE, 0x00, 0x20,
                                       0x05, 0x06, 0x33, 0xCD, 0x00, 0x40};
        rc = raw(ctx, req, sizeof(req), rsp);
        check_bytes(rsp, rc < 0 ? 0 : rc, want, sizeof(want), "14 two sub-requests (seed example)");
    }
    {
        static const uint16_t w[3] = {0x06AF, 0x04BE, 0x100D};
        struct dump d;
        rc = modbus_write_file_record(ctx, 4, 7, 3, w);
        EXPECT(rc == 3, "15 write file 4 records 7-9: rc=%d", rc);
        rc = modbus_read_file_record(ctx, 4, 6, 5, v);
        EXPECT(rc == 5 && v[0] == 0 && v[1] == 0x06AF && v[2] == 0x04BE && v[3] == 0x100D && v[4] == 0,
               "14 reads back what 15 wrote: rc=%d", rc);
        dump(&d);
        EXPECT(d.rc_file == 16 && d.file4[1] == 0x0DFE && d.file4[7] == 0x06AF && d.file4[9] == 0x100D,
               "modbus_get_file_record on the server sees the write: rc=%d", d.rc_file);
    }
    {
        /* The seed's write: echoed whole. */
        static const uint8_t req[] = {0x15, 0x0D, 0x06, 0x00, 0x04, 0x00, 0x07, 0x00,
                                      0x03, 0x06, 0xAF, 0x04, 0xBE, 0x10, 0x0D};
        rc = raw(ctx, req, sizeof(req), rsp);
        check_bytes(rsp, rc < 0 ? 0 : rc, req, sizeof(req), "15 seed example echoed");
    }

    /* 18 */
    memset(v, 0, sizeof(v));
    rc = modbus_read_fifo_queue(ctx, 0x04DE, v);
    EXPECT(rc == 2 && v[0] == 0x01B8 && v[1] == 0x1204, "18 FIFO 0x04DE (seed example): rc=%d", rc);
    rc = modbus_read_fifo_queue(ctx, 0x0100, v);
    for (i = 0; i < 31 && v[i] == i + 1; i++) {
    }
    EXPECT(rc == 31 && i == 31, "18 FIFO of 31 values: rc=%d", rc);
    rc = modbus_read_fifo_queue(ctx, 0x0300, v);
    check_rc(rc, errno, 0, 0, "18 empty FIFO");
    errno = 0;
    rc = modbus_read_fifo_queue(ctx, 0x0200, v);
    check_rc(rc, errno, -1, EMBXILVAL, "18 FIFO of 32 values: ILLEGAL DATA VALUE");
    errno = 0;
    rc = modbus_read_fifo_queue(ctx, 0x0999, v);
    check_rc(rc, errno, -1, EMBXILADD, "18 unknown FIFO pointer: ILLEGAL DATA ADDRESS");
}

/* The _async forms of the extensions' calls (the event-driven client): the same
 * answers as the blocking calls above, through modbus_process. */
struct ares {
    int done, rc, error, id;
};

static void ares_cb(modbus_t *ctx, int id, int rc, int error, void *user)
{
    struct ares *r = user;
    (void) ctx;
    r->id = id;
    r->done++;
    r->rc = rc;
    r->error = error;
}

static struct ares await_one(modbus_t *ctx, int id, struct ares *r)
{
    if (id < 0) {
        struct ares bad = {1, -1, errno, id};
        return bad;
    }
    for (int i = 0; i < 200 && modbus_pending(ctx) > 0; i++) {
        struct pollfd pfd;
        int timeout;
        modbus_get_pollfd(ctx, &pfd, &timeout);
        int n = poll(&pfd, pfd.fd >= 0 ? 1 : 0, timeout < 0 || timeout > 100 ? 100 : timeout);
        modbus_process(ctx, n > 0 ? pfd.revents : 0);
    }
    return *r;
}

static void test_async_extensions(modbus_t *ctx)
{
    struct ares r;
    uint8_t status = 0, events[64];
    uint16_t v[40], st = 0xFFFF, ev = 0, msgs = 0;

    printf("# the _async forms: 07, 08/00, 0B, 0C, 14, 15, 18\n");
    memset(&r, 0, sizeof(r));
    r = await_one(ctx, modbus_read_exception_status_async(ctx, &status, ares_cb, &r), &r);
    EXPECT(r.done == 1 && r.rc == 1 && status == 0x6D, "07 async: rc=%d status 0x%02X", r.rc, status);
    {
        uint16_t q[3] = {0xA537, 0x0001, 0xFFFF}, echo[3] = {0, 0, 0};
        int nb = (transport == T_TCP || transport == T_ASCII) ? 3 : 1;
        memset(&r, 0, sizeof(r));
        r = await_one(ctx, modbus_diagnostics_async(ctx, 0, q, nb, echo, 3, ares_cb, &r), &r);
        EXPECT(r.done == 1 && r.rc == nb && memcmp(q, echo, sizeof(uint16_t) * (size_t) nb) == 0,
               "08/00 async, %d word(s): rc=%d %s", nb, r.rc, r.rc == -1 ? modbus_strerror(r.error) : "");
    }
    memset(&r, 0, sizeof(r));
    r = await_one(ctx, modbus_get_comm_event_counter_async(ctx, &st, &ev, ares_cb, &r), &r);
    EXPECT(r.done == 1 && r.rc == 1 && st == 0, "0B async: rc=%d status 0x%04X", r.rc, st);
    memset(&r, 0, sizeof(r));
    memset(events, 0, sizeof(events));
    r = await_one(ctx, modbus_get_comm_event_log_async(ctx, &st, &ev, &msgs, events, 64, ares_cb, &r), &r);
    EXPECT(r.done == 1 && r.rc >= 2 && st == 0 && events[0] == 0x80, "0C async: rc=%d, newest event 0x%02X", r.rc,
           events[0]);
    memset(&r, 0, sizeof(r));
    memset(v, 0, sizeof(v));
    r = await_one(ctx, modbus_read_file_record_async(ctx, 4, 1, 2, v, ares_cb, &r), &r);
    EXPECT(r.done == 1 && r.rc == 2 && v[0] == 0x0DFE && v[1] == 0x0020, "14 async: rc=%d 0x%04X 0x%04X", r.rc, v[0],
           v[1]);
    {
        static const uint16_t w[2] = {0x1234, 0x5678};
        memset(&r, 0, sizeof(r));
        r = await_one(ctx, modbus_write_file_record_async(ctx, 4, 12, 2, w, ares_cb, &r), &r);
        int rc = modbus_read_file_record(ctx, 4, 12, 2, v);
        EXPECT(r.done == 1 && r.rc == 2 && rc == 2 && v[0] == 0x1234 && v[1] == 0x5678,
               "15 async: rc=%d, read back 0x%04X 0x%04X", r.rc, v[0], v[1]);
    }
    memset(&r, 0, sizeof(r));
    memset(v, 0, sizeof(v));
    r = await_one(ctx, modbus_read_fifo_queue_async(ctx, 0x04DE, v, ares_cb, &r), &r);
    EXPECT(r.done == 1 && r.rc == 2 && v[0] == 0x01B8 && v[1] == 0x1204, "18 async FIFO 0x04DE: rc=%d", r.rc);
    memset(&r, 0, sizeof(r));
    r = await_one(ctx, modbus_read_fifo_queue_async(ctx, 0x0200, v, ares_cb, &r), &r);
    EXPECT(r.done == 1 && r.rc == -1 && r.error == EMBXILVAL, "18 async FIFO of 32 values: -1 %s",
           modbus_strerror(r.error));
    errno = 0;
    EXPECT(modbus_read_file_record_async(ctx, 0, 1, 2, v, ares_cb, &r) == -1 && errno == EINVAL,
           "14 async with file 0: -1 EINVAL at once");
}

static void test_device_identification(modbus_t *ctx)
{
    modbus_device_id_object_t obj[16];
    uint8_t rsp[MODBUS_MAX_PDU_LENGTH];
    char ext[EXT_LEN];
    int rc, conf = 0, i, ok;

    printf("# 2B/0E read device identification\n");
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_BASIC, 0, obj, 16, &conf);
    ok = rc == 3 && conf == 0x83;
    for (i = 0; ok && i < 3; i++) {
        ok = obj[i].id == i && obj[i].length == strlen(OBJ[i]) && strcmp(obj[i].value, OBJ[i]) == 0;
    }
    EXPECT(ok, "basic stream: %d objects, conformity 0x%02X", rc, conf);
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_REGULAR, 0, obj, 16, &conf);
    ok = rc == 7;
    for (i = 0; ok && i < 7; i++) {
        ok = obj[i].id == i && strcmp(obj[i].value, OBJ[i]) == 0;
    }
    EXPECT(ok, "regular stream: %d objects", rc);
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, obj, 16, &conf);
    ok = rc == 10;
    for (i = 0; ok && i < 10; i++) {
        int id = i < 7 ? i : 0x80 + i - 7;
        ok = obj[i].id == id;
        if (ok && id >= 0x80) {
            ext_value(id, ext);
            ok = obj[i].length == EXT_LEN && memcmp(obj[i].value, ext, EXT_LEN) == 0;
        }
    }
    EXPECT(ok, "extended stream over several responses (more follows): %d objects", rc);
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_EXTENDED, 0x81, obj, 16, &conf);
    EXPECT(rc == 2 && obj[0].id == 0x81 && obj[1].id == 0x82, "extended stream from object 0x81: %d objects", rc);
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x04, obj, 16, &conf);
    EXPECT(rc == 1 && obj[0].id == 4 && strcmp(obj[0].value, OBJ[4]) == 0, "individual object 4: rc=%d", rc);
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x82, obj, 16, &conf);
    EXPECT(rc == 1 && obj[0].id == 0x82 && obj[0].length == EXT_LEN, "individual object 0x82: rc=%d", rc);
    errno = 0;
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x90, obj, 16, &conf);
    check_rc(rc, errno, -1, EMBXILADD, "individual unknown object 0x90: ILLEGAL DATA ADDRESS");
    {
        /* On the wire: the first extended answer stops before 0x80 with more follows. */
        static const uint8_t req[] = {0x2B, 0x0E, 0x03, 0x00};
        rc = raw(ctx, req, sizeof(req), rsp);
        EXPECT(rc > 7 && rsp[3] == 0x83 && rsp[4] == 0xFF && rsp[5] == 0x80 && rsp[6] == 7,
               "first extended answer: 7 objects, more follows, next object 0x80 (%d bytes)", rc);
        static const uint8_t last[] = {0x2B, 0x0E, 0x03, 0x82};
        rc = raw(ctx, last, sizeof(last), rsp);
        EXPECT(rc == 7 + 2 + EXT_LEN && rsp[4] == 0 && rsp[5] == 0 && rsp[6] == 1,
               "last extended answer: no more follows, next object 0 (%d bytes)", rc);
        static const uint8_t unknown_start[] = {0x2B, 0x0E, 0x01, 0x42};
        rc = raw(ctx, unknown_start, sizeof(unknown_start), rsp);
        EXPECT(rc > 7 && rsp[6] == 3 && rsp[7] == 0, "an unknown starting object restarts at object 0");
    }
    {
        /* The _async form: the same stream, its rounds under one request id. */
        modbus_device_id_object_t blk[16], asy[16];
        struct ares r;
        int nblk = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, blk, 16, &conf);
        int id;
        memset(asy, 0xEE, sizeof(asy));
        memset(&r, 0, sizeof(r));
        conf = 0;
        id = modbus_read_device_identification_async(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, asy, 16, &conf, ares_cb, &r);
        r = await_one(ctx, id, &r);
        ok = r.done == 1 && r.id == id && r.rc == nblk && nblk == 10 && conf == 0x83;
        for (i = 0; ok && i < nblk; i++) {
            ok = asy[i].id == blk[i].id && asy[i].length == blk[i].length &&
                 memcmp(asy[i].value, blk[i].value, blk[i].length + 1u) == 0;
        }
        EXPECT(ok, "2B/0E async, extended stream over several answers: rc=%d (blocking %d), one callback (%d) "
               "for id %d (%d), the blocking call's objects", r.rc, nblk, r.done, r.id, id);
        memset(&r, 0, sizeof(r));
        id = modbus_read_device_identification_async(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, asy, 8, NULL, ares_cb, &r);
        r = await_one(ctx, id, &r);
        EXPECT(r.done == 1 && r.rc == 8 && asy[7].id == 0x80, "2B/0E async with room for 8 objects: rc=%d", r.rc);
        memset(&r, 0, sizeof(r));
        id = modbus_read_device_identification_async(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x90, asy, 16, NULL, ares_cb,
                                                     &r);
        r = await_one(ctx, id, &r);
        EXPECT(r.done == 1 && r.rc == -1 && r.error == EMBXILADD, "2B/0E async, unknown object: -1 %s",
               modbus_strerror(r.error));
        {
            /* Cancelled in its second round: the id is still the request's. */
            struct pollfd pfd;
            int timeout, rounds = 0;
            memset(&r, 0, sizeof(r));
            id = modbus_read_device_identification_async(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, asy, 16, NULL, ares_cb,
                                                         &r);
            /* The first answer: 7 objects, more follows (written before the next round). */
            memset(asy, 0, sizeof(asy));
            for (i = 0; i < 200 && asy[6].length == 0 && r.done == 0; i++) {
                modbus_get_pollfd(ctx, &pfd, &timeout);
                int n = poll(&pfd, pfd.fd >= 0 ? 1 : 0, timeout < 0 || timeout > 100 ? 100 : timeout);
                modbus_process(ctx, n > 0 ? pfd.revents : 0);
                rounds++;
            }
            int pending = modbus_pending(ctx);
            int crc = modbus_cancel(ctx, id);
            EXPECT(r.done == 1 && crc == 0 && pending == 1 && r.id == id && r.rc == -1 && r.error == ECANCELED,
                   "2B/0E async cancelled between rounds: pending %d, cancel %d, callback %d with %s", pending, crc,
                   r.done, r.rc == -1 ? modbus_strerror(r.error) : "success");
            (void) rounds;
            /* Its second answer, if it was on the wire, is dropped: the next call gets its own. */
            rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_BASIC, 0, obj, 16, &conf);
            EXPECT(rc == 3, "the blocking call after it: %d objects", rc);
        }
    }
}

static void test_diagnostics(modbus_t *ctx)
{
    uint16_t d, got;
    int rc;
    struct dump st;

    printf("# 08 diagnostics sub-functions\n");
    restart_clear(ctx);
    got = diag_value(ctx, 0x02);
    EXPECT(got == 0x8000, "08/02 diagnostic register as the application set it: 0x%04X", got);
    /* 03: on an ASCII line a new delimiter would change the framing of what follows,
     * so it is set to LF there; elsewhere to '!' and back. */
    d = transport == T_ASCII ? 0x0A00 : 0x2100;
    got = 0;
    rc = modbus_diagnostics(ctx, 3, &d, 1, &got, 1);
    dump(&st);
    EXPECT(rc == 1 && got == d && st.delim == (d >> 8), "08/03 change ASCII input delimiter to 0x%02X: rc=%d, server has 0x%02X",
           d >> 8, rc, st.delim);
    d = 0x0A00;
    rc = modbus_diagnostics(ctx, 3, &d, 1, &got, 1);
    EXPECT(rc == 1 && got == 0x0A00, "08/03 back to LF: rc=%d", rc);
    d = 0x3A00;
    errno = 0;
    rc = modbus_diagnostics(ctx, 3, &d, 1, &got, 1);
    check_rc(rc, errno, -1, EMBXILVAL, "08/03 ':' as delimiter: ILLEGAL DATA VALUE");
    d = 0;
    rc = modbus_diagnostics(ctx, 0x0A, &d, 1, &got, 1);
    EXPECT(rc == 1 && got == 0, "08/0A clear counters and diagnostic register: rc=%d", rc);
    got = diag_value(ctx, 0x02);
    EXPECT(got == 0, "08/02 after 08/0A: 0x%04X", got);
    rc = modbus_diagnostics(ctx, 0x14, &d, 1, &got, 1);
    EXPECT(rc == 1 && got == 0, "08/14 clear overrun counter and flag: rc=%d", rc);
    for (rc = 0x0B; rc <= 0x12; rc++) {
        int r;
        got = 0xDEAD;
        r = modbus_diagnostics(ctx, rc, &d, 1, &got, 1);
        EXPECT(r == 1 && got != 0xDEAD, "08/%02X answers one counter (%u)", rc, got);
    }
    {
        static const int reserved[] = {0x05, 0x09, 0x13, 0x15, 0xFFFF};
        size_t i;
        for (i = 0; i < sizeof(reserved) / sizeof(reserved[0]); i++) {
            errno = 0;
            rc = modbus_diagnostics(ctx, reserved[i], &d, 1, &got, 1);
            EXPECT(rc == -1 && errno == EMBXILFUN, "08/%02X reserved: ILLEGAL FUNCTION (%s)", reserved[i],
                   modbus_strerror(errno));
        }
    }
    d = 1;
    errno = 0;
    rc = modbus_diagnostics(ctx, 0x0B, &d, 1, &got, 1);
    check_rc(rc, errno, -1, EMBXILVAL, "08/0B with data 0001: ILLEGAL DATA VALUE");
    d = 0x1234;
    errno = 0;
    rc = modbus_diagnostics(ctx, 0x01, &d, 1, &got, 1);
    check_rc(rc, errno, -1, EMBXILVAL, "08/01 with data 1234: ILLEGAL DATA VALUE");
    d = 0;
    rc = modbus_diagnostics(ctx, 0x01, &d, 1, &got, 1);
    EXPECT(rc == 1 && got == 0, "08/01 restart communications (keep log): rc=%d", rc);
}

/* The expected event log, built newest first as the traffic goes. */
struct model {
    uint8_t log[64];
    int n;
};

static void push(struct model *m, int e)
{
    memmove(m->log + 1, m->log, 63);
    m->log[0] = (uint8_t) e;
    if (m->n < 64) {
        m->n++;
    }
}

static void test_counters(modbus_t *ctx)
{
    struct model m = {{0}, 0};
    struct dump st;
    uint16_t v[64], status = 0xFFFF, events = 0, messages = 0, zero = 0;
    uint8_t log[64];
    unsigned bus = 0, comm = 0, exc = 0, srv = 0, noresp = 0, ovr = 0, ev = 0;
    int rc, i, sub;

    printf("# counters and event log after known traffic\n");
    restart_clear(ctx);
    push(&m, 0x00);
    server_command('G'); /* diagnostic register 0x8000 */
    for (i = 0; i < 3; i++) {
        rc = modbus_read_registers(ctx, 0, 2, v);
        EXPECT(rc == 2, "read holding registers %d: rc=%d", i, rc);
        bus++, srv++, ev++;
        push(&m, 0x80), push(&m, 0x40);
    }
    errno = 0;
    rc = modbus_read_registers(ctx, 190, 20, v);
    check_rc(rc, errno, -1, EMBXILADD, "read past the table: ILLEGAL DATA ADDRESS");
    bus++, srv++, exc++;
    push(&m, 0x80), push(&m, 0x41);
    rc = modbus_read_exception_status(ctx, log);
    EXPECT(rc == 1, "07: rc=%d", rc);
    bus++, srv++, ev++;
    push(&m, 0x80), push(&m, 0x40);
    if (serial()) {
        /* A broadcast write: done, not answered. */
        static const uint8_t bc[] = {0x00, 0x06, 0x00, 0x0A, 0x11, 0x11};
        rc = modbus_send_raw_request(ctx, bc, sizeof(bc));
        EXPECT(rc > 0, "broadcast write sent: rc=%d", rc);
        msleep(150);
        bus++, srv++, noresp++, ev++;
        push(&m, 0xC0), push(&m, 0x40);
        /* A frame with a bad checksum. */
        {
            static const uint8_t rd[] = {SLAVE, 0x03, 0x00, 0x00, 0x00, 0x01};
            write_frame(ctx, rd, sizeof(rd), 1);
            bus++, comm++;
            push(&m, 0x82);
        }
    }
    if (transport == T_ASCII) {
        /* A frame that is not hexadecimal: a communication error too. */
        write_line(ctx, ":11GG00\r\n", 9);
        bus++, comm++;
        push(&m, 0x82);
    } else {
        /* A write of 125 registers announces 250 bytes: more than the ADU holds. */
        static const uint8_t tcp_over[] = {0x00, 0x09, 0x00, 0x00, 0x00, 0x07, 0xFF, 0x10, 0x00, 0x00, 0x00, 0x7D, 0xFA};
        static const uint8_t rtu_over[] = {SLAVE, 0x10, 0x00, 0x00, 0x00, 0x7D, 0xFA};
        if (transport == T_TCP) {
            write_line(ctx, tcp_over, sizeof(tcp_over));
        } else {
            write_line(ctx, rtu_over, sizeof(rtu_over));
        }
        bus++, ovr++;
        push(&m, 0x90);
    }
    if (serial()) {
        /* A request for slave 5: bus traffic, not ours. On a serial line its answer
         * follows (the server skips it as a confirmation); over TCP nobody else
         * answers on this connection. */
        static const uint8_t other_req[] = {0x05, 0x03, 0x00, 0x00, 0x00, 0x01};
        static const uint8_t other_rsp[] = {0x05, 0x03, 0x02, 0x12, 0x34};
        write_frame(ctx, other_req, sizeof(other_req), 0);
        bus++;
        if (transport != T_RTUTCP) {
            write_frame(ctx, other_rsp, sizeof(other_rsp), 0);
            bus++;
        }
    }
    /* Exceptions sent by the application with modbus_reply_exception. */
    errno = 0;
    rc = modbus_read_registers(ctx, ADDR_BUSY, 1, v);
    check_rc(rc, errno, -1, EMBXSBUSY, "modbus_reply_exception 06");
    errno = 0;
    rc = modbus_read_registers(ctx, ADDR_NAK, 1, v);
    check_rc(rc, errno, -1, EMBXNACK, "modbus_reply_exception 07");
    errno = 0;
    rc = modbus_read_registers(ctx, ADDR_FAIL, 1, v);
    check_rc(rc, errno, -1, EMBXSFAIL, "modbus_reply_exception 04");
    bus += 3, srv += 3, exc += 3;
    push(&m, 0x80), push(&m, 0x44), push(&m, 0x80), push(&m, 0x48), push(&m, 0x80), push(&m, 0x42);

    /* The counters over the wire; each request counts itself on the bus and as a
     * server message before it is answered. */
    for (sub = 0x0B; sub <= 0x12; sub++) {
        unsigned want[8];
        uint16_t got;
        bus++, srv++;
        want[0] = bus, want[1] = comm, want[2] = exc, want[3] = srv, want[4] = noresp, want[5] = 1, want[6] = 1,
        want[7] = ovr;
        got = diag_value(ctx, sub);
        EXPECT(got == want[sub - 0x0B], "08/%02X = %u (want %u)", sub, got, want[sub - 0x0B]);
        ev++;
        push(&m, 0x80), push(&m, 0x40);
    }
    bus++, srv++, ev++;
    v[0] = diag_value(ctx, 0x02);
    EXPECT(v[0] == (ovr ? 0x8001 : 0x8000), "08/02 diagnostic register: 0x%04X (bit 0: overrun flag)", v[0]);
    push(&m, 0x80), push(&m, 0x40);
    rc = modbus_get_comm_event_counter(ctx, &status, &events);
    bus++, srv++;
    push(&m, 0x80), push(&m, 0x40);
    EXPECT(rc == 1 && status == 0 && events == ev, "0B: status 0x%04X, event count %u (want %u)", status, events, ev);
    rc = modbus_get_comm_event_log(ctx, &status, &events, &messages, log, 64);
    bus++, srv++;
    push(&m, 0x80);
    EXPECT(rc == m.n && events == ev && messages == bus, "0C: %d events (want %d), event count %u, message count %u (want %u)",
           rc, m.n, events, messages, bus);
    check_bytes(log, rc < 0 ? 0 : rc, m.log, m.n, "0C: the event log, newest first");
    /* The server's own view, after the 0C answer went out. */
    push(&m, 0x40);
    dump(&st);
    EXPECT(st.rc_diag == 0 && st.counters[0] == bus && st.counters[1] == comm && st.counters[2] == exc &&
               st.counters[3] == srv && st.counters[4] == noresp && st.counters[5] == 1 && st.counters[6] == 1 &&
               st.counters[7] == ovr,
           "modbus_get_diagnostics: %u %u %u %u %u %u %u %u", st.counters[0], st.counters[1], st.counters[2],
           st.counters[3], st.counters[4], st.counters[5], st.counters[6], st.counters[7]);
    EXPECT(st.event_count == ev && st.message_count == bus, "modbus_get_event_log counters: %u %u", st.event_count,
           st.message_count);
    check_bytes(st.log, st.nlog < 0 ? 0 : st.nlog, m.log, m.n, "modbus_get_event_log events");
    (void) zero;
}

static void test_listen_only(modbus_t *ctx)
{
    struct model m = {{0}, 0};
    struct dump st;
    uint16_t v[4], d = 0, got, status, events, messages;
    uint8_t log[64];
    int rc;

    printf("# listen-only mode\n");
    restart_clear(ctx);
    push(&m, 0x00);
    rc = modbus_diagnostics(ctx, 4, &d, 1, &got, 1);
    EXPECT(rc == 0, "08/04 force listen only mode: sent, no answer expected (rc=%d)", rc);
    msleep(150);
    push(&m, 0x80), push(&m, 0x04);
    dump(&st);
    EXPECT(st.lom == 1 && st.counters[4] == 1, "the server is in listen-only mode (no response count %u)",
           st.counters[4]);
    set_timeout_ms(ctx, 300);
    errno = 0;
    rc = modbus_read_registers(ctx, 0, 1, v);
    check_rc(rc, errno, -1, ETIMEDOUT, "read in listen-only mode: no answer");
    errno = 0;
    rc = modbus_write_register(ctx, 20, 0xBEEF);
    check_rc(rc, errno, -1, ETIMEDOUT, "write in listen-only mode: no answer");
    errno = 0;
    rc = modbus_get_comm_event_counter(ctx, &status, &events);
    check_rc(rc, errno, -1, ETIMEDOUT, "0B in listen-only mode: no answer");
    d = 0x1234;
    errno = 0;
    rc = modbus_diagnostics(ctx, 0, &d, 1, &got, 1);
    check_rc(rc, errno, -1, ETIMEDOUT, "08/00 in listen-only mode: no answer");
    errno = 0;
    rc = modbus_read_registers(ctx, ADDR_BUSY, 1, v);
    check_rc(rc, errno, -1, ETIMEDOUT, "modbus_reply_exception in listen-only mode: nothing sent");
    errno = 0;
    rc = modbus_diagnostics(ctx, 1, &d, 1, &got, 1);
    check_rc(rc, errno, -1, ETIMEDOUT, "08/01 with bad data 1234: ignored");
    dump(&st);
    EXPECT(st.lom == 1 && st.counters[0] == 7 && st.counters[3] == 7 && st.counters[4] == 7 && st.event_count == 0,
           "still listening only; bus %u, server %u, no response %u, events %u", st.counters[0], st.counters[3],
           st.counters[4], st.event_count);
    for (rc = 0; rc < 6; rc++) {
        push(&m, 0xA0), push(&m, 0x60);
    }
    d = 0;
    errno = 0;
    rc = modbus_diagnostics(ctx, 1, &d, 1, &got, 1);
    check_rc(rc, errno, -1, ETIMEDOUT, "08/01 restart communications: no answer in listen-only mode");
    push(&m, 0xA0), push(&m, 0x00);
    dump(&st);
    EXPECT(st.lom == 0 && st.counters[0] == 0 && st.counters[4] == 0, "the restart left listen-only mode and cleared the counters");
    set_timeout_ms(ctx, 2000);
    rc = modbus_read_registers(ctx, 20, 1, v);
    EXPECT(rc == 1 && v[0] == 0, "answered again; the write sent in listen-only mode was not done (0x%04X)", v[0]);
    push(&m, 0x80), push(&m, 0x40);
    rc = modbus_get_comm_event_log(ctx, &status, &events, &messages, log, 64);
    push(&m, 0x80);
    EXPECT(rc == m.n && events == 1 && messages == 2, "0C: %d events, event count %u, message count %u", rc, events,
           messages);
    check_bytes(log, rc < 0 ? 0 : rc, m.log, m.n, "0C: the listen-only story, newest first");
}

static void test_malformed(modbus_t *ctx)
{
    uint16_t v[2];
    int rc;

    printf("# malformed and out-of-range requests\n");
    {
        static const uint8_t bc8[] = {0x14, 0x08, 0x06, 0x00, 0x04, 0x00, 0x01, 0x00, 0x02, 0x00};
        static const uint8_t nofile[] = {0x14, 0x07, 0x06, 0x00, 0x63, 0x00, 0x00, 0x00, 0x01};
        static const uint8_t rec10000[] = {0x14, 0x07, 0x06, 0x00, 0x0A, 0x27, 0x10, 0x00, 0x01};
        static const uint8_t ref5[] = {0x14, 0x07, 0x05, 0x00, 0x04, 0x00, 0x00, 0x00, 0x01};
        static const uint8_t zero[] = {0x14, 0x07, 0x06, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00};
        static const uint8_t pastend[] = {0x14, 0x07, 0x06, 0x00, 0x04, 0x00, 0x13, 0x00, 0x02};
        static const uint8_t toolong[] = {0x14, 0x07, 0x06, 0x00, 0x0A, 0x00, 0x00, 0x00, 0x7D};
        static const uint8_t wshort[] = {0x15, 0x0B, 0x06, 0x00, 0x04, 0x00, 0x00, 0x00, 0x03, 0xAA, 0xAA, 0xBB, 0xBB};
        static const uint8_t wfile0[] = {0x15, 0x09, 0x06, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0xAA, 0xAA};
        static const uint8_t mei0d[] = {0x2B, 0x0D, 0x00, 0x00};
        static const uint8_t code0[] = {0x2B, 0x0E, 0x00, 0x00};
        static const uint8_t code5[] = {0x2B, 0x0E, 0x05, 0x00};
        static const uint8_t obj10[] = {0x2B, 0x0E, 0x04, 0x10};
        static const uint8_t sub5[] = {0x08, 0x00, 0x05, 0x00, 0x00};
        static const uint8_t sub0b[] = {0x08, 0x00, 0x0B, 0x00, 0x01};
        static const uint8_t fifo[] = {0x18, 0x12, 0x34};
        check_exception(ctx, bc8, sizeof(bc8), 3, "14 byte count 8 (not a multiple of 7)");
        check_exception(ctx, nofile, sizeof(nofile), 2, "14 unknown file 99");
        check_exception(ctx, rec10000, sizeof(rec10000), 2, "14 record 10000");
        check_exception(ctx, ref5, sizeof(ref5), 2, "14 reference type 5");
        check_exception(ctx, zero, sizeof(zero), 3, "14 zero records");
        check_exception(ctx, pastend, sizeof(pastend), 2, "14 past the end of file 4");
        check_exception(ctx, toolong, sizeof(toolong), 3, "14 125 records: the answer would not fit");
        check_exception(ctx, wshort, sizeof(wshort), 3, "15 claims 3 records, carries 2");
        check_exception(ctx, wfile0, sizeof(wfile0), 2, "15 file 0");
        check_exception(ctx, mei0d, sizeof(mei0d), 1, "2B MEI type 0x0D");
        check_exception(ctx, code0, sizeof(code0), 3, "2B/0E read code 0");
        check_exception(ctx, code5, sizeof(code5), 3, "2B/0E read code 5");
        check_exception(ctx, obj10, sizeof(obj10), 2, "2B/0E individual object 0x10 (reserved)");
        check_exception(ctx, sub5, sizeof(sub5), 1, "08 sub-function 05 (reserved)");
        check_exception(ctx, sub0b, sizeof(sub0b), 3, "08/0B with data 0001");
        check_exception(ctx, fifo, sizeof(fifo), 2, "18 unknown pointer 0x1234");
    }
    errno = 0;
    rc = modbus_write_file_record(ctx, 4, 19, 2, v);
    check_rc(rc, errno, -1, EMBXILADD, "15 through the client, past the end of file 4");
    rc = modbus_read_registers(ctx, 0, 2, v);
    EXPECT(rc == 2, "the server still answers normally: rc=%d", rc);
}

/* Servers with less (or nothing) configured keep libmodbus' answers for the rest. */
static void test_unconfigured(modbus_t *ctx)
{
    uint8_t status, id[64];
    uint16_t v[32], st, ev, d = 0x1234, got;
    modbus_device_id_object_t obj[4];
    int rc;

    printf("# %s server: libmodbus' answers where not configured\n", mode == M_PLAIN ? "unconfigured" : "FIFO-only");
    set_timeout_ms(ctx, 1500);
    errno = 0;
    rc = modbus_diagnostics(ctx, 0, &d, 1, &got, 1);
    check_rc(rc, errno, -1, EMBXILFUN, "08: ILLEGAL FUNCTION");
    errno = 0;
    rc = modbus_get_comm_event_counter(ctx, &st, &ev);
    check_rc(rc, errno, -1, EMBXILFUN, "0B: ILLEGAL FUNCTION");
    errno = 0;
    rc = modbus_read_device_identification(ctx, 1, 0, obj, 4, NULL);
    check_rc(rc, errno, -1, EMBXILFUN, "2B: ILLEGAL FUNCTION");
    rc = modbus_report_slave_id(ctx, (int) sizeof(id), id);
    EXPECT(rc == 11 && memcmp(id + 2, "LMB3.1.12", 9) == 0, "11: libmodbus' LMB3.1.12 answer (rc=%d)", rc);
    set_timeout_ms(ctx, 300);
    errno = 0;
    rc = modbus_read_exception_status(ctx, &status);
    check_rc(rc, errno, -1, ETIMEDOUT, "07: no answer (libmodbus 3.1.12 sends nothing)");
    set_timeout_ms(ctx, 1500);
    if (mode == M_FIFO_ONLY) {
        errno = 0;
        rc = modbus_read_file_record(ctx, 4, 0, 1, v);
        check_rc(rc, errno, -1, EMBXILFUN, "14: ILLEGAL FUNCTION");
        rc = modbus_read_fifo_queue(ctx, 0x04DE, v);
        EXPECT(rc == 2 && v[0] == 0x01B8, "18: the configured FIFO (rc=%d)", rc);
    } else {
        errno = 0;
        rc = modbus_read_fifo_queue(ctx, 0x04DE, v);
        check_rc(rc, errno, -1, EMBXILFUN, "18: ILLEGAL FUNCTION");
    }
    rc = modbus_read_registers(ctx, 0, 2, v);
    EXPECT(rc == 2, "03 still answered: rc=%d", rc);
}

/* ------------------------------------------------------------------ main */

int main(int argc, char **argv)
{
    int to_child[2], from_child[2], port = 0;
    pid_t pid;
    modbus_t *ctx;
    char port_s[16];
    const char *client_dev;

    if (argc < 3) {
        fprintf(stderr, "usage: %s full|fifo-only|plain tcp|rtutcp|rtu|ascii [server-dev client-dev]\n", argv[0]);
        return 2;
    }
    mode = strcmp(argv[1], "plain") == 0 ? M_PLAIN : strcmp(argv[1], "fifo-only") == 0 ? M_FIFO_ONLY : M_FULL;
    if (strcmp(argv[2], "tcp") == 0) {
        transport = T_TCP;
    } else if (strcmp(argv[2], "rtutcp") == 0) {
        transport = T_RTUTCP;
    } else if (strcmp(argv[2], "rtu") == 0 || strcmp(argv[2], "ascii") == 0) {
        transport = argv[2][0] == 'r' ? T_RTU : T_ASCII;
        if (argc < 5) {
            fprintf(stderr, "%s needs two devices\n", argv[2]);
            return 2;
        }
    } else {
        fprintf(stderr, "unknown transport %s\n", argv[2]);
        return 2;
    }
    if (pipe(to_child) != 0 || pipe(from_child) != 0) {
        return 2;
    }
    fflush(stdout);
    pid = fork();
    if (pid < 0) {
        return 2;
    }
    if (pid == 0) {
        close(to_child[1]);
        close(from_child[0]);
        server(serial() && transport != T_RTUTCP ? argv[3] : NULL, to_child[0], from_child[1]);
    }
    close(to_child[0]);
    close(from_child[1]);
    cmd_fd = to_child[1];
    res_fd = from_child[0];
    signal(SIGPIPE, SIG_IGN);
    printf("server pid %d, mode %s, transport %s\n", (int) pid, argv[1], argv[2]);
    if (read_pipe(&port, sizeof(port)) != 0) {
        EXPECT(0, "the server starts");
        kill(pid, SIGKILL);
        waitpid(pid, NULL, 0);
        chk_summary();
        return 1;
    }
    snprintf(port_s, sizeof(port_s), "%d", port);
    client_dev = (transport == T_RTU || transport == T_ASCII) ? argv[4] : port_s;
    ctx = new_ctx(client_dev, 0);
    if (ctx == NULL || modbus_connect(ctx) != 0) {
        EXPECT(0, "client connects: %s", modbus_strerror(errno));
    } else {
        set_timeout_ms(ctx, 2000);
        if (mode == M_FULL) {
            struct dump st;
            dump(&st);
            EXPECT(st.rc_diag == 0 && st.counters[0] == 0 && st.nlog == 0 && st.reg == 0x8000 && st.delim == 0x0A &&
                       st.lom == 0,
                   "power-up state: counters 0, empty log, register 0x%04X, delimiter 0x%02X", st.reg, st.delim);
            test_function_codes(ctx);
            test_async_extensions(ctx);
            test_device_identification(ctx);
            test_diagnostics(ctx);
            test_counters(ctx);
            test_listen_only(ctx);
            test_malformed(ctx);
        } else {
            test_unconfigured(ctx);
        }
        modbus_close(ctx);
    }
    if (ctx != NULL) {
        modbus_free(ctx);
    }
    /* Stop the server by its PID: ask, then insist. */
    server_command('Q');
    {
        int i, st = 0;
        for (i = 0; i < 50 && waitpid(pid, &st, WNOHANG) == 0; i++) {
            msleep(20);
        }
        if (i == 50) {
            kill(pid, SIGTERM);
            msleep(200);
            kill(pid, SIGKILL);
            waitpid(pid, &st, 0);
            EXPECT(0, "the server stops when asked");
        } else {
            EXPECT(WIFEXITED(st) && WEXITSTATUS(st) == 0, "the server exits cleanly (status %d)", st);
        }
    }
    return chk_summary();
}
