/*
 * tls-idle.c: N Modbus/TCP Security clients that connect, read once and then stay
 * connected and silent, for benches/server-many.sh to read the server's memory with
 * N idle TLS clients.
 *
 *   tls-idle CA CERT KEY PORT N
 *
 * Each client is its own rsmodbus context (modbus_new_tcp_tls, the client's
 * certificate given), connected in turn (the TLS handshake is done in
 * modbus_connect), and reads 10 holding registers once. Prints
 *   IDLE ok=OK failed=F ms=MS
 * once all have tried, then waits for SIGTERM or SIGINT, and closes them (a TLS
 * close_notify each) before it exits.
 *
 * Prints the library it loaded first (LIBINFO). Built against our include/ and
 * linked to our library.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

int print_loaded_libmodbus(void); /* c-tests/common/libinfo.c: the LIBINFO line */

static volatile sig_atomic_t stopping;

static void on_term(int sig)
{
    (void) sig;
    stopping = 1;
}

int main(int argc, char **argv)
{
    modbus_t **ctx;
    int n, i, ok = 0, failed = 0;
    struct timespec t0, t1;
    struct sigaction act;
    struct rlimit rl;

    if (argc != 6 || (n = atoi(argv[5])) < 1) {
        fprintf(stderr, "usage: tls-idle CA CERT KEY PORT N\n");
        return 2;
    }
    print_loaded_libmodbus();
    getrlimit(RLIMIT_NOFILE, &rl);
    if (rl.rlim_cur < (rlim_t) n + 64) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
    memset(&act, 0, sizeof act);
    act.sa_handler = on_term;
    sigaction(SIGTERM, &act, NULL);
    sigaction(SIGINT, &act, NULL);
    ctx = calloc((size_t) n, sizeof *ctx);
    if (ctx == NULL) {
        return 1;
    }
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (i = 0; i < n && !stopping; i++) {
        uint16_t regs[10];
        ctx[i] = modbus_new_tcp_tls("127.0.0.1", atoi(argv[4]));
        if (ctx[i] == NULL || modbus_set_tls_ca(ctx[i], argv[1]) != 0 ||
            modbus_set_tls_certificate(ctx[i], argv[2], argv[3]) != 0) {
            fprintf(stderr, "tls-idle: context: %s\n", modbus_strerror(errno));
            return 1;
        }
        modbus_set_response_timeout(ctx[i], 5, 0);
        if (modbus_connect(ctx[i]) != 0 || modbus_read_registers(ctx[i], 0, 10, regs) != 10) {
            if (failed++ == 0) {
                fprintf(stderr, "tls-idle: client %d: %s\n", i, modbus_strerror(errno));
            }
            modbus_close(ctx[i]);
            modbus_free(ctx[i]);
            ctx[i] = NULL;
            continue;
        }
        ok++;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    printf("IDLE ok=%d failed=%d ms=%.0f\n", ok, failed,
           (double) (t1.tv_sec - t0.tv_sec) * 1e3 + (double) (t1.tv_nsec - t0.tv_nsec) / 1e6);
    fflush(stdout);
    while (!stopping) {
        pause();
    }
    for (i = 0; i < n; i++) {
        if (ctx[i] != NULL) {
            modbus_close(ctx[i]);
            modbus_free(ctx[i]);
        }
    }
    free(ctx);
    return 0;
}
