#!/usr/bin/env bash
# benches/gateway.sh: rsmodbus-gateway beside mbusd (built from ../shared/anchors/mbusd,
# the reference only), in one run (scripts/bench.sh --gateway). Each gateway fronts
# an RTU line on a pty pair at 115200 baud whose device is benches/mb-server.c on
# Debian's libmodbus (slave 1); the masters are c-tests/gateway/gw-check.c (Debian's
# libmodbus) reading one holding register. Both gateways run with -R 1 -W 300 -N 1
# (mbusd's shortest pause between requests; the default, 100 ms, would be the
# figure). Prints a Markdown table:
#   - one master in a closed loop: answers per second;
#   - the same on a line that takes a real line's time (benches/line-pace.c: two ptys
#     and a relay that delivers each frame when its last byte would have ended at
#     115200 baud, half duplex), against the line's own limit (the frames' bits plus a
#     3.5-character silence each way): mbusd at -R 1 (its least pause), ours at -R 1
#     and at -R 0 (the 3.5-character silence only); and the floor of this apparatus:
#     a master on the paced line itself (benches/bench-client.c, our blocking RTU
#     client, no gateway, no TCP, no silence between frames);
#   - 100 masters in closed loops: answers per second and the spread (busiest /
#     least served);
#   - 1,000 masters held (mbusd: its maximum, 128): the gateway's resident memory, and
#     the latency of one read by each, in turn (p50, p99);
#   - ours only, on the paced line: one master through the Modbus/TCP Security front
#     against the plain front (the line is the bottleneck).
# BENCH_SECONDS (5) per closed loop. The gateway measured: GATEWAY_BIN, by default
# target/release/rsmodbus-gateway (built here by `cargo build --release`).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
SECS=${BENCH_SECONDS:-5}
OUT=$ROOT/target/bench-gateway
mkdir -p "$OUT"
rm -f "$OUT"/*.log
cargo build --release -q
ln -sf libmodbus.so target/release/libmodbus.so.5
make -s -C c-tests gateway >/dev/null
BIN=$(make -s -C c-tests print-CTEST_BUILD 2>/dev/null || true)
BIN=${BIN:-target/c-tests-build}/bin
CFLAGS=(-std=gnu11 -O2 -Wall -Wextra -Werror)
gcc "${CFLAGS[@]}" benches/line-pace.c -o "$OUT/line-pace"
gcc "${CFLAGS[@]}" -I/usr/include/modbus benches/bench-client.c c-tests/common/libinfo.c -o "$OUT/bench-client" \
    -lmodbus -ldl
# The gateway under test (GATEWAY_BIN=... for another build, e.g. the C one).
GATEWAY_BIN=${GATEWAY_BIN:-$ROOT/target/release/rsmodbus-gateway}
MBUSD=
if [ -f ../shared/anchors/mbusd/CMakeLists.txt ]; then
    command -v cmake >/dev/null || apt-get install -y -qq cmake >/dev/null
    mkdir -p target/mbusd-build
    (cd target/mbusd-build && cmake "$ROOT/../shared/anchors/mbusd" >/dev/null 2>&1 && make -s >/dev/null 2>&1)
    MBUSD=$ROOT/target/mbusd-build/mbusd
fi

pids=()
stop_all() {
    local p
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
    pids=()
}
trap stop_all EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
bg() { # bg LOG CMD...: in the background; sets PID
    local log=$1
    shift
    "$@" >"$log" 2>&1 &
    PID=$!
    pids+=("$PID")
}
wait_for() { local i; for i in $(seq 100); do grep -q "$2" "$1" 2>/dev/null && return 0; sleep 0.1; done; return 1; }

# setup WHICH pty|paced [ARGS...]: a line (a pty pair, or two with the pacing relay
# between them), the device, the gateway; sets PORT and GW_PID. The gateway's pause is
# -R 1 unless ARGS give another.
setup() {
    local which=$1 kind=$2
    shift 2
    rm -f "$OUT/D" "$OUT/G"
    if [ "$kind" = paced ]; then
        bg "$OUT/pace.log" "$OUT/line-pace" 115200 10 "$OUT/D" "$OUT/G"
    else
        bg "$OUT/socat.log" socat pty,raw,echo=0,link="$OUT/D" pty,raw,echo=0,link="$OUT/G"
    fi
    for _ in $(seq 50); do [ -e "$OUT/D" ] && [ -e "$OUT/G" ] && break; sleep 0.1; done
    bg "$OUT/device-$which.log" env -u LD_LIBRARY_PATH "$BIN/mb-server" rtu "$OUT/D"
    wait_for "$OUT/device-$which.log" READY
    PORT=$(free_port)
    if [ "$which" = ours ]; then
        bg "$OUT/gw-$which.log" env LD_LIBRARY_PATH="$ROOT/target/release" "$GATEWAY_BIN" -d -L - -v 1 \
            -p "$OUT/G" -s 115200 -P "$PORT" -R 1 -W 300 -N 1 "$@"
    else
        bg "$OUT/gw-$which.log" "$MBUSD" -d -L - -v 1 -p "$OUT/G" -s 115200 -P "$PORT" -R 1 -W 300 -N 1 "$@"
    fi
    GW_PID=$PID
    sleep 0.5
}
# warm_up: a master for 2 s, not counted: the first seconds after the programs start
# are up to 20% slower here.
warm_up() { "$BIN/gw-check" "$PORT" fair 1 2 >/dev/null 2>&1 || true; }
# paced WHICH NAME [ARGS...]: one master for $SECS on the paced line, 3 rounds (a
# new line, device and gateway each): PACED[NAME] is the median, PACED_ALL[NAME] all.
declare -A PACED PACED_ALL
paced() {
    local which=$1 name=$2 round rates=()
    shift 2
    for round in 1 2 3; do
        setup "$which" paced "$@"
        warm_up
        "$BIN/gw-check" "$PORT" fair 1 "$SECS" >"$OUT/paced-$name-$round.log" 2>&1 || true
        rates+=("$(rate "$OUT/paced-$name-$round.log")")
        stop_all
    done
    PACED_ALL[$name]=${rates[*]}
    PACED[$name]=$(printf '%s\n' "${rates[@]}" | median)
}
# median: the middle of the numbers on stdin (a failed round, an empty line, left out).
median() { { grep . || true; } | sort -n | awk '{ v[NR] = $1 } END { if (NR) print v[int((NR + 1) / 2)] }'; }
rate() { sed -n 's/.*(\([0-9.]*\)\/s).*/\1/p' "$1" | head -n 1; }
# spread LOG: busiest / least served, or how many masters got nothing (and of those,
# how many could not connect).
spread() {
    local line
    line=$(grep '^# fair' "$1" | head -n 1)
    if [[ $line =~ unserved\ ([0-9]+),\ not\ connected\ ([0-9]+) ]] && [ "${BASH_REMATCH[1]}" != 0 ]; then
        echo "${BASH_REMATCH[1]} never served (${BASH_REMATCH[2]} not connected)"
    else
        sed -n 's/.*spread \([0-9.]*\).*/\1/p' <<<"$line"
    fi
}

declare -A ONE MANY SPREAD RSS0 RSS P50 P99 HELD
for which in ours ${MBUSD:+mbusd}; do
    max=1000 conns=1010
    # mbusd takes at most 128 connections (-C 1-128).
    [ "$which" = mbusd ] && max=120 conns=128
    setup "$which" pty -C "$conns"
    warm_up
    "$BIN/gw-check" "$PORT" fair 1 "$SECS" >"$OUT/one-$which.log" 2>&1 || true
    ONE[$which]=$(rate "$OUT/one-$which.log")
    "$BIN/gw-check" "$PORT" fair 100 "$SECS" >"$OUT/many-$which.log" 2>&1 || true
    MANY[$which]=$(rate "$OUT/many-$which.log")
    SPREAD[$which]=$(spread "$OUT/many-$which.log")
    RSS0[$which]=$(awk '/VmRSS/ {print $2}' "/proc/$GW_PID/status")
    bg "$OUT/hold-$which.log" "$BIN/gw-check" "$PORT" hold "$max" 3
    wait_for "$OUT/hold-$which.log" HOLDING || true
    RSS[$which]=$(awk '/VmRSS/ {print $2}' "/proc/$GW_PID/status")
    HELD[$which]=$max
    P50[$which]=$(sed -n 's/.*p50 \([0-9.]*\) ms.*/\1/p' "$OUT/hold-$which.log")
    P99[$which]=$(sed -n 's/.*p99 \([0-9.]*\) ms.*/\1/p' "$OUT/hold-$which.log")
    sleep 3.5
    stop_all
done

# The paced line: one master, each gateway at -R 1; ours at -R 0 too.
for which in ours ${MBUSD:+mbusd}; do
    paced "$which" "$which-R1"
done
paced ours ours-R0 -R 0
# The floor: the device read by a master on the paced line itself, 3 rounds.
direct_rates=()
for round in 1 2 3; do
    setup ours paced
    # (gone before the master opens the line: its close would reset the terminal)
    kill "$GW_PID" 2>/dev/null || true
    wait "$GW_PID" 2>/dev/null || true
    env LD_LIBRARY_PATH="$ROOT/target/release" "$OUT/bench-client" rtu "$OUT/G" r1 -t "$SECS" -w 1000 \
        >"$OUT/direct-$round.log" 2>&1 || true
    direct_rates+=("$(sed -n 's/.*tps=\([0-9.]*\).*/\1/p' "$OUT/direct-$round.log")")
    stop_all
done
DIRECT=$(printf '%s\n' "${direct_rates[@]}" | median)

# Ours through the TLS front, against the plain front, on the same paced line.
C=$OUT/certs
c-tests/tls/make-certs.sh "$C" >/dev/null 2>&1
TLS_PORT=$(free_port)
printf 'tls_port = %s\ntls_cert = %s\ntls_key = %s\ntls_ca = %s\ntls_role.Operator = rw 1-247\nallow_plain = yes\n' \
    "$TLS_PORT" "$C/server.pem" "$C/server.key" "$C/ca.pem" >"$OUT/tls.conf"
setup ours paced -R 0 -c "$OUT/tls.conf"
tls_rates=() plain_rates=()
for round in 1 2 3; do # taking turns on the same line; the medians
    env LD_LIBRARY_PATH="$ROOT/target/release" "$BIN/gw-ours" tlsloop "$C" "$TLS_PORT" "$SECS" \
        >"$OUT/tls-$round.log" 2>&1 || true
    "$BIN/gw-check" "$PORT" fair 1 "$SECS" >"$OUT/plain-$round.log" 2>&1 || true
    tls_rates+=("$(rate "$OUT/tls-$round.log")")
    plain_rates+=("$(rate "$OUT/plain-$round.log")")
done
TLS=$(printf '%s\n' "${tls_rates[@]}" | median)
PLAIN=$(printf '%s\n' "${plain_rates[@]}" | median)
stop_all

# The line's own limit: a read of one register is 8 bytes out and 7 back, 10 bits
# each at 8N1, and a 3.5-character silence after each frame.
LIMIT=$(awk 'BEGIN { bits = (8 + 7) * 10 + 2 * 3.5 * 10; printf "%.0f", 115200 / bits }')

ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (b > 0) printf "%.2fx", a / b; else print "-" }'; }
echo
echo "## rsmodbus-gateway beside mbusd ($(date -u +%F), $(nproc) CPUs; pty at 115200 baud, -R 1 -W 300 -N 1)"
echo
echo "| measure | rsmodbus-gateway | mbusd 0.5.3 | ratio | target |"
echo "|---|---:|---:|---:|---|"
echo "| one master, answers/s | ${ONE[ours]} | ${ONE[mbusd]:--} | $(ratio "${ONE[ours]}" "${ONE[mbusd]:-0}") | >= mbusd's |"
echo "| one master on a paced line (115200 baud, half duplex; its limit: $LIMIT/s), -R 1: answers/s, median of 3 | ${PACED[ours-R1]} | ${PACED[mbusd-R1]:--} | $(ratio "${PACED[ours-R1]}" "${PACED[mbusd-R1]:-0}") | |"
echo "| the same against the line's limit | $(ratio "${PACED[ours-R1]}" "$LIMIT") | $(ratio "${PACED[mbusd-R1]:-0}" "$LIMIT") | | |"
echo "| ours at -R 0 (3.5 characters between frames, mbusd's least is 1 ms): answers/s (rounds: ${PACED_ALL[ours-R0]}), and against the limit | ${PACED[ours-R0]} ($(ratio "${PACED[ours-R0]}" "$LIMIT")) | | | >= 0.95x |"
echo "| the floor: a master on the paced line itself, no gateway and no silence (rounds: ${direct_rates[*]}): answers/s, and the gateway at -R 0 against it | $DIRECT ($(ratio "${PACED[ours-R0]}" "$DIRECT")) | | | |"
echo "| 100 masters, answers/s | ${MANY[ours]} | ${MANY[mbusd]:--} | $(ratio "${MANY[ours]}" "${MANY[mbusd]:-0}") | |"
echo "| 100 masters, busiest / least served | ${SPREAD[ours]} | ${SPREAD[mbusd]:--} | | <= 1.2 |"
echo "| masters held | ${HELD[ours]} | ${HELD[mbusd]:--} (its -C maximum is 128) | | 1,000 |"
echo "| resident memory, KiB: idle / with them held | ${RSS0[ours]} / ${RSS[ours]} | ${RSS0[mbusd]:--} / ${RSS[mbusd]:--} | | |"
echo "| one read by each held master in turn: p50 / p99, ms | ${P50[ours]} / ${P99[ours]} | ${P50[mbusd]:--} / ${P99[mbusd]:--} | | |"
echo "| one master through the Modbus/TCP Security front on the paced line at -R 0, answers/s, median of 3 (plain front: $PLAIN) | $TLS | | $(ratio "$TLS" "$PLAIN") of plain | the same (the line decides) |"
