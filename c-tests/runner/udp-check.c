/*
 * udp-check.c: our Modbus/UDP client (modbus_new_udp) against a UDP server: ours
 * (runner-server udp) or pymodbus' (c-tests/runner/pm_udp.py server), directly or
 * through a proxy that loses and repeats datagrams (c-tests/suites/runner.sh).
 *
 *   udp-check <port> basic      reads, writes, reads back, an exception, 200 reads in
 *                               a row, and 20 asynchronous reads (modbus_process)
 *   udp-check <port> lossy N    N reads with a 300 ms response timeout through a lossy
 *                               path: each is its own right value or a timeout (a lost
 *                               datagram), never another request's answer (a repeated
 *                               one), and most get through
 *
 * The server's data: register i and input register i hold i (modulo 1000 checked),
 * coil i is i % 3 == 0.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <modbus.h>

#include "../common/check.h"
#include "../common/mbtest.h"

static modbus_t *open_udp(int port)
{
    modbus_t *ctx = modbus_new_udp("127.0.0.1", port);
    if (!EXPECT(ctx != NULL && modbus_connect(ctx) == 0, "modbus_new_udp + modbus_connect")) {
        return NULL;
    }
    modbus_set_slave(ctx, 1);
    return ctx;
}

static int done_count;
static int done_right;

static void on_done(modbus_t *ctx, int id, int rc, int error, void *user_data)
{
    uint16_t *v = user_data;
    (void) ctx;
    (void) error;
    done_count++;
    if (rc == 1 && *v % 1000 == 100 + id % 20) {
        done_right++;
    }
}

static void basic(int port)
{
    modbus_t *ctx = open_udp(port);
    uint16_t v[125], async_v[20];
    uint8_t bits[9];
    int i, ok = 0, rc;
    if (ctx == NULL) {
        return;
    }
    modbus_set_response_timeout(ctx, 2, 0);
    rc = modbus_read_registers(ctx, 300, 10, v);
    EXPECT(rc == 10 && v[0] % 1000 == 300 && v[9] % 1000 == 309, "read 10 registers (rc %d)", rc);
    v[0] = 11;
    v[1] = 22;
    EXPECT(modbus_write_registers(ctx, 610, 2, v) == 2, "write 2 registers");
    EXPECT(modbus_read_registers(ctx, 610, 2, v) == 2 && v[0] == 11 && v[1] == 22, "read them back");
    EXPECT(modbus_read_bits(ctx, 0, 9, bits) == 9 && bits[0] == 1 && bits[1] == 0 && bits[3] == 1, "read 9 coils");
    errno = 0;
    rc = modbus_read_registers(ctx, 995, 10, v);
    EXPECT(rc == -1 && errno == EMBXILADD, "a read past the table: exception 02 (errno %d)", errno);
    for (i = 0; i < 200; i++) {
        if (modbus_read_input_registers(ctx, i, 1, v) == 1 && v[0] % 1000 == i) {
            ok++;
        }
    }
    EXPECT(ok == 200, "200 reads in a row (%d right)", ok);
    for (i = 0; i < 20; i++) {
        int id = modbus_read_input_registers_async(ctx, 100 + i, 1, &async_v[i], on_done, &async_v[i]);
        if (id < 0) {
            break;
        }
    }
    while (done_count < 20) {
        struct pollfd p;
        int timeout;
        modbus_get_pollfd(ctx, &p, &timeout);
        poll(&p, 1, timeout < 0 ? 2000 : timeout);
        if (modbus_process(ctx, p.revents) < 0) {
            break;
        }
    }
    EXPECT(done_count == 20 && done_right == 20, "20 asynchronous reads (%d done, %d right)", done_count,
           done_right);
    modbus_close(ctx);
    modbus_free(ctx);
}

static void lossy(int port, int n)
{
    modbus_t *ctx = open_udp(port);
    int i, right = 0, timeouts = 0, wrong = 0;
    uint16_t v;
    if (ctx == NULL) {
        return;
    }
    modbus_set_response_timeout(ctx, 0, 300000);
    for (i = 0; i < n; i++) {
        int addr = i % 900, rc;
        errno = 0;
        rc = modbus_read_input_registers(ctx, addr, 1, &v);
        if (rc == 1 && v % 1000 == addr) {
            right++;
        } else if (rc == -1 && errno == ETIMEDOUT) {
            timeouts++;
        } else {
            wrong++;
            printf("# read %d: rc %d errno %d value %d\n", i, rc, errno, v);
        }
    }
    printf("# %d reads: %d right, %d timed out, %d wrong\n", n, right, timeouts, wrong);
    EXPECT(wrong == 0, "never another request's answer or an error but a timeout (%d wrong)", wrong);
    EXPECT(timeouts > 0, "lost datagrams are timeouts (%d)", timeouts);
    EXPECT(right >= n * 3 / 4, "most reads get through (%d of %d)", right, n);
    modbus_close(ctx);
    modbus_free(ctx);
}

int main(int argc, char **argv)
{
    int port;
    if (argc < 3) {
        fprintf(stderr, "usage: udp-check PORT basic|lossy N\n");
        return 2;
    }
    print_loaded_libmodbus();
    port = atoi(argv[1]);
    if (strcmp(argv[2], "basic") == 0) {
        basic(port);
    } else if (strcmp(argv[2], "lossy") == 0 && argc > 3) {
        lossy(port, atoi(argv[3]));
    } else {
        fprintf(stderr, "unknown scenario %s\n", argv[2]);
        return 2;
    }
    return chk_summary();
}
