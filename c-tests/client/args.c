/*
 * Scenario "args": invalid arguments to the client calls (limits, nb < 1, NULL
 * buffers, raw request lengths, unconnected contexts), with the debug trace on.
 * Backends: tcp, rtu.
 *
 * Calls whose wire traffic differs between 3.1.6 and 3.1.12 run on a scratch context
 * inside a named DIFF block, so that the main context's TID sequence stays identical.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include "../common/mbtest.h"

static int g_argc;
static char **g_argv;

/* A second connection to the same server, traced (inside a DIFF block). */
static modbus_t *scratch(void)
{
    char backend;
    modbus_t *ctx = mbt_ctx_from_args(g_argc, g_argv, &backend);
    if (ctx == NULL) {
        exit(3);
    }
    modbus_set_debug(ctx, TRUE);
    /* The server sleeps 100 ms and flushes before an ILLEGAL_DATA_VALUE reply. */
    modbus_set_response_timeout(ctx, 1, 0);
    mbt_connect_or_die(ctx);
    return ctx;
}

static void done(modbus_t *ctx)
{
    modbus_close(ctx);
    modbus_free(ctx);
    /* Let the server see this connection go before the next marker arrives. */
    fflush(stdout);
    mbt_msleep(100);
}

struct nb_case {
    const char *label;
    int fn; /* 0 read_bits 1 read_input_bits 2 read_registers 3 read_input_registers
               4 write_bits 5 write_registers */
    int nb;
};

static int call_nb(modbus_t *ctx, int fn, int nb, uint8_t *bits, uint16_t *regs)
{
    switch (fn) {
    case 0: return modbus_read_bits(ctx, 0, nb, bits);
    case 1: return modbus_read_input_bits(ctx, 0, nb, bits);
    case 2: return modbus_read_registers(ctx, 0, nb, regs);
    case 3: return modbus_read_input_registers(ctx, 0, nb, regs);
    case 4: return modbus_write_bits(ctx, 0, nb, bits);
    default: return modbus_write_registers(ctx, 0, nb, regs);
    }
}

/* NULL destination/source: 3.1.6 writes through NULL (crash), 3.1.12 says EINVAL. */
struct null_arg {
    int fn;
};

static void null_child(void *p)
{
    const struct null_arg *a = p;
    modbus_t *ctx = scratch();
    int rc;
    errno = 0;
    switch (a->fn) {
    case 0: rc = modbus_read_bits(ctx, 0, 1, NULL); break;
    case 1: rc = modbus_read_input_bits(ctx, 0, 1, NULL); break;
    case 2: rc = modbus_read_registers(ctx, 0, 1, NULL); break;
    case 3: rc = modbus_read_input_registers(ctx, 0, 1, NULL); break;
    case 4: rc = modbus_write_bits(ctx, 0, 1, NULL); break;
    default: rc = modbus_write_registers(ctx, 0, 1, NULL); break;
    }
    printf("rc=%d errno=%s\n", rc, mbt_errname(errno));
    fflush(stdout);
    done(ctx);
    /* exit status 10 + 1 for EINVAL, for the parent's DIFF-OK line */
    _exit(rc == -1 && errno == EINVAL ? 11 : 10);
}

static void unconnected_child(void *p)
{
    uint8_t rsp[MODBUS_TCP_MAX_ADU_LENGTH];
    modbus_t *ctx;
    char backend;
    int rc;
    (void) p;
    ctx = mbt_ctx_from_args(g_argc, g_argv, &backend);
    modbus_set_debug(ctx, TRUE);
    modbus_set_response_timeout(ctx, 0, 100000);
    errno = 0;
    rc = modbus_receive_confirmation(ctx, rsp);
    printf("rc=%d errno=%s\n", rc, mbt_errname(errno));
    fflush(stdout);
    modbus_free(ctx);
    _exit(rc == -1 ? 11 : 10);
}

int main(int argc, char **argv)
{
    char backend;
    modbus_t *ctx;
    uint8_t bits[MODBUS_MAX_READ_BITS + 16];
    uint16_t regs[MODBUS_MAX_READ_REGISTERS + 16];
    uint8_t raw[300];
    uint8_t rsp[MODBUS_TCP_MAX_ADU_LENGTH];
    char got[128];
    unsigned int i;
    int rc;

    g_argc = argc;
    g_argv = argv;
    ctx = mbt_open_scenario(argc, argv, &backend, 0);
    if (ctx == NULL) {
        return 1;
    }
    memset(bits, 0, sizeof(bits));
    memset(regs, 0, sizeof(regs));

    mbt_section("too many data (client-side limits)");
    CHECK(modbus_read_bits(ctx, 0, MODBUS_MAX_READ_BITS + 1, bits));
    CHECK(modbus_read_input_bits(ctx, 0, MODBUS_MAX_READ_BITS + 1, bits));
    CHECK(modbus_read_registers(ctx, 0, MODBUS_MAX_READ_REGISTERS + 1, regs));
    CHECK(modbus_read_input_registers(ctx, 0, MODBUS_MAX_READ_REGISTERS + 1, regs));
    CHECK(modbus_write_bits(ctx, 0, MODBUS_MAX_WRITE_BITS + 1, bits));
    CHECK(modbus_write_registers(ctx, 0, MODBUS_MAX_WRITE_REGISTERS + 1, regs));
    CHECK(modbus_write_and_read_registers(ctx, 0, MODBUS_MAX_WR_WRITE_REGISTERS + 1, regs, 0, 1, regs));
    CHECK(modbus_write_and_read_registers(ctx, 0, 1, regs, 0, MODBUS_MAX_WR_READ_REGISTERS + 1, regs));
    CHECK(modbus_read_bits(ctx, 0, 100000, bits));
    CHECK(modbus_read_registers(ctx, 0, 70000, regs));

    mbt_section("limits accepted by the client, refused by the server");
    /* These go on the wire; the server replies ILLEGAL_DATA_ADDRESS. */
    CHECK(modbus_read_bits(ctx, 0, MODBUS_MAX_READ_BITS, bits));
    CHECK(modbus_read_registers(ctx, 0, MODBUS_MAX_READ_REGISTERS, regs));
    CHECK(modbus_write_bits(ctx, 0, MODBUS_MAX_WRITE_BITS, bits));
    CHECK(modbus_write_registers(ctx, 0, MODBUS_MAX_WRITE_REGISTERS, regs));
    CHECK(modbus_write_and_read_registers(ctx, 0, MODBUS_MAX_WR_WRITE_REGISTERS, regs, 0,
                                          MODBUS_MAX_WR_READ_REGISTERS, regs));

    mbt_section("write_and_read_registers with 0 values (no lower bound in any version)");
    /* The server sleeps 100 ms then flushes before the ILLEGAL_DATA_VALUE reply. */
    CHECK(modbus_write_and_read_registers(ctx, 0, 0, regs, 0, 1, regs));
    CHECK(modbus_write_and_read_registers(ctx, 0, 1, regs, 0, 0, regs));

    mbt_section("nb < 1");
    {
        static const struct nb_case cases[] = {
            {"read_bits nb=0", 0, 0},           {"read_bits nb=-1", 0, -1},
            {"read_input_bits nb=0", 1, 0},     {"read_registers nb=0", 2, 0},
            {"read_registers nb=-1", 2, -1},    {"read_input_registers nb=0", 3, 0},
            {"write_bits nb=0", 4, 0},          {"write_registers nb=0", 5, 0},
            {"write_registers nb=-1", 5, -1},
        };
        for (i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
            modbus_t *s;
            int err;
            char deb[128], ours[128];
            mbt_diff_begin(ctx, "client-nb-lower-bound");
            s = scratch();
            errno = 0;
            rc = call_nb(s, cases[i].fn, cases[i].nb, bits, regs);
            err = errno;
            done(s);
            fflush(stdout);
            mbt_diff_end(ctx, "client-nb-lower-bound");
            snprintf(got, sizeof(got), "%s: %s", cases[i].label,
                     mbt_fmt_rc(deb, sizeof(deb), rc, err));
            /* 3.1.6 sends nb=-1 for write_registers with byte count 0xFE: the server
             * fails with "too many data" and drops the TCP connection (RTU: no reply). */
            snprintf(deb, sizeof(deb), "%s: rc=-1 errno=%s", cases[i].label,
                     (cases[i].fn == 5 && cases[i].nb < 0)
                         ? (backend == 'r' ? "ETIMEDOUT" : "ECONNRESET")
                         : "EMBXILVAL");
            snprintf(ours, sizeof(ours), "%s: rc=-1 errno=EMBMDATA", cases[i].label);
            mbt_diff_value("client-nb-lower-bound", got, deb, ours);
        }
    }

    mbt_section("NULL destination / source");
    for (i = 0; i < 6; i++) {
        struct null_arg a;
        int status;
        a.fn = (int) i;
        mbt_diff_begin(ctx, "null-dest-einval");
        status = mbt_in_child("NULL buffer", null_child, &a);
        mbt_msleep(100);
        mbt_diff_end(ctx, "null-dest-einval");
        snprintf(got, sizeof(got), "fn %u NULL buffer: %s", i,
                 (WIFEXITED(status) && WEXITSTATUS(status) == 11) ? "EINVAL"
                 : WIFSIGNALED(status)                              ? "crash"
                                                                    : "other");
        {
            char deb[64], ours[64];
            snprintf(deb, sizeof(deb), "fn %u NULL buffer: crash", i);
            snprintf(ours, sizeof(ours), "fn %u NULL buffer: EINVAL", i);
            mbt_diff_value("null-dest-einval", got, deb, ours);
        }
    }

    mbt_section("report_slave_id max_dest");
    CHECK(modbus_report_slave_id(ctx, 0, bits));
    CHECK(modbus_report_slave_id(ctx, -1, bits));

    mbt_section("raw request lengths");
    memset(raw, 0, sizeof(raw));
    raw[0] = (backend == 'r') ? (uint8_t) atoi(argv[3]) : 0xFF;
    raw[1] = 0x03;
    raw[5] = 1;
    CHECK(modbus_send_raw_request(ctx, raw, 0));
    CHECK(modbus_send_raw_request(ctx, raw, 1));
    CHECK(modbus_send_raw_request(ctx, raw, -5));
    CHECK(modbus_send_raw_request(ctx, raw, MODBUS_MAX_PDU_LENGTH + 2));
    CHECK(modbus_send_raw_request(ctx, raw, 1000));
    /* Only slave+FC: a 2-byte request for FC03; the server waits for more bytes. */
    {
        uint8_t fc17[] = {raw[0], 0x11};
        CHECK(modbus_send_raw_request(ctx, fc17, 2));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, rsp));
        mbt_dump_u8("confirmation", rsp, rc > 0 ? rc : 0);
    }

    mbt_section("odd values");
    CHECK(modbus_write_bit(ctx, 1, 2));
    CHECK(modbus_write_bit(ctx, 1, -1));
    CHECK_RC(rc, modbus_read_bits(ctx, 0, 3, bits));
    mbt_dump_bits("coils 0..2", bits, 3);
    CHECK(modbus_write_bit(ctx, 1, 0));
    CHECK(modbus_read_registers(ctx, -1, 1, regs));
    CHECK_RC(rc, modbus_read_registers(ctx, 65536 + 3, 1, regs));
    mbt_dump_u16("register 3", regs, 1);
    CHECK(modbus_write_register(ctx, 3, (uint16_t) 0x12345));
    CHECK_RC(rc, modbus_read_registers(ctx, 3, 1, regs));
    mbt_dump_u16("register 3", regs, 1);

    mbt_section("calls on an unconnected context");
    {
        modbus_t *u;
        char b2;
        u = mbt_ctx_from_args(argc, argv, &b2);
        CHECK(modbus_set_debug(u, TRUE));
        CHECK(modbus_read_registers(u, 0, 1, regs));
        CHECK(modbus_write_register(u, 0, 1));
        CHECK(modbus_send_raw_request(u, raw, 6));
        CHECK(modbus_flush(u));
        CALL(modbus_close(u));
        modbus_free(u);
    }
    {
        int status;
        mbt_diff_begin(ctx, "unconnected-receive");
        status = mbt_in_child("receive_confirmation unconnected", unconnected_child, NULL);
        mbt_diff_end(ctx, "unconnected-receive");
        snprintf(got, sizeof(got), "receive_confirmation unconnected: %s",
                 (WIFEXITED(status) && WEXITSTATUS(status) == 11) ? "rc=-1"
                 : WIFSIGNALED(status)                              ? "abort"
                                                                    : "other");
        mbt_diff_value("unconnected-receive", got, "receive_confirmation unconnected: abort",
                       "receive_confirmation unconnected: rc=-1");
    }

    mbt_section("after all that, the main context still works");
    CHECK_RC(rc, modbus_read_registers(ctx, 0, 4, regs));
    mbt_dump_u16("registers 0..3", regs, 4);
    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));
    printf("END\n");
    return 0;
}
