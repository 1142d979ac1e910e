/*
 * Scenario "basic": every client call on the happy path, with the debug trace on,
 * against mbtest-server (Debian's libmodbus). Backends: tcp, tcppi, rtu.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>

#include "../common/mbtest.h"

int main(int argc, char **argv)
{
    char backend;
    modbus_t *ctx;
    uint8_t bits[MODBUS_MAX_READ_BITS];
    uint16_t regs[MODBUS_MAX_READ_REGISTERS];
    uint8_t wbits[64];
    uint16_t wregs[MODBUS_MAX_WRITE_REGISTERS];
    uint8_t raw_rsp[MODBUS_TCP_MAX_ADU_LENGTH];
    uint8_t slave_id[64];
    int i, rc;

    ctx = mbt_open_scenario(argc, argv, &backend, 0);
    if (ctx == NULL) {
        return 1;
    }

    mbt_section("reads");
    memset(bits, 0xAA, sizeof(bits));
    CHECK_RC(rc, modbus_read_bits(ctx, 0, 10, bits));
    mbt_dump_bits("coils 0..9", bits, 10);
    CHECK_RC(rc, modbus_read_bits(ctx, 3, 37, bits));
    mbt_dump_bits("coils 3..39", bits, 37);
    CHECK_RC(rc, modbus_read_bits(ctx, 0, 64, bits));
    mbt_dump_bits("coils 0..63", bits, 64);
    CHECK_RC(rc, modbus_read_input_bits(ctx, 0, 22, bits));
    mbt_dump_bits("inputs 0..21", bits, 22);
    CHECK_RC(rc, modbus_read_input_bits(ctx, 60, 4, bits));
    mbt_dump_bits("inputs 60..63", bits, 4);
    memset(regs, 0x55, sizeof(regs));
    CHECK_RC(rc, modbus_read_registers(ctx, 0, 10, regs));
    mbt_dump_u16("registers 0..9", regs, 10);
    CHECK_RC(rc, modbus_read_registers(ctx, 0, MODBUS_MAX_READ_REGISTERS, regs));
    mbt_dump_u16("registers 0..124", regs, MODBUS_MAX_READ_REGISTERS);
    CHECK_RC(rc, modbus_read_input_registers(ctx, 0, 5, regs));
    mbt_dump_u16("input registers 0..4", regs, 5);
    CHECK_RC(rc, modbus_read_input_registers(ctx, 59, 5, regs));
    mbt_dump_u16("input registers 59..63", regs, 5);

    mbt_section("single writes");
    CHECK(modbus_write_bit(ctx, 5, ON));
    CHECK(modbus_write_bit(ctx, 6, OFF));
    CHECK(modbus_write_bit(ctx, 7, 123));
    CHECK_RC(rc, modbus_read_bits(ctx, 0, 10, bits));
    mbt_dump_bits("coils 0..9", bits, 10);
    CHECK(modbus_write_register(ctx, 10, 0xBEEF));
    CHECK(modbus_write_register(ctx, 11, 0));
    CHECK(modbus_write_register(ctx, 127, 0xFFFF));
    CHECK_RC(rc, modbus_read_registers(ctx, 10, 2, regs));
    mbt_dump_u16("registers 10..11", regs, 2);
    CHECK_RC(rc, modbus_read_registers(ctx, 127, 1, regs));
    mbt_dump_u16("register 127", regs, 1);

    mbt_section("multiple writes");
    for (i = 0; i < 64; i++) {
        wbits[i] = (uint8_t) ((i * 5 + 1) % 3 == 0);
    }
    CHECK(modbus_write_bits(ctx, 20, 13, wbits));
    CHECK_RC(rc, modbus_read_bits(ctx, 20, 13, bits));
    mbt_dump_bits("coils 20..32", bits, 13);
    CHECK(modbus_write_bits(ctx, 0, 64, wbits));
    CHECK(modbus_write_bits(ctx, 63, 1, wbits + 2));
    CHECK_RC(rc, modbus_read_bits(ctx, 0, 64, bits));
    mbt_dump_bits("coils 0..63", bits, 64);
    for (i = 0; i < MODBUS_MAX_WRITE_REGISTERS; i++) {
        wregs[i] = (uint16_t) (0x1111 * (i % 15) + i);
    }
    CHECK(modbus_write_registers(ctx, 30, 5, wregs));
    CHECK_RC(rc, modbus_read_registers(ctx, 30, 5, regs));
    mbt_dump_u16("registers 30..34", regs, 5);
    CHECK(modbus_write_registers(ctx, 0, MODBUS_MAX_WRITE_REGISTERS, wregs));
    CHECK_RC(rc, modbus_read_registers(ctx, 0, 125, regs));
    mbt_dump_u16("registers 0..124", regs, 125);
    CHECK(modbus_write_registers(ctx, 127, 1, wregs + 7));

    mbt_section("mask write");
    CHECK(modbus_write_register(ctx, 40, 0x1234));
    CHECK(modbus_mask_write_register(ctx, 40, 0xF0F0, 0x0A0A));
    CHECK_RC(rc, modbus_read_registers(ctx, 40, 1, regs));
    mbt_dump_u16("register 40", regs, 1);
    CHECK(modbus_mask_write_register(ctx, 40, 0x0000, 0xFFFF));
    CHECK(modbus_mask_write_register(ctx, 40, 0xFFFF, 0x0000));
    CHECK_RC(rc, modbus_read_registers(ctx, 40, 1, regs));
    mbt_dump_u16("register 40", regs, 1);

    mbt_section("write and read");
    wregs[0] = 0xAAAA;
    wregs[1] = 0xBBBB;
    wregs[2] = 0xCCCC;
    memset(regs, 0, sizeof(regs));
    CHECK(modbus_write_and_read_registers(ctx, 50, 3, wregs, 48, 8, regs));
    mbt_dump_u16("registers 48..55", regs, 8);
    /* Same buffer for source and destination, like Debian's unit test. */
    regs[0] = 0x0102;
    regs[1] = 0x0304;
    CHECK(modbus_write_and_read_registers(ctx, 60, 2, regs, 60, 4, regs));
    mbt_dump_u16("registers 60..63", regs, 4);
    CHECK(modbus_write_and_read_registers(ctx, 0, MODBUS_MAX_WR_WRITE_REGISTERS, wregs, 0,
                                          MODBUS_MAX_WR_READ_REGISTERS, regs));
    mbt_dump_u16("registers 0..124", regs, MODBUS_MAX_WR_READ_REGISTERS);

    mbt_section("report slave id");
    memset(slave_id, 0xEE, sizeof(slave_id));
    CHECK_RC(rc, modbus_report_slave_id(ctx, sizeof(slave_id), slave_id));
    mbt_dump_u8("slave id", slave_id, 16);
    memset(slave_id, 0xEE, sizeof(slave_id));
    CHECK_RC(rc, modbus_report_slave_id(ctx, 3, slave_id));
    mbt_dump_u8("slave id (max 3)", slave_id, 16);
    memset(slave_id, 0xEE, sizeof(slave_id));
    CHECK_RC(rc, modbus_report_slave_id(ctx, 1, slave_id));
    mbt_dump_u8("slave id (max 1)", slave_id, 4);

    mbt_section("illegal data address exceptions");
    CHECK(modbus_read_bits(ctx, 60, 10, bits));
    CHECK(modbus_read_bits(ctx, 64, 1, bits));
    CHECK(modbus_read_input_bits(ctx, 100, 1, bits));
    CHECK(modbus_read_registers(ctx, 120, 10, regs));
    CHECK(modbus_read_input_registers(ctx, 64, 1, regs));
    CHECK(modbus_write_bit(ctx, 64, ON));
    CHECK(modbus_write_register(ctx, 128, 1));
    CHECK(modbus_write_bits(ctx, 60, 10, wbits));
    CHECK(modbus_write_registers(ctx, 126, 3, wregs));
    CHECK(modbus_mask_write_register(ctx, 128, 1, 2));
    CHECK(modbus_write_and_read_registers(ctx, 126, 3, wregs, 0, 1, regs));
    CHECK(modbus_write_and_read_registers(ctx, 0, 1, wregs, 126, 3, regs));
    CHECK(modbus_read_registers(ctx, 0xFFFF, 1, regs));

    mbt_section("raw requests");
    {
        /* slave byte is ignored by TCP (unit id copied), used by RTU */
        uint8_t slave = (backend == 'r') ? (uint8_t) atoi(argv[3]) : 0xFF;
        uint8_t read_req[] = {slave, 0x03, 0x00, 0x02, 0x00, 0x03};
        uint8_t coils_req[] = {slave, 0x01, 0x00, 0x00, 0x00, 0x0B};
        uint8_t write_req[] = {slave, 0x10, 0x00, 0x44, 0x00, 0x02, 0x04, 0xCA, 0xFE, 0xBA, 0xBE};
        uint8_t rsid_req[] = {slave, 0x11};
        uint8_t badfc_req[] = {slave, 0x42, 0x00, 0x00, 0x00, 0x00};
        uint8_t fc83_req[] = {slave, 0x83, 0x00, 0x00, 0x00, 0x01};

        CHECK(modbus_send_raw_request(ctx, read_req, sizeof(read_req)));
        memset(raw_rsp, 0, sizeof(raw_rsp));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, raw_rsp));
        mbt_dump_u8("confirmation", raw_rsp, rc > 0 ? rc : 0);
        CHECK(modbus_send_raw_request(ctx, coils_req, sizeof(coils_req)));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, raw_rsp));
        mbt_dump_u8("confirmation", raw_rsp, rc > 0 ? rc : 0);
        CHECK(modbus_send_raw_request(ctx, write_req, sizeof(write_req)));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, raw_rsp));
        mbt_dump_u8("confirmation", raw_rsp, rc > 0 ? rc : 0);
        CHECK(modbus_send_raw_request(ctx, rsid_req, sizeof(rsid_req)));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, raw_rsp));
        mbt_dump_u8("confirmation", raw_rsp, rc > 0 ? rc : 0);
        /* Unknown function code: the server sleeps (100 ms) and flushes, then replies. */
        CHECK(modbus_send_raw_request(ctx, badfc_req, sizeof(badfc_req)));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, raw_rsp));
        mbt_dump_u8("confirmation", raw_rsp, rc > 0 ? rc : 0);
        CHECK(modbus_send_raw_request(ctx, fc83_req, sizeof(fc83_req)));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, raw_rsp));
        mbt_dump_u8("confirmation", raw_rsp, rc > 0 ? rc : 0);
        /* A normal call after raw exchanges: the TID sequence is untouched by raw. */
        CHECK_RC(rc, modbus_read_registers(ctx, 0x44, 2, regs));
        mbt_dump_u16("registers 0x44..0x45", regs, 2);
    }

    mbt_section("flush and close");
    CHECK(modbus_flush(ctx));
    CALL(modbus_close(ctx));
    CHECK(modbus_get_socket(ctx));
    mbt_connect_or_die(ctx);
    CHECK_RC(rc, modbus_read_registers(ctx, 10, 1, regs));
    mbt_dump_u16("register 10", regs, 1);
    CALL(modbus_close(ctx));
    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));
    printf("END\n");
    return 0;
}
