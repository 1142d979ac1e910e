#!/usr/bin/env bash
# install.sh: installs the built library, headers, pkg-config file and manual pages,
# in the layout of Debian's libmodbus5 + libmodbus-dev (and, with --gateway, what the
# package rsmodbus-gateway installs). debian/rules uses it (into debian/tmp); it is
# also the from-source install, which --uninstall undoes.
#
# Usage: scripts/install.sh [--prefix=DIR] [--libdir=DIR] [--includedir=DIR]
#                           [--mandir=DIR] [--destdir=DIR] [--no-build] [--from=DIR]
#                           [--no-strip] [--gateway[=BIN]] [--unitdir=DIR]
#                           [--no-manifest]
#        scripts/install.sh --uninstall [--prefix=DIR] [--destdir=DIR]
#        scripts/install.sh --check-shadow [--prefix=DIR] [--libdir=DIR]
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
#   --no-manifest write no manifest (debian/rules: dpkg keeps the packages' lists)
#   --uninstall   removes every file the manifest lists (PREFIX/share/rsmodbus/
#                 install-manifest.txt, written by each install; a second install
#                 adds to it), the manifest, and the directories the installs made,
#                 when empty; then runs ldconfig as an install does
#   --check-shadow  only says whether LIBDIR/libmodbus.so.5 would take over from the
#                 system's libmodbus.so.5 (below), and exits
#
# Shadowing: when LIBDIR is in the loader's search path (ld.so.conf) before the
# directory of a libmodbus.so.5 the system already has (Debian's libmodbus5, e.g.
# /usr/local/lib before /lib/x86_64-linux-gnu), every program on the system linked
# with libmodbus loads rsmodbus after this install. The install says so on stderr,
# loudly, and goes on (no prompt: scripts and packagers run it unattended); the
# packages (librsmodbus5 replaces libmodbus5) or a PREFIX outside the loader's path
# (--prefix=$HOME/.local, with LD_LIBRARY_PATH or an rpath) avoid it.
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
manifest=1
mode=install
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
        --no-manifest) manifest=0 ;;
        --uninstall) mode=uninstall ;;
        --check-shadow) mode=check-shadow ;;
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
D=$destdir
MANIFEST=$prefix/share/rsmodbus/install-manifest.txt

REAL_NAME=libmodbus.so.5.1.0
SONAME=libmodbus.so.5

# shadowed: prints the system's libmodbus.so.5 that LIBDIR's would take over from
# (see the header), if any.
shadowed() {
    command -v ldconfig >/dev/null || return 0
    local mine dirs other odir i_mine=-1 i_other=-1 i=0 d
    mine=$(realpath -m "$libdir")
    mapfile -t dirs < <(ldconfig -v -N -X 2>/dev/null | sed -n 's/^\([^[:space:]][^:]*\):.*/\1/p')
    while read -r other; do
        odir=$(realpath -m "$(dirname "$other")")
        [ "$odir" != "$mine" ] || continue
        i=0 i_mine=-1 i_other=-1
        for d in "${dirs[@]}"; do
            d=$(realpath -m "$d")
            [ "$d" != "$mine" ] || [ $i_mine -ge 0 ] || i_mine=$i
            [ "$d" != "$odir" ] || [ $i_other -ge 0 ] || i_other=$i
            i=$((i + 1))
        done
        if [ $i_mine -ge 0 ] && { [ $i_other -lt 0 ] || [ $i_mine -lt $i_other ]; }; then
            echo "$other"
            return 0
        fi
    done < <(ldconfig -p 2>/dev/null | awk '$1 == "libmodbus.so.5" { print $NF }')
}
warn_shadow() {
    local other
    other=$(shadowed)
    [ -n "$other" ] || return 0
    {
        echo "install.sh: ================================== WARNING =================================="
        echo "install.sh: $libdir comes before $(dirname "$other") in the loader's search path"
        echo "install.sh: (ld.so.conf): $libdir/$SONAME takes over from the system's $other"
        echo "install.sh: for EVERY program on this system linked with libmodbus$1."
        echo "install.sh: scripts/install.sh --uninstall undoes it; the packages, or --prefix outside the"
        echo "install.sh: loader's path (e.g. \$HOME/.local with LD_LIBRARY_PATH), avoid it."
        echo "install.sh: ============================================================================="
    } >&2
}
distro_libmodbus() {
    if command -v dpkg-query >/dev/null &&
        [ "$(dpkg-query -W -f='${Status}' libmodbus5 2>/dev/null)" = "install ok installed" ]; then
        echo " (the distribution's libmodbus5 $(dpkg-query -W -f='${Version}' libmodbus5))"
    fi
}

if [ "$mode" = check-shadow ]; then
    other=$(shadowed)
    if [ -n "$other" ]; then
        warn_shadow "$(distro_libmodbus)"
        exit 1
    fi
    echo "install.sh: $libdir/$SONAME would take over from no other libmodbus.so.5 the loader knows"
    exit 0
fi

if [ "$mode" = uninstall ]; then
    [ -f "$D$MANIFEST" ] || { echo "install.sh: no manifest $D$MANIFEST: nothing installed there by install.sh" >&2; exit 1; }
    mapfile -t entries < <(grep -v -e '^#' -e '^$' "$D$MANIFEST")
    nfiles=0
    for path in "${entries[@]}"; do
        case $path in */) continue ;; esac
        if [ -e "$D$path" ] || [ -L "$D$path" ]; then
            rm -f "$D$path"
            nfiles=$((nfiles + 1))
        fi
    done
    rm -f "$D$MANIFEST"
    # The directories the installs made, deepest first, when nothing else is in them.
    ndirs=0
    while IFS= read -r dir; do
        if [ -d "$D$dir" ] && rmdir "$D$dir" 2>/dev/null; then ndirs=$((ndirs + 1)); fi
    done < <(printf '%s\n' "${entries[@]}" | grep '/$' | awk '{ print length($0) "\t" $0 }' | sort -rn | cut -f2-)
    echo "install.sh: removed $nfiles files and $ndirs directories listed in ${D}$MANIFEST"
    if [ -z "$D" ] && [ "$(id -u)" = 0 ] && command -v ldconfig >/dev/null; then
        ldconfig
    fi
    exit 0
fi

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

# The manifest: every file installed, and every directory made ("DIR/"), without
# DESTDIR; an earlier install's entries stay (a second install adds to them).
declare -a made=() files=() before=()
[ ! -f "$D$MANIFEST" ] || mapfile -t before < <(grep -v -e '^#' -e '^$' "$D$MANIFEST")
mkdirs() { # DIR...: install -d, remembering the directories that were not there
    local d p
    for d in "$@"; do
        p=$d
        while [ "$p" != / ] && [ "$p" != . ] && [ ! -d "$D$p" ]; do
            made+=("$p/")
            p=$(dirname "$p")
        done
        install -d "$D$d"
    done
}
ours() { # PATH...: files about to be installed; says which ones replace a file not ours
    local f
    for f in "$@"; do
        if { [ -e "$D$f" ] || [ -L "$D$f" ]; } && ! printf '%s\n' "${before[@]}" | grep -qxF -- "$f"; then
            echo "install.sh: replacing $D$f, which no install.sh installed (--uninstall removes, not restores it)" >&2
        fi
        files+=("$f")
    done
}

[ -n "$D" ] || warn_shadow "$(distro_libmodbus)"
mkdirs "$libdir/pkgconfig" "$includedir/modbus" "$mandir/man3" "$mandir/man7"
headers=(modbus.h modbus-rtu.h modbus-tcp.h modbus-tls.h modbus-version.h)
ours "$libdir/$REAL_NAME" "$libdir/$SONAME" "$libdir/libmodbus.so" "$libdir/libmodbus.a" \
    "$libdir/pkgconfig/libmodbus.pc" "${headers[@]/#/$includedir/modbus/}"
for page in target/man/man3/*.3 target/man/man7/*.7; do
    ours "$mandir/$(basename "$(dirname "$page")")/$(basename "$page")"
done

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

install -m 0644 "${headers[@]/#/include/}" "$D$includedir/modbus/"
install -m 0644 target/man/man3/*.3 "$D$mandir/man3/"
install -m 0644 target/man/man7/*.7 "$D$mandir/man7/"

if [ -n "$gateway" ]; then
    mkdirs "$prefix/bin" "$mandir/man8" "$unitdir"
    ours "$prefix/bin/rsmodbus-gateway" "$mandir/man8/rsmodbus-gateway.8" "$unitdir/rsmodbus-gateway@.service"
    install -m 0755 "$gateway" "$D$prefix/bin/rsmodbus-gateway"
    [ "$do_strip" = 0 ] || strip --strip-unneeded --remove-section=.comment "$D$prefix/bin/rsmodbus-gateway"
    install -m 0644 target/man/man8/rsmodbus-gateway.8 "$D$mandir/man8/"
    sed "s|/usr/bin/rsmodbus-gateway|$prefix/bin/rsmodbus-gateway|" gateway/rsmodbus-gateway@.service \
        >"$D$unitdir/rsmodbus-gateway@.service"
    chmod 0644 "$D$unitdir/rsmodbus-gateway@.service"
    echo "installed the gateway into ${D:-/}: $prefix/bin/rsmodbus-gateway, $mandir/man8/rsmodbus-gateway.8," \
        "$unitdir/rsmodbus-gateway@.service"
fi
if [ "$manifest" = 1 ]; then
    [ -d "$D$(dirname "$MANIFEST")" ] || mkdirs "$(dirname "$MANIFEST")"
    {
        echo "# rsmodbus: the files scripts/install.sh installed (DIR/: a directory it made);"
        echo "# scripts/install.sh --uninstall --prefix=$prefix${D:+ --destdir=$D} removes them"
        printf '%s\n' "${before[@]}" "${files[@]}" "${made[@]}" | awk 'NF && !seen[$0]++'
    } >"$D$MANIFEST.new"
    mv "$D$MANIFEST.new" "$D$MANIFEST"
    chmod 0644 "$D$MANIFEST"
fi
echo "installed rsmodbus into ${D:-/}: $libdir/$REAL_NAME (+ $SONAME, libmodbus.so, libmodbus.a," \
    "pkgconfig/libmodbus.pc), $includedir/modbus/, $(ls target/man/man3 | wc -l) pages in $mandir/man3"
if [ -z "$D" ] && [ "$(id -u)" = 0 ] && command -v ldconfig >/dev/null; then
    ldconfig
fi
