/* A Modbus TCP client: reads and writes a few registers and coils and prints what
 * it exchanged. Usage: tcp-client [host [port]] (default 127.0.0.1 1502).
 *
 * Build: gcc tcp-client.c -o tcp-client $(pkg-config --cflags --libs libmodbus)
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
    const char *host = argc > 1 ? argv[1] : "127.0.0.1";
    int port = argc > 2 ? atoi(argv[2]) : 1502;
    uint16_t regs[10];
    uint8_t coils[8];
    const uint16_t values[3] = {0x1234, 0xBEEF, 42};
    int i, rc;

    modbus_t *ctx = modbus_new_tcp(host, port);
    if (ctx == NULL) {
        fprintf(stderr, "modbus_new_tcp: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    /* Print every frame sent ([..]) and received (<..>). */
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

    if (modbus_write_bit(ctx, 3, ON) != 1)
        return fail("write_bit", ctx);
    rc = modbus_read_bits(ctx, 0, 8, coils);
    if (rc != 8)
        return fail("read_bits", ctx);
    printf("coils 0..7:");
    for (i = 0; i < rc; i++)
        printf(" %d", coils[i]);
    printf("\n");

    /* Reading past the server's table gives a Modbus exception, reported as errno. */
    rc = modbus_read_registers(ctx, 9999, 1, regs);
    printf("read at 9999: rc=%d (%s)\n", rc, rc == -1 ? modbus_strerror(errno) : "ok");

    modbus_close(ctx);
    modbus_free(ctx);
    printf("client done\n");
    return EXIT_SUCCESS;
}
