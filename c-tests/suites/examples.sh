#!/usr/bin/env bash
# examples.sh: compiles the programs of examples/ (the TLS ones: tls.sh) against the built
# library (through target/release/libmodbus-uninstalled.pc, -Wall -Wextra -Werror)
# and runs each against a peer, checking what they print and their exit codes:
#   - tcp-client against tcp-server on loopback, then three clients at once against
#     one server (its poll() loop), then a client built on Debian's libmodbus 3.1.6
#     against our server and ours against a server built on Debian's;
#   - poll-many (12 devices from one thread, 3 cycles) against tcp-server, and at 100
#     and 1,000 devices against runner-server (the README's pair: every read right);
#   - `make -C examples` (examples/Makefile) builds every example, and every example
#     has a build line in its header;
#   - rtu-client against rtu-server over a pty pair (socat), and a client asking the
#     wrong slave id (it must time out); then against server-callbacks (three units
#     through callbacks), units 17 and 18, and unit 20 (not served: a timeout);
#   - tcp-client linked statically with libmodbus.a (pkg-config --static), and
#     fully static (gcc -static); the README's sizes of the first, stripped, and of
#     the stripped archive;
#   - scripts/install.sh into a scratch --prefix (and --destdir, --gateway): every file a
#     package installs, the manifest lists exactly the files installed, the installed
#     libmodbus.pc builds a program, `man -M` finds our pages there; --uninstall leaves
#     the file list exactly as before; --check-shadow on /usr/local/lib warns when the
#     loader's path puts it before an installed libmodbus.so.5;
#   - README.md's fenced blocks, each run as written by the shell its fence names (sh:
#     dash, bash: bash), in the checkout or in a scratch directory, with their output
#     checked; the ones that cannot run here (root, /usr, a serial device, a .deb, the
#     whole test run) are listed as skipped with the reason; a block the suite does not
#     know fails (a new block needs a row in readme_block).
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

# The README's pair: runner-server (modbus_server_new) and poll-many at 100 and 1,000
# devices, 3 cycles each; every read right.
for prog in runner-server; do
    # shellcheck disable=SC2046
    check "compile $prog against the build tree" \
        "$CC" "${CFLAGS_W[@]}" "examples/$prog.c" -o "$WORK/$prog" \
        $(pkg-config --cflags --libs "$PC") -Wl,-rpath,"$LIB"
done
port=$(free_port)
start runner "$WORK/runner-server" "$port"
if wait_ready runner "serving on 127.0.0.1:$port" 10; then
    for n in 100 1000; do
        start "poll-many-$n" "$WORK/poll-many" 127.0.0.1 "$port" "$n" 3
        wait_exit "poll-many-$n" 120
        [ "$rc" -eq 0 ] && ok "poll-many, $n devices against runner-server: exits 0" ||
            bad "poll-many, $n devices against runner-server: exits 0" "exit $rc" "$(tail -n 5 "$WORK/poll-many-$n.log")"
        expect_line "poll-many, $n devices x 3 cycles against runner-server: every read right" \
            "$WORK/poll-many-$n.log" "$((n * 3)) reads: $((n * 3)) ok, 0 failed"
    done
    stop runner
    expect_line "runner-server stops on SIGTERM" "$WORK/runner.log" "server stopped"
else
    bad "runner-server starts" "$(cat "$WORK/runner.log")"
    stop runner
fi

# examples/Makefile builds every example; every example has its build line.
if make -s -C examples clean >/dev/null && make -s -C examples CFLAGS="${CFLAGS_W[*]}" >"$WORK/make.log" 2>&1; then
    ok "make -C examples builds every example ($(make -s -C examples -p 2>/dev/null | sed -n 's/^PROGRAMS = //p' | wc -w) programs, -Werror)"
else
    bad "make -C examples builds every example" "$(tail -n 20 "$WORK/make.log")"
fi
missing=()
for f in examples/*.c; do
    prog=$(basename "$f" .c)
    grep -qF "gcc $prog.c -o $prog \$(pkg-config --cflags --libs libmodbus)" "$f" || missing+=("$f: no build line")
    [ -x "examples/$prog" ] || missing+=("examples/$prog: not built by make -C examples")
done
[ ${#missing[@]} -eq 0 ] && ok "every example has a build line and a make target" ||
    bad "every example has a build line and a make target" "${missing[@]}"

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


# --- scripts/install.sh and --uninstall ------------------------------------------
# Into a scratch root (--destdir, --prefix=/usr/local, --gateway), then a scratch prefix
# without --destdir (what a user's --prefix=$HOME/.local is): every file the packages
# install, the manifest, and after --uninstall the file list exactly as it was.
list_tree() { (cd "$1" && find . -printf '%y %m %p\n' | sort); }
IR=$WORK/install-root
mkdir -p "$IR/usr/local/lib" "$IR/etc"
echo keep >"$IR/usr/local/lib/unrelated.so"
list_tree "$IR" >"$WORK/install-before.txt"
if scripts/install.sh --no-build --destdir="$IR" --prefix=/usr/local --gateway >"$WORK/install.log" 2>&1; then
    ok "install.sh --destdir --prefix=/usr/local --gateway"
    begin "install.sh installs what the packages install"
    for f in lib/libmodbus.so.5.1.0 lib/libmodbus.so.5 lib/libmodbus.so lib/libmodbus.a lib/pkgconfig/libmodbus.pc \
        include/modbus/modbus.h include/modbus/modbus-rtu.h include/modbus/modbus-tcp.h include/modbus/modbus-tls.h \
        include/modbus/modbus-version.h share/man/man3/modbus_new_tcp_tls.3 share/man/man3/modbus_read_registers.3 \
        share/man/man7/libmodbus.7 share/man/man7/rsmodbus.7 share/man/man8/rsmodbus-gateway.8 bin/rsmodbus-gateway \
        lib/systemd/system/rsmodbus-gateway@.service share/rsmodbus/install-manifest.txt; do
        [ -e "$IR/usr/local/$f" ] || err "missing: /usr/local/$f"
    done
    npages=$(ls target/man/man3 | wc -l)
    [ "$(ls "$IR/usr/local/share/man/man3" | wc -l)" = "$npages" ] || err "not the $npages section-3 pages"
    grep -q '^ExecStart=/usr/local/bin/rsmodbus-gateway' "$IR/usr/local/lib/systemd/system/rsmodbus-gateway@.service" ||
        err "the unit's ExecStart does not name /usr/local/bin"
    end "$(grep -vc -e '^#' -e '/$' "$IR/usr/local/share/rsmodbus/install-manifest.txt") files"
    # The manifest lists exactly what appeared (files and links; directories as DIR/).
    (cd "$IR" && find . ! -type d -printf '/%P\n' | sort) | grep -vx -e /usr/local/lib/unrelated.so \
        -e /usr/local/share/rsmodbus/install-manifest.txt >"$WORK/installed.txt"
    grep -v -e '^#' -e '/$' "$IR/usr/local/share/rsmodbus/install-manifest.txt" | sort >"$WORK/manifest-files.txt"
    if diff -u "$WORK/installed.txt" "$WORK/manifest-files.txt" >"$WORK/manifest.diff"; then
        ok "the manifest lists every file installed, and nothing else"
    else
        bad "the manifest lists every file installed, and nothing else" "$(head -n 20 "$WORK/manifest.diff")"
    fi
    scripts/install.sh --uninstall --destdir="$IR" --prefix=/usr/local >"$WORK/uninstall.log" 2>&1
    list_tree "$IR" >"$WORK/install-after.txt"
    if diff -u "$WORK/install-before.txt" "$WORK/install-after.txt" >"$WORK/uninstall.diff"; then
        ok "install.sh --uninstall leaves the tree exactly as before ($(cat "$WORK/uninstall.log"))"
    else
        bad "install.sh --uninstall leaves the tree exactly as before" "$(head -n 30 "$WORK/uninstall.diff")"
    fi
else
    bad "install.sh --destdir --prefix=/usr/local --gateway" "$(tail -n 20 "$WORK/install.log")"
fi

# A user's prefix (no --destdir): the installed .pc builds a program, man -M finds our
# pages there; installed twice (one manifest), then removed: the scratch dir as before.
UP=$WORK/prefix
mkdir -p "$UP"
list_tree "$UP" >"$WORK/prefix-before.txt"
if scripts/install.sh --no-build --prefix="$UP" >"$WORK/install-prefix.log" 2>&1 &&
    scripts/install.sh --no-build --prefix="$UP" >>"$WORK/install-prefix.log" 2>&1; then
    ok "install.sh --prefix=DIR, twice"
    # shellcheck disable=SC2046
    if PKG_CONFIG_PATH=$UP/lib/pkgconfig "$CC" "${CFLAGS_W[@]}" examples/tcp-client.c -o "$WORK/tcp-client-installed" \
        $(PKG_CONFIG_PATH=$UP/lib/pkgconfig pkg-config --cflags --libs libmodbus) -Wl,-rpath,"$UP/lib" 2>"$WORK/installed-cc.log" &&
        [ "$(ldd "$WORK/tcp-client-installed" | awk '/libmodbus\.so\.5/ {print $3}')" = "$UP/lib/libmodbus.so.5" ]; then
        ok "the installed libmodbus.pc builds tcp-client, which loads PREFIX/lib/libmodbus.so.5"
    else
        bad "the installed libmodbus.pc builds tcp-client" "$(cat "$WORK/installed-cc.log")"
    fi
    out=$(MANWIDTH=80 man -M "$UP/share/man" -P cat modbus_new_tcp_tls 2>&1)
    if grep -q 'modbus_new_tcp_tls' <<<"$out" && grep -q 'rsmodbus' <<<"$(head -n 1 <<<"$out")$(tail -n 1 <<<"$out")"; then
        ok "man -M PREFIX/share/man modbus_new_tcp_tls: our page, \"rsmodbus\" in its header and footer"
    else
        bad "man -M PREFIX/share/man modbus_new_tcp_tls" "${out:0:600}"
    fi
    scripts/install.sh --uninstall --prefix="$UP" >"$WORK/uninstall-prefix.log" 2>&1
    list_tree "$UP" >"$WORK/prefix-after.txt"
    if diff -u "$WORK/prefix-before.txt" "$WORK/prefix-after.txt" >"$WORK/uninstall-prefix.diff"; then
        ok "install.sh --uninstall --prefix=DIR: as before ($(cat "$WORK/uninstall-prefix.log"))"
    else
        bad "install.sh --uninstall --prefix=DIR: as before" "$(head -n 30 "$WORK/uninstall-prefix.diff")"
    fi
else
    bad "install.sh --prefix=DIR" "$(tail -n 20 "$WORK/install-prefix.log")"
fi

# The shadowing warning: /usr/local/lib before the directory of an installed
# libmodbus.so.5 in the loader's search path (Debian's libmodbus5, the tests' oracle).
shadow_out=$(scripts/install.sh --check-shadow --libdir=/usr/local/lib 2>&1)
shadow_rc=$?
sys_so5=$(ldconfig -p 2>/dev/null | awk '$1 == "libmodbus.so.5" && $NF !~ /^\/usr\/local\// { print $NF; exit }')
local_first=$(ldconfig -v -N -X 2>/dev/null | sed -n 's/^\([^[:space:]][^:]*\):.*/\1/p' | grep -nx /usr/local/lib | cut -d: -f1)
if [ -n "$sys_so5" ] && [ -n "$local_first" ]; then
    if [ "$shadow_rc" -ne 0 ] && grep -q "takes over from the system's $sys_so5" <<<"$shadow_out"; then
        ok "install.sh --check-shadow: /usr/local/lib would take over from $sys_so5 (warned)"
    else
        bad "install.sh --check-shadow warns about $sys_so5" "exit $shadow_rc" "$shadow_out"
    fi
else
    ok "install.sh --check-shadow: nothing to shadow here (exit $shadow_rc)"
fi
if [ "$(scripts/install.sh --check-shadow --prefix="$UP" 2>&1 >/dev/null)" = "" ]; then
    ok "install.sh --check-shadow: a prefix outside the loader's path shadows nothing"
else
    bad "install.sh --check-shadow: a prefix outside the loader's path shadows nothing"
fi

# --- README.md's commands ----------------------------------------------------------
# Each fenced block of README.md, as written, by the shell its fence names, in the
# checkout (ROOT) or in a scratch directory; what cannot run here is skipped, saying why.
# readme_block FIRST-LINE: sets how (root, scratch, skip) and why / what to check.
readme_block() {
    how=skip why='' want=''
    case $1 in
    scripts/demo.sh) how=root want='== server: server done after 5 requests' ;;
    scripts/test-all.sh) why='the whole test run (it runs this suite)' ;;
    'openssl genpkey'*) how=scratch want='' ;;
    'cargo build --release       # target/release/rsmodbus-gateway'*)
        why='needs a serial line at /dev/ttyUSB0 (the gateway suite runs the gateway on ptys)' ;;
    scripts/install-deps.sh*) why='as root: apt installs packages into /usr (test-all runs it)' ;;
    scripts/build-pgo.sh*) why='the profile-guided build (the pgo-build suite) and an install into /usr/local' ;;
    'dpkg -x target/debian'*) why='needs the .deb scripts/build-deb.sh makes (the package suite); your-program is a placeholder' ;;
    'gcc app.c -o app $(pkg-config --cflags --libs libmodbus)') how=installed ;;
    'gcc app.c -o app $(pkg-config --cflags libmodbus) -Wl,--gc-sections'*) how=installed ;;
    'cargo build --release && make -C examples') how=root want=$'[1]: \t1000' ;;
    'python3 man/gen-man.py --out target/man') how=root want='modbus_new_tcp_tls' ;;
    'make -C examples') how=root want='3000 reads: 3000 ok, 0 failed' ;;
    'socat pty,raw'*) how=root want='client done' ;;
    'cargo build --release')
        if grep -q '^export PKG_CONFIG_PATH=' "$2"; then
            how=scratch-root want=''
        else
            why='installs into /usr/local for the whole system (checked above in a scratch root and prefix)'
        fi ;;
    *) how=unknown ;;
    esac
}
RB=$WORK/readme
mkdir -p "$RB"
python3 - "$RB" <<'PYEOF'
import re, sys, os
out = sys.argv[1]
lines = open("README.md", encoding="utf-8").read().split("\n")
n, i = 0, 0
while i < len(lines):
    m = re.match(r"^```(\S*)\s*$", lines[i])
    if m and m.group(1):
        j = i + 1
        while not lines[j].startswith("```"):
            j += 1
        n += 1
        with open(os.path.join(out, "%02d.%s" % (n, m.group(1))), "w") as f:
            f.write("\n".join(lines[i + 1:j]) + "\n")
        with open(os.path.join(out, "%02d.line" % n), "w") as f:
            f.write("%d\n" % (i + 1))
        i = j
    i += 1
PYEOF
# app.c: what the README's compile lines build (tcp-client, the paired example).
cp examples/tcp-client.c "$RB/app.c"
# The installed prefix the "installed" blocks compile against (pkg-config libmodbus).
RP=$WORK/readme-prefix
scripts/install.sh --no-build --no-manifest --prefix="$RP" >"$RB/install.log" 2>&1 || bad "install.sh --prefix for the README's blocks"
# The README's servers listen on 127.0.0.1:1502, as written. A block that names the port
# runs in a network namespace of its own (unshare -n, its loopback brought up), so that
# the port is its own and no other program's: not taken by one, and taking none. Where
# that cannot be done (not root), the block waits while another program has the port.
own_net=()
if unshare -n sh -c 'ip link set lo up' 2>/dev/null; then
    own_net=(unshare -n sh -c 'ip link set lo up && exec "$@"' own-net)
fi
wait_for_1502() {
    for ((i = 0; i < 300; i++)); do
        ss -Hltn 'sport = :1502' 2>/dev/null | grep -q . || return 0
        sleep 0.2
    done
}
# With namespaces, 127.0.0.1:1502 is held outside them while the blocks run (unless
# another program holds it already): a block that ran outside its namespace would find
# the port taken and fail.
holder=
if [ ${#own_net[@]} -gt 0 ]; then
    python3 -c 'import socket, sys, time
s = socket.socket()
try:
    s.bind(("127.0.0.1", 1502))
except OSError:
    sys.exit(0)
s.listen(1)
print("held", flush=True)
time.sleep(3600)' >"$RB/holder.out" 2>&1 &
    holder=$!
    for ((i = 0; i < 50; i++)); do
        grep -q held "$RB/holder.out" && break
        kill -0 "$holder" 2>/dev/null || break
        sleep 0.1
    done
fi
for block in "$RB"/[0-9][0-9].*; do
    case $block in *.line | *.out) continue ;; esac
    lang=${block##*.}
    base=$(basename "$block" ".$lang")
    line=$(cat "$RB/$base.line")
    first=$(head -n 1 "$block")
    readme_block "$first" "$block"
    name="README.md:$line ($lang): ${first:0:60}"
    case $lang in sh) shell=sh ;; bash) shell=bash ;; c) shell='' ;; *) how=unknown ;; esac
    if [ "$how" = unknown ]; then
        bad "$name: a block the suite knows (add it to readme_block)" "$(cat "$block")"
        continue
    fi
    if [ "$how" = skip ]; then
        echo "skip - $name: $why"
        continue
    fi
    dir=$ROOT env=()
    case $how in
    scratch) dir=$RB/run-$base ;;
    installed) dir=$RB/run-$base; env=(PKG_CONFIG_PATH="$RP/lib/pkgconfig") ;;
    scratch-root)
        # The build tree's lines ($PWD/target/release) from the checkout, app.c put there
        # for the block and removed after it.
        cp "$RB/app.c" "$ROOT/app.c" ;;
    esac
    mkdir -p "$dir"
    [ "$how" != scratch ] && [ "$how" != installed ] || cp "$RB/app.c" "$dir/"
    out=$RB/$base.out
    net=()
    if grep -q 1502 "$block"; then
        net=("${own_net[@]}")
        [ ${#net[@]} -gt 0 ] || wait_for_1502
    fi
    # Its own session: what the block leaves running is found by the session id (every
    # step to the block's shell is an exec, so its PID is the subshell's).
    (cd "$dir" && exec env "${env[@]}" "${net[@]}" setsid "$shell" "$block" >"$out" 2>&1) &
    bpid=$!
    start_s=$SECONDS
    while kill -0 "$bpid" 2>/dev/null && [ $((SECONDS - start_s)) -lt 600 ]; do sleep 0.2; done
    if kill -0 "$bpid" 2>/dev/null; then
        echo "(timed out after 600 s)" >>"$out"
    fi
    # setsid made the block's shell (bpid) a session leader: the session's id is its PID.
    # What the block left running in it is stopped by PID after it.
    left=$(session_pids "$bpid" | grep -vx "$bpid" | tr '\n' ' ')
    kill "$bpid" 2>/dev/null
    wait "$bpid"
    brc=$?
    for p in $left; do kill "$p" 2>/dev/null; done
    if [ "$how" = scratch-root ]; then rm -f "$ROOT/app.c" "$ROOT/app"; fi
    if [ "$brc" -eq 0 ] && { [ -z "$want" ] || grep -qF -- "$want" "$out"; }; then
        ok "$name: runs as written (${how/scratch-root/checkout}${net:+; its own network namespace}${want:+; prints \"$want\"})"
    else
        bad "$name: runs as written" "exit $brc${left:+; left running: $left}" "$(tail -n 15 "$out")"
    fi
    case $first in
    'openssl genpkey'*)
        for f in ca.pem server.pem client.pem; do
            [ -s "$dir/$f" ] || bad "$name: makes $f"
        done ;;
    'gcc app.c'*)
        [ -x "$dir/app" ] && ldd "$dir/app" >/dev/null 2>&1 || bad "$name: makes ./app" ;;
    esac
done
if [ -n "$holder" ]; then
    held=$(grep -c held "$RB/holder.out" || true)
    kill "$holder" 2>/dev/null
    wait "$holder" 2>/dev/null
    if [ "$held" -gt 0 ]; then
        ok "the README's blocks on port 1502 ran while 127.0.0.1:1502 was held outside their network namespaces"
    fi
fi

summary
