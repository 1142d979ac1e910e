#!/usr/bin/env bash
# tls.sh: Modbus/TCP Security (TLS, mutual authentication, roles) against
# real peers on loopback. Certificates are made at test time with openssl
# (c-tests/tls/make-certs.sh). The server is examples/tls-server.c with its role
# policy (Operator: everything; Reader: reads; anything else: exception 01); the
# clients are c-tests/tls/tls-test.c, examples/tls-client.c, openssl s_client and
# python. Checks:
#   - roles: an Operator writes, a Reader's write is refused with exception 01 and
#     changes nothing, a client without a role is refused; the client's view of the
#     server (no role: ENOENT);
#   - refusals, with the errno on the client and the reason the server reports: no
#     client certificate, another CA, an expired certificate, TLS 1.1
#     (openssl s_client -tls1_1), a server certificate for another name, no CA set;
#   - session resumption (the debug trace of the second handshake);
#   - 64 clients at once on the one server context (its poll() loop);
#   - faults: garbage instead of a handshake, a client that stops halfway through
#     the handshake (the server goes on serving others), a connection cut under a
#     client (the next connect works), records cut in the middle (FIN or RST) on
#     both sides and peers that leave without close_notify (c-tests/tls/cut.py),
#     a refusal (and reset) while the client still writes its flight: the alert,
#     not the failed write, is reported (c-tests/tls/alert_server.py);
#   - interoperability with pymodbus, both directions, IPv4 and IPv6;
#   - every cipher suite of TLS 1.2 and 1.3 against OpenSSL, both directions, with a
#     key update asked by the peer (c-tests/tls/suites.sh, c-tests/tls/suite_server.py);
#   - AddressSanitizer (with its leak checker) on the C programs: the test client's
#     scenarios and the example server, built with -fsanitize=address.
# Every process started here is stopped by its PID. Ends with "N passed, M failed".
# Usage: c-tests/suites/tls.sh [--no-cargo]
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 1
ROOT=$PWD
WORK=$ROOT/target/tls-tests
rm -rf "$WORK"
mkdir -p "$WORK"
# shellcheck source=c-tests/common/testlib.sh
. c-tests/common/testlib.sh

CARGO=1
[ "${1:-}" = --no-cargo ] && CARGO=0
LIB=$ROOT/target/release
if [ $CARGO -eq 1 ] && ! cargo build --release --quiet; then
    bad "cargo build --release"
    summary
    exit 1
fi
# examples/tls-server.c, examples/tls-client.c and c-tests/tls/tls-test.c: c-tests/Makefile
# (group TLS: our headers, linked with an rpath to target/release), one check each.
BIN=$(c_build_dir)
ASAN_BIN=$(c_build_dir address)
LOGS=$WORK
c_build_group TLS
# The example programs print no LIBINFO line: the loader's choice, from ldd.
for prog in tls-server tls-client server-many; do
    loaded=$(ldd "$BIN/$prog" 2>/dev/null | awk '/libmodbus\.so\.5/ {print $3}')
    if [ "$(readlink -f "$loaded")" = "$(readlink -f "$LIB/libmodbus.so")" ]; then
        ok "$prog loads target/release/libmodbus.so ($loaded)"
    else
        bad "$prog loads target/release/libmodbus.so" "ldd says: $loaded"
    fi
done
if ! check "make the test certificates with openssl" c-tests/tls/make-certs.sh "$WORK/certs"; then
    summary
    exit 1
fi
C=$WORK/certs

# start_server NAME CERT [PROGRAM]: starts tls-server (or PROGRAM, which takes the
# same arguments: examples/server-many.c) on a free port with the server
# certificate CERT; sets PORT and SERVER_PID
start_server() {
    local name=$1 cert=$2 prog=${3:-tls-server}
    PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
    "$BIN/$prog" "$C/ca.pem" "$C/$cert.pem" "$C/$cert.key" "$PORT" >"$WORK/$name.out" 2>"$WORK/$name.err" &
    SERVER_PID=$!
    for _ in $(seq 100); do
        grep -q serving "$WORK/$name.out" 2>/dev/null && return 0
        sleep 0.05
    done
    bad "$name: server started" "$(cat "$WORK/$name.err")"
    return 1
}
stop_server() {
    kill "$SERVER_PID" 2>/dev/null
    wait "$SERVER_PID" 2>/dev/null
}

# count_lines FILE [PREFIX]: every "PASS x"/"ok   - x" and "FAIL x"/"FAIL - x" line of
# FILE counts as a check (named PREFIX: x)
count_lines() {
    local line name
    while IFS= read -r line; do
        case $line in
        PASS\ * | "ok   - "*) name=${line#PASS } && name=${name#ok   - } && ok "${2:+$2: }$name" ;;
        FAIL\ *) name=${line#FAIL } && name=${name#- } && bad "${2:+$2: }$name" "" ;;
        esac
    done <"$1"
}

# scenario NAME [ARGS]: runs tls-test against the server; every PASS/FAIL line counts
scenario() {
    local name=$1
    shift
    local out=$WORK/scenario-$name.out
    timeout 60 "$BIN/tls-test" "$C" "${HOST:-127.0.0.1}" "$PORT" "$name" "$@" >"$out" 2>&1
    local rc=$?
    if ! grep -q "LIBINFO: .*$(readlink -f "$LIB/libmodbus.so" | sed 's/[.]/[.]/g').*(rsmodbus" "$out" &&
        ! grep -q "LIBINFO: .*target/release/libmodbus.so.*(rsmodbus" "$out"; then
        bad "$name: loaded target/release/libmodbus.so" "$(grep LIBINFO "$out")"
    fi
    count_lines "$out"
    [ $rc -eq 0 ] || bad "$name: exit status" "$rc: $(tail -n 3 "$out")"
}

# server_reported TEXT WHAT: the server's stderr names the reason of a refusal
server_reported() {
    if grep -q "$1" "$WORK/main.err"; then ok "$2"; else bad "$2" "$(tail -n 3 "$WORK/main.err")"; fi
}

start_server main server || { summary; exit 1; }
scenario operator
scenario reader
scenario norole
scenario nocert
server_reported "client refused: TLS: the peer sent no certificate" "server: no client certificate refused (EMBTLSNOCERT)"
scenario rogue
server_reported "client refused: TLS: certificate not issued by a trusted CA" "server: another CA refused (EMBTLSUNKNOWNCA)"
scenario expired
server_reported "client refused: TLS: certificate expired" "server: expired certificate refused (EMBTLSEXPIRED)"
scenario noca
scenario password
scenario resume
if grep -q "TLS handshake done: .*resumed" "$WORK/scenario-resume.out"; then
    ok "resume: the second handshake resumed the session"
else
    bad "resume: the second handshake resumed the session" "$(grep 'TLS handshake' "$WORK/scenario-resume.out")"
fi
# Our client offers AES-128-GCM first (the specification's recommended suites are
# AES-128-GCM ones, R-36; TLS 1.3's mandatory one): ours against ours agree on it.
if grep -q "TLS handshake done: TLSv1_3, TLS13_AES_128_GCM_SHA256" "$WORK/scenario-resume.out"; then
    ok "suite: ours against ours agree on TLS13_AES_128_GCM_SHA256"
else
    bad "suite: ours against ours agree on TLS13_AES_128_GCM_SHA256" "$(grep 'TLS handshake' "$WORK/scenario-resume.out")"
fi
# The example client against the example server.
out=$("$BIN/tls-client" "$C/ca.pem" "$C/operator.pem" "$C/operator.key" 127.0.0.1 "$PORT" 2>&1)
if [[ $out == *"registers 0-4: 1000 1001 1002 1003 1004"* && $out == *"write allowed"* ]]; then
    ok "examples: tls-client as Operator reads and writes"
else
    bad "examples: tls-client as Operator" "$out"
fi
out=$("$BIN/tls-client" "$C/ca.pem" "$C/reader.pem" "$C/reader.key" 127.0.0.1 "$PORT" 2>&1)
if [[ $out == *"write refused: Illegal function"* ]]; then
    ok "examples: tls-client as Reader is refused the write"
else
    bad "examples: tls-client as Reader" "$out"
fi
# A server name the certificate carries (a DNS name; the host is an address), and a
# unit id; then a name it does not carry.
out=$("$BIN/tls-client" "$C/ca.pem" "$C/reader.pem" "$C/reader.key" 127.0.0.1 "$PORT" localhost 7 2>&1)
if [[ $out == *"server localhost, unit 7"* && $out == *"registers 0-4:"* && $out == *"write refused"* ]]; then
    ok "examples: tls-client with server name localhost (host 127.0.0.1) and unit 7"
else
    bad "examples: tls-client with server name localhost and unit 7" "$out"
fi
out=$("$BIN/tls-client" "$C/ca.pem" "$C/reader.pem" "$C/reader.key" 127.0.0.1 "$PORT" wrong.example 2>&1)
if [[ $out == *"connection failed: TLS: certificate not valid for the peer's name"* ]]; then
    ok "examples: tls-client with a server name the certificate does not carry: EMBTLSNAME"
else
    bad "examples: tls-client with a wrong server name" "$out"
fi
# Restore register 0 (the examples wrote it).
# TLS 1.1 is refused by the server.
if grep -q -- -tls1_1 <<<"$(openssl s_client -help 2>&1)"; then
    echo Q | timeout 10 openssl s_client -connect "127.0.0.1:$PORT" -tls1_1 -cipher 'DEFAULT@SECLEVEL=0' \
        -cert "$C/operator.pem" -key "$C/operator.key" >"$WORK/tls11.out" 2>&1
    if grep -q "Cipher is (NONE)\|alert protocol version\|no protocols available\|wrong version number" "$WORK/tls11.out"; then
        ok "TLS 1.1: no session"
    else
        bad "TLS 1.1: no session" "$(tail -n 5 "$WORK/tls11.out")"
    fi
    server_reported "client refused: TLS: protocol version" "server: TLS 1.1 refused (EMBTLSVERSION)"
fi
# Garbage instead of a handshake, then a client that stops halfway: the server
# refuses both and serves the next client.
python3 - "$PORT" <<'PY' >"$WORK/faults.out" 2>&1
import socket, sys, time
port = int(sys.argv[1])
g = socket.create_connection(("127.0.0.1", port))
g.sendall(b"GET / HTTP/1.0\r\n\r\n" * 4)
time.sleep(0.2)
g.close()
h = socket.create_connection(("127.0.0.1", port))
h.sendall(bytes([0x16, 0x03, 0x01, 0x02, 0x00, 0x01, 0x00]))  # a ClientHello header, then nothing
time.sleep(1.5)
h.close()
print("done")
PY
server_reported "client refused: TLS failure" "server: garbage instead of a handshake refused (EMBTLS)"
server_reported "client refused: Connection timed out" "server: a handshake stalled halfway ends at the response timeout"
# Three requests in one TLS record (one SSL_write): the poll-loop server answers all
# three at once (modbus_get_tls_pending), not the later ones only when the client
# sends more.
pipelined_record() { # pipelined_record NAME: against the server on $PORT
    python3 - "$PORT" "$C" <<'PY' >"$WORK/pipelined-$1.out" 2>&1
import socket, ssl, struct, sys
port, certs = int(sys.argv[1]), sys.argv[2]
ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
ctx.load_verify_locations(f"{certs}/ca.pem")
ctx.load_cert_chain(f"{certs}/operator.pem", f"{certs}/operator.key")
s = ctx.wrap_socket(socket.create_connection(("127.0.0.1", port)), server_hostname="127.0.0.1")
s.sendall(b"".join(struct.pack(">HHHBBHH", tid, 0, 6, 1, 3, 4 + tid, 1) for tid in (1, 2, 3)))
s.settimeout(5)
got = b""
try:
    while len(got) < 33:
        chunk = s.recv(1024)
        if not chunk:
            break
        got += chunk
except socket.timeout:
    pass
answers = [struct.unpack(">HHHBBBH", got[k:k + 11]) for k in range(0, len(got) - 10, 11)]
ok = [(a[0], a[6]) for a in answers] == [(1, 1005), (2, 1006), (3, 1007)]
print(f"{'PASS' if ok else 'FAIL'} three requests in one TLS record, three answers within 5 s: {answers}")
s.close()
PY
    count_lines "$WORK/pipelined-$1.out" "$1"
}
pipelined_record tls-server
scenario operator
scenario many 64
scenario threads 8
if kill -0 "$SERVER_PID" 2>/dev/null; then ok "server alive after the faults"; else bad "server alive" ""; fi
stop_server

# The server that runs itself (examples/server-many.c, modbus_server_new(3)): the same
# role policy through the authorization callback, handshakes without waiting, three
# requests in one TLS record answered at once.
start_server server-many server server-many && {
    scenario operator
    scenario reader
    scenario norole
    scenario nocert
    scenario rogue
    scenario resume
    scenario many 64
    pipelined_record server-many
    if kill -0 "$SERVER_PID" 2>/dev/null; then ok "server-many alive after the refusals"; else bad "server-many alive" ""; fi
    stop_server
}

# A server whose certificate names another host.
start_server wrongname wrongname && {
    scenario wrongname
    stop_server
}

# A connection cut under the client: the server is stopped and started again on the
# same port, and the client connects again.
start_server cut server && {
    mkfifo "$WORK/cut.in"
    "$BIN/tls-test" "$C" 127.0.0.1 "$PORT" reconnect <"$WORK/cut.in" >"$WORK/scenario-reconnect.out" 2>&1 &
    CLIENT_PID=$!
    exec 7>"$WORK/cut.in"
    for _ in $(seq 100); do grep -q WAITING "$WORK/scenario-reconnect.out" && break; sleep 0.05; done
    kill -9 "$SERVER_PID"
    wait "$SERVER_PID" 2>/dev/null
    "$BIN/tls-server" "$C/ca.pem" "$C/server.pem" "$C/server.key" "$PORT" >"$WORK/cut2.out" 2>&1 &
    SERVER_PID=$!
    for _ in $(seq 100); do grep -q serving "$WORK/cut2.out" && break; sleep 0.05; done
    echo go >&7
    exec 7>&-
    wait "$CLIENT_PID"
    count_lines "$WORK/scenario-reconnect.out"
    stop_server
}

# Stopping TLS contexts (issue 19's rules): in-process peers, no server needed.
scenario stop
scenario callback
scenario sessions
# Callbacks over TLS: the role in the request info; a request answered later.
scenario later
# A CA's certificate presented as a peer's own: named (errno and debug trace).
scenario caaspeer
if grep -q "ERROR TLS handshake: TLS: the peer presented a CA certificate as its own" "$WORK/scenario-caaspeer.out"; then
    ok "caaspeer: the client's debug trace names the reason"
else
    bad "caaspeer: the client's debug trace names the reason" "$(grep 'TLS handshake' "$WORK/scenario-caaspeer.out" | head -n 2)"
fi

# Records cut in the middle, and peers that leave without close_notify
# (c-tests/tls/cut.py): clients of our poll-loop server first, then our client
# against a server that sends half of its answer's record.
start_server cutrecord server && {
    python3 c-tests/tls/cut.py clients "$PORT" "$C" >"$WORK/cut-clients.out" 2>&1 ||
        bad "cut.py clients: exit status" "$(tail -n 3 "$WORK/cut-clients.out")"
    count_lines "$WORK/cut-clients.out"
    if kill -0 "$SERVER_PID" 2>/dev/null; then ok "server alive after records cut mid-way"; else bad "server alive after records cut mid-way" ""; fi
    stop_server
}
python3 c-tests/tls/cut.py server "$C" >"$WORK/cut-server.out" 2>&1 &
CUT_PID=$!
for _ in $(seq 100); do grep -q READY "$WORK/cut-server.out" && break; sleep 0.05; done
PORT=$(sed -n 's/^READY //p' "$WORK/cut-server.out")
if [ -n "$PORT" ]; then
    scenario halfrecord
else
    bad "cut.py server started" "$(cat "$WORK/cut-server.out")"
fi
kill "$CUT_PID" 2>/dev/null
wait "$CUT_PID" 2>/dev/null

# A TLS 1.2 server that refuses the client's certificate while the client is still
# writing its flight, then resets the connection (c-tests/tls/alert_server.py): the
# client's write fails first, yet it reports the server's alert (issue 39, item 12).
# The client certificate "bulky" carries a chain of some 7 MB, more than the client's
# send buffer can hold (at most tcp_wmem's 4 MB), so that the client is still writing.
cp "$C/rogue.key" "$C/bulky.key"
{
    cat "$C/rogue.pem"
    for _ in $(seq 12000); do cat "$C/rogue-ca.pem"; done
} >"$C/bulky.pem"
PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
python3 c-tests/tls/alert_server.py "$C" "$PORT" 20 >"$WORK/alert-server.out" 2>&1 &
ALERT_PID=$!
for _ in $(seq 100); do grep -q READY "$WORK/alert-server.out" && break; sleep 0.05; done
if grep -q READY "$WORK/alert-server.out"; then
    scenario alert 20
    what="alert server: each of 20 alerts sent while the client's flight was arriving"
    if [ "$(grep -c "client's flight arriving, alert sent, reset" "$WORK/alert-server.out")" = 20 ]; then
        ok "$what"
    else
        bad "$what" "$(grep '^#' "$WORK/alert-server.out" | tail -n 3)"
    fi
else
    bad "alert_server.py started" "$(cat "$WORK/alert-server.out")"
fi
kill "$ALERT_PID" 2>/dev/null
wait "$ALERT_PID" 2>/dev/null

# AddressSanitizer on both C programs: an instrumented server that exits by itself
# after its requests (so that the leak checker runs), and the instrumented client's
# scenarios against it.
# (make -C c-tests SAN=address: the group ASAN, one check each.)
if c_build_group ASAN SAN=address; then
    PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
    # operator: 4 requests; reader: 4 served; nocert, rogue: refused before any is
    # served; password: 3 keys accepted, 2 requests each; 1 left for the last client.
    ASAN_OPTIONS=detect_leaks=1 "$ASAN_BIN/tls-server" "$C/ca.pem" "$C/server.pem" "$C/server.key" "$PORT" 15 \
        >"$WORK/asan-server.out" 2>&1 &
    SERVER_PID=$!
    for _ in $(seq 100); do grep -q serving "$WORK/asan-server.out" && break; sleep 0.05; done
    for sc in operator reader nocert rogue password stop callback sessions later; do
        if ASAN_OPTIONS=detect_leaks=1 timeout 60 "$ASAN_BIN/tls-test" "$C" 127.0.0.1 "$PORT" "$sc" \
            >"$WORK/asan-$sc.out" 2>&1 && ! grep -q "Sanitizer" "$WORK/asan-$sc.out"; then
            ok "AddressSanitizer: client scenario $sc"
        else
            bad "AddressSanitizer: client scenario $sc" "$(grep -A3 'Sanitizer\|FAIL' "$WORK/asan-$sc.out" | head -n 8)"
        fi
    done
    # Requests left before the server ends: serve them.
    ASAN_OPTIONS=detect_leaks=1 timeout 60 "$ASAN_BIN/tls-test" "$C" 127.0.0.1 "$PORT" operator >/dev/null 2>&1
    if timeout 30 tail --pid="$SERVER_PID" -f /dev/null; then
        wait "$SERVER_PID"
        rc=$?
        if [ $rc -eq 0 ] && ! grep -q "Sanitizer" "$WORK/asan-server.out"; then
            ok "AddressSanitizer: the example server, exit 0, no error, no leak"
        else
            bad "AddressSanitizer: the example server" "exit $rc: $(grep -A5 Sanitizer "$WORK/asan-server.out" | head -n 10)"
        fi
    else
        bad "AddressSanitizer: the example server ended after its requests" "still running"
        stop_server
    fi
fi

# Interoperability with pymodbus (mutual TLS), both directions, IPv4 and IPv6: a
# pymodbus client against our server (every libmodbus function code; a reader's
# writes refused), our client against a pymodbus server.
if pymodbus_venv "$ROOT/target/interop/venv" "$ROOT/c-tests/interop/requirements.txt" "$WORK" 1 >"$WORK/venv-setup.log" 2>&1; then
    ok "pymodbus $("$PY" -c 'import pymodbus; print(pymodbus.__version__)') in target/interop/venv"
    # pm_check NAME CMD...: every ok/FAIL line of a pymodbus run counts
    pm_check() {
        local name=$1
        shift
        timeout 60 "$@" >"$WORK/$name.out" 2>&1
        local rc=$?
        count_lines "$WORK/$name.out" "$name"
        [ $rc -eq 0 ] || bad "$name: exit status" "$rc: $(tail -n 3 "$WORK/$name.out")"
    }
    for fam in 127.0.0.1 ::1; do
        start_server "pm-$fam" server || continue
        kill "$SERVER_PID"
        wait "$SERVER_PID" 2>/dev/null
        "$BIN/tls-server" "$C/ca.pem" "$C/server.pem" "$C/server.key" "$PORT" 0 "$fam" >"$WORK/pm-$fam.out" 2>&1 &
        SERVER_PID=$!
        for _ in $(seq 100); do grep -q serving "$WORK/pm-$fam.out" && break; sleep 0.05; done
        pm_check "pymodbus client (reader) -> our server [$fam]" "$PY" c-tests/tls/pm_tls.py client "$fam" "$PORT" "$C" reader
        pm_check "pymodbus client (operator) -> our server [$fam]" "$PY" c-tests/tls/pm_tls.py client "$fam" "$PORT" "$C" operator
        stop_server
        # Our client against a pymodbus TLS server.
        PORT=$(python3 -c 'import socket; s=socket.socket(socket.AF_INET6 if ":" in "'"$fam"'" else socket.AF_INET); s.bind(("'"$fam"'",0)); print(s.getsockname()[1])')
        "$PY" c-tests/tls/pm_tls.py server "$fam" "$PORT" "$C" >"$WORK/pmserver-$fam.out" 2>&1 &
        PM_PID=$!
        for _ in $(seq 200); do grep -q READY "$WORK/pmserver-$fam.out" && break; sleep 0.05; done
        HOST=$fam scenario operator
        kill "$PM_PID" 2>/dev/null
        wait "$PM_PID" 2>/dev/null
    done
else
    bad "pymodbus for the interoperability checks" "$(tail -n 5 "$WORK/venv-setup.log")"
fi

# Every cipher suite of TLS 1.2 and 1.3 against OpenSSL, both ways: our server under
# openssl s_client (over TLS 1.3 with a key update asked between two requests), our
# client (examples/tls-client.c: reads registers 0-4, writes one) against a server of
# Python's ssl (over TLS 1.3 OpenSSL sends its session tickets after the handshake).
start_server suites server && {
    c-tests/tls/suites.sh "$C" "$PORT" >"$WORK/suites-server.out" 2>&1
    count_lines "$WORK/suites-server.out" "our server, openssl s_client"
    stop_server
}
for suite in "1.2 ECDHE-ECDSA-AES128-GCM-SHA256" "1.2 ECDHE-ECDSA-AES256-GCM-SHA384" \
    "1.2 ECDHE-ECDSA-CHACHA20-POLY1305" "1.3"; do
    read -r version cipher <<<"$suite"
    out=$WORK/suites-client-${cipher:-1.3}
    python3 c-tests/tls/suite_server.py "$C" "$version" ${cipher:+"$cipher"} >"$out.server" 2>&1 &
    suite_pid=$!
    for _ in $(seq 100); do [ -s "$out.server" ] && break; sleep 0.05; done
    timeout 20 "$BIN/tls-client" "$C/ca.pem" "$C/operator.pem" "$C/operator.key" 127.0.0.1 "$(head -n 1 "$out.server")" \
        >"$out" 2>&1
    wait "$suite_pid"
    name="our client, TLS $version ${cipher:-(the suite OpenSSL picks)} against the ssl module of Python"
    if grep -q "registers 0-4: 0 1 2 3 4" "$out" && grep -q "write allowed" "$out" &&
        grep -q "served TLSv$version .*: 2 requests" "$out.server"; then
        ok "$name: read and write answered ($(tail -n 1 "$out.server"))"
    else
        bad "$name: read and write answered" "$(cat "$out" "$out.server" | tail -n 4)"
    fi
done
summary
