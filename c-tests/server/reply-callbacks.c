/*
 * reply-callbacks.c: LD_PRELOADed into a server program run on rsmodbus, replaces
 * modbus_reply() with modbus_reply_dispatch() over a callback set that serves the
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

#include "../common/mapping-callbacks.h"

int modbus_reply(modbus_t *ctx, const uint8_t *req, int req_length, modbus_mapping_t *mb_mapping)
{
    static int told;
    if (!told) {
        told = 1;
        fprintf(stderr, "reply-callbacks: modbus_reply answers through modbus_reply_dispatch\n");
    }
    return modbus_reply_dispatch(ctx, req, req_length, &MAPPING_CALLBACKS, mb_mapping);
}
