/* A Modbus RTU server that answers three unit ids on one serial line, each with its
 * own data, through callbacks (modbus_reply_dispatch): the values are the
 * application's own variables, computed when a master asks for them.
 *
 * Usage: server-callbacks DEVICE [BAUD [PARITY [MAX_REQUESTS]]]
 *   serves units 17, 18 and 19 (19200 8E1 by default); every other unit id on the
 *   bus gets no answer. MAX_REQUESTS: stop after that many (default 0 = never).
 *
 * Each unit has 100 holding registers (register i starts at 1000 + i) and 100 coils.
 * Input registers 0..9 read 2000 + i; the live ones: 10 = the requests this unit has
 * answered, 11 = the seconds since the server started. Input bit i is i % 2.
 *
 * Build: gcc server-callbacks.c -o server-callbacks $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <modbus.h>

#define UNITS 3
#define SIZE 100

struct unit {
    int id;
    long requests;
    uint16_t registers[SIZE];
    uint8_t coils[SIZE];
};

struct server {
    struct unit units[UNITS];
    time_t started;
};

static struct unit *find(struct server *s, int id)
{
    for (int i = 0; i < UNITS; i++)
        if (s->units[i].id == id)
            return &s->units[i];
    return NULL;
}

static int accept_unit(const modbus_request_info_t *ri, int unit_id, void *user_data)
{
    (void) ri;
    return find(user_data, unit_id) != NULL;
}

/* The unit a request is for (a broadcast, unit 0, writes to the first one), or NULL
 * when [addr, addr + nb) is outside the tables. */
static struct unit *target(struct server *s, const modbus_request_info_t *ri, int addr, int nb)
{
    if (addr < 0 || addr + nb > SIZE)
        return NULL;
    struct unit *u = find(s, ri->unit_id);
    return u != NULL ? u : &s->units[0];
}

static int read_bits(const modbus_request_info_t *ri, int addr, int nb, uint8_t *dest, void *user_data)
{
    struct unit *u = target(user_data, ri, addr, nb);
    if (u == NULL)
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    for (int i = 0; i < nb; i++)
        dest[i] = ri->function == MODBUS_FC_READ_DISCRETE_INPUTS ? (uint8_t)((addr + i) % 2) : u->coils[addr + i];
    return 0;
}

static int read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *user_data)
{
    struct server *s = user_data;
    struct unit *u = target(s, ri, addr, nb);
    if (u == NULL)
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    for (int i = 0; i < nb; i++) {
        int a = addr + i;
        if (ri->function != MODBUS_FC_READ_INPUT_REGISTERS)
            dest[i] = u->registers[a];
        else if (a == 10)
            dest[i] = (uint16_t)u->requests;
        else if (a == 11)
            dest[i] = (uint16_t)(time(NULL) - s->started);
        else
            dest[i] = (uint16_t)(2000 + a);
    }
    return 0;
}

static int write_bits(const modbus_request_info_t *ri, int addr, int nb, const uint8_t *src, void *user_data)
{
    struct unit *u = target(user_data, ri, addr, nb);
    if (u == NULL)
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    memcpy(u->coils + addr, src, (size_t)nb);
    return 0;
}

static int write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src, void *user_data)
{
    struct unit *u = target(user_data, ri, addr, nb);
    if (u == NULL)
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    memcpy(u->registers + addr, src, (size_t)nb * sizeof(uint16_t));
    return 0;
}

int main(int argc, char *argv[])
{
    if (argc < 2) {
        fprintf(stderr, "usage: %s DEVICE [BAUD [PARITY [MAX_REQUESTS]]]\n", argv[0]);
        return EXIT_FAILURE;
    }
    int baud = argc > 2 ? atoi(argv[2]) : 19200;
    char parity = argc > 3 ? argv[3][0] : 'E';
    long max_requests = argc > 4 ? atol(argv[4]) : 0;
    long served = 0;
    uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];
    static struct server s;
    const modbus_server_callbacks_t cb = {
        .struct_size = sizeof(modbus_server_callbacks_t),
        .accept_unit = accept_unit,
        .read_bits = read_bits,
        .read_registers = read_registers,
        .write_bits = write_bits,
        .write_registers = write_registers,
    };

    s.started = time(NULL);
    for (int k = 0; k < UNITS; k++) {
        s.units[k].id = 17 + k;
        for (int i = 0; i < SIZE; i++)
            s.units[k].registers[i] = (uint16_t)(1000 + i);
    }
    modbus_t *ctx = modbus_new_rtu(argv[1], baud, parity, 8, 1);
    if (ctx == NULL || modbus_connect(ctx) == -1) {
        fprintf(stderr, "cannot open %s: %s\n", argv[1], modbus_strerror(errno));
        modbus_free(ctx);
        return EXIT_FAILURE;
    }
    printf("serving units 17, 18, 19 on %s at %d 8%c1\n", argv[1], baud, parity);
    fflush(stdout);

    while (max_requests == 0 || served < max_requests) {
        /* Takes the requests for every unit accept_unit serves (0 for the others). */
        int rc = modbus_receive_dispatch(ctx, query, &cb, &s);
        if (rc > 0) {
            struct unit *u = find(&s, query[0]);
            if (modbus_reply_dispatch(ctx, query, rc, &cb, &s) == -1)
                fprintf(stderr, "reply failed: %s\n", modbus_strerror(errno));
            if (u != NULL)
                u->requests++;
            served++;
        } else if (rc == -1 && (errno == EMBBADCRC || errno == EMBBADDATA)) {
            modbus_flush(ctx);
        } else if (rc == -1) {
            fprintf(stderr, "receive failed: %s\n", modbus_strerror(errno));
            break;
        }
    }
    for (int k = 0; k < UNITS; k++)
        printf("unit %d: %ld requests\n", s.units[k].id, s.units[k].requests);
    printf("server done after %ld requests\n", served);
    modbus_close(ctx);
    modbus_free(ctx);
    return EXIT_SUCCESS;
}
