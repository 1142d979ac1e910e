#!/usr/bin/env bash
# callbacks.sh: a server answering through modbus_reply_dispatch and receiving
# through modbus_receive_dispatch (c-tests/callbacks/cb-test.c), checked by a client
# of the same library, over TCP and over RTU on a pty pair (socat): every function
# code's values both ways, the request info, exceptions and no answer from every
# callback, NULL callbacks and a shorter struct, `other`, several units (silence for
# the others on RTU, exception 0B on TCP), a broadcast, a request answered after the
# one that followed it. The TCP and RTU runs are repeated under valgrind memcheck
# when it is installed. (modbus_reply through the callbacks against the raw-frame
# differential and Debian's unit tests: c-tests/suites/server.sh, section 1b and 3.)
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
# usage: c-tests/suites/callbacks.sh [--no-cargo] [--no-valgrind]
# Output goes to target/callbacks-tests. The last line is "N passed, M failed"; the
# exit status is non-zero if M > 0. Every process started here is stopped by its PID.
set -u
set -o pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
OUT=${CBTEST_OUT:-$ROOT/target/callbacks-tests}
LOGS=$OUT/logs
LIBDIR=$ROOT/target/release

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"

parse_flags --no-valgrind -- "$@"

section "build"
our_lib_result "$LIBDIR" 2
rm -rf "$OUT"
mkdir -p "$OUT" "$LOGS"
BIN=$(c_build_dir)
c_build_group CALLBACKS

run() { # run NAME [valgrind] : one transport
    local name=$1 vg=${2:-} log=$LOGS/$1${2:+-valgrind}.log pre=() port pid rc
    [ -n "$vg" ] && pre=(valgrind -q --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite
        --show-leak-kinds=definite --log-file="$LOGS/vg-$name/valgrind.%p.log")
    [ -n "$vg" ] && mkdir -p "$LOGS/vg-$name"
    if [ "$name" = tcp ]; then
        port=$(free_port)
        env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 300 "${pre[@]}" "$BIN/cb-test" tcp "$port" >"$log" 2>&1 &
    else
        socat_pair "$LOGS/socat-$name.log" "$LOGS/socat-$name.log" "$OUT/ttyA-$name" "$OUT/ttyB-$name" ||
            { result "cb-test rtu: pty pair" FAIL "socat"; return; }
        local socat=$LAST_PID
        env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 300 "${pre[@]}" "$BIN/cb-test" rtu "$OUT/ttyA-$name" \
            "$OUT/ttyB-$name" >"$log" 2>&1 &
    fi
    pid=$!
    PIDS+=("$pid")
    wait_pid "$pid"
    rc=$?
    [ "$name" = rtu ] && stop_pid "$socat"
    libinfo_ours "cb-test $name${vg:+ (valgrind)}" "$log"
    program_checks "cb-test $name${vg:+ (valgrind)}" "$log" "$rc"
    if [ -n "$vg" ]; then valgrind_clean "cb-test $name" "$LOGS/vg-$name"; fi
}

section "callbacks"
run tcp
run rtu
if [ "$VALGRIND" = 1 ] && command -v valgrind >/dev/null; then
    section "callbacks under valgrind memcheck"
    run tcp valgrind
    run rtu valgrind
fi
summary
