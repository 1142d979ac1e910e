/* A Modbus/TCP Security client: TLS with its own certificate (the server finds the
 * client's role in it), reading and then writing holding registers.
 *
 * Usage: tls-client CA_PEM CERT_PEM KEY_PEM [host [port [server_name [unit]]]]
 *        (default 127.0.0.1, port 8802; server_name: the name the server's
 *        certificate must carry, when it is a DNS name and host an address ("-":
 *        host itself); unit: the unit id of the requests, default 255)
 *
 * Prints the registers read and whether the write was allowed: with tls-server, a
 * certificate with the role "Operator" may write, "Reader" may not.
 *
 * Build: gcc tls-client.c -o tls-client $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>

#include <modbus.h>

int main(int argc, char *argv[])
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s CA_PEM CERT_PEM KEY_PEM [host [port [server_name [unit]]]]\n", argv[0]);
        return EXIT_FAILURE;
    }
    const char *host = argc > 4 ? argv[4] : "127.0.0.1";
    const char *port = argc > 5 ? argv[5] : "8802";
    const char *server_name = argc > 6 && argv[6][0] != '-' ? argv[6] : NULL;
    int unit = argc > 7 ? atoi(argv[7]) : MODBUS_TCP_SLAVE;
    uint16_t regs[5];

    modbus_t *ctx = modbus_new_tcp_tls_pi(host, port);
    if (ctx == NULL) {
        fprintf(stderr, "cannot create the context: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    /* The CA the server's certificate must chain to, and our own certificate. */
    if (modbus_set_tls_ca(ctx, argv[1]) == -1 || modbus_set_tls_certificate(ctx, argv[2], argv[3]) == -1) {
        fprintf(stderr, "TLS setup failed: %s\n", modbus_strerror(errno));
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    if ((server_name != NULL && modbus_set_tls_server_name(ctx, server_name) == -1) ||
        modbus_set_slave(ctx, unit) == -1) {
        fprintf(stderr, "invalid server name or unit id: %s\n", modbus_strerror(errno));
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    if (modbus_connect(ctx) == -1) {
        /* e.g. EMBTLSUNKNOWNCA, EMBTLSEXPIRED, EMBTLSNAME: modbus_strerror says which. */
        fprintf(stderr, "connection failed: %s\n", modbus_strerror(errno));
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    int rc = modbus_read_registers(ctx, 0, 5, regs);
    if (rc != 5) {
        fprintf(stderr, "read failed: %s\n", modbus_strerror(errno));
        modbus_close(ctx);
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    if (server_name != NULL || argc > 7)
        printf("server %s, unit %d\n", server_name != NULL ? server_name : host, unit);
    printf("registers 0-4: %u %u %u %u %u\n", regs[0], regs[1], regs[2], regs[3], regs[4]);
    if (modbus_write_register(ctx, 0, (uint16_t)(regs[0] + 1)) == 1)
        printf("write allowed\n");
    else if (errno == EMBXILFUN)
        printf("write refused: %s\n", modbus_strerror(errno));
    else
        fprintf(stderr, "write failed: %s\n", modbus_strerror(errno));
    modbus_close(ctx); /* sends close_notify */
    modbus_free(ctx);
    return EXIT_SUCCESS;
}
