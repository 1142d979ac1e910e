#!/usr/bin/env bash
# install.sh: installs the built library, headers, pkg-config file and manual pages,
# in the layout of Debian's libmodbus5 + libmodbus-dev. debian/rules uses it (into
# debian/tmp); it is also the from-source install.
#
# Usage: scripts/install.sh [--prefix=DIR] [--libdir=DIR] [--includedir=DIR]
#                           [--mandir=DIR] [--destdir=DIR] [--no-build] [--from=DIR]
#                           [--no-strip] [--gateway[=BIN]] [--unitdir=DIR]
#   --prefix      default /usr/local
#   --libdir      default PREFIX/lib (Debian: /usr/lib/x86_64-linux-gnu)
#   --includedir  default PREFIX/include (headers go into INCLUDEDIR/modbus)
#   --mandir      default PREFIX/share/man
#   --destdir     staging root prepended to every path (packaging); without it, and
#                 as root, ldconfig runs at the end
#   --no-build    use target/release as it is (no `cargo build --release`)
#   --from=DIR    use the build in DIR as it is, e.g. target/pgo/release from
#                 scripts/build-pgo.sh (debian/rules); implies --no-build
#   --no-strip    keep the symbol tables and debug sections
#   --gateway     also the gateway (gateway/, Rust): BIN (default
#                 target/release/rsmodbus-gateway, which `cargo build --release`
#                 makes) as PREFIX/bin/rsmodbus-gateway, MANDIR/man8/rsmodbus-gateway.8
#                 and the systemd unit template UNITDIR/rsmodbus-gateway@.service
#                 (its ExecStart names PREFIX/bin); as the package rsmodbus-gateway
#   --unitdir     default PREFIX/lib/systemd/system (Debian's package: /lib/systemd/system)
#
# Installs LIBDIR/libmodbus.so.5.1.0 with the links libmodbus.so.5 and libmodbus.so,
# LIBDIR/libmodbus.a (debug sections and the embedded LLVM bitcode of the Rust
# standard library removed), LIBDIR/pkgconfig/libmodbus.pc, INCLUDEDIR/modbus/*.h,
# MANDIR/man3/*.3 (one page per function) and MANDIR/man7/{libmodbus,rsmodbus}.7.
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."

prefix=/usr/local
libdir=
includedir=
mandir=
destdir=
build=1
built=target/release
do_strip=1
gateway=
unitdir=
for arg in "$@"; do
    case $arg in
        --prefix=*) prefix=${arg#*=} ;;
        --libdir=*) libdir=${arg#*=} ;;
        --includedir=*) includedir=${arg#*=} ;;
        --mandir=*) mandir=${arg#*=} ;;
        --destdir=*) destdir=${arg#*=} ;;
        --no-build) build=0 ;;
        --from=*) built=${arg#*=}; build=0 ;;
        --no-strip) do_strip=0 ;;
        --gateway) gateway=target/release/rsmodbus-gateway ;;
        --gateway=*) gateway=${arg#*=} ;;
        --unitdir=*) unitdir=${arg#*=} ;;
        -h | --help)
            sed -n '2,/^# SPDX/p' "$0" | sed 's/^# \{0,1\}//'
            exit 0
            ;;
        *)
            echo "install.sh: unknown argument $arg (see --help)" >&2
            exit 2
            ;;
    esac
done
prefix=${prefix%/}
libdir=${libdir:-$prefix/lib}
includedir=${includedir:-$prefix/include}
mandir=${mandir:-$prefix/share/man}
unitdir=${unitdir:-$prefix/lib/systemd/system}

REAL_NAME=libmodbus.so.5.1.0
SONAME=libmodbus.so.5

if [ "$build" = 1 ]; then
    cargo build --release
fi
for f in libmodbus.so libmodbus.a libmodbus.pc; do
    [ -f "$built/$f" ] || { echo "install.sh: $built/$f missing; build it first" >&2; exit 1; }
done
if [ -n "$gateway" ] && [ ! -x "$gateway" ]; then
    echo "install.sh: $gateway missing; build it first (cargo build --release)" >&2
    exit 1
fi
soname=$(objdump -p "$built/libmodbus.so" | awk '$1 == "SONAME" {print $2}')
if [ "$soname" != "$SONAME" ]; then
    echo "install.sh: $built/libmodbus.so has soname '$soname', expected $SONAME" >&2
    exit 1
fi
python3 man/gen-man.py --out target/man

# A path below PREFIX is written relative to ${prefix} in the .pc file.
pc_path() {
    case $1 in
        "$prefix"/*) printf '${prefix}%s' "${1#"$prefix"}" ;;
        "$prefix") printf '${prefix}' ;;
        *) printf '%s' "$1" ;;
    esac
}

D=$destdir
install -d "$D$libdir/pkgconfig" "$D$includedir/modbus" "$D$mandir/man3" "$D$mandir/man7"

install -m 0644 "$built/libmodbus.so" "$D$libdir/$REAL_NAME"
ln -sfn "$REAL_NAME" "$D$libdir/$SONAME"
ln -sfn "$REAL_NAME" "$D$libdir/libmodbus.so"
install -m 0644 "$built/libmodbus.a" "$D$libdir/libmodbus.a"
if [ "$do_strip" = 1 ]; then
    strip --strip-unneeded --remove-section=.comment --remove-section=.note "$D$libdir/$REAL_NAME"
    # What a C program linking the archive never uses: DWARF, and the LLVM bitcode
    # that the Rust standard library objects embed for cross-language LTO.
    strip --strip-debug --remove-section=.llvmbc --remove-section=.llvmcmd \
        --remove-section=.comment --enable-deterministic-archives "$D$libdir/libmodbus.a"
fi

# build.rs wrote libmodbus.pc for its default prefix; only the paths change here.
sed -e "s|^prefix=.*|prefix=$prefix|" \
    -e "s|^exec_prefix=.*|exec_prefix=\${prefix}|" \
    -e "s|^libdir=.*|libdir=$(pc_path "$libdir")|" \
    -e "s|^includedir=.*|includedir=$(pc_path "$includedir")|" \
    "$built/libmodbus.pc" >"$D$libdir/pkgconfig/libmodbus.pc"
chmod 0644 "$D$libdir/pkgconfig/libmodbus.pc"

install -m 0644 include/modbus.h include/modbus-rtu.h include/modbus-tcp.h \
    include/modbus-tls.h include/modbus-version.h "$D$includedir/modbus/"
install -m 0644 target/man/man3/*.3 "$D$mandir/man3/"
install -m 0644 target/man/man7/*.7 "$D$mandir/man7/"

if [ -n "$gateway" ]; then
    install -d "$D$prefix/bin" "$D$mandir/man8" "$D$unitdir"
    install -m 0755 "$gateway" "$D$prefix/bin/rsmodbus-gateway"
    [ "$do_strip" = 0 ] || strip --strip-unneeded --remove-section=.comment "$D$prefix/bin/rsmodbus-gateway"
    install -m 0644 target/man/man8/rsmodbus-gateway.8 "$D$mandir/man8/"
    sed "s|/usr/bin/rsmodbus-gateway|$prefix/bin/rsmodbus-gateway|" gateway/rsmodbus-gateway@.service \
        >"$D$unitdir/rsmodbus-gateway@.service"
    chmod 0644 "$D$unitdir/rsmodbus-gateway@.service"
    echo "installed the gateway into ${D:-/}: $prefix/bin/rsmodbus-gateway, $mandir/man8/rsmodbus-gateway.8," \
        "$unitdir/rsmodbus-gateway@.service"
fi
echo "installed rsmodbus into ${D:-/}: $libdir/$REAL_NAME (+ $SONAME, libmodbus.so, libmodbus.a," \
    "pkgconfig/libmodbus.pc), $includedir/modbus/, $(ls target/man/man3 | wc -l) pages in $mandir/man3"
if [ -z "$D" ] && [ "$(id -u)" = 0 ] && command -v ldconfig >/dev/null; then
    ldconfig
fi
