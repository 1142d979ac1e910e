/*
 * reply-callbacks.c: LD_PRELOADed into a server program run on rsmodbus, replaces
 * modbus_reply() with modbus_reply_callbacks() over a callback set that serves the
 * same modbus_mapping_t: the server tests (c-tests/suites/server.sh) run the same
 * frames and Debian's unit tests through the callbacks and compare the answers with
 * modbus_reply's.
 *
 * The callbacks do what an application's would: check the range against the table
 * (exception 02 outside it), copy the values. They print nothing (modbus_reply's
 * "Illegal data address" lines come from the mapping's own range check), so the
 * comparison is of the responses and their timing.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdio.h>
#include <string.h>

#include <modbus.h>

/* The table a request's function code reaches. */
static void table(modbus_mapping_t *m, int function, int bits, int *start, int *nb, void **tab)
{
    if (bits) {
        int input = function == MODBUS_FC_READ_DISCRETE_INPUTS;
        *start = input ? m->start_input_bits : m->start_bits;
        *nb = input ? m->nb_input_bits : m->nb_bits;
        *tab = input ? (void *) m->tab_input_bits : (void *) m->tab_bits;
    } else {
        int input = function == MODBUS_FC_READ_INPUT_REGISTERS;
        *start = input ? m->start_input_registers : m->start_registers;
        *nb = input ? m->nb_input_registers : m->nb_registers;
        *tab = input ? (void *) m->tab_input_registers : (void *) m->tab_registers;
    }
}

/* The index of `addr` in the table, or -1 when [addr, addr + nb) is not all in it. */
static int index_of(modbus_mapping_t *m, int function, int bits, int addr, int nb, void **tab)
{
    int start, size;
    if (m == NULL) {
        return -1;
    }
    table(m, function, bits, &start, &size, tab);
    if (*tab == NULL || addr < start || addr - start + nb > size) {
        return -1;
    }
    return addr - start;
}

static int read_bits(void *user_data, const modbus_request_info_t *ri, int addr, int nb, uint8_t *dest)
{
    void *tab;
    int i = index_of(user_data, ri->function, 1, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    memcpy(dest, (uint8_t *) tab + i, (size_t) nb);
    return 0;
}

static int read_registers(void *user_data, const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest)
{
    void *tab;
    int i = index_of(user_data, ri->function, 0, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    memcpy(dest, (uint16_t *) tab + i, (size_t) nb * 2);
    return 0;
}

static int write_bits(void *user_data, const modbus_request_info_t *ri, int addr, int nb, const uint8_t *src)
{
    void *tab;
    int i = index_of(user_data, ri->function, 1, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    memcpy((uint8_t *) tab + i, src, (size_t) nb);
    return 0;
}

static int write_registers(void *user_data, const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src)
{
    void *tab;
    int i = index_of(user_data, ri->function, 0, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    memcpy((uint16_t *) tab + i, src, (size_t) nb * 2);
    return 0;
}

static const modbus_server_callbacks_t CALLBACKS = {
    .struct_size = sizeof(modbus_server_callbacks_t),
    .read_bits = read_bits,
    .read_registers = read_registers,
    .write_bits = write_bits,
    .write_registers = write_registers,
};

int modbus_reply(modbus_t *ctx, const uint8_t *req, int req_length, modbus_mapping_t *mb_mapping)
{
    static int told;
    if (!told) {
        told = 1;
        fprintf(stderr, "reply-callbacks: modbus_reply answers through modbus_reply_callbacks\n");
    }
    return modbus_reply_callbacks(ctx, req, req_length, &CALLBACKS, mb_mapping);
}
