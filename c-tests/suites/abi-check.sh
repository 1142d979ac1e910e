#!/usr/bin/env bash
# abi-check.sh: the library's ABI is the committed baseline, and a C++ program on the
# extensions compiles and runs (docs/abi.md).
#
# Checks:
#   baseline-library  abidw of the built library (debug information dropped: its ELF
#                     symbols, SONAME, symbol versions) equals abi/libmodbus.abi
#   baseline-headers  abidw of the witness of the public headers (scripts/abi-witness.py:
#                     the header's type of every export, every typedef and tag with
#                     its members, the integer constants) equals abi/headers.abi
#                     Both: the fresh dumps are made by scripts/abi-update.sh --out;
#                     libabigail's abidiff prints what changed; ANY difference fails,
#                     an addition too, and also a difference abidiff counts as harmless
#                     or does not report (an object's size...): then the dumps'
#                     diff -u is shown. If the change is intended, run
#                     scripts/abi-update.sh and commit abi/*.abi with it.
#   cxx-extensions    c-tests/abi/cxx-extensions.cpp compiles as C++11 and as C++17 with
#                     -Wall -Wextra -Werror -pedantic against include/, links against
#                     the built library and runs: a server runner on a thread, an
#                     event-driven client (poll + modbus_process), a multi handle; it
#                     must load this tree's libmodbus.so.5 and pass all its checks
#
# Usage: c-tests/suites/abi-check.sh   (after `cargo build --release`; takes seconds)
# Env:   PROFILE (release), CARGO_TARGET_DIR (target), CXX (g++), ABI_CC (gcc: the
#        witness's compiler, see scripts/abi-update.sh)
# Needs: abigail-tools (abidw, abidiff; scripts/install-deps.sh installs it), python3
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
if [[ ${1:-} == -h || ${1:-} == --help ]]; then
    sed -n '2,/^# SPDX/p' "$0" | sed '$d; s/^# \{0,1\}//'
    exit 0
fi

NAME=check-abi-baseline
PROFILE=${PROFILE:-release}
LIBDIR=${CARGO_TARGET_DIR:-$ROOT/target}/$PROFILE
LIB=$LIBDIR/libmodbus.so
CXX=${CXX:-g++}
UPDATE_HINT="if intended, run scripts/abi-update.sh and commit the baseline (abi/*.abi) with the change (docs/abi.md)"

# shellcheck source=../common/testlib.sh
source c-tests/common/testlib.sh
TMP=$(mktemp -d)
trap '_cleanup_pids; rm -rf "$TMP"' EXIT

verdict() {
    if summary; then
        echo "PASS: $NAME: the ABI is the baseline's; the C++ program on the extensions builds and runs"
        exit 0
    fi
    echo "FAIL: $NAME: ${FAILED[*]}"
    exit 1
}

# --- the fresh dumps -----------------------------------------------------------------
begin dumps
for tool in abidw abidiff; do
    command -v "$tool" >/dev/null || err "$tool not found: apt-get install abigail-tools (scripts/install-deps.sh)"
done
[[ -f $LIB ]] || err "$LIB not found (cargo build --release)"
if [[ ${#CHECK_ERRORS[@]} -eq 0 ]] &&
    ! scripts/abi-update.sh --out "$TMP/now" "$LIB" >"$TMP/update.log" 2>&1; then
    err "scripts/abi-update.sh --out failed:"
    err_file "$TMP/update.log"
fi
if [[ ${#CHECK_ERRORS[@]} -gt 0 ]]; then
    end
    verdict
fi
end "$(abidw --version): $(grep -c '<elf-symbol ' "$TMP/now/libmodbus.abi") library symbols, $(grep -c '<elf-symbol ' "$TMP/now/headers.abi") witness variables"

# compare LABEL BASELINE FRESH: abidiff's report, and the dumps byte for byte.
compare() {
    local label=$1 base=$2 now=$3 rc=0
    if [[ ! -f $base ]]; then
        err "$base is missing: run scripts/abi-update.sh and commit it"
        return
    fi
    abidiff "$base" "$now" >"$TMP/$label.abidiff" 2>&1 || rc=$?
    if ((rc & 3)); then # ABIDIFF_ERROR | ABIDIFF_USAGE_ERROR
        err "abidiff could not compare $base with the fresh dump (exit $rc):"
        err_file "$TMP/$label.abidiff" 20
    elif ((rc != 0)); then
        err "the $label ABI differs from $base (abidiff exit $rc$( ((rc & 8)) && echo ": incompatible change")):"
        err_file "$TMP/$label.abidiff" 120
        err "$UPDATE_HINT"
    elif ! cmp -s "$base" "$now"; then
        err "the $label dump differs from $base, in a way abidiff reports as no ABI change or as a harmless one (an object's size...):"
        diff -u --label "$base" --label "the fresh dump" "$base" "$now" >"$TMP/$label.diff" || true
        err_file "$TMP/$label.diff" 60
        err "$UPDATE_HINT"
    fi
}

begin baseline-library
compare library abi/libmodbus.abi "$TMP/now/libmodbus.abi"
end "$LIB = abi/libmodbus.abi (SONAME $(sed -n "s/.*soname='\([^']*\)'.*/\1/p; T; q" "$TMP/now/libmodbus.abi"), $(grep -c '<elf-symbol ' "$TMP/now/libmodbus.abi") symbols)"

begin baseline-headers
compare headers abi/headers.abi "$TMP/now/headers.abi"
end "include/ = abi/headers.abi ($(grep -c "<var-decl name='fn_" "$TMP/now/headers.abi") functions, $(grep -c "<var-decl name='type_" "$TMP/now/headers.abi") typedefs, $(grep -c "<var-decl name='tag_" "$TMP/now/headers.abi") tags, $(grep -c "<var-decl name='const_" "$TMP/now/headers.abi") constants)"

# --- cxx-extensions: the extensions from C++ -------------------------------------------
begin cxx-extensions
real_lib=$(readlink -f "$LIB")
ran=()
for std in c++11 c++17; do
    bin=$TMP/cxx-extensions-$std
    if ! "$CXX" -std=$std -Wall -Wextra -Werror -pedantic -Iinclude -Ic-tests/common \
        c-tests/abi/cxx-extensions.cpp -o "$bin" -pthread -L"$LIBDIR" -lmodbus \
        -Wl,-rpath,"$LIBDIR" 2>"$TMP/cxx-$std.log"; then
        err "cxx-extensions.cpp does not build as -std=$std:"
        err_file "$TMP/cxx-$std.log" 20
        continue
    fi
    rc=0
    timeout 30 "$bin" >"$TMP/run-$std.log" 2>&1 || rc=$?
    sed "s/^/         $std | /" "$TMP/run-$std.log"
    loaded=$(sed -n 's/^LOADED \([^ ]*\) (rsmodbus .*/\1/p; T; q' "$TMP/run-$std.log")
    summary=$(grep -E '^[0-9]+ passed, [0-9]+ failed$' "$TMP/run-$std.log" | tail -n 1 || true)
    if [[ -z $loaded || $(readlink -f "$loaded") != "$real_lib" ]]; then
        err "-std=$std: loaded '${loaded:-nothing}', not $real_lib"
    fi
    if [[ $rc -ne 0 || -z $summary || $summary != *" 0 failed" ]]; then
        err "-std=$std: exit $rc, ${summary:-no summary line}"
    else
        ran+=("$std: ${summary%%,*}")
    fi
done
end "built with -Wall -Wextra -Werror -pedantic, ran against $real_lib (${ran[*]:-})"

verdict
