/*
 * Scenario "timeouts": response timeout, byte timeout, disabled byte timeout, and a
 * response arriving after the timeout (stale reply read by the next call), with the
 * debug trace on. Backends: tcp, rtu. Server delays are >= 2x the timeouts, so that the
 * traces are deterministic on a loaded machine.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <pthread.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <time.h>

#include "../common/mbtest.h"

static long now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1000L + ts.tv_nsec / 1000000L;
}

/* Prints whether the elapsed time is in [lo, hi] ms (not the time itself). */
static void elapsed(long t0, long lo, long hi)
{
    long d = now_ms() - t0;
    /* The measured value itself is not printed: it would make the outputs differ. */
    printf("elapsed %s [%ld, %ld] ms\n", (d >= lo && d <= hi) ? "within" : "OUTSIDE", lo, hi);
}

/* Another thread's way out of a wait: shut the context's socket down. */
static void *shut_down_later(void *ctx)
{
    mbt_msleep(200);
    shutdown(modbus_get_socket((modbus_t *) ctx), SHUT_RDWR);
    return NULL;
}

static void resync(modbus_t *ctx, int ms)
{
    mbt_msleep(ms);
    CHECK(modbus_flush(ctx));
}

int main(int argc, char **argv)
{
    char backend;
    modbus_t *ctx;
    uint16_t regs[8];
    uint32_t s, us;
    long t0;
    int rc;

    ctx = mbt_open_scenario(argc, argv, &backend, 0);
    if (ctx == NULL) {
        return 1;
    }
    memset(regs, 0, sizeof(regs));

    mbt_section("connect does not change the response timeout");
    CHECK(modbus_get_response_timeout(ctx, &s, &us));
    printf("response timeout %u.%06u\n", s, us);

    mbt_section("response timeout 0.2 s < 0.5 s server delay");
    CHECK(modbus_set_response_timeout(ctx, 0, 200000));
    t0 = now_ms();
    CHECK(modbus_read_registers(ctx, 0x1020, 1, regs));
    elapsed(t0, 180, 450);

    mbt_section("the late reply is read by the next call");
    /* TCP: TID mismatch; RTU: same length, accepted with the stale values. */
    CHECK_RC(rc, modbus_read_registers(ctx, 5, 1, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);
    resync(ctx, 300);
    CHECK_RC(rc, modbus_read_registers(ctx, 5, 1, regs));
    mbt_dump_u16("register 5", regs, rc > 0 ? rc : 0);

    mbt_section("response timeout 1.0 s > 0.5 s");
    CHECK(modbus_set_response_timeout(ctx, 1, 0));
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1020, 1, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);

    mbt_section("byte timeout: one byte every 50 ms");
    CHECK(modbus_set_byte_timeout(ctx, 0, 10000));
    t0 = now_ms();
    CHECK(modbus_read_registers(ctx, 0x1021, 1, regs));
    elapsed(t0, 5, 49);
    resync(ctx, 800);
    CHECK(modbus_set_byte_timeout(ctx, 0, 200000));
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1021, 1, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);

    mbt_section("4 bytes, 400 ms pause, rest");
    CHECK(modbus_set_byte_timeout(ctx, 0, 100000));
    CHECK(modbus_read_registers(ctx, 0x1022, 1, regs));
    resync(ctx, 600);
    CHECK(modbus_set_byte_timeout(ctx, 0, 800000));
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1022, 1, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);

    mbt_section("byte timeout disabled: the whole reply within the response timeout");
    CHECK(modbus_set_byte_timeout(ctx, 0, 0));
    CHECK(modbus_get_byte_timeout(ctx, &s, &us));
    printf("byte timeout %u.%06u\n", s, us);
    CHECK(modbus_set_response_timeout(ctx, 0, 200000));
    CHECK(modbus_read_registers(ctx, 0x1022, 1, regs));
    resync(ctx, 600);
    CHECK(modbus_set_response_timeout(ctx, 1, 0));
    CHECK_RC(rc, modbus_read_registers(ctx, 0x1022, 1, regs));
    mbt_dump_u16("registers", regs, rc > 0 ? rc : 0);

    mbt_section("no reply at all");
    CHECK(modbus_set_response_timeout(ctx, 0, 300000));
    CHECK(modbus_set_byte_timeout(ctx, 0, 500000));
    t0 = now_ms();
    CHECK(modbus_read_registers(ctx, 0x1045, 1, regs));
    elapsed(t0, 280, 700);
    CHECK(modbus_write_register(ctx, 0x1045, 1));

    mbt_section("tiny response timeout");
    CHECK(modbus_set_response_timeout(ctx, 0, 1));
    CHECK(modbus_get_response_timeout(ctx, &s, &us));
    printf("response timeout %u.%06u\n", s, us);
    CHECK(modbus_set_response_timeout(ctx, 0, 500000));
    mbt_read_two(ctx);

    if (backend == 't') {
        /* modbus_get_socket from another thread must not wait for the call that is
         * waiting (libmodbus reads the field): the shutdown ends the wait long
         * before the 3 s response timeout. */
        pthread_t thread;
        mbt_section("another thread shuts the socket down during a wait");
        CHECK(modbus_set_response_timeout(ctx, 3, 0));
        CHECK(pthread_create(&thread, NULL, shut_down_later, ctx));
        t0 = now_ms();
        CHECK(modbus_read_registers(ctx, 0x1045, 1, regs));
        elapsed(t0, 150, 2000);
        CHECK(pthread_join(thread, NULL));
    }

    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));
    printf("END\n");
    return 0;
}
