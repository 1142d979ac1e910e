/*
 * Scenario "rtu": RTU-only behaviour over a pty pair (pty-relay): open errors, baud
 * rates, serial mode and RTS on a pty, a custom RTS callback, broadcast, other slaves.
 *   scn-rtu rtu <device> <slave> <auxport>
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>

#include "../common/mbtest.h"

static void custom_rts(modbus_t *ctx, int on)
{
    (void) ctx;
    printf("custom_rts(on=%d)\n", on);
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    const char *dev;
    int slave;
    uint16_t regs[4];
    uint8_t rsp[MODBUS_RTU_MAX_ADU_LENGTH];
    int rc;

    if (argc < 4 || strcmp(argv[1], "rtu") != 0) {
        fprintf(stderr, "usage: %s rtu <device> <slave> [aux]\n", argv[0]);
        return 1;
    }
    dev = argv[2];
    slave = atoi(argv[3]);

    mbt_section("open errors");
    CHECK_PTR(ctx, modbus_new_rtu("/nonexistent/tty", 115200, 'N', 8, 1));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    CHECK(modbus_get_socket(ctx));
    CALL(modbus_free(ctx));

    mbt_section("baud rates and framing");
    {
        static const int bauds[] = {9600, 19200, 38400, 57600, 230400, 14400, 1800};
        unsigned int i;
        for (i = 0; i < sizeof(bauds) / sizeof(bauds[0]); i++) {
            printf("-- baud %d\n", bauds[i]);
            CHECK_PTR(ctx, modbus_new_rtu(dev, bauds[i], 'E', 8, 1));
            CHECK(modbus_set_slave(ctx, slave));
            CHECK(modbus_set_debug(ctx, TRUE));
            CHECK(modbus_rtu_get_rts_delay(ctx));
            CHECK(modbus_connect(ctx));
            mbt_read_two(ctx);
            CALL(modbus_close(ctx));
            CALL(modbus_free(ctx));
        }
        CHECK_PTR(ctx, modbus_new_rtu(dev, 115200, 'O', 7, 2));
        CHECK(modbus_set_slave(ctx, slave));
        CHECK(modbus_connect(ctx));
        mbt_read_two(ctx);
        CALL(modbus_close(ctx));
        CALL(modbus_free(ctx));
    }

    CHECK_PTR(ctx, modbus_new_rtu(dev, 115200, 'N', 8, 1));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_set_response_timeout(ctx, 0, 300000));

    mbt_section("serial mode and RTS on a pty");
    CHECK(modbus_set_slave(ctx, slave));
    CHECK(modbus_connect(ctx));
    CHECK_ERRNO(modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS485));
    CHECK(modbus_rtu_get_serial_mode(ctx));
    CHECK(modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS232));
    CHECK(modbus_rtu_get_serial_mode(ctx));
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_UP));
    CHECK(modbus_rtu_get_rts(ctx));
    mbt_read_two(ctx);
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_DOWN));
    mbt_read_two(ctx);

    mbt_section("custom RTS callback");
    CHECK(modbus_rtu_set_custom_rts(ctx, custom_rts));
    CHECK(modbus_rtu_set_rts_delay(ctx, 1000));
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_UP));
    mbt_read_two(ctx);
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_DOWN));
    mbt_read_two(ctx);
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_NONE));
    mbt_read_two(ctx);

    mbt_section("another slave: no reply");
    CHECK(modbus_set_slave(ctx, slave + 1));
    CHECK(modbus_read_registers(ctx, 0, 2, regs));
    CHECK(modbus_set_slave(ctx, slave));

    mbt_section("broadcast: the server writes but does not reply; the client times out");
    CHECK(modbus_set_slave(ctx, MODBUS_BROADCAST_ADDRESS));
    CHECK(modbus_write_register(ctx, 50, 0x5555));
    CHECK(modbus_read_registers(ctx, 50, 1, regs));
    CHECK(modbus_set_slave(ctx, slave));
    CHECK_RC(rc, modbus_read_registers(ctx, 50, 1, regs));
    mbt_dump_u16("register 50", regs, rc > 0 ? rc : 0);

    mbt_section("raw request for another slave, then a reply-looking frame");
    {
        uint8_t req[] = {(uint8_t) (slave + 1), 0x03, 0x00, 0x01, 0x00, 0x01};
        uint8_t fake_rsp[] = {(uint8_t) (slave + 1), 0x03, 0x02, 0x12, 0x34};
        CHECK(modbus_send_raw_request(ctx, req, sizeof(req)));
        CHECK(modbus_send_raw_request(ctx, fake_rsp, sizeof(fake_rsp)));
        CHECK_RC(rc, modbus_receive_confirmation(ctx, rsp));
        mbt_dump_u8("confirmation", rsp, rc > 0 ? rc : 0);
        mbt_read_two(ctx);
    }

    mbt_section("flush");
    CHECK(modbus_flush(ctx));
    CALL(modbus_close(ctx));
    CHECK(modbus_flush(ctx));
    CALL(modbus_free(ctx));
    printf("END\n");
    return 0;
}
