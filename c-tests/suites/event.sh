#!/usr/bin/env bash
# c-tests/suites/event.sh: the event-driven client (modbus_*_async, modbus_process...,
# c-tests/event/event-test.c, loading our library) against a server no one here
# wrote: benches/mb-server.c, a plain libmodbus server, on Debian's libmodbus and on
# ours, over TCP (then servers of the test's own: one that never answers, one that
# answers late) and RTU on a pty pair. Every asynchronous result is compared with the
# blocking call's on the same context; against pymodbus' server too (target/interop/venv,
# made as the interop suite makes it). Modbus/TCP Security against our server (the
# handshake without waiting, and a peer that stalls it). A user-defined function code
# (0x41, c-tests/event/fc41_device.py) through the raw calls, on every framing. Once more under valgrind;
# two threads on a context under ThreadSanitizer.
#
# Usage: c-tests/suites/event.sh [--no-cargo] [--no-valgrind] [--no-tsan] [--only REGEX]
# Logs: target/event-tests/<case>/. Last line "N passed, M failed".
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT" || exit 2
OUT=$ROOT/target/event-tests
LIBDIR=$ROOT/target/release
# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"
TSAN=1
suite_flag() {
    case "$1" in
    --no-tsan) TSAN=0 ;;
    *) return 1 ;;
    esac
}
parse_flags --only --no-valgrind -- "$@"

section "build"
our_lib_result "$LIBDIR" 2
rm -rf "$OUT"
mkdir -p "$OUT"
LOGS=$OUT
c_build_group EVENT || { summary; exit 1; }
BIN=$(c_build_dir)
DEB_LIB=$(readlink -f "$(ldconfig -p | awk '$1 == "libmodbus.so.5" {print $NF; exit}')")

# event_test NAME SECS [VAR=VALUE...] -- ARGS...: event-test ARGS (loading ours, the
# variables set, stopped after SECS), output in $WORK; its library and its checks.
event_test() {
    local name=$1 secs=$2 vars=() rc
    shift 2
    while [ "$1" != -- ]; do vars+=("$1"); shift; done
    shift
    start_bg "$WORK/out.log" "$WORK/err.log" env LD_LIBRARY_PATH="$LIBDIR" "${vars[@]}" timeout -k 5 "$secs" \
        "${EVENT_PRE[@]}" "$BIN/event-test" "$@"
    wait_pid "$LAST_PID"
    rc=$?
    libinfo_ours "$name" "$WORK/out.log"
    program_checks "$name" "$WORK/out.log" "$rc" || tail -n 5 "$WORK/err.log" | sed 's/^/    | /'
}
EVENT_PRE=()

# run_case NAME SERVER_LIB(debian|ours) TRANSPORT(tcp|rtu) [valgrind]
run_case() {
    local name=$1 lib=$2 t=$3 vg=${4:-} srv_env=() pre=() where
    selected "$name" || return 0
    WORK=$OUT/$name
    mkdir -p "$WORK"
    if [ "$lib" = ours ]; then srv_env=(LD_LIBRARY_PATH="$LIBDIR"); fi
    local cli_env=()
    if [ "$t" = tls ]; then
        srv_env+=(MB_TLS_CA="$CERTS/ca.pem" MB_TLS_CERT="$CERTS/server.pem" MB_TLS_KEY="$CERTS/server.key")
        cli_env=(MB_TLS_CA="$CERTS/ca.pem" MB_TLS_CERT="$CERTS/operator.pem" MB_TLS_KEY="$CERTS/operator.key")
    fi
    if [ "$t" = rtu ]; then
        if ! pty_pair pty "$WORK/server" "$WORK/client"; then
            result "$name: pty pair" FAIL "see $WORK/pty.log"
            return
        fi
        start server env "${srv_env[@]}" "$BIN/mb-server" rtu "$WORK/server"
        where=$WORK/client
    else
        start server env "${srv_env[@]}" "$BIN/mb-server" "$t" 0
    fi
    if ! wait_ready server READY 10; then
        result "$name: mb-server ready" FAIL "$(tail -n 3 "$WORK/server.log")"
        stop server
        stop pty
        return
    fi
    [ "$t" != rtu ] && where=$(sed -n 's/^READY //p' "$WORK/server.log" | head -n 1)
    # The server's library is the one asked for.
    local mapped
    mapped=$(sed -n 's/^LIBINFO: pid [0-9]* libmodbus.so.5 = \([^ ]*\) .*/\1/p' "$WORK/server.log" | head -n 1)
    if [ "$lib" = ours ]; then
        [ "$(readlink -f "$mapped")" = "$OURS_LIB" ]
    else
        [ "$(readlink -f "$mapped")" = "$DEB_LIB" ]
    fi && result "$name: mb-server loaded $lib's libmodbus.so.5 ($mapped)" PASS ||
        result "$name: mb-server loaded $lib's libmodbus.so.5" FAIL "LIBINFO says '${mapped:-nothing}'"
    if [ "$vg" = valgrind ]; then
        pre=(valgrind -q --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite
            --show-leak-kinds=definite --log-file="$WORK/valgrind.%p.log")
    fi
    EVENT_PRE=("${pre[@]}")
    event_test "$name" 300 "${cli_env[@]}" -- "$t" "$where"
    EVENT_PRE=()
    stop server
    stop pty
    if [ "$vg" = valgrind ]; then valgrind_clean "$name" "$WORK"; fi
}

CERTS=$OUT/certs
check "make the test certificates (c-tests/tls/make-certs.sh)" c-tests/tls/make-certs.sh "$CERTS"

section "against Debian's libmodbus server"
run_case debian-tcp debian tcp
run_case debian-rtu debian rtu
section "against our server"
run_case ours-tcp ours tcp
run_case ours-rtu ours rtu
run_case ours-tls ours tls
section "a serial device that answers late (the error-recovery mode decides)"
if selected rtu-late; then
    WORK=$OUT/rtu-late
    mkdir -p "$WORK"
    if pty_pair pty "$WORK/dev" "$WORK/client"; then
        event_test rtu-late 60 -- rtu-late "$WORK/dev" "$WORK/client"
    else
        result "rtu-late: pty pair" FAIL "see $WORK/pty.log"
    fi
    stop pty
fi

section "a user-defined function code (0x41): the whole answer (c-tests/event/fc41_device.py)"
# The device answers the PDU 41 01 02 03 04 05 06 07 08 (9 bytes), which libmodbus
# cannot size: modbus_send_raw_request + modbus_receive_confirmation and
# modbus_send_raw_request_async must return it whole, on RTU and ASCII (pty pairs),
# Modbus/TCP and RTU over TCP.
for mode in rtu ascii tcp rtutcp; do
    selected "fc41-$mode" || continue
    WORK=$OUT/fc41-$mode
    mkdir -p "$WORK"
    if [ "$mode" = rtu ] || [ "$mode" = ascii ]; then
        if ! pty_pair pty "$WORK/dev" "$WORK/client"; then
            result "fc41-$mode: pty pair" FAIL "see $WORK/pty.log"
            continue
        fi
        start device python3 "$ROOT/c-tests/event/fc41_device.py" "$mode" "$WORK/dev"
        where=$WORK/client
    else
        start device python3 "$ROOT/c-tests/event/fc41_device.py" "$mode"
    fi
    if wait_ready device READY 10; then
        [ "$mode" = rtu ] || [ "$mode" = ascii ] || where=$(sed -n 's/^READY //p' "$WORK/device.log" | head -n 1)
        event_test "fc41-$mode" 60 -- fc41 "$mode" "$where"
    else
        result "fc41-$mode: fc41_device.py ready" FAIL "$(tail -n 3 "$WORK/device.log")"
    fi
    stop device
    stop pty
done

section "lost wake-ups: a request from the loop or another thread, a deadline, modbus_multi_wakeup (issue 39)"
if selected wake; then
    WORK=$OUT/wake
    mkdir -p "$WORK"
    event_test wake 60 -- wake
fi

section "1,000 devices from one thread, every 10th dead (c-tests/event/sim-devices.c)"
if selected many; then
    WORK=$OUT/many
    mkdir -p "$WORK"
    start sim "$BIN/sim-devices" 0 5 10
    if wait_ready sim READY 10; then
        port=$(sed -n 's/^READY //p' "$WORK/sim.log" | head -n 1)
        event_test many 120 -- many "$port" 1000
    else
        result "many: sim-devices ready" FAIL "$(tail -n 3 "$WORK/sim.log")"
    fi
    stop sim
fi

# pymodbus 3.16.1 answers only the first of several requests one read brings it: no
# pipelining there (EVENT_DEPTH=1), as modbus_set_max_in_flight(3) warns.
section "against pymodbus' server (c-tests/interop/pm_server.py, unit 17)"
if selected pymodbus; then
    WORK=$OUT/pymodbus
    mkdir -p "$WORK"
    if pymodbus_venv "$ROOT/target/interop/venv" "$ROOT/c-tests/interop/requirements.txt" "$WORK" 1; then
        port=$(free_port)
        start pm "$PY" "$ROOT/c-tests/interop/pm_server.py" tcp "$port" --timeout 100
        if wait_ready pm READY 30; then
            event_test pymodbus 120 EVENT_SLAVE=17 EVENT_DEPTH=1 -- tcp "$port"
        else
            result "pymodbus: pm_server.py ready" FAIL "$(tail -n 3 "$WORK/pm.log")"
        fi
        stop pm
    else
        result "pymodbus: the venv of c-tests/interop/requirements.txt" FAIL "see $WORK"
    fi
fi

if [ "$VALGRIND" = 1 ] && command -v valgrind >/dev/null; then
    section "under valgrind memcheck"
    run_case valgrind-tcp debian tcp valgrind
fi

# Two threads on one context (one gives requests, one processes them) and on a multi
# handle, and the lost wake-ups' cases (event-test wake), with the library and
# event-test built for ThreadSanitizer (the threads suite's build of the library,
# target/tsan).
if [ "$TSAN" = 1 ] && selected tsan; then
    section "under ThreadSanitizer: two threads on a context (event-test threads)"
    WORK=$OUT/tsan
    mkdir -p "$WORK"
    if tsan_library "$WORK/cargo-tsan.log" && c_build SAN=thread event-test; then
        start server "$BIN/mb-server" tcp 0
        if wait_ready server READY 10; then
            port=$(sed -n 's/^READY //p' "$WORK/server.log" | head -n 1)
            TSAN_OPTIONS="halt_on_error=0 exitcode=66" LD_LIBRARY_PATH=$TSAN_LIB_DIR timeout -k 5 300 \
                "$(c_build_dir thread)/event-test" threads "$port" 2000 >"$WORK/out.log" 2>"$WORK/err.log"
            rc=$?
            if grep -q "LIBINFO: .*$TSAN_LIB_DIR/libmodbus.so" "$WORK/out.log"; then
                result "tsan: loaded the ThreadSanitizer build of our library" PASS
            else
                result "tsan: loaded the ThreadSanitizer build of our library" FAIL "$(head -n 2 "$WORK/out.log")"
            fi
            program_checks tsan "$WORK/out.log" "$rc"
            if grep -q ThreadSanitizer "$WORK/err.log"; then
                result "tsan: no ThreadSanitizer report" FAIL "$(grep -E '^(WARNING|SUMMARY)' "$WORK/err.log" | head -n 5)"
            else
                result "tsan: no ThreadSanitizer report" PASS
            fi
            # The lost wake-ups' threads: a request given, a wake-up, while another waits.
            TSAN_OPTIONS="halt_on_error=0 exitcode=66" LD_LIBRARY_PATH=$TSAN_LIB_DIR timeout -k 5 120 \
                "$(c_build_dir thread)/event-test" wake >"$WORK/wake-out.log" 2>"$WORK/wake-err.log"
            rc=$?
            program_checks tsan-wake "$WORK/wake-out.log" "$rc"
            if grep -q ThreadSanitizer "$WORK/wake-err.log"; then
                result "tsan-wake: no ThreadSanitizer report" FAIL \
                    "$(grep -E '^(WARNING|SUMMARY)' "$WORK/wake-err.log" | head -n 5)"
            else
                result "tsan-wake: no ThreadSanitizer report" PASS
            fi
        else
            result "tsan: mb-server ready" FAIL "$(tail -n 3 "$WORK/server.log")"
        fi
        stop server
    else
        result "tsan: the ThreadSanitizer builds" FAIL "see $WORK/cargo-tsan.log and the build log"
    fi
fi

section "summary"
summary
