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
# and benches/tokio-many (Rust, its own Cargo.lock, built into target/tokio-many:
# about 15 s the first time) polls them with tokio-modbus 0.17 on one current-thread
# tokio runtime, every read of a cycle at once; if cargo cannot build it (no network
# for the crates), its row is skipped with a line saying why.
# Prints a Markdown table: the median cycle, the peak resident memory of the client
# process, the memory per device (the peak of N devices less the peak of one, over
# N - 1: what each device costs, without the process and libraries both ways
# load), the ratios, and the CPU time (user + system, all threads) the client
# process spent in the measured cycles. BENCH_DEVICES (1000), BENCH_CYCLES (20),
# BENCH_BIG (10000, or what the descriptor limit allows: the async client alone, its
# cycle and memory).
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
TOKIO=target/tokio-many/release/tokio-many
tokio_skip=
if ! command -v cargo >/dev/null; then
    tokio_skip="cargo is not installed"
elif ! cargo build --release --manifest-path benches/tokio-many/Cargo.toml --target-dir target/tokio-many \
    >"$OUT/tokio-build.log" 2>&1; then
    tokio_skip="cargo could not build benches/tokio-many ($(grep -m1 '^error' "$OUT/tokio-build.log" ||
        tail -n1 "$OUT/tokio-build.log"); $OUT/tokio-build.log has the rest)"
fi
[ -z "$tokio_skip" ] || echo "many.sh: the tokio-modbus row is skipped: $tokio_skip" >&2

sim_pid=
stop_sim() { [ -z "$sim_pid" ] || { kill "$sim_pid" 2>/dev/null; wait "$sim_pid" 2>/dev/null || true; sim_pid=; }; }
trap stop_sim EXIT
# run MODE DEVICES CYCLES LIB(ours|debian|tokio): one client run against fresh
# devices (LIB tokio: benches/tokio-many, MODE tokio); prints its RESULT line.
run() {
    local mode=$1 n=$2 cycles=$3 lib=$4 port env=() want
    # Empty the log first: the simulator's shell truncates it in the background, after
    # which the loop below could still read the last run's READY line (a dead port).
    : >"$OUT/sim.log"
    "$SIM" 0 "$DELAY" 0 >"$OUT/sim.log" 2>&1 &
    sim_pid=$!
    for _ in $(seq 50); do grep -q READY "$OUT/sim.log" && break; sleep 0.1; done
    port=$(sed -n 's/^READY //p' "$OUT/sim.log")
    case $lib in
        ours) env=(LD_LIBRARY_PATH="$OURS") want=rsmodbus ;;
        debian) want=debian ;;
        tokio) want=tokio-modbus ;;
    esac
    if [ "$lib" = tokio ]; then
        "$TOKIO" "$port" "$n" "$cycles" >"$OUT/$mode-$n.log" 2>&1 || true
    else
        env "${env[@]}" "$OUT/many-client" "$mode" "$port" "$n" "$cycles" >"$OUT/$mode-$n.log" 2>&1 || true
    fi
    stop_sim
    grep -q "LIBINFO: .*$want" "$OUT/$mode-$n.log" ||
        { echo "many.sh: $mode did not load $lib's library" >&2; cat "$OUT/$mode-$n.log" >&2; exit 1; }
    grep '^RESULT' "$OUT/$mode-$n.log" || { cat "$OUT/$mode-$n.log" >&2; exit 1; }
}
field() { sed -n "s/.* $1=\([^ ]*\).*/\1/p" <<<"$2"; }

a=$(run async "$N" "$CYCLES" ours)
t=$(run threads "$N" "$CYCLES" debian)
a1=$(run async 1 3 ours)
t1=$(run threads 1 3 debian)
s=$(run serial $((N / 10)) 3 debian)
if [ -z "$tokio_skip" ]; then
    k=$(run tokio "$N" "$CYCLES" tokio)
    k1=$(run tokio 1 3 tokio)
fi
b=$(run async "$BIG" 5 ours)
am=$(field median_ms "$a") tm=$(field median_ms "$t") sm=$(field median_ms "$s")
ar=$(field rss_kb "$a") tr=$(field rss_kb "$t")
# KiB per device: (peak with N - peak with 1) / (N - 1).
per() { awk -v n="$N" -v big="$1" -v one="$2" 'BEGIN { printf "%.2f", (big - one) / (n - 1) }'; }
ad=$(per "$ar" "$(field rss_kb "$a1")") td=$(per "$tr" "$(field rss_kb "$t1")")
ac=$(field cpu_ms "$a")
echo
echo "$N devices answering after $DELAY ms, one read of 10 registers each per cycle ($(date -u +%F))"
echo
echo "| | cycle (median of $CYCLES) | peak memory of the client | per device | |"
echo "|---|---:|---:|---:|---|"
awk -v n="$N" -v c="$CYCLES" -v a="$am" -v ar="$ar" -v ad="$ad" -v ac="$ac" 'BEGIN { printf "| rsmodbus, event-driven, one thread | %s ms | %s KiB | %s KiB | CPU time %s ms in the %d cycles (%.1f µs a read) |\n", a, ar, ad, ac, c, ac * 1000 / (n * c) }'
awk -v t="$tm" -v a="$am" -v tr="$tr" -v ar="$ar" -v td="$td" -v ad="$ad" 'BEGIN { printf "| libmodbus 3.1.6, one thread per device | %s ms | %s KiB | %s KiB | rsmodbus %.1fx faster, %.2fx the memory (%.2fx per device) |\n", t, tr, td, t / a, ar / tr, ad / td }'
awk -v s="$sm" -v a="$am" -v n="$N" 'BEGIN { printf "| libmodbus 3.1.6, one thread, in turn | %.0f ms (%d devices: %s ms) | | | rsmodbus %.0fx faster |\n", s * 10, n / 10, s, s * 10 / a }'
if [ -z "$tokio_skip" ]; then
    km=$(field median_ms "$k") kr=$(field rss_kb "$k") kc=$(field cpu_ms "$k")
    kd=$(per "$kr" "$(field rss_kb "$k1")")
    awk -v k="$km" -v a="$am" -v kr="$kr" -v ar="$ar" -v kd="$kd" -v ad="$ad" -v kc="$kc" -v ac="$ac" 'BEGIN {
        speed = k / a >= 1 ? sprintf("%.1fx faster", k / a) : sprintf("%.1fx slower", a / k)
        cpu = kc > 0 ? sprintf("%.2fx the CPU time (%s ms against %s ms)", ac / kc, ac, kc) : "CPU time " ac " ms against " kc " ms"
        printf "| tokio-modbus 0.17, current-thread runtime, one thread | %s ms | %s KiB | %s KiB | rsmodbus %s, %.2fx the memory (%.2fx per device), %s |\n", k, kr, kd, speed, ar / kr, ad / kd, cpu }'
fi
echo "| rsmodbus, event-driven, $BIG devices (descriptor limit $limit) | $(field median_ms "$b") ms (median of 5) | $(field rss_kb "$b") KiB | | |"
[ -z "$tokio_skip" ] || { echo; echo "The tokio-modbus row is skipped: $tokio_skip."; }
