/*
 * Scenario "recovery": modbus_set_error_recovery LINK and PROTOCOL (sleep + flush,
 * reconnect after the peer closed), with the debug trace on. Backends: tcp, rtu.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>

#include "../common/mbtest.h"

int main(int argc, char **argv)
{
    char backend;
    modbus_t *ctx;
    uint16_t regs[8];
    int rc;

    ctx = mbt_open_scenario(argc, argv, &backend, 300000);
    if (ctx == NULL) {
        return 1;
    }
    memset(regs, 0, sizeof(regs));

    mbt_section("PROTOCOL recovery");
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_PROTOCOL));
    /* wrong TID / slave: sleep response timeout, then flush */
    CHECK(modbus_read_registers(ctx, 0x1030, 2, regs));
    /* wrong function code */
    CHECK(modbus_read_registers(ctx, 0x1040, 2, regs));
    /* length mismatch */
    CHECK(modbus_read_registers(ctx, 0x1041, 3, regs));
    /* exceptions do not trigger a flush */
    CHECK(modbus_read_registers(ctx, 0x1006, 1, regs));
    /* reply twice: the stale copy is flushed by the recovery (TCP: TID mismatch) */
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1046, 2, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);
    CHECK_RC(rc, modbus_read_registers(ctx, 8, 2, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);
    mbt_msleep(200);
    CHECK(modbus_flush(ctx));
    /* timeout: PROTOCOL alone does nothing special */
    CHECK(modbus_read_registers(ctx, 0x1045, 1, regs));
    mbt_read_two(ctx);

    mbt_section("LINK recovery");
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_LINK));
    /* timeout: sleep response timeout, then flush */
    CHECK(modbus_read_registers(ctx, 0x1045, 1, regs));
    /* peer closes mid-frame (TCP): the library reconnects by itself */
    CHECK(modbus_read_registers(ctx, 0x1043, 2, regs));
    if (backend == 'r') {
        mbt_msleep(200);
        CHECK(modbus_flush(ctx));
    }
    mbt_read_two(ctx);

    mbt_section("LINK | PROTOCOL");
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_LINK | MODBUS_ERROR_RECOVERY_PROTOCOL));
    CHECK(modbus_read_registers(ctx, 0x1030, 2, regs));
    CHECK_RC(rc, modbus_read_registers(ctx, 1, 2, regs));
    mbt_dump_u16("registers 1..2", regs, rc > 0 ? rc : 0);

    mbt_section("LINK recovery on a closed context (send fails with EBADF)");
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE));
    CALL(modbus_close(ctx));
    CHECK(modbus_read_registers(ctx, 0, 1, regs));
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_LINK));
    /* EBADF: close, sleep, connect, and the send is retried */
    mbt_read_two(ctx);

    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));
    printf("END\n");
    return 0;
}
