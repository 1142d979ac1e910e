#!/usr/bin/env bash
# symbols.sh: the ELF identity and exported symbols of the built libmodbus.so
# must be those of a drop-in for Debian's libmodbus.so.5.
#
# Checks, against committed data in abi/ (no network, no Debian library needed):
#   - SONAME is libmodbus.so.5; DT_NEEDED holds only libc.so.6 plus the entries
#     listed as "needed" in abi/symbols-intended-differences.txt; no RPATH/RUNPATH,
#     no TEXTREL, no symbol version definitions (Debian's exports are unversioned);
#   - the defined dynamic symbols are exactly the rows of abi/exports.txt, which are
#     Debian's 74 (abi/debian-libmodbus5.nm) minus the "omit" entries plus the rows
#     beyond Debian's (libmodbus functions newer than 3.1.6, rsmodbus' own), with
#     Debian's symbol types; the rows of Debian's symbols carry Debian's minimum
#     versions; all 67 libmodbus 3.1.12 functions are there; the three
#     libmodbus_version_* objects are read-only (R) and 4 bytes;
#   - abi/debian-libmodbus5.nm agrees with abi/debian-libmodbus5.symbols;
#   - target/<profile>/libmodbus.so.5 and libmodbus.so.5.1.0 resolve to the library;
#   - a C program linked with -lmodbus against the build tree loads this library
#     (not the system's), and the version objects hold the values of modbus-version.h;
#     a program built against Debian's libmodbus runs on it via LD_LIBRARY_PATH.
#
# Usage: c-tests/suites/symbols.sh [path/to/libmodbus.so]
#        (default target/${PROFILE:-release}/libmodbus.so; run `cargo build --release` first)
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"

case ${1:-} in
-h | --help)
    sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"
    exit 0 ;;
-*)
    echo "symbols.sh: unknown option $1 (usage: c-tests/suites/symbols.sh [path/to/libmodbus.so])" >&2
    exit 2 ;;
esac

NAME=check-symbols
PROFILE=${PROFILE:-release}
LIB=${1:-${CARGO_TARGET_DIR:-target}/$PROFILE/libmodbus.so}
[[ -f "$LIB" ]] || { echo "FAIL: $NAME: $LIB not found (run cargo build --release)"; exit 1; }
LIBDIR=$(cd "$(dirname -- "$LIB")" && pwd)
DEB_NM=abi/debian-libmodbus5.nm
DEB_SYMBOLS=abi/debian-libmodbus5.symbols
INTENDED=abi/symbols-intended-differences.txt
EXPORTS=abi/exports.txt
INCLUDE_DIR=${INCLUDE_DIR:-include}
CC=${CC:-gcc}

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

errors=()
err() { errors+=("$*"); }
trim() {
    local s=$1
    s=${s#"${s%%[![:space:]]*}"}
    printf '%s' "${s%"${s##*[![:space:]]}"}"
}

for tool in nm objdump readelf; do
    command -v "$tool" >/dev/null || { echo "FAIL: $NAME: $tool not found (binutils)"; exit 1; }
done

# --- the intended-differences list -------------------------------------------------
declare -A omit=() needed_ok=()
while IFS= read -r line; do
    [[ $line =~ ^[[:space:]]*(#|$) ]] && continue
    IFS='|' read -r kind name reason <<<"$line"
    kind=$(trim "$kind")
    name=$(trim "$name")
    reason=$(trim "${reason:-}")
    if [[ -z $name || -z $reason ]]; then
        err "malformed line in $INTENDED (need kind | name | reason): $line"
        continue
    fi
    case $kind in
    omit) omit[$name]=1 ;;
    needed) needed_ok[$name]=1 ;;
    api | extension) err "'$kind' line in $INTENDED: the additions are the rows of $EXPORTS now: $line" ;;
    *) err "unknown kind '$kind' in $INTENDED: $line" ;;
    esac
done <"$INTENDED"

# --- the table of the exports --------------------------------------------------------
declare -A row_since=()
while IFS= read -r line; do
    [[ $line =~ ^[[:space:]]*(#|$) ]] && continue
    IFS='|' read -r name header since page extra <<<"$line"
    name=$(trim "$name")
    since=$(trim "${since:-}")
    page=$(trim "${page:-}")
    if [[ -z $name || -z $since || -z $page || -n ${extra:-} ]]; then
        err "malformed row in $EXPORTS (need name | header | since | page): $line"
        continue
    fi
    [[ -z ${row_since[$name]:-} ]] || err "$EXPORTS has two rows for $name"
    row_since[$name]=$since
done <"$EXPORTS"

# --- Debian's reference list -------------------------------------------------------
declare -A deb_type=() deb_size=() deb_minver=()
while read -r name type size; do
    [[ -z $name || $name == \#* ]] && continue
    deb_type[$name]=$type
    deb_size[$name]=$size
done <"$DEB_NM"
ndeb=${#deb_type[@]}
[[ $ndeb -eq 74 ]] || err "$DEB_NM lists $ndeb symbols, expected Debian's 74"

# The dpkg symbols file must name the same set (it is the packaging-side reference).
sed -n 's/^ \([^@ ]*\)@Base .*/\1/p' "$DEB_SYMBOLS" | LC_ALL=C sort >"$TMP/deb-symbols"
printf '%s\n' "${!deb_type[@]}" | LC_ALL=C sort >"$TMP/deb-nm"
if ! diff -u "$TMP/deb-symbols" "$TMP/deb-nm" >"$TMP/deb-diff"; then
    err "$DEB_SYMBOLS and $DEB_NM disagree: $(tr '\n' ' ' <"$TMP/deb-diff")"
fi

while read -r sym minver _; do
    deb_minver[${sym%@Base}]=$minver
done < <(grep '^ [^ ]*@Base ' "$DEB_SYMBOLS")

for name in "${!omit[@]}"; do
    [[ -n ${deb_type[$name]:-} ]] || err "$INTENDED omits $name, which Debian does not export"
    [[ -z ${row_since[$name]:-} ]] || err "$EXPORTS has a row for $name, which $INTENDED omits"
done
# The rows beyond Debian's symbols are the additions: libmodbus functions newer than
# Debian's 3.1.6, or rsmodbus' own. The rows of Debian's symbols keep its versions.
declare -A add=()
for name in "${!row_since[@]}"; do
    since=${row_since[$name]}
    if [[ -n ${deb_type[$name]:-} ]]; then
        [[ $since == "${deb_minver[$name]:-}" ]] ||
            err "$EXPORTS: $name since $since, but Debian's symbols file says ${deb_minver[$name]:-nothing}"
    elif [[ $since == rsmodbus ]]; then
        add[$name]=extension
    elif [[ $since =~ ^[0-9]+\.[0-9]+\.[0-9]+$ && $(printf '%s\n' 3.1.6 "$since" | sort -V | tail -n 1) != 3.1.6 ]]; then
        add[$name]=api
    else
        err "$EXPORTS: $name since $since, but Debian's libmodbus5 3.1.6 does not export it (a later libmodbus version, or rsmodbus)"
    fi
done

# Expected: Debian - omit + the additions; every one of them a row.
declare -A want_type=() want_size=()
for name in "${!deb_type[@]}"; do
    [[ -n ${omit[$name]:-} ]] && continue
    [[ -n ${row_since[$name]:-} ]] || err "$name (exported by Debian's libmodbus, not omitted in $INTENDED) has no row in $EXPORTS"
    want_type[$name]=${deb_type[$name]}
    want_size[$name]=${deb_size[$name]}
done
for name in "${!add[@]}"; do
    want_type[$name]=T
    want_size[$name]=-
done

# --- ELF identity ------------------------------------------------------------------
objdump -p "$LIB" >"$TMP/dynamic"
soname=$(awk '$1 == "SONAME" { print $2 }' "$TMP/dynamic")
[[ $soname == libmodbus.so.5 ]] || err "SONAME is '${soname:-none}', expected libmodbus.so.5"
needed=$(awk '$1 == "NEEDED" { print $2 }' "$TMP/dynamic")
[[ $needed == *libc.so.6* ]] || err "libc.so.6 is not NEEDED"
for lib in $needed; do
    [[ $lib == libc.so.6 || -n ${needed_ok[$lib]:-} ]] ||
        err "unexpected NEEDED $lib (list it as 'needed' in $INTENDED with a reason, or drop the dependency)"
done
for lib in "${!needed_ok[@]}"; do
    [[ " $(echo $needed) " == *" $lib "* ]] || echo "  note: $lib is listed as needed but not NEEDED any more"
done
if grep -qE '^\s*(RPATH|RUNPATH|TEXTREL)\b' "$TMP/dynamic"; then
    err "unexpected dynamic entries: $(grep -E '^\s*(RPATH|RUNPATH|TEXTREL)\b' "$TMP/dynamic" | tr -s ' \n' ' ')"
fi
if grep -q '^Version definitions' "$TMP/dynamic"; then
    err "the library defines symbol versions; Debian's libmodbus exports unversioned symbols"
fi

# --- exported symbols --------------------------------------------------------------
nm -D --defined-only -S "$LIB" >"$TMP/ours.nm"
declare -A our_type=() our_size=()
while read -r -a f; do
    # "addr size type name" (or "addr type name" for symbols without a size)
    if [[ ${#f[@]} -eq 4 ]]; then
        name=${f[3]} type=${f[2]} size=$((16#${f[1]}))
    else
        name=${f[2]} type=${f[1]} size=0
    fi
    if [[ $name == *@* ]]; then
        err "exported symbol $name carries a version; Debian's are unversioned"
        name=${name%%@*}
    fi
    our_type[$name]=$type
    our_size[$name]=$size
done <"$TMP/ours.nm"

nmissing=0
nunexpected=0
for name in $(printf '%s\n' "${!want_type[@]}" | LC_ALL=C sort); do
    if [[ -z ${our_type[$name]:-} ]]; then
        err "missing symbol: $name (${add[$name]:+row of $EXPORTS, }${add[$name]:-exported by Debian libmodbus})"
        nmissing=$((nmissing + 1))
        continue
    fi
    [[ ${our_type[$name]} == "${want_type[$name]}" ]] ||
        err "symbol $name has type ${our_type[$name]}, expected ${want_type[$name]}"
    if [[ ${want_size[$name]} != - && ${our_size[$name]} != "${want_size[$name]}" ]]; then
        err "object $name is ${our_size[$name]} bytes, expected ${want_size[$name]}"
    fi
done
for name in $(printf '%s\n' "${!our_type[@]}" | LC_ALL=C sort); do
    if [[ -z ${want_type[$name]:-} ]]; then
        if [[ -n ${omit[$name]:-} ]]; then
            err "exported symbol $name is listed as omitted in $INTENDED"
        else
            err "unexpected exported symbol: $name (type ${our_type[$name]}; not in Debian's list, no row in $EXPORTS)"
        fi
        nunexpected=$((nunexpected + 1))
    fi
done

# libmodbus 3.1.12 functions: modbus_* names that are not rsmodbus extensions.
nfunc=0
for name in "${!our_type[@]}"; do
    [[ $name == modbus_* && ${our_type[$name]} == T && ${add[$name]:-} != extension ]] && nfunc=$((nfunc + 1))
done
next=0
for name in "${!add[@]}"; do
    [[ ${add[$name]} == extension && -n ${our_type[$name]:-} ]] && next=$((next + 1))
done
nwant_func=0
for name in "${!want_type[@]}"; do
    [[ $name == modbus_* && ${add[$name]:-} != extension ]] && nwant_func=$((nwant_func + 1))
done
[[ $nwant_func -eq 67 ]] || err "the expected set has $nwant_func libmodbus functions, libmodbus 3.1.12 has 67"
for v in major minor micro; do
    name=libmodbus_version_$v
    [[ ${our_type[$name]:-} == R && ${our_size[$name]:-} == 4 ]] ||
        err "$name must be a 4-byte read-only object (R), got type ${our_type[$name]:-none} size ${our_size[$name]:-none}"
done

# --- symlinks in the build tree ----------------------------------------------------
real_lib=$(readlink -f "$LIB")
for link in libmodbus.so.5 libmodbus.so.5.1.0; do
    if [[ ! -e "$LIBDIR/$link" ]]; then
        err "$LIBDIR/$link does not exist (build.rs creates it)"
    elif [[ $(readlink -f "$LIBDIR/$link") != "$real_lib" ]]; then
        err "$LIBDIR/$link resolves to $(readlink -f "$LIBDIR/$link"), not $real_lib"
    fi
done

# --- run time: which library gets loaded -------------------------------------------
cat >"$TMP/which-lib.c" <<'EOF'
/* Prints which file provides the libmodbus functions, and the version objects.
   Declares what it uses itself, so that it does not depend on any header. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>

extern const unsigned int libmodbus_version_major;
extern const unsigned int libmodbus_version_minor;
extern const unsigned int libmodbus_version_micro;
const char *modbus_strerror(int errnum);

int main(void)
{
    Dl_info info;
    void *fn = dlsym(RTLD_DEFAULT, "modbus_strerror");
    const char *(*ext)(void);

    /* Not &libmodbus_version_major: the executable holds a copy-relocated copy. */
    if (fn == NULL || dladdr(fn, &info) == 0 || info.dli_fname == NULL) {
        printf("loaded-from ?\n");
        return 1;
    }
    printf("loaded-from %s\n", info.dli_fname);
    printf("objects %u.%u.%u\n", libmodbus_version_major, libmodbus_version_minor,
           libmodbus_version_micro);
    printf("strerror %s\n", modbus_strerror(112345690));
    *(void **) &ext = dlsym(RTLD_DEFAULT, "rsmodbus_version");
    printf("rsmodbus_version %s\n", ext != NULL ? ext() : "(absent)");
    return 0;
}
EOF
check_run() { # label, expected major.minor.micro of the objects, command...
    local label=$1 want=$2
    shift 2
    local out
    if ! out=$("$@" 2>&1); then
        err "$label: program failed: $out"
        return
    fi
    local from objects ext
    from=$(sed -n 's/^loaded-from //p' <<<"$out")
    objects=$(sed -n 's/^objects //p' <<<"$out")
    ext=$(sed -n 's/^rsmodbus_version //p' <<<"$out")
    [[ -n $from && $(readlink -f "$from") == "$real_lib" ]] ||
        err "$label: loaded ${from:-?} instead of $real_lib"
    [[ $objects == "$want" ]] || err "$label: libmodbus_version_* = $objects, expected $want"
    [[ -n $ext && $ext != "(absent)" ]] || err "$label: rsmodbus_version not found at run time"
    echo "  $label: loaded $from, version objects $objects, rsmodbus_version $ext"
}
header_version=$(sed -n 's/^#define LIBMODBUS_VERSION_STRING "\(.*\)"$/\1/p' "$INCLUDE_DIR/modbus-version.h")
if "$CC" -Wall -Wextra -Werror "$TMP/which-lib.c" -o "$TMP/which-ours" \
    -L"$LIBDIR" -lmodbus -Wl,-rpath,"$LIBDIR" 2>"$TMP/cc.log"; then
    check_run "linked with -L$LIBDIR -lmodbus" "$header_version" "$TMP/which-ours"
else
    err "cannot link a C program against $LIBDIR: $(cat "$TMP/cc.log")"
fi
if [[ -e /usr/lib/x86_64-linux-gnu/libmodbus.so ]]; then
    # Linked against Debian's library, run on ours: the drop-in case.
    if "$CC" -Wall -Wextra -Werror "$TMP/which-lib.c" -o "$TMP/which-deb" \
        -L/usr/lib/x86_64-linux-gnu -lmodbus 2>"$TMP/cc.log"; then
        check_run "built against Debian's libmodbus, LD_LIBRARY_PATH=$LIBDIR" "$header_version" \
            env LD_LIBRARY_PATH="$LIBDIR" "$TMP/which-deb"
    else
        err "cannot build against Debian's libmodbus: $(cat "$TMP/cc.log")"
    fi
else
    echo "  note: Debian's libmodbus-dev not installed; drop-in run skipped"
fi

# --- verdict -----------------------------------------------------------------------
nours=${#our_type[@]}
nomit=${#omit[@]}
nadd=${#add[@]}
if [[ ${#errors[@]} -gt 0 ]]; then
    printf '  %s\n' "${errors[@]}"
    echo "FAIL: $NAME: ${#errors[@]} problem(s); $nmissing missing, $nunexpected unexpected" \
        "($nours exported; expected $ndeb Debian - $nomit omitted + $nadd added)"
    exit 1
fi
echo "PASS: $NAME: $nours symbols = $ndeb Debian - $nomit omitted + $nadd added" \
    "($nfunc libmodbus 3.1.12 functions, 3 version objects R/4 bytes, $next rsmodbus extensions);" \
    "SONAME $soname;" \
    "NEEDED $(echo $needed)"
