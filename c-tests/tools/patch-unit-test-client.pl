#!/usr/bin/perl
# patch-unit-test-client.pl FILE: patches (in place) a COPY of Debian's 3.1.6
# unit-test-client.c, made at test time; the original is never committed.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
# The checks below fail against a library with upstream 3.1.12 behaviour for documented
# reasons (c-tests/allowed-differences.txt, kind "unit"). Each ASSERT_TRUE is replaced by
# ALLOW_DIFF(name, cond, alt, ...): "OK" if cond holds (the 3.1.6 behaviour), the line
# "EXPECTED-3.1.12-DIFFERENCE: name" if exactly the 3.1.12 alternative holds (and the test
# goes on), and the normal assertion failure otherwise. Every patch must apply the
# expected number of times, or this script fails.
use strict;
use warnings;

my $file = shift or die "usage: $0 FILE\n";
open(my $in, '<', $file) or die "$file: $!\n";
my $src = do { local $/; <$in> };
close($in);

sub patch {
    my ($what, $want, $re, $repl) = @_;
    my $n = ($src =~ s/$re/$repl->()/ge);
    $n = 0 if $n eq '';
    die "patch '$what' applied $n times, expected $want\n" if $n != $want;
}

my $macro = <<'C';
#include "unit-test.h"

/* Added by rsmodbus c-tests/tools/patch-unit-test-client.pl (test-time copy only). */
#define ALLOW_DIFF(_name, _cond, _alt, _format, __args...) {          \
    if (_cond) {                                                      \
        printf("OK\n");                                               \
    } else if (_alt) {                                                \
        printf("EXPECTED-3.1.12-DIFFERENCE: %s\n", _name);            \
    } else {                                                          \
        BUG_REPORT(_cond, _format, ## __args);                        \
        goto close;                                                   \
    }                                                                 \
};
C
# The macro needs BUG_REPORT, defined after the includes: insert it after ASSERT_TRUE.
patch('include', 1, qr/#include "unit-test.h"\n/, sub { "#include \"unit-test.h\"\n" });
patch('macro', 1, qr/(#define ASSERT_TRUE\(.*?\n\};\n)/s, sub { "$1\n" . (split /\n/, $macro, 2)[1] });

# 1. float setters: memory bytes of 3.1.8..3.1.10 vs register values of 3.1.12
patch('float-setters', 4,
      qr/ASSERT_TRUE\(is_memory_equal\(tab_rp_registers, UT_IREAL_([A-D]{4})_SET, 4\), /,
      sub { "ALLOW_DIFF(\"float-setters\", is_memory_equal(tab_rp_registers, UT_IREAL_$1_SET, 4), "
            . "(tab_rp_registers[0] == UT_IREAL_$1_GET[0] && tab_rp_registers[1] == UT_IREAL_$1_GET[1]), " });

# 2. report slave id from a 3.1.12 server: "LMB3.1.12" is one byte longer
patch('report-slave-id-length (truncated)', 1,
      qr/ASSERT_TRUE\(rc == NB_REPORT_SLAVE_ID &&\s*\n(\s*)tab_rp_bits\[NB_REPORT_SLAVE_ID - 1\] == 42,/,
      sub { "ALLOW_DIFF(\"report-slave-id-length\", rc == NB_REPORT_SLAVE_ID &&\n$1tab_rp_bits[NB_REPORT_SLAVE_ID - 1] == 42,\n"
            . "$1rc == NB_REPORT_SLAVE_ID + 1 && tab_rp_bits[NB_REPORT_SLAVE_ID - 1] == 42," });
patch('report-slave-id-length (full)', 1,
      qr/(rc = modbus_report_slave_id\(ctx, NB_REPORT_SLAVE_ID, tab_rp_bits\);\s*\n\s*)ASSERT_TRUE\(rc == NB_REPORT_SLAVE_ID, ""\);/,
      sub { "$1ALLOW_DIFF(\"report-slave-id-length\", rc == NB_REPORT_SLAVE_ID, rc == NB_REPORT_SLAVE_ID + 1, \"\");" });

# 3. modbus_new_tcp_pi(NULL, NULL): EINVAL in 3.1.6, a context in 3.1.8+
patch('tcp-pi-null-null', 1,
      qr/(ctx = modbus_new_tcp_pi\(NULL, NULL\);\s*\n\s*)ASSERT_TRUE\(ctx == NULL && errno == EINVAL, ""\);/,
      sub { "$1ALLOW_DIFF(\"tcp-pi-null-null\", ctx == NULL && errno == EINVAL, ctx != NULL, \"\");" });

# 4. Not a difference: the "adapted byte timeout" check gives 7 ms to bytes sent 5 ms
#    apart, no margin on a shared 2-core machine (Debian's own library failed it there).
#    50 ms keeps the check's meaning (a byte timeout longer than the gaps).
patch('byte-timeout-margin', 1,
      qr/modbus_set_byte_timeout\(ctx, 0, 7000\);/,
      sub { "modbus_set_byte_timeout(ctx, 0, 50000);" });

open(my $out, '>', $file) or die "$file: $!\n";
print $out $src;
close($out);
