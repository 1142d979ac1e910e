/*
 * driver.c: the raw-frame differential of the server side.
 *
 * It does not use libmodbus. It starts the server under test (srv.c, or any command
 * given after "--", to which it appends the transport and the port or device), sends it
 * a list of request frames, valid and malformed, over TCP, TCP-PI (IPv6) or a pty (RTU),
 * and records for each frame the response bytes and their timing class:
 *   immediate  first byte within 120 ms;
 *   delayed    later (the server slept its response timeout, 200 ms, and flushed);
 *   none       nothing within the frame's window (600 ms unless the case says less).
 * It also records, per case, the part of the server's debug log written meanwhile.
 *
 *   driver run tcp|tcppi|rtu <server log> [--slow] -- <server command...>
 *       runs every case, prints the record on stdout.
 *   driver compare <debian record> <ours record> [--same-lib | --responses]
 *       compares two records case by case: responses, timing classes and debug logs
 *       must be equal. A case may carry one allowed difference (a 3.1.12 vs 3.1.6
 *       behaviour named in c-tests/allowed-differences.txt); then each side must match
 *       exactly the response its version gives (computed here). --same-lib compares two
 *       runs of the same library (e.g. under valgrind): no allowed difference, no
 *       timing classes. --responses compares two runs of the same library that print
 *       different debug text (modbus_reply and modbus_reply_dispatch): responses and
 *       timing classes only. Prints one PASS/FAIL line per case.
 *   driver freeport
 *       prints a TCP port free on 127.0.0.1 and on [::].
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "srvtest.h"

#define T_TCP 1u
#define T_RTU 2u
#define T_ALL 3u

#define F_BAD_CRC 1u /* RTU: corrupt the CRC */

#define DEFAULT_WINDOW_MS 1000
#define IMMEDIATE_MS 120
#define QUIET_MS 25
#define LATE_DRAIN_MS 30

typedef struct {
    int unit; /* -1: 0xFF in TCP, SRVTEST_SLAVE in RTU */
    uint8_t pdu[300];
    int pdu_len;
    unsigned flags;
    int proto_id; /* TCP MBAP protocol id */
    int mbap_len; /* TCP MBAP length field; -1 computes it */
    int cut;      /* send only this many bytes of the frame (0: all) */
    int window_ms;
} frame_t;

typedef struct {
    char name[48];
    unsigned transports;
    const char *allow; /* name of the allowed 3.1.12-vs-3.1.6 difference, or NULL */
    int nframes;
    frame_t frames[4];
} case_t;

static case_t cases[200];
static int ncases;
static case_t *cur;
static uint8_t P[300];
static int PL;

static void die(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "driver: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    exit(3);
}

/* ------------------------------------------------------------------- the cases */

static void add_case(const char *name, unsigned transports, const char *allow)
{
    if (ncases == (int) (sizeof(cases) / sizeof(cases[0]))) {
        die("too many cases");
    }
    cur = &cases[ncases++];
    memset(cur, 0, sizeof(*cur));
    snprintf(cur->name, sizeof(cur->name), "%s", name);
    cur->transports = transports;
    cur->allow = allow;
}

static void pb(int fc)
{
    PL = 0;
    P[PL++] = (uint8_t) fc;
}
static void p8(int v)
{
    P[PL++] = (uint8_t) v;
}
static void p16(int v)
{
    p8(v >> 8);
    p8(v);
}

/* Adds the PDU built in P as the next frame of the current case. */
static frame_t *frame(int unit)
{
    frame_t *f;
    if (cur->nframes == 4) {
        die("too many frames in %s", cur->name);
    }
    f = &cur->frames[cur->nframes++];
    memset(f, 0, sizeof(*f));
    f->unit = unit;
    memcpy(f->pdu, P, (size_t) PL);
    f->pdu_len = PL;
    f->mbap_len = -1;
    return f;
}

static frame_t *rd(int fc, int addr, int nb)
{
    pb(fc);
    p16(addr);
    p16(nb);
    return frame(-1);
}

static frame_t *w1(int fc, int addr, int value)
{
    pb(fc);
    p16(addr);
    p16(value);
    return frame(-1);
}

static frame_t *wbits(int addr, int nb, int bc, int ndata)
{
    int i;
    pb(0x0F);
    p16(addr);
    p16(nb);
    p8(bc);
    for (i = 0; i < ndata; i++) {
        p8(0x5A ^ (i * 37));
    }
    return frame(-1);
}

static frame_t *wregs(int addr, int nb, int bc, int ndata_bytes)
{
    int i;
    pb(0x10);
    p16(addr);
    p16(nb);
    p8(bc);
    for (i = 0; i < ndata_bytes; i++) {
        p8(0x21 + i * 13);
    }
    return frame(-1);
}

static frame_t *wrr(int raddr, int rnb, int waddr, int wnb, int bc, int ndata_bytes)
{
    int i;
    pb(0x17);
    p16(raddr);
    p16(rnb);
    p16(waddr);
    p16(wnb);
    p8(bc);
    for (i = 0; i < ndata_bytes; i++) {
        p8(0x77 + i * 3);
    }
    return frame(-1);
}

static frame_t *raw(int n, const uint8_t *bytes)
{
    PL = n;
    memcpy(P, bytes, (size_t) n);
    return frame(-1);
}

#define RAW(...) raw((int) sizeof((const uint8_t[]){__VA_ARGS__}), (const uint8_t[]){__VA_ARGS__})

static void build_cases(void)
{
    const int B = SRVTEST_BITS_START, IB = SRVTEST_IBITS_START;
    const int R = SRVTEST_REGS_START, IR = SRVTEST_IREGS_START;
    frame_t *f;

    /* FC 01 / 02: first and last address, start offset, count 0, max, max + 1. */
    add_case("rb-first", T_ALL, NULL), rd(1, B, 1);
    add_case("rb-37", T_ALL, NULL), rd(1, B, 37);
    add_case("rb-max", T_ALL, NULL), rd(1, B, 2000);
    add_case("rb-max-at-end", T_ALL, NULL), rd(1, B + 100, 2000);
    add_case("rb-last", T_ALL, NULL), rd(1, B + SRVTEST_BITS_NB - 1, 1);
    add_case("rb-past-end", T_ALL, NULL), rd(1, B + SRVTEST_BITS_NB - 1, 2);
    add_case("rb-below-start", T_ALL, NULL), rd(1, B - 1, 1);
    add_case("rb-addr-0", T_ALL, NULL), rd(1, 0, 1);
    add_case("rb-count-0", T_ALL, NULL), rd(1, B, 0);
    add_case("rb-count-2001", T_ALL, NULL), rd(1, B, 2001);
    add_case("rb-count-ffff", T_ALL, NULL), rd(1, 0xFFFF, 0xFFFF);
    add_case("rib-first", T_ALL, NULL), rd(2, IB, 1);
    add_case("rib-max", T_ALL, NULL), rd(2, IB, 2000);
    add_case("rib-count-2001", T_ALL, NULL), rd(2, IB, 2001);
    add_case("rib-past-end", T_ALL, NULL), rd(2, IB + SRVTEST_IBITS_NB - 1, 2);
    add_case("rib-below-start", T_ALL, NULL), rd(2, IB - 1, 1);
    add_case("rib-count-0", T_ALL, NULL), rd(2, IB, 0);

    /* FC 03 / 04. */
    add_case("rr-3", T_ALL, NULL), rd(3, R, 3);
    add_case("rr-max", T_ALL, NULL), rd(3, R, 125);
    add_case("rr-last", T_ALL, NULL), rd(3, R + SRVTEST_REGS_NB - 1, 1);
    add_case("rr-past-end", T_ALL, NULL), rd(3, R + SRVTEST_REGS_NB - 1, 2);
    add_case("rr-below-start", T_ALL, NULL), rd(3, R - 1, 1);
    add_case("rr-count-0", T_ALL, NULL), rd(3, R, 0);
    add_case("rr-count-126", T_ALL, NULL), rd(3, R, 126);
    add_case("rir-first", T_ALL, NULL), rd(4, IR, 1);
    add_case("rir-max", T_ALL, NULL), rd(4, IR, 125);
    add_case("rir-last", T_ALL, NULL), rd(4, IR + SRVTEST_IREGS_NB - 1, 1);
    add_case("rir-past-end", T_ALL, NULL), rd(4, IR + 6, 125);
    add_case("rir-below-start", T_ALL, NULL), rd(4, IR - 1, 1);
    add_case("rir-count-126", T_ALL, NULL), rd(4, IR, 126);
    add_case("rir-count-0", T_ALL, NULL), rd(4, IR, 0);

    /* FC 05 / 06 (then read back). */
    add_case("wb-on", T_ALL, NULL), w1(5, B + 5, 0xFF00), rd(1, B, 8);
    add_case("wb-off", T_ALL, NULL), w1(5, B, 0), rd(1, B, 8);
    add_case("wb-value-0001", T_ALL, NULL), w1(5, B + 1, 0x0001), rd(1, B, 8);
    add_case("wb-value-ffff", T_ALL, NULL), w1(5, B + 1, 0xFFFF);
    add_case("wb-last", T_ALL, NULL), w1(5, B + SRVTEST_BITS_NB - 1, 0xFF00);
    add_case("wb-past-end", T_ALL, NULL), w1(5, B + SRVTEST_BITS_NB, 0xFF00);
    add_case("wb-below-start", T_ALL, NULL), w1(5, B - 1, 0xFF00);
    add_case("wr", T_ALL, NULL), w1(6, R + 0x10, 0x1234), rd(3, R + 0x10, 1);
    add_case("wr-last", T_ALL, NULL), w1(6, R + SRVTEST_REGS_NB - 1, 0xBEEF);
    add_case("wr-past-end", T_ALL, NULL), w1(6, R + SRVTEST_REGS_NB, 1);
    add_case("wr-below-start", T_ALL, NULL), w1(6, R - 1, 1);

    /* FC 0F: counts, byte counts that disagree (CVE-2019-14462), ranges. */
    add_case("wbs-10", T_ALL, NULL), wbits(B + 0x20, 10, 2, 2), rd(1, B + 0x20, 10);
    add_case("wbs-max", T_ALL, NULL), wbits(B, 1968, 246, 246), rd(1, B + 1960, 16);
    add_case("wbs-count-1969", T_ALL, NULL), wbits(B, 1969, 247, 247);
    add_case("wbs-count-0", T_ALL, NULL), wbits(B, 0, 0, 0);
    add_case("wbs-cve-2019-14462", T_ALL, NULL), wbits(B, 1968, 6, 6), rd(1, B, 16);
    add_case("wbs-bc-short-by-1", T_ALL, NULL), wbits(B, 9, 1, 1);
    add_case("wbs-bc-larger", T_ALL, NULL), wbits(B + 0x40, 3, 4, 4), rd(1, B + 0x40, 8);
    add_case("wbs-past-end", T_ALL, NULL), wbits(B + SRVTEST_BITS_NB - 5, 10, 2, 2);
    add_case("wbs-below-start", T_ALL, NULL), wbits(B - 8, 10, 2, 2);

    /* FC 10 (CVE-2019-14463). */
    add_case("wrs-3", T_ALL, NULL), wregs(R + 0x30, 3, 6, 6), rd(3, R + 0x30, 3);
    add_case("wrs-max", T_ALL, NULL), wregs(R, 123, 246, 246), rd(3, R + 120, 4);
    /* Refused by the receive (longer than an ADU); the rest is parsed as new frames:
     * zeros, so that RTU sees broadcasts with a bad CRC whatever the version. */
    add_case("wrs-count-124-too-long", T_ALL, NULL), f = wregs(R, 124, 248, 248), memset(f->pdu + 6, 0, 248);
    add_case("wrs-count-124", T_ALL, NULL), wregs(R, 124, 2, 2);
    add_case("wrs-count-0", T_ALL, NULL), wregs(R, 0, 0, 0);
    add_case("wrs-cve-2019-14463", T_ALL, NULL), wregs(R, 123, 6, 6), rd(3, R, 3);
    add_case("wrs-bc-odd", T_ALL, NULL), wregs(R, 2, 3, 3);
    add_case("wrs-bc-3.1.5-rule", T_ALL, NULL), wregs(R, 3, 1, 1);
    add_case("wrs-past-end", T_ALL, NULL), wregs(R + SRVTEST_REGS_NB - 1, 2, 4, 4);
    add_case("wrs-below-start", T_ALL, NULL), wregs(R - 1, 1, 2, 2);

    /* FC 16. */
    add_case("mask", T_ALL, NULL), w1(6, R + 0x40, 0x12), (pb(0x16), p16(R + 0x40), p16(0xF2), p16(0x25), frame(-1)),
        rd(3, R + 0x40, 1);
    add_case("mask-past-end", T_ALL, NULL), pb(0x16), p16(R + SRVTEST_REGS_NB), p16(0), p16(0), frame(-1);
    add_case("mask-below-start", T_ALL, NULL), pb(0x16), p16(R - 1), p16(0), p16(0), frame(-1);

    /* FC 17 (CVE-2022-0367: write address below the start). */
    add_case("wrr", T_ALL, NULL), wrr(R + 0x50, 4, R + 0x51, 2, 4, 4);
    add_case("wrr-max", T_ALL, NULL), wrr(R, 125, R + 130, 121, 242, 242);
    add_case("wrr-read-0", T_ALL, NULL), wrr(R, 0, R, 1, 2, 2);
    add_case("wrr-read-126", T_ALL, NULL), wrr(R, 126, R, 1, 2, 2);
    add_case("wrr-write-0", T_ALL, NULL), wrr(R, 1, R, 0, 0, 0);
    add_case("wrr-write-122", T_ALL, NULL), wrr(R, 1, R, 122, 2, 2);
    add_case("wrr-write-122-too-long", T_ALL, NULL), f = wrr(R, 1, R, 122, 244, 244), memset(f->pdu + 10, 0, 244);
    add_case("wrr-bc-mismatch", T_ALL, NULL), wrr(R, 1, R, 2, 2, 2);
    add_case("wrr-cve-2022-0367", T_ALL, NULL), wrr(R, 1, R - 0x80, 2, 4, 4), rd(3, R, 2);
    /* (A write range no other case reads: through modbus_reply_dispatch the write
     * callback runs before the read callback refuses, see server/allowed-differences.txt,
     * callbacks-fc17-write-first.) */
    add_case("wrr-read-below-start", T_ALL, NULL), wrr(R - 1, 1, R + 0x90, 1, 2, 2);
    add_case("wrr-read-past-end", T_ALL, NULL), wrr(R + SRVTEST_REGS_NB - 1, 2, R + 0x91, 1, 2, 2);
    add_case("wrr-write-past-end", T_ALL, NULL), wrr(R, 1, R + SRVTEST_REGS_NB - 1, 2, 4, 4);

    /* FC 11 (payload "LMB" + version), FC 07 (no answer), unknown function codes. */
    add_case("report-slave-id", T_ALL, "report-slave-id-length"), pb(0x11), frame(-1);
    add_case("fc07-no-answer", T_ALL, NULL), pb(0x07), frame(-1);
    add_case("fc00", T_ALL, NULL), RAW(0x00, 0, 0, 0, 1);
    add_case("fc08-diagnostics", T_ALL, NULL), RAW(0x08, 0, 0, 0x12, 0x34);
    add_case("fc2b-device-id", T_ALL, NULL), RAW(0x2B, 0x0E, 0x01, 0x00);
    add_case("fc42", T_ALL, NULL), RAW(0x42);
    add_case("fc83", T_ALL, NULL), RAW(0x83, 0, 0, 0, 1);
    add_case("fc14-file-record", T_ALL, NULL), RAW(0x14, 7, 6, 0, 4, 0, 1, 0, 2);
    add_case("fcff", T_ALL, NULL), RAW(0xFF, 1, 2);

    /* modbus_reply_exception: codes 0..11 are sent as given, 12 and above give EINVAL. */
    add_case("reply-exception-0", T_ALL, NULL), rd(3, SRVTEST_EXCEPTION_ADDRESS, 0);
    add_case("reply-exception-6", T_ALL, NULL), rd(3, SRVTEST_EXCEPTION_ADDRESS, 6);
    add_case("reply-exception-11", T_ALL, NULL), rd(3, SRVTEST_EXCEPTION_ADDRESS, 11);
    add_case("reply-exception-12", T_ALL, NULL), rd(3, SRVTEST_EXCEPTION_ADDRESS, 12);
    add_case("reply-exception-255", T_ALL, NULL), rd(3, SRVTEST_EXCEPTION_ADDRESS, 255);

    /* TCP: the MBAP is never validated; units are never filtered. */
    add_case("tcp-proto-id-5-echo", T_TCP, NULL), f = w1(5, B, 0xFF00), f->proto_id = 5;
    add_case("tcp-proto-id-5-read", T_TCP, NULL), f = rd(3, R, 1), f->proto_id = 5;
    add_case("tcp-mbap-len-99", T_TCP, NULL), f = rd(3, R, 1), f->mbap_len = 99;
    add_case("tcp-unit-0", T_TCP, NULL), f = w1(6, R + 0x60, 0x4242), f->unit = 0;
    add_case("tcp-unit-18", T_TCP, NULL), f = rd(3, R + 0x60, 1), f->unit = 18;
    add_case("tcp-truncated-mbap", T_TCP, NULL), f = rd(3, R, 1), f->cut = 5, rd(3, R, 1);
    add_case("tcp-truncated-meta", T_TCP, NULL), f = rd(3, R, 1), f->cut = 10;
    add_case("tcp-truncated-data", T_TCP, NULL), f = wregs(R, 2, 4, 4), f->cut = 15;
    add_case("tcp-too-many-data", T_TCP, NULL), f = wregs(R, 2, 255, 0), f->cut = 13, rd(3, R, 1);

    /* RTU: CRC, slave filtering, broadcast, the confirmation to ignore. */
    add_case("rtu-bad-crc", T_RTU, NULL), f = rd(3, R, 1), f->flags = F_BAD_CRC;
    add_case("rtu-bad-crc-fc05", T_RTU, NULL), f = w1(5, B, 0xFF00), f->flags = F_BAD_CRC;
    add_case("rtu-other-slave-then-its-answer", T_RTU, NULL);
    f = rd(3, R, 1), f->unit = 18, f->window_ms = 60;
    f = raw(4, (const uint8_t[]){0x03, 0x02, 0x12, 0x34}), f->unit = 18, f->window_ms = 60;
    rd(3, R, 1);
    add_case("rtu-other-slave-alone", T_RTU, NULL), f = rd(3, R, 1), f->unit = 18, rd(3, R, 1);
    add_case("rtu-slave-247", T_RTU, NULL), f = rd(3, R, 1), f->unit = 247;
    add_case("rtu-slave-255", T_RTU, NULL), f = rd(3, R, 1), f->unit = 255;
    add_case("rtu-broadcast-write", T_RTU, NULL), f = w1(6, R + 0x70, 0x4343), f->unit = 0, rd(3, R + 0x70, 1);
    add_case("rtu-broadcast-read", T_RTU, NULL), f = rd(3, R, 1), f->unit = 0;
    add_case("rtu-broadcast-count-0", T_RTU, NULL), f = rd(3, R, 0), f->unit = 0;
    add_case("rtu-broadcast-unknown-fc", T_RTU, NULL), pb(0x42), f = frame(0);
    add_case("rtu-broadcast-fc07", T_RTU, NULL), pb(0x07), f = frame(0);
    add_case("rtu-broadcast-reply-exception", T_RTU, NULL), f = rd(3, SRVTEST_EXCEPTION_ADDRESS, 4), f->unit = 0;
    add_case("rtu-truncated", T_RTU, NULL), f = rd(3, R, 1), f->cut = 4, rd(3, R, 1);
    add_case("rtu-too-many-data", T_RTU, NULL), f = wregs(R, 2, 250, 0), f->cut = 7, rd(3, R, 1);
    add_case("rtu-bad-crc-other-slave", T_RTU, "rtu-crc-before-slave-filter");
    f = w1(6, R + 0x80, 7), f->unit = 18, f->flags = F_BAD_CRC, f->window_ms = 100;
    w1(6, R + 0x81, 0x1234);
}

/* ------------------------------------------------------------------ wire helpers */

static uint16_t crc16(const uint8_t *b, int n)
{
    uint16_t crc = 0xFFFF;
    int i, k;
    for (i = 0; i < n; i++) {
        crc ^= b[i];
        for (k = 0; k < 8; k++) {
            crc = (crc & 1) ? (uint16_t) ((crc >> 1) ^ 0xA001) : (uint16_t) (crc >> 1);
        }
    }
    return crc;
}

static int is_rtu;
static uint16_t next_tid = 1;

/* Builds the ADU of `f` into `out`; returns its length (before any cut). */
static int wire(const frame_t *f, uint16_t tid, uint8_t *out)
{
    int n = 0;
    int unit = f->unit >= 0 ? f->unit : (is_rtu ? SRVTEST_SLAVE : 0xFF);
    if (is_rtu) {
        uint16_t crc;
        out[n++] = (uint8_t) unit;
        memcpy(out + n, f->pdu, (size_t) f->pdu_len);
        n += f->pdu_len;
        crc = crc16(out, n);
        if (f->flags & F_BAD_CRC) {
            crc ^= 0x5555;
        }
        out[n++] = (uint8_t) crc;
        out[n++] = (uint8_t) (crc >> 8);
    } else {
        int len = f->mbap_len >= 0 ? f->mbap_len : f->pdu_len + 1;
        out[n++] = (uint8_t) (tid >> 8);
        out[n++] = (uint8_t) tid;
        out[n++] = (uint8_t) (f->proto_id >> 8);
        out[n++] = (uint8_t) f->proto_id;
        out[n++] = (uint8_t) (len >> 8);
        out[n++] = (uint8_t) len;
        out[n++] = (uint8_t) unit;
        memcpy(out + n, f->pdu, (size_t) f->pdu_len);
        n += f->pdu_len;
    }
    return n;
}

/* An ADU around `pdu` as a server answers it (TCP: TID and unit echoed, protocol 0). */
static int response(uint16_t tid, int unit, const uint8_t *pdu, int pdu_len, uint8_t *out)
{
    frame_t f;
    memset(&f, 0, sizeof(f));
    f.unit = unit;
    memcpy(f.pdu, pdu, (size_t) pdu_len);
    f.pdu_len = pdu_len;
    f.mbap_len = -1;
    return wire(&f, tid, out);
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1000.0 + (double) ts.tv_nsec / 1e6;
}

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long) (ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

static void write_all(int fd, const uint8_t *b, int n)
{
    while (n > 0) {
        ssize_t w = write(fd, b, (size_t) n);
        if (w < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            die("write: %s", strerror(errno));
        }
        b += w;
        n -= (int) w;
    }
}

static const char *log_path;
static long log_offset;

static long log_size(void)
{
    struct stat st;
    return stat(log_path, &st) == 0 ? (long) st.st_size : 0;
}

/* Whether the server wrote something after `since` and its log now ends with `suffix`. */
static int log_tail_is(const char *suffix, long since)
{
    char buf[128];
    size_t n = strlen(suffix);
    long size = log_size();
    FILE *f;
    int ok = 0;
    if (size <= since || (long) n > size || n >= sizeof(buf)) {
        return 0;
    }
    f = fopen(log_path, "r");
    if (f != NULL && fseek(f, size - (long) n, SEEK_SET) == 0 && fread(buf, 1, n, f) == n) {
        ok = memcmp(buf, suffix, n) == 0;
    }
    if (f != NULL) {
        fclose(f);
    }
    return ok;
}

static const char *const IDLE = "Waiting for an indication...\n";

/* Waits until the log ends with `suffix` (after `since`), at most `timeout_ms`. */
static void wait_log_tail(const char *suffix, long since, int timeout_ms)
{
    double start = now_ms();
    while (!log_tail_is(suffix, since) && now_ms() - start < timeout_ms) {
        sleep_ms(2);
    }
}

/* Collects a response: reads whatever arrives within `window_ms`, and stops earlier
 * once the server is idle again (its log, grown since `since`, ends with "Waiting for
 * an indication...") and QUIET_MS passed without data. Returns the byte count and the
 * first byte's latency (-1 if none). */
static int collect(int fd, int window_ms, long since, uint8_t *buf, int cap, double *latency)
{
    double start = now_ms(), last = start;
    int n = 0;

    *latency = -1;
    for (;;) {
        struct pollfd p = {fd, POLLIN, 0};
        double t;
        if (poll(&p, 1, 3) > 0) {
            ssize_t r = read(fd, buf + n, (size_t) (cap - n));
            if (r > 0) {
                if (*latency < 0) {
                    *latency = now_ms() - start;
                }
                n += (int) r;
                last = now_ms();
                if (n == cap) {
                    break;
                }
            } else if (r == 0 || (errno != EINTR && errno != EAGAIN)) {
                break;
            }
        }
        t = now_ms();
        if (t - start > window_ms) {
            break;
        }
        if (t - last > QUIET_MS && log_tail_is(IDLE, since)) {
            break;
        }
    }
    return n;
}

/* Reads what is already waiting on `fd` (a response the server sent after the frame's
 * window, e.g. when a loaded machine stretched its 200 ms sleep past it): stops after
 * LATE_DRAIN_MS without data. */
static int drain_late(int fd, uint8_t *buf, int cap)
{
    int n = 0;
    while (n < cap) {
        struct pollfd p = {fd, POLLIN, 0};
        ssize_t r;
        if (poll(&p, 1, LATE_DRAIN_MS) <= 0) {
            break;
        }
        r = read(fd, buf + n, (size_t) (cap - n));
        if (r <= 0) {
            break;
        }
        n += (int) r;
    }
    return n;
}

static const char *class_of(double latency)
{
    if (latency < 0) {
        return "none";
    }
    return latency < IMMEDIATE_MS ? "immediate" : "delayed";
}

static void print_hex(FILE *o, const uint8_t *b, int n)
{
    int i;
    if (n == 0) {
        fputc('-', o);
    }
    for (i = 0; i < n; i++) {
        fprintf(o, "%02X", b[i]);
    }
}

static void print_response(const char *name, int k, double latency, const uint8_t *rsp, int n)
{
    printf("R %s#%d %s ", name, k, class_of(latency));
    print_hex(stdout, rsp, n);
    printf("\n");
}

/* ------------------------------------------------------------------ the server */

static pid_t server_pid = -1;

static void spawn(char **cmd, int ncmd, const char *a1, const char *a2)
{
    char **argv = calloc((size_t) ncmd + 3, sizeof(char *));
    int fd, i;
    if (argv == NULL) {
        die("calloc");
    }
    for (i = 0; i < ncmd; i++) {
        argv[i] = cmd[i];
    }
    argv[ncmd] = (char *) a1;
    argv[ncmd + 1] = (char *) a2;
    fd = open(log_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        die("open %s: %s", log_path, strerror(errno));
    }
    fflush(stdout);
    server_pid = fork();
    if (server_pid == 0) {
        dup2(fd, 1);
        dup2(fd, 2);
        execvp(argv[0], argv);
        _exit(127);
    }
    close(fd);
    free(argv);
}

/* The log written since the last call, escaped on one line. */
static void print_log_segment(FILE *o, const char *label)
{
    FILE *f = fopen(log_path, "r");
    int c;
    fprintf(o, "L %s ", label);
    if (f != NULL && fseek(f, log_offset, SEEK_SET) == 0) {
        while ((c = fgetc(f)) != EOF) {
            log_offset++;
            if (c == '\n') {
                fputs("\\n", o);
            } else if (c == '\\') {
                fputs("\\\\", o);
            } else if (c < 0x20 || c > 0x7E) {
                fprintf(o, "\\x%02X", c);
            } else {
                fputc(c, o);
            }
        }
    }
    if (f != NULL) {
        fclose(f);
    }
    fputc('\n', o);
}

static int log_contains(const char *needle)
{
    char buf[8192];
    FILE *f = fopen(log_path, "r");
    size_t n;
    if (f == NULL) {
        return 0;
    }
    n = fread(buf, 1, sizeof(buf) - 1, f);
    fclose(f);
    buf[n] = '\0';
    return strstr(buf, needle) != NULL;
}

static int server_exited(int *status)
{
    return waitpid(server_pid, status, WNOHANG) == server_pid;
}

/* ------------------------------------------------------------------ connections */

static int free_port(int family)
{
    struct sockaddr_storage ss;
    socklen_t len = sizeof(ss);
    int s = socket(family, SOCK_STREAM, 0), port;
    memset(&ss, 0, sizeof(ss));
    if (family == AF_INET) {
        struct sockaddr_in *a = (struct sockaddr_in *) &ss;
        a->sin_family = AF_INET;
        a->sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        len = sizeof(*a);
    } else {
        struct sockaddr_in6 *a = (struct sockaddr_in6 *) &ss;
        a->sin6_family = AF_INET6;
        a->sin6_addr = in6addr_loopback;
        len = sizeof(*a);
    }
    if (s < 0 || bind(s, (struct sockaddr *) &ss, len) != 0 || getsockname(s, (struct sockaddr *) &ss, &len) != 0) {
        die("cannot find a free port: %s", strerror(errno));
    }
    port = ntohs(family == AF_INET ? ((struct sockaddr_in *) &ss)->sin_port : ((struct sockaddr_in6 *) &ss)->sin6_port);
    close(s);
    return port;
}

static int tcp_family;
static int tcp_port;

static int tcp_connect(void)
{
    int attempt;
    for (attempt = 0; attempt < 300; attempt++) {
        struct sockaddr_storage ss;
        socklen_t len;
        int s = socket(tcp_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
        memset(&ss, 0, sizeof(ss));
        if (tcp_family == AF_INET) {
            struct sockaddr_in *a = (struct sockaddr_in *) &ss;
            a->sin_family = AF_INET;
            a->sin_port = htons((uint16_t) tcp_port);
            a->sin_addr.s_addr = htonl(INADDR_LOOPBACK);
            len = sizeof(*a);
        } else {
            struct sockaddr_in6 *a = (struct sockaddr_in6 *) &ss;
            a->sin6_family = AF_INET6;
            a->sin6_port = htons((uint16_t) tcp_port);
            a->sin6_addr = in6addr_loopback;
            len = sizeof(*a);
        }
        if (connect(s, (struct sockaddr *) &ss, len) == 0) {
            return s;
        }
        close(s);
        sleep_ms(20);
    }
    die("cannot connect to the server on port %d", tcp_port);
    return -1;
}

/* ------------------------------------------------------------------ expectations */

/* The responses a given libmodbus version sends for the frames of an allowed-difference
 * case: `version` 316 (Debian 3.1.6) or 312 (3.1.12). One "E" line per frame. */
static void print_expectations(FILE *o, const case_t *c, const uint16_t *tids, int version)
{
    int k;
    for (k = 0; k < c->nframes; k++) {
        const frame_t *f = &c->frames[k];
        uint8_t pdu[64], adu[300];
        int pl = 0, n = 0;
        const char *cls = "none";
        int unit = f->unit >= 0 ? f->unit : (is_rtu ? SRVTEST_SLAVE : 0xFF);

        if (strcmp(c->allow, "report-slave-id-length") == 0) {
            const char *v = version == 316 ? "3.1.6" : "3.1.12";
            pdu[pl++] = 0x11;
            pdu[pl++] = (uint8_t) (2 + 3 + strlen(v));
            pdu[pl++] = 0xB4;
            pdu[pl++] = 0xFF;
            memcpy(pdu + pl, "LMB", 3);
            pl += 3;
            memcpy(pdu + pl, v, strlen(v));
            pl += (int) strlen(v);
            cls = "immediate";
        } else if (strcmp(c->allow, "rtu-crc-before-slave-filter") == 0 && version == 312) {
            if (k == 0) {
                /* EMBBADCRC: the server replies with req_length -1, which fails the
                 * write-register length check (ILLEGAL_DATA_VALUE), to slave 18. */
                pdu[pl++] = 0x86;
                pdu[pl++] = 0x03;
            } else {
                memcpy(pdu, f->pdu, (size_t) f->pdu_len);
                pl = f->pdu_len;
            }
            cls = "immediate";
        }
        if (pl > 0) {
            n = response(tids[k], unit, pdu, pl, adu);
        }
        fprintf(o, "E %s#%d %d %s ", c->name, k, version, cls);
        print_hex(o, adu, n);
        fputc('\n', o);
    }
}

/* ------------------------------------------------------------------ run */

static int run(const char *transport, int slow, char **cmd, int ncmd)
{
    int master = -1, i, k, status = 0, waited;
    char arg[512];
    unsigned mask;
    double start = now_ms();
    int window_scale = slow ? 5 : 1;

    is_rtu = strcmp(transport, "rtu") == 0;
    mask = is_rtu ? T_RTU : T_TCP;
    build_cases();

    if (is_rtu) {
        struct termios t;
        master = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
        if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) {
            die("pty: %s", strerror(errno));
        }
        snprintf(arg, sizeof(arg), "%s", ptsname(master));
        /* Raw on our side too, so that nothing is echoed before the server opens it. */
        tcgetattr(master, &t);
        cfmakeraw(&t);
        tcsetattr(master, TCSANOW, &t);
    } else {
        tcp_family = strcmp(transport, "tcppi") == 0 ? AF_INET6 : AF_INET;
        tcp_port = free_port(tcp_family);
        snprintf(arg, sizeof(arg), "%d", tcp_port);
    }
    spawn(cmd, ncmd, transport, arg);
    for (waited = 0; !log_contains("== ready\n"); waited += 20) {
        if (server_exited(&status) || waited > 60000) {
            die("the server did not start (see %s)", log_path);
        }
        sleep_ms(20);
    }
    /* An RTU server goes straight to its first receive: let its idle line belong
     * to the start segment however slowly it gets there (valgrind). */
    if (is_rtu) {
        wait_log_tail(IDLE, 0, 5000 * window_scale);
    }
    printf("T %s\n", transport);
    print_log_segment(stdout, "start");

    for (i = 0; i < ncases; i++) {
        case_t *c = &cases[i];
        uint16_t tids[4];
        int fd = master, got = 0;
        uint8_t rsp[1024];
        double latency = -1;

        if (!(c->transports & mask)) {
            continue;
        }
        printf("C %s %s\n", c->name, c->allow ? c->allow : "-");
        if (!is_rtu) {
            long before = log_size();
            fd = tcp_connect();
            wait_log_tail(IDLE, before, 5000 * window_scale);
        }
        for (k = 0; k < c->nframes; k++) {
            frame_t *f = &c->frames[k];
            uint8_t adu[600];
            int n;
            int window = (f->window_ms ? f->window_ms : DEFAULT_WINDOW_MS) * (f->window_ms ? 1 : window_scale);

            long since;
            tids[k] = next_tid++;
            n = wire(f, tids[k], adu);
            if (f->cut > 0 && f->cut < n) {
                n = f->cut;
            }
            since = log_size();
            write_all(fd, adu, n);
            got = collect(fd, window, since, rsp, (int) sizeof(rsp), &latency);
            /* Frames before the last are printed now; the last one once the server is
             * idle again, so that a response sent after its window still counts. */
            if (k + 1 < c->nframes) {
                print_response(c->name, k, latency, rsp, got);
            }
        }
        if (!is_rtu) {
            /* Half-close: the server reads end of file once it is done with the frame,
             * and a response it is still about to send reaches us. */
            long before = log_size();
            shutdown(fd, SHUT_WR);
            wait_log_tail("(Connection reset by peer)\n", before, 5000 * window_scale);
        } else {
            wait_log_tail(IDLE, log_offset, 5000 * window_scale);
        }
        if (c->nframes > 0) {
            int late = drain_late(fd, rsp + got, (int) sizeof(rsp) - got);
            if (late > 0 && latency < 0) {
                latency = DEFAULT_WINDOW_MS; /* arrived after the window: delayed */
                fprintf(stderr, "driver: %s#%d: %d bytes arrived after the frame's window\n", c->name,
                        c->nframes - 1, late);
            }
            print_response(c->name, c->nframes - 1, latency, rsp, got + late);
        }
        if (c->allow != NULL) {
            print_expectations(stdout, c, tids, 316);
            print_expectations(stdout, c, tids, 312);
        }
        if (!is_rtu) {
            close(fd);
        }
        print_log_segment(stdout, c->name);
        if (server_exited(&status)) {
            printf("S died during %s: status 0x%X\n", c->name, (unsigned) status);
            print_log_segment(stdout, "end");
            return 1;
        }
    }

    /* Stop the server with its quit request and wait for a clean exit. */
    {
        frame_t q;
        uint8_t adu[16];
        int n, fd = master;
        memset(&q, 0, sizeof(q));
        q.unit = -1;
        q.pdu[0] = SRVTEST_QUIT_FC;
        q.pdu_len = 1;
        q.mbap_len = -1;
        if (!is_rtu) {
            fd = tcp_connect();
        }
        n = wire(&q, next_tid++, adu);
        write_all(fd, adu, n);
        for (waited = 0; !server_exited(&status); waited += 20) {
            if (waited > 60000) {
                kill(server_pid, SIGKILL);
                waitpid(server_pid, &status, 0);
                printf("S killed: no exit after the quit request\n");
                break;
            }
            sleep_ms(20);
        }
        if (!is_rtu) {
            close(fd);
        }
        print_log_segment(stdout, "quit");
        if (WIFEXITED(status)) {
            printf("S exit %d\n", WEXITSTATUS(status));
        } else {
            printf("S signal %d\n", WIFSIGNALED(status) ? WTERMSIG(status) : -1);
        }
    }
    if (master >= 0) {
        close(master);
    }
    fprintf(stderr, "driver: %s run took %.1f s\n", transport, (now_ms() - start) / 1000.0);
    return 0;
}

/* ------------------------------------------------------------------ compare */

typedef struct {
    char *lines[4096];
    int n;
} record_t;

static void load(const char *path, record_t *r)
{
    FILE *f = fopen(path, "r");
    char *line = NULL;
    size_t cap = 0;
    ssize_t len;
    if (f == NULL) {
        die("open %s: %s", path, strerror(errno));
    }
    r->n = 0;
    while ((len = getline(&line, &cap, f)) >= 0) {
        if (len > 0 && line[len - 1] == '\n') {
            line[len - 1] = '\0';
        }
        if (r->n == 4096) {
            die("%s: too many lines", path);
        }
        r->lines[r->n++] = strdup(line);
    }
    free(line);
    fclose(f);
}

/* The line of `r` that starts with `prefix` (kind and name), or NULL. */
static const char *find(const record_t *r, const char *prefix)
{
    size_t n = strlen(prefix);
    int i;
    for (i = 0; i < r->n; i++) {
        if (strncmp(r->lines[i], prefix, n) == 0) {
            return r->lines[i];
        }
    }
    return NULL;
}

/* Replaces every `from` with `to` in `s` (a malloc'ed string). */
static char *replace_all(char *s, const char *from, const char *to)
{
    char *p;
    size_t fl = strlen(from), tl = strlen(to);
    while ((p = strstr(s, from)) != NULL) {
        size_t off = (size_t) (p - s);
        char *t = malloc(strlen(s) - fl + tl + 1);
        if (t == NULL) {
            die("malloc");
        }
        memcpy(t, s, off);
        memcpy(t + off, to, tl);
        strcpy(t + off + tl, p + fl);
        free(s);
        s = t;
    }
    return s;
}

/* Debian-side debug text rewritten into 3.1.12's wording (the named "sed"-kind
 * differences): the accept messages, and the CRC debug line, whose two values 3.1.6
 * prints with their bytes swapped. */
static char *normalize_debian(const char *line)
{
    char *s = strdup(line), *p, *q;
    s = replace_all(s, "The client connection is accepted.\\n", "Client connection accepted from ::1.\\n");
    while ((p = strstr(s, "The client connection from ")) != NULL &&
           (q = strstr(p, " is accepted\\n")) != NULL) {
        char ip[64], *t;
        size_t iplen = (size_t) (q - p) - strlen("The client connection from ");
        if (iplen >= sizeof(ip)) {
            break;
        }
        memcpy(ip, p + strlen("The client connection from "), iplen);
        ip[iplen] = '\0';
        t = malloc(strlen(s) + 64);
        if (t == NULL) {
            die("malloc");
        }
        memcpy(t, s, (size_t) (p - s));
        sprintf(t + (p - s), "Client connection accepted from %s.\\n%s", ip, q + strlen(" is accepted\\n"));
        free(s);
        s = t;
    }
    p = s;
    while ((p = strstr(p, "ERROR CRC received 0x")) != NULL) {
        unsigned a, b;
        char tail[16], buf[96], *end;
        if (sscanf(p, "ERROR CRC received 0x%X != CRC calculated 0x%X%15s", &a, &b, tail) < 2) {
            break;
        }
        end = strstr(p, "\\n");
        if (end == NULL) {
            break;
        }
        snprintf(buf, sizeof(buf), "ERROR CRC received 0x%X != CRC calculated 0x%X", ((a & 0xFF) << 8) | (a >> 8),
                 ((b & 0xFF) << 8) | (b >> 8));
        {
            char *t = malloc(strlen(s) + sizeof(buf));
            if (t == NULL) {
                die("malloc");
            }
            memcpy(t, s, (size_t) (p - s));
            strcpy(t + (p - s), buf);
            strcat(t, end);
            p = t + (p - s) + strlen(buf);
            free(s);
            s = t;
        }
    }
    return s;
}

/* "R name#k class hex" without the class. */
static const char *skip_class(const char *line)
{
    const char *p = strchr(line + 2, ' ');
    p = p ? strchr(p + 1, ' ') : NULL;
    return p ? p : line;
}

/* same_lib: two runs of one library (responses without their timing class, logs);
 * responses_only: two runs of one library that print different debug text (the
 * callbacks run): responses with their timing class, no logs. */
static int compare(const char *debian_path, const char *ours_path, int same_lib, int responses_only)
{
    static record_t a, b;
    int i, pass = 0, fail = 0, allowed = 0;
    char prefix[128];

    load(debian_path, &a);
    load(ours_path, &b);
    for (i = 0; i < a.n; i++) {
        char name[64], allow[64];
        int k, ok = 1, exact = 1, allowed_ok = 1;
        const char *la, *lb;
        char why[2048] = "";

        if (sscanf(a.lines[i], "C %63s %63s", name, allow) != 2) {
            continue;
        }
        snprintf(prefix, sizeof(prefix), "C %s ", name);
        if (find(&b, prefix) == NULL) {
            printf("FAIL %s: missing from %s\n", name, ours_path);
            fail++;
            continue;
        }
        for (k = 0; k < 4; k++) {
            snprintf(prefix, sizeof(prefix), "R %s#%d ", name, k);
            la = find(&a, prefix);
            lb = find(&b, prefix);
            if (la == NULL && lb == NULL) {
                break;
            }
            if (la == NULL || lb == NULL) {
                exact = 0;
                snprintf(why, sizeof(why), "frame %d missing", k);
                break;
            }
            if (same_lib && !responses_only ? strcmp(skip_class(la), skip_class(lb)) != 0 : strcmp(la, lb) != 0) {
                exact = 0;
                if (why[0] == '\0') {
                    snprintf(why, sizeof(why), "frame %d: %.200s | %.200s", k, la, lb);
                }
            }
            if (!same_lib && strcmp(allow, "-") != 0) {
                /* Each side must give exactly what its version gives. */
                char e[160];
                const char *ea, *eb;
                snprintf(e, sizeof(e), "E %s#%d 316 ", name, k);
                ea = find(&a, e);
                snprintf(e, sizeof(e), "E %s#%d 312 ", name, k);
                eb = find(&b, e);
                if (ea == NULL || eb == NULL || strcmp(ea + strlen(e), la + strlen(prefix)) != 0 ||
                    strcmp(eb + strlen(e), lb + strlen(prefix)) != 0) {
                    allowed_ok = 0;
                }
            }
        }
        if (exact && responses_only) {
            /* The responses are the comparison. */
        } else if (exact) {
            /* Same responses: the debug logs must be equal too. */
            char *na, *nb;
            snprintf(prefix, sizeof(prefix), "L %s ", name);
            la = find(&a, prefix);
            lb = find(&b, prefix);
            na = la && !same_lib ? normalize_debian(la) : strdup(la ? la : "");
            nb = strdup(lb ? lb : "");
            if (strcmp(na, nb) != 0) {
                ok = 0;
                size_t d = 0, from;
                while (na[d] != '\0' && na[d] == nb[d]) {
                    d++;
                }
                from = d > 120 ? d - 120 : 0;
                snprintf(why, sizeof(why), "debug log differs at offset %zu:\n    debian: ...%.600s\n    ours:   ...%.600s",
                         d, na + from, nb + from);
            }
            free(na);
            free(nb);
            if (ok && strcmp(allow, "-") != 0 && !same_lib) {
                ok = 0;
                snprintf(why, sizeof(why), "allowed difference %s expected but both sides agree", allow);
            }
        } else if (!same_lib && strcmp(allow, "-") != 0 && allowed_ok) {
            printf("PASS %s (allowed difference %s: each side matches its version exactly)\n", name, allow);
            allowed++;
            pass++;
            continue;
        } else {
            ok = 0;
        }
        if (ok) {
            printf("PASS %s\n", name);
            pass++;
        } else {
            printf("FAIL %s: %s\n", name, why);
            fail++;
        }
    }
    for (i = 0; i < b.n; i++) {
        if (strncmp(b.lines[i], "S ", 2) == 0) {
            const char *sa = NULL;
            int j;
            for (j = 0; j < a.n; j++) {
                if (strncmp(a.lines[j], "S ", 2) == 0) {
                    sa = a.lines[j];
                }
            }
            if (sa == NULL || strcmp(sa, b.lines[i]) != 0 || strcmp(b.lines[i], "S exit 0") != 0) {
                printf("FAIL server-exit: %s | %s\n", sa ? sa : "(none)", b.lines[i]);
                fail++;
            } else {
                printf("PASS server-exit (clean exit after the quit request)\n");
                pass++;
            }
        }
    }
    printf("COMPARED %d passed (%d with an allowed difference), %d failed\n", pass, allowed, fail);
    return fail ? 1 : 0;
}

int main(int argc, char **argv)
{
    signal(SIGPIPE, SIG_IGN);
    if (argc == 2 && strcmp(argv[1], "freeport") == 0) {
        /* A free TCP port on both loopbacks (for the unit-test programs). */
        int tries;
        for (tries = 0; tries < 50; tries++) {
            int p = free_port(AF_INET), s = socket(AF_INET6, SOCK_STREAM, 0);
            struct sockaddr_in6 a;
            memset(&a, 0, sizeof(a));
            a.sin6_family = AF_INET6;
            a.sin6_port = htons((uint16_t) p);
            if (s >= 0 && bind(s, (struct sockaddr *) &a, sizeof(a)) == 0) {
                close(s);
                printf("%d\n", p);
                return 0;
            }
            if (s >= 0) {
                close(s);
            }
        }
        die("no free port");
    }
    if (argc >= 4 && strcmp(argv[1], "compare") == 0) {
        int responses_only = argc > 4 && strcmp(argv[4], "--responses") == 0;
        return compare(argv[2], argv[3], responses_only || (argc > 4 && strcmp(argv[4], "--same-lib") == 0),
                       responses_only);
    }
    if (argc >= 5 && strcmp(argv[1], "run") == 0) {
        int i, slow = 0;
        log_path = argv[3];
        for (i = 4; i < argc && strcmp(argv[i], "--") != 0; i++) {
            if (strcmp(argv[i], "--slow") == 0) {
                slow = 1;
            }
        }
        if (i >= argc - 1) {
            die("missing server command after --");
        }
        return run(argv[2], slow, argv + i + 1, argc - i - 1);
    }
    fprintf(stderr, "usage: %s run tcp|tcppi|rtu <log> [--slow] -- <server...>\n"
                    "       %s compare <debian record> <ours record> [--same-lib | --responses]\n"
                    "       %s freeport\n",
            argv[0], argv[0], argv[0]);
    return 2;
}
