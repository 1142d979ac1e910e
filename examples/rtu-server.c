/* A Modbus RTU server (slave) on a serial line: answers every request addressed to
 * its slave id from one register map, until it is stopped.
 *
 * Usage: rtu-server DEVICE [SLAVE_ID [BAUD [PARITY [MAX_REQUESTS]]]]
 *   DEVICE        serial port, e.g. /dev/ttyUSB0 (or one end of a pty pair)
 *   SLAVE_ID      1..247 (default 17)
 *   BAUD          default 19200
 *   PARITY        N, E or O (default E: 19200 8E1 is the Modbus default, and mbpoll's)
 *   MAX_REQUESTS  stop after answering that many requests (default 0 = never)
 *
 * The map holds 100 of each table. Holding register i starts at 1000 + i, input
 * register i at 2000 + i, input bit i at i % 2; coils start at 0.
 *
 * Build: gcc rtu-server.c -o rtu-server $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>

#include <modbus.h>

int main(int argc, char *argv[])
{
    if (argc < 2) {
        fprintf(stderr, "usage: %s DEVICE [SLAVE_ID [BAUD [PARITY [MAX_REQUESTS]]]]\n", argv[0]);
        return EXIT_FAILURE;
    }
    const char *device = argv[1];
    int slave = argc > 2 ? atoi(argv[2]) : 17;
    int baud = argc > 3 ? atoi(argv[3]) : 19200;
    char parity = argc > 4 ? argv[4][0] : 'E';
    long max_requests = argc > 5 ? atol(argv[5]) : 0;
    long served = 0;
    uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];
    int status = EXIT_SUCCESS;

    modbus_t *ctx = modbus_new_rtu(device, baud, parity, 8, 1);
    if (ctx == NULL) {
        fprintf(stderr, "modbus_new_rtu: %s\n", modbus_strerror(errno));
        return EXIT_FAILURE;
    }
    /* A server answers only the frames for its own id (and broadcasts, id 0). */
    if (modbus_set_slave(ctx, slave) == -1) {
        fprintf(stderr, "invalid slave id %d: %s\n", slave, modbus_strerror(errno));
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    modbus_mapping_t *map = modbus_mapping_new(100, 100, 100, 100);
    if (map == NULL) {
        fprintf(stderr, "modbus_mapping_new: %s\n", modbus_strerror(errno));
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    for (int i = 0; i < 100; i++) {
        map->tab_registers[i] = (uint16_t)(1000 + i);
        map->tab_input_registers[i] = (uint16_t)(2000 + i);
        map->tab_input_bits[i] = (uint8_t)(i % 2);
    }
    if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "cannot open %s: %s\n", device, modbus_strerror(errno));
        modbus_mapping_free(map);
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    printf("serving slave %d on %s at %d 8%c1\n", slave, device, baud, parity);
    fflush(stdout);

    while (max_requests == 0 || served < max_requests) {
        /* Waits for the next frame (forever: no indication timeout is set). */
        int rc = modbus_receive(ctx, query);
        if (rc > 0) {
            /* Answers from the map; for a broadcast (id 0) nothing is sent. */
            if (modbus_reply(ctx, query, rc, map) == -1)
                fprintf(stderr, "reply failed: %s\n", modbus_strerror(errno));
            served++;
        } else if (rc == 0) {
            /* A frame for another slave on the bus: ignored. */
            continue;
        } else if (errno == EMBBADCRC || errno == EMBBADDATA) {
            /* Line noise: drop the frame, keep serving. */
            fprintf(stderr, "bad frame ignored: %s\n", modbus_strerror(errno));
            modbus_flush(ctx);
        } else {
            fprintf(stderr, "receive failed: %s\n", modbus_strerror(errno));
            status = EXIT_FAILURE;
            break;
        }
    }
    printf("server done after %ld requests\n", served);
    modbus_close(ctx);
    modbus_mapping_free(map);
    modbus_free(ctx);
    return status;
}
