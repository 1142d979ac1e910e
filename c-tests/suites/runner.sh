#!/usr/bin/env bash
# runner.sh: the server that runs itself (modbus_server_new(3)): c-tests/runner/
# runner-server.c, ours, against clients no one here wrote the library of: Debian's
# libmodbus (c-tests/runner/runner-check.c, built against Debian's headers and run on
# Debian's library, then on ours), pymodbus (c-tests/runner/pm_runner.py: MBAP and RTU
# framing over TCP, asyncio clients at once; UDP both ways), raw sockets that misbehave (pipelined
# requests, a byte at a time, a request stalled halfway, garbage, half-open, a client
# that never reads, idle clients), Modbus/TCP Security clients beside 50 handshakes
# that stall, an RTU line on a pty pair with three units, 10,000 clients at once, a
# stop from a signal handler and from a callback, the server in the application's
# own poll loop, the runner beside the blocking server (c-tests/runner/runner-diag.c:
# diagnostics counters, the ASCII input delimiter, a stop during a flush), servers
# started the libmodbus way (modbus_tcp_listen, then modbus_server_new) and a
# hand-written Modbus/UDP loop answering two peers (c-tests/runner/server-setup.c),
# callbacks with their request info and answers given later
# (c-tests/runner/runner-later.c), Modbus/UDP (our client and runner against
# pymodbus' server and client, and through a proxy that loses and repeats
# datagrams), and the server under AddressSanitizer.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
# usage: c-tests/suites/runner.sh [--no-cargo] [--no-install] [--quick]
#   --quick: 1,000 clients instead of 10,000
# Output goes to target/runner-tests. The last line is "N passed, M failed"; the exit
# status is non-zero if M > 0. Every process started here is stopped by its PID.
set -u
set -o pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
WORK=${RUNNERTEST_OUT:-$ROOT/target/runner-tests}
LIBDIR=$ROOT/target/release

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"

QUICK=0
INSTALL=1
suite_flag() {
    case "$1" in
    --quick) QUICK=1 ;;
    --no-install) INSTALL=0 ;;
    *) return 1 ;;
    esac
}
parse_flags -- "$@"
MANY=10000
[ "$QUICK" = 1 ] && MANY=1000

section "build"
our_lib_result "$LIBDIR" 2
rm -rf "$WORK"
mkdir -p "$WORK"
BIN=$(c_build_dir)
c_build_group RUNNER
c_build tls-test
C=$WORK/certs
check "make the test certificates with openssl" "$ROOT/c-tests/tls/make-certs.sh" "$C"

# serve NAME MODE ADDR [OPTIONS...]: starts runner-server (ours) as NAME; PORT is
# the port when ADDR is "port".
serve() {
    local name=$1 mode=$2 addr=$3
    shift 3
    if [ "$addr" = port ]; then
        PORT=$(free_port)
        addr=$PORT
    fi
    local extra=()
    [ "$mode" = tls ] && extra=("$C/server.pem" "$C/server.key" "$C/ca.pem")
    start "$name" env LD_LIBRARY_PATH="$LIBDIR" "$BIN/runner-server" "$mode" "$addr" "${extra[@]}" "$@"
    if wait_ready "$name" READY 10; then
        libinfo_ours "$name: the server is ours" "$WORK/$name.log"
    else
        bad "$name: the server starts" "$(tail -n 5 "$WORK/$name.log")"
    fi
}

# client LIB NAME SCENARIO...: runner-check on Debian's libmodbus (LIB=debian) or ours.
client() {
    local lib=$1 name=$2 log rc=0
    shift 2
    log=$WORK/$name.log
    if [ "$lib" = ours ]; then
        env LD_LIBRARY_PATH="$LIBDIR" EXPECT_LIB=ours timeout -k 5 300 "$BIN/runner-check" "$@" >"$log" 2>&1 || rc=$?
    else
        env -u LD_LIBRARY_PATH EXPECT_LIB=debian timeout -k 5 300 "$BIN/runner-check" "$@" >"$log" 2>&1 || rc=$?
    fi
    program_checks "$name ($lib's libmodbus clients)" "$log" "$rc"
}

# halt NAME TEXT: stops NAME by SIGTERM (its handler calls modbus_server_stop) and
# checks that it ended cleanly, saying TEXT.
halt() {
    local name=$1 text=$2 pid=${_pids[$1]:-}
    [ -n "$pid" ] && kill -TERM "$pid" 2>/dev/null
    wait_exit "$name" 10
    if [ "$rc" = 0 ] && grep -q "$text" "$WORK/$name.log"; then
        ok "$name: stopped ($(grep -o "$text.*" "$WORK/$name.log" | head -n 1))"
    else
        bad "$name: stopped" "exit $rc: $(tail -n 3 "$WORK/$name.log")"
    fi
}

# in_process PROGRAM NAME SECS ARGS...: a program of ours that runs its servers and
# clients itself (on our library), for up to SECS seconds; its log is
# $WORK/NAME.log, its "#" lines are shown, its checks counted.
in_process() {
    local prog=$1 name=$2 secs=$3 log rc=0
    shift 3
    log=$WORK/$name.log
    env LD_LIBRARY_PATH="$LIBDIR" EXPECT_LIB=ours timeout -k 5 "$secs" "$BIN/$prog" "$@" >"$log" 2>&1 || rc=$?
    libinfo_ours "$name" "$log"
    grep '^#' "$log"
    program_checks "$name" "$log" "$rc"
}

section "TCP, a mapping: Debian's libmodbus clients, then ours"
serve tcp tcp port --idle 3000
for lib in debian ours; do
    client "$lib" "tcp-basic-$lib" "$PORT" basic 0
    client "$lib" "tcp-many-$lib" "$PORT" many 500
done
client ours tcp-pipelined "$PORT" pipelined
client ours tcp-slow "$PORT" slow
client ours tcp-full "$PORT" full
halt tcp "stopped by a signal"

section "TCP, callbacks: three units, a stop from a callback"
serve tcpcb tcp port --callbacks
client debian tcpcb-basic-1 "$PORT" basic 1
client debian tcpcb-basic-7 "$PORT" basic 3
client debian tcpcb-units "$PORT" units
client debian tcpcb-stop "$PORT" stop
wait_exit tcpcb 10
if [ "$rc" = 0 ] && grep -q "stop asked by a client" "$WORK/tcpcb.log" && grep -q "^stopped," "$WORK/tcpcb.log"; then
    ok "tcpcb: modbus_server_stop from a callback ends the run"
else
    bad "tcpcb: modbus_server_stop from a callback ends the run" "exit $rc: $(tail -n 3 "$WORK/tcpcb.log")"
fi

section "answers given later (a raw callback, MODBUS_REPLY_LATER, modbus_server_answer from a thread)"
serve later tcp port --later
client debian later "$PORT" later
client debian later-many "$PORT" many 100
halt later "stopped by a signal"

section "the application's own poll loop (modbus_server_get_fd, modbus_server_run(s, 0))"
serve polled tcp port --poll --idle 1000
client debian polled-basic "$PORT" basic 0
client debian polled-many "$PORT" many 200
client debian polled-idle "$PORT" idle 1000
halt polled "stopped by a signal"

section "a server context configured beyond libmodbus: its configuration serves every client"
serve status tcp port --status 90
client debian status "$PORT" status 90
halt status "stopped by a signal"

section "a listening socket the application made (modbus_tcp_listen, modbus_set_socket)"
start given env LD_LIBRARY_PATH="$LIBDIR" "$BIN/runner-server" tcp 0
if wait_ready given READY 10; then
    PORT=$(sed -n 's/^READY //p' "$WORK/given.log")
    client debian given-basic "$PORT" basic 0
    client debian given-pipelined "$PORT" pipelined
else
    bad "given: the server starts" "$(tail -n 5 "$WORK/given.log")"
fi
halt given "stopped by a signal"

section "the libmodbus habit: modbus_tcp_listen first, then modbus_server_new (c-tests/runner/server-setup.c)"
# setup NAME ARGS...: server-setup (a server of ours and its client in one process).
setup() {
    local name=$1
    shift
    in_process server-setup "setup-$name" 60 "$@"
}
# The server serves on the socket the listen made (it does not bind again:
# EADDRINUSE), TCP, TCP-PI, Modbus/UDP; and on modbus_udp_bind's.
for how in tcp tcppi udp udpbind; do
    setup "listen-$how" listen "$how"
done

section "Modbus/UDP, a hand-written loop: each answer to its request's sender"
# Two peers' requests received, then answered (first, second, exception): each
# peer gets its own answer; the socket from modbus_tcp_listen or modbus_udp_bind.
for how in listen bind; do
    setup "udp-loop-$how" udp-loop "$how"
done

section "idle clients"
serve idle tcp port --idle 500
client debian idle "$PORT" idle 500
halt idle "stopped by a signal"

section "Modbus/TCP Security: clients beside 50 stalled handshakes"
serve tls tls port --idle 3000
start hold env LD_LIBRARY_PATH="$LIBDIR" "$BIN/runner-check" "$PORT" hold 50 5
if wait_ready hold HOLDING 10; then
    ok "50 clients stall their handshakes"
    t0=$(date +%s%N)
    log=$WORK/tls-many.log
    rc=0
    env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 60 "$BIN/tls-test" "$C" 127.0.0.1 "$PORT" many 20 >"$log" 2>&1 || rc=$?
    ms=$((($(date +%s%N) - t0) / 1000000))
    program_checks "tls: 20 clients handshake, write and read back meanwhile (${ms} ms)" "$log" "$rc"
    result "tls: done before the stalled handshakes end (${ms} ms < 4000 ms)" "$([ "$ms" -lt 4000 ] && echo PASS || echo FAIL)"
else
    bad "50 clients stall their handshakes" "$(tail -n 3 "$WORK/hold.log")"
fi
wait_exit hold 20
if grep -q "# 50 of 50 closed by the server" "$WORK/hold.log"; then
    ok "tls: the stalled handshakes are closed at the idle timeout"
else
    bad "tls: the stalled handshakes are closed at the idle timeout" "$(grep '^#' "$WORK/hold.log")"
fi
halt tls "stopped by a signal"

section "RTU on a pty pair: units 1, 2 and 7 (callbacks)"
if socat_pair "$WORK/socat.log" "$WORK/socat.log" "$WORK/ttyA" "$WORK/ttyB"; then
    socat=$LAST_PID
    serve rtu rtu "$WORK/ttyA" --callbacks
    client debian rtu "$WORK/ttyB" rtu
    halt rtu "stopped by a signal"
    stop_pid "$socat"
else
    bad "RTU: a pty pair" "socat"
fi

section "callbacks in a runner (c-tests/runner/runner-later.c): the request info, answers given later"
# The client's connection id and address (two TCP clients one after the other; two
# UDP senders on one socket), accept_unit's request info, and the typed answers.
for mode in tcp udp; do
    rc=0
    log=$WORK/later-$mode.log
    env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 120 "$BIN/runner-later" "$mode" >"$log" 2>&1 || rc=$?
    libinfo_ours "runner-later $mode" "$log"
    program_checks "runner-later $mode" "$log" "$rc"
done

section "the runner as the blocking server (c-tests/runner/runner-diag.c): counters, ASCII delimiter, stop"
# runner-diag runs a blocking server (modbus_receive + modbus_reply) and a runner of
# ours in its own threads, on pty pairs it opens (openpty) and on loopback.
diag() {
    local name=$1
    shift
    in_process runner-diag "diag-$name" 120 "$@"
}
# The diagnostics bus counters (0x0B, 0x0C, 0x12) of a runner: the blocking server's,
# for the same requests, bad checksums and an overrun.
diag counters-rtu counters rtu
diag counters-ascii counters ascii
diag counters-tcp counters tcp
# FC 08/03 (Change ASCII Input Delimiter), then a request ended by CR and the new one.
diag delimiter delimiter
# modbus_server_stop while the runner handles a request libmodbus answers after
# sleeping the response timeout (3 s) and flushing; on UDP, another peer meanwhile.
diag stop-rtu stop rtu
diag stop-udp stop udp

section "pymodbus clients (MBAP, RTU framing over TCP, asyncio)"
if pymodbus_venv "$ROOT/target/interop/venv" "$ROOT/c-tests/interop/requirements.txt" "$WORK" "$INSTALL"; then
    for mode in tcp rtutcp; do
        serve "pm-$mode" "$mode" port
        rc=0
        timeout -k 5 120 "$PY" "$ROOT/c-tests/runner/pm_runner.py" "$mode" "$PORT" 50 >"$WORK/pm-$mode-client.log" 2>&1 || rc=$?
        program_checks "pymodbus $mode" "$WORK/pm-$mode-client.log" "$rc"
        halt "pm-$mode" "stopped by a signal"
    done
else
    bad "pymodbus" "no venv"
fi

section "Modbus/UDP: pymodbus both ways, a path that loses and repeats datagrams"
if [ -x "${PY:-}" ]; then
    serve udp udp port
    rc=0
    env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 120 "$BIN/udp-check" "$PORT" basic >"$WORK/udp-ours.log" 2>&1 || rc=$?
    program_checks "udp: our client, our runner" "$WORK/udp-ours.log" "$rc"
    rc=0
    timeout -k 5 120 "$PY" "$ROOT/c-tests/runner/pm_udp.py" client "$PORT" >"$WORK/udp-pm-client.log" 2>&1 || rc=$?
    program_checks "udp: pymodbus' client, our runner" "$WORK/udp-pm-client.log" "$rc"
    PROXY_PORT=$(free_port)
    start udp-proxy "$PY" "$ROOT/c-tests/runner/pm_udp.py" proxy "$PROXY_PORT" "$PORT" 7 5
    if wait_ready udp-proxy READY 10; then
        rc=0
        env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 300 "$BIN/udp-check" "$PROXY_PORT" lossy 300 \
            >"$WORK/udp-lossy.log" 2>&1 || rc=$?
        program_checks "udp: every 7th datagram lost, every 5th repeated" "$WORK/udp-lossy.log" "$rc"
        grep '^#' "$WORK/udp-lossy.log" | tail -n 1
    else
        bad "udp: the proxy starts" "$(tail -n 3 "$WORK/udp-proxy.log")"
    fi
    stop udp-proxy
    halt udp "stopped by a signal"
    PM_PORT=$(free_port)
    start udp-pm-server "$PY" "$ROOT/c-tests/runner/pm_udp.py" server "$PM_PORT"
    if wait_ready udp-pm-server READY 20; then
        rc=0
        env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 120 "$BIN/udp-check" "$PM_PORT" basic >"$WORK/udp-vs-pm.log" 2>&1 ||
            rc=$?
        program_checks "udp: our client, pymodbus' server" "$WORK/udp-vs-pm.log" "$rc"
    else
        bad "udp: pymodbus' server starts" "$(tail -n 3 "$WORK/udp-pm-server.log")"
    fi
    stop udp-pm-server
fi

section "$MANY clients connected at once"
serve many tcp port --nofile $((MANY * 2 + 100)) --max $((MANY + 100))
client ours many "$PORT" many "$MANY"
grep '^#' "$WORK/many.log"
halt many "stopped by a signal"

section "AddressSanitizer"
if c_build_group RUNNER SAN=address; then
    ASAN_BIN=$(c_build_dir address)
    PORT=$(free_port)
    start asan env LD_LIBRARY_PATH="$LIBDIR" ASAN_OPTIONS=detect_leaks=1 "$ASAN_BIN/runner-server" tcp "$PORT" --callbacks
    if wait_ready asan READY 20; then
        client ours asan-basic "$PORT" basic 1
        client ours asan-slow "$PORT" slow
        client ours asan-pipelined "$PORT" pipelined
        halt asan "stopped by a signal"
        if grep -q Sanitizer "$WORK/asan.log"; then
            bad "AddressSanitizer: no report" "$(grep -A5 Sanitizer "$WORK/asan.log" | head -n 10)"
        else
            ok "AddressSanitizer: no report"
        fi
    else
        bad "asan: the server starts" "$(tail -n 5 "$WORK/asan.log")"
    fi
fi

summary
