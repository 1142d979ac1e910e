#!/usr/bin/env bash
# gateway.sh: rsmodbus-gateway (the crate gateway/: target/release/rsmodbus-gateway, or
# the program GATEWAY_BIN names) beside mbusd, built from
# ../shared/anchors/mbusd when its source is there (cmake), each in front of an RTU
# line on a pty pair whose device is benches/mb-server.c on Debian's libmodbus
# (slave 1). The masters are Debian's libmodbus (c-tests/gateway/gw-check.c) and
# mbpoll:
#   - every function code mbusd handles, on a unit that answers and on one that is
#     not there: the same answers and exceptions from both gateways (0x0B after the
#     retries), line by line;
#   - mbpoll's output through both;
#   - fairness: 8 masters in tight loops, each served within 1.2x of the others
#     (ours; mbusd's spread reported);
#   - a master that leaves while its request is on the line; 100 masters held;
#   - the Modbus/TCP Security front (tls_* keys): roles mapped to units and access;
#   - the configuration file (mbusd's keys) and -h;
#   - a user-defined function code (0x41) answered whole (c-tests/event/fc41_device.py
#     on the line, c-tests/event/event-test.c fc41 as the master);
#   - the security review's findings (issue 40), one check or a few per finding, each
#     named "finding N: ..." (masters: c-tests/gateway/gw-findings.py, plain sockets).
#
# GATEWAY_BIN: the gateway under test (default target/release/rsmodbus-gateway, made by
# cargo build --release; it runs with LD_LIBRARY_PATH=target/release, which a program
# linking the library statically ignores). GATEWAY_BIN=/tmp/c-gateway runs the same
# checks against another build, e.g. the C gateway of before issue 40:
#   git show 41bf819:gateway/rsmodbus-gateway.c >/tmp/c-gateway.c
#   gcc -Iinclude -Wall /tmp/c-gateway.c -o /tmp/c-gateway -Ltarget/release -lmodbus
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
# usage: c-tests/suites/gateway.sh [--no-cargo]
# Output goes to target/gateway-tests. The last line is "N passed, M failed"; the exit
# status is non-zero if M > 0. Every process started here is stopped by its PID.
set -u
set -o pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
WORK=${GATEWAYTEST_OUT:-$ROOT/target/gateway-tests}
LIBDIR=$ROOT/target/release
GATEWAY_BIN=${GATEWAY_BIN:-$ROOT/target/release/rsmodbus-gateway}
# The gateway under test, as a command.
GW=(env LD_LIBRARY_PATH="$LIBDIR" "$GATEWAY_BIN")

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"

parse_flags -- "$@"

section "build"
our_lib_result "$LIBDIR" 2
rm -rf "$WORK"
mkdir -p "$WORK"
BIN=$(c_build_dir)
c_build_group GATEWAY
if [ -x "$GATEWAY_BIN" ] && "${GW[@]}" -h >"$WORK/gateway-h.log" 2>&1; then
    ok "the gateway under test: $GATEWAY_BIN (-h exits 0)"
else
    bad "the gateway under test: $GATEWAY_BIN runs (-h exits 0)" "$(head -n 3 "$WORK/gateway-h.log" 2>&1)"
fi
# Since issue 40 the policy keys are needed where a plain front reaches a role's units
# (allow_plain) and beside udp_port (udp_allow); a gateway of before does not know them.
NEW_KEYS=0
! grep -q allow_plain "$WORK/gateway-h.log" || NEW_KEYS=1
MBUSD=
MBUSD_SRC=$(realpath -m "$ROOT/../shared/anchors/mbusd")
if [ -f "$MBUSD_SRC/CMakeLists.txt" ]; then
    command -v cmake >/dev/null || apt-get install -y -qq cmake >/dev/null 2>&1
    mkdir -p "$ROOT/target/mbusd-build"
    if (cd "$ROOT/target/mbusd-build" && cmake "$MBUSD_SRC" >/dev/null && make -s >/dev/null) 2>"$WORK/mbusd-build.log"; then
        MBUSD=$ROOT/target/mbusd-build/mbusd
        ok "build mbusd from $MBUSD_SRC (the reference, beside ours; not part of the project)"
    else
        bad "build mbusd" "$(tail -n 5 "$WORK/mbusd-build.log")"
    fi
else
    echo "# no mbusd source at $MBUSD_SRC: ours alone"
fi

# line NAME: a pty pair with mb-server (Debian's libmodbus, slave 1) on one end;
# the gateway's end is $WORK/NAME-G.
line() {
    if ! socat_pair "$WORK/socat-$1.log" "$WORK/socat-$1.log" "$WORK/$1-D" "$WORK/$1-G"; then
        bad "$1: a pty pair" "socat"
        return 1
    fi
    SOCAT=$LAST_PID
    start "$1-device" env -u LD_LIBRARY_PATH "$BIN/mb-server" rtu "$WORK/$1-D"
    wait_ready "$1-device" READY 10 || { bad "$1: the device starts" "$(tail -n 3 "$WORK/$1-device.log")"; return 1; }
}

# gateway NAME ours|mbusd ARGS...: the gateway in front of line NAME, on a free port.
gateway() {
    local name=$1 which=$2 prog
    shift 2
    PORT=$(free_port)
    if [ "$which" = ours ]; then
        prog=("${GW[@]}")
    else
        prog=("$MBUSD")
    fi
    start "$name-gw" "${prog[@]}" -d -L - -v 2 -p "$WORK/$name-G" -s 115200 -P "$PORT" "$@"
    sleep 0.5
    kill -0 "${_pids[$name-gw]}" 2>/dev/null || { bad "$name: the gateway starts" "$(tail -n 3 "$WORK/$name-gw.log")"; return 1; }
}

# done_with NAME: stops the gateway, the device and the pty pair of NAME.
done_with() {
    stop "$1-gw"
    stop "$1-device"
    stop_pid "$SOCAT"
}

checks() { # checks NAME LOG ARGS...: gw-check's checks
    local name=$1 log=$2 rc=0
    shift 2
    timeout -k 5 120 "$BIN/gw-check" "$@" >"$log" 2>&1 || rc=$?
    program_checks "$name" "$log" "$rc"
}

GW_ARGS=(-R 1 -W 300 -N 1 -C 128)
for which in ours ${MBUSD:+mbusd}; do
    section "$which: through the gateway"
    line "$which" || continue
    gateway "$which" "$which" "${GW_ARGS[@]}" || { done_with "$which"; continue; }
    if [ "$which" = ours ]; then
        checks "ours: 8 masters in tight loops" "$WORK/fair-ours.log" "$PORT" fair 8 3
        grep '^#' "$WORK/fair-ours.log"
        checks "ours: 100 masters held" "$WORK/held-ours.log" "$PORT" held 100
    else
        timeout -k 5 60 "$BIN/gw-check" "$PORT" fair 8 3 >"$WORK/fair-mbusd.log" 2>&1
        echo "# mbusd $(grep '^# fair' "$WORK/fair-mbusd.log" | cut -c3-)"
        timeout -k 5 60 "$BIN/gw-check" "$PORT" held 30 >"$WORK/held-mbusd.log" 2>&1
    fi
    checks "$which: a master leaves with its request on the line" "$WORK/leave-$which.log" "$PORT" leave
    checks "$which: a broadcast" "$WORK/broadcast-$which.log" "$PORT" broadcast 0
    timeout -k 5 30 mbpoll -m tcp -a 1 -r 1 -c 8 -p "$PORT" -1 127.0.0.1 >"$WORK/mbpoll-$which.txt" 2>&1
    # Last: the requests for unit 9 (no device) leave Debian's RTU server waiting for
    # the answer of "another slave" (it then takes the next request for it).
    timeout -k 5 120 "$BIN/gw-check" "$PORT" calls >"$WORK/calls-$which.txt" 2>&1
    done_with "$which"
done

section "the same answers as mbusd"
if grep -q '^unit 1 FC03 read 10 registers at 4: rc=10 12 15' "$WORK/calls-ours.txt"; then
    ok "ours: unit 1 answers through the gateway (FC 03: 12 15 18 ...)"
else
    bad "ours: unit 1 answers through the gateway" "$(head -n 5 "$WORK/calls-ours.txt")"
fi
if grep -q '^unit 9 FC03 read 10 registers at 4: rc=-1 errno=EMBXGTAR' "$WORK/calls-ours.txt"; then
    ok "ours: a unit with no device: exception 0x0B (gateway target device failed to respond)"
else
    bad "ours: a unit with no device: exception 0x0B" "$(grep '^unit 9' "$WORK/calls-ours.txt" | head -n 3)"
fi
if grep -q 'Polling slave 1' "$WORK/mbpoll-ours.txt" && grep -q '^\[8\]:' "$WORK/mbpoll-ours.txt"; then
    ok "ours: mbpoll reads 8 registers through it"
else
    bad "ours: mbpoll reads 8 registers through it" "$(tail -n 3 "$WORK/mbpoll-ours.txt")"
fi
if [ -n "$MBUSD" ]; then
    if diff <(grep -v LIBINFO "$WORK/calls-ours.txt") <(grep -v LIBINFO "$WORK/calls-mbusd.txt") >"$WORK/calls.diff"; then
        ok "every call: the same rc, errno and values as through mbusd ($(grep -vc LIBINFO "$WORK/calls-ours.txt") calls)"
    else
        bad "every call: the same as through mbusd" "$(head -n 10 "$WORK/calls.diff")"
    fi
    if diff <(grep -v '^Communication' "$WORK/mbpoll-ours.txt") <(grep -v '^Communication' "$WORK/mbpoll-mbusd.txt") \
        >"$WORK/mbpoll.diff"; then
        ok "mbpoll: the same output through both"
    else
        bad "mbpoll: the same output through both" "$(head -n 10 "$WORK/mbpoll.diff")"
    fi
fi

section "pymodbus: as the line's device (both gateways, the same answers), and as a master"
PM_OK=0
if pymodbus_venv "$ROOT/target/interop/venv" "$ROOT/c-tests/interop/requirements.txt" "$WORK" 1; then
    PM_OK=1
    for which in ours ${MBUSD:+mbusd}; do
        if ! socat_pair "$WORK/socat-pm-$which.log" "$WORK/socat-pm-$which.log" "$WORK/pm-$which-D" "$WORK/pm-$which-G"; then
            bad "pm-$which: a pty pair" "socat"
            continue
        fi
        SOCAT=$LAST_PID
        start "pm-$which-device" "$PY" "$ROOT/c-tests/interop/pm_server.py" rtu "$WORK/pm-$which-D"
        if wait_ready "pm-$which-device" READY 20 && gateway "pm-$which" "$which" "${GW_ARGS[@]}"; then
            GW_UNIT=17 timeout -k 5 120 "$BIN/gw-check" "$PORT" calls >"$WORK/pmcalls-$which.txt" 2>&1
            if [ "$which" = ours ]; then
                # A pymodbus master through our gateway (mb-server's data: pymodbus' here).
                timeout -k 5 60 "$PY" - "$PORT" >"$WORK/pm-master.log" 2>&1 <<'PY'
import sys
from pymodbus.client import ModbusTcpClient
c = ModbusTcpClient("127.0.0.1", port=int(sys.argv[1]), timeout=5)
c.connect()
r = c.read_holding_registers(0, count=3, device_id=17)
ok = not r.isError() and r.registers == [(0x1000 + i * 0x0101) & 0xFFFF for i in range(3)]
print(("ok   - " if ok else "FAIL - ") + "a pymodbus master reads 3 registers of the pymodbus device: %s" % r)
print("%d passed, %d failed" % (ok, not ok))
sys.exit(0 if ok else 1)
PY
                program_checks "ours: a pymodbus master" "$WORK/pm-master.log" "$?"
            fi
        fi
        stop "pm-$which-gw"
        stop "pm-$which-device"
        stop_pid "$SOCAT"
    done
    if grep -q '^unit 17 FC03 read 10 registers at 4: rc=10' "$WORK/pmcalls-ours.txt"; then
        ok "ours: the pymodbus device answers through the gateway"
    else
        bad "ours: the pymodbus device answers through the gateway" "$(head -n 4 "$WORK/pmcalls-ours.txt")"
    fi
    if [ -n "$MBUSD" ]; then
        if diff <(grep -v LIBINFO "$WORK/pmcalls-ours.txt") <(grep -v LIBINFO "$WORK/pmcalls-mbusd.txt") >"$WORK/pmcalls.diff"; then
            ok "pymodbus device: every call the same through both gateways"
        else
            bad "pymodbus device: every call the same through both gateways" "$(head -n 10 "$WORK/pmcalls.diff")"
        fi
    fi
fi

section "faults on the line: a bad CRC, garbage, a device unplugged and back"
# fake_line NAME: a pty pair with c-tests/gateway/fake_device.py on one end.
fake_line() {
    if ! socat_pair "$WORK/socat-$1.log" "$WORK/socat-$1.log" "$WORK/$1-D" "$WORK/$1-G"; then
        bad "$1: a pty pair" "socat"
        return 1
    fi
    SOCAT=$LAST_PID
    start "$1-device" python3 "$ROOT/c-tests/gateway/fake_device.py" "$WORK/$1-D"
    wait_ready "$1-device" READY 10 || { bad "$1: the fake device starts" "$(tail -n 3 "$WORK/$1-device.log")"; return 1; }
}
for which in ours ${MBUSD:+mbusd}; do
    fake_line "fault-$which" || continue
    gateway "fault-$which" "$which" -R 1 -W 200 -N 2 || { done_with "fault-$which"; continue; }
    checks "$which: unit 6 answers with a bad CRC: exception 0x04 after the retries" "$WORK/crc-$which.log" "$PORT" unit 6 4
    checks "$which: unit 8 answers garbage: exception 0x04, as for a bad CRC" "$WORK/garbage-$which.log" "$PORT" unit 8 4
    checks "$which: unit 1 is answered after them" "$WORK/after-$which.log" "$PORT" held 2
    tries=$(grep -c '^unit 6 fc 3' "$WORK/fault-$which-device.log")
    echo "# $which: unit 6 was asked $tries times (-N 2: 3 expected)"
    # Unplugged: the pty pair and its device go; a request fails (0x0B). Back: a new
    # pair under the same names; the gateway opens the line again.
    stop "fault-$which-device"
    stop_pid "$SOCAT"
    timeout -k 5 60 "$BIN/gw-check" "$PORT" unit 1 0B >"$WORK/unplugged-$which.log" 2>&1
    if fake_line "fault-$which"; then
        sleep 0.5
        rc=0
        timeout -k 5 60 "$BIN/gw-check" "$PORT" held 2 >"$WORK/replugged-$which.log" 2>&1 || rc=$?
        if [ "$which" = ours ]; then
            program_checks "ours: the line unplugged and back: answered again" "$WORK/replugged-$which.log" "$rc"
        else
            echo "# mbusd, the line unplugged and back: $(tail -n 1 "$WORK/replugged-$which.log")"
        fi
    fi
    done_with "fault-$which"
done

section "a user-defined function code (0x41) through the gateway: the whole answer"
# c-tests/event/fc41_device.py on the RTU line answers FC 0x41 with a 9-byte PDU
# (41 01 02 03 04 05 06 07 08) libmodbus cannot size; a master over TCP
# (c-tests/event/event-test.c fc41, our library: modbus_send_raw_request and
# modbus_send_raw_request_async) must get it whole: 16 bytes, MBAP length 10.
if socat_pair "$WORK/socat-fc41.log" "$WORK/socat-fc41.log" "$WORK/fc41-D" "$WORK/fc41-G"; then
    SOCAT=$LAST_PID
    start fc41-device python3 "$ROOT/c-tests/event/fc41_device.py" rtu "$WORK/fc41-D"
    if wait_ready fc41-device READY 10 && gateway fc41 ours "${GW_ARGS[@]}"; then
        rc=0
        env LD_LIBRARY_PATH="$LIBDIR" EXPECT_LIB=ours timeout -k 5 60 "$BIN/event-test" fc41 tcp "$PORT" \
            >"$WORK/fc41-master.log" 2>&1 || rc=$?
        libinfo_ours "fc41 master" "$WORK/fc41-master.log"
        program_checks "ours: FC 0x41 answered whole through the gateway" "$WORK/fc41-master.log" "$rc"
        echo "# the device saw: $(grep -c 'fc 0x41' "$WORK/fc41-device.log") requests for FC 0x41"
    else
        bad "fc41: the device and the gateway start" "$(tail -n 3 "$WORK/fc41-device.log")"
    fi
    done_with fc41
else
    bad "fc41: a pty pair" "socat"
fi

section "Modbus/TCP Security front: roles mapped to units and access"
C=$WORK/certs
if check "make the test certificates with openssl" "$ROOT/c-tests/tls/make-certs.sh" "$C" && line tls; then
    PORT=$(free_port)
    TLS_PORT=$(free_port)
    cat >"$WORK/tls.conf" <<EOF
device = $WORK/tls-G
speed = 115200
port = $PORT
pause = 1
wait = 300
retries = 1
logfile = -
tls_port = $TLS_PORT
tls_cert = $C/server.pem
tls_key = $C/server.key
tls_ca = $C/ca.pem
tls_role.Operator = rw 1-3
tls_role.Reader = r 1-247
EOF
    [ "$NEW_KEYS" = 0 ] || echo "allow_plain = yes" >>"$WORK/tls.conf"
    start tls-gw "${GW[@]}" -d -v 3 -c "$WORK/tls.conf"
    sleep 0.5
    rc=0
    env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 120 "$BIN/gw-ours" tls "$C" "$TLS_PORT" >"$WORK/tls-masters.log" 2>&1 ||
        rc=$?
    program_checks "TLS front: Operator, Reader, no role" "$WORK/tls-masters.log" "$rc"
    # The same policy from pymodbus' TLS client (Python's ssl), its certificates.
    if [ "$PM_OK" = 1 ]; then
        timeout -k 5 60 "$PY" - "$TLS_PORT" "$C" >"$WORK/tls-pymodbus.log" 2>&1 <<'PY'
import asyncio, os, ssl, sys
from pymodbus.client import AsyncModbusTlsClient
from pymodbus.pdu import ExceptionResponse
port, certs = int(sys.argv[1]), sys.argv[2]
passed = failed = 0
def check(cond, name, r):
    global passed, failed
    passed += bool(cond)
    failed += not cond
    print(("ok   - " if cond else "FAIL - ") + name + ("" if cond else ": %s" % r))
def refused(r):
    return isinstance(r, ExceptionResponse) and r.exception_code == 1
async def master(who):
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.load_verify_locations(os.path.join(certs, "ca.pem"))
    ctx.load_cert_chain(os.path.join(certs, who + ".pem"), os.path.join(certs, who + ".key"))
    ctx.check_hostname = False  # pymodbus passes no server name; the chain is verified
    c = AsyncModbusTlsClient("127.0.0.1", port=port, sslctx=ctx, timeout=3, retries=0)
    check(await c.connect(), "pymodbus %s: connects to the TLS front" % who, "")
    r = await c.read_holding_registers(10, count=2, device_id=1)
    check(not r.isError() and r.registers == [30, 33], "pymodbus %s: reads unit 1" % who, r)
    r = await c.write_register(70, 7000, device_id=1)
    if who == "operator":
        check(not r.isError(), "pymodbus operator: writes unit 1 (rw 1-3)", r)
        r = await c.write_register(70, 7001, device_id=5)
        check(refused(r), "pymodbus operator: a write to unit 5 is refused with exception 01", r)
    else:
        check(refused(r), "pymodbus reader: a write is refused with exception 01 (r 1-247)", r)
    c.close()
async def main():
    await master("operator")
    await master("reader")
asyncio.run(main())
print("%d passed, %d failed" % (passed, failed))
sys.exit(1 if failed else 0)
PY
        program_checks "TLS front: pymodbus masters, Operator and Reader" "$WORK/tls-pymodbus.log" "$?"
    fi
    checks "TLS front: the plain TCP front serves beside it" "$WORK/tls-plain.log" "$PORT" held 3
    done_with tls
fi

section "more fronts (RTU over TCP, Modbus/UDP) and other lines (Modbus/TCP, RTU over TCP)"
# ours_master NAME ARGS...: gw-ours' checks
ours_master() {
    local name=$1 rc=0
    shift
    env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 120 "$BIN/gw-ours" "$@" >"$WORK/$name.log" 2>&1 || rc=$?
    program_checks "$name" "$WORK/$name.log" "$rc"
}
if line fronts; then
    PORT=$(free_port)
    RTUTCP_PORT=$(free_port)
    UDP_PORT=$(free_port)
    printf 'rtutcp_port = %s\nudp_port = %s\n' "$RTUTCP_PORT" "$UDP_PORT" >"$WORK/fronts.conf"
    [ "$NEW_KEYS" = 0 ] || echo "udp_allow = 127.0.0.1/32" >>"$WORK/fronts.conf"
    start fronts-gw "${GW[@]}" -c "$WORK/fronts.conf" -d -L - \
        -p "$WORK/fronts-G" -s 115200 -P "$PORT" -R 1 -W 300 -N 1
    sleep 0.5
    ours_master "front: RTU over TCP" rtutcp "$RTUTCP_PORT"
    ours_master "front: Modbus UDP" udp "$UDP_PORT"
    checks "front: Modbus/TCP beside them" "$WORK/fronts-held.log" "$PORT" held 3
    done_with fronts
fi
# A Modbus/TCP device (mb-server on Debian's libmodbus), then an RTU-over-TCP one
# (our server that runs itself, the same data), as the line.
for back in tcp rtutcp; do
    dev_port=
    if [ "$back" = tcp ]; then
        start "back-$back-device" env -u LD_LIBRARY_PATH "$BIN/mb-server" tcp 0
    else
        dev_port=$(free_port)
        start "back-$back-device" env LD_LIBRARY_PATH="$LIBDIR" "$BIN/runner-server" rtutcp "$dev_port" --bench
    fi
    if wait_ready "back-$back-device" READY 10; then
        [ -n "$dev_port" ] || dev_port=$(sed -n 's/^READY \([0-9]*\)$/\1/p' "$WORK/back-$back-device.log")
        PORT=$(free_port)
        printf 'backend = %s 127.0.0.1 %s\n' "$back" "$dev_port" >"$WORK/back-$back.conf"
        start "back-$back-gw" "${GW[@]}" -c "$WORK/back-$back.conf" -d -L - \
            -P "$PORT" -R 1 -W 300 -N 1
        sleep 0.5
        checks "line: a $back device" "$WORK/back-$back-held.log" "$PORT" held 3
        stop "back-$back-gw"
    else
        bad "line: a $back device starts" "$(tail -n 3 "$WORK/back-$back-device.log")"
    fi
    stop "back-$back-device"
done

section "RS-485 direction through a sysfs file (-y, -Y)"
# The "sysfs file" is a FIFO whose reader records every write: -y writes 1 before a
# request goes out and 0 after it, -Y the reverse (mbusd's -y/-Y).
fifo_reader() { # fifo_reader NAME: $WORK/NAME.fifo, recorded in $WORK/NAME.rec
    rm -f "$WORK/$1.fifo" "$WORK/$1.rec"
    mkfifo "$WORK/$1.fifo"
    start "$1-rec" python3 -c 'import os, sys
fd = os.open(sys.argv[1], os.O_RDWR)
print("READY", flush=True)
with open(sys.argv[2], "ab", buffering=0) as out:
    while True:
        out.write(os.read(fd, 64))' "$WORK/$1.fifo" "$WORK/$1.rec"
    wait_ready "$1-rec" READY 10
}
for which in ours ${MBUSD:+mbusd}; do
    for opt in -y -Y; do
        n=trx$opt-$which
        fifo_reader "$n" || { bad "$n: the FIFO's reader starts"; continue; }
        if line "$n" && gateway "$n" "$which" -R 1 -W 300 -N 0 "$opt" "$WORK/$n.fifo"; then
            checks "$which $opt: requests through the line" "$WORK/$n.log" "$PORT" reads 1
        fi
        done_with "$n"
        sleep 0.2
        stop "$n-rec"
        rec=$(cat "$WORK/$n.rec" 2>/dev/null)
        if [ "$which" = mbusd ]; then
            echo "# mbusd $opt wrote: $rec"
        elif { [ "$opt" = -y ] && [[ $rec =~ ^0?(10){3}$ ]]; } || { [ "$opt" = -Y ] && [[ $rec =~ ^1?(01){3}$ ]]; }; then
            ok "ours $opt: the direction file is written around each of the 3 requests: $rec"
        else
            bad "ours $opt: the direction file is written around each of the 3 requests" "wrote: $rec"
        fi
    done
done

section "-R 0: the 3.5-character silence only (mbusd's least pause is 1 ms)"
# At 9600 baud (the pty does not pace bytes; the gateway times its silence by the
# speed it is given) 3.5 characters are 3.65 ms: one master gets at most 274 answers a
# second whatever the machine's load, and far more than the 10 a second of the
# default pause (100 ms) or than nothing.
if line r0 && gateway r0 ours -s 9600 -R 0 -W 300 -N 0; then
    checks "ours -R 0: requests through the line" "$WORK/r0.log" "$PORT" reads 1
    checks "ours -R 0: 20 masters in turn" "$WORK/r0-fair.log" "$PORT" fair 20 2
    timeout -k 5 60 "$BIN/gw-check" "$PORT" fair 1 2 >"$WORK/r0-one.log" 2>&1
    r0_rate=$(sed -n 's/.*(\([0-9.]*\)\/s).*/\1/p' "$WORK/r0-one.log" | head -n 1)
    if awk -v r="${r0_rate:-0}" 'BEGIN { exit !(r >= 50 && r <= 280) }'; then
        ok "ours -R 0 at 9600 baud: $r0_rate answers/s to one master (the silence kept: <= 274; no 100 ms pause: >= 50)"
    else
        bad "ours -R 0 at 9600 baud: between 50 and 280 answers/s to one master" "got: ${r0_rate:-none}"
    fi
fi
done_with r0
if [ -n "$MBUSD" ]; then
    timeout 5 "$MBUSD" -d -L - -R 0 -p "$WORK/none" -P "$(free_port)" >"$WORK/mbusd-r0.log" 2>&1
    if grep -q "invalid inter-request pause" "$WORK/mbusd-r0.log"; then
        ok "mbusd refuses -R 0 (as our manual page says): $(head -n 1 "$WORK/mbusd-r0.log")"
    else
        bad "mbusd refuses -R 0 (as our manual page says)" "$(cat "$WORK/mbusd-r0.log")"
    fi
fi

section "broadcasts answered (-b), a master's full queue (0x06), 1,000 masters"
if line more; then
    gateway more ours -R 1 -W 100 -N 0 -b -C 1100 || true
    checks "ours -b: a broadcast answered" "$WORK/broadcast-b.log" "$PORT" broadcast 1
    checks "ours: 1,000 masters connected at once" "$WORK/held-1000.log" "$PORT" held 1000
    # Last (requests for a unit not there confuse Debian's RTU server: see above).
    checks "ours: a master's queue full" "$WORK/busy.log" "$PORT" busy
    done_with more
fi

section "routing: two serial lines by unit ranges, a unit remapped, no route"
RA_SOCAT=
if line ra && RA_SOCAT=$SOCAT && line rb; then
    PORT=$(free_port)
    cat >"$WORK/routes.conf" <<EOF
device = $WORK/ra-G
speed = 115200
port = $PORT
pause = 1
wait = 300
retries = 1
logfile = -
line.b = serial $WORK/rb-G 115200 8N1
route = 1-1 default
route = 2-2 b -1
EOF
    start routes-gw "${GW[@]}" -d -v 5 -c "$WORK/routes.conf"
    sleep 0.5
    checks "route: unit 1 to the default line" "$WORK/route-1.log" "$PORT" reads 1
    checks "route: unit 2 to line b as its unit 1" "$WORK/route-2.log" "$PORT" reads 2
    checks "route: unit 5 has none: exception 0x0A (gateway path unavailable)" "$WORK/route-5.log" "$PORT" unit 5 0A
    # Each line's device saw its own writes only.
    if grep -q "line b" "$WORK/routes-gw.log"; then
        ok "route: the gateway names the line of each request"
    else
        bad "route: the gateway names the line of each request" "$(tail -n 3 "$WORK/routes-gw.log")"
    fi
    stop routes-gw
    stop ra-device
    stop rb-device
    stop_pid "$SOCAT"
fi
stop_pid "$RA_SOCAT"

section "SIGHUP: the configuration again, connections kept; the counters' status file"
if line hup; then
    PORT=$(free_port)
    write_hup_conf() { # write_hup_conf ROUTES...
        {
            printf 'device = %s\nspeed = 115200\nport = %s\npause = 1\nwait = 300\nretries = 1\nlogfile = -\n' \
                "$WORK/hup-G" "$PORT"
            printf 'status_file = %s\n' "$WORK/hup.status"
            printf 'route = %s\n' "$@"
        } >"$WORK/hup.conf"
    }
    write_hup_conf "1-1 default"
    start hup-gw "${GW[@]}" -d -v 3 -c "$WORK/hup.conf"
    sleep 0.5
    start hup-master "$BIN/gw-check" "$PORT" across 3 2
    if wait_ready hup-master WAITING 10; then
        write_hup_conf "1-1 default" "3-3 default -2"
        kill -HUP "${_pids[hup-gw]}"
    fi
    wait_exit hup-master 20
    program_checks "SIGHUP: a route added, the master's connection kept" "$WORK/hup-master.log" "$rc"
    if grep -q "configuration reloaded from $WORK/hup.conf: 2 route(s), 0 role(s)" "$WORK/hup-gw.log"; then
        ok "SIGHUP: the gateway says what it reloaded (2 routes)"
    else
        bad "SIGHUP: the gateway says what it reloaded" "$(tail -n 3 "$WORK/hup-gw.log")"
    fi
    echo "device = /dev/elsewhere" >>"$WORK/hup.conf"
    kill -HUP "${_pids[hup-gw]}"
    sleep 0.5
    if grep -q "reload: device changed: it takes a restart" "$WORK/hup-gw.log"; then
        ok "SIGHUP: a change of the device is named, and takes a restart"
    else
        bad "SIGHUP: a change of the device is named" "$(tail -n 3 "$WORK/hup-gw.log")"
    fi
    sleep 1.2
    if grep -q '^rsmodbus_gateway_answers_total{line="default"} [1-9]' "$WORK/hup.status" &&
        grep -q '^rsmodbus_gateway_exceptions_total{line="default"} ' "$WORK/hup.status"; then
        ok "status file: the line's counters ($(grep -c . "$WORK/hup.status") lines, Prometheus text format)"
    else
        bad "status file: the line's counters" "$(cat "$WORK/hup.status" 2>&1 | head -n 5)"
    fi
    stop hup-gw
    stop hup-device
    stop_pid "$SOCAT"
fi

section "configuration file and help"
cat >"$WORK/gw.conf" <<EOF
# mbusd's keys
loglevel = 2
logfile = -
device = $WORK/conf-G
speed = 115200
mode = 8N1
address = 127.0.0.1
port = PORT_HERE
maxconn = 8
timeout = 10
retries = 1
pause = 1
wait = 300
replyonbroadcast = no
EOF
if line conf; then
    PORT=$(free_port)
    sed -i "s/PORT_HERE/$PORT/" "$WORK/gw.conf"
    start conf-gw "${GW[@]}" -d -c "$WORK/gw.conf"
    sleep 0.5
    checks "configuration file: the gateway reads it (port, device, speed)" "$WORK/conf-held.log" "$PORT" held 3
    done_with conf
fi
if line example; then
    PORT=$(free_port)
    # The example configuration as shipped, with the test's line, port and log.
    start example-gw "${GW[@]}" -d -c "$ROOT/gateway/example.conf" \
        -p "$WORK/example-G" -s 115200 -P "$PORT" -L - -R 1
    sleep 0.5
    checks "gateway/example.conf: the gateway runs with it" "$WORK/example-held.log" "$PORT" held 3
    done_with example
fi
if grep -q '^ExecStart=/usr/bin/rsmodbus-gateway -d -L - -c /etc/rsmodbus-gateway/%i.conf$' \
    "$ROOT/gateway/rsmodbus-gateway@.service"; then
    ok "the systemd unit template runs one gateway per /etc/rsmodbus-gateway/<instance>.conf"
else
    bad "the systemd unit template" "$(grep ExecStart "$ROOT/gateway/rsmodbus-gateway@.service")"
fi
out=$("${GW[@]}" -h 2>&1)
missing=
for o in -h -d -L -v -c -p -s -m -S -t -r -y -Y -A -P -C -N -R -W -T -b; do
    grep -q -- "^  $o " <<<"$out" || missing+=" $o"
done
result "-h lists mbusd's options${missing:+ (missing:$missing)}" "$([ -z "$missing" ] && echo PASS || echo FAIL)"
# ... and every key of the configuration file, mbusd's and the extended ones, each of
# which the man page documents too: as a word of -h's part on the file and of the
# page's section CONFIGURATION FILE.
missing=
keys_help=$(sed -n '/^Configuration file/,/^SIGHUP/p' <<<"$out")
keys_page=$(sed -n '/^## CONFIGURATION FILE/,/^## SIGNALS/p' "$ROOT/man/src/rsmodbus-gateway.md" | sed 's/`//g')
for k in loglevel logfile device speed mode enable_rs485 trx_control trx_sysfile address port maxconn \
    timeout retries pause wait replyonbroadcast tls_cert tls_key tls_ca tls_address tls_port tls_role. \
    rtutcp_port udp_port backend line. route status_file; do
    re="(^|[^a-z_.])${k//./\\.}([^a-z_]|\$)"
    grep -qE -- "$re" <<<"$keys_help" && grep -qE -- "$re" <<<"$keys_page" || missing+=" $k"
done
result "-h and rsmodbus-gateway(8) list every configuration key${missing:+ (missing:$missing)}" \
    "$([ -z "$missing" ] && echo PASS || echo FAIL)"
echo "bogus = 1" >"$WORK/bad.conf"
if ! "${GW[@]}" -d -c "$WORK/bad.conf" >"$WORK/bad.log" 2>&1 &&
    grep -q "unknown key 'bogus'" "$WORK/bad.log"; then
    ok "an unknown key in the configuration file is refused, named"
else
    bad "an unknown key in the configuration file is refused" "$(cat "$WORK/bad.log")"
fi

section "the security review's findings (issue 40)"
# One check or a few per finding 1-16 of issue 40, each reproducing it as the issue
# describes and asserting the fixed behaviour of /work/issue40-design.md's decisions:
# configuration errors "rsmodbus-gateway: FILE:LINE: KEY: ..." with exit status 1, the
# limits (64 lines, 256 routes, 64 roles), the new keys (port = 0, user, plain_units,
# allow_plain, udp_allow). The lines: FX, a pty with mb-server (Debian's libmodbus,
# slave 1); FY, a pty with fake_device.py (unit 1 answers FC 03, and FC 0x64; other
# units never answer; every request it sees is logged). A gateway whose line is a TCP
# device nobody listens on needs no pty (base_conf).
F=$WORK/findings
mkdir -p "$F"
FINDINGS=$ROOT/c-tests/gateway/gw-findings.py
DEAD_PORT=$(free_port)
CERTS=$WORK/certs
[ -f "$CERTS/ca.pem" ] || "$ROOT/c-tests/tls/make-certs.sh" "$CERTS" >"$F/certs.log" 2>&1

# gw_up NAME CHECK ARGS...: the gateway under test started as NAME (output in
# $WORK/NAME.log); true when it still runs 1.5 s later, else the check CHECK fails
# with its exit status and last lines.
gw_up() {
    local name=$1 what=$2
    shift 2
    start "$name" "${GW[@]}" "$@"
    sleep 1.5
    kill -0 "${_pids[$name]}" 2>/dev/null && return 0
    wait_exit "$name" 1
    bad "$what" "the gateway did not start: exit status $rc" "$(tail -n 3 "$WORK/$name.log")"
    return 1
}
# gw_refuses CHECK CONF REGEX [ARGS...]: the check CHECK: the gateway (-d -L -c CONF
# ARGS) refuses to start: exit status 1 within 5 s, its output matching REGEX (grep -E).
gw_refuses() {
    local what=$1 conf=$2 re=$3 log rc=0
    shift 3
    log=$F/refused-$(basename "$conf" .conf).log
    timeout -k 2 5 "${GW[@]}" -d -L - -c "$conf" "$@" </dev/null >"$log" 2>&1 || rc=$?
    if [ "$rc" = 1 ] && grep -qE -- "$re" "$log"; then
        ok "$what"
    elif [ "$rc" = 124 ]; then
        bad "$what" "accepted: still running after 5 s (stopped)" "$(head -n 3 "$log")"
    else
        bad "$what" "exit status $rc (1 expected), output matching '$re' expected:" "$(head -n 5 "$log")"
    fi
}
# base_conf FILE [LINE...]: a gateway on a free port ($BPORT) whose line is a TCP device
# nobody answers, then LINEs; NEXT is the number of the line after it (for an appended key).
base_conf() {
    local f=$1
    shift
    BPORT=$(free_port)
    {
        printf 'port = %s\nbackend = tcp 127.0.0.1 %s\npause = 1\nwait = 300\nretries = 0\n' "$BPORT" "$DEAD_PORT"
        [ $# -eq 0 ] || printf '%s\n' "$@"
    } >"$f"
    NEXT=$(($(wc -l <"$f") + 1))
}
# fx_conf FILE [LINE...]: a gateway on a free port ($PORT) in front of line FX, then LINEs.
fx_conf() {
    local f=$1
    shift
    PORT=$(free_port)
    {
        printf 'device = %s\nspeed = 115200\nport = %s\npause = 1\nwait = 300\nretries = 0\nlogfile = -\n' \
            "$WORK/fx-G" "$PORT"
        [ $# -eq 0 ] || printf '%s\n' "$@"
    } >"$f"
    NEXT=$(($(wc -l <"$f") + 1))
}
# hup_checks NAME CONF TEXT CHECK LOG ARGS...: SIGHUP to the gateway NAME; once its log
# says "configuration reloaded from CONF" followed by TEXT (within 10 s), gw-check's
# checks (CHECK LOG ARGS: as checks); else CHECK fails.
hup_checks() {
    local name=$1 conf=$2 text=$3
    shift 3
    kill -HUP "${_pids[$name]}"
    if wait_for "$WORK/$name.log" "configuration reloaded from $conf$text" 10; then
        checks "$@"
    else
        bad "$1" "no 'configuration reloaded from $conf$text' in the log:" "$(tail -n 3 "$WORK/$name.log")"
    fi
}
# findings CHECK LOG ARGS...: gw-findings.py's checks, counted.
findings() {
    local what=$1 log=$2 rc=0
    shift 2
    timeout -k 5 120 python3 "$FINDINGS" "$@" >"$log" 2>&1 || rc=$?
    program_checks "$what" "$log" "$rc"
}
FX_SOCAT= FY_SOCAT=
line fx && FX_SOCAT=$SOCAT
fake_line fy && FY_SOCAT=$SOCAT
FY_LOG=$WORK/fy-device.log
FYARGS=(-d -L - -v 2 -p "$WORK/fy-G" -s 115200 -R 1 -W 300 -N 0)

# The new keys in -h and the manual page's CONFIGURATION FILE.
missing=
for k in user plain_units allow_plain udp_allow; do
    re="(^|[^a-z_.])$k([^a-z_]|\$)"
    grep -qE -- "$re" <<<"$keys_help" && grep -qE -- "$re" <<<"$keys_page" || missing+=" $k"
done
result "findings 4, 9, 10: -h and rsmodbus-gateway(8) list user, plain_units, allow_plain, udp_allow${missing:+ (missing:$missing)}" \
    "$([ -z "$missing" ] && echo PASS || echo FAIL)"

# --- 1. An 8th line.* entry wrote past lines[] (C: SIGSEGV at start). Limit: 64.
fx_conf "$F/f1.conf" "backend = tcp 127.0.0.1 $DEAD_PORT"
for i in 1 2 3 4 5 6 7 8; do echo "line.n$i = tcp 127.0.0.1 $DEAD_PORT"; done >>"$F/f1.conf"
printf 'line.n9 = serial %s 115200 8N1\nroute = 1-1 n9\n' "$WORK/fx-G" >>"$F/f1.conf"
if gw_up f1-gw "finding 1: 9 line.* entries accepted" -d -c "$F/f1.conf"; then
    checks "finding 1: 9 line.* entries accepted; unit 1 answered through the 9th" "$F/f1-reads.log" "$PORT" reads 1
fi
stop f1-gw
base_conf "$F/f1-65.conf"
for i in $(seq 1 65); do echo "line.n$i = tcp 127.0.0.1 $DEAD_PORT"; done >>"$F/f1-65.conf"
# (64 lines: with the default one or besides it, 65 entries are past it.)
gw_refuses "finding 1: 65 line.* entries (past 64): refused, naming the file, line and key" "$F/f1-65.conf" \
    "$F/f1-65.conf:($((NEXT + 63)): line\.n64|$((NEXT + 64)): line\.n65):"

# --- 2. A 33rd route was written past routes[32] (at start and on SIGHUP). Limit: 256.
f2_routes() { # f2_routes N: routes 1-1 .. N-N, unit k to the line's unit 1
    echo "route = 1-1 default"
    for k in $(seq 2 "$1"); do echo "route = $k-$k default -$((k - 1))"; done
}
fx_conf "$F/f2.conf" "route = 0-0 default"
f2_routes 255 >>"$F/f2.conf"
if gw_up f2-gw "finding 2: 256 routes accepted" -d -v 3 -c "$F/f2.conf"; then
    checks "finding 2: 256 routes (0-0 .. 255-255) accepted; unit 255 (route 255-255 default -254) answered" \
        "$F/f2-reads.log" "$PORT" reads 255
    # SIGHUP: 40 routes now; unit 41 has none.
    head -n 7 "$F/f2.conf" >"$F/f2.new"
    f2_routes 40 >>"$F/f2.new"
    mv "$F/f2.new" "$F/f2.conf"
    hup_checks f2-gw "$F/f2.conf" ": 40 route(s)" "finding 2: SIGHUP, 40 routes: unit 40 answered" \
        "$F/f2-reads40.log" "$PORT" reads 40
    checks "finding 2: SIGHUP, 40 routes: unit 41 has none now, exception 0x0A" "$F/f2-41.log" "$PORT" unit 41 0A
fi
stop f2-gw

# --- 3. unit + offset overflowed int; a route could remap a unit to 0 (a broadcast).
base_conf "$F/f3a.conf" "route = 1-1 default 2147483647"
gw_refuses "finding 3: route offset 2147483647: refused, naming the file, line and key" "$F/f3a.conf" \
    "$F/f3a.conf:$((NEXT - 1)): route"
base_conf "$F/f3b.conf" "route = 5-5 default -5"
gw_refuses "finding 3: a route remapping unit 5 to unit 0 (a broadcast): refused, naming the file, line and key" \
    "$F/f3b.conf" "$F/f3b.conf:$((NEXT - 1)): route"
base_conf "$F/f3c.conf" "route = 250-255 default 10"
gw_refuses "finding 3: a route remapping units past 255: refused, naming the file, line and key" "$F/f3c.conf" \
    "$F/f3c.conf:$((NEXT - 1)): route"

# --- 4. TLS roles protected nothing: the plain fronts reached the same units.
TLS_KEYS=("tls_port = $(free_port)" "tls_cert = $CERTS/server.pem" "tls_key = $CERTS/server.key"
    "tls_ca = $CERTS/ca.pem")
base_conf "$F/f4a.conf" "${TLS_KEYS[@]}" "tls_role.Operator = rw 1-3"
gw_refuses "finding 4: TLS roles and the plain front on the same units: refused, naming allow_plain" \
    "$F/f4a.conf" "allow_plain"
base_conf "$F/f4b.conf" "${TLS_KEYS[@]}" "tls_role.Operator = rw 1-3" "rtutcp_port = $(free_port)"
sed -i 's/^port = .*/port = 0/' "$F/f4b.conf"
gw_refuses "finding 4: TLS roles and the RTU-over-TCP front on the same units (port = 0): refused, naming allow_plain" \
    "$F/f4b.conf" "allow_plain"
TLS_PORT=$(free_port)
fx_conf "$F/f4c.conf" "tls_port = $TLS_PORT" "tls_cert = $CERTS/server.pem" "tls_key = $CERTS/server.key" \
    "tls_ca = $CERTS/ca.pem" "tls_role.Operator = rw 1-3" "tls_role.Reader = r 1-247"
sed -i 's/^port = .*/port = 0/' "$F/f4c.conf"
if gw_up f4c-gw "finding 4: port = 0 (the plain front off) with TLS roles: starts" -d -c "$F/f4c.conf"; then
    rc=0
    env LD_LIBRARY_PATH="$LIBDIR" timeout -k 5 120 "$BIN/gw-ours" tls "$CERTS" "$TLS_PORT" >"$F/f4c-tls.log" 2>&1 || rc=$?
    program_checks "finding 4: port = 0 (the plain front off) with TLS roles: starts, the TLS front's policy holds" \
        "$F/f4c-tls.log" "$rc"
fi
stop f4c-gw
fx_conf "$F/f4d.conf" "tls_port = $(free_port)" "tls_cert = $CERTS/server.pem" "tls_key = $CERTS/server.key" \
    "tls_ca = $CERTS/ca.pem" "tls_role.Operator = rw 1-3" "allow_plain = yes"
if gw_up f4d-gw "finding 4: allow_plain = yes: starts" -d -c "$F/f4d.conf"; then
    checks "finding 4: allow_plain = yes: starts with TLS roles and the plain front; the plain front serves" \
        "$F/f4d-held.log" "$PORT" held 1
fi
stop f4d-gw
RTUTCP_PORT=$(free_port)
fx_conf "$F/f4e.conf" "tls_port = $(free_port)" "tls_cert = $CERTS/server.pem" "tls_key = $CERTS/server.key" \
    "tls_ca = $CERTS/ca.pem" "tls_role.Operator = rw 1-3" "tls_role.Reader = r 1-3" "plain_units = 4-255" \
    "rtutcp_port = $RTUTCP_PORT"
if gw_up f4e-gw "finding 4: plain_units = 4-255 beside roles on 1-3: starts" -d -v 3 -c "$F/f4e.conf"; then
    checks "finding 4: plain_units = 4-255: the plain front refuses unit 1 (role-protected), exception 0x0A" \
        "$F/f4e-plain.log" "$PORT" unit 1 0A
    findings "finding 4: plain_units = 4-255: the RTU-over-TCP front refuses unit 1, exception 0x0A" \
        "$F/f4e-rtutcp.log" rtutcp "$RTUTCP_PORT" 1 0A
fi
stop f4e-gw
# The manual page's example: roles, and no plain front reaching their units (port = 0
# or plain_units; not allow_plain); the gateway starts with it (the test's line,
# certificates and ports put in).
# (The section's first code block: the section ends at the next heading.)
awk '/^## /{in_ex = ($0 ~ /^## EXAMPLE/)} in_ex && /^```/{n++; next} in_ex && n == 1' \
    "$ROOT/man/src/rsmodbus-gateway.md" >"$F/f4-example.conf"
begin "finding 4: the manual page's EXAMPLE configuration is safe"
grep -q '^tls_role\.' "$F/f4-example.conf" || err "it has no tls_role.* line"
grep -qE '^allow_plain *= *(yes|true|on|1)' "$F/f4-example.conf" && err "it sets allow_plain"
grep -qE '^(port *= *0$|plain_units *=)' "$F/f4-example.conf" ||
    err "its plain Modbus/TCP front reaches the roles' units (no port = 0, no plain_units)"
EX_PORT=$(free_port)
sed -e "s|^device *=.*|device = $WORK/fx-G|" -e 's|^speed *=.*|speed = 115200|' -e 's|^mode *=.*|mode = 8N1|' \
    -e "s|^port *= *[1-9][0-9]*\$|port = $EX_PORT|" -e "s|^tls_cert *=.*|tls_cert = $CERTS/server.pem|" \
    -e "s|^tls_key *=.*|tls_key = $CERTS/server.key|" -e "s|^tls_ca *=.*|tls_ca = $CERTS/ca.pem|" \
    -e '/^tls_port *=/d' -e '/^logfile *=/d' -e '/^status_file *=/d' "$F/f4-example.conf" >"$F/f4-run.conf"
echo "tls_port = $(free_port)" >>"$F/f4-run.conf"
start f4x-gw "${GW[@]}" -d -L - -c "$F/f4-run.conf"
sleep 1.5
if ! kill -0 "${_pids[f4x-gw]}" 2>/dev/null; then
    err "the gateway does not start with it:"
    err_file "$WORK/f4x-gw.log" 5
fi
stop f4x-gw
end

# --- 5. Descriptors exhausted through one front deafened another one for good.
RTUTCP_PORT=$(free_port)
PORT=$(free_port)
printf 'rtutcp_port = %s\nmaxconn = 100\n' "$RTUTCP_PORT" >"$F/f5.conf"
start f5-gw bash -c 'ulimit -n 40 && exec "$@"' f5 "${GW[@]}" -d -L - -v 1 -c "$F/f5.conf" -p "$WORK/fx-G" \
    -s 115200 -P "$PORT" -R 1 -W 300 -N 0
sleep 1.5
if kill -0 "${_pids[f5-gw]}" 2>/dev/null; then
    findings "finding 5: ulimit -n 40, 60 connections to the plain front then closed: the RTU-over-TCP front answers again" \
        "$F/f5.log" fds "$PORT" "$RTUTCP_PORT" 60
else
    wait_exit f5-gw 1
    bad "finding 5: the gateway starts under ulimit -n 40" "exit status $rc" "$(tail -n 3 "$WORK/f5-gw.log")"
fi
stop f5-gw

# --- 6. Every refusal of a full queue was logged (1.6 MB of log for 240 kB of requests).
PORT=$(free_port)
if gw_up f6-gw "finding 6: the gateway starts" "${FYARGS[@]}" -W 1000 -P "$PORT"; then
    findings "finding 6: 20,000 requests (240 kB) pipelined for unit 9 (no device): refused, 0x06" "$F/f6.log" \
        flood "$PORT" 9 20000
    size=$(stat -c %s "$WORK/f6-gw.log")
    if [ "$size" -lt 20000 ] && grep -q "queues full (busy)" "$WORK/f6-gw.log"; then
        ok "finding 6: the log stays small at -v 2 ($size bytes), the refusals counted ('queues full (busy)')"
    else
        bad "finding 6: the log stays under 20 kB at -v 2, the refusals counted ('queues full (busy)')" \
            "$size bytes" "$(grep -m 3 -i 'full\|busy' "$WORK/f6-gw.log")"
    fi
fi
stop f6-gw

# --- 7. A TCP line's host name was resolved on the loop: a DNS outage froze everything.
# The gateway runs in a mount namespace of its own (unshare -m) whose /etc/resolv.conf
# names a server on loopback that reads the queries and never answers.
cat >"$F/resolv.conf" <<EOF
nameserver 127.0.0.77
options timeout:4 attempts:2
EOF
start f7-dns python3 -c 'import socket
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.77", 53))
print("READY", flush=True)
while True:
    s.recvfrom(2048)'
fx_conf "$F/f7.conf" "line.net = tcp plc.gwtests.invalid 502" "route = 1-1 default" "route = 2-2 net"
if wait_ready f7-dns READY 10; then
    start f7-gw unshare -m sh -c 'mount --bind "$0" /etc/resolv.conf && exec "$@"' "$F/resolv.conf" \
        "${GW[@]}" -d -v 3 -c "$F/f7.conf"
    if timeout 90 python3 "$FINDINGS" ready "$PORT" 60; then
        findings "finding 7: DNS not answering: the other line is served while a TCP line's host name resolves" \
            "$F/f7.log" dns "$PORT" 2 3
    else
        bad "finding 7: the gateway answers unit 1 (a TCP line's host name unresolved, DNS not answering)" \
            "$(tail -n 3 "$WORK/f7-gw.log")"
    fi
    stop f7-gw
else
    bad "finding 7: a DNS server that never answers, on 127.0.0.77:53" "$(tail -n 3 "$WORK/f7-dns.log")"
fi
stop f7-dns

# --- 8. The status file's temporary file was opened with fopen: symlinks followed,
# a FIFO waited on.
echo "victim" >"$F/f8-victim"
rm -f "$F/f8a.status" "$F/f8a.status.tmp"
ln -s "$F/f8-victim" "$F/f8a.status.tmp"
base_conf "$F/f8a.conf" "status_file = $F/f8a.status"
if gw_up f8a-gw "finding 8: the gateway starts" -d -L - -c "$F/f8a.conf"; then
    sleep 2
    begin "finding 8: status_file's .tmp name a symlink to another file: that file is left alone"
    [ "$(cat "$F/f8-victim")" = victim ] || err "the file the symlink names was written: $(head -c 200 "$F/f8-victim")"
    if [ -L "$F/f8a.status" ] || ! grep -q '^rsmodbus_gateway_requests_total' "$F/f8a.status" 2>/dev/null; then
        err "no status file of its own at $F/f8a.status: $(ls -l "$F/f8a.status" 2>&1)"
    fi
    end
fi
stop f8a-gw
rm -f "$F/f8b.status" "$F/f8b.status.tmp"
mkfifo "$F/f8b.status.tmp"
fx_conf "$F/f8b.conf" "status_file = $F/f8b.status"
if gw_up f8b-gw "finding 8: the gateway starts (a FIFO at the status file's .tmp name)" -d -c "$F/f8b.conf"; then
    checks "finding 8: status_file's .tmp name a FIFO: the gateway keeps answering" "$F/f8b-held.log" "$PORT" held 1
    sleep 1.2
    if grep -q '^rsmodbus_gateway_requests_total' "$F/f8b.status" 2>/dev/null; then
        ok "finding 8: status_file's .tmp name a FIFO: the status file written all the same"
    else
        bad "finding 8: status_file's .tmp name a FIFO: the status file written all the same" \
            "$(ls -l "$F"/f8b.status* 2>&1)"
    fi
fi
stop f8b-gw

# --- 9. No privilege drop. (The packaged unit's sandbox: c-tests/suites/package.sh,
# systemd-analyze security.) The user key: the gateway runs as that user once its
# line and fronts are open.
fx_conf "$F/f9.conf" "user = nobody"
if gw_up f9-gw "finding 9: user = nobody: the gateway starts" -d -c "$F/f9.conf"; then
    uid=$(awk '/^Uid:/ { print $2, $3, $4, $5 }' "/proc/${_pids[f9-gw]}/status")
    want=$(id -u nobody)
    if [ "$uid" = "$want $want $want $want" ]; then
        checks "finding 9: user = nobody: runs as nobody (uid $want), the line still answers" "$F/f9-reads.log" \
            "$PORT" reads 1
    else
        bad "finding 9: user = nobody: runs as nobody" "Uid: $uid (want $want)"
    fi
fi
stop f9-gw
base_conf "$F/f9b.conf" "user = no-such-user-gwtests"
gw_refuses "finding 9: an unknown user: refused, named" "$F/f9b.conf" "no-such-user-gwtests"

# --- 10. UDP: all senders shared one queue; any sender was answered (reflection).
UDP_PORT=$(free_port)
PORT=$(free_port)
printf 'udp_port = %s\nudp_allow = 127.0.0.1/32\n' "$UDP_PORT" >"$F/f10.conf"
if gw_up f10-gw "finding 10: the gateway starts (udp_port, udp_allow)" "${FYARGS[@]}" -P "$PORT" -c "$F/f10.conf"; then
    findings "finding 10: UDP: one sender floods, another is still served" "$F/f10.log" udp "$UDP_PORT"
    findings "finding 10: UDP: a sender outside udp_allow gets nothing" "$F/f10-deny.log" udpdeny "$UDP_PORT" 127.0.0.2
fi
stop f10-gw
base_conf "$F/f10b.conf" "udp_port = $(free_port)"
gw_refuses "finding 10: udp_port without udp_allow: refused, naming udp_allow" "$F/f10b.conf" "udp_allow"

# --- 11. Answers of user-defined function codes were cut (fixed by issue 38; a long one).
PORT=$(free_port)
if gw_up f11-gw "finding 11: the gateway starts" "${FYARGS[@]}" -P "$PORT"; then
    findings "finding 11: a user-defined function code's long answer passes whole" "$F/f11.log" longfc "$PORT"
fi
stop f11-gw

# --- 12. daemon() went to /: a relative -c and status_file broke (on SIGHUP too).
D12=$F/f12
mkdir -p "$D12"
C12=gwtests-f12-$$.conf
S12=gwtests-f12-$$.status
rm -f "$D12/$S12" "$D12/gw.log"
fx_conf "$D12/$C12" "logfile = $D12/gw.log" "status_file = $S12" "loglevel = 2"
sed -i '/^logfile = -$/d' "$D12/$C12"
rc=0
(cd "$D12" && timeout -k 2 10 "${GW[@]}" -c "$C12" </dev/null >"$F/f12-start.log" 2>&1) || rc=$?
sleep 1.5
pid12=$(pgrep -f -- "-c $C12\$" | head -n 1)
if [ "$rc" = 0 ] && [ -n "$pid12" ]; then
    PIDS+=("$pid12")
    sleep 1
    if grep -q '^rsmodbus_gateway_requests_total' "$D12/$S12" 2>/dev/null; then
        ok "finding 12: daemonized (no -d), a relative status_file: written in the directory it started in"
    else
        bad "finding 12: daemonized, a relative status_file: written in the directory it started in" \
            "$(ls -l "$D12/$S12" "/$S12" 2>&1)"
    fi
    kill -HUP "$pid12"
    if wait_for "$D12/gw.log" "configuration reloaded from $C12" 10; then
        ok "finding 12: daemonized, a relative -c: SIGHUP reloads it"
    else
        bad "finding 12: daemonized, a relative -c: SIGHUP reloads it" "$(tail -n 3 "$D12/gw.log")"
    fi
    stop_pid "$pid12"
else
    bad "finding 12: daemonized with a relative -c: starts (exit 0, running)" "exit status $rc, pid '${pid12}'" \
        "$(tail -n 3 "$F/f12-start.log")" "$(tail -n 3 "$D12/gw.log" 2>&1)"
    [ -z "$pid12" ] || stop_pid "$pid12"
fi
# (the gateway of before wrote its status file at /)
rm -f "/$S12" "/$S12.tmp"

# --- 13. Reload errors went to stderr (/dev/null once daemonized), named no file or
# line; start failures exited 0; SIGHUP could be lost (an idle gateway).
fx_conf "$F/f13.conf"
sed -i '/^logfile = -$/d' "$F/f13.conf"
rm -f "$F/f13.log"
if gw_up f13-gw "finding 13: the gateway starts" -d -L "$F/f13.log" -v 2 -c "$F/f13.conf"; then
    sleep 2
    kill -HUP "${_pids[f13-gw]}"
    if wait_for "$F/f13.log" "configuration reloaded from $F/f13.conf" 3; then
        ok "finding 13: an idle gateway reloads at once on SIGHUP (within 3 s, no traffic)"
    else
        bad "finding 13: an idle gateway reloads at once on SIGHUP (within 3 s, no traffic)" "$(tail -n 3 "$F/f13.log")"
    fi
    n13=$(($(wc -l <"$F/f13.conf") + 1))
    echo "speed = 9600abc" >>"$F/f13.conf"
    kill -HUP "${_pids[f13-gw]}"
    if wait_for "$F/f13.log" "$F/f13.conf:$n13: speed" 10; then
        ok "finding 13: a reload error is in the log file, naming the file, line and key"
    else
        bad "finding 13: a reload error is in the log file, naming the file, line and key ($F/f13.conf:$n13: speed)" \
            "$(tail -n 3 "$F/f13.log")"
    fi
    if kill -0 "${_pids[f13-gw]}" 2>/dev/null; then
        checks "finding 13: after the reload error, the gateway runs on, answering" "$F/f13-reads.log" "$PORT" reads 1
    else
        bad "finding 13: after the reload error, the gateway runs on" "$(tail -n 3 "$WORK/f13-gw.log")"
    fi
fi
stop f13-gw
base_conf "$F/f13c.conf" "retries = 99"
gw_refuses "finding 13: a range error: exit status 1, naming the file, line and key" "$F/f13c.conf" \
    "$F/f13c.conf:$((NEXT - 1)): retries"
# Daemonized (no -d): a missing TLS certificate is a start failure, exit status 1.
C13=gwtests-f13-$$.conf
base_conf "$F/$C13" "logfile = $F/f13d.log" "tls_port = $(free_port)" "tls_cert = $F/no-such-cert.pem" \
    "tls_key = $CERTS/server.key" "tls_ca = $CERTS/ca.pem"
rc=0
(cd "$F" && timeout -k 2 10 "${GW[@]}" -c "$C13" </dev/null >"$F/f13d-start.log" 2>&1) || rc=$?
sleep 0.5
pid13=$(pgrep -f -- "-c $C13\$" | head -n 1)
[ -z "$pid13" ] || stop_pid "$pid13"
if [ "$rc" = 1 ] && grep -qs "no-such-cert.pem" "$F/f13d-start.log" "$F/f13d.log"; then
    ok "finding 13: daemonized, a missing TLS certificate: exit status 1, the file named"
else
    bad "finding 13: daemonized, a missing TLS certificate: exit status 1, the file named" \
        "exit status $rc${pid13:+, left running as $pid13}" "$(cat "$F/f13d-start.log" "$F/f13d.log" 2>/dev/null | head -n 4)"
fi

# --- 14. A master that left still had its queued requests executed (writes too).
PORT=$(free_port)
# The master leaves 50 ms after sending, while the first write waits (-W 1000) on the line.
if gw_up f14-gw "finding 14: the gateway starts" "${FYARGS[@]}" -W 1000 -P "$PORT"; then
    before=$(grep -c '^unit 9 fc 6$' "$FY_LOG")
    timeout 30 python3 "$FINDINGS" queue "$PORT" 9 16 >"$F/f14.log" 2>&1
    # Queued writes still executed would reach the device one a second.
    sleep 5
    seen=$(($(grep -c '^unit 9 fc 6$' "$FY_LOG") - before))
    if [ "$seen" -le 1 ]; then
        ok "finding 14: a master queues 16 writes and leaves: the device sees $seen (at most the one on the line)"
    else
        bad "finding 14: a master queues 16 writes and leaves: the device sees at most the one on the line" \
            "it saw $seen"
    fi
fi
stop f14-gw

# --- 15. The configuration file: truncations, '#' in values, duplicates, overlaps,
# atoi; on reload, removed keys kept and command-line options lost.
LONG=$F/f15/$(printf 'a%.0s' $(seq 200))/$(printf 'b%.0s' $(seq 200))
mkdir -p "$LONG"
S15=$LONG/$(printf 'c%.0s' $(seq 150)).status
rm -f "$S15"
# status_at NAME CHECK PATH VALUE: a gateway (NAME) whose file has status_file = VALUE
# writes its status file at PATH.
status_at() {
    base_conf "$F/$1.conf" "status_file = $4"
    if gw_up "$1-gw" "$2" -d -L - -c "$F/$1.conf"; then
        sleep 1.2
        if [ -f "$3" ]; then ok "$2"; else bad "$2" "no file at $3:" "$(ls "$(dirname "$3")")"; fi
    fi
    stop "$1-gw"
}
status_at f15a "finding 15: a line of $((${#S15} + 14)) bytes: its ${#S15}-byte status_file path used whole" \
    "$S15" "$S15"
rm -f "$F/f15/st#1.status" "$F/f15/st"
status_at f15b "finding 15: '#' inside a value (status_file = .../st#1.status # comment): the path kept whole" \
    "$F/f15/st#1.status" "$F/f15/st#1.status # a comment after a blank"
ROLE=$(printf 'R%.0s' $(seq 100))
base_conf "$F/f15c.conf" "tls_role.$ROLE = r 1-3"
gw_refuses "finding 15: a 100-character role name: refused, naming the file, line and key" "$F/f15c.conf" \
    "$F/f15c.conf:$((NEXT - 1)): tls_role\.R"
base_conf "$F/f15d.conf" "line.b = tcp 127.0.0.1 $DEAD_PORT" "line.b = tcp 127.0.0.1 $DEAD_PORT"
gw_refuses "finding 15: a duplicate line.NAME: refused, naming both lines" "$F/f15d.conf" \
    "$F/f15d.conf:$((NEXT - 1)): line\.b.*\<$((NEXT - 2))\>"
base_conf "$F/f15e.conf" "route = 1-10 default" "route = 5-20 default"
gw_refuses "finding 15: overlapping routes: refused, naming both" "$F/f15e.conf" \
    "$F/f15e.conf:$((NEXT - 1)): route.*(\<$((NEXT - 2))\>|1-10)"
base_conf "$F/f15f.conf" "speed = 9600abc"
gw_refuses "finding 15: speed = 9600abc: refused, naming the file, line and key" "$F/f15f.conf" \
    "$F/f15f.conf:$((NEXT - 1)): speed"
base_conf "$F/f15g.conf" "line.b = serial /dev/null 9600abc 8N1"
gw_refuses "finding 15: line.b's speed 9600abc: refused, naming the file, line and key" "$F/f15g.conf" \
    "$F/f15g.conf:$((NEXT - 1)): line\.b"
# A removed key returns to its default on reload: replyonbroadcast.
fx_conf "$F/f15h.conf" "replyonbroadcast = yes"
if gw_up f15h-gw "finding 15: the gateway starts (replyonbroadcast = yes)" -d -c "$F/f15h.conf"; then
    timeout -k 5 60 "$BIN/gw-check" "$PORT" broadcast 1 >"$F/f15h-before.log" 2>&1
    sed -i '/^replyonbroadcast/d' "$F/f15h.conf"
    hup_checks f15h-gw "$F/f15h.conf" "" \
        "finding 15: replyonbroadcast removed from the file, SIGHUP: back to its default (no answer)" \
        "$F/f15h-after.log" "$PORT" broadcast 0
    grep '^FAIL' "$F/f15h-before.log" | sed 's/^/       (before the reload) /'
fi
stop f15h-gw
# A command-line option keeps winning after a reload: -b over replyonbroadcast = no.
fx_conf "$F/f15i.conf" "replyonbroadcast = no"
if gw_up f15i-gw "finding 15: the gateway starts (-b, replyonbroadcast = no)" -d -c "$F/f15i.conf" -b; then
    timeout -k 5 60 "$BIN/gw-check" "$PORT" broadcast 1 >"$F/f15i-before.log" 2>&1
    hup_checks f15i-gw "$F/f15i.conf" "" \
        "finding 15: -b on the command line, replyonbroadcast = no in the file: -b still wins after SIGHUP" \
        "$F/f15i-after.log" "$PORT" broadcast 1
    grep '^FAIL' "$F/f15i-before.log" | sed 's/^/       (before the reload) /'
fi
stop f15i-gw

# --- 16. mbusd's behaviours: a non-zero MBAP protocol id, maxconn, an unreachable
# TCP device, a missing TLS file.
PORT=$(free_port)
if gw_up f16a-gw "finding 16: the gateway starts" "${FYARGS[@]}" -P "$PORT"; then
    before=$(grep -c '^unit 7 ' "$FY_LOG")
    findings "finding 16: MBAP protocol id 1: the connection dropped" "$F/f16a.log" proto "$PORT" 7
    sleep 0.5
    seen=$(($(grep -c '^unit 7 ' "$FY_LOG") - before))
    if [ "$seen" = 0 ]; then
        ok "finding 16: MBAP protocol id 1: not forwarded (the device saw nothing for unit 7)"
    else
        bad "finding 16: MBAP protocol id 1: not forwarded" "the device saw $seen request(s) for unit 7"
    fi
fi
stop f16a-gw
PORT=$(free_port)
if gw_up f16b-gw "finding 16: the gateway starts (-C 2)" "${FYARGS[@]}" -P "$PORT" -C 2; then
    findings "finding 16: at maxconn (-C 2) a new connection is accepted and closed" "$F/f16b.log" full "$PORT" 2
fi
stop f16b-gw
base_conf "$F/f16c.conf"
if gw_up f16c-gw "finding 16: the gateway starts (a TCP device nobody listens on)" -d -L - -c "$F/f16c.conf"; then
    checks "finding 16: an unreachable TCP device: exception 0x0A (gateway path unavailable)" "$F/f16c.log" \
        "$BPORT" unit 1 0A
fi
stop f16c-gw
base_conf "$F/f16d.conf" "tls_port = $(free_port)" "tls_cert = $CERTS/server.pem" "tls_key = $CERTS/server.key" \
    "tls_ca = $F/no-such-ca.pem"
gw_refuses "finding 16: a missing TLS file (tls_ca): exit status 1, the file named" "$F/f16d.conf" "no-such-ca\.pem"

stop fx-device
stop fy-device
stop_pid "$FX_SOCAT"
stop_pid "$FY_SOCAT"

summary
