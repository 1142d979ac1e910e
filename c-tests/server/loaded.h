/* SPDX-License-Identifier: MIT OR Apache-2.0 */
#ifndef SRVTEST_LOADED_H
#define SRVTEST_LOADED_H

/* The path of the libmodbus.so.5 mapped into this process (from /proc/self/maps). */
const char *srvtest_loaded_path(void);

#endif
