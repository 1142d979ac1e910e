/*
 * abi-probe.c: print every ABI-relevant fact that the libmodbus headers define.
 *
 * The program is compiled twice, once against Debian's libmodbus headers
 * (-I/usr/include/modbus) and once against rsmodbus' generated headers
 * (-Iinclude), and c-tests/suites/abi.sh diffs the two outputs. Only the
 * differences named in abi/abi-probe-intended-differences.txt are accepted.
 *
 * It needs no library at run time: it only evaluates the headers' constants,
 * enums, struct layout and macros, and checks the type of every declared
 * function at compile time (no function is called or referenced).
 *
 * Output: one "KEY = VALUE" line per fact, KEY being unique. Build with
 * -Wall -Wextra -Werror (and -std=gnu11 or later).
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <modbus.h>

#define STR_(x) #x
#define STR(x) STR_(x)

#define PRINT_INT(name) printf("%s = %lld\n", #name, (long long) (name))
#define PRINT_SIZE(key, value) printf("%s = %zu\n", key, (size_t) (value))

/* Reads through a volatile pointer so that sample inputs are not constant-folded. */
static int16_t i16(volatile const int16_t *p) { return *p; }

/*
 * Compile-time signature checks: each function's declared type must be exactly
 * the libmodbus 3.1.x type (top-level parameter qualifiers do not count, as in C).
 * A mismatch is a compile error, so the probe fails to build.
 */
#define SIG(fn, type)                                                                     \
    _Static_assert(__builtin_types_compatible_p(__typeof__(&fn), type), #fn " has the wrong type"); \
    static const char sig_##fn[] = #fn;

SIG(modbus_set_slave, int (*)(modbus_t *, int))
SIG(modbus_get_slave, int (*)(modbus_t *))
SIG(modbus_set_error_recovery, int (*)(modbus_t *, modbus_error_recovery_mode))
SIG(modbus_set_socket, int (*)(modbus_t *, int))
SIG(modbus_get_socket, int (*)(modbus_t *))
SIG(modbus_get_response_timeout, int (*)(modbus_t *, uint32_t *, uint32_t *))
SIG(modbus_set_response_timeout, int (*)(modbus_t *, uint32_t, uint32_t))
SIG(modbus_get_byte_timeout, int (*)(modbus_t *, uint32_t *, uint32_t *))
SIG(modbus_set_byte_timeout, int (*)(modbus_t *, uint32_t, uint32_t))
SIG(modbus_get_indication_timeout, int (*)(modbus_t *, uint32_t *, uint32_t *))
SIG(modbus_set_indication_timeout, int (*)(modbus_t *, uint32_t, uint32_t))
SIG(modbus_get_header_length, int (*)(modbus_t *))
SIG(modbus_connect, int (*)(modbus_t *))
SIG(modbus_close, void (*)(modbus_t *))
SIG(modbus_free, void (*)(modbus_t *))
SIG(modbus_flush, int (*)(modbus_t *))
SIG(modbus_set_debug, int (*)(modbus_t *, int))
SIG(modbus_strerror, const char *(*)(int))
SIG(modbus_read_bits, int (*)(modbus_t *, int, int, uint8_t *))
SIG(modbus_read_input_bits, int (*)(modbus_t *, int, int, uint8_t *))
SIG(modbus_read_registers, int (*)(modbus_t *, int, int, uint16_t *))
SIG(modbus_read_input_registers, int (*)(modbus_t *, int, int, uint16_t *))
SIG(modbus_write_bit, int (*)(modbus_t *, int, int))
SIG(modbus_write_register, int (*)(modbus_t *, int, uint16_t))
SIG(modbus_write_bits, int (*)(modbus_t *, int, int, const uint8_t *))
SIG(modbus_write_registers, int (*)(modbus_t *, int, int, const uint16_t *))
SIG(modbus_mask_write_register, int (*)(modbus_t *, int, uint16_t, uint16_t))
SIG(modbus_write_and_read_registers,
    int (*)(modbus_t *, int, int, const uint16_t *, int, int, uint16_t *))
SIG(modbus_report_slave_id, int (*)(modbus_t *, int, uint8_t *))
SIG(modbus_mapping_new_start_address,
    modbus_mapping_t *(*) (unsigned int, unsigned int, unsigned int, unsigned int, unsigned int,
                           unsigned int, unsigned int, unsigned int))
SIG(modbus_mapping_new, modbus_mapping_t *(*) (int, int, int, int))
SIG(modbus_mapping_free, void (*)(modbus_mapping_t *))
SIG(modbus_send_raw_request, int (*)(modbus_t *, const uint8_t *, int))
SIG(modbus_receive, int (*)(modbus_t *, uint8_t *))
SIG(modbus_receive_confirmation, int (*)(modbus_t *, uint8_t *))
SIG(modbus_reply, int (*)(modbus_t *, const uint8_t *, int, modbus_mapping_t *))
SIG(modbus_reply_exception, int (*)(modbus_t *, const uint8_t *, unsigned int))
SIG(modbus_set_bits_from_byte, void (*)(uint8_t *, int, uint8_t))
SIG(modbus_set_bits_from_bytes, void (*)(uint8_t *, int, unsigned int, const uint8_t *))
SIG(modbus_get_byte_from_bits, uint8_t (*)(const uint8_t *, int, unsigned int))
SIG(modbus_get_float, float (*)(const uint16_t *))
SIG(modbus_get_float_abcd, float (*)(const uint16_t *))
SIG(modbus_get_float_dcba, float (*)(const uint16_t *))
SIG(modbus_get_float_badc, float (*)(const uint16_t *))
SIG(modbus_get_float_cdab, float (*)(const uint16_t *))
SIG(modbus_set_float, void (*)(float, uint16_t *))
SIG(modbus_set_float_abcd, void (*)(float, uint16_t *))
SIG(modbus_set_float_dcba, void (*)(float, uint16_t *))
SIG(modbus_set_float_badc, void (*)(float, uint16_t *))
SIG(modbus_set_float_cdab, void (*)(float, uint16_t *))
SIG(modbus_new_rtu, modbus_t *(*) (const char *, int, char, int, int))
SIG(modbus_rtu_set_serial_mode, int (*)(modbus_t *, int))
SIG(modbus_rtu_get_serial_mode, int (*)(modbus_t *))
SIG(modbus_rtu_set_rts, int (*)(modbus_t *, int))
SIG(modbus_rtu_get_rts, int (*)(modbus_t *))
SIG(modbus_rtu_set_custom_rts, int (*)(modbus_t *, void (*)(modbus_t *, int)))
SIG(modbus_rtu_set_rts_delay, int (*)(modbus_t *, int))
SIG(modbus_rtu_get_rts_delay, int (*)(modbus_t *))
SIG(modbus_new_tcp, modbus_t *(*) (const char *, int))
SIG(modbus_tcp_listen, int (*)(modbus_t *, int))
SIG(modbus_tcp_accept, int (*)(modbus_t *, int *))
SIG(modbus_new_tcp_pi, modbus_t *(*) (const char *, const char *))
SIG(modbus_tcp_pi_listen, int (*)(modbus_t *, int))
SIG(modbus_tcp_pi_accept, int (*)(modbus_t *, int *))
#if LIBMODBUS_VERSION_CHECK(3, 1, 9)
SIG(modbus_enable_quirks, int (*)(modbus_t *, unsigned int))
SIG(modbus_disable_quirks, int (*)(modbus_t *, unsigned int))
#endif
#if LIBMODBUS_VERSION_CHECK(3, 1, 11)
SIG(modbus_send_raw_request_tid, int (*)(modbus_t *, const uint8_t *, int, int))
#endif

_Static_assert(__builtin_types_compatible_p(__typeof__(libmodbus_version_major), const unsigned int),
               "libmodbus_version_major has the wrong type");
_Static_assert(__builtin_types_compatible_p(__typeof__(libmodbus_version_minor), const unsigned int),
               "libmodbus_version_minor has the wrong type");
_Static_assert(__builtin_types_compatible_p(__typeof__(libmodbus_version_micro), const unsigned int),
               "libmodbus_version_micro has the wrong type");

static const char *const signatures_checked[] = {
    sig_modbus_set_slave, sig_modbus_get_slave, sig_modbus_set_error_recovery,
    sig_modbus_set_socket, sig_modbus_get_socket, sig_modbus_get_response_timeout,
    sig_modbus_set_response_timeout, sig_modbus_get_byte_timeout, sig_modbus_set_byte_timeout,
    sig_modbus_get_indication_timeout, sig_modbus_set_indication_timeout,
    sig_modbus_get_header_length, sig_modbus_connect, sig_modbus_close, sig_modbus_free,
    sig_modbus_flush, sig_modbus_set_debug, sig_modbus_strerror, sig_modbus_read_bits,
    sig_modbus_read_input_bits, sig_modbus_read_registers, sig_modbus_read_input_registers,
    sig_modbus_write_bit, sig_modbus_write_register, sig_modbus_write_bits,
    sig_modbus_write_registers, sig_modbus_mask_write_register,
    sig_modbus_write_and_read_registers, sig_modbus_report_slave_id,
    sig_modbus_mapping_new_start_address, sig_modbus_mapping_new, sig_modbus_mapping_free,
    sig_modbus_send_raw_request, sig_modbus_receive, sig_modbus_receive_confirmation,
    sig_modbus_reply, sig_modbus_reply_exception, sig_modbus_set_bits_from_byte,
    sig_modbus_set_bits_from_bytes, sig_modbus_get_byte_from_bits, sig_modbus_get_float,
    sig_modbus_get_float_abcd, sig_modbus_get_float_dcba, sig_modbus_get_float_badc,
    sig_modbus_get_float_cdab, sig_modbus_set_float, sig_modbus_set_float_abcd,
    sig_modbus_set_float_dcba, sig_modbus_set_float_badc, sig_modbus_set_float_cdab,
    sig_modbus_new_rtu, sig_modbus_rtu_set_serial_mode, sig_modbus_rtu_get_serial_mode,
    sig_modbus_rtu_set_rts, sig_modbus_rtu_get_rts, sig_modbus_rtu_set_custom_rts,
    sig_modbus_rtu_set_rts_delay, sig_modbus_rtu_get_rts_delay, sig_modbus_new_tcp,
    sig_modbus_tcp_listen, sig_modbus_tcp_accept, sig_modbus_new_tcp_pi,
    sig_modbus_tcp_pi_listen, sig_modbus_tcp_pi_accept,
#if LIBMODBUS_VERSION_CHECK(3, 1, 9)
    sig_modbus_enable_quirks, sig_modbus_disable_quirks,
#endif
#if LIBMODBUS_VERSION_CHECK(3, 1, 11)
    sig_modbus_send_raw_request_tid,
#endif
};

static void print_layout(void)
{
    PRINT_SIZE("sizeof(modbus_mapping_t)", sizeof(modbus_mapping_t));
    PRINT_SIZE("alignof(modbus_mapping_t)", _Alignof(modbus_mapping_t));
#define FIELD(f)                                                                 \
    PRINT_SIZE("offsetof(modbus_mapping_t, " #f ")", offsetof(modbus_mapping_t, f)); \
    PRINT_SIZE("sizeof(modbus_mapping_t." #f ")", sizeof(((modbus_mapping_t *) 0)->f))
    FIELD(nb_bits);
    FIELD(start_bits);
    FIELD(nb_input_bits);
    FIELD(start_input_bits);
    FIELD(nb_input_registers);
    FIELD(start_input_registers);
    FIELD(nb_registers);
    FIELD(start_registers);
    FIELD(tab_bits);
    FIELD(tab_input_bits);
    FIELD(tab_input_registers);
    FIELD(tab_registers);
#undef FIELD
    /* The pointee types matter as much as the sizes. */
    printf("type(modbus_mapping_t.tab_bits) = %s\n",
           _Generic(((modbus_mapping_t *) 0)->tab_bits, uint8_t *: "uint8_t *", default: "other"));
    printf("type(modbus_mapping_t.tab_input_bits) = %s\n",
           _Generic(((modbus_mapping_t *) 0)->tab_input_bits, uint8_t *: "uint8_t *",
                    default: "other"));
    printf("type(modbus_mapping_t.tab_input_registers) = %s\n",
           _Generic(((modbus_mapping_t *) 0)->tab_input_registers, uint16_t *: "uint16_t *",
                    default: "other"));
    printf("type(modbus_mapping_t.tab_registers) = %s\n",
           _Generic(((modbus_mapping_t *) 0)->tab_registers, uint16_t *: "uint16_t *",
                    default: "other"));
    PRINT_SIZE("sizeof(modbus_error_recovery_mode)", sizeof(modbus_error_recovery_mode));
#if LIBMODBUS_VERSION_CHECK(3, 1, 9)
    PRINT_SIZE("sizeof(modbus_quirks)", sizeof(modbus_quirks));
#endif
}

static void print_constants(void)
{
    PRINT_INT(FALSE);
    PRINT_INT(TRUE);
    PRINT_INT(OFF);
    PRINT_INT(ON);

    PRINT_INT(MODBUS_FC_READ_COILS);
    PRINT_INT(MODBUS_FC_READ_DISCRETE_INPUTS);
    PRINT_INT(MODBUS_FC_READ_HOLDING_REGISTERS);
    PRINT_INT(MODBUS_FC_READ_INPUT_REGISTERS);
    PRINT_INT(MODBUS_FC_WRITE_SINGLE_COIL);
    PRINT_INT(MODBUS_FC_WRITE_SINGLE_REGISTER);
    PRINT_INT(MODBUS_FC_READ_EXCEPTION_STATUS);
    PRINT_INT(MODBUS_FC_WRITE_MULTIPLE_COILS);
    PRINT_INT(MODBUS_FC_WRITE_MULTIPLE_REGISTERS);
    PRINT_INT(MODBUS_FC_REPORT_SLAVE_ID);
    PRINT_INT(MODBUS_FC_MASK_WRITE_REGISTER);
    PRINT_INT(MODBUS_FC_WRITE_AND_READ_REGISTERS);

    PRINT_INT(MODBUS_BROADCAST_ADDRESS);
    PRINT_INT(MODBUS_MAX_READ_BITS);
    PRINT_INT(MODBUS_MAX_WRITE_BITS);
    PRINT_INT(MODBUS_MAX_READ_REGISTERS);
    PRINT_INT(MODBUS_MAX_WRITE_REGISTERS);
    PRINT_INT(MODBUS_MAX_WR_WRITE_REGISTERS);
    PRINT_INT(MODBUS_MAX_WR_READ_REGISTERS);
    PRINT_INT(MODBUS_MAX_PDU_LENGTH);
    PRINT_INT(MODBUS_MAX_ADU_LENGTH);
    PRINT_INT(MODBUS_ENOBASE);

    PRINT_INT(MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    PRINT_INT(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    PRINT_INT(MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
    PRINT_INT(MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
    PRINT_INT(MODBUS_EXCEPTION_ACKNOWLEDGE);
    PRINT_INT(MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
    PRINT_INT(MODBUS_EXCEPTION_NEGATIVE_ACKNOWLEDGE);
    PRINT_INT(MODBUS_EXCEPTION_MEMORY_PARITY);
    PRINT_INT(MODBUS_EXCEPTION_NOT_DEFINED);
    PRINT_INT(MODBUS_EXCEPTION_GATEWAY_PATH);
    PRINT_INT(MODBUS_EXCEPTION_GATEWAY_TARGET);
    PRINT_INT(MODBUS_EXCEPTION_MAX);

    PRINT_INT(EMBXILFUN);
    PRINT_INT(EMBXILADD);
    PRINT_INT(EMBXILVAL);
    PRINT_INT(EMBXSFAIL);
    PRINT_INT(EMBXACK);
    PRINT_INT(EMBXSBUSY);
    PRINT_INT(EMBXNACK);
    PRINT_INT(EMBXMEMPAR);
    PRINT_INT(EMBXGPATH);
    PRINT_INT(EMBXGTAR);
    PRINT_INT(EMBBADCRC);
    PRINT_INT(EMBBADDATA);
    PRINT_INT(EMBBADEXC);
    PRINT_INT(EMBUNKEXC);
    PRINT_INT(EMBMDATA);
    PRINT_INT(EMBBADSLAVE);

    PRINT_INT(MODBUS_ERROR_RECOVERY_NONE);
    PRINT_INT(MODBUS_ERROR_RECOVERY_LINK);
    PRINT_INT(MODBUS_ERROR_RECOVERY_PROTOCOL);
#if LIBMODBUS_VERSION_CHECK(3, 1, 9)
    PRINT_INT(MODBUS_QUIRK_NONE);
    PRINT_INT(MODBUS_QUIRK_MAX_SLAVE);
    PRINT_INT(MODBUS_QUIRK_REPLY_TO_BROADCAST);
    PRINT_INT(MODBUS_QUIRK_ALL);
#endif

    PRINT_INT(MODBUS_RTU_MAX_ADU_LENGTH);
    PRINT_INT(MODBUS_RTU_RS232);
    PRINT_INT(MODBUS_RTU_RS485);
    PRINT_INT(MODBUS_RTU_RTS_NONE);
    PRINT_INT(MODBUS_RTU_RTS_UP);
    PRINT_INT(MODBUS_RTU_RTS_DOWN);

    PRINT_INT(MODBUS_TCP_DEFAULT_PORT);
    PRINT_INT(MODBUS_TCP_SLAVE);
    PRINT_INT(MODBUS_TCP_MAX_ADU_LENGTH);

    /* Macros that must expand to nothing in C. */
    printf("MODBUS_API = \"%s\"\n", STR(MODBUS_API));
    printf("MODBUS_BEGIN_DECLS = \"%s\"\n", STR(MODBUS_BEGIN_DECLS));
    printf("MODBUS_END_DECLS = \"%s\"\n", STR(MODBUS_END_DECLS));
}

static void print_version(void)
{
    PRINT_INT(LIBMODBUS_VERSION_MAJOR);
    PRINT_INT(LIBMODBUS_VERSION_MINOR);
    PRINT_INT(LIBMODBUS_VERSION_MICRO);
    printf("LIBMODBUS_VERSION = %s\n", STR(LIBMODBUS_VERSION));
    printf("LIBMODBUS_VERSION_STRING = \"%s\"\n", LIBMODBUS_VERSION_STRING);
    printf("LIBMODBUS_VERSION_HEX = 0x%06llx\n", (unsigned long long) LIBMODBUS_VERSION_HEX);
#define PRINT_VERSION_CHECK(a, b, c)                                                         \
    printf("LIBMODBUS_VERSION_CHECK(%d,%d,%d) = %d\n", a, b, c, (int) LIBMODBUS_VERSION_CHECK(a, b, c))
    PRINT_VERSION_CHECK(2, 9, 9);
    PRINT_VERSION_CHECK(3, 0, 99);
    PRINT_VERSION_CHECK(3, 1, 0);
    PRINT_VERSION_CHECK(3, 1, 5);
    PRINT_VERSION_CHECK(3, 1, 6);
    PRINT_VERSION_CHECK(3, 1, 7);
    PRINT_VERSION_CHECK(3, 1, 12);
    PRINT_VERSION_CHECK(3, 1, 13);
    PRINT_VERSION_CHECK(3, 2, 0);
    PRINT_VERSION_CHECK(4, 0, 0);
#undef PRINT_VERSION_CHECK
}

static void print_hex_u8(const char *key, const uint8_t *t, int n)
{
    int i;
    printf("%s =", key);
    for (i = 0; i < n; i++) {
        printf(" %02x", t[i]);
    }
    printf("\n");
}

static void print_hex_u16(const char *key, const uint16_t *t, int n)
{
    int i;
    printf("%s =", key);
    for (i = 0; i < n; i++) {
        printf(" %04x", t[i]);
    }
    printf("\n");
}

static void print_macros(void)
{
    static volatile const int16_t neg_src[4] = {0, 0, 1, -1};
    const uint16_t u16[4] = {0x1234, 0x5678, 0x9abc, 0xdef0};
    const uint16_t u16_high[4] = {0x7edc, 0xba98, 0x7654, 0x3210};
    const uint8_t u8[2] = {0x12, 0x34};
    const uint8_t u8_high[2] = {0xfe, 0xdc};
    int16_t s16[4];
    int8_t s8[2];
    uint8_t out8[2];
    uint16_t out16[4];
    /* Inputs of the SET macros live in volatile objects: with constants, the 3.1.6
       macro forms trigger -Woverflow, which -Werror would turn into an error. */
    volatile int32_t v16 = 0x1234, v16_neg = -2;
    volatile int32_t v32 = 0x12345678, v32_neg = -2;
    volatile int64_t v64 = (int64_t) 0x123456789abcdef0LL, v64_neg = -2;
    int i;

    for (i = 0; i < 4; i++) {
        s16[i] = i16(&neg_src[i]);
    }
    s8[0] = 1;
    s8[1] = (int8_t) s16[3];

    printf("MODBUS_GET_HIGH_BYTE(0x1234) = 0x%x\n", (unsigned) MODBUS_GET_HIGH_BYTE(0x1234));
    printf("MODBUS_GET_LOW_BYTE(0x1234) = 0x%x\n", (unsigned) MODBUS_GET_LOW_BYTE(0x1234));
    printf("MODBUS_GET_HIGH_BYTE(0xfedc) = 0x%x\n", (unsigned) MODBUS_GET_HIGH_BYTE(0xfedc));
    printf("MODBUS_GET_LOW_BYTE(0xfedc) = 0x%x\n", (unsigned) MODBUS_GET_LOW_BYTE(0xfedc));

    printf("MODBUS_GET_INT64_FROM_INT16(u16{1234,5678,9abc,def0}) = 0x%016llx\n",
           (unsigned long long) MODBUS_GET_INT64_FROM_INT16(u16, 0));
    printf("MODBUS_GET_INT64_FROM_INT16(u16{7edc,ba98,7654,3210}) = 0x%016llx\n",
           (unsigned long long) MODBUS_GET_INT64_FROM_INT16(u16_high, 0));
    printf("MODBUS_GET_INT64_FROM_INT16(s16{0,0,1,-1}) = %lld\n",
           (long long) MODBUS_GET_INT64_FROM_INT16(s16, 0));
    printf("sizeof(MODBUS_GET_INT64_FROM_INT16) = %zu\n", sizeof(MODBUS_GET_INT64_FROM_INT16(u16, 0)));

    printf("MODBUS_GET_INT32_FROM_INT16(u16{1234,5678}) = 0x%08lx\n",
           (unsigned long) (uint32_t) MODBUS_GET_INT32_FROM_INT16(u16, 0));
    printf("MODBUS_GET_INT32_FROM_INT16(u16{5678,9abc}) = 0x%08lx\n",
           (unsigned long) (uint32_t) MODBUS_GET_INT32_FROM_INT16(u16, 1));
    printf("MODBUS_GET_INT32_FROM_INT16(s16{1,-1}) = %ld\n",
           (long) MODBUS_GET_INT32_FROM_INT16(s16, 2));
    printf("sizeof(MODBUS_GET_INT32_FROM_INT16) = %zu\n", sizeof(MODBUS_GET_INT32_FROM_INT16(u16, 0)));

    printf("MODBUS_GET_INT16_FROM_INT8(u8{12,34}) = 0x%04x\n",
           (unsigned) (uint16_t) MODBUS_GET_INT16_FROM_INT8(u8, 0));
    printf("MODBUS_GET_INT16_FROM_INT8(u8{fe,dc}) = 0x%04x\n",
           (unsigned) (uint16_t) MODBUS_GET_INT16_FROM_INT8(u8_high, 0));
    printf("MODBUS_GET_INT16_FROM_INT8(s8{1,-1}) = %d\n", (int) MODBUS_GET_INT16_FROM_INT8(s8, 0));
    printf("sizeof(MODBUS_GET_INT16_FROM_INT8) = %zu\n", sizeof(MODBUS_GET_INT16_FROM_INT8(u8, 0)));

    memset(out8, 0, sizeof(out8));
    MODBUS_SET_INT16_TO_INT8(out8, 0, v16);
    print_hex_u8("MODBUS_SET_INT16_TO_INT8(0x1234)", out8, 2);
    MODBUS_SET_INT16_TO_INT8(out8, 0, v16_neg);
    print_hex_u8("MODBUS_SET_INT16_TO_INT8(-2)", out8, 2);

    memset(out16, 0, sizeof(out16));
    MODBUS_SET_INT32_TO_INT16(out16, 1, v32);
    print_hex_u16("MODBUS_SET_INT32_TO_INT16(0x12345678 at 1)", out16, 4);
    MODBUS_SET_INT32_TO_INT16(out16, 0, v32_neg);
    print_hex_u16("MODBUS_SET_INT32_TO_INT16(-2)", out16, 2);

    memset(out16, 0, sizeof(out16));
    MODBUS_SET_INT64_TO_INT16(out16, 0, v64);
    print_hex_u16("MODBUS_SET_INT64_TO_INT16(0x123456789abcdef0)", out16, 4);
    MODBUS_SET_INT64_TO_INT16(out16, 0, v64_neg);
    print_hex_u16("MODBUS_SET_INT64_TO_INT16(-2)", out16, 4);
}

int main(void)
{
    size_t i;

    print_layout();
    print_constants();
    print_version();
    print_macros();
    for (i = 0; i < sizeof(signatures_checked) / sizeof(signatures_checked[0]); i++) {
        printf("signature %s = ok\n", signatures_checked[i]);
    }
    return 0;
}
