/*
 * Shared helpers of the interoperability programs: the data model both sides agree on
 * (the same formulas as pm_model.py), check macros, context from argv, and the report
 * of which libmodbus.so.5 the loader mapped.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef INTEROP_H
#define INTEROP_H

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <modbus.h>

/* ---- the model (pm_model.py) ------------------------------------------------------ */
#define IO_SLAVE 17
#define IO_SIZE 200

static inline int io_coil(int i) { return i % 3 == 0; }
static inline int io_discrete(int i) { return i % 4 == 1; }
static inline uint16_t io_holding(int i) { return (uint16_t) (0x1000 + i * 0x0101); }
static inline uint16_t io_input(int i) { return (uint16_t) (0x8000 + i * 7); }
static inline uint16_t io_file_reg(int file, int record)
{
    return (uint16_t) (file * 0x1000 + record * 3);
}

#define IO_EXCEPTION_STATUS 0xA5
#define IO_EVENT_COUNT 0x0A0B
static const uint16_t io_counters[8] = {0x0102, 3, 4, 5, 6, 7, 8, 9}; /* subs 0x0B..0x12 */
static const uint8_t io_events[5] = {0x00, 0x04, 0xC0, 0x42, 0x81};
#define IO_NB_EVENTS 5

static const char *const io_device_id_regular[7] = {
    "rsmodbus-interop", "PM-3", "V3.16", "http://localhost/", "interop-device", "model-5",
    "pymodbus-peer"};
#define IO_NB_EXTENDED 16
/* extended object 0x80 + k: "extended-object-%02d-xxxxxxxx" */

/* ---- results ---------------------------------------------------------------------- */
/* c-tests/common/check.h's lines and counters ("ok   - name", "FAIL - name: why",
 * "N passed, M failed"), kept in interop.c for every file of the program. */
void io_ok(const char *name);
void io_fail(const char *name, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* rc must equal want; on -1 the errno is shown. */
int io_rc(const char *name, int rc, int want);
/* the call must fail with errno want_errno. */
int io_err(const char *name, int rc, int want_errno);
/* "N passed, M failed"; the exit status (1 when a check failed or none ran). */
int io_summary(void);
/* "11 03 02 .." of n bytes (static buffer, up to 300 bytes shown). */
const char *io_hex(const uint8_t *b, int n);

/* ---- library in use --------------------------------------------------------------- */
/* The path of the libmodbus.so.5 mapped into this process (/proc/self/maps). */
const char *io_loaded_path(void);
/* Prints "LOADED <path> (rsmodbus <version>|not rsmodbus)"; returns 1 for ours. */
int io_print_loaded(void);

/* ---- contexts --------------------------------------------------------------------- */
/* transport: tcp PORT | tcppi PORT | rtutcp PORT | rtutcppi PORT | ascii DEV | ascii7 DEV |
 * rtu DEV. Returns NULL (with a message) on failure. */
modbus_t *io_new_ctx(const char *transport, const char *where);
int io_is_serial(const char *transport);

#endif
