#!/usr/bin/env bash
# gateway.sh: rsmodbus-gateway (gateway/rsmodbus-gateway.c) beside mbusd, built from
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
#     on the line, c-tests/event/event-test.c fc41 as the master).
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

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"

parse_flags -- "$@"

section "build"
our_lib_result "$LIBDIR" 2
rm -rf "$WORK"
mkdir -p "$WORK"
BIN=$(c_build_dir)
c_build_group GATEWAY
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
        prog=(env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway")
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
    start tls-gw env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -d -v 3 -c "$WORK/tls.conf"
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
    start fronts-gw env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -c "$WORK/fronts.conf" -d -L - \
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
        start "back-$back-gw" env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -c "$WORK/back-$back.conf" -d -L - \
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
    start routes-gw env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -d -v 5 -c "$WORK/routes.conf"
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
    start hup-gw env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -d -v 3 -c "$WORK/hup.conf"
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
    start conf-gw env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -d -c "$WORK/gw.conf"
    sleep 0.5
    checks "configuration file: the gateway reads it (port, device, speed)" "$WORK/conf-held.log" "$PORT" held 3
    done_with conf
fi
if line example; then
    PORT=$(free_port)
    # The example configuration as shipped, with the test's line, port and log.
    start example-gw env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -d -c "$ROOT/gateway/example.conf" \
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
out=$(env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -h 2>&1)
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
if ! env LD_LIBRARY_PATH="$LIBDIR" "$BIN/rsmodbus-gateway" -d -c "$WORK/bad.conf" >"$WORK/bad.log" 2>&1 &&
    grep -q "unknown key 'bogus'" "$WORK/bad.log"; then
    ok "an unknown key in the configuration file is refused, named"
else
    bad "an unknown key in the configuration file is refused" "$(cat "$WORK/bad.log")"
fi

summary
