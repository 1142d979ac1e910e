/*
 * cb-test.c: a server answering through modbus_reply_dispatch (and receiving
 * through modbus_receive_dispatch), checked by a client of the same library in the
 * same process, over TCP or RTU (c-tests/suites/callbacks.sh).
 *
 *   cb-test tcp <port>
 *   cb-test rtu <server device> <client device>     (a pty pair)
 *
 * The server serves units 1, 2 and 7, each with its own data, and unit 9 with a
 * callback set that has only read_registers. It checks: the values of every function
 * code, both ways; the request info (unit, function, transaction id, socket); the
 * order of the accesses of FC 16 and FC 17; each exception code, no answer, and a
 * value that is no exception code from a callback; NULL callbacks; `other` for report
 * slave id, read exception status and unknown codes; the units not served (silence
 * on RTU, and the answer that follows skipped; exception 0B on TCP); a broadcast on
 * RTU (the write callbacks run, nothing is sent); and, on TCP, a request answered
 * after the one that followed it (two requests in flight from the event-driven
 * client).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <poll.h>
#include <stddef.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <sys/socket.h>

#include <modbus.h>

#include "../common/check.h"

#define NREG 200
#define UNITS 3

static const int UNIT_IDS[UNITS] = {1, 2, 7};

/* The server's state: its data, what the callbacks saw. */
static struct {
    uint16_t regs[UNITS][NREG];
    uint8_t bits[UNITS][NREG];
    modbus_request_info_t last; /* the last data access's request */
    char order[16];             /* the accesses of the last request: r, w */
    int socket;                 /* the server context's socket */
    uint8_t pdu[8]; /* the start of the last request `other` saw */
    int pdu_length;
    int quit;
    int tcp;
} S;

static int unit_index(int unit)
{
    int i;
    for (i = 0; i < UNITS; i++) {
        if (UNIT_IDS[i] == unit) {
            return i;
        }
    }
    return -1;
}

static void note(const modbus_request_info_t *ri, char access)
{
    size_t n;
    /* (Field by field: the struct has padding.) */
    if (ri->unit_id != S.last.unit_id || ri->function != S.last.function ||
        ri->transaction_id != S.last.transaction_id || ri->socket != S.last.socket ||
        ri->tls_role != S.last.tls_role || ri->request_id != S.last.request_id) {
        S.order[0] = '\0';
    }
    S.last = *ri;
    n = strlen(S.order);
    if (n + 1 < sizeof(S.order)) {
        S.order[n] = access;
        S.order[n + 1] = '\0';
    }
}

#define NOT_SPECIAL 0x7FFF

/* The answer for an address of the test ranges: 9000 + code (an exception,
 * MODBUS_REPLY_EXCEPTION(code)), 9100 (no answer), 9200 (a value that is no answer),
 * 9300 (a positive exception code: a programming error); NOT_SPECIAL for the others. */
static int special(int addr)
{
    if (addr > 9000 && addr < 9000 + MODBUS_EXCEPTION_MAX) {
        return MODBUS_REPLY_EXCEPTION(addr - 9000);
    }
    if (addr == 9100) {
        return MODBUS_REPLY_NONE;
    }
    if (addr == 9200) {
        return 77;
    }
    if (addr == 9300) {
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    return NOT_SPECIAL;
}

/* What accept_unit saw of the last request it was asked about. */
static struct {
    int calls, function, socket, pdu_length, struct_size_ok;
    uint64_t connection_id;
    int has_peer, peer_family;
    uint8_t pdu0;
} A;

static int accept_unit(const modbus_request_info_t *ri, int unit_id, void *user_data)
{
    (void) user_data;
    A.calls++;
    A.struct_size_ok = ri->struct_size >= offsetof(modbus_request_info_t, pdu_length) + sizeof(int);
    A.function = ri->function;
    A.socket = ri->socket;
    A.connection_id = ri->connection_id;
    A.has_peer = ri->peer != NULL && ri->peer_length > 0;
    A.peer_family = ri->peer != NULL ? ri->peer->sa_family : -1;
    A.pdu_length = ri->pdu_length;
    A.pdu0 = ri->pdu_length > 0 ? ri->pdu[0] : 0;
    return unit_index(unit_id) >= 0 || unit_id == 8 || unit_id == 9;
}

/* Checks a request's range: 0 or the answer to give. */
static int range(int addr, int nb, int *u, const modbus_request_info_t *ri)
{
    int sp = special(addr);
    if (sp != NOT_SPECIAL) {
        return sp;
    }
    *u = unit_index(ri->unit_id);
    if (*u < 0) {
        *u = 0; /* units 8 and 9 (and the broadcast) see unit 1's data */
    }
    if (addr < 0 || addr + nb > NREG) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    return 0;
}

static int read_bits(const modbus_request_info_t *ri, int addr, int nb, uint8_t *dest, void *user_data)
{
    int u = 0, rc = range(addr, nb, &u, ri), i;
    (void) user_data;
    note(ri, 'r');
    if (rc != 0) {
        return rc;
    }
    for (i = 0; i < nb; i++) {
        /* Discrete inputs: a pattern of the unit; coils: the table. */
        dest[i] = ri->function == MODBUS_FC_READ_DISCRETE_INPUTS ? (uint8_t) ((addr + i + ri->unit_id) % 2)
                                                                 : S.bits[u][addr + i];
    }
    return 0;
}

static int read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *user_data)
{
    int u = 0, rc = range(addr, nb, &u, ri), i;
    (void) user_data;
    note(ri, 'r');
    if (rc != 0) {
        return rc;
    }
    for (i = 0; i < nb; i++) {
        dest[i] = ri->function == MODBUS_FC_READ_INPUT_REGISTERS ? (uint16_t) (ri->unit_id * 1000 + addr + i)
                                                                 : S.regs[u < 0 ? 0 : u][addr + i];
    }
    return 0;
}

static int write_bits(const modbus_request_info_t *ri, int addr, int nb, const uint8_t *src, void *user_data)
{
    int u = 0, rc = range(addr, nb, &u, ri), i, k;
    (void) user_data;
    note(ri, 'w');
    if (rc != 0) {
        return rc;
    }
    for (k = 0; k < UNITS; k++) {
        if (k == u || ri->unit_id == 0) {
            for (i = 0; i < nb; i++) {
                S.bits[k][addr + i] = src[i];
            }
        }
    }
    return 0;
}

static int write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src, void *user_data)
{
    int u = 0, rc = range(addr, nb, &u, ri), i, k;
    (void) user_data;
    note(ri, 'w');
    if (rc != 0) {
        return rc;
    }
    for (k = 0; k < UNITS; k++) {
        if (k == u || ri->unit_id == 0) {
            for (i = 0; i < nb; i++) {
                S.regs[k][addr + i] = src[i];
            }
        }
    }
    return 0;
}

static int other(const modbus_request_info_t *ri, const uint8_t *pdu, int pdu_length, uint8_t *rsp, int rsp_max, void *user_data)
{
    (void) user_data;
    S.last = *ri;
    S.pdu_length = pdu_length;
    memcpy(S.pdu, pdu, (size_t) (pdu_length < 8 ? pdu_length : 8));
    if (rsp_max < 8) {
        return -MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE;
    }
    switch (pdu[0]) {
    case MODBUS_FC_REPORT_SLAVE_ID:
        rsp[0] = pdu[0];
        rsp[1] = 3;
        rsp[2] = 0x42;
        rsp[3] = 0xFF;
        rsp[4] = 'X';
        return 5;
    case MODBUS_FC_READ_EXCEPTION_STATUS:
        rsp[0] = pdu[0];
        rsp[1] = 0x5A;
        return 2;
    case 0x41: /* the request's length (a client frames an unknown code's answer
                  as the code and one byte) */
        rsp[0] = 0x41;
        rsp[1] = (uint8_t) pdu_length;
        return 2;
    case 0x42:
        return -MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    case 0x43:
        return MODBUS_REPLY_NONE;
    case 0x44:
        return 9999; /* no length, no exception: answered 04 */
    case 0x45:
        S.quit = 1;
        return MODBUS_REPLY_NONE;
    case 0x46:
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    default:
        return -MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
}

static const modbus_server_callbacks_t FULL = {
    .struct_size = sizeof(modbus_server_callbacks_t),
    .accept_unit = accept_unit,
    .read_bits = read_bits,
    .read_registers = read_registers,
    .write_bits = write_bits,
    .write_registers = write_registers,
    .other = other,
};

/* Unit 9: only read_registers. */
static const modbus_server_callbacks_t SPARSE = {
    .struct_size = sizeof(modbus_server_callbacks_t),
    .accept_unit = accept_unit,
    .read_registers = read_registers,
};

/* An application built against a newer, longer struct whose members this library
 * does not know are all NULL (a zero tail): accepted, as the struct it knows. */
static struct newer {
    modbus_server_callbacks_t cb;
    void *future[3];
} NEWER;

static void *server(void *arg)
{
    modbus_t *ctx = arg;
    uint8_t req[MODBUS_MAX_ADU_LENGTH], held[MODBUS_MAX_ADU_LENGTH];
    int held_len = 0, h = modbus_get_header_length(ctx), s = -1, round;

    if (S.tcp) {
        s = modbus_tcp_listen(ctx, 1);
        if (s < 0 || modbus_tcp_accept(ctx, &s) < 0) {
            fprintf(stderr, "server: listen/accept: %s\n", modbus_strerror(errno));
            return NULL;
        }
    } else if (modbus_connect(ctx) < 0) {
        fprintf(stderr, "server: connect: %s\n", modbus_strerror(errno));
        return NULL;
    }
    S.socket = modbus_get_socket(ctx);
    /* (An unknown code is answered after the response timeout, as modbus_reply does:
     * below the client's.) */
    modbus_set_response_timeout(ctx, 0, 100000);
    for (round = 0; round < 2; round++) {
    if (round == 1) {
        /* TCP: a second client, accepted once the first has left: its socket
         * most likely gets the same descriptor number. */
        if (!S.tcp) {
            break;
        }
        modbus_close(ctx);
        S.quit = 0;
        if (modbus_tcp_accept(ctx, &s) < 0) {
            break;
        }
    }
    while (!S.quit) {
        const modbus_server_callbacks_t *cb = &FULL;
        int rc = modbus_receive_dispatch(ctx, req, &FULL, NULL);
        if (rc == -1 && (errno == ETIMEDOUT || errno == EMBBADCRC)) {
            continue;
        }
        if (rc < 0) {
            break;
        }
        if (rc == 0) {
            continue;
        }
        if (req[h - 1] == 9) {
            cb = &SPARSE;
        } else if (req[h - 1] == 8) {
            cb = &NEWER.cb;
        }
        /* Answering later: the read at 150 waits for the read at 160, answered first. */
        if (req[h] == MODBUS_FC_READ_HOLDING_REGISTERS && req[h + 1] == 0 && req[h + 2] == 150) {
            memcpy(held, req, (size_t) rc);
            held_len = rc;
            continue;
        }
        modbus_reply_dispatch(ctx, req, rc, cb, NULL);
        if (held_len > 0) {
            modbus_reply_dispatch(ctx, held, held_len, cb, NULL);
            held_len = 0;
        }
    }
    }
    if (s >= 0) {
        close(s);
    }
    modbus_close(ctx);
    return NULL;
}

/* A raw request for `unit`: its answer's length (-1 with errno). */
static int raw(modbus_t *ctx, int unit, const uint8_t *pdu, int n, uint8_t *rsp)
{
    uint8_t req[260];
    req[0] = (uint8_t) unit;
    memcpy(req + 1, pdu, (size_t) n);
    if (modbus_send_raw_request(ctx, req, n + 1) < 0) {
        return -1;
    }
    return modbus_receive_confirmation(ctx, rsp);
}

static int later_done;
static void later_cb(modbus_t *ctx, int id, int rc, int error, void *user_data)
{
    (void) ctx;
    (void) id;
    (void) error;
    ((int *) user_data)[0] = rc;
    ((int *) user_data)[1] = later_done++;
}

static void client(modbus_t *ctx, int tcp)
{
    uint16_t regs[130], want[130];
    uint8_t bits[64], rsp[MODBUS_MAX_ADU_LENGTH];
    int i, rc, u, h = tcp ? 7 : 1, tid;

    modbus_set_response_timeout(ctx, 0, 500000);
    for (u = 0; u < UNITS; u++) {
        int unit = UNIT_IDS[u];
        modbus_set_slave(ctx, unit);
        for (i = 0; i < 20; i++) {
            want[i] = (uint16_t) (unit * 100 + i);
        }
        EXPECT(modbus_write_registers(ctx, 10, 20, want) == 20, "unit %d: FC 10 writes 20 registers", unit);
        EXPECT(S.last.unit_id == unit && S.last.function == 0x10 && S.regs[u][10] == want[0] &&
                   S.regs[u][29] == want[19],
               "unit %d: write_registers got the unit, FC 10 and the values in host order", unit);
        tid = S.last.transaction_id;
        EXPECT(S.last.socket == S.socket && S.last.tls_role == NULL,
               "unit %d: the request info names the server's descriptor (%d), no TLS role", unit, S.last.socket);
        rc = modbus_read_registers(ctx, 10, 20, regs);
        EXPECT(rc == 20 && memcmp(regs, want, 40) == 0, "unit %d: FC 03 reads them back", unit);
        EXPECT(tcp ? S.last.transaction_id == ((tid + 1) & 0xFFFF) : S.last.transaction_id == 0,
               "unit %d: the transaction id (%d after %d)", unit, S.last.transaction_id, tid);
        rc = modbus_read_input_registers(ctx, 5, 3, regs);
        EXPECT(rc == 3 && regs[0] == unit * 1000 + 5 && regs[2] == unit * 1000 + 7,
               "unit %d: FC 04 from the input callback", unit);
        EXPECT(modbus_write_register(ctx, 3, 0xBEEF) == 1 && S.regs[u][3] == 0xBEEF, "unit %d: FC 06", unit);
        EXPECT(modbus_mask_write_register(ctx, 3, 0x00FF, 0x1200) == 1 && S.regs[u][3] == 0x12EF &&
                   strcmp(S.order, "rw") == 0,
               "unit %d: FC 16 reads then writes the register (%s), 0x%04X", unit, S.order, S.regs[u][3]);
        for (i = 0; i < 4; i++) {
            want[i] = (uint16_t) (0x700 + i);
        }
        rc = modbus_write_and_read_registers(ctx, 40, 4, want, 40, 4, regs);
        EXPECT(rc == 4 && memcmp(regs, want, 8) == 0 && strcmp(S.order, "wr") == 0,
               "unit %d: FC 17 writes then reads (%s)", unit, S.order);
        for (i = 0; i < 37; i++) {
            bits[i] = (uint8_t) ((i * 7 + unit) % 3 == 0);
        }
        EXPECT(modbus_write_bits(ctx, 50, 37, bits) == 37 && S.bits[u][50] == bits[0] && S.bits[u][86] == bits[36],
               "unit %d: FC 0F, one bit per byte", unit);
        memset(rsp, 0xEE, sizeof(rsp));
        rc = modbus_read_bits(ctx, 50, 37, rsp);
        EXPECT(rc == 37 && memcmp(rsp, bits, 37) == 0, "unit %d: FC 01 reads them back", unit);
        EXPECT(modbus_write_bit(ctx, 60, 0) == 1 && S.bits[u][60] == 0 && modbus_write_bit(ctx, 61, 1) == 1 &&
                   S.bits[u][61] == 1,
               "unit %d: FC 05", unit);
        rc = modbus_read_input_bits(ctx, 0, 9, rsp);
        EXPECT(rc == 9 && rsp[0] == unit % 2 && rsp[1] == (1 + unit) % 2 && rsp[8] == (8 + unit) % 2,
               "unit %d: FC 02 from the input callback", unit);
    }
    /* accept_unit gets the request info: the request, and who sent it. */
    modbus_set_slave(ctx, 7);
    A.calls = 0;
    rc = modbus_read_registers(ctx, 10, 2, regs);
    EXPECT(rc == 2 && A.calls >= 1 && A.function == 3 && A.pdu_length == 5 &&
               A.pdu0 == 3 && A.struct_size_ok,
           "accept_unit sees the request info (function %d, a PDU of %d bytes)", A.function, A.pdu_length);
    if (tcp) {
        EXPECT(A.connection_id != 0 && A.has_peer && A.peer_family == AF_INET && A.socket == S.socket,
               "TCP: accept_unit sees the connection (id %llu), its peer and socket",
               (unsigned long long) A.connection_id);
    } else {
        EXPECT(A.connection_id == 0 && !A.has_peer, "RTU: no connection id, no peer");
    }

    /* The units' data stayed apart. */
    modbus_set_slave(ctx, 1);
    EXPECT(modbus_read_registers(ctx, 10, 1, regs) == 1 && regs[0] == 100, "unit 1 kept its own data");
    modbus_set_slave(ctx, 7);
    EXPECT(modbus_read_registers(ctx, 10, 1, regs) == 1 && regs[0] == 700, "unit 7 kept its own data");

    /* Exceptions and no answer, from every data callback. */
    modbus_set_slave(ctx, 2);
    for (i = 1; i < MODBUS_EXCEPTION_MAX; i++) {
        int e1, e2, e3, e4;
        errno = 0;
        rc = modbus_read_registers(ctx, 9000 + i, 1, regs);
        e1 = rc == -1 ? errno : 0;
        rc = modbus_read_bits(ctx, 9000 + i, 1, bits);
        e2 = rc == -1 ? errno : 0;
        rc = modbus_write_register(ctx, 9000 + i, 1);
        e3 = rc == -1 ? errno : 0;
        rc = modbus_write_bits(ctx, 9000 + i, 3, bits);
        e4 = rc == -1 ? errno : 0;
        EXPECT(e1 == MODBUS_ENOBASE + i && e2 == e1 && e3 == e1 && e4 == e1,
               "exception %d from read_registers, read_bits, write_registers, write_bits", i);
    }
    errno = 0;
    EXPECT(modbus_read_registers(ctx, 9100, 1, regs) == -1 && errno == ETIMEDOUT,
           "MODBUS_REPLY_NONE from read_registers: no answer (%s)", modbus_strerror(errno));
    EXPECT(modbus_write_bit(ctx, 9100, 1) == -1 && errno == ETIMEDOUT, "MODBUS_REPLY_NONE from write_bits");
    EXPECT(modbus_read_registers(ctx, 9200, 1, regs) == -1 && errno == EMBXSFAIL,
           "a value that is no exception code: exception 04 (%s)", modbus_strerror(errno));
    errno = 0;
    EXPECT(modbus_read_registers(ctx, 9300, 1, regs) == -1 && errno == EMBXSFAIL,
           "a positive exception code from a data callback (no MODBUS_REPLY_EXCEPTION): exception 04, not 02 (%s)",
           modbus_strerror(errno));
    EXPECT(modbus_read_registers(ctx, 195, 10, regs) == -1 && errno == EMBXILADD,
           "the callback's own range check: exception 02");
    want[0] = 0x5151;
    EXPECT(modbus_write_and_read_registers(ctx, 30, 1, want, 195, 10, regs) == -1 && errno == EMBXILADD &&
               strcmp(S.order, "wr") == 0 && S.regs[1][30] == 0x5151,
           "FC 17 with a read range refused: the write callback ran first (%s), exception 02", S.order);
    {
        const uint8_t over[] = {0x03, 0x00, 0x00, 0x00, 126};
        rc = raw(ctx, 2, over, 5, rsp);
        EXPECT(rc > h + 1 && rsp[h] == 0x83 && rsp[h + 1] == 3,
               "a quantity over 125 is refused before any callback (exception 03)");
    }

    /* NULL callbacks: exception 01; unit 9 has read_registers only. */
    modbus_set_slave(ctx, 9);
    EXPECT(modbus_read_registers(ctx, 10, 2, regs) == 2, "unit 9: read_registers");
    EXPECT(modbus_read_bits(ctx, 0, 2, bits) == -1 && errno == EMBXILFUN, "unit 9: NULL read_bits, exception 01");
    EXPECT(modbus_write_register(ctx, 0, 2) == -1 && errno == EMBXILFUN,
           "unit 9: NULL write_registers, exception 01");
    EXPECT(modbus_write_bit(ctx, 0, 1) == -1 && errno == EMBXILFUN, "unit 9: NULL write_bits, exception 01");
    EXPECT(modbus_mask_write_register(ctx, 0, 1, 2) == -1 && errno == EMBXILFUN,
           "unit 9: FC 16 needs write_registers too, exception 01");
    EXPECT(modbus_report_slave_id(ctx, sizeof(rsp), rsp) == 11 && memcmp(rsp + 2, "LMB", 3) == 0,
           "unit 9: NULL other, report slave id is modbus_reply's");
    {
        const uint8_t pdu[] = {0x41, 1, 2};
        rc = raw(ctx, 9, pdu, tcp ? 3 : 1, rsp);
        EXPECT(rc > h + 1 && rsp[h] == 0xC1 && rsp[h + 1] == 1, "unit 9: NULL other, an unknown code: 01");
    }

    /* other */
    modbus_set_slave(ctx, 1);
    rc = modbus_report_slave_id(ctx, sizeof(rsp), rsp);
    EXPECT(rc == 3 && rsp[0] == 0x42 && rsp[1] == 0xFF && rsp[2] == 'X', "other answers report slave id (rc %d)", rc);
    {
        const uint8_t p41[] = {0x41, 0x33, 0x44, 0x55}, p07[] = {0x07}, p42[] = {0x42}, p43[] = {0x43},
                      p44[] = {0x44};
        /* (On RTU an unknown code has no length: only its code is framed.) */
        rc = raw(ctx, 1, p41, tcp ? 4 : 1, rsp);
        EXPECT(rc == h + 2 + (tcp ? 0 : 2) && rsp[h] == 0x41 && rsp[h + 1] == (tcp ? 4 : 1),
               "other answers an unknown code (rc %d, length %d)", rc, rsp[h + 1]);
        if (tcp) {
            EXPECT(S.pdu_length == 4 && memcmp(S.pdu, p41, 4) == 0,
                   "TCP: other sees the unknown code's whole request (MBAP length)");
        } else {
            EXPECT(S.pdu_length == 1, "RTU: other sees an unknown code's request");
        }
        rc = raw(ctx, 1, p07, 1, rsp);
        EXPECT(rc > h && rsp[h] == 0x07 && rsp[h + 1] == 0x5A, "other answers read exception status");
        rc = raw(ctx, 1, p42, 1, rsp);
        EXPECT(rc > h + 1 && rsp[h] == 0xC2 && rsp[h + 1] == 3, "other: -3 is exception 03");
        EXPECT(raw(ctx, 1, p43, 1, rsp) == -1 && errno == ETIMEDOUT, "other: MODBUS_REPLY_NONE, no answer");
        rc = raw(ctx, 1, p44, 1, rsp);
        EXPECT(rc > h + 1 && rsp[h] == 0xC4 && rsp[h + 1] == 4, "other: an impossible length is exception 04");
        {
            const uint8_t p46[] = {0x46};
            rc = raw(ctx, 1, p46, 1, rsp);
            EXPECT(rc > h + 1 && rsp[h] == 0xC6 && rsp[h + 1] == 2,
                   "other: MODBUS_REPLY_EXCEPTION(2) is exception 02 (rc %d, 0x%02X %d)", rc, rsp[h], rsp[h + 1]);
        }
    }

    /* A unit not served. */
    modbus_set_slave(ctx, 3);
    errno = 0;
    rc = modbus_read_registers(ctx, 0, 1, regs);
    if (tcp) {
        EXPECT(rc == -1 && errno == EMBXGTAR, "TCP: unit 3 not served, exception 0B (%s)", modbus_strerror(errno));
    } else {
        EXPECT(rc == -1 && errno == ETIMEDOUT, "RTU: unit 3 not served, no answer (%s)", modbus_strerror(errno));
        /* On a bus, unit 3 answers at once: the frame that follows a request for
         * another unit is skipped as that unit's answer. */
        modbus_send_raw_request(ctx, (uint8_t[]){3, 0x03, 0x00, 0x00, 0x00, 0x01}, 6);
        modbus_send_raw_request(ctx, (uint8_t[]){3, 0x03, 0x02, 0x00, 0x00}, 5);
        modbus_set_slave(ctx, 1);
        EXPECT(modbus_read_registers(ctx, 10, 1, regs) == 1 && regs[0] == 100,
               "RTU: the frame after it is skipped as unit 3's answer; unit 1 answers the next");
        /* A broadcast: the write callbacks run for unit 0, nothing is sent. */
        modbus_set_slave(ctx, 0);
        errno = 0;
        EXPECT(modbus_write_register(ctx, 5, 4242) == -1 && errno == ETIMEDOUT,
               "RTU: a broadcast write is not answered (the client waits, as libmodbus's does)");
        modbus_set_slave(ctx, 2);
        EXPECT(modbus_read_registers(ctx, 5, 1, regs) == 1 && regs[0] == 4242 && S.regs[0][5] == 4242 &&
                   S.regs[2][5] == 4242,
               "RTU: the broadcast ran the write callback (every unit has 4242)");
    }
    /* Unit 8: a newer, longer struct with a zero tail, served as the one known. */
    modbus_set_slave(ctx, 8);
    EXPECT(modbus_read_bits(ctx, 50, 2, bits) == 2 && modbus_read_registers(ctx, 10, 1, regs) == 1,
           "unit 8 (struct_size past what the library knows, zero tail): served");

    if (tcp) {
        /* Answering later: two requests in flight; the first is answered second. */
        int a[2] = {-2, -1}, b[2] = {-2, -1};
        uint16_t ra[4], rb[4];
        struct pollfd pfd;
        int to;
        modbus_set_slave(ctx, 1);
        for (i = 0; i < 4; i++) {
            want[i] = (uint16_t) (0x1500 + i);
            want[10 + i] = (uint16_t) (0x1600 + i);
        }
        modbus_write_registers(ctx, 150, 4, want);
        modbus_write_registers(ctx, 160, 4, want + 10);
        EXPECT(modbus_set_max_in_flight(ctx, 2) == 0, "two requests in flight");
        EXPECT(modbus_read_registers_async(ctx, 150, 4, ra, later_cb, a) >= 0 &&
                   modbus_read_registers_async(ctx, 160, 4, rb, later_cb, b) >= 0,
               "two reads submitted");
        for (i = 0; i < 100 && modbus_pending(ctx) > 0; i++) {
            modbus_get_pollfd(ctx, &pfd, &to);
            pfd.revents = 0;
            poll(&pfd, 1, to < 0 || to > 100 ? 100 : to);
            modbus_process(ctx, pfd.revents);
        }
        EXPECT(a[0] == 4 && b[0] == 4 && memcmp(ra, want, 8) == 0 && memcmp(rb, want + 10, 8) == 0,
               "the read at 150, answered after the read at 160, has its own values (rc %d, %d)", a[0], b[0]);
        EXPECT(b[1] == 0 && a[1] == 1, "the later request completed first");
        modbus_set_max_in_flight(ctx, 1);
    }

    {
        const uint8_t quit[] = {0x45};
        modbus_set_slave(ctx, 1);
        raw(ctx, 1, quit, 1, rsp);
    }
}

int main(int argc, char **argv)
{
    modbus_t *srv, *cli;
    pthread_t t;
    int rc;
    modbus_server_callbacks_t bad = {0};

    if (argc < 3) {
        fprintf(stderr, "usage: %s tcp <port> | rtu <server device> <client device>\n", argv[0]);
        return 2;
    }
    S.tcp = strcmp(argv[1], "tcp") == 0;
    if (S.tcp) {
        srv = modbus_new_tcp("127.0.0.1", atoi(argv[2]));
        cli = modbus_new_tcp("127.0.0.1", atoi(argv[2]));
    } else {
        if (argc < 4) {
            return 2;
        }
        srv = modbus_new_rtu(argv[2], 115200, 'N', 8, 1);
        cli = modbus_new_rtu(argv[3], 115200, 'N', 8, 1);
        modbus_set_slave(srv, 1);
    }
    if (srv == NULL || cli == NULL) {
        fprintf(stderr, "new: %s\n", modbus_strerror(errno));
        return 2;
    }
    chk_set_prefix(S.tcp ? "tcp: " : "rtu: ");
    if (getenv("CBTEST_DEBUG") != NULL) {
        modbus_set_debug(srv, TRUE);
        modbus_set_debug(cli, TRUE);
    }
    /* An application of a newer, longer struct (members unknown here all NULL). */
    memset(&NEWER, 0, sizeof NEWER);
    NEWER.cb = FULL;
    NEWER.cb.struct_size = sizeof NEWER;

    EXPECT(modbus_reply_dispatch(srv, (uint8_t[]){1, 3, 0, 0, 0, 1}, 6, NULL, NULL) == -1 && errno == EINVAL,
           "modbus_reply_dispatch: NULL callbacks, EINVAL");
    bad.struct_size = 4;
    EXPECT(modbus_reply_dispatch(srv, (uint8_t[]){1, 3, 0, 0, 0, 1}, 6, &bad, NULL) == -1 && errno == EINVAL,
           "modbus_reply_dispatch: a struct_size too small, EINVAL");
    {
        /* The struct_size rules (man page): below the first published size, not on a
         * member's end, or past what the library knows with a member set there: EINVAL. */
        struct newer big;
        modbus_server_callbacks_t small = FULL;
        small.struct_size = offsetof(modbus_server_callbacks_t, read_registers);
        errno = 0;
        EXPECT(modbus_reply_dispatch(srv, (uint8_t[]){1, 3, 0, 0, 0, 1}, 6, &small, NULL) == -1 && errno == EINVAL,
               "struct_size below the first published size (%d): EINVAL", (int) small.struct_size);
        small.struct_size = sizeof(modbus_server_callbacks_t) - sizeof(void *) / 2;
        errno = 0;
        EXPECT(modbus_reply_dispatch(srv, (uint8_t[]){1, 3, 0, 0, 0, 1}, 6, &small, NULL) == -1 && errno == EINVAL,
               "struct_size in the middle of a member (%d): EINVAL", (int) small.struct_size);
        memset(&big, 0, sizeof big);
        big.cb = FULL;
        big.cb.struct_size = sizeof big;
        big.future[1] = (void *) &big;
        errno = 0;
        EXPECT(modbus_reply_dispatch(srv, (uint8_t[]){1, 3, 0, 0, 0, 1}, 6, &big.cb, NULL) == -1 &&
                   errno == EINVAL,
               "struct_size larger than the library knows, a member it does not know set: EINVAL (%s)",
               modbus_strerror(errno));
        errno = 0;
        EXPECT(modbus_server_set_callbacks(NULL, &NEWER.cb, NULL) == -1 && errno == EINVAL,
               "modbus_server_set_callbacks: NULL server, EINVAL");
    }
    EXPECT(modbus_receive_dispatch(srv, NULL, &FULL, NULL) == -1 && errno == EINVAL,
           "modbus_receive_dispatch: NULL request buffer, EINVAL");

    pthread_create(&t, NULL, server, srv);
    if (S.tcp) {
        for (rc = -1; rc < 0 && !S.quit;) {
            rc = modbus_connect(cli);
            if (rc < 0) {
                usleep(20000);
            }
        }
    } else if (modbus_connect(cli) < 0) {
        fprintf(stderr, "connect: %s\n", modbus_strerror(errno));
        return 2;
    }
    client(cli, S.tcp);
    modbus_close(cli);
    if (S.tcp) {
        /* A second client after the first has left: a new connection id, though its
         * socket on the server likely has the same number. */
        uint64_t first = A.connection_id;
        int first_socket = A.socket;
        uint16_t regs[2];
        modbus_t *cli2 = modbus_new_tcp("127.0.0.1", atoi(argv[2]));
        usleep(100000);
        for (rc = -1; rc < 0;) {
            rc = modbus_connect(cli2);
            if (rc < 0) {
                usleep(20000);
            }
        }
        modbus_set_slave(cli2, 1);
        modbus_set_response_timeout(cli2, 0, 500000);
        rc = modbus_read_registers(cli2, 10, 2, regs);
        EXPECT(rc == 2 && A.connection_id != 0 && A.connection_id != first,
               "a second client gets another connection id (%llu after %llu; socket %d after %d)",
               (unsigned long long) A.connection_id, (unsigned long long) first, A.socket, first_socket);
        EXPECT(A.socket == first_socket, "(the second client's socket has the first one's number, %d)", A.socket);
        raw(cli2, 1, (const uint8_t[]){0x45}, 1, (uint8_t[MODBUS_MAX_ADU_LENGTH]){0});
        modbus_close(cli2);
        modbus_free(cli2);
    }
    pthread_join(t, NULL);
    modbus_free(cli);
    modbus_free(srv);
    chk_set_prefix("");
    return chk_summary();
}
