#!/usr/bin/env bash
# package.sh: builds the Debian packages (scripts/build-deb.sh) and checks them
# without installing them on this machine (Debian's libmodbus5 stays: it is the
# oracle of the differential tests):
#   - the build leaves the tree as it found it (git status, ignored files too);
#   - control fields (dpkg-deb -f): names, version, Provides/Conflicts/Replaces
#     libmodbus5 and libmodbus-dev, Depends (rsmodbus-gateway: libc6, not the
#     library it links in); the ldconfig trigger, shlibs and symbols (dpkg-deb -I);
#     the exact file lists (dpkg-deb -c);
#   - apt's resolver (simulation only): installing both packages removes libmodbus5
#     and libmodbus-dev but keeps Debian's mbpoll, and collectd-core and zabbix-agent
#     install with librsmodbus5 satisfying their libmodbus5 dependency;
#   - the extracted tree (dpkg -x into a scratch root): the library is the
#     profile-guided build (its code equals target/pgo/release's), soname, exported
#     symbols, stripped libraries (sizes reported), libmodbus.pc, man pages render;
#   - the examples compiled against the extracted root with PKG_CONFIG_SYSROOT_DIR
#     and PKG_CONFIG_PATH, dynamically and statically (pkg-config --static), and run
#     against each other over loopback and a pty pair;
#   - Debian's unmodified /usr/bin/mbpoll with LD_LIBRARY_PATH pointing into the
#     extracted root, against examples/tcp-server on loopback and examples/rtu-server
#     over a pty: printed values, exit codes, and the libmodbus.so.5 it loaded
#     (LD_DEBUG=libs, /proc/PID/maps), and through the packaged rsmodbus-gateway in
#     front of that pty (its -h too; it loads no libmodbus.so.5);
#   - the packaged systemd unit: systemd-analyze verify, and systemd-analyze security
#     --offline=yes rates its exposure 2.0 or below; the gateway's maintainer scripts
#     (in a mount namespace with a scratch /run and a systemctl that notes its
#     arguments): an upgrade restarts the template's running instances, a removal
#     stops them.
# Every process started here is stopped by its PID. Ends with "N passed, M failed".
# Usage: c-tests/suites/package.sh [--no-build]   (--no-build: use target/debian/*.deb)
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 1
ROOT_DIR=$PWD
WORK=$ROOT_DIR/target/check-package
rm -rf "$WORK"
mkdir -p "$WORK"
# shellcheck source=c-tests/common/testlib.sh
. c-tests/common/testlib.sh
CC=${CC:-gcc}
MA=$(dpkg-architecture -qDEB_HOST_MULTIARCH)
DEBS=$ROOT_DIR/target/debian
# What debian/rules builds and installs (scripts/build-pgo.sh).
BUILT=target/pgo/release

# --- build ------------------------------------------------------------------------
# The tree's state (what git sees, ignored files too, but target/): the build must
# leave it as it was (debian/PACKAGE/, debian/tmp/, debhelper's files removed).
tree_state() { git status --porcelain --ignored 2>/dev/null | grep -vx '!! target/' | sort; }
if [ "${1:-}" != "--no-build" ]; then
    tree_state >"$WORK/tree.before"
    start_s=$(date +%s)
    if scripts/build-deb.sh "$DEBS" >"$WORK/build-deb.log" 2>&1; then
        ok "scripts/build-deb.sh built the packages in $(($(date +%s) - start_s)) s"
    else
        bad "scripts/build-deb.sh" "$(tail -n 30 "$WORK/build-deb.log")"
    fi
    tree_state >"$WORK/tree.after"
    if left=$(comm -13 "$WORK/tree.before" "$WORK/tree.after") && [ -z "$left" ]; then
        ok "building the packages leaves the tree as it was (git status --porcelain --ignored)"
    else
        bad "building the packages leaves the tree as it was" "left behind:" "$left"
    fi
    [ -s "$WORK/build-deb.log" ] && grep -q '^packages in ' "$WORK/build-deb.log" || { summary; exit 1; }
fi
RUNTIME=$(ls "$DEBS"/librsmodbus5_*.deb 2>/dev/null | head -n 1)
DEV=$(ls "$DEBS"/librsmodbus-dev_*.deb 2>/dev/null | head -n 1)
GW=$(ls "$DEBS"/rsmodbus-gateway_*.deb 2>/dev/null | head -n 1)
if [ -z "$RUNTIME" ] || [ -z "$DEV" ] || [ -z "$GW" ]; then
    bad "the three packages exist in target/debian" "$(ls "$DEBS" 2>&1)"
    summary
    exit 1
fi
echo "       $(basename "$RUNTIME"): $(stat -c %s "$RUNTIME") bytes; $(basename "$DEV"): $(stat -c %s "$DEV") bytes;" \
    "$(basename "$GW"): $(stat -c %s "$GW") bytes"

# --- copyright: every Rust crate linked into the library is named, with its licence ---
if out=$(python3 debian/embedded-crates.py --check 2>&1); then
    ok "$out"
else
    bad "debian/copyright names the linked crates (debian/embedded-crates.py --check)" "$out"
fi

# --- control fields ------------------------------------------------------------------
# Linux only (epoll, eventfd, timerfd, ppoll, futex): every package of debian/control
# says linux-any (the README's "Platforms").
archs=$(sed -n 's/^Architecture: *//p' debian/control | sort | uniq -c | sed 's/^ *//')
npkgs=$(grep -c '^Package:' debian/control)
if [ "$archs" = "$npkgs linux-any" ]; then
    ok "debian/control: Architecture: linux-any for all $npkgs packages"
else
    bad "debian/control: Architecture: linux-any for every package" "got (count, value):" "$archs"
fi
crate_version=$(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n 1)
api=$(sed -n 's/^Version: *//p' $BUILT/libmodbus.pc)
version="$api+rs$crate_version"
field() { dpkg-deb -f "$1" "$2"; }
expect_field() {
    local deb=$1 name=$2 want=$3 got
    got=$(field "$deb" "$name")
    if [ "$got" = "$want" ]; then
        ok "$(field "$deb" Package): $name: $want"
    else
        bad "$(field "$deb" Package): $name" "expected: $want" "got:      $got"
    fi
}
expect_field "$RUNTIME" Package librsmodbus5
expect_field "$RUNTIME" Version "$version"
expect_field "$RUNTIME" Architecture "$(dpkg-architecture -qDEB_HOST_ARCH)"
expect_field "$RUNTIME" Multi-Arch same
expect_field "$RUNTIME" Provides "libmodbus5 (= $api)"
expect_field "$RUNTIME" Conflicts libmodbus5
expect_field "$RUNTIME" Replaces libmodbus5
expect_field "$DEV" Package librsmodbus-dev
expect_field "$DEV" Version "$version"
expect_field "$DEV" Depends "librsmodbus5 (= $version)"
expect_field "$DEV" Provides "libmodbus-dev (= $api)"
expect_field "$DEV" Conflicts libmodbus-dev
expect_field "$DEV" Replaces libmodbus-dev
expect_field "$DEV" Section libdevel
expect_field "$GW" Package rsmodbus-gateway
expect_field "$GW" Version "$version"
expect_field "$GW" Section net
# The gateway links the library in (an rlib): dpkg-shlibdeps finds libc6 (and
# libgcc-s1), no libmodbus5 or librsmodbus5.
gw_depends=$(field "$GW" Depends)
if grep -q "libc6 (>= " <<<"$gw_depends" && ! grep -q "modbus" <<<"$gw_depends"; then
    ok "rsmodbus-gateway: Depends: $gw_depends (no libmodbus5: the library is linked in)"
else
    bad "rsmodbus-gateway: Depends on libc6 and on no libmodbus5 or librsmodbus5" "got: $gw_depends"
fi
if grep -q 'libc6 (>= ' <<<"$(field "$RUNTIME" Depends)"; then
    ok "librsmodbus5: Depends (from dpkg-shlibdeps): $(field "$RUNTIME" Depends)"
else
    bad "librsmodbus5: Depends lists libc6" "got: $(field "$RUNTIME" Depends)"
fi

mkdir -p "$WORK/control"
dpkg-deb -e "$RUNTIME" "$WORK/control"
if grep -qx 'activate-noawait ldconfig' "$WORK/control/triggers" 2>/dev/null; then
    ok "librsmodbus5: triggers ldconfig (activate-noawait ldconfig)"
else
    bad "librsmodbus5: triggers ldconfig" "$(cat "$WORK/control/triggers" 2>&1)"
fi
expect_line "librsmodbus5: shlibs" "$WORK/control/shlibs" "libmodbus 5 librsmodbus5 (>= $version)"
expect_line "librsmodbus5: symbols file: libmodbus5 dependency template" "$WORK/control/symbols" \
    "libmodbus.so.5 libmodbus5 #MINVER#"
expect_line "librsmodbus5: symbols file: modbus_read_registers since 3.0.2 (as Debian's)" \
    "$WORK/control/symbols" " modbus_read_registers@Base 3.0.2"
expect_line "librsmodbus5: symbols file: modbus_send_raw_request_tid since 3.1.11" \
    "$WORK/control/symbols" " modbus_send_raw_request_tid@Base 3.1.11"
expect_line "librsmodbus5: symbols file: extensions depend on librsmodbus5" \
    "$WORK/control/symbols" " rsmodbus_version@Base $version 1"

# --- apt's resolver (simulation, nothing is installed) ------------------------------
apt-get -s install "$RUNTIME" "$DEV" >"$WORK/apt-sim.log" 2>&1
if grep -q '^Remv libmodbus5 ' "$WORK/apt-sim.log" && grep -q '^Inst librsmodbus5 ' "$WORK/apt-sim.log" &&
    grep -q '^Inst librsmodbus-dev ' "$WORK/apt-sim.log" && ! grep -q '^Remv mbpoll' "$WORK/apt-sim.log"; then
    ok "apt (simulated): librsmodbus5 + librsmodbus-dev replace libmodbus5 + libmodbus-dev, mbpoll stays installed"
else
    bad "apt (simulated): the packages replace libmodbus5 and keep mbpoll" "$(grep -E '^(Inst|Remv|E:)' "$WORK/apt-sim.log")"
fi
apt-get -s install "$GW" >"$WORK/apt-sim-gw.log" 2>&1
if grep -q '^Inst rsmodbus-gateway ' "$WORK/apt-sim-gw.log" && ! grep -q -e '^Remv' -e '^Inst librsmodbus5 ' "$WORK/apt-sim-gw.log"; then
    ok "apt (simulated): rsmodbus-gateway installs alone, beside Debian's libmodbus5"
else
    bad "apt (simulated): rsmodbus-gateway installs alone, beside Debian's libmodbus5" "$(grep -E '^(Inst|Remv|E:)' "$WORK/apt-sim-gw.log")"
fi
apt-get -s install "$RUNTIME" "$GW" >"$WORK/apt-sim-gw2.log" 2>&1
if grep -q '^Inst rsmodbus-gateway ' "$WORK/apt-sim-gw2.log" && grep -q '^Inst librsmodbus5 ' "$WORK/apt-sim-gw2.log"; then
    ok "apt (simulated): rsmodbus-gateway installs beside librsmodbus5"
else
    bad "apt (simulated): rsmodbus-gateway installs beside librsmodbus5" "$(grep -E '^(Inst|Remv|E:)' "$WORK/apt-sim-gw2.log")"
fi
if apt-cache show collectd-core zabbix-agent >/dev/null 2>&1; then
    apt-get -s install "$RUNTIME" collectd-core zabbix-agent >"$WORK/apt-sim2.log" 2>&1
    if grep -q '^Inst collectd-core ' "$WORK/apt-sim2.log" && grep -q '^Inst zabbix-agent ' "$WORK/apt-sim2.log" &&
        ! grep -q '^Inst libmodbus5 ' "$WORK/apt-sim2.log"; then
        ok "apt (simulated): collectd-core and zabbix-agent install on librsmodbus5 (no libmodbus5)"
    else
        bad "apt (simulated): collectd-core and zabbix-agent accept librsmodbus5" \
            "$(grep -E '^(Inst|Remv|E:)|modbus' "$WORK/apt-sim2.log" | head -n 20)"
    fi
fi

# --- file lists -----------------------------------------------------------------------
list() { dpkg-deb -c "$1" | awk '{ if ($6 == "") next; l = $6; if (NF >= 8 && $7 == "->") l = l " -> " $8; if (substr($1,1,1) != "d") print l }' | sed 's|^\./|/|' | sort; }
L=/usr/lib/$MA
# expect_files KEY DEB [NOTE]: DEB's files are exactly the lines of stdin.
expect_files() {
    local key=$1 deb=$2 note=${3:-}
    sort >"$WORK/$key.expected"
    list "$deb" >"$WORK/$key.files"
    if diff -u "$WORK/$key.expected" "$WORK/$key.files" >"$WORK/$key.diff"; then
        ok "$(field "$deb" Package): file list ($(wc -l <"$WORK/$key.files") files$note)"
    else
        bad "$(field "$deb" Package): file list" "$(head -n 40 "$WORK/$key.diff")"
    fi
}
{
    echo "$L/libmodbus.so.5 -> libmodbus.so.5.1.0"
    echo "$L/libmodbus.so.5.1.0"
    echo "/usr/share/doc/librsmodbus5/changelog.gz"
    echo "/usr/share/doc/librsmodbus5/copyright"
    echo "/usr/share/lintian/overrides/librsmodbus5"
} | expect_files runtime "$RUNTIME"
nm -D --defined-only $BUILT/libmodbus.so | awk '{print $3}' | sort >"$WORK/exported"
{
    for h in modbus.h modbus-rtu.h modbus-tcp.h modbus-tls.h modbus-version.h; do echo "/usr/include/modbus/$h"; done
    echo "$L/libmodbus.so -> libmodbus.so.5.1.0"
    echo "$L/libmodbus.a"
    echo "$L/pkgconfig/libmodbus.pc"
    sed "s|.*|/usr/share/man/man3/&.3.gz|" "$WORK/exported"
    echo "/usr/share/man/man7/libmodbus.7.gz"
    echo "/usr/share/man/man7/rsmodbus.7.gz"
    for f in changelog.gz copyright; do echo "/usr/share/doc/librsmodbus-dev/$f"; done
    # dh_compress compresses documents above 4 kB.
    if [ "$(stat -c %s README.md)" -gt 4096 ]; then readme=README.md.gz; else readme=README.md; fi
    echo "/usr/share/doc/librsmodbus-dev/$readme"
    for f in examples/*.c; do echo "/usr/share/doc/librsmodbus-dev/examples/$(basename "$f")"; done
} | expect_files dev "$DEV" ", a page in man3 for each of the $(wc -l <"$WORK/exported") exported symbols"
{
    echo "/usr/bin/rsmodbus-gateway"
    echo "/usr/share/man/man8/rsmodbus-gateway.8.gz"
    echo "/lib/systemd/system/rsmodbus-gateway@.service"
    for f in changelog.gz copyright examples/example.conf; do echo "/usr/share/doc/rsmodbus-gateway/$f"; done
} | expect_files gw "$GW"
for deb in "$RUNTIME" "$DEV" "$GW"; do
    pkg=$(field "$deb" Package)
    dpkg-deb --fsys-tarfile "$deb" | tar -xO "./usr/share/doc/$pkg/copyright" >"$WORK/$pkg.copyright" 2>/dev/null
    if grep -q '^License: MIT or Apache-2.0' "$WORK/$pkg.copyright"; then
        ok "$pkg: copyright file states MIT or Apache-2.0"
    else
        bad "$pkg: copyright file states MIT or Apache-2.0"
    fi
    # The linked crates' licences (debian/embedded-crates.py), ring's for one.
    if grep -q "ring .*: Apache-2.0 AND ISC" "$WORK/$pkg.copyright" && grep -q '^License: ISC' "$WORK/$pkg.copyright"; then
        ok "$pkg: copyright file names the linked crates (ring: Apache-2.0 AND ISC)"
    else
        bad "$pkg: copyright file names the linked crates (ring: Apache-2.0 AND ISC)" ""
    fi
done

# --- the extracted tree -----------------------------------------------------------------
R=$WORK/root
mkdir -p "$R"
dpkg -x "$RUNTIME" "$R" && dpkg -x "$DEV" "$R" && dpkg -x "$GW" "$R"
RL=$R$L
so=$RL/libmodbus.so.5.1.0
soname=$(objdump -p "$so" | awk '$1 == "SONAME" {print $2}')
[ "$soname" = libmodbus.so.5 ] && ok "extracted libmodbus.so.5.1.0 has soname libmodbus.so.5" ||
    bad "extracted library soname" "got: $soname"
# Stripping leaves the code alone: the same .text means the same build.
text_of() { objcopy -O binary --only-section=.text "$1" "$WORK/text.bin" && md5sum <"$WORK/text.bin"; }
if [ "$(text_of "$so")" = "$(text_of $BUILT/libmodbus.so)" ]; then
    ok "the packaged library is the profile-guided build: its code equals $BUILT/libmodbus.so's"
else
    bad "the packaged library is the profile-guided build" "its .text differs from $BUILT/libmodbus.so's"
fi
nm -D --defined-only "$so" | awk '{print $3}' | sort >"$WORK/exported.pkg"
if diff -q "$WORK/exported" "$WORK/exported.pkg" >/dev/null; then
    ok "extracted library exports the $(wc -l <"$WORK/exported.pkg") symbols of $BUILT/libmodbus.so"
else
    bad "extracted library exports the built symbols" "$(diff "$WORK/exported" "$WORK/exported.pkg" | head)"
fi
if ! grep -q -e '\.symtab' -e '\.debug_' <<<"$(readelf -S "$so")"; then
    ok "libmodbus.so.5.1.0 is stripped: $(stat -c %s "$so") bytes ($BUILT/libmodbus.so: $(stat -c %s $BUILT/libmodbus.so))"
else
    bad "libmodbus.so.5.1.0 is stripped" "$(readelf -S "$so" | grep -e symtab -e debug_)"
fi
# stack_protected FILE NAME: dpkg-buildflags' hardening reached the C code inside
# FILE (ring's): compiled with -fstack-protector-strong, it calls __stack_chk_fail.
# The test run builds the library with the packages' flags (build-pgo.sh
# --debian-flags) for the packages to keep it; a library built without them must not
# be taken instead (build-pgo.sh's inputs).
stack_protected() {
    if grep -qw __stack_chk_fail <<<"$(nm -D --undefined-only "$1")"; then
        ok "$2 carries dpkg-buildflags' stack protector (ring's C code calls __stack_chk_fail)"
    else
        bad "$2 carries dpkg-buildflags' stack protector" "no __stack_chk_fail among its undefined symbols"
    fi
}
stack_protected "$so" libmodbus.so.5.1.0
a=$RL/libmodbus.a
a_before=$(stat -c %s $BUILT/libmodbus.a)
a_after=$(stat -c %s "$a")
extra=$(objdump -h "$a" 2>/dev/null | awk '$2 ~ /^\.(debug_|llvmbc|llvmcmd)/ {print $2}' | sort -u | tr '\n' ' ')
if [ -z "$extra" ] && [ "$a_after" -lt "$a_before" ]; then
    ok "libmodbus.a stripped of debug sections and embedded LLVM bitcode: $a_before -> $a_after bytes"
else
    bad "libmodbus.a stripped" "sections left: $extra" "$a_before -> $a_after bytes"
fi
nm --defined-only "$a" 2>/dev/null | awk '$2 == "T" || $2 == "R" {print $3}' | grep -E '^(modbus_|rsmodbus_|libmodbus_)' | sort -u >"$WORK/archive.syms"
if diff -q "$WORK/exported" "$WORK/archive.syms" >/dev/null; then
    ok "libmodbus.a defines the same $(wc -l <"$WORK/archive.syms") public symbols"
else
    bad "libmodbus.a defines the public symbols" "$(diff "$WORK/exported" "$WORK/archive.syms" | head)"
fi

export PKG_CONFIG_SYSROOT_DIR=$R
export PKG_CONFIG_PATH=$RL/pkgconfig
pcv=$(pkg-config --modversion libmodbus 2>&1)
[ "$pcv" = "$api" ] && ok "pkg-config finds the extracted libmodbus.pc (version $pcv)" ||
    bad "pkg-config finds the extracted libmodbus.pc" "modversion: $pcv"
trim() { sed -e 's/^ *//' -e 's/ *$//'; }
cflags=$(pkg-config --cflags libmodbus | trim)
libs=$(pkg-config --libs libmodbus | trim)
slibs=$(pkg-config --static --libs libmodbus | trim)
if [ "$cflags" = "-I$R/usr/include/modbus" ] && [ "$libs" = "-L$RL -lmodbus" ]; then
    ok "pkg-config --cflags --libs: $cflags $libs"
else
    bad "pkg-config paths point into the root" "cflags: $cflags" "libs: $libs"
fi
expect_line "libmodbus.pc: prefix=/usr" "$RL/pkgconfig/libmodbus.pc" "prefix=/usr"
expect_line "libmodbus.pc: libdir" "$RL/pkgconfig/libmodbus.pc" "libdir=\${prefix}/lib/$MA"
expect_line "libmodbus.pc: Cflags" "$RL/pkgconfig/libmodbus.pc" "Cflags: -I\${includedir}/modbus"

# The packaged manual pages render (gzipped, as man-db reads them).
man_bad=()
npages=0
for page in "$R"/usr/share/man/man3/*.3.gz "$R"/usr/share/man/man7/*.7.gz "$R"/usr/share/man/man8/*.8.gz; do
    npages=$((npages + 1))
    warn=$(MANWIDTH=80 man --warnings=all -l "$page" 2>&1 >/dev/null)
    [ -z "$warn" ] || man_bad+=("$(basename "$page"): $warn")
done
if [ ${#man_bad[@]} -eq 0 ] && [ "$npages" -gt 0 ]; then
    ok "the $npages packaged pages render with man -l without warnings"
else
    bad "the packaged pages render without warnings" "${man_bad[@]:0:5}"
fi

# The packaged gateway: its help lists mbusd's options and the extended keys.
if out=$("$R/usr/bin/rsmodbus-gateway" -h 2>&1) && grep -q -- "^  -y file" <<<"$out" &&
    grep -q "tls_role" <<<"$out"; then
    ok "the packaged rsmodbus-gateway -h exits 0 and lists -y and tls_role"
else
    bad "the packaged rsmodbus-gateway -h" "$(head -n 5 <<<"$out")"
fi
# The Rust binary debian/rules built (cargo build --release, in target/deb-cargo),
# stripped, as hardened as Debian's flags would make a C program: PIE, a read-only
# relocation table bound at start (RELRO, BIND_NOW), no executable stack; it needs
# no libmodbus.so.5.
gw_bin=$R/usr/bin/rsmodbus-gateway
gw_built=target/deb-cargo/release/rsmodbus-gateway
if [ "$(text_of "$gw_bin")" = "$(text_of $gw_built)" ]; then
    ok "the packaged rsmodbus-gateway is $gw_built, stripped: $(stat -c %s "$gw_bin") bytes ($(stat -c %s $gw_built))"
else
    bad "the packaged rsmodbus-gateway is $gw_built" "their .text differ"
fi
stack_protected "$gw_bin" rsmodbus-gateway
gw_dyn=$(readelf -d "$gw_bin")
gw_seg=$(readelf -lW "$gw_bin")
if [ "$(readelf -h "$gw_bin" | awk '$1 == "Type:" {print $2}')" = DYN ] && grep -q GNU_RELRO <<<"$gw_seg" &&
    grep -q 'FLAGS.*BIND_NOW\|FLAGS_1.*NOW' <<<"$gw_dyn" && grep -q 'GNU_STACK.* RW  ' <<<"$gw_seg" &&
    ! grep -q -e '\.symtab' -e '\.debug_' <<<"$(readelf -S "$gw_bin")"; then
    ok "rsmodbus-gateway: PIE, RELRO, BIND_NOW, no executable stack, stripped"
else
    bad "rsmodbus-gateway: PIE, RELRO, BIND_NOW, no executable stack, stripped" "$(readelf -h "$gw_bin" | grep Type)" \
        "$(grep -e GNU_RELRO -e GNU_STACK <<<"$gw_seg")" "$(grep FLAGS <<<"$gw_dyn")"
fi
if ! grep -q 'NEEDED.*libmodbus' <<<"$gw_dyn"; then
    ok "rsmodbus-gateway needs no libmodbus.so.5 (NEEDED: $(sed -n 's/.*NEEDED.*\[\(.*\)\]/\1/p' <<<"$gw_dyn" | tr '\n' ' '))"
else
    bad "rsmodbus-gateway needs no libmodbus.so.5" "$(grep NEEDED <<<"$gw_dyn")"
fi
if [ -d "$R/etc/rsmodbus-gateway" ]; then
    ok "rsmodbus-gateway makes /etc/rsmodbus-gateway (the unit template's configurations)"
else
    bad "rsmodbus-gateway makes /etc/rsmodbus-gateway"
fi

# The packaged unit template: gateway/'s; systemd-analyze verify finds nothing to say
# (on a copy whose ExecStart names the extracted binary: this machine has no
# /usr/bin/rsmodbus-gateway); its exposure (systemd-analyze security, offline) is
# 2.0 or below (the unit as it was, running as root: 9.6).
unit=$R/lib/systemd/system/rsmodbus-gateway@.service
if cmp -s "$unit" gateway/rsmodbus-gateway@.service; then
    ok "the packaged unit template is gateway/rsmodbus-gateway@.service"
else
    bad "the packaged unit template is gateway/rsmodbus-gateway@.service" "$(diff "$unit" gateway/rsmodbus-gateway@.service | head)"
fi
if command -v systemd-analyze >/dev/null; then
    sed "s|/usr/bin/rsmodbus-gateway|$R/usr/bin/rsmodbus-gateway|" "$unit" >"$WORK/rsmodbus-gateway@.service"
    if out=$(systemd-analyze verify --man=no "$WORK/rsmodbus-gateway@.service" 2>&1) && [ -z "$out" ]; then
        ok "systemd-analyze verify: the unit template has nothing to report"
    else
        bad "systemd-analyze verify: the unit template has nothing to report" "$out"
    fi
    systemd-analyze security --offline=yes --no-pager "$unit" >"$WORK/unit-security.txt" 2>&1
    exposure=$(sed -n 's/.*Overall exposure level for .*: \([0-9.]*\) .*/\1/p' "$WORK/unit-security.txt")
    if [ -n "$exposure" ] && awk -v e="$exposure" 'BEGIN { exit !(e <= 2.0) }'; then
        ok "systemd-analyze security --offline=yes: the unit's exposure is $exposure (at most 2.0)"
    else
        bad "systemd-analyze security --offline=yes: the unit's exposure is at most 2.0" "got: ${exposure:-none}" \
            "$(grep -e '✗' -e 'exposure' "$WORK/unit-security.txt" | head -n 20)"
    fi
else
    bad "systemd-analyze is installed (apt-get install systemd) for the unit's checks"
fi

# The gateway's maintainer scripts (debian/rsmodbus-gateway.{postinst,prerm,postrm}), run
# as dpkg runs them, each in a mount namespace of its own whose /run is a scratch tmpfs
# (holding /run/systemd/system: systemd runs; or not), with a systemctl first on PATH
# that writes down its arguments (and exits STATUS): an upgrade restarts the running
# instances of the template, a removal stops them, a first install starts none.
MS=$WORK/gateway-control
rm -rf "$MS" "$WORK/stub"
mkdir -p "$WORK/stub"
dpkg-deb -e "$GW" "$MS"
printf '#!/bin/sh\necho "$*" >>"%s"\nexit ${STATUS:-0}\n' "$WORK/systemctl.calls" >"$WORK/stub/systemctl"
chmod +x "$WORK/stub/systemctl"
# maint SYSTEMD STATUS SCRIPT ARG...: the calls to systemctl ("; " between them, or
# "none"), and the script's exit status when not 0.
maint() {
    local systemd=$1 status=$2 script=$3 rc
    shift 3
    rm -f "$WORK/systemctl.calls"
    STUB=$WORK/stub STATUS=$status unshare --mount --propagation private sh -c \
        'mount -t tmpfs tmpfs /run || exit 99; [ "$1" = 0 ] || mkdir -p /run/systemd/system; shift; PATH="$STUB:$PATH" exec sh "$@"' \
        maint "$systemd" "$MS/$script" "$@" >"$WORK/maint.out" 2>&1
    rc=$?
    if [ -s "$WORK/systemctl.calls" ]; then paste -sd';' "$WORK/systemctl.calls" | sed 's/;/; /g'; else echo none; fi
    [ "$rc" = 0 ] || echo "exit $rc: $(head -c 300 "$WORK/maint.out")"
}
# expect_maint WHAT WANT SYSTEMD STATUS SCRIPT ARG...: one check of maint's answer.
expect_maint() {
    local what=$1 want=$2 got
    shift 2
    got=$(maint "$@")
    if [ "$got" = "$want" ]; then ok "rsmodbus-gateway $what: $want"; else bad "rsmodbus-gateway $what" "want: $want" "got: $got"; fi
}
old=3.1.12+rs0.0.1
for f in postinst prerm postrm; do
    if [ -x "$MS/$f" ]; then ok "rsmodbus-gateway has a $f"; else bad "rsmodbus-gateway has a $f" "$(ls "$MS")"; fi
done
expect_maint "upgraded (postinst configure $old)" \
    "--system daemon-reload; try-restart rsmodbus-gateway@*.service" 1 0 postinst configure "$old"
expect_maint "installed (postinst configure)" "--system daemon-reload" 1 0 postinst configure ""
expect_maint "upgraded without systemd running" none 0 0 postinst configure "$old"
expect_maint "upgraded while systemctl fails (the upgrade goes on)" \
    "--system daemon-reload; try-restart rsmodbus-gateway@*.service" 1 1 postinst configure "$old"
expect_maint "removed (prerm remove)" "stop rsmodbus-gateway@*.service" 1 0 prerm remove
expect_maint "upgraded (prerm upgrade: the instances run on)" none 1 0 prerm upgrade 3.1.12+rs0.2.0
expect_maint "removed (postrm remove)" "--system daemon-reload" 1 0 postrm remove

# --- examples against the extracted root --------------------------------------------
B=$WORK/bin
mkdir -p "$B"
for prog in tcp-client tcp-server rtu-client rtu-server; do
    # shellcheck disable=SC2086
    check "compile $prog against the extracted root (pkg-config --cflags --libs)" \
        "$CC" -Wall -Wextra -Werror -O2 "examples/$prog.c" -o "$B/$prog" $cflags $libs
done
for prog in tcp-client tcp-server; do
    # shellcheck disable=SC2086
    check "compile $prog statically with the extracted libmodbus.a (pkg-config --static --libs)" \
        "$CC" -Wall -Wextra -Werror -O2 "examples/$prog.c" -o "$B/$prog-static" $cflags -Wl,--gc-sections \
        -Wl,-Bstatic -lmodbus -Wl,-Bdynamic -Wl,--as-needed $slibs
done
if [ -x "$B/tcp-client-static" ]; then
    if grep -q 'NEEDED.*libmodbus' <<<"$(readelf -d "$B/tcp-client-static")"; then
        bad "static tcp-client does not need libmodbus.so.5"
    else
        ok "static tcp-client needs no libmodbus.so.5 ($(stat -c %s "$B/tcp-client-static") bytes; NEEDED: $(readelf -d "$B/tcp-client-static" | sed -n 's/.*NEEDED.*\[\(.*\)\]/\1/p' | tr '\n' ' '))"
    fi
fi

export LD_LIBRARY_PATH=$RL
loaded=$(ldd "$B/tcp-client" | awk '/libmodbus\.so\.5/ {print $3}')
[ "$loaded" = "$RL/libmodbus.so.5" ] && ok "with LD_LIBRARY_PATH the examples load $loaded" ||
    bad "the examples load the extracted library" "ldd: $loaded"

client_checks() {
    local name=$1 log=$2
    expect_line "$name: registers read back" "$log" \
        "registers 0..9: 0x1234 0xBEEF 0x002A 0x03EB 0x03EC 0x03ED 0x03EE 0x03EF 0x03F0 0x03F1"
    expect_line "$name: exception reported as errno" "$log" "read at 9999: rc=-1 (Illegal data address)"
}
# tcp_run NAME SERVER CLIENT
tcp_run() {
    local name=$1 server=$2 client=$3 port
    [ -x "$server" ] && [ -x "$client" ] || { bad "$name: not run, a program did not build"; return; }
    port=$(free_port)
    start "$name-server" "$server" "$port" 5
    if ! wait_ready "$name-server" "serving on" 10; then
        bad "$name: server starts" "$(cat "$WORK/$name-server.log")"
        stop "$name-server"
        return
    fi
    start "$name-client" "$client" 127.0.0.1 "$port"
    wait_exit "$name-client" 20
    [ "$rc" -eq 0 ] && ok "$name: client exits 0" || bad "$name: client exits 0" "exit $rc" "$(tail -n 5 "$WORK/$name-client.log")"
    wait_exit "$name-server" 10
    [ "$rc" -eq 0 ] && ok "$name: server exits 0 after 5 requests" || bad "$name: server exits 0" "exit $rc"
    client_checks "$name" "$WORK/$name-client.log"
}
tcp_run "dynamic tcp" "$B/tcp-server" "$B/tcp-client"
tcp_run "static tcp" "$B/tcp-server-static" "$B/tcp-client-static"

# --- Debian's mbpoll on the extracted library --------------------------------------------
MBPOLL=/usr/bin/mbpoll
if [ -x "$MBPOLL" ] && grep -q '^mbpoll:' <<<"$(dpkg -S "$MBPOLL" 2>/dev/null)"; then
    if dpkg --verify mbpoll >/dev/null 2>&1; then
        ok "mbpoll is Debian's, unmodified ($(dpkg-query -W -f='${Version}' mbpoll), dpkg --verify)"
    else
        bad "mbpoll is Debian's, unmodified" "$(dpkg --verify mbpoll 2>&1)"
    fi

    # mbpoll_run NAME EXPECTED_RC ARGS...: runs mbpoll with LD_DEBUG=libs; output in NAME.out
    mbpoll_run() {
        local name=$1 want=$2
        shift 2
        LD_DEBUG=libs LD_DEBUG_OUTPUT="$WORK/$name.lddebug" timeout 20 "$MBPOLL" "$@" >"$WORK/$name.out" 2>&1
        rc=$?
        if [ "$rc" -eq "$want" ]; then
            ok "mbpoll $name: exit code $rc"
        else
            bad "mbpoll $name: exit code $want" "exit $rc: mbpoll $*" "$(tail -n 8 "$WORK/$name.out")"
        fi
        if grep -qF "calling init: $RL/libmodbus.so.5" "$WORK/$name.lddebug".* 2>/dev/null; then
            ok "mbpoll $name: loaded $RL/libmodbus.so.5 (LD_DEBUG=libs)"
        else
            bad "mbpoll $name: loaded the extracted libmodbus.so.5" "$(grep -h libmodbus "$WORK/$name.lddebug".* 2>/dev/null | head -n 5)"
        fi
    }
    # expect_values NAME "ref:value" ...: the lines mbpoll prints for each reference
    expect_values() {
        local name=$1 pair missing=()
        shift
        for pair in "$@"; do
            grep -qxF "[${pair%%:*}]: 	${pair#*:}" "$WORK/$name.out" || missing+=("[${pair%%:*}]: ${pair#*:}")
        done
        if [ ${#missing[@]} -eq 0 ]; then
            ok "mbpoll $name: printed $*"
        else
            bad "mbpoll $name: printed values" "missing: ${missing[*]}" "$(tail -n 8 "$WORK/$name.out")"
        fi
    }

    # TCP, loopback, against examples/tcp-server on the extracted library.
    port=$(free_port)
    start mbpoll-tcp-server "$B/tcp-server" "$port" 0
    if wait_ready mbpoll-tcp-server "serving on" 10; then
        pid=${_pids[mbpoll-tcp-server]}
        if grep -qF "$RL/libmodbus.so.5.1.0" "/proc/$pid/maps"; then
            ok "tcp-server (pid $pid) maps $RL/libmodbus.so.5.1.0 (/proc/PID/maps)"
        else
            bad "tcp-server maps the extracted library" "$(grep libmodbus "/proc/$pid/maps" | head -n 2)"
        fi
        mbpoll_run tcp-read 0 -m tcp -p "$port" -a 1 -r 1 -c 5 -1 127.0.0.1
        expect_values tcp-read 1:1000 2:1001 3:1002 4:1003 5:1004
        mbpoll_run tcp-write 0 -m tcp -p "$port" -a 1 -r 10 127.0.0.1 111 222 333
        grep -qF "Written 3 references." "$WORK/tcp-write.out" && ok "mbpoll tcp-write: wrote 3 registers" ||
            bad "mbpoll tcp-write: wrote 3 registers" "$(tail -n 5 "$WORK/tcp-write.out")"
        mbpoll_run tcp-readback 0 -m tcp -p "$port" -a 1 -r 10 -c 3 -1 127.0.0.1
        expect_values tcp-readback 10:111 11:222 12:333
        mbpoll_run tcp-input-registers 0 -m tcp -p "$port" -a 1 -t 3 -r 1 -c 2 -1 127.0.0.1
        expect_values tcp-input-registers 1:2000 2:2001
        mbpoll_run tcp-discrete-inputs 0 -m tcp -p "$port" -a 1 -t 1 -r 1 -c 4 -1 127.0.0.1
        expect_values tcp-discrete-inputs 1:0 2:1 3:0 4:1
        mbpoll_run tcp-bad-address 1 -m tcp -p "$port" -a 1 -r 500 -c 1 -1 127.0.0.1
        grep -qF "Illegal data address" "$WORK/tcp-bad-address.out" &&
            ok "mbpoll tcp-bad-address: reports \"Illegal data address\"" ||
            bad "mbpoll tcp-bad-address: reports the exception" "$(tail -n 5 "$WORK/tcp-bad-address.out")"
    else
        bad "tcp-server for mbpoll starts" "$(cat "$WORK/mbpoll-tcp-server.log")"
    fi
    stop mbpoll-tcp-server

    # RTU over a pty pair, against examples/rtu-server (slave 17, 19200 8E1).
    if pty_pair pty "$WORK/ttyS" "$WORK/ttyC"; then
        start mbpoll-rtu-server "$B/rtu-server" "$WORK/ttyS" 17 19200 E
        if wait_ready mbpoll-rtu-server "serving slave 17" 10; then
            mbpoll_run rtu-read 0 -m rtu -b 19200 -P even -a 17 -r 1 -c 5 -1 "$WORK/ttyC"
            expect_values rtu-read 1:1000 2:1001 3:1002 4:1003 5:1004
            mbpoll_run rtu-write 0 -m rtu -b 19200 -P even -a 17 -r 30 "$WORK/ttyC" 7 8
            mbpoll_run rtu-readback 0 -m rtu -b 19200 -P even -a 17 -r 30 -c 2 -1 "$WORK/ttyC"
            expect_values rtu-readback 30:7 31:8
            # Another slave id: no answer, mbpoll times out and fails.
            mbpoll_run rtu-wrong-slave 1 -m rtu -b 19200 -P even -a 18 -t 4 -r 1 -c 1 -1 -o 0.5 "$WORK/ttyC"
            grep -qiF "timed out" "$WORK/rtu-wrong-slave.out" &&
                ok "mbpoll rtu-wrong-slave: times out" ||
                bad "mbpoll rtu-wrong-slave: times out" "$(tail -n 5 "$WORK/rtu-wrong-slave.out")"
            # And the RTU example client, on the extracted library too.
            start pkg-rtu-client "$B/rtu-client" "$WORK/ttyC" 17 19200 E
            wait_exit pkg-rtu-client 30
            [ "$rc" -eq 0 ] && ok "rtu-client (extracted library) exits 0" ||
                bad "rtu-client (extracted library) exits 0" "exit $rc" "$(tail -n 5 "$WORK/pkg-rtu-client.log")"
            client_checks "rtu" "$WORK/pkg-rtu-client.log"
            # The packaged gateway in front of the same line: mbpoll over TCP through it.
            if [ -x "$R/usr/bin/rsmodbus-gateway" ]; then
                gport=$(free_port)
                start pkg-gateway "$R/usr/bin/rsmodbus-gateway" -d -L - -p "$WORK/ttyC" -s 19200 -m 8E1 \
                    -P "$gport" -R 1 -W 500
                if wait_ready pkg-gateway "started" 10; then
                    # (registers 0-2 hold what rtu-client wrote)
                    mbpoll_run gateway-read 0 -m tcp -p "$gport" -a 17 -r 4 -c 3 -1 127.0.0.1
                    expect_values gateway-read 4:1003 5:1004 6:1005
                    if ! grep -qF "libmodbus.so" "/proc/${_pids[pkg-gateway]}/maps"; then
                        ok "the packaged rsmodbus-gateway maps no libmodbus.so.5 (the library is linked in)"
                    else
                        bad "the packaged rsmodbus-gateway maps no libmodbus.so.5" \
                            "$(grep libmodbus "/proc/${_pids[pkg-gateway]}/maps" | head -n 2)"
                    fi
                else
                    bad "the packaged rsmodbus-gateway starts" "$(tail -n 5 "$WORK/pkg-gateway.log")"
                fi
                stop pkg-gateway
            fi
        else
            bad "rtu-server for mbpoll starts" "$(cat "$WORK/mbpoll-rtu-server.log")"
        fi
        stop mbpoll-rtu-server
        stop pty
    else
        bad "socat pty pair"
    fi
else
    bad "Debian's mbpoll is installed (scripts/install-deps.sh)"
fi

summary
