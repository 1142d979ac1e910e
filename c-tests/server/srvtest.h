/*
 * srvtest.h: what the differential's server (srv.c) and driver (driver.c) agree on.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#ifndef SRVTEST_H
#define SRVTEST_H

#define SRVTEST_SLAVE 17
/* The flush delay before "illegal number of values" and unknown-function exceptions. */
#define SRVTEST_RESPONSE_TIMEOUT_US 200000
#define SRVTEST_BYTE_TIMEOUT_US 150000

/* The mapping: every table starts above 0 to exercise the start offsets. */
#define SRVTEST_BITS_START 0x100
#define SRVTEST_BITS_NB 2100
#define SRVTEST_IBITS_START 0x1000
#define SRVTEST_IBITS_NB 2000
#define SRVTEST_REGS_START 0x100
#define SRVTEST_REGS_NB 300
#define SRVTEST_IREGS_START 0x400
#define SRVTEST_IREGS_NB 130

/* Initial values, item i of each table. */
#define SRVTEST_BIT(i) ((uint8_t) ((i) % 3 == 0))
#define SRVTEST_IBIT(i) ((uint8_t) ((i) % 5 == 1))
#define SRVTEST_REG(i) ((uint16_t) (0x1000 + (i) * 7))
#define SRVTEST_IREG(i) ((uint16_t) (0xA000 + (i)))

/* FC 03 at this address: modbus_reply_exception() with code = low byte of the quantity. */
#define SRVTEST_EXCEPTION_ADDRESS 0x7FFF

/* A request made of this function code alone stops the server cleanly. */
#define SRVTEST_QUIT_FC 0x65

#endif
