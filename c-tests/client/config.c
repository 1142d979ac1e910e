/*
 * Scenario "config": context constructors, configuration getters/setters, NULL
 * contexts, modbus_strerror for every code, the data helpers (bits, floats) and the
 * exported version objects. Needs no server (run with backend "none").
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>

#include "../common/mbtest.h"

extern const unsigned int libmodbus_version_major;
extern const unsigned int libmodbus_version_minor;
extern const unsigned int libmodbus_version_micro;

static void timeouts(modbus_t *ctx)
{
    uint32_t s = 77, us = 77;

    CHECK(modbus_get_response_timeout(ctx, &s, &us));
    printf("response timeout %u.%06u\n", s, us);
    CHECK(modbus_get_byte_timeout(ctx, &s, &us));
    printf("byte timeout %u.%06u\n", s, us);
    CHECK(modbus_get_indication_timeout(ctx, &s, &us));
    printf("indication timeout %u.%06u\n", s, us);

    CHECK(modbus_set_response_timeout(ctx, 0, 0));
    CHECK(modbus_set_response_timeout(ctx, 0, 1000000));
    CHECK(modbus_set_response_timeout(ctx, 1, 1000000));
    CHECK(modbus_set_response_timeout(ctx, 3, 999999));
    CHECK(modbus_get_response_timeout(ctx, &s, &us));
    printf("response timeout %u.%06u\n", s, us);
    CHECK(modbus_set_response_timeout(ctx, 0, 1));
    CHECK(modbus_get_response_timeout(ctx, &s, &us));
    printf("response timeout %u.%06u\n", s, us);
    CHECK(modbus_set_response_timeout(ctx, 7, 0));
    CHECK(modbus_get_response_timeout(ctx, &s, &us));
    printf("response timeout %u.%06u\n", s, us);

    CHECK(modbus_set_byte_timeout(ctx, 0, 0));
    CHECK(modbus_get_byte_timeout(ctx, &s, &us));
    printf("byte timeout %u.%06u\n", s, us);
    CHECK(modbus_set_byte_timeout(ctx, 0, 1000000));
    CHECK(modbus_set_byte_timeout(ctx, 2, 500));
    CHECK(modbus_get_byte_timeout(ctx, &s, &us));
    printf("byte timeout %u.%06u\n", s, us);

    CHECK(modbus_set_indication_timeout(ctx, 0, 1000000));
    CHECK(modbus_set_indication_timeout(ctx, 0, 0));
    CHECK(modbus_set_indication_timeout(ctx, 4, 250000));
    CHECK(modbus_get_indication_timeout(ctx, &s, &us));
    printf("indication timeout %u.%06u\n", s, us);
}

static void common_setters(modbus_t *ctx)
{
    CHECK(modbus_get_slave(ctx));
    CHECK(modbus_get_header_length(ctx));
    CHECK(modbus_set_slave(ctx, -1));
    CHECK(modbus_set_slave(ctx, 0));
    CHECK(modbus_get_slave(ctx));
    CHECK(modbus_set_slave(ctx, 1));
    CHECK(modbus_set_slave(ctx, 247));
    CHECK(modbus_get_slave(ctx));
    CHECK(modbus_set_slave(ctx, 248));
    CHECK(modbus_set_slave(ctx, 254));
    CHECK(modbus_set_slave(ctx, 255));
    CHECK(modbus_get_slave(ctx));
    CHECK(modbus_set_slave(ctx, 256));
    CHECK(modbus_set_slave(ctx, 100000));
    CHECK(modbus_get_slave(ctx));

    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE));
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_LINK));
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_PROTOCOL));
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_LINK |
                                             MODBUS_ERROR_RECOVERY_PROTOCOL));
    CHECK(modbus_set_error_recovery(ctx, (modbus_error_recovery_mode) 99));
    CHECK(modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE));

    CHECK(modbus_get_socket(ctx));
    CHECK(modbus_set_socket(ctx, 42));
    CHECK(modbus_get_socket(ctx));
    CHECK(modbus_set_socket(ctx, -5));
    CHECK(modbus_get_socket(ctx));
    CHECK(modbus_set_socket(ctx, -1));
    CHECK(modbus_get_socket(ctx));

    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_set_debug(ctx, 5));
    CHECK(modbus_set_debug(ctx, FALSE));

    timeouts(ctx);
}

static void rtu_specific(modbus_t *ctx)
{
    CHECK(modbus_rtu_get_serial_mode(ctx));
    CHECK(modbus_rtu_set_serial_mode(ctx, 5));
    CHECK(modbus_rtu_set_serial_mode(ctx, -1));
    /* Before connect: the ioctl runs on fd -1. */
    CHECK(modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS485));
    CHECK(modbus_rtu_get_serial_mode(ctx));
    CHECK(modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS232));
    CHECK(modbus_rtu_get_rts(ctx));
    CHECK(modbus_rtu_set_rts(ctx, 3));
    CHECK(modbus_rtu_set_rts(ctx, -1));
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_UP));
    CHECK(modbus_rtu_get_rts(ctx));
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_DOWN));
    CHECK(modbus_rtu_get_rts(ctx));
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_NONE));
    CHECK(modbus_rtu_get_rts(ctx));
    CHECK(modbus_rtu_get_rts_delay(ctx));
    CHECK(modbus_rtu_set_rts_delay(ctx, -1));
    CHECK(modbus_rtu_set_rts_delay(ctx, 0));
    CHECK(modbus_rtu_get_rts_delay(ctx));
    CHECK(modbus_rtu_set_rts_delay(ctx, 12345));
    CHECK(modbus_rtu_get_rts_delay(ctx));
    CHECK(modbus_rtu_set_custom_rts(ctx, NULL));
}

static void rtu_on_tcp(modbus_t *ctx)
{
    CHECK(modbus_rtu_get_serial_mode(ctx));
    CHECK(modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS232));
    CHECK(modbus_rtu_get_rts(ctx));
    CHECK(modbus_rtu_set_rts(ctx, MODBUS_RTU_RTS_NONE));
    CHECK(modbus_rtu_get_rts_delay(ctx));
    CHECK(modbus_rtu_set_rts_delay(ctx, 10));
    CHECK(modbus_rtu_set_custom_rts(ctx, NULL));
}

static void null_ctx(void)
{
    uint32_t s = 0, us = 0;
    uint8_t b[8];
    uint16_t r[8];
    int fd = 3;

    mbt_section("NULL context");
    CHECK(modbus_connect(NULL));
    CALL(modbus_close(NULL));
    CALL(modbus_free(NULL));
    CHECK(modbus_flush(NULL));
    CHECK(modbus_set_slave(NULL, 1));
    CHECK(modbus_get_slave(NULL));
    CHECK(modbus_set_error_recovery(NULL, MODBUS_ERROR_RECOVERY_NONE));
    CHECK(modbus_set_socket(NULL, 3));
    CHECK(modbus_get_socket(NULL));
    CHECK(modbus_get_response_timeout(NULL, &s, &us));
    CHECK(modbus_set_response_timeout(NULL, 1, 0));
    CHECK(modbus_get_byte_timeout(NULL, &s, &us));
    CHECK(modbus_set_byte_timeout(NULL, 1, 0));
    CHECK(modbus_get_indication_timeout(NULL, &s, &us));
    CHECK(modbus_set_indication_timeout(NULL, 1, 0));
    CHECK(modbus_get_header_length(NULL));
    CHECK(modbus_set_debug(NULL, TRUE));
    CHECK(modbus_read_bits(NULL, 0, 1, b));
    CHECK(modbus_read_input_bits(NULL, 0, 1, b));
    CHECK(modbus_read_registers(NULL, 0, 1, r));
    CHECK(modbus_read_input_registers(NULL, 0, 1, r));
    CHECK(modbus_write_bit(NULL, 0, 1));
    CHECK(modbus_write_register(NULL, 0, 1));
    CHECK(modbus_write_bits(NULL, 0, 1, b));
    CHECK(modbus_write_registers(NULL, 0, 1, r));
    CHECK(modbus_write_and_read_registers(NULL, 0, 1, r, 0, 1, r));
    CHECK(modbus_report_slave_id(NULL, 8, b));
    CHECK(modbus_send_raw_request(NULL, b, 2));
    CHECK(modbus_receive_confirmation(NULL, b));
    CHECK(modbus_receive(NULL, b));
    CHECK(modbus_reply(NULL, b, 2, NULL));
    CHECK(modbus_reply_exception(NULL, b, 1));
    CHECK(modbus_rtu_set_serial_mode(NULL, 0));
    CHECK(modbus_rtu_get_serial_mode(NULL));
    CHECK(modbus_rtu_set_rts(NULL, 0));
    CHECK(modbus_rtu_get_rts(NULL));
    CHECK(modbus_rtu_set_custom_rts(NULL, NULL));
    CHECK(modbus_rtu_set_rts_delay(NULL, 0));
    CHECK(modbus_rtu_get_rts_delay(NULL));
    CHECK(modbus_tcp_listen(NULL, 1));
    CHECK(modbus_tcp_accept(NULL, &fd));
    CHECK(modbus_tcp_pi_listen(NULL, 1));
    CHECK(modbus_tcp_pi_accept(NULL, &fd));
    CALL(modbus_mapping_free(NULL));
}

static void strerrors(void)
{
    int e;
    mbt_section("modbus_strerror");
    for (e = MODBUS_ENOBASE - 1; e <= MODBUS_ENOBASE + 20; e++) {
        printf("strerror(%d) = \"%s\"\n", e, modbus_strerror(e));
    }
    printf("strerror(0) = \"%s\"\n", modbus_strerror(0));
    printf("strerror(EINVAL) = \"%s\"\n", modbus_strerror(EINVAL));
    printf("strerror(ETIMEDOUT) = \"%s\"\n", modbus_strerror(ETIMEDOUT));
    printf("strerror(ECONNRESET) = \"%s\"\n", modbus_strerror(ECONNRESET));
    printf("strerror(ENOPROTOOPT) = \"%s\"\n", modbus_strerror(ENOPROTOOPT));
    printf("strerror(-1) = \"%s\"\n", modbus_strerror(-1));
    printf("strerror(4000) = \"%s\"\n", modbus_strerror(4000));
    printf("strerror(2147483647) = \"%s\"\n", modbus_strerror(2147483647));
}

static void data_helpers(void)
{
    uint8_t dest[40];
    const uint8_t tab[3] = {0xA5, 0x3C, 0x81};
    const uint16_t abcd[2] = {0x47F1, 0x2000};
    const uint16_t dcba[2] = {0x0020, 0xF147};
    const uint16_t badc[2] = {0xF147, 0x0020};
    const uint16_t cdab[2] = {0x2000, 0x47F1};
    const float values[] = {123456.0f, -1.5f, 0.0f, 3.14159265f};
    uint16_t regs[2];
    char got[64];
    unsigned int k;
    int i;

    mbt_section("bit helpers");
    memset(dest, 0x77, sizeof(dest));
    CALL(modbus_set_bits_from_byte(dest, 0, 0xA5));
    mbt_dump_u8("dest", dest, 12);
    CALL(modbus_set_bits_from_byte(dest, 3, 0x00));
    mbt_dump_u8("dest", dest, 12);
    memset(dest, 0x77, sizeof(dest));
    CALL(modbus_set_bits_from_bytes(dest, 2, 19, tab));
    mbt_dump_u8("dest", dest, 24);
    CALL(modbus_set_bits_from_bytes(dest, 0, 0, tab));
    mbt_dump_u8("dest", dest, 4);
    for (i = 0; i <= 8; i++) {
        printf("get_byte_from_bits(dest, 2, %d) = 0x%02X\n", i,
               modbus_get_byte_from_bits(dest, 2, (unsigned int) i));
    }
    printf("get_byte_from_bits(dest, 10, 8) = 0x%02X\n", modbus_get_byte_from_bits(dest, 10, 8));

    mbt_section("float getters");
    mbt_print_float("get_float_abcd({47F1,2000})", modbus_get_float_abcd(abcd));
    mbt_print_float("get_float_dcba({0020,F147})", modbus_get_float_dcba(dcba));
    mbt_print_float("get_float_badc({F147,0020})", modbus_get_float_badc(badc));
    mbt_print_float("get_float_cdab({2000,47F1})", modbus_get_float_cdab(cdab));
    mbt_print_float("get_float({2000,47F1})", modbus_get_float(cdab));
    mbt_print_float("get_float_abcd({2000,47F1})", modbus_get_float_abcd(cdab));
    mbt_print_float("get_float_dcba({47F1,2000})", modbus_get_float_dcba(abcd));

    mbt_section("float setters");
    for (k = 0; k < sizeof(values) / sizeof(values[0]); k++) {
        float f = values[k];
        uint32_t bits;
        uint16_t hi, lo, shi, slo;
        char deb[64], ours[64];
        memcpy(&bits, &f, sizeof(bits));
        hi = (uint16_t) (bits >> 16);
        lo = (uint16_t) bits;
        /* byte-swapped halves: the 3.1.6-deb (3.1.8..3.1.10) setter output */
        shi = (uint16_t) ((hi << 8) | (hi >> 8));
        slo = (uint16_t) ((lo << 8) | (lo >> 8));
        printf("value %.6f bits 0x%08X\n", (double) f, bits);

        modbus_set_float_abcd(f, regs);
        snprintf(got, sizeof(got), "abcd {%04X,%04X}", regs[0], regs[1]);
        snprintf(deb, sizeof(deb), "abcd {%04X,%04X}", shi, slo);
        snprintf(ours, sizeof(ours), "abcd {%04X,%04X}", hi, lo);
        mbt_diff_value("float-setters", got, deb, ours);
        {
            /* Round trip: identity with 3.1.12; with 3.1.6-deb the bytes of each half
             * come back swapped. */
            float back = modbus_get_float_abcd(regs);
            uint32_t bb;
            memcpy(&bb, &back, sizeof(bb));
            snprintf(got, sizeof(got), "get_float_abcd(set_float_abcd) bits 0x%08X", bb);
            snprintf(deb, sizeof(deb), "get_float_abcd(set_float_abcd) bits 0x%08X",
                     ((uint32_t) shi << 16) | slo);
            snprintf(ours, sizeof(ours), "get_float_abcd(set_float_abcd) bits 0x%08X", bits);
            mbt_diff_value("float-setters", got, deb, ours);
        }

        modbus_set_float_dcba(f, regs);
        snprintf(got, sizeof(got), "dcba {%04X,%04X}", regs[0], regs[1]);
        snprintf(deb, sizeof(deb), "dcba {%04X,%04X}", (uint16_t) (slo >> 8 | slo << 8),
                 (uint16_t) (shi >> 8 | shi << 8));
        snprintf(ours, sizeof(ours), "dcba {%04X,%04X}", slo, shi);
        mbt_diff_value("float-setters", got, deb, ours);

        modbus_set_float_badc(f, regs);
        snprintf(got, sizeof(got), "badc {%04X,%04X}", regs[0], regs[1]);
        snprintf(deb, sizeof(deb), "badc {%04X,%04X}", hi, lo);
        snprintf(ours, sizeof(ours), "badc {%04X,%04X}", shi, slo);
        mbt_diff_value("float-setters", got, deb, ours);

        modbus_set_float_cdab(f, regs);
        snprintf(got, sizeof(got), "cdab {%04X,%04X}", regs[0], regs[1]);
        snprintf(deb, sizeof(deb), "cdab {%04X,%04X}", slo, shi);
        snprintf(ours, sizeof(ours), "cdab {%04X,%04X}", lo, hi);
        mbt_diff_value("float-setters", got, deb, ours);

        modbus_set_float(f, regs);
        printf("set_float -> {%04X,%04X}\n", regs[0], regs[1]);
        mbt_print_float("  get_float(set)", modbus_get_float(regs));
    }
}

static void constructors(void)
{
    modbus_t *ctx;
    char longnode[1100];
    char longservice[40];

    mbt_section("modbus_new_rtu");
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_rtu(NULL, 9600, 'N', 8, 1));
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_rtu("", 9600, 'N', 8, 1));
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 0, 'N', 8, 1));
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 9600, 'X', 8, 1));
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 9600, 'n', 8, 1));
    modbus_free(ctx);
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 9600, 'E', 5, 2));
    modbus_free(ctx);
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", -9600, 'O', 99, 99));
    modbus_free(ctx);

    mbt_section("modbus_new_tcp");
    CHECK_PTR(ctx, modbus_new_tcp(NULL, 502));
    modbus_free(ctx);
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_tcp("", 502));
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_tcp("255.255.255.255", 502));
    modbus_free(ctx);
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_tcp("1234567890123456", 502));
    fflush(stdout);
    CHECK_PTR(ctx, modbus_new_tcp("not-an-ip", -1));
    modbus_free(ctx);
    CHECK_PTR(ctx, modbus_new_tcp("127.0.0.1", 70000));
    modbus_free(ctx);

    mbt_section("modbus_new_tcp_pi");
    memset(longnode, 'a', sizeof(longnode));
    longnode[sizeof(longnode) - 1] = '\0';
    memset(longservice, '1', sizeof(longservice));
    longservice[sizeof(longservice) - 1] = '\0';
    CHECK_PTR(ctx, modbus_new_tcp_pi("::1", "1502"));
    modbus_free(ctx);
    CHECK_PTR(ctx, modbus_new_tcp_pi(NULL, "1502"));
    modbus_free(ctx);
    /* 3.1.6 rejects an empty node, a NULL/empty service and over-long strings (fixed
     * arrays); 3.1.8+ strdup()s them and defaults the service to "502". */
    {
        struct {
            const char *label;
            const char *node;
            const char *service;
        } cases[] = {
            {"(NULL, NULL)", NULL, NULL},
            {"(\"::1\", NULL)", "::1", NULL},
            {"(\"::1\", \"\")", "::1", ""},
            {"(\"\", \"502\")", "", "502"},
            {"(long node, \"502\")", longnode, "502"},
            {"(\"::1\", long service)", "::1", longservice},
        };
        unsigned int i;
        for (i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
            char got[96];
            int err;
            mbt_diff_begin(NULL, "tcp-pi-strings");
            fflush(stdout);
            errno = 0;
            ctx = modbus_new_tcp_pi(cases[i].node, cases[i].service);
            err = errno;
            fflush(stderr);
            mbt_diff_end(NULL, "tcp-pi-strings");
            snprintf(got, sizeof(got), "modbus_new_tcp_pi%s = %s", cases[i].label,
                     ctx ? "ctx" : (err == EINVAL ? "NULL EINVAL" : "NULL other"));
            {
                char deb[96], ours[96];
                snprintf(deb, sizeof(deb), "modbus_new_tcp_pi%s = NULL EINVAL", cases[i].label);
                snprintf(ours, sizeof(ours), "modbus_new_tcp_pi%s = ctx", cases[i].label);
                mbt_diff_value("tcp-pi-strings", got, deb, ours);
            }
            modbus_free(ctx);
        }
    }
}

int main(void)
{
    modbus_t *ctx;
    char got[64];

    mbt_section("version objects");
    snprintf(got, sizeof(got), "%u.%u.%u", libmodbus_version_major, libmodbus_version_minor,
             libmodbus_version_micro);
    mbt_diff_value("version-3.1.12", got, "3.1.6", "3.1.12");
    printf("header LIBMODBUS_VERSION_STRING %s\n", LIBMODBUS_VERSION_STRING);

    constructors();

    mbt_section("TCP context settings");
    CHECK_PTR(ctx, modbus_new_tcp("127.0.0.1", 1502));
    common_setters(ctx);
    rtu_on_tcp(ctx);
    modbus_free(ctx);

    mbt_section("TCP PI context settings");
    CHECK_PTR(ctx, modbus_new_tcp_pi("::1", "1502"));
    common_setters(ctx);
    modbus_free(ctx);

    mbt_section("RTU context settings");
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 9600, 'N', 8, 1));
    common_setters(ctx);
    rtu_specific(ctx);
    modbus_free(ctx);
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 19200, 'E', 7, 2));
    CHECK(modbus_rtu_get_rts_delay(ctx));
    modbus_free(ctx);
    CHECK_PTR(ctx, modbus_new_rtu("/dev/null", 115200, 'N', 8, 1));
    CHECK(modbus_rtu_get_rts_delay(ctx));
    /* connect on a non-tty: tcsetattr fails with ENOTTY */
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    CHECK(modbus_get_socket(ctx));
    modbus_close(ctx);
    modbus_free(ctx);

    null_ctx();
    strerrors();
    data_helpers();
    printf("END\n");
    return 0;
}
