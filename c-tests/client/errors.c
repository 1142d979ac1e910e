/*
 * Scenario "errors": malformed, unexpected and exceptional responses from mbtest-server
 * (see the special addresses in c-tests/servers/mbtest-server.c), with the debug trace
 * on and no error recovery. Backends: tcp, rtu.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>

#include "../common/mbtest.h"

static char backend;

/* Wait for any late bytes, then discard them (traced: "Bytes flushed (n)"). */
static void resync(modbus_t *ctx)
{
    mbt_msleep(250);
    CHECK(modbus_flush(ctx));
}

/* A call whose library trace differs by name: masked block, then the result. */
#define BLOCK_CALL(ctx, name, expr)                                                  \
    do {                                                                             \
        int brc_, berr_;                                                             \
        DIFF_BLOCK_RC(ctx, name, brc_, berr_, expr);                                 \
        mbt_report_int(#expr, brc_, berr_);                                          \
    } while (0)

/* A call whose result differs by name: masked block, then a checked DIFF-OK line. */
#define DIFF_CALL(ctx, name, expr, deb, ours)                                        \
    do {                                                                             \
        int brc_, berr_;                                                             \
        char got_[160], r_[64];                                                      \
        DIFF_BLOCK_RC(ctx, name, brc_, berr_, expr);                                 \
        snprintf(got_, sizeof(got_), "%s: %s", #expr,                                \
                 mbt_fmt_rc(r_, sizeof(r_), brc_, berr_));                           \
        mbt_diff_value(name, got_, #expr ": " deb, #expr ": " ours);                 \
    } while (0)

int main(int argc, char **argv)
{
    modbus_t *ctx;
    uint16_t regs[MODBUS_MAX_READ_REGISTERS];
    uint8_t bits[64];
    int code, rc;

    ctx = mbt_open_scenario(argc, argv, &backend, 300000);
    if (ctx == NULL) {
        return 1;
    }
    memset(regs, 0, sizeof(regs));
    memset(bits, 1, sizeof(bits));

    mbt_section("exception codes 0..15");
    for (code = 0; code <= 15; code++) {
        CHECK(modbus_read_registers(ctx, 0x1000 + code, 1, regs));
    }
    CHECK(modbus_read_registers(ctx, 0x1010, 1, regs));
    if (backend == 'r') {
        BLOCK_CALL(ctx, "rtu-crc-debug-value", modbus_read_registers(ctx, 0x1011, 1, regs));
    } else {
        CHECK(modbus_read_registers(ctx, 0x1011, 1, regs));
    }

    mbt_section("wrong transaction id / slave");
    CHECK(modbus_read_registers(ctx, 0x1030, 2, regs));
    resync(ctx);
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1034, 2, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);

    mbt_section("protocol id");
    if (backend == 't') {
        DIFF_CALL(ctx, "protocol-id-check", modbus_read_registers(ctx, 0x1031, 2, regs), "rc=2",
                  "rc=-1 errno=EMBBADDATA");
        DIFF_CALL(ctx, "protocol-id-check", modbus_read_registers(ctx, 0x1033, 2, regs), "rc=2",
                  "rc=-1 errno=EMBBADDATA");
        CHECK(modbus_read_registers(ctx, 0x1032, 2, regs));
    }

    mbt_section("CRC");
    if (backend == 'r') {
        BLOCK_CALL(ctx, "rtu-crc-debug-value", modbus_read_registers(ctx, 0x1035, 2, regs));
        DIFF_CALL(ctx, "rtu-crc-before-slave-filter", modbus_read_registers(ctx, 0x1036, 2, regs),
                  "rc=-1 errno=EMBBADSLAVE", "rc=-1 errno=EMBBADCRC");
    }

    mbt_section("wrong function code, lengths, byte counts");
    CHECK(modbus_read_registers(ctx, 0x1040, 2, regs));
    CHECK(modbus_read_registers(ctx, 0x1041, 3, regs));
    CHECK(modbus_read_registers(ctx, 0x1048, 2, regs));
    CHECK(modbus_read_registers(ctx, 0x1042, 2, regs));
    resync(ctx);
    memset(regs, 0, sizeof(regs)); /* earlier results differ by design (protocol-id-check) */
    CHECK(modbus_write_and_read_registers(ctx, 0, 1, regs, 0x1200, 3, regs));
    CHECK(modbus_write_and_read_registers(ctx, 0, 1, regs, 0x1200, 1, regs));

    mbt_section("garbage");
    if (backend == 'r') {
        DIFF_CALL(ctx, "rtu-crc-before-slave-filter", modbus_read_registers(ctx, 0x1044, 2, regs),
                  "rc=-1 errno=EMBBADSLAVE", "rc=-1 errno=EMBBADCRC");
    } else {
        CHECK(modbus_read_registers(ctx, 0x1044, 2, regs));
    }
    resync(ctx);

    mbt_section("no reply");
    CHECK(modbus_read_registers(ctx, 0x1045, 2, regs));

    mbt_section("reply sent twice: the next call reads the stale copy");
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1046, 2, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);
    memset(regs, 0, sizeof(regs));
    CHECK_RC(rc, modbus_read_registers(ctx, 8, 2, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);
    resync(ctx);

    mbt_section("extra trailing bytes");
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1047, 2, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);
    resync(ctx);

    mbt_section("write echo checks");
    DIFF_CALL(ctx, "write-echo-check", modbus_write_bit(ctx, 0x1200, ON), "rc=1",
              "rc=-1 errno=EMBBADDATA");
    DIFF_CALL(ctx, "write-echo-check", modbus_write_bit(ctx, 0x1201, ON), "rc=1",
              "rc=-1 errno=EMBBADDATA");
    DIFF_CALL(ctx, "write-echo-check", modbus_write_register(ctx, 0x1200, 5), "rc=1",
              "rc=-1 errno=EMBBADDATA");
    DIFF_CALL(ctx, "write-echo-check", modbus_write_register(ctx, 0x1201, 5), "rc=1",
              "rc=-1 errno=EMBBADDATA");
    DIFF_CALL(ctx, "write-echo-check", modbus_write_bits(ctx, 0x1200, 3, bits), "rc=3",
              "rc=-1 errno=EMBBADDATA");
    DIFF_CALL(ctx, "write-echo-check", modbus_write_registers(ctx, 0x1200, 2, regs), "rc=2",
              "rc=-1 errno=EMBBADDATA");
    CHECK(modbus_write_bits(ctx, 0x1201, 3, bits));
    CHECK(modbus_write_registers(ctx, 0x1201, 2, regs));
    CHECK(modbus_mask_write_register(ctx, 0x1200, 0x00FF, 0x1100));

    mbt_section("peer closes mid-frame");
    CHECK(modbus_read_registers(ctx, 0x1043, 2, regs));
    if (backend == 't') {
        /* The connection is gone (no LINK recovery): reconnect by hand. */
        CALL(modbus_close(ctx));
        mbt_msleep(100);
        mbt_connect_or_die(ctx);
    } else {
        resync(ctx);
    }
    CHECK_RC(rc, modbus_read_registers(ctx, 0, 3, regs));
    mbt_dump_u16("registers 0..2", regs, rc > 0 ? rc : 0);

    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));
    printf("END\n");
    return 0;
}
