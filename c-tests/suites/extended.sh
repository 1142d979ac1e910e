#!/usr/bin/env bash
# extended.sh: rsmodbus' client calls for the function codes beyond
# libmodbus (07, 08 and every diagnostics sub-function, 0B, 0C, 11, 14, 15, 18, 2B/0E)
# against rsmodbus' server side of them (c-tests/extended/ext-test.c), including
# listen-only mode, exact counters after known traffic and the event log contents.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
# Transports: TCP, RTU over TCP, RTU over a pty pair, ASCII over a pty pair (socat).
# Server modes: fully configured; FIFO-only and unconfigured (the rest keeps
# libmodbus' answers). Every program is built by c-tests/Makefile (-Wall -Wextra
# -Werror) against our headers, reports the libmodbus.so.5 it mapped (/proc/self/maps),
# and the runner requires it to be ours. The fully configured TCP and RTU runs are repeated under
# valgrind memcheck when it is installed. Every process started here is stopped by
# its PID.
#
# usage: c-tests/suites/extended.sh [--no-cargo] [--no-valgrind] [--only REGEX]
# Output goes to target/ext-tests (logs/ per run). The last line is
# "N passed, M failed"; the exit status is non-zero if M > 0.
set -u
set -o pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
SRC=$ROOT/c-tests/extended
OUT=${EXTTEST_OUT:-$ROOT/target/ext-tests}
LOGS=$OUT/logs
LIBDIR=$ROOT/target/release

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"

parse_flags --no-valgrind --only -- "$@"

# ------------------------------------------------------------ build
section "build"
our_lib_result "$LIBDIR" 2
echo "ours: $OURS_LIB"
rm -rf "$OUT"
mkdir -p "$OUT" "$LOGS"
# c-tests/Makefile: our headers (the server configuration calls are rsmodbus
# extensions), linked with target/release's library.
if ! c_build ext-test; then
    summary
    exit 1
fi
BIN=$(c_build_dir)/ext-test

# ------------------------------------------------------------ pty pairs
SOCAT_PID=
start_pty_pair() { # start_pty_pair DIR: socat links DIR/server and DIR/client
    local rc=0
    mkdir -p "$1"
    socat_pair "$1/socat.log" "$1/socat.log" "$1/server" "$1/client" || rc=$?
    SOCAT_PID=$LAST_PID
    return $rc
}

# ------------------------------------------------------------ runs
# run_case NAME VALGRIND(0|1) MODE TRANSPORT
run_case() {
    local name=$1 vg=$2 mode=$3 t=$4 d=$LOGS/$1 args=() pre=() rc
    selected "$name" || return 0
    mkdir -p "$d"
    if [ "$t" = rtu ] || [ "$t" = ascii ]; then
        if ! command -v socat >/dev/null; then
            result "$name" FAIL "socat is not installed"
            return
        fi
        if ! start_pty_pair "$d/pty"; then
            result "$name: pty pair" FAIL "socat did not create the links (see $d/pty/socat.log)"
            stop_pid "$SOCAT_PID"
            return
        fi
        args=("$d/pty/server" "$d/pty/client")
    fi
    if [ "$vg" = 1 ]; then
        pre=(valgrind -q --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite
            --show-leak-kinds=definite --log-file="$d/valgrind.%p.log")
    fi
    start_bg "$d/out.log" "$d/err.log" \
        env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 300 "${pre[@]}" "$BIN" "$mode" "$t" "${args[@]}"
    wait_pid "$LAST_PID"
    rc=$?
    [ -n "$SOCAT_PID" ] && stop_pid "$SOCAT_PID"
    SOCAT_PID=

    # The library the program mapped must be ours; the program's own checks.
    libinfo_ours "$name" "$d/out.log"
    program_checks "$name" "$d/out.log" "$rc" || tail -n 5 "$d/err.log" | sed 's/^/    | /'
    if [ "$vg" = 1 ]; then valgrind_clean "$name" "$d"; fi
}

section "our client against our server, fully configured"
run_case full-tcp 0 full tcp
run_case full-rtutcp 0 full rtutcp
run_case full-rtu 0 full rtu
run_case full-ascii 0 full ascii

section "partly configured and unconfigured servers keep libmodbus' answers"
run_case fifo-only-tcp 0 fifo-only tcp
run_case fifo-only-rtu 0 fifo-only rtu
run_case plain-tcp 0 plain tcp

if [ "$VALGRIND" = 1 ] && command -v valgrind >/dev/null; then
    section "under valgrind memcheck"
    run_case valgrind-full-tcp 1 full tcp
    run_case valgrind-full-rtu 1 full rtu
fi

section "summary"
if [ ${#FAILED[@]} -gt 0 ]; then
    echo "failed:"
    printf '  %s\n' "${FAILED[@]}"
fi
echo "logs: $LOGS"
summary
