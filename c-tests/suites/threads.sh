#!/usr/bin/env bash
# threads.sh: many threads sharing one rsmodbus context.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
#  1. c-tests/threads/threads.c: 16 threads share ONE context and run 10,000
#     transactions each (160,000 per context), every result checked (see threads.c;
#     libmodbus function codes and two new ones, 08/00 and 14),
#     against our_server (c-tests/interop) loading our library: a TCP context, an RTU
#     context on a pty pair, an RTU-over-TCP context and an ASCII context on a pty pair.
#     A watchdog fails a run in which nothing completes for 30 s (deadlock, lost answer).
#  2. The same program under ThreadSanitizer, with the LIBRARY instrumented too: the
#     Rust crate is built into target/tsan with -Zsanitizer=thread (RUSTC_BOOTSTRAP=1 on
#     the stable toolchain, the std library left uninstrumented) and the C program with
#     gcc -fsanitize=thread (make -C c-tests SAN=thread; gcc's libtsan;
#     c-tests/threads/tsan-shims.c supplies three entry points newer LLVM emits). First a self-test: a race the program makes on
#     purpose on a buffer it hands to modbus_write_registers must be reported with a
#     frame inside libmodbus.so (so the library's memory accesses are seen); then TCP and
#     RTU, 16 x 10,000 each, must end with no report at all.
#  3. A measurement, not a test: the single-threaded cost of the context mutex
#     (c-tests/threads/mutex_cost.c, ours against Debian's lock-free libmodbus).
#
# What TSan does and does not prove here: it sees every access of the C program and of
# our crate (instrumented; the context lock's atomics give the happens-before edges),
# and the libc calls it intercepts; it does not see inside Rust's std (uninstrumented;
# the library uses it for allocation and I/O wrappers only), and it only judges the
# interleavings that happened in this run. helgrind/DRD are not used: they know
# pthread primitives only, and the context lock (src/handle/lock.rs) is atomics and futex calls,
# so every access made under it would be reported. Deadlock detection would need a
# checker thread inside the library (and its feature flag); the watchdog covers hangs.
#
# usage: c-tests/suites/threads.sh [--no-cargo] [--no-tsan] [--long] [--ntx N]
#   --long   100,000 transactions per thread (1.6 M per context), TSan runs included
# Logs: target/threads/logs. Last line "N passed, M failed"; non-zero exit on failure.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT" || exit 2
OUT=$ROOT/target/threads
LOGS=$OUT/logs
OURS=$ROOT/target/release
NTHREADS=16
NTX=10000

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"
# The programs: c-tests/Makefile, group THREADS (plain) and SAN=thread's threads.
BIN=$(c_build_dir)
TSAN_BIN=$(c_build_dir thread)/threads

TSAN=1
suite_flag() {
    case "$1" in
    --no-tsan) TSAN=0 ;;
    --long) NTX=100000 ;;
    --ntx) NTX=$2; return 2 ;;
    *) return 1 ;;
    esac
}
parse_flags -- "$@"

prepare_run gcc make socat python3

c_build_group THREADS || { summary; exit 1; }

# start_server NAME TRANSPORT: our_server (our library, no trace); sets WHERE (client side)
start_server() {
    local name=$1 transport=$2 where
    case "$transport" in
    tcp | rtutcp)
        where=$(free_port)
        WHERE=$where
        ;;
    *)
        pty_pair "pty-$name" "$WORK/$name-a" "$WORK/$name-b" || return 1
        where=$WORK/$name-b
        WHERE=$WORK/$name-a
        ;;
    esac
    LD_LIBRARY_PATH=$OURS INTEROP_QUIET=1 start "srv-$name" "$BIN/our_server" "$transport" "$where" 60 --configure
    wait_ready "srv-$name" READY 20
}
stop_server() {
    stop "srv-$1"
    stop "pty-$1"
}

# run_threads NAME TRANSPORT BINARY LIBDIR [env...]
run_threads() {
    local name=$1 transport=$2 binary=$3 libdir=$4 log=$LOGS/$1.log rc
    shift 4
    echo "=== $name: $NTHREADS threads x $NTX transactions, one $transport context"
    if ! start_server "$name" "$transport"; then
        bad "$name: server did not start" "$(tail -n 10 "$WORK/srv-$name.log" 2>/dev/null)"
        stop_server "$name"
        return
    fi
    env LD_LIBRARY_PATH="$libdir" "$@" timeout 900 "$binary" "$transport" "$WHERE" "$NTHREADS" "$NTX" >"$log" 2>&1
    rc=$?
    stop_server "$name"
    loaded_ours "$name" "$log" "$libdir/libmodbus.so.5"
    grep -E '^[a-z]+: [0-9]+ threads' "$log" | sed 's/^/     /'
    grep -E '^FAIL' "$log" | head -n 20 | sed 's/^/     /'
    if [ "$rc" -eq 0 ] && grep -q '^ok   - all transactions correct' "$log" &&
        grep -q '^ok   - all threads were running at the same time' "$log"; then
        ok "$name: all $((NTHREADS * NTX)) transactions correct"
    else
        bad "$name: exit $rc" "$(grep -E '^(FAIL|WARNING|SUMMARY)' "$log" | head -n 10)"
    fi
    if grep -q 'ThreadSanitizer' "$log"; then
        bad "$name: ThreadSanitizer reports" "$(grep -E '^(WARNING|SUMMARY)' "$log" | head -n 10)" "(see $log)"
    elif [ "$binary" = "$TSAN_BIN" ]; then
        ok "$name: no ThreadSanitizer report"
    fi
}

# ---------------------------------------------------------------- 1. plain
for transport in tcp rtu rtutcp ascii; do
    run_threads "threads-$transport" "$transport" "$BIN/threads" "$OURS"
done

# ---------------------------------------------------------------- 2. TSan
if [ "$TSAN" -eq 1 ]; then
    echo "=== ThreadSanitizer build of the library (target/tsan)"
    if tsan_library "$LOGS/cargo-tsan.log"; then
        ok "cargo build -Zsanitizer=thread"
        if c_build SAN=thread threads; then
            export TSAN_OPTIONS="halt_on_error=0 exitcode=66"
            echo "=== tsan-selftest: a deliberate race must be reported inside libmodbus.so"
            if start_server tsan-selftest tcp; then
                LD_LIBRARY_PATH=$TSAN_LIB_DIR timeout 120 "$TSAN_BIN" tcp "$WHERE" 1 1 --race-selftest \
                    >"$LOGS/tsan-selftest.log" 2>&1
                loaded_ours tsan-selftest "$LOGS/tsan-selftest.log" "$TSAN_LIB_DIR/libmodbus.so.5"
                if grep -q 'WARNING: ThreadSanitizer: data race' "$LOGS/tsan-selftest.log" &&
                    grep -qE '\(libmodbus\.so[.0-9]*\+0x' "$LOGS/tsan-selftest.log"; then
                    ok "tsan-selftest: race reported with frames in libmodbus.so"
                else
                    bad "tsan-selftest: the deliberate race was not reported inside libmodbus.so" \
                        "(the library's accesses are not instrumented; see $LOGS/tsan-selftest.log)"
                fi
            else
                bad "tsan-selftest: server did not start"
            fi
            stop_server tsan-selftest
            for transport in tcp rtu; do
                run_threads "tsan-$transport" "$transport" "$TSAN_BIN" "$TSAN_LIB_DIR"
            done
        fi
    else
        bad "cargo build -Zsanitizer=thread" "$(tail -n 15 "$LOGS/cargo-tsan.log")" "(--no-tsan skips)"
    fi
fi

# ---------------------------------------------------------------- 3. measurement
echo "=== measurement: single-threaded cost of the context mutex (not a test)"
if start_server mutex-cost tcp; then
    LD_LIBRARY_PATH=$OURS "$BIN/mutex_cost" "$WHERE" 20000 >"$LOGS/mutex-cost-ours.log" 2>&1
    loaded_ours mutex-cost "$LOGS/mutex-cost-ours.log" "$OURS/libmodbus.so.5"
    ours_line=$(grep '^RESULT' "$LOGS/mutex-cost-ours.log")
    deb_line=""
    if [ -e /usr/lib/x86_64-linux-gnu/libmodbus.so.5 ]; then
        env -u LD_LIBRARY_PATH "$BIN/mutex_cost" "$WHERE" 20000 >"$LOGS/mutex-cost-debian.log" 2>&1
        deb_line=$(grep '^RESULT' "$LOGS/mutex-cost-debian.log")
    fi
    echo "     $ours_line"
    [ -n "$deb_line" ] || deb_line="(Debian libmodbus5 not installed: no comparison)"
    echo "     $deb_line"
    if [ -n "$ours_line" ] && [[ $deb_line == RESULT* ]]; then
        python3 - "$ours_line" "$deb_line" <<'EOF'
import sys
def parse(line):
    return {k: v for k, v in (f.split("=") for f in line.split()[1:])}
o, d = parse(sys.argv[1]), parse(sys.argv[2])
extra = float(o["call_ns"]) - float(d["call_ns"])
txn = float(o["txn_us"]) * 1000
print("     lock + call shim: %+.1f ns per call (ours %s ns, Debian %s ns); "
      "a loopback TCP transaction takes %s us (Debian's library: %s us): "
      "the lock is %.3f%% of a transaction" % (extra, o["call_ns"], d["call_ns"],
      o["txn_us"], d["txn_us"], 100 * max(extra, 0) / txn))
EOF
    fi
fi
stop_server mutex-cost

echo
summary
