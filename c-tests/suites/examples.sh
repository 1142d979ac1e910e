#!/usr/bin/env bash
# examples.sh: compiles the programs of examples/ (the TLS ones: tls.sh) against the built
# library (through target/release/libmodbus-uninstalled.pc, -Wall -Wextra -Werror)
# and runs each against a peer, checking what they print and their exit codes:
#   - tcp-client against tcp-server on loopback, then three clients at once against
#     one server (its poll() loop), then a client built on Debian's libmodbus 3.1.6
#     against our server and ours against a server built on Debian's;
#   - poll-many (12 devices from one thread, 3 cycles) against tcp-server;
#   - rtu-client against rtu-server over a pty pair (socat), and a client asking the
#     wrong slave id (it must time out); then against server-callbacks (three units
#     through callbacks), units 17 and 18, and unit 20 (not served: a timeout);
#   - tcp-client linked statically with libmodbus.a (pkg-config --static), and
#     fully static (gcc -static); the README's sizes of the first, stripped, and of
#     the stripped archive.
# Every process started here is stopped by its PID. Ends with "N passed, M failed".
# Usage: c-tests/suites/examples.sh   (builds with `cargo build --release` first)
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 1
ROOT=$PWD
WORK=$ROOT/target/check-examples
rm -rf "$WORK"
mkdir -p "$WORK"
# shellcheck source=c-tests/common/testlib.sh
. c-tests/common/testlib.sh

CC=${CC:-gcc}
CFLAGS_W=(-Wall -Wextra -Werror -O2)
LIB=$ROOT/target/release

if ! cargo build --release --quiet; then
    bad "cargo build --release"
    summary
    exit 1
fi
export PKG_CONFIG_PATH=$LIB
PC=libmodbus-uninstalled

# --- build --------------------------------------------------------------------
for prog in tcp-client tcp-server rtu-client rtu-server poll-many server-callbacks; do
    # shellcheck disable=SC2046
    check "compile $prog against the build tree" \
        "$CC" "${CFLAGS_W[@]}" "examples/$prog.c" -o "$WORK/$prog" \
        $(pkg-config --cflags --libs "$PC") -Wl,-rpath,"$LIB"
done
loaded=$(ldd "$WORK/tcp-client" 2>/dev/null | awk '/libmodbus\.so\.5/ {print $3}')
if [ "$(readlink -f "$loaded")" = "$(readlink -f "$LIB/libmodbus.so")" ]; then
    ok "tcp-client loads target/release/libmodbus.so ($loaded)"
else
    bad "tcp-client loads target/release/libmodbus.so" "ldd says: $loaded"
fi

# Same programs on Debian's libmodbus (the cross-implementation pairs).
have_debian=0
if pkg-config --exists libmodbus 2>/dev/null && [ -e /usr/include/modbus/modbus.h ]; then
    have_debian=1
    for prog in tcp-client tcp-server; do
        PKG_CONFIG_PATH='' check "compile $prog against Debian's libmodbus" \
            "$CC" -Wall -Wextra -O2 "examples/$prog.c" -o "$WORK/$prog-debian" \
            -I/usr/include/modbus -lmodbus
    done
fi

# tcp_pair NAME SERVER CLIENT: server for 5 requests, client, check both outputs.
tcp_pair() {
    local name=$1 server=$2 client=$3 port
    if [ ! -x "$server" ] || [ ! -x "$client" ]; then
        bad "$name: not run, a program did not build"
        return
    fi
    port=$(free_port)
    start "$name-server" "$server" "$port" 5
    if ! wait_ready "$name-server" "serving on" 10; then
        bad "$name: server starts" "$(cat "$WORK/$name-server.log")"
        stop "$name-server"
        return
    fi
    start "$name-client" "$client" 127.0.0.1 "$port"
    wait_exit "$name-client" 20
    local crc=$rc
    wait_exit "$name-server" 10
    local src=$rc
    [ "$crc" -eq 0 ] && ok "$name: client exits 0" || bad "$name: client exits 0" "exit $crc" "$(tail -n 5 "$WORK/$name-client.log")"
    [ "$src" -eq 0 ] && ok "$name: server exits 0 after 5 requests" || bad "$name: server exits 0 after 5 requests" "exit $src"
    local log=$WORK/$name-client.log
    expect_line "$name: registers read back" "$log" \
        "registers 0..9: 0x1234 0xBEEF 0x002A 0x03EB 0x03EC 0x03ED 0x03EE 0x03EF 0x03F0 0x03F1"
    expect_line "$name: coils read back" "$log" "coils 0..7: 0 0 0 1 0 0 0 0"
    expect_line "$name: exception reported as errno" "$log" "read at 9999: rc=-1 (Illegal data address)"
    expect_line "$name: debug trace of the first request" "$log" \
        "[00][01][00][00][00][0D][FF][10][00][00][00][03][06][12][34][BE][EF][00][2A]"
    expect_line "$name: server summary" "$WORK/$name-server.log" "server done after 5 requests"
}

# --- TCP ----------------------------------------------------------------------
tcp_pair tcp "$WORK/tcp-server" "$WORK/tcp-client"

# Several clients at once on one server (its poll loop): 3 x 5 requests.
port=$(free_port)
start multi-server "$WORK/tcp-server" "$port" 15
if wait_ready multi-server "serving on" 10; then
    for i in 1 2 3; do start "multi-client$i" "$WORK/tcp-client" 127.0.0.1 "$port"; done
    for i in 1 2 3; do
        wait_exit "multi-client$i" 20
        if [ "$rc" -eq 0 ] && grep -qxF "client done" "$WORK/multi-client$i.log"; then
            ok "3 clients at once: client $i served"
        else
            bad "3 clients at once: client $i served" "exit $rc" "$(tail -n 5 "$WORK/multi-client$i.log")"
        fi
    done
    wait_exit multi-server 10
    expect_line "3 clients at once: server answered 15 requests" "$WORK/multi-server.log" \
        "server done after 15 requests"
else
    bad "3 clients at once: server starts" "$(cat "$WORK/multi-server.log")"
    stop multi-server
fi

# Many devices from one thread (poll-many: the event-driven client and a multi
# handle): 12 connections to the server's poll loop, 3 cycles of one read each.
port=$(free_port)
start many-server "$WORK/tcp-server" "$port" 36
if wait_ready many-server "serving on" 10; then
    start poll-many "$WORK/poll-many" 127.0.0.1 "$port" 12 3
    wait_exit poll-many 30
    [ "$rc" -eq 0 ] && ok "poll-many: exits 0" || bad "poll-many: exits 0" "exit $rc" "$(tail -n 5 "$WORK/poll-many.log")"
    expect_line "poll-many: 12 devices x 3 cycles, all read" "$WORK/poll-many.log" "36 reads: 36 ok, 0 failed"
    wait_exit many-server 10
    expect_line "poll-many: the server answered 36 requests" "$WORK/many-server.log" "server done after 36 requests"
else
    bad "poll-many: server starts" "$(cat "$WORK/many-server.log")"
    stop many-server
fi

if [ "$have_debian" = 1 ]; then
    tcp_pair debian-client "$WORK/tcp-server" "$WORK/tcp-client-debian"
    tcp_pair debian-server "$WORK/tcp-server-debian" "$WORK/tcp-client"
fi

# --- RTU over a pty pair --------------------------------------------------------
if pty_pair pty "$WORK/ttyS" "$WORK/ttyC"; then
    ok "socat pty pair"
    start rtu-server "$WORK/rtu-server" "$WORK/ttyS" 17 19200 E
    if wait_ready rtu-server "serving slave 17" 10; then
        start rtu-client "$WORK/rtu-client" "$WORK/ttyC" 17 19200 E
        wait_exit rtu-client 30
        log=$WORK/rtu-client.log
        [ "$rc" -eq 0 ] && ok "rtu: client exits 0" || bad "rtu: client exits 0" "exit $rc" "$(tail -n 5 "$log")"
        expect_line "rtu: registers read back" "$log" \
            "registers 0..9: 0x1234 0xBEEF 0x002A 0x03EB 0x03EC 0x03ED 0x03EE 0x03EF 0x03F0 0x03F1"
        expect_line "rtu: input registers" "$log" "input registers 0..3: 2000 2001 2002 2003"
        expect_line "rtu: coils read back" "$log" "coils 0..7: 0 0 0 1 0 0 0 0"
        expect_line "rtu: float round trip" "$log" "float at 20: 21.50 (0x41AC 0x0000)"
        expect_line "rtu: exception reported as errno" "$log" "read at 9999: rc=-1 (Illegal data address)"
        expect_line "rtu: debug trace with CRC" "$log" "[11][03][00][00][00][0A][C7][5D]"
        # A request for another slave id gets no answer: the client times out (1 s).
        start rtu-wrong "$WORK/rtu-client" "$WORK/ttyC" 18 19200 E
        wait_exit rtu-wrong 20
        if [ "$rc" -ne 0 ] && grep -qxF "write_registers failed: Connection timed out" "$WORK/rtu-wrong.log"; then
            ok "rtu: a request for slave 18 times out (exit $rc)"
        else
            bad "rtu: a request for slave 18 times out" "exit $rc" "$(tail -n 5 "$WORK/rtu-wrong.log")"
        fi
    else
        bad "rtu: server starts" "$(cat "$WORK/rtu-server.log")"
    fi
    stop rtu-server
    stop pty
else
    bad "socat pty pair" "socat did not create $WORK/ttyS and $WORK/ttyC"
fi

# Three units on one line through callbacks (server-callbacks): two of them answer
# rtu-client with their own data, a fourth unit gets no answer. (A pty pair of its
# own: socat ends a pair when the first server closes its end.)
if pty_pair cbpty "$WORK/ttyS2" "$WORK/ttyC2"; then
    start cb-server "$WORK/server-callbacks" "$WORK/ttyS2" 19200 E 16
    if wait_ready cb-server "serving units 17, 18, 19" 10; then
        for unit in 17 18; do
            start "cb-client$unit" "$WORK/rtu-client" "$WORK/ttyC2" "$unit" 19200 E
            wait_exit "cb-client$unit" 30
            log=$WORK/cb-client$unit.log
            [ "$rc" -eq 0 ] && ok "callbacks: unit $unit client exits 0" ||
                bad "callbacks: unit $unit client exits 0" "exit $rc" "$(tail -n 5 "$log")"
            expect_line "callbacks: unit $unit registers read back" "$log" \
                "registers 0..9: 0x1234 0xBEEF 0x002A 0x03EB 0x03EC 0x03ED 0x03EE 0x03EF 0x03F0 0x03F1"
            expect_line "callbacks: unit $unit input registers" "$log" "input registers 0..3: 2000 2001 2002 2003"
            expect_line "callbacks: unit $unit exception reported as errno" "$log" \
                "read at 9999: rc=-1 (Illegal data address)"
        done
        start cb-wrong "$WORK/rtu-client" "$WORK/ttyC2" 20 19200 E
        wait_exit cb-wrong 20
        if [ "$rc" -ne 0 ] && grep -qxF "write_registers failed: Connection timed out" "$WORK/cb-wrong.log"; then
            ok "callbacks: unit 20, not served, times out (exit $rc)"
        else
            bad "callbacks: unit 20, not served, times out" "exit $rc" "$(tail -n 5 "$WORK/cb-wrong.log")"
        fi
        wait_exit cb-server 20
        expect_line "callbacks: unit 17 answered its 8 requests" "$WORK/cb-server.log" "unit 17: 8 requests"
        expect_line "callbacks: unit 18 answered its 8 requests" "$WORK/cb-server.log" "unit 18: 8 requests"
        expect_line "callbacks: unit 19 got none" "$WORK/cb-server.log" "unit 19: 0 requests"
    else
        bad "callbacks: server starts" "$(cat "$WORK/cb-server.log")"
    fi
    stop cb-server
    stop cbpty
else
    bad "socat pty pair for server-callbacks" "socat did not create $WORK/ttyS2 and $WORK/ttyC2"
fi

# --- static -------------------------------------------------------------------
# libmodbus.a inside the executable; the C library stays shared.
# shellcheck disable=SC2046
check "compile tcp-client statically with libmodbus.a (pkg-config --static)" \
    "$CC" "${CFLAGS_W[@]}" examples/tcp-client.c -o "$WORK/tcp-client-static" \
    $(pkg-config --cflags "$PC") -Wl,--gc-sections -Wl,-Bstatic -lmodbus -Wl,-Bdynamic \
    -Wl,--as-needed $(pkg-config --static --libs "$PC")
if [ -x "$WORK/tcp-client-static" ]; then
    if grep -q 'NEEDED.*libmodbus' <<<"$(readelf -d "$WORK/tcp-client-static")"; then
        bad "static tcp-client does not need libmodbus.so.5" "$(readelf -d "$WORK/tcp-client-static" | grep NEEDED)"
    else
        ok "static tcp-client does not need libmodbus.so.5"
    fi
    tcp_pair static "$WORK/tcp-server" "$WORK/tcp-client-static"
fi

# The README's sizes ("`examples/tcp-client`: about N MB stripped; the installed, stripped
# archive is about M MB"), each within 25% of what this build gives: the static
# tcp-client stripped, and libmodbus.a stripped as scripts/install.sh strips it.
readme_size() { # phrase-before-the-number
    grep -o "$1 [0-9.]* MB" README.md | head -n 1 | grep -o '[0-9.]* MB' | cut -d' ' -f1
}
size_near() { # what readme-MB file
    local what=$1 mb=$2 file=$3 got
    got=$(stat -c %s "$file" 2>/dev/null) || { bad "README's size of $what" "no $file"; return; }
    if [ -n "$mb" ] && awk -v g="$got" -v m="$mb" 'BEGIN { r = g / (m * 1e6); exit !(r > 0.75 && r < 1.25) }'; then
        ok "README's size of $what (about $mb MB): $got bytes"
    else
        bad "README's size of $what" "README.md: about ${mb:-(no figure found)} MB" "this build:  $got bytes"
    fi
}
if [ -x "$WORK/tcp-client-static" ] && strip -o "$WORK/tcp-client-static.stripped" "$WORK/tcp-client-static"; then
    size_near "the static tcp-client, stripped" "$(readme_size '`examples/tcp-client`: about')" \
        "$WORK/tcp-client-static.stripped"
fi
if strip --strip-debug --remove-section=.llvmbc --remove-section=.llvmcmd --remove-section=.comment \
    -o "$WORK/libmodbus.a" "$LIB/libmodbus.a"; then
    size_near "the installed libmodbus.a" "$(readme_size 'stripped archive is about')" "$WORK/libmodbus.a"
fi

# A fully static executable (gcc -static): libc too comes from its archive.
check "compile tcp-client fully static (gcc -static)" \
    "$CC" "${CFLAGS_W[@]}" -static examples/tcp-client.c -o "$WORK/tcp-client-full-static" \
    $(pkg-config --cflags "$PC") -Wl,--gc-sections -lmodbus $(pkg-config --static --libs "$PC" | sed 's/-lgcc_s//')
if [ -x "$WORK/tcp-client-full-static" ]; then
    if grep -q NEEDED <<<"$(readelf -d "$WORK/tcp-client-full-static" 2>/dev/null)"; then
        bad "fully static tcp-client needs no shared library" "$(readelf -d "$WORK/tcp-client-full-static" | grep NEEDED)"
    else
        ok "fully static tcp-client needs no shared library"
    fi
    tcp_pair full-static "$WORK/tcp-server" "$WORK/tcp-client-full-static"
fi

summary
