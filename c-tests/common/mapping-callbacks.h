/*
 * mapping-callbacks.h: a modbus_server_callbacks_t that serves a modbus_mapping_t
 * (user_data), as an application's callbacks would: the range checked against the
 * table (exception 02 outside it), the values copied; nothing printed. Used where
 * modbus_reply_dispatch is measured or compared against modbus_reply on the same
 * mapping (c-tests/server/reply-callbacks.c, benches/reply-cost.c).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef MBT_MAPPING_CALLBACKS_H
#define MBT_MAPPING_CALLBACKS_H

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

static int read_bits(const modbus_request_info_t *ri, int addr, int nb, uint8_t *dest, void *user_data)
{
    void *tab;
    int i = index_of(user_data, ri->function, 1, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    memcpy(dest, (uint8_t *) tab + i, (size_t) nb);
    return 0;
}

static int read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *user_data)
{
    void *tab;
    int i = index_of(user_data, ri->function, 0, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    memcpy(dest, (uint16_t *) tab + i, (size_t) nb * 2);
    return 0;
}

static int write_bits(const modbus_request_info_t *ri, int addr, int nb, const uint8_t *src, void *user_data)
{
    void *tab;
    int i = index_of(user_data, ri->function, 1, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    memcpy((uint8_t *) tab + i, src, (size_t) nb);
    return 0;
}

static int write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src, void *user_data)
{
    void *tab;
    int i = index_of(user_data, ri->function, 0, addr, nb, &tab);
    if (i < 0) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    memcpy((uint16_t *) tab + i, src, (size_t) nb * 2);
    return 0;
}

static const modbus_server_callbacks_t MAPPING_CALLBACKS = {
    .struct_size = sizeof(modbus_server_callbacks_t),
    .read_bits = read_bits,
    .read_registers = read_registers,
    .write_bits = write_bits,
    .write_registers = write_registers,
};

#endif /* MBT_MAPPING_CALLBACKS_H */
