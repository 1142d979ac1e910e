#!/usr/bin/env bash
# benches/many.sh: many devices from one thread (the event-driven client) against
# libmodbus' ways of polling them, in one run (scripts/bench.sh --many).
#
# The devices are c-tests/event/sim-devices.c: one connection each, a read of 10
# registers answered after BENCH_DELAY_MS (5). benches/many-client.c polls them:
#   async    rsmodbus' multi handle, one thread (the library the packages ship)
#   threads  Debian's libmodbus, one thread per device (64 KiB stacks)
#   serial   Debian's libmodbus, one thread, the devices in turn (measured on 100
#            devices: its cycle grows with their number, 1,000 take ten times that)
# Prints a Markdown table: the median cycle, the peak resident memory of the client
# process, the memory per device (the peak of N devices less the peak of one, over
# N - 1: what each device costs, without the process and libraries both ways
# load), and the ratios. BENCH_DEVICES (1000), BENCH_CYCLES (20), BENCH_BIG (10000,
# or what the descriptor limit allows: the async client alone, its cycle and memory).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
N=${BENCH_DEVICES:-1000}
CYCLES=${BENCH_CYCLES:-20}
# Each context of the event-driven client holds one descriptor (its socket).
limit=$(ulimit -n)
BIG=${BENCH_BIG:-$(( limit - 200 < 10000 ? limit - 200 : 10000 ))}
DELAY=${BENCH_DELAY_MS:-5}
OUT=target/bench-many
mkdir -p "$OUT"
[ -e target/pgo/release/libmodbus.so.5 ] || scripts/build-pgo.sh >/dev/null
OURS=$(realpath target/pgo/release)
make -s -C c-tests sim-devices >/dev/null
gcc -std=gnu11 -Wall -Wextra -Werror -O2 $(pkg-config --cflags libmodbus) benches/many-client.c \
    c-tests/common/libinfo.c -o "$OUT/many-client" -lmodbus -ldl -pthread
SIM=$(make -s -C c-tests print-CTEST_BUILD 2>/dev/null || true)
SIM=${SIM:-target/c-tests-build}/bin/sim-devices
[ -x "$SIM" ] || SIM=target/c-tests-build/bin/sim-devices

sim_pid=
stop_sim() { [ -z "$sim_pid" ] || { kill "$sim_pid" 2>/dev/null; wait "$sim_pid" 2>/dev/null || true; sim_pid=; }; }
trap stop_sim EXIT
# run MODE DEVICES CYCLES LIB(ours|debian): one client run against fresh devices;
# prints its RESULT line.
run() {
    local mode=$1 n=$2 cycles=$3 lib=$4 port env=()
    "$SIM" 0 "$DELAY" 0 >"$OUT/sim.log" 2>&1 &
    sim_pid=$!
    for _ in $(seq 50); do grep -q READY "$OUT/sim.log" && break; sleep 0.1; done
    port=$(sed -n 's/^READY //p' "$OUT/sim.log")
    [ "$lib" = ours ] && env=(LD_LIBRARY_PATH="$OURS")
    env "${env[@]}" "$OUT/many-client" "$mode" "$port" "$n" "$cycles" >"$OUT/$mode-$n.log" 2>&1 || true
    stop_sim
    grep -q "LIBINFO: .*$([ "$lib" = ours ] && echo rsmodbus || echo debian)" "$OUT/$mode-$n.log" ||
        { echo "many.sh: $mode did not load $lib's library" >&2; cat "$OUT/$mode-$n.log" >&2; exit 1; }
    grep '^RESULT' "$OUT/$mode-$n.log" || { cat "$OUT/$mode-$n.log" >&2; exit 1; }
}
field() { sed -n "s/.* $1=\([^ ]*\).*/\1/p" <<<"$2"; }

a=$(run async "$N" "$CYCLES" ours)
t=$(run threads "$N" "$CYCLES" debian)
a1=$(run async 1 3 ours)
t1=$(run threads 1 3 debian)
s=$(run serial $((N / 10)) 3 debian)
b=$(run async "$BIG" 5 ours)
am=$(field median_ms "$a") tm=$(field median_ms "$t") sm=$(field median_ms "$s")
ar=$(field rss_kb "$a") tr=$(field rss_kb "$t")
# KiB per device: (peak with N - peak with 1) / (N - 1).
per() { awk -v n="$N" -v big="$1" -v one="$2" 'BEGIN { printf "%.2f", (big - one) / (n - 1) }'; }
ad=$(per "$ar" "$(field rss_kb "$a1")") td=$(per "$tr" "$(field rss_kb "$t1")")
echo
echo "$N devices answering after $DELAY ms, one read of 10 registers each per cycle ($(date -u +%F))"
echo
echo "| | cycle (median of $CYCLES) | peak memory of the client | per device | |"
echo "|---|---:|---:|---:|---|"
echo "| rsmodbus, event-driven, one thread | $am ms | $ar KiB | $ad KiB | |"
awk -v t="$tm" -v a="$am" -v tr="$tr" -v ar="$ar" -v td="$td" -v ad="$ad" 'BEGIN { printf "| libmodbus 3.1.6, one thread per device | %s ms | %s KiB | %s KiB | rsmodbus %.1fx faster, %.2fx the memory (%.2fx per device) |\n", t, tr, td, t / a, ar / tr, ad / td }'
awk -v s="$sm" -v a="$am" -v n="$N" 'BEGIN { printf "| libmodbus 3.1.6, one thread, in turn | %.0f ms (%d devices: %s ms) | | | rsmodbus %.0fx faster |\n", s * 10, n / 10, s, s * 10 / a }'
echo "| rsmodbus, event-driven, $BIG devices (descriptor limit $limit) | $(field median_ms "$b") ms (median of 5) | $(field rss_kb "$b") KiB | | |"
