/*
 * mbtest: helpers shared by the rsmodbus C test programs.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 *
 * Every program is compiled ONCE against Debian's <modbus.h> and then run twice:
 * with Debian's libmodbus.so.5 (LD_LIBRARY_PATH unset) and with rsmodbus
 * (LD_LIBRARY_PATH=target/release). Everything printed on stdout/stderr must
 * therefore be deterministic and independent of which library was loaded, except
 * the lines tagged with a named, allowed difference (see c-tests/allowed-differences.txt):
 *
 *   DIFF-OK <name>: <text>          one line known to differ between 3.1.6-deb and ours
 *   DIFF-OK-BEGIN <name> ...
 *   DIFF-OK-END <name>              a block (library debug trace included) known to differ
 *
 * The comparer masks such lines/blocks only when <name> is in the allowed list.
 */
#ifndef MBTEST_H
#define MBTEST_H

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <modbus.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- which libmodbus.so.5 is loaded ---------------------------------------------- */

/* Prints "LIBINFO: libmodbus.so.5 = <real path> (rsmodbus <version>|debian libmodbus)"
 * to the file named by $MBTEST_LIBINFO (appended) or, if unset, to stdout.
 * Then enforces $EXPECT_LIB=ours|debian: exits with status 97 and a clear message on
 * stderr if the wrong library is loaded. Returns 1 if rsmodbus is loaded, else 0. */
int print_loaded_libmodbus(void);
/* 1 if the loaded libmodbus exports rsmodbus_version(), else 0. */
int mbt_is_rsmodbus(void);
/* Real path of the mapped libmodbus (static buffer), or "(not mapped)". */
const char *mbt_libmodbus_path(void);

/* ---- tracing -------------------------------------------------------------------- */

/* Symbolic name of an errno value ("EINVAL", "EMBXILADD", "E#123" if unknown). */
const char *mbt_errname(int e);
/* Prints "<what> = <rc>" and, if rc == -1, " errno=<n> <NAME> \"<modbus_strerror>\"". */
void mbt_report_int(const char *what, int rc, int err);
/* Same, always printing errno (for calls whose errno is part of the contract). */
void mbt_report_int_errno(const char *what, int rc, int err);
/* Prints "<what> = NULL errno=..." or "<what> = ctx". */
void mbt_report_ptr(const char *what, const void *p, int err);
void mbt_dump_u8(const char *label, const uint8_t *v, int n);
void mbt_dump_u16(const char *label, const uint16_t *v, int n);
void mbt_dump_bits(const char *label, const uint8_t *v, int n);
/* Prints a float as %.6f and its IEEE-754 bit pattern. */
void mbt_print_float(const char *label, float f);
/* Section header (stdout only). */
void mbt_section(const char *title);

#define CHECK(expr)                                                                  \
    do {                                                                             \
        int mbt_rc_;                                                                 \
        errno = 0;                                                                   \
        mbt_rc_ = (int) (expr);                                                      \
        mbt_report_int(#expr, mbt_rc_, errno);                                       \
    } while (0)

/* Like CHECK but stores the return value in `var`. */
#define CHECK_RC(var, expr)                                                          \
    do {                                                                             \
        errno = 0;                                                                   \
        (var) = (int) (expr);                                                        \
        mbt_report_int(#expr, (var), errno);                                         \
    } while (0)

#define CHECK_ERRNO(expr)                                                            \
    do {                                                                             \
        int mbt_rc_;                                                                 \
        errno = 0;                                                                   \
        mbt_rc_ = (int) (expr);                                                      \
        mbt_report_int_errno(#expr, mbt_rc_, errno);                                 \
    } while (0)

/* For constructors: stores the pointer in `var`. */
#define CHECK_PTR(var, expr)                                                         \
    do {                                                                             \
        errno = 0;                                                                   \
        (var) = (expr);                                                              \
        mbt_report_ptr(#expr, (const void *) (var), errno);                          \
    } while (0)

/* Runs a void call and prints that it returned. */
#define CALL(expr)                                                                   \
    do {                                                                             \
        errno = 0;                                                                   \
        expr;                                                                        \
        printf("%s done\n", #expr);                                                  \
    } while (0)

/* ---- named, allowed differences ------------------------------------------------- */

/* Prints "DIFF-OK <name>: <text>" if `got` equals the value expected for the loaded
 * library (`deb` for Debian's, one of the '|'-separated `ours` values for rsmodbus),
 * else "DIFF-UNEXPECTED <name>: <got> (expected <...>)", which is never masked. */
void mbt_diff_value(const char *name, const char *got, const char *deb, const char *ours);
/* Formats the rc/errno of a call as "rc=<rc>" or "rc=-1 errno=<NAME>". */
const char *mbt_fmt_rc(char *buf, size_t len, int rc, int err);
/* Block markers, printed on stdout and stderr. If ctx is not NULL (and connected to
 * c-tests/servers/mbtest-server), a marker request is also sent so that the server
 * log carries the same block boundaries. */
void mbt_diff_begin(modbus_t *ctx, const char *name);
void mbt_diff_end(modbus_t *ctx, const char *name);

/* Runs expr inside the block of `name` (mbt_diff_begin/end): its trace is masked, its
 * return value goes to `rc` and its errno to `err`, for the caller to report after
 * the block (unmasked, or checked with mbt_diff_value). */
#define DIFF_BLOCK_RC(ctx, name, rc, err, expr)                                      \
    do {                                                                             \
        mbt_diff_begin(ctx, name);                                                   \
        errno = 0;                                                                   \
        (rc) = (int) (expr);                                                         \
        (err) = errno;                                                               \
        fflush(stdout);                                                              \
        mbt_diff_end(ctx, name);                                                     \
    } while (0)

/* ---- crash isolation ------------------------------------------------------------ */

/* Runs fn(arg) in a forked child (stdout/stderr flushed before and after) and prints
 * "child: exit <n>" or "child: killed by signal <n>". Returns the child's status. */
int mbt_in_child(const char *what, void (*fn)(void *), void *arg);

/* ---- connection set-up from argv ------------------------------------------------ */

/* Scenario programs take:  tcp <ip> <port> | tcppi <node> <service> | rtu <device> <slave>
 * followed by optional extra arguments. Creates (and traces) the context; does not
 * connect. Returns NULL on bad usage. *backend is set to 't', 'p' or 'r'. */
modbus_t *mbt_ctx_from_args(int argc, char **argv, char *backend);
/* Connects with a trace; exits(2) on failure (the scenario cannot continue). */
void mbt_connect_or_die(modbus_t *ctx);
/* The opening the client scenarios share: mbt_ctx_from_args, the debug trace on, the
 * response timeout set to response_us (< 1 s; 0 keeps the library's default), then
 * mbt_connect_or_die. Traced as the same calls written out would be. NULL on bad usage. */
modbus_t *mbt_open_scenario(int argc, char **argv, char *backend, uint32_t response_us);
/* Reads holding registers 0..1 and prints them: the scenarios' check that the
 * context still works after a fault. */
void mbt_read_two(modbus_t *ctx);

/* ---- pty and loopback helpers --------------------------------------------------- */

/* Opens a pty pair in raw mode (cfmakeraw on the slave). Copies the slave path into
 * name (size len). Returns 0 or -1 (errno set). */
int mbt_openpty_raw(int *master, int *slave, char *name, size_t len);
/* Loopback TCP helpers (127.0.0.1). Returns a listening fd bound to `port` (0: any)
 * with the given backlog, or -1. *bound_port receives the port. */
int mbt_tcp_listen(int port, int backlog, int *bound_port);
/* Same for IPv6 "::" or "::1" (v6only=0 when node is "::"). */
int mbt_tcp6_listen(const char *node, int port, int backlog, int *bound_port);
/* Fills the accept queue of a listener (nobody accepts) so that further SYNs are
 * dropped and a connect() hangs: a local "black hole". Returns 0 or -1. */
int mbt_fill_backlog(int port, int *fds, int nfds);
/* Blocking loopback connect, returns fd or -1. */
int mbt_tcp_connect(int port);

/* Modbus CRC-16 (own implementation; low byte is sent first). */
uint16_t mbt_crc16(const uint8_t *buf, int len);
/* Milliseconds sleep. */
void mbt_msleep(int ms);

#ifdef __cplusplus
}
#endif

#endif /* MBTEST_H */
