#!/usr/bin/env bash
# The benchmark suite: Debian's libmodbus.so.5 vs rsmodbus, same C programs, one run.
#
#   scripts/bench.sh                 full mode (about 15 minutes)
#   BENCH_QUICK=1 scripts/bench.sh   short mode (about 1-2 minutes)
#   scripts/bench.sh --many          many devices from one thread (the event-driven
#                                    client) against libmodbus' ways (benches/many.sh)
#   scripts/bench.sh --pipeline      pipelined requests on one connection (the
#                                    event-driven client, modbus_set_max_in_flight)
#                                    against libmodbus' blocking calls, over loopback
#                                    and a 10 ms round trip (benches/pipeline.sh,
#                                    about 3 minutes)
#   scripts/bench.sh --server-many   the server that runs itself (modbus_server_new)
#                                    under many clients: 100 in closed loop against
#                                    libmodbus' select() loop and pymodbus' asyncio
#                                    server, 10,000 at one request a second, memory
#                                    per idle client (TCP and TLS), TLS clients beside
#                                    stalled handshakes (benches/server-many.sh, about
#                                    2 minutes)
#   scripts/bench.sh --gateway       target/release/rsmodbus-gateway (or GATEWAY_BIN)
#                                    beside mbusd (built from
#                                    ../shared/anchors/mbusd when it is there) on an
#                                    RTU line, a pty pair or one paced at 115200 baud:
#                                    one master, 100 masters (spread), 1,000 held (RSS,
#                                    p99), the TLS front (benches/gateway.sh, about 4
#                                    minutes)
#   scripts/bench.sh --callbacks     modbus_reply_dispatch against modbus_reply on one
#                                    mapping: CPU per reply (benches/reply-cost.sh,
#                                    about 20 s)
#   scripts/bench.sh --repeat N [CASE ...]
#                                    the throughput of CASE (default wr121, TCP) in N
#                                    runs with new processes each: how far a ratio
#                                    moves between runs (benches/repeat.py)
#
# Prints Markdown tables (also written to target/bench/results.md): transactions/s
# of every case over TCP loopback and an RTU pty pair, for our client, our server and
# both against Debian's, the bare floor, Modbus/TCP Security against our plain TCP and
# against stunnel in front of Debian's libmodbus (BENCH_STUNNEL=0: without it), and
# system calls, instructions and heap
# allocations per transaction. Knobs: BENCH_CASES, BENCH_TRANSPORTS, BENCH_SLICE,
# BENCH_SECONDS, BENCH_METRIC_CASES, BENCH_METRICS, BENCH_THROUGHPUT, BENCH_PIN,
# BENCH_FLOOR_PARTS, BENCH_RESULTS (see benches/README.md). c-tests/suites/bench-smoke.sh is the short run
# of the test command. "Ours" is the library the Debian packages ship, built with
# profile-guided optimisation (scripts/build-pgo.sh); BENCH_PGO=0 measures a plain
# `cargo build --release` instead.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
program=(benches/bench.py)
if [ "${1:-}" = --many ]; then
    # Many devices from one thread: benches/many.sh (about 10 s).
    scripts/install-deps.sh >/dev/null
    exec benches/many.sh
fi
if [ "${1:-}" = --pipeline ]; then
    # Pipelining on one connection: benches/pipeline.sh (about 3 minutes).
    scripts/install-deps.sh >/dev/null
    exec benches/pipeline.sh
fi
if [ "${1:-}" = --server-many ]; then
    # The server runner under many clients: benches/server-many.sh (about 2 minutes).
    scripts/install-deps.sh >/dev/null
    exec benches/server-many.sh
fi
if [ "${1:-}" = --gateway ]; then
    # The gateway beside mbusd: benches/gateway.sh (about 4 minutes).
    scripts/install-deps.sh >/dev/null
    exec benches/gateway.sh
fi
if [ "${1:-}" = --callbacks ]; then
    exec benches/reply-cost.sh
fi
if [ "${1:-}" = --repeat ]; then
    [ $# -ge 2 ] || { echo "usage: $0 --repeat N [CASE ...]" >&2; exit 2; }
    shift
    program=(benches/repeat.py "$@")
fi
scripts/install-deps.sh >/dev/null
for tool in strace socat valgrind python3 gcc openssl; do
    command -v "$tool" >/dev/null || { apt-get install -y -qq "$tool" >/dev/null; }
done
# Modbus/TCP Security's comparison: Debian's libmodbus behind stunnel (package stunnel4).
command -v stunnel >/dev/null || apt-get install -y -qq stunnel4 >/dev/null || true
if [ "${BENCH_PGO:-1}" = 0 ]; then
    cargo build --release -q
    built=target/release
    export BENCH_OURS_BUILD="a plain cargo build --release (BENCH_PGO=0)"
else
    # With the packages' flags: the library they ship (and the one the test run builds).
    scripts/build-pgo.sh --debian-flags >/dev/null
    built=target/pgo/release
    export BENCH_OURS_BUILD="the profile-guided build the Debian packages ship (scripts/build-pgo.sh --debian-flags)"
fi
benches/build.sh target/bench
# Measure a copy: a rebuild of the library during the run must not change it.
mkdir -p target/bench/ours
cp "$built/libmodbus.so" target/bench/ours/libmodbus.so.5
BENCH_OURS_DIR=$PWD/target/bench/ours exec python3 "${program[@]}"
