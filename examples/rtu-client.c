/* A Modbus RTU client (master) on a serial line: writes and reads registers, coils
 * and a float on one slave, and prints every frame it exchanges.
 *
 * Usage: rtu-client DEVICE [SLAVE_ID [BAUD [PARITY]]]
 *   defaults: slave 17, 19200 baud, parity E (8 data bits, 1 stop bit)
 * Try it with examples/rtu-server on the other end of a pty pair:
 *   socat pty,raw,echo=0,link=/tmp/ttyS pty,raw,echo=0,link=/tmp/ttyC &
 *   ./rtu-server /tmp/ttyS & ./rtu-client /tmp/ttyC
 *
 * Build: gcc rtu-client.c -o rtu-client $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>

#include <modbus.h>

static int fail(const char *what, modbus_t *ctx)
{
    fprintf(stderr, "%s failed: %s\n", what, modbus_strerror(errno));
    modbus_close(ctx);
    modbus_free(ctx);
    return EXIT_FAILURE;
}

int main(int argc, char *argv[])
{
    if (argc < 2) {
        fprintf(stderr, "usage: %s DEVICE [SLAVE_ID [BAUD [PARITY]]]\n", argv[0]);
        return EXIT_FAILURE;
    }
    const char *device = argv[1];
    int slave = argc > 2 ? atoi(argv[2]) : 17;
    int baud = argc > 3 ? atoi(argv[3]) : 19200;
    char parity = argc > 4 ? argv[4][0] : 'E';
    const uint16_t values[3] = {0x1234, 0xBEEF, 42};
    uint16_t regs[10];
    uint8_t coils[8];
    int i, rc;

    modbus_t *ctx = modbus_new_rtu(device, baud, parity, 8, 1);
    if (ctx == NULL) {
        fprintf(stderr, "modbus_new_rtu: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    /* Every RTU request names the slave it is for: set it before the first call. */
    if (modbus_set_slave(ctx, slave) == -1)
        return fail("set_slave", ctx);
    /* Wait up to one second for each reply (the default is 0.5 s). */
    modbus_set_response_timeout(ctx, 1, 0);
    /* Print every frame sent ([..]) and received (<..>), CRC included. */
    modbus_set_debug(ctx, TRUE);
    if (modbus_connect(ctx) == -1)
        return fail("connect", ctx);

    rc = modbus_write_registers(ctx, 0, 3, values);
    if (rc != 3)
        return fail("write_registers", ctx);
    printf("wrote 3 registers at 0\n");

    rc = modbus_read_registers(ctx, 0, 10, regs);
    if (rc != 10)
        return fail("read_registers", ctx);
    printf("registers 0..9:");
    for (i = 0; i < rc; i++)
        printf(" 0x%04X", regs[i]);
    printf("\n");

    rc = modbus_read_input_registers(ctx, 0, 4, regs);
    if (rc != 4)
        return fail("read_input_registers", ctx);
    printf("input registers 0..3:");
    for (i = 0; i < rc; i++)
        printf(" %u", regs[i]);
    printf("\n");

    if (modbus_write_bit(ctx, 3, ON) != 1)
        return fail("write_bit", ctx);
    rc = modbus_read_bits(ctx, 0, 8, coils);
    if (rc != 8)
        return fail("read_bits", ctx);
    printf("coils 0..7:");
    for (i = 0; i < rc; i++)
        printf(" %d", coils[i]);
    printf("\n");

    /* A float travels in two registers; "abcd" is big-endian, the usual order. */
    modbus_set_float_abcd(21.5f, regs);
    if (modbus_write_registers(ctx, 20, 2, regs) != 2)
        return fail("write float", ctx);
    if (modbus_read_registers(ctx, 20, 2, regs) != 2)
        return fail("read float", ctx);
    printf("float at 20: %.2f (0x%04X 0x%04X)\n", modbus_get_float_abcd(regs), regs[0], regs[1]);

    /* Reading past the server's table gives a Modbus exception, reported as errno. */
    rc = modbus_read_registers(ctx, 9999, 1, regs);
    printf("read at 9999: rc=%d (%s)\n", rc, rc == -1 ? modbus_strerror(errno) : "ok");

    modbus_close(ctx);
    modbus_free(ctx);
    printf("client done\n");
    return EXIT_SUCCESS;
}
