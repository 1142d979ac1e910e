#!/usr/bin/env bash
# abi.sh: compare the ABI facts of rsmodbus' headers with Debian's libmodbus.
#
# Builds c-tests/abi/abi-probe.c twice with -Wall -Wextra -Werror -Wpedantic
# (c-tests/Makefile, group ABI), once against Debian's headers (/usr/include/modbus,
# package libmodbus-dev) and once against include/, runs both and compares their
# "KEY = VALUE" lines. Every
# difference must be listed, with both values, in
# abi/abi-probe-intended-differences.txt; every listed difference must still occur.
#
# The probe also checks, at compile time, the type of every declared function
# against the libmodbus 3.1.x signatures, so a wrong prototype fails the build.
#
# Usage: c-tests/suites/abi.sh   (no build of the crate needed: headers only)
# Env:   DEBIAN_MODBUS_INCLUDE (default /usr/include/modbus), CC (default gcc)
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"

NAME=check-abi
DEB_INC=${DEBIAN_MODBUS_INCLUDE:-/usr/include/modbus}
CC=${CC:-gcc}
ALLOWED=abi/abi-probe-intended-differences.txt
BUILD=${CTEST_BUILD:-$ROOT/target/c-tests-build}

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

fail_now() {
    echo "FAIL: $NAME: $*"
    exit 1
}

[[ -f "$DEB_INC/modbus.h" ]] ||
    fail_now "Debian's libmodbus headers not found in $DEB_INC (apt-get install libmodbus-dev)"
for h in modbus.h modbus-rtu.h modbus-tcp.h modbus-version.h; do
    [[ -f "include/$h" ]] || fail_now "include/$h missing (RSMODBUS_UPDATE_HEADERS=1 cargo build)"
done

mkdir -p "$BUILD"
for side in debian ours; do
    inc=$DEB_INC
    [[ $side == ours ]] && inc=$ROOT/include
    if ! flock -w 900 "$BUILD/.lock" make -s -C c-tests --no-print-directory CC="$CC" DEB_INC="$DEB_INC" \
        "abi-probe-$side" >"$TMP/cc-$side.log" 2>&1; then
        cat "$TMP/cc-$side.log"
        rm -f "$BUILD/bin/abi-probe-$side"
        fail_now "abi-probe.c does not compile against the $side headers ($inc)"
    fi
    "$BUILD/bin/abi-probe-$side" >"$TMP/$side.txt" || fail_now "abi-probe ($side) exited with status $?"
done

# Join the two outputs and the allowance list on KEY; awk reports every mismatch.
problems=$(
    awk -v allowed="$ALLOWED" '
    function trim(s) { gsub(/^[ \t]+|[ \t]+$/, "", s); return s }
    function split_kv(line, kv,   i) {
        i = index(line, " = ")
        if (i == 0) { kv[1] = line; kv[2] = ""; return }
        kv[1] = substr(line, 1, i - 1); kv[2] = substr(line, i + 3)
    }
    BEGIN {
        while ((getline line < allowed) > 0) {
            if (line ~ /^[ \t]*(#|$)/) continue
            n = split(line, f, "|")
            if (n < 4 || trim(f[4]) == "") {
                print "malformed entry in " allowed " (need KEY | debian | ours | reason): " line
                continue
            }
            k = trim(f[1]); want_deb[k] = trim(f[2]); want_ours[k] = trim(f[3]); listed[k] = 1
        }
    }
    FILENAME ~ /debian\.txt$/ { split_kv($0, kv); if (kv[1] in deb) print "duplicate key (debian): " kv[1]; deb[kv[1]] = kv[2]; keys[kv[1]] = 1; next }
    FILENAME ~ /ours\.txt$/   { split_kv($0, kv); if (kv[1] in ours) print "duplicate key (ours): " kv[1]; ours[kv[1]] = kv[2]; keys[kv[1]] = 1; next }
    END {
        ndiff = 0
        for (k in keys) {
            d = (k in deb) ? deb[k] : "(absent)"
            o = (k in ours) ? ours[k] : "(absent)"
            if (d == o) {
                if (k in listed) print "listed difference no longer occurs: " k " (both " d ")"
                continue
            }
            ndiff++
            if (!(k in listed)) {
                print "unexpected difference: " k ": debian " d ", ours " o
            } else if (want_deb[k] != d || want_ours[k] != o) {
                print "difference changed: " k ": debian " d ", ours " o \
                      " (listed: debian " want_deb[k] ", ours " want_ours[k] ")"
            }
        }
        for (k in listed) if (!(k in keys)) print "listed key never printed by the probe: " k
        print "#ndiff " ndiff
    }' "$TMP/debian.txt" "$TMP/ours.txt"
)

ndiff=$(printf '%s\n' "$problems" | sed -n 's/^#ndiff //p')
errors=$(printf '%s\n' "$problems" | grep -v '^#ndiff ' || true)
nkeys=$(wc -l <"$TMP/ours.txt")
nsig=$(grep -c '^signature ' "$TMP/ours.txt" || true)

if [[ -n "$errors" ]]; then
    printf '%s\n' "$errors" | sort | sed 's/^/  /'
    echo "  (full outputs: diff of debian vs ours follows)"
    diff "$TMP/debian.txt" "$TMP/ours.txt" | sed 's/^/    /' || true
    echo "FAIL: $NAME: ABI probe differs from Debian's headers beyond $ALLOWED"
    exit 1
fi
echo "PASS: $NAME: $nkeys facts compared ($nsig function signatures type-checked);" \
    "$ndiff differences, all listed in $ALLOWED"
