#!/usr/bin/env bash
# benches/pipeline.sh: the event-driven client's pipelining (modbus_set_max_in_flight)
# against libmodbus' blocking calls, one connection, in one run
# (scripts/bench.sh --pipeline). Loopback only.
#
# The client is benches/pipeline-client.c (a read of 10 holding registers, each
# answer checked); the servers: rsmodbus' server that runs itself (modbus_server_new,
# c-tests/runner/runner-server.c; BENCH_OURS_SERVER=mb-server: benches/mb-server.c's
# blocking loop instead) on the profile-guided build the packages ship
# (scripts/build-pgo.sh), and benches/mb-server.c on Debian's libmodbus 3.1.6.
# Three figures, each a Markdown table with its ratios and targets:
#  (a) Through benches/delay-proxy.c, which adds BENCH_DELAY_MS (5) each way (a round
#      trip of about 10 ms): the async client at depth BENCH_DEPTH (16) against depth
#      1, for each server. Target: at least 12x the transactions per second.
#      Diagnostic rows (BENCH_NODELAY_DIAG=0 leaves them out): the same servers with
#      benches/nodelay-preload.c preloaded, which sets TCP_NODELAY on the sockets they
#      accept (libmodbus leaves Nagle's algorithm on there; rsmodbus' servers set
#      it themselves): how much of the pipeline's gain the servers' Nagle holds back.
#  (b) Loopback, no proxy: the async client at depth 16 on rsmodbus against Debian's
#      blocking client (modbus_read_registers in a loop), each server. Targets:
#      at least 3x the transactions per second; at most 0.5 system calls per
#      transaction on the async client (against our server).
#  (c) Loopback: the async client at depth 1 against our own blocking client, each
#      server. Target: at least 0.9x the transactions per second.
# (b) and (c) are measured in two placements (BENCH_PLACEMENTS, "free one"): free,
# where the scheduler places client and server (on an otherwise idle 2-CPU VM, on
# different CPUs: a blocking transaction then waits for a wake-up across CPUs), and
# one, where server and clients all run on CPU BENCH_PIN_CPU (1; taskset), which
# makes each wake-up a context switch. On this machine (2026-12-04) a blocking client ran about 3x
# faster on one CPU than across two, the pipelined one about 1.5x slower, so the
# ratios depend on the placement much more than on anything else.
#
# Method. The clients compared in a table take turns against the same server: the
# BENCH_SECONDS (5) of each are cut into BENCH_ROUNDS (5) runs, and each round runs
# every client once, in an order that rotates from round to round, so a change of
# the shared machine's load falls on all of them alike. A client is a new process
# and connection each round, with 20 transactions of warm-up that are not counted.
# tx/s: the transactions of all rounds over their time; a ratio: of those, with the
# lowest and highest ratio of a single round in brackets.
# System calls per transaction: the async client is run for exactly N and 2N
# transactions (pipeline-client -n, BENCH_STRACE_TX: 20,000) after the same warm-up;
# (calls(2N) - calls(N)) / N leaves the calls of start-up, connect, warm-up and exit,
# which both runs make alike, out. Counted with `strace -f -c` (ptrace: every system
# call stops the client, which slows it and can change how many answers one read
# finds) and, where the kernel lets it, with `perf stat -e raw_syscalls:sys_enter`
# (a counter: no stop), which the target is also judged on.
#
# Every program prints the libmodbus.so.5 it loaded (LIBINFO); the script checks it.
# Logs in target/bench-pipeline/. Knobs: BENCH_SECONDS, BENCH_ROUNDS, BENCH_DELAY_MS,
# BENCH_DEPTH, BENCH_STRACE_TX, BENCH_NODELAY_DIAG, BENCH_PLACEMENTS, BENCH_PIN_CPU.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
SECS=${BENCH_SECONDS:-5}
ROUNDS=${BENCH_ROUNDS:-5}
DELAY=${BENCH_DELAY_MS:-5}
DEPTH=${BENCH_DEPTH:-16}
STRACE_TX=${BENCH_STRACE_TX:-20000}
DIAG=${BENCH_NODELAY_DIAG:-1}
PLACEMENTS=${BENCH_PLACEMENTS:-free one}
PIN_CPU=${BENCH_PIN_CPU:-$(($(nproc) > 1 ? 1 : 0))}
PIN=() # the placement of the programs started: (taskset -c CPU) or none
OUT=target/bench-pipeline
DEBIAN_LIB=$(realpath /usr/lib/x86_64-linux-gnu/libmodbus.so.5)
mkdir -p "$OUT"
rm -f "$OUT"/*.log "$OUT"/rounds-*.txt "$OUT"/*.strace "$OUT"/*.perf

# --- build ---------------------------------------------------------------------------
for tool in strace gcc pkg-config; do
    command -v "$tool" >/dev/null || apt-get install -y -qq "$tool" >/dev/null
done
[ -e target/pgo/release/libmodbus.so.5 ] || scripts/build-pgo.sh >/dev/null
# Measure a copy: a rebuild of the library during the run must not change it.
mkdir -p "$OUT/ours"
cp target/pgo/release/libmodbus.so "$OUT/ours/libmodbus.so.5"
OURS=$(realpath "$OUT/ours")
benches/build.sh "$OUT" # mb-server (and the other benchmark programs)
OURS_SERVER=${BENCH_OURS_SERVER:-runner}
make -s -C c-tests runner-server >/dev/null
RUNNER=$(make -s -C c-tests print-CTEST_BUILD 2>/dev/null || true)
RUNNER=${RUNNER:-target/c-tests-build}/bin/runner-server
CFLAGS=(-std=gnu11 -O2 -g -Wall -Wextra -Werror)
gcc "${CFLAGS[@]}" benches/delay-proxy.c -o "$OUT/delay-proxy"
gcc "${CFLAGS[@]}" -shared -fPIC benches/nodelay-preload.c -o "$OUT/nodelay-preload.so" -ldl
gcc "${CFLAGS[@]}" $(pkg-config --cflags libmodbus) benches/pipeline-client.c c-tests/common/libinfo.c \
    -o "$OUT/pipeline-client" -lmodbus -ldl
perf_ok=0
if command -v perf >/dev/null && perf stat -x, -e raw_syscalls:sys_enter -- true >/dev/null 2>&1; then
    perf_ok=1
fi

# --- processes -----------------------------------------------------------------------
# Every background process is started by start() and stopped by its PID on exit.
pids=()
stop_all() {
    local p
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
}
trap stop_all EXIT

# lib_env ours|debian: sets LIBENV, the `env` arguments that make a program load that
# library (and have libinfo.c exit if it did not: EXPECT_LIB).
lib_env() {
    if [ "$1" = ours ]; then
        LIBENV=(LD_LIBRARY_PATH="$OURS" EXPECT_LIB=ours)
    else
        LIBENV=(-u LD_LIBRARY_PATH EXPECT_LIB=debian)
    fi
}
# check_lib LOG ours|debian: the LIBINFO line of LOG names that library.
check_lib() {
    local want
    if [ "$2" = ours ]; then want="$OURS/libmodbus.so.5 (rsmodbus"; else want="$DEBIAN_LIB (debian"; fi
    grep -qF "libmodbus.so.5 = $want" "$1" ||
        { echo "pipeline.sh: $1 did not load $2's library:" >&2; cat "$1" >&2; exit 1; }
}
# start NAME CMD...: runs CMD in the background (logged to $OUT/NAME.log) until it
# prints "READY <port>"; sets $port. taskset and env exec what follows them: the PID
# kept is the program's.
start() {
    local name=$1 pid
    shift
    "$@" >"$OUT/$name.log" 2>&1 &
    pid=$!
    pids+=("$pid")
    for _ in $(seq 100); do
        grep -q '^READY' "$OUT/$name.log" && break
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.05
    done
    port=$(sed -n 's/^READY //p' "$OUT/$name.log")
    [ -n "$port" ] || { echo "pipeline.sh: $name did not start:" >&2; cat "$OUT/$name.log" >&2; exit 1; }
}
# server NAME ours|debian [VAR=VALUE...]: the server on that library, with those
# variables too, placed as PIN says; sets $port. Debian's: mb-server (a blocking
# modbus_receive/modbus_reply loop); ours: the server that runs itself
# (modbus_server_new: c-tests/runner/runner-server.c, the same data), or mb-server with
# BENCH_OURS_SERVER=mb-server.
server() {
    local name=$1 lib=$2 prog=("$OUT/mb-server" tcp 0)
    shift 2
    lib_env "$lib"
    [ "$lib" = ours ] && [ "$OURS_SERVER" = runner ] && prog=("$RUNNER" tcp 0 --bench)
    start "$name" "${PIN[@]}" env "${LIBENV[@]}" "$@" "${prog[@]}"
    check_lib "$OUT/$name.log" "$lib"
}

# A client is named LIB:MODE:DEPTH (ours:async:16, debian:blocking:1).
# client_cmd SPEC PORT [OPTIONS...] -- [SECONDS]: sets ENVCMD (the placement, PIN,
# and `env` with the library's variables), PROG (the client's command line) and CLIB (the library).
client_cmd() {
    local lib mode depth spec=$1 port=$2 opts=()
    shift 2
    IFS=: read -r lib mode depth <<<"$spec"
    while [ $# -gt 0 ] && [ "$1" != -- ]; do opts+=("$1"); shift; done
    [ $# -gt 0 ] && shift
    lib_env "$lib"
    ENVCMD=("${PIN[@]}" env "${LIBENV[@]}")
    PROG=("$OUT/pipeline-client" "${opts[@]}" 127.0.0.1 "$port" "$mode")
    [ "$mode" = async ] && PROG+=("$depth")
    PROG+=("$@")
    CLIB=$lib
}
# run_client LOG SPEC PORT [OPTIONS...] -- [SECONDS]: one run; prints its RESULT line.
run_client() {
    local log=$1
    shift
    client_cmd "$@"
    "${ENVCMD[@]}" "${PROG[@]}" >"$log" 2>&1 ||
        { echo "pipeline.sh: client $* failed:" >&2; cat "$log" >&2; exit 1; }
    check_lib "$log" "$CLIB"
    grep '^RESULT' "$log"
}
field() { sed -n "s/.* $1=\([^ ]*\).*/\1/p" <<<"$2"; }

# rounds SET PORT SPEC...: the clients SPEC take turns against PORT (see Method);
# each run's numbers go to $OUT/rounds-SET.txt as "SPEC ROUND tx seconds polls
# processes batches".
rounds() {
    local set=$1 port=$2 r i n slice r_line spec
    shift 2
    local specs=("$@")
    n=${#specs[@]}
    slice=$(awk -v s="$SECS" -v r="$ROUNDS" 'BEGIN { printf "%.3f", s / r }')
    for r in $(seq 0 $((ROUNDS - 1))); do
        for i in $(seq 0 $((n - 1))); do
            spec=${specs[$(((i + r) % n))]}
            r_line=$(run_client "$OUT/$set-${spec//:/-}-$r.log" "$spec" "$port" -- "$slice")
            echo "$spec $r $(field tx "$r_line") $(field seconds "$r_line") $(field polls "$r_line")" \
                "$(field processes "$r_line") $(field batches "$r_line")" >>"$OUT/rounds-$set.txt"
        done
    done
}
# tps SET SPEC: the transactions per second of SPEC over all its rounds.
tps() {
    awk -v s="$2" '$1 == s { tx += $3; t += $4 } END { printf "%.0f", tx / t }' "$OUT/rounds-$1.txt"
}
# per_tx SET SPEC COLUMN(polls|processes|batches): that count per transaction.
per_tx() {
    awk -v s="$2" -v c="$3" 'BEGIN { k = c == "polls" ? 5 : c == "processes" ? 6 : 7 }
        $1 == s { tx += $3; v += $k } END { printf "%.3f", v / tx }' "$OUT/rounds-$1.txt"
}
# ratio SET A B: (tx/s of A) / (tx/s of B) over all rounds, and the lowest and highest
# ratio of one round: "R (LO-HI)".
ratio() {
    awk -v a="$2" -v b="$3" '
        $1 == a { ta += $3; sa += $4; ra[$2] = $3 / $4 }
        $1 == b { tb += $3; sb += $4; rb[$2] = $3 / $4 }
        END {
            lo = 1e30; hi = 0
            for (r in ra) { x = ra[r] / rb[r]; if (x < lo) lo = x; if (x > hi) hi = x }
            printf "%.2fx (%.2f-%.2fx)", (ta / sa) / (tb / sb), lo, hi
        }' "$OUT/rounds-$1.txt"
}
# verdict VALUE >=|<= TARGET: "yes (+N% of the target)" or "no (...)".
verdict() {
    awk -v v="${1%%x*}" -v op="$2" -v t="$3" 'BEGIN {
        ok = op == ">=" ? v >= t : v <= t
        printf "%s (%+.0f%% of the target)", ok ? "**yes**" : "**no**", (v / t - 1) * 100 }'
}

# --- the servers and proxies -----------------------------------------------------------
server srv-ours ours
ours_port=$port
server srv-debian debian
debian_port=$port
start proxy-ours "$OUT/delay-proxy" 0 "$ours_port" "$DELAY"
proxy_ours=$port
start proxy-debian "$OUT/delay-proxy" 0 "$debian_port" "$DELAY"
proxy_debian=$port
if [ "$DIAG" = 1 ]; then
    server srv-ours-nodelay ours LD_PRELOAD="$(realpath "$OUT/nodelay-preload.so")"
    start proxy-ours-nodelay "$OUT/delay-proxy" 0 "$port" "$DELAY"
    proxy_ours_nodelay=$port
    server srv-debian-nodelay debian LD_PRELOAD="$(realpath "$OUT/nodelay-preload.so")"
    start proxy-debian-nodelay "$OUT/delay-proxy" 0 "$port" "$DELAY"
    proxy_debian_nodelay=$port
fi
# One CPU: a server and its clients all on CPU $PIN_CPU.
if [[ " $PLACEMENTS " == *" one "* ]]; then
    PIN=(taskset -c "$PIN_CPU")
    server srv-ours-one ours
    ours_one_port=$port
    server srv-debian-one debian
    debian_one_port=$port
    PIN=()
fi

echo "pipeline.sh: $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg); $ROUNDS rounds," \
    "$SECS s per client; logs in $OUT" >&2
A16=ours:async:$DEPTH A1=ours:async:1 DB=debian:blocking:1 OB=ours:blocking:1
echo "(a) through the delay proxy..." >&2
rounds a-ours "$proxy_ours" "$A1" "$A16"
rounds a-debian "$proxy_debian" "$A1" "$A16"
if [ "$DIAG" = 1 ]; then
    rounds a-ours-nodelay "$proxy_ours_nodelay" "$A1" "$A16"
    rounds a-debian-nodelay "$proxy_debian_nodelay" "$A1" "$A16"
fi
echo "(b), (c) loopback..." >&2
for placement in $PLACEMENTS; do
    if [ "$placement" = one ]; then
        PIN=(taskset -c "$PIN_CPU")
        rounds one-ours "$ours_one_port" "$A16" "$DB" "$A1" "$OB"
        rounds one-debian "$debian_one_port" "$A16" "$DB" "$A1" "$OB"
    else
        PIN=()
        rounds free-ours "$ours_port" "$A16" "$DB" "$A1" "$OB"
        rounds free-debian "$debian_port" "$A16" "$DB" "$A1" "$OB"
    fi
done
PIN=()

# --- system calls per transaction (our server) -----------------------------------------
echo "(b) system calls..." >&2
N2=$((2 * STRACE_TX))
# traced NAME SPEC PORT N: SPEC for N transactions (after 200 of warm-up) under
# strace -f -c, the table in $OUT/NAME-N.strace; prints the total of calls.
traced() {
    client_cmd "$2" "$3" -n "$4" -w 200 --
    "${ENVCMD[@]}" strace -f -c -o "$OUT/$1-$4.strace" "${PROG[@]}" >"$OUT/$1-$4.log" 2>&1 ||
        { echo "pipeline.sh: strace run of $2 failed:" >&2; cat "$OUT/$1-$4.log" >&2; exit 1; }
    check_lib "$OUT/$1-$4.log" "$CLIB"
    awk '$NF == "total" { print $4 }' "$OUT/$1-$4.strace"
}
# strace_per_tx NAME SPEC PORT: (calls(2N) - calls(N)) / N under strace.
strace_per_tx() {
    local a b
    a=$(traced "$1" "$2" "$3" "$STRACE_TX")
    b=$(traced "$1" "$2" "$3" "$N2")
    awk -v a="$a" -v b="$b" -v n="$STRACE_TX" 'BEGIN { printf "%.3f", (b - a) / n }'
}
# strace_split NAME: per system call, (calls in the 2N run - calls in the N run) / N,
# those of 0.005 or more: "poll 0.210, recvfrom 0.250".
strace_split() {
    awk -v n="$STRACE_TX" '
        FNR == 1 { f++ } /^-|^%|total$/ { next }
        NF >= 5 { c[$NF] += (f == 1 ? -$4 : $4) }
        END { for (k in c) if (c[k] / n >= 0.005) { printf "%s%s %.3f", sep, k, c[k] / n; sep = ", " } }' \
        "$OUT/$1-$STRACE_TX.strace" "$OUT/$1-$N2.strace"
}
# perf_counted NAME SPEC PORT N: the same run under perf stat, counting every system
# call and a few by name (a counter: the client is never stopped).
perf_counted() {
    local ev=(-e raw_syscalls:sys_enter) s
    for s in poll ppoll recvfrom sendto read write readv writev recvmsg sendmsg; do
        ev+=(-e "syscalls:sys_enter_$s")
    done
    client_cmd "$2" "$3" -n "$4" -w 200 --
    perf stat -x, "${ev[@]}" -o "$OUT/$1-$4.perf" -- "${ENVCMD[@]}" "${PROG[@]}" >"$OUT/$1-$4.log" 2>&1 ||
        { echo "pipeline.sh: perf run of $2 failed:" >&2; cat "$OUT/$1-$4.log" >&2; exit 1; }
    check_lib "$OUT/$1-$4.log" "$CLIB"
}
# perf_per_tx NAME SPEC PORT: prints "TOTAL_PER_TX SPLIT" (as strace_split).
perf_per_tx() {
    perf_counted "$1" "$2" "$3" "$STRACE_TX"
    perf_counted "$1" "$2" "$3" "$N2"
    awk -F, -v n="$STRACE_TX" '
        FNR == 1 { f++ } $3 ~ /sys_enter/ { c[$3] += (f == 1 ? -$1 : $1) }
        END {
            printf "%.3f ", c["raw_syscalls:sys_enter"] / n
            for (k in c) if (k != "raw_syscalls:sys_enter" && c[k] / n >= 0.005) {
                name = k; sub(/.*sys_enter_/, "", name); printf "%s%s %.3f", sep, name, c[k] / n; sep = ", " }
        }' "$OUT/$1-$STRACE_TX.perf" "$OUT/$1-$N2.perf"
}
# run_stats LOG: the tx/s of the RESULT line in LOG, and its transactions per
# modbus_process call that completed any (a batch).
run_stats() {
    local line
    line=$(grep '^RESULT' "$1")
    awk -v t="$(field tx "$line")" -v b="$(field batches "$line")" -v r="$(field tx_per_s "$line")" \
        'BEGIN { printf "%.0f tx/s, %.2f answers per batch", r, t / b }'
}
declare -A STRACE_PER STRACE_SPLIT STRACE_STATS PERF_PER PERF_SPLIT PERF_STATS
for placement in $PLACEMENTS; do
    if [ "$placement" = one ]; then PIN=(taskset -c "$PIN_CPU") p=$ours_one_port; else PIN=() p=$ours_port; fi
    STRACE_PER[$placement]=$(strace_per_tx "strace-async-$placement" "$A16" "$p")
    STRACE_SPLIT[$placement]=$(strace_split "strace-async-$placement")
    STRACE_STATS[$placement]=$(run_stats "$OUT/strace-async-$placement-$N2.log")
    if [ "$perf_ok" = 1 ]; then
        out=$(perf_per_tx "perf-async-$placement" "$A16" "$p")
        PERF_PER[$placement]=${out%% *}
        PERF_SPLIT[$placement]=${out#* }
        PERF_STATS[$placement]=$(run_stats "$OUT/perf-async-$placement-$N2.log")
    fi
done
PIN=()
# The blocking clients, for scale (the same count in either placement).
debian_calls=$(strace_per_tx strace-debian-blocking "$DB" "$ours_port")
ours_calls=$(strace_per_tx strace-ours-blocking "$OB" "$ours_port")

# --- the tables ------------------------------------------------------------------------
placement_name() {
    if [ "$1" = one ]; then echo "one CPU (taskset -c $PIN_CPU)"; else echo "$(nproc) CPUs, scheduler's choice"; fi
}
server_name() { if [ "$1" = ours ]; then echo rsmodbus; else echo "libmodbus 3.1.6"; fi; }
# server_prog ours|debian: which server program ran.
server_prog() {
    if [ "$1" = ours ] && [ "$OURS_SERVER" = runner ]; then echo "runner (modbus_server_new)"; else echo mb-server; fi
}
echo
echo "## Pipelining, one connection, read of 10 holding registers ($(date -u +%F), $(nproc) CPUs)"
echo
echo "rsmodbus: the profile-guided build (scripts/build-pgo.sh); libmodbus 3.1.6: Debian's."
echo "$ROUNDS rounds, $SECS s per client in all; ratio: over all rounds (lowest-highest round)."
echo
echo "### (a) Through a delay proxy, $DELAY ms each way: depth $DEPTH against depth 1"
echo
echo "| server | depth 1: tx/s (round trip) | depth $DEPTH: tx/s | ratio | target | met |"
echo "|---|---:|---:|---:|---|---|"
sets=(a-ours a-debian)
[ "$DIAG" = 1 ] && sets+=(a-ours-nodelay a-debian-nodelay)
for set in "${sets[@]}"; do
    one=$(tps "$set" "$A1") many=$(tps "$set" "$A16") r=$(ratio "$set" "$A16" "$A1")
    rtt=$(awk -v t="$one" 'BEGIN { printf "%.2f", 1000 / t }')
    srv=${set#a-}
    srv=${srv%-nodelay}
    if [ "$set" = "a-$srv" ]; then
        echo "| $(server_name "$srv") $(server_prog "$srv") | $one ($rtt ms) | $many | $r | >= 12x | $(verdict "$r" '>=' 12) |"
    else
        echo "| diagnostic: $(server_name "$srv") $(server_prog "$srv"), TCP_NODELAY on its accepted socket |" \
            "$one ($rtt ms) | $many | $r | (not the figure) | |"
    fi
done
if [ "$DIAG" = 1 ]; then
    echo
    echo "Diagnostic rows: the same server binary and library with benches/nodelay-preload.c"
    echo "preloaded (TCP_NODELAY on the accepted socket; libmodbus leaves Nagle's algorithm on"
    echo "there, so its answers after the first of a burst wait for their acknowledgement;"
    echo "rsmodbus' servers set TCP_NODELAY themselves)."
fi
echo
# ratio_rows NUM DEN TARGET [MEASURE]: one table row per placement and server, the
# transactions per second of client set NUM against DEN, and whether the ratio is at
# least TARGET (MEASURE: a column naming the measure, when the table has one).
ratio_rows() {
    local placement srv set r
    for placement in $PLACEMENTS; do
        for srv in ours debian; do
            set=$placement-$srv
            r=$(ratio "$set" "$1" "$2")
            echo "| $(server_name $srv) | $(placement_name "$placement") |${4:+ $4 |} $(tps "$set" "$1") |" \
                "$(tps "$set" "$2") | $r | >= ${3}x | $(verdict "$r" '>=' "$3") |"
        done
    done
}
echo "### (b) Loopback: rsmodbus async, depth $DEPTH, against libmodbus' blocking client"
echo
echo "| server | placement | measure | rsmodbus async, depth $DEPTH | libmodbus 3.1.6 blocking | ratio | target | met |"
echo "|---|---|---|---:|---:|---:|---|---|"
ratio_rows "$A16" "$DB" 3 tx/s
for placement in $PLACEMENTS; do
    v=${STRACE_PER[$placement]}
    echo "| rsmodbus | $(placement_name "$placement") | client system calls per transaction (strace -f -c) |" \
        "$v | $debian_calls | | <= 0.5 | $(verdict "$v" '<=' 0.5) |"
    if [ "$perf_ok" = 1 ]; then
        v=${PERF_PER[$placement]}
        echo "| rsmodbus | $(placement_name "$placement") | the same, counted by perf (no ptrace stops) |" \
            "$v | | | <= 0.5 | $(verdict "$v" '<=' 0.5) |"
    fi
done
echo
echo "Where the async client's system calls go, per transaction (depth $DEPTH, our server), and"
echo "how many answers one modbus_process call that completed any took (a batch):"
echo
for placement in $PLACEMENTS; do
    echo "- $(placement_name "$placement"), strace: ${STRACE_SPLIT[$placement]}; under strace:" \
        "${STRACE_STATS[$placement]}"
    if [ "$perf_ok" = 1 ]; then
        echo "- $(placement_name "$placement"), perf: ${PERF_SPLIT[$placement]}; ${PERF_STATS[$placement]}"
    fi
    echo "- $(placement_name "$placement"), timed rounds: poll() $(per_tx "$placement-ours" "$A16" polls)," \
        "modbus_process() $(per_tx "$placement-ours" "$A16" processes) per transaction;" \
        "$(awk -v b="$(per_tx "$placement-ours" "$A16" batches)" 'BEGIN { printf "%.2f", 1 / b }')" \
        "answers per batch"
done
echo "- for scale (strace): our blocking client $ours_calls system calls per transaction," \
    "libmodbus' $debian_calls"
echo
echo "### (c) Loopback, depth 1: rsmodbus async against rsmodbus blocking"
echo
echo "| server | placement | rsmodbus async, depth 1: tx/s | rsmodbus blocking: tx/s | ratio | target | met |"
echo "|---|---|---:|---:|---:|---|---|"
ratio_rows "$A1" "$OB" 0.9
echo
for placement in $PLACEMENTS; do
    echo "Async depth 1, our server, $(placement_name "$placement"): poll() $(per_tx "$placement-ours" "$A1" polls)," \
        "modbus_process() $(per_tx "$placement-ours" "$A1" processes) per transaction."
done
