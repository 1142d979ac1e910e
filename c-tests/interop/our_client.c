/*
 * our_client: rsmodbus as the CLIENT of a pymodbus server (pm_server.py) serving the
 * data of pm_model.py. Every libmodbus function code and every new one (07, 08 with each
 * sub-function, 0B, 0C, 14, 15, 18, 2B/0E), raw requests of the new codes through
 * modbus_send_raw_request/modbus_receive_confirmation, and exception answers.
 *
 * usage: our_client TRANSPORT WHERE   (see io_new_ctx; the slave is 17)
 * INTEROP_ONLY=WORD runs the checks whose function name contains WORD;
 * INTEROP_ONLY=t_echo runs only t_echo (against pm_echo.py).
 * Prints "ok   - name" / "FAIL - name: why" per check and "N passed, M failed".
 * With INTEROP_DEBUG=1 the library traces every frame (modbus_set_debug).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include "interop.h"

#include <unistd.h>

static modbus_t *ctx;
static int serial;
static int ascii;
static int rtu_framing; /* RTU on a line or over TCP: frames carry no length */

/* ---- libmodbus function codes ------------------------------------------------------ */

static void t_read_bits(void)
{
    uint8_t bits[IO_SIZE];
    int starts[] = {0, 7, 150};
    int counts[] = {37, 1, 50};
    for (int k = 0; k < 3; k++) {
        char name[64];
        int bad = -1;
        snprintf(name, sizeof(name), "read_bits(%d, %d)", starts[k], counts[k]);
        memset(bits, 0xEE, sizeof(bits));
        if (!io_rc(name, modbus_read_bits(ctx, starts[k], counts[k], bits), counts[k])) {
            continue;
        }
        for (int i = 0; i < counts[k] && bad < 0; i++) {
            if (bits[i] != io_coil(starts[k] + i)) {
                bad = i;
            }
        }
        if (bad >= 0) {
            io_fail(name, "bit %d is %d, expected %d", starts[k] + bad, bits[bad],
                    io_coil(starts[k] + bad));
        } else {
            io_ok(name);
        }
    }
}

static void t_read_input_bits(void)
{
    uint8_t bits[IO_SIZE];
    int bad = -1;
    if (!io_rc("read_input_bits(3, 100)", modbus_read_input_bits(ctx, 3, 100, bits), 100)) {
        return;
    }
    for (int i = 0; i < 100 && bad < 0; i++) {
        if (bits[i] != io_discrete(3 + i)) {
            bad = i;
        }
    }
    if (bad >= 0) {
        io_fail("read_input_bits(3, 100)", "bit %d is %d", 3 + bad, bits[bad]);
    } else {
        io_ok("read_input_bits(3, 100)");
    }
}

static int regs_equal(const char *name, const uint16_t *got, int nb, uint16_t (*f)(int), int at)
{
    for (int i = 0; i < nb; i++) {
        if (got[i] != f(at + i)) {
            io_fail(name, "register %d is 0x%04X, expected 0x%04X", at + i, got[i], f(at + i));
            return 0;
        }
    }
    io_ok(name);
    return 1;
}

static void t_read_registers(void)
{
    uint16_t regs[IO_SIZE];
    if (io_rc("read_registers(0, 125)", modbus_read_registers(ctx, 0, 125, regs), 125)) {
        regs_equal("read_registers(0, 125)", regs, 125, io_holding, 0);
    }
    if (io_rc("read_registers(190, 10)", modbus_read_registers(ctx, 190, 10, regs), 10)) {
        regs_equal("read_registers(190, 10)", regs, 10, io_holding, 190);
    }
    if (io_rc("read_input_registers(1, 125)", modbus_read_input_registers(ctx, 1, 125, regs),
              125)) {
        regs_equal("read_input_registers(1, 125)", regs, 125, io_input, 1);
    }
}

static void t_writes(void)
{
    uint8_t bits[16], back[16];
    uint16_t regs[16], rback[16];
    int ok;

    if (io_rc("write_bit(11, ON)", modbus_write_bit(ctx, 11, 1), 1) &&
        io_rc("write_bit(12, OFF)", modbus_write_bit(ctx, 12, 0), 1) &&
        io_rc("read back bits 11..12", modbus_read_bits(ctx, 11, 2, back), 2)) {
        if (back[0] == 1 && back[1] == 0) {
            io_ok("write_bit + read back");
        } else {
            io_fail("write_bit + read back", "got %d %d, expected 1 0", back[0], back[1]);
        }
    }
    for (int i = 0; i < 11; i++) {
        bits[i] = (uint8_t) ((i * 5) % 3 == 1);
    }
    if (io_rc("write_bits(40, 11)", modbus_write_bits(ctx, 40, 11, bits), 11) &&
        io_rc("read back bits 40..50", modbus_read_bits(ctx, 40, 11, back), 11)) {
        ok = memcmp(bits, back, 11) == 0;
        if (ok) {
            io_ok("write_bits + read back");
        } else {
            io_fail("write_bits + read back", "bits differ");
        }
    }
    if (io_rc("write_register(20, 0xBEEF)", modbus_write_register(ctx, 20, 0xBEEF), 1) &&
        io_rc("read back register 20", modbus_read_registers(ctx, 20, 1, rback), 1)) {
        if (rback[0] == 0xBEEF) {
            io_ok("write_register + read back");
        } else {
            io_fail("write_register + read back", "got 0x%04X", rback[0]);
        }
    }
    for (int i = 0; i < 12; i++) {
        regs[i] = (uint16_t) (0xA000 + i * 0x111);
    }
    if (io_rc("write_registers(60, 12)", modbus_write_registers(ctx, 60, 12, regs), 12) &&
        io_rc("read back registers 60..71", modbus_read_registers(ctx, 60, 12, rback), 12)) {
        if (memcmp(regs, rback, 12 * sizeof(uint16_t)) == 0) {
            io_ok("write_registers + read back");
        } else {
            io_fail("write_registers + read back", "registers differ");
        }
    }
    /* (0x1000 + 30*0x0101) = 0x2E1E; AND 0xF0F0 OR 0x0005 -> 0x2015 */
    if (io_rc("mask_write_register(30)", modbus_mask_write_register(ctx, 30, 0xF0F0, 0x0005), 1) &&
        io_rc("read back register 30", modbus_read_registers(ctx, 30, 1, rback), 1)) {
        uint16_t want = (uint16_t) ((io_holding(30) & 0xF0F0) | (0x0005 & ~0xF0F0));
        if (rback[0] == want) {
            io_ok("mask_write_register + read back");
        } else {
            io_fail("mask_write_register + read back", "got 0x%04X, expected 0x%04X", rback[0],
                    want);
        }
    }
    regs[0] = 0x1111;
    regs[1] = 0x2222;
    regs[2] = 0x3333;
    if (io_rc("write_and_read_registers(w 80..82, r 79..84)",
              modbus_write_and_read_registers(ctx, 80, 3, regs, 79, 6, rback), 6)) {
        uint16_t want[6] = {io_holding(79), 0x1111, 0x2222, 0x3333, io_holding(83),
                            io_holding(84)};
        if (memcmp(want, rback, sizeof(want)) == 0) {
            io_ok("write_and_read_registers");
        } else {
            io_fail("write_and_read_registers", "got %04X %04X %04X %04X %04X %04X", rback[0],
                    rback[1], rback[2], rback[3], rback[4], rback[5]);
        }
    }
}

static void t_report_slave_id(void)
{
    /* pymodbus answers the basic objects joined by '-' and the run indicator 0xFF. */
    const char *want = "rsmodbus-interop-PM-3-V3.16";
    uint8_t dest[256];
    int n = (int) strlen(want);
    int rc = modbus_report_slave_id(ctx, sizeof(dest), dest);
    if (!io_rc("report_slave_id", rc, n + 1)) {
        return;
    }
    if (memcmp(dest, want, (size_t) n) == 0 && dest[n] == 0xFF) {
        io_ok("report_slave_id");
    } else {
        io_fail("report_slave_id", "got '%.*s' + 0x%02X", n, (const char *) dest, dest[n]);
    }
}

static void t_exceptions(void)
{
    uint16_t regs[8];
    uint8_t bits[8];
    io_err("read_registers(250, 2) -> illegal data address",
           modbus_read_registers(ctx, 250, 2, regs), EMBXILADD);
    io_err("read_bits(300, 2) -> illegal data address", modbus_read_bits(ctx, 300, 2, bits),
           EMBXILADD);
    io_err("write_register(300) -> illegal data address", modbus_write_register(ctx, 300, 1),
           EMBXILADD);
}

/* ---- new function codes --------------------------------------------------------------- */

static void t_exception_status(void)
{
    uint8_t st = 0;
    if (io_rc("read_exception_status", modbus_read_exception_status(ctx, &st), 1)) {
        if (st == IO_EXCEPTION_STATUS) {
            io_ok("read_exception_status");
        } else {
            io_fail("read_exception_status", "got 0x%02X, expected 0x%02X", st,
                    IO_EXCEPTION_STATUS);
        }
    }
}

static void diag_expect(const char *name, int sub, const uint16_t *data, int nb,
                        const uint16_t *want, int nwant)
{
    uint16_t dest[130];
    int rc;
    memset(dest, 0xEE, sizeof(dest));
    rc = modbus_diagnostics(ctx, sub, data, nb, dest, 130);
    if (!io_rc(name, rc, nwant)) {
        return;
    }
    for (int i = 0; i < nwant; i++) {
        if (dest[i] != want[i]) {
            io_fail(name, "word %d is 0x%04X, expected 0x%04X", i, dest[i], want[i]);
            return;
        }
    }
    io_ok(name);
}

static void t_diagnostics(void)
{
    uint16_t d[130], w[130];
    char name[96];
    uint16_t dest[8];

    d[0] = 0xA537;
    diag_expect("diagnostics 00 return query data (1 word)", 0x00, d, 1, d, 1);
    d[0] = 0x1234;
    d[1] = 0x5678;
    d[2] = 0x9ABC;
    if (rtu_framing) {
        /* pymodbus 3.16.1's RTU framer takes every FC 08 frame for 8 bytes: it cannot
         * receive this request (pm_echo.py checks our side of it). */
        printf("skip - diagnostics 00 return query data (3 words): pymodbus RTU framer\n");
    } else {
        diag_expect("diagnostics 00 return query data (3 words)", 0x00, d, 3, d, 3);
    }
    d[0] = 0x0000;
    diag_expect("diagnostics 01 restart communications (0000)", 0x01, d, 1, d, 1);
    d[0] = 0xFF00;
    diag_expect("diagnostics 01 restart communications (FF00)", 0x01, d, 1, d, 1);
    d[0] = 0;
    w[0] = 0x0A02; /* bits 1, 3, 9 */
    diag_expect("diagnostics 02 return diagnostic register", 0x02, d, 1, w, 1);
    d[0] = 0x0A00; /* keep LF as the ASCII delimiter */
    diag_expect("diagnostics 03 change ASCII input delimiter", 0x03, d, 1, d, 1);
    for (int sub = 0x0B; sub <= 0x12; sub++) {
        snprintf(name, sizeof(name), "diagnostics %02X counter", sub);
        d[0] = 0;
        diag_expect(name, sub, d, 1, &io_counters[sub - 0x0B], 1);
    }
    d[0] = 0;
    diag_expect("diagnostics 13 return IOP overrun count (pymodbus: = 12)", 0x13, d, 1,
                &io_counters[0x12 - 0x0B], 1);
    diag_expect("diagnostics 14 clear overrun counter", 0x14, d, 1, d, 1);
    diag_expect("diagnostics 12 after 14 is 0", 0x12, d, 1, d, 1);
    /* Get statistics: the operation word and the statistics. The seeds mark 0x15 as
     * reserved; Modbus Plus devices send 54 statistics words, pymodbus 3.16.1 sends 55
     * (its table has two bytes too many). The client must return whatever came: 56. */
    d[0] = 0x0003;
    memset(w, 0, sizeof(w));
    w[0] = 0x0003;
    if (rtu_framing) {
        /* Nothing in an RTU frame tells the length of a reserved sub-function's answer. */
        printf("skip - diagnostics 15 (reserved sub-function): no length in RTU frames\n");
    } else {
        diag_expect("diagnostics 15 get Modbus Plus statistics (1 + 55 words)", 0x15, d, 1, w,
                    56);
        d[0] = 0x0004; /* clear statistics */
        diag_expect("diagnostics 15 clear Modbus Plus statistics", 0x15, d, 1, d, 1);
    }

    /* Force Listen Only Mode: no answer, the device stays silent until restart. */
    d[0] = 0;
    if (io_rc("diagnostics 04 force listen only mode (no answer)",
              modbus_diagnostics(ctx, 0x04, d, 1, NULL, 0), 0)) {
        uint32_t s, us;
        int rc;
        io_ok("diagnostics 04 force listen only mode (no answer)");
        /* pymodbus 3.16.1 decodes one frame per arrival of data: a request sent right
         * behind one that got no answer waits in its buffer for the next one. Wait. */
        usleep(300000);
        modbus_get_response_timeout(ctx, &s, &us);
        modbus_set_response_timeout(ctx, 0, 400000);
        rc = modbus_read_registers(ctx, 0, 1, dest);
        modbus_set_response_timeout(ctx, s, us);
        io_err("listen only: read_registers times out", rc, ETIMEDOUT);
        usleep(300000);
        if (serial) {
            modbus_flush(ctx);
        }
        /* Restart is the way out, and gets no answer in listen only mode either: send it
         * raw (modbus_diagnostics would wait for an answer). */
        {
            const uint8_t restart[] = {IO_SLAVE, 0x08, 0x00, 0x01, 0x00, 0x00};
            if (modbus_send_raw_request(ctx, restart, sizeof(restart)) == -1) {
                io_fail("diagnostics 01 restart (raw) in listen only mode", "send: %s",
                        modbus_strerror(errno));
            } else {
                io_ok("diagnostics 01 restart (raw) in listen only mode");
            }
        }
        usleep(300000);
        modbus_flush(ctx);
        if (io_rc("read_registers after restart", modbus_read_registers(ctx, 0, 1, dest), 1)) {
            io_ok("read_registers after restart");
        }
    }

    /* Clear counters last: the counters read 0 afterwards. */
    d[0] = 0;
    diag_expect("diagnostics 0A clear counters", 0x0A, d, 1, d, 1);
    diag_expect("diagnostics 0B after clear is 0", 0x0B, d, 1, d, 1);
    diag_expect("diagnostics 02 after clear is 0", 0x02, d, 1, d, 1);
}

static void t_comm_events(void)
{
    uint16_t st = 0xEEEE, ev = 0xEEEE, msg = 0xEEEE;
    uint8_t events[64];
    int rc;
    if (io_rc("get_comm_event_counter", modbus_get_comm_event_counter(ctx, &st, &ev), 1)) {
        if (st == 0x0000 && ev == IO_EVENT_COUNT) {
            io_ok("get_comm_event_counter");
        } else {
            io_fail("get_comm_event_counter", "status 0x%04X count 0x%04X, expected 0 0x%04X",
                    st, ev, IO_EVENT_COUNT);
        }
    }
    st = ev = msg = 0xEEEE;
    memset(events, 0xEE, sizeof(events));
    rc = modbus_get_comm_event_log(ctx, &st, &ev, &msg, events, 64);
    if (io_rc("get_comm_event_log", rc, IO_NB_EVENTS)) {
        if (st == 0 && ev == IO_EVENT_COUNT && msg == io_counters[0] &&
            memcmp(events, io_events, IO_NB_EVENTS) == 0 && events[IO_NB_EVENTS] == 0xEE) {
            io_ok("get_comm_event_log");
        } else {
            io_fail("get_comm_event_log",
                    "status 0x%04X events 0x%04X messages 0x%04X log %02X %02X %02X %02X %02X",
                    st, ev, msg, events[0], events[1], events[2], events[3], events[4]);
        }
    }
    /* max_events smaller than the log: copies 2, still returns the number sent */
    memset(events, 0xEE, sizeof(events));
    rc = modbus_get_comm_event_log(ctx, NULL, NULL, NULL, events, 2);
    if (io_rc("get_comm_event_log(max 2)", rc, IO_NB_EVENTS)) {
        if (events[0] == io_events[0] && events[1] == io_events[1] && events[2] == 0xEE) {
            io_ok("get_comm_event_log(max 2)");
        } else {
            io_fail("get_comm_event_log(max 2)", "copied past max_events or wrong bytes");
        }
    }
}

static void t_file_records(void)
{
    uint16_t regs[130], src[130];
    char name[96];
    int files[] = {1, 3, 2};
    int records[] = {2, 9990, 0};
    int nbs[] = {3, 10, 124};
    for (int k = 0; k < 3; k++) {
        snprintf(name, sizeof(name), "read_file_record(file %d, record %d, %d)", files[k],
                 records[k], nbs[k]);
        memset(regs, 0xEE, sizeof(regs));
        if (io_rc(name, modbus_read_file_record(ctx, files[k], records[k], nbs[k], regs),
                  nbs[k])) {
            int bad = -1;
            for (int i = 0; i < nbs[k] && bad < 0; i++) {
                if (regs[i] != io_file_reg(files[k], records[k] + i)) {
                    bad = i;
                }
            }
            if (bad < 0 && regs[nbs[k]] != 0xEEEE) {
                io_fail(name, "wrote past nb");
            } else if (bad >= 0) {
                io_fail(name, "register %d is 0x%04X, expected 0x%04X", bad, regs[bad],
                        io_file_reg(files[k], records[k] + bad));
            } else {
                io_ok(name);
            }
        }
    }
    for (int i = 0; i < 122; i++) {
        src[i] = (uint16_t) (0xC000 + i);
    }
    if (io_rc("write_file_record(file 2, record 100, 5)",
              modbus_write_file_record(ctx, 2, 100, 5, src), 5) &&
        io_rc("read back file 2 record 99..106", modbus_read_file_record(ctx, 2, 99, 7, regs),
              7)) {
        uint16_t want[7] = {io_file_reg(2, 99), src[0], src[1], src[2], src[3], src[4],
                            io_file_reg(2, 105)};
        if (memcmp(want, regs, sizeof(want)) == 0) {
            io_ok("write_file_record + read back");
        } else {
            io_fail("write_file_record + read back", "registers differ");
        }
    }
    if (io_rc("write_file_record(file 3, record 0, 122)",
              modbus_write_file_record(ctx, 3, 0, 122, src), 122) &&
        io_rc("read back file 3 record 0..121", modbus_read_file_record(ctx, 3, 0, 122, regs),
              122)) {
        if (memcmp(src, regs, 122 * sizeof(uint16_t)) == 0) {
            io_ok("write_file_record(122) + read back");
        } else {
            io_fail("write_file_record(122) + read back", "registers differ");
        }
    }
    io_err("read_file_record(file 9) -> illegal data address",
           modbus_read_file_record(ctx, 9, 0, 1, regs), EMBXILADD);
    io_err("write_file_record(file 9) -> illegal data address",
           modbus_write_file_record(ctx, 9, 0, 1, src), EMBXILADD);
}

static void t_fifo(void)
{
    uint16_t q[31];
    memset(q, 0xEE, sizeof(q));
    if (io_rc("read_fifo_queue(0x04DE)", modbus_read_fifo_queue(ctx, 0x04DE, q), 2)) {
        if (q[0] == 0x01B8 && q[1] == 0x1284 && q[2] == 0xEEEE) {
            io_ok("read_fifo_queue(0x04DE)");
        } else {
            io_fail("read_fifo_queue(0x04DE)", "got %04X %04X", q[0], q[1]);
        }
    }
    if (io_rc("read_fifo_queue(5) 31 values", modbus_read_fifo_queue(ctx, 5, q), 31)) {
        int bad = -1;
        for (int i = 0; i < 31 && bad < 0; i++) {
            if (q[i] != (uint16_t) (i * 11)) {
                bad = i;
            }
        }
        if (bad < 0) {
            io_ok("read_fifo_queue(5) 31 values");
        } else {
            io_fail("read_fifo_queue(5) 31 values", "value %d is 0x%04X", bad, q[bad]);
        }
    }
    if (io_rc("read_fifo_queue(6) empty", modbus_read_fifo_queue(ctx, 6, q), 0)) {
        io_ok("read_fifo_queue(6) empty");
    }
    io_err("read_fifo_queue(7) -> illegal data address", modbus_read_fifo_queue(ctx, 7, q),
           EMBXILADD);
}

static void expected_object(int id, char *out, size_t n)
{
    if (id < 7) {
        snprintf(out, n, "%s", io_device_id_regular[id]);
    } else {
        snprintf(out, n, "extended-object-%02d-xxxxxxxx", id - 0x80);
    }
}

static void check_objects(const char *name, const modbus_device_id_object_t *o, int n,
                          const int *ids)
{
    char want[300];
    for (int i = 0; i < n; i++) {
        expected_object(ids[i], want, sizeof(want));
        if (o[i].id != ids[i] || o[i].length != strlen(want) ||
            memcmp(o[i].value, want, o[i].length) != 0 || o[i].value[o[i].length] != '\0') {
            io_fail(name, "object %d: id 0x%02X length %d '%s', expected id 0x%02X '%s'", i,
                    o[i].id, o[i].length, o[i].value, ids[i], want);
            return;
        }
    }
    io_ok(name);
}

static void t_device_id(void)
{
    static modbus_device_id_object_t o[64];
    int ids[64];
    int conf = -1, rc;

    for (int i = 0; i < 7; i++) {
        ids[i] = i;
    }
    for (int i = 0; i < IO_NB_EXTENDED; i++) {
        ids[7 + i] = 0x80 + i;
    }
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_BASIC, 0, o, 64, &conf);
    if (io_rc("device id basic", rc, 3)) {
        check_objects("device id basic", o, 3, ids);
        if (conf == 0x83) {
            io_ok("device id conformity level 0x83");
        } else {
            io_fail("device id conformity level 0x83", "got 0x%02X", conf);
        }
    }
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_REGULAR, 0, o, 64, NULL);
    if (io_rc("device id regular", rc, 7)) {
        check_objects("device id regular", o, 7, ids);
    }
    /* 23 objects do not fit one response: pymodbus sets "more follows" */
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, o, 64, NULL);
    if (io_rc("device id extended (more follows)", rc, 7 + IO_NB_EXTENDED)) {
        check_objects("device id extended (more follows)", o, 7 + IO_NB_EXTENDED, ids);
    }
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_EXTENDED, 0, o, 10, NULL);
    if (io_rc("device id extended, max_objects 10", rc, 10)) {
        check_objects("device id extended, max_objects 10", o, 10, ids);
    }
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x85, o, 64, NULL);
    if (io_rc("device id specific 0x85", rc, 1)) {
        check_objects("device id specific 0x85", o, 1, &ids[7 + 5]);
    }
    rc = modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x04, o, 64, NULL);
    if (io_rc("device id specific 0x04", rc, 1)) {
        check_objects("device id specific 0x04", o, 1, &ids[4]);
    }
    io_err("device id specific 0x20 -> illegal data address",
           modbus_read_device_identification(ctx, MODBUS_DEVICE_ID_SPECIFIC, 0x20, o, 64, NULL),
           EMBXILADD);
}

/* Raw requests of the new codes come back whole through modbus_receive_confirmation. */
static void t_raw(void)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    int h = modbus_get_header_length(ctx);
    int rc;
    /* FC 14 with two sub-requests: file 1 record 4 x2, file 1 record 50 x1 */
    const uint8_t req14[] = {IO_SLAVE, 0x14, 14, 6, 0, 1, 0, 4, 0, 2, 6, 0, 1, 0, 50, 0, 1};
    const uint8_t req2b[] = {IO_SLAVE, 0x2B, 0x0E, 0x04, 0x81};
    uint16_t r1a = io_file_reg(1, 4), r1b = io_file_reg(1, 5), r3 = io_file_reg(1, 50);
    const uint8_t want14[] = {0x14, 10, 5, 6, (uint8_t) (r1a >> 8), (uint8_t) r1a,
                              (uint8_t) (r1b >> 8), (uint8_t) r1b, 3, 6, (uint8_t) (r3 >> 8),
                              (uint8_t) r3};
    const uint8_t want2b[] = {0x2B, 0x0E, 0x04, 0x83, 0x00, 0x00, 0x01, 0x81, 27};
    int crc = h == 7 ? 0 : ascii ? 1 : 2; /* MBAP: none; ASCII: LRC; RTU: CRC */
    int len14 = h + (int) sizeof(want14) + crc;

    if (modbus_send_raw_request(ctx, req14, sizeof(req14)) < 0) {
        io_fail("raw FC 14, two sub-requests", "send: %s", modbus_strerror(errno));
    } else {
        rc = modbus_receive_confirmation(ctx, rsp);
        if (rc != len14) {
            io_fail("raw FC 14, two sub-requests", "receive_confirmation %d, expected %d (%s)",
                    rc, len14, rc < 0 ? modbus_strerror(errno) : "length");
        } else if (memcmp(rsp + h, want14, sizeof(want14)) != 0) {
            io_fail("raw FC 14, two sub-requests", "got %s", io_hex(rsp, rc));
        } else {
            io_ok("raw FC 14, two sub-requests");
        }
    }
    if (modbus_send_raw_request(ctx, req2b, sizeof(req2b)) < 0) {
        io_fail("raw FC 2B/0E specific 0x81", "send: %s", modbus_strerror(errno));
    } else {
        int want_len = h + (int) sizeof(want2b) + 27 + crc;
        rc = modbus_receive_confirmation(ctx, rsp);
        if (rc != want_len) {
            io_fail("raw FC 2B/0E specific 0x81", "receive_confirmation %d, expected %d (%s)", rc,
                    want_len, rc < 0 ? modbus_strerror(errno) : "length");
        } else if (memcmp(rsp + h, want2b, sizeof(want2b)) != 0 ||
                   memcmp(rsp + h + sizeof(want2b), "extended-object-01-xxxxxxxx", 27) != 0) {
            io_fail("raw FC 2B/0E specific 0x81", "got %s", io_hex(rsp, rc));
        } else {
            io_ok("raw FC 2B/0E specific 0x81");
        }
    }
}

/* Against pm_echo.py (a peer that sends each request back): Return Query Data with 1, 3,
 * 10 and 125 data words must come back whole, whatever the framing. */
static void t_echo(void)
{
    uint16_t d[125];
    int nbs[] = {1, 3, 10, 125};
    for (int i = 0; i < 125; i++) {
        d[i] = (uint16_t) (0x0101 * (i + 1));
    }
    for (int k = 0; k < 4; k++) {
        char name[80];
        snprintf(name, sizeof(name), "diagnostics 00 echo of %d words", nbs[k]);
        diag_expect(name, 0x00, d, nbs[k], d, nbs[k]);
        modbus_flush(ctx);
    }
}

int main(int argc, char **argv)
{
    const char *only = getenv("INTEROP_ONLY");
    if (argc < 3) {
        fprintf(stderr, "usage: %s TRANSPORT WHERE\n", argv[0]);
        return 2;
    }
    if (!io_print_loaded()) {
        fprintf(stderr, "not rsmodbus: refusing to run\n");
        return 97;
    }
    ctx = io_new_ctx(argv[1], argv[2]);
    if (ctx == NULL) {
        return 2;
    }
    serial = io_is_serial(argv[1]);
    ascii = strncmp(argv[1], "ascii", 5) == 0;
    rtu_framing = strncmp(argv[1], "rtu", 3) == 0;
    modbus_set_slave(ctx, IO_SLAVE);
    modbus_set_response_timeout(ctx, 2, 0);
    if (getenv("INTEROP_DEBUG") != NULL) {
        modbus_set_debug(ctx, 1);
    }
    if (modbus_connect(ctx) == -1) {
        io_fail("connect", "%s", modbus_strerror(errno));
        return io_summary();
    }
    if (serial) {
        usleep(200000); /* let the pty settle */
        modbus_flush(ctx);
    }
#define RUN(f)                                                                          \
    do {                                                                                \
        if (only == NULL || strstr(#f, only) != NULL) {                                 \
            f();                                                                        \
        }                                                                               \
    } while (0)
    if (only != NULL && strcmp(only, "t_echo") == 0) {
        t_echo();
        only = "none";
    }
    RUN(t_read_bits);
    RUN(t_read_input_bits);
    RUN(t_read_registers);
    RUN(t_writes);
    RUN(t_report_slave_id);
    RUN(t_exceptions);
    RUN(t_exception_status);
    RUN(t_comm_events);
    RUN(t_file_records);
    RUN(t_fifo);
    RUN(t_device_id);
    RUN(t_raw);
    RUN(t_diagnostics);
    modbus_close(ctx);
    modbus_free(ctx);
    return io_summary();
}
