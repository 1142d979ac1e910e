/* A Modbus/TCP Security server for thousands of clients from one thread: the
 * server that runs itself (modbus_server_new(3)) over a TLS context, answering
 * through callbacks with live values, and tls-server.c's role policy:
 *   - "Operator" may read and write everything;
 *   - "Reader" may only read (FC 01-04);
 *   - any other role, or none, is refused (exception 01, ILLEGAL FUNCTION).
 *
 * Holding register i starts at 1000 + i; input register 0 is the seconds since the
 * start, input register 1 the requests answered so far. A client that sends no
 * whole request for 30 s (or stalls its TLS handshake) is closed; the others never
 * wait for it.
 *
 * Usage: server-many CA_PEM CERT_PEM KEY_PEM [port [max_requests]]
 *        (default port 8802; max_requests 0 = serve until SIGINT or SIGTERM)
 *
 * Build: gcc server-many.c -o server-many $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <modbus.h>

#define NB 100

static struct {
    uint16_t registers[NB];
    uint8_t coils[NB];
    time_t started;
    long answered;
} data;

static modbus_server_t *server;
static volatile sig_atomic_t stopping;

static void on_signal(int sig)
{
    (void)sig;
    stopping = 1;
    modbus_server_stop(server); /* async-signal-safe */
}

/* The role policy: 1 allows the request, 0 refuses it. */
static int authorize(modbus_t *ctx, const char *role, int unit_id, int function, int address, int nb,
                     void *user_data)
{
    (void)ctx;
    (void)unit_id;
    (void)address;
    (void)nb;
    (void)user_data;
    if (role == NULL)
        return 0;
    if (strcmp(role, "Operator") == 0)
        return 1;
    if (strcmp(role, "Reader") == 0)
        return function >= MODBUS_FC_READ_COILS && function <= MODBUS_FC_READ_INPUT_REGISTERS;
    return 0;
}

static int in_range(int addr, int nb)
{
    return addr >= 0 && addr + nb <= NB;
}

static int read_bits(const modbus_request_info_t *ri, int addr, int nb, uint8_t *dest, void *ud)
{
    (void)ud;
    (void)ri;
    if (!in_range(addr, nb))
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    memcpy(dest, data.coils + addr, (size_t)nb);
    data.answered++;
    return 0;
}

static int read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *ud)
{
    (void)ud;
    if (!in_range(addr, nb))
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    if (ri->function == MODBUS_FC_READ_INPUT_REGISTERS) {
        uint16_t live[NB] = {0};
        live[0] = (uint16_t)(time(NULL) - data.started);
        live[1] = (uint16_t)data.answered;
        memcpy(dest, live + addr, (size_t)nb * 2);
    } else {
        memcpy(dest, data.registers + addr, (size_t)nb * 2);
    }
    data.answered++;
    return 0;
}

static int write_bits(const modbus_request_info_t *ri, int addr, int nb, const uint8_t *src, void *ud)
{
    (void)ud;
    (void)ri;
    if (!in_range(addr, nb))
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    memcpy(data.coils + addr, src, (size_t)nb);
    data.answered++;
    return 0;
}

static int write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src, void *ud)
{
    (void)ud;
    (void)ri;
    if (!in_range(addr, nb))
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    memcpy(data.registers + addr, src, (size_t)nb * 2);
    data.answered++;
    return 0;
}

int main(int argc, char *argv[])
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s CA_PEM CERT_PEM KEY_PEM [port [max_requests]]\n", argv[0]);
        return EXIT_FAILURE;
    }
    const char *port = argc > 4 ? argv[4] : "8802";
    long max_requests = argc > 5 ? atol(argv[5]) : 0;
    long served = 0;
    modbus_server_callbacks_t cb;

    for (int i = 0; i < NB; i++)
        data.registers[i] = (uint16_t)(1000 + i);
    data.started = time(NULL);

    modbus_t *ctx = modbus_new_tcp_tls_pi("127.0.0.1", port);
    if (ctx == NULL) {
        fprintf(stderr, "setup failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    if (modbus_set_tls_ca(ctx, argv[1]) == -1 || modbus_set_tls_certificate(ctx, argv[2], argv[3]) == -1 ||
        modbus_set_tls_authorization(ctx, authorize, NULL) == -1) {
        fprintf(stderr, "TLS setup failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    server = modbus_server_new(ctx, 10000);
    if (server == NULL) {
        fprintf(stderr, "server failed: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    memset(&cb, 0, sizeof cb);
    cb.struct_size = sizeof cb;
    cb.read_bits = read_bits;
    cb.read_registers = read_registers;
    cb.write_bits = write_bits;
    cb.write_registers = write_registers;
    modbus_server_set_callbacks(server, &cb, NULL);
    modbus_server_set_idle_timeout(server, 30, 0);
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    printf("serving Modbus/TCP Security on 127.0.0.1 port %s\n", port);
    fflush(stdout);

    for (;;) {
        /* In steps of a second, to count; -1 would run until modbus_server_stop(). */
        int rc = modbus_server_run(server, max_requests > 0 ? 1000 : -1);
        if (rc == -1) {
            fprintf(stderr, "run failed: %s\n", modbus_strerror(errno));
            break;
        }
        served += rc;
        if (stopping || max_requests == 0 || served >= max_requests)
            break;
    }
    modbus_server_free(server);
    modbus_free(ctx);
    printf("server done after %ld requests\n", served);
    return EXIT_SUCCESS;
}
