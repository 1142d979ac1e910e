/*
 * poll-many: many Modbus TCP devices polled from one thread (rsmodbus' event-driven
 * client). Each device gets a read of 10 holding registers per cycle; the requests
 * of all devices are in flight at once, and one multi handle waits for all of them.
 * A device that does not answer delays nobody: its request fails after its own
 * response timeout.
 *
 *   poll-many [HOST [PORT [DEVICES [CYCLES]]]]   (default 127.0.0.1 1502 1000 3)
 *
 * (every device is HOST:PORT here; a real poller has one address per device): by
 * default 1,000 connections to runner-server.c's server. Prints one line per cycle
 * and a summary; exits 0 when every read succeeded.
 *
 * Build: make -C examples, or
 *        gcc poll-many.c -o poll-many $(pkg-config --cflags --libs libmodbus)
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <time.h>

#include <modbus.h>

struct device {
    modbus_t *ctx;
    uint16_t regs[10];
    int ok, failed;
};

static int left; /* requests of this cycle not completed yet */

/* Called once per request, from modbus_multi_perform. */
static void done(modbus_t *ctx, int request_id, int rc, int error, void *user_data)
{
    struct device *d = user_data;
    (void) ctx;
    (void) request_id;
    if (rc == -1) {
        d->failed++;
        fprintf(stderr, "device %p: %s\n", (void *) d, modbus_strerror(error));
    } else {
        d->ok++;
    }
    left--;
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

int main(int argc, char *argv[])
{
    const char *host = argc > 1 ? argv[1] : "127.0.0.1";
    int port = argc > 2 ? atoi(argv[2]) : 1502;
    int n = argc > 3 ? atoi(argv[3]) : 1000, cycles = argc > 4 ? atoi(argv[4]) : 3;
    if (n < 1 || cycles < 1) {
        fprintf(stderr, "usage: %s [HOST [PORT [DEVICES [CYCLES]]]]\n", argv[0]);
        return 2;
    }
    /* One descriptor per device: take the hard limit (often 1,024 soft). */
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < rl.rlim_max) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
    struct device *dev = calloc((size_t) n, sizeof(*dev));
    modbus_multi_t *m = modbus_multi_new();
    if (dev == NULL || m == NULL) {
        return 1;
    }
    for (int i = 0; i < n; i++) {
        /* Not connected here: the first request connects, without waiting. */
        dev[i].ctx = modbus_new_tcp(host, port);
        if (dev[i].ctx == NULL || modbus_multi_add(m, dev[i].ctx) == -1) {
            fprintf(stderr, "device %d: %s\n", i, modbus_strerror(errno));
            return 1;
        }
        modbus_set_response_timeout(dev[i].ctx, 3, 0); /* connect included */
    }

    int total_ok = 0, total_failed = 0;
    for (int c = 0; c < cycles; c++) {
        double t0 = now_ms();
        for (int i = 0; i < n; i++) {
            if (modbus_read_registers_async(dev[i].ctx, 0, 10, dev[i].regs, done, &dev[i]) != -1) {
                left++;
            }
        }
        /* One thread, one wait for all the devices. */
        while (left > 0) {
            if (modbus_multi_perform(m, -1) == -1) {
                fprintf(stderr, "modbus_multi_perform: %s\n", modbus_strerror(errno));
                return 1;
            }
        }
        printf("cycle %d: %d devices in %.1f ms\n", c + 1, n, now_ms() - t0);
    }
    for (int i = 0; i < n; i++) {
        total_ok += dev[i].ok;
        total_failed += dev[i].failed;
        modbus_free(dev[i].ctx);
    }
    modbus_multi_free(m);
    free(dev);
    printf("%d reads: %d ok, %d failed\n", n * cycles, total_ok, total_failed);
    return total_failed == 0 ? 0 : 1;
}
