/*
 * our_server: rsmodbus as the SERVER for a pymodbus client (pm_client.py), serving the
 * data of pm_model.py through a modbus_mapping_t and modbus_receive/modbus_reply.
 *
 * usage: our_server TRANSPORT WHERE [IDLE_SECS [--configure]]   (see io_new_ctx; the
 * slave is 17). --configure sets up every new server function (see configure());
 * without it the server is configured for none of them, as a libmodbus server.
 * TCP transports (tcp, rtutcp, their -pi forms) listen and serve one connection after
 * another; serial ones (ascii, ascii7, rtu) serve the line. Prints "READY" once it
 * listens, traces every frame (modbus_set_debug; not with INTEROP_QUIET set), and exits by itself after IDLE_SECS
 * (default 60) without a request.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include "interop.h"

#include <time.h>
#include <unistd.h>

static modbus_mapping_t *new_mapping(void)
{
    modbus_mapping_t *m = modbus_mapping_new(IO_SIZE, IO_SIZE, IO_SIZE, IO_SIZE);
    if (m == NULL) {
        return NULL;
    }
    for (int i = 0; i < IO_SIZE; i++) {
        m->tab_bits[i] = (uint8_t) io_coil(i);
        m->tab_input_bits[i] = (uint8_t) io_discrete(i);
        m->tab_registers[i] = io_holding(i);
        m->tab_input_registers[i] = io_input(i);
    }
    return m;
}

/* --configure: the new server functions, set up with pm_model.py's data. */
static int configure(modbus_t *ctx)
{
    static uint16_t file[10000];
    uint16_t fifo5[31], fifo8[32];
    const uint16_t fifo4de[2] = {0x01B8, 0x1284};
    char ext[64];
    int rc = 0;

    rc |= modbus_enable_diagnostics(ctx, 1);
    rc |= modbus_set_diagnostic_register(ctx, 0x0A02);
    rc |= modbus_set_exception_status(ctx, IO_EXCEPTION_STATUS);
    for (int id = 0; id < 7; id++) {
        rc |= modbus_set_device_identification(ctx, id, io_device_id_regular[id], -1);
    }
    for (int k = 0; k < IO_NB_EXTENDED; k++) {
        snprintf(ext, sizeof(ext), "extended-object-%02d-xxxxxxxx", k);
        rc |= modbus_set_device_identification(ctx, 0x80 + k, ext, -1);
    }
    for (int f = 1; f <= 3; f++) {
        for (int r = 0; r < 10000; r++) {
            file[r] = io_file_reg(f, r);
        }
        rc |= modbus_set_file_record(ctx, f, 0, 10000, file) == 10000 ? 0 : -1;
    }
    for (int i = 0; i < 32; i++) {
        if (i < 31) {
            fifo5[i] = (uint16_t) (i * 11);
        }
        fifo8[i] = (uint16_t) i;
    }
    rc |= modbus_set_fifo_queue(ctx, 0x04DE, fifo4de, 2);
    rc |= modbus_set_fifo_queue(ctx, 5, fifo5, 31);
    rc |= modbus_set_fifo_queue(ctx, 6, NULL, 0);
    rc |= modbus_set_fifo_queue(ctx, 8, fifo8, 32); /* too long: ILLEGAL DATA VALUE */
    rc |= modbus_set_report_slave_id(ctx, 0x42, 1, (const uint8_t *) "rsmodbus-srv", 12);
    if (rc != 0) {
        fprintf(stderr, "configuring the new functions failed: %s\n", modbus_strerror(errno));
        return -1;
    }
    printf("configured: diagnostics, exception status, device identification, files, FIFOs, "
           "report slave id\n");
    return 0;
}

/* Serves requests until the peer goes away or nothing comes for the idle time.
 * Returns 0 on idle timeout, 1 when the connection closed. */
static int serve(modbus_t *ctx, modbus_mapping_t *map, int idle)
{
    uint8_t req[MODBUS_MAX_ADU_LENGTH];
    time_t last = time(NULL);
    for (;;) {
        int rc = modbus_receive(ctx, req);
        if (rc > 0) {
            last = time(NULL);
            modbus_reply(ctx, req, rc, map);
        } else if (rc == -1) {
            int e = errno;
            printf("receive: %s\n", modbus_strerror(e));
            fflush(stdout);
            /* the indication timeout, or the byte timeout inside a broken frame */
            if (e == ETIMEDOUT && time(NULL) - last >= idle) {
                return 0;
            }
            if (e == ECONNRESET || e == EPIPE || e == EBADF || e == ENOTCONN) {
                return 1;
            }
            /* bad CRC, bad data: libmodbus servers go on */
        }
    }
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    modbus_mapping_t *map;
    int idle = argc > 3 ? atoi(argv[3]) : 60;
    int tcp;

    if (argc < 3) {
        fprintf(stderr, "usage: %s TRANSPORT WHERE [IDLE_SECS]\n", argv[0]);
        return 2;
    }
    if (!io_print_loaded()) {
        fprintf(stderr, "not rsmodbus: refusing to run\n");
        return 97;
    }
    ctx = io_new_ctx(argv[1], argv[2]);
    map = new_mapping();
    if (ctx == NULL || map == NULL) {
        return 2;
    }
    tcp = !io_is_serial(argv[1]);
    if (argc > 4 && strcmp(argv[4], "--configure") == 0 && configure(ctx) != 0) {
        return 2;
    }
    modbus_set_slave(ctx, IO_SLAVE);
    if (getenv("INTEROP_QUIET") == NULL) {
        modbus_set_debug(ctx, 1);
    }
    modbus_set_indication_timeout(ctx, (uint32_t) idle, 0);
    if (tcp) {
        int pi = strstr(argv[1], "pi") != NULL;
        int s = pi ? modbus_tcp_pi_listen(ctx, 4) : modbus_tcp_listen(ctx, 4);
        if (s == -1) {
            fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
            return 2;
        }
        printf("READY\n");
        fflush(stdout);
        for (;;) {
            int c = pi ? modbus_tcp_pi_accept(ctx, &s) : modbus_tcp_accept(ctx, &s);
            if (c == -1) {
                fprintf(stderr, "accept: %s\n", modbus_strerror(errno));
                break;
            }
            printf("accepted\n");
            fflush(stdout);
            if (serve(ctx, map, idle) == 0) {
                break;
            }
            close(c);
        }
        close(s);
    } else {
        if (modbus_connect(ctx) == -1) {
            fprintf(stderr, "connect: %s\n", modbus_strerror(errno));
            return 2;
        }
        printf("READY\n");
        fflush(stdout);
        serve(ctx, map, idle);
    }
    printf("server done\n");
    modbus_close(ctx);
    modbus_free(ctx);
    modbus_mapping_free(map);
    return 0;
}
