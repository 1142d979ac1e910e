#!/usr/bin/env bash
# headers.sh: the committed C headers are cbindgen's output, declare exactly
# libmodbus' API, and compile unchanged with C and C++ programs written for libmodbus.
#
# Checks:
#   generated   include/*.h are byte-identical to the headers build.rs generated with
#               cbindgen in OUT_DIR (fix: RSMODBUS_UPDATE_HEADERS=1 cargo build)
#   prototypes  every MODBUS_API prototype equals Debian's (types and parameter
#               names, whitespace normalised) or declares a function that Debian's
#               headers lack and that has a row in abi/exports.txt; every row is
#               declared in the header it names (its extensions section: "modbus.h
#               extensions"). The signatures beyond Debian's are pinned by the
#               SYNOPSIS of their pages (c-tests/suites/man.sh) and, for libmodbus'
#               own, by the ABI probe
#   c-alone     each header compiles on its own as C89, C99 and C11 (also without
#               the unix macros: -U__unix__ -Uunix) with
#               -Wall -Wextra -Werror -pedantic-errors
#   cxx-alone   each header compiles on its own as C++98, C++11 and C++17, same flags
#   linux-only  the comment of every epoll-based call in modbus.h (modbus_multi_*,
#               modbus_server_*, modbus_get_pollfd) says "Linux only (epoll)."
#   readme      the headers README.md names (`modbus*.h`) are the files of include/ and
#               this script's list, no more and no fewer
#   cxx-linkage a C++ file using the API references the functions unmangled
#               (extern "C" guards work) and links against the built library
#   examples    Debian's libmodbus example programs (unit tests, random tests,
#               bandwidth tests, version.c) compile unchanged against include/ with
#               -Wall -Wextra -Werror and link against the built library
#   pkg-config  target/<profile>/libmodbus.pc and libmodbus-uninstalled.pc: version
#               equals LIBMODBUS_VERSION_STRING, flags build and run version.c
#   abi-probe   c-tests/suites/abi.sh (constants, layout, macros, signatures vs Debian)
#
# Usage: c-tests/suites/headers.sh   (after `cargo build --release`; it runs cargo
#        build again only to learn OUT_DIR, which is a no-op on a fresh tree)
# Env:   PROFILE (release), DEBIAN_MODBUS_INCLUDE (/usr/include/modbus),
#        LIBMODBUS_EXAMPLES (/usr/share/doc/libmodbus-dev/examples), CC, C            static=ok
            out=$("$TMP/version-static" 2>&1 || true)
            [[ $out == *"$header_version"* ]] || err "statically linked version.c printed: $out"
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"

NAME=check-headers
PROFILE=${PROFILE:-release}
DEB_INC=${DEBIAN_MODBUS_INCLUDE:-/usr/include/modbus}
EXAMPLES=${LIBMODBUS_EXAMPLES:-/usr/share/doc/libmodbus-dev/examples}
CC=${CC:-gcc}
CXX=${CXX:-g++}
HEADERS=(modbus.h modbus-rtu.h modbus-tcp.h modbus-tls.h modbus-version.h)
EXPORTS=abi/exports.txt
TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
LIBDIR=$TARGET_DIR/$PROFILE
WFLAGS=(-Wall -Wextra -Werror)

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

passed=0
failed=0
failures=()
current=
current_errors=()
begin() {
    current=$1
    current_errors=()
}
err() { current_errors+=("$*"); }
end() { # end [summary]
    if [[ ${#current_errors[@]} -eq 0 ]]; then
        passed=$((passed + 1))
        echo "  ok   $current${1:+: $1}"
    else
        failed=$((failed + 1))
        failures+=("$current")
        echo "  FAIL $current"
        printf '       %s\n' "${current_errors[@]}" | head -n 80
    fi
}
# the diagnostic lines of a compiler log, indented (for error messages)
excerpt() {
    { grep -E 'error|warning|undefined' "$1" || head -n 8 "$1"; } | head -n "${2:-6}" | sed 's/^/         | /'
}

# --- generated: committed headers == cbindgen output -------------------------------
begin generated
out_dir=
if ! cargo build --profile "$PROFILE" --message-format=json-render-diagnostics \
    >"$TMP/cargo.json" 2>"$TMP/cargo.log"; then
    echo "  note: cargo build failed (headers are compared if build.rs ran):"
    grep -E '^(error|warning: rsmodbus)' "$TMP/cargo.log" | head -5 | sed 's/^/       /' || true
fi
out_dir=$(grep '"reason":"build-script-executed"' "$TMP/cargo.json" |
    grep '"package_id":"[^"]*rsmodbus' |
    sed -E 's/.*"out_dir":"([^"]*)".*/\1/' | tail -n 1 || true)
if [[ -z $out_dir || ! -d "$out_dir/include" ]]; then
    err "build.rs produced no headers (no OUT_DIR/include); see cargo build output"
else
    for h in "${HEADERS[@]}"; do
        if [[ ! -f "include/$h" ]]; then
            err "include/$h is missing (RSMODBUS_UPDATE_HEADERS=1 cargo build --release)"
        elif ! diff -u "include/$h" "$out_dir/include/$h" >"$TMP/$h.diff"; then
            err "include/$h differs from cbindgen's output (RSMODBUS_UPDATE_HEADERS=1 cargo build --release):"
            current_errors+=("$(head -n 30 "$TMP/$h.diff" | sed 's/^/         | /')")
        fi
        if grep -n '@[A-Z_]*@' "include/$h" >"$TMP/placeholders" 2>/dev/null; then
            err "include/$h has unsubstituted placeholders: $(tr '\n' ' ' <"$TMP/placeholders")"
        fi
    done
fi
end "${#HEADERS[@]} headers identical to ${out_dir:+OUT_DIR/include}"

# OUT_DIR is <target>/<profile>/build/rsmodbus-<hash>/out: the library is next to build/.
[[ -n $out_dir ]] && LIBDIR=${out_dir%/build/*}
have_lib=false
[[ -f "$LIBDIR/libmodbus.so" ]] && have_lib=true

# --- prototypes: same declarations as Debian's libmodbus ---------------------------
# Normalised form: comments and directives dropped, MODBUS_API removed, one space
# between tokens, none around parentheses and commas, "type *name" for pointers.
protos() {
    cat "$@" | "$CC" -fpreprocessed -dD -E -P -x c - 2>/dev/null |
        grep -v '^[[:space:]]*#' | tr '\n\t' '  ' | grep -o 'MODBUS_API[^;]*;' |
        sed -E 's/^MODBUS_API +//; s/ +/ /g; s/ *([(),]) */\1/g; s/,/, /g; s/ *\* */ */g; s/\( \*/(*/g; s/ ;$/;/' |
        LC_ALL=C sort
}
fname() { sed -E 's/^[^(]*[ *]([A-Za-z_][A-Za-z0-9_]*)\(.*/\1/'; }
# The names a header (or part of one) declares: its functions and extern objects. (A
# part of modbus.h ends inside its include guard, which the preprocessor reports.)
declared() {
    protos "$1" | fname || true
    sed -n 's/^extern const unsigned int \([A-Za-z_][A-Za-z0-9_]*\);$/\1/p' "$1"
}
begin prototypes
declare -A row_header=()
while IFS= read -r line; do
    [[ $line =~ ^[[:space:]]*(#|$) ]] && continue
    IFS='|' read -r name header _ <<<"$line"
    name=$(echo $name)
    row_header[$name]=$(echo $header)
done <"$EXPORTS"
if [[ ! -f "$DEB_INC/modbus.h" ]]; then
    err "Debian's headers not found in $DEB_INC (apt-get install libmodbus-dev)"
else
    protos "$DEB_INC"/modbus.h "$DEB_INC"/modbus-rtu.h "$DEB_INC"/modbus-tcp.h >"$TMP/deb.protos"
    protos include/modbus.h include/modbus-rtu.h include/modbus-tcp.h include/modbus-tls.h >"$TMP/ours.protos"
    while IFS= read -r p; do
        name=$(fname <<<"$p")
        if grep -qxF -- "$p" "$TMP/ours.protos"; then
            continue
        fi
        mine=$(grep -E "[ *]$name\(" "$TMP/ours.protos" || true)
        if [[ -z $mine ]]; then
            err "$name is not declared (Debian: $p)"
        else
            err "$name differs: Debian: $p  ours: $mine"
        fi
    done <"$TMP/deb.protos"
    nadd=0
    while IFS= read -r p; do
        grep -qxF -- "$p" "$TMP/deb.protos" && continue
        name=$(fname <<<"$p")
        # A function of Debian's headers declared differently was reported above.
        grep -qE "[ *]$name\(" "$TMP/deb.protos" && continue
        if [[ -n ${row_header[$name]:-} ]]; then
            nadd=$((nadd + 1))
        else
            err "unexpected declaration (not in Debian's headers, no row in $EXPORTS): $p"
        fi
    done <"$TMP/ours.protos"
fi
# Each row in its header; modbus.h's extensions section begins at its comment.
ext_line=$(grep -n '^ \* rsmodbus extensions\.' include/modbus.h | head -n 1 | cut -d: -f1)
if [[ -z $ext_line ]]; then
    err "include/modbus.h has no \" * rsmodbus extensions.\" comment line (the extensions section)"
else
    head -n $((ext_line - 1)) include/modbus.h >"$TMP/modbus.h"
    tail -n +"$ext_line" include/modbus.h >"$TMP/modbus.h extensions"
    for h in modbus-rtu.h modbus-tcp.h modbus-tls.h; do cp "include/$h" "$TMP/$h"; done
    declare -A where=()
    for h in modbus.h "modbus.h extensions" modbus-rtu.h modbus-tcp.h modbus-tls.h; do
        while read -r name; do where[$name]=$h; done < <(declared "$TMP/$h")
    done
    for name in "${!row_header[@]}"; do
        if [[ -z ${where[$name]:-} ]]; then
            err "$name (row of $EXPORTS) is not declared; its row says ${row_header[$name]}"
        elif [[ ${where[$name]} != "${row_header[$name]}" ]]; then
            err "$name is declared in ${where[$name]}, its row of $EXPORTS says ${row_header[$name]}"
        fi
    done
    for name in "${!where[@]}"; do
        [[ -n ${row_header[$name]:-} ]] || err "$name is declared in ${where[$name]} but has no row in $EXPORTS"
    done
fi
end "$(wc -l <"$TMP/ours.protos" 2>/dev/null || echo 0) prototypes: $(wc -l <"$TMP/deb.protos" 2>/dev/null || echo 0) as in Debian's headers + ${nadd:-0} beyond them, each a row of $EXPORTS; ${#row_header[@]} rows, each declared in its header"

# --- c-alone / cxx-alone: each header is self-contained -----------------------------
# Each also without the unix macros (-U__unix__ -Uunix): then <sys/param.h>, which
# brings size_t along on glibc, is not included, and the header must stand alone.
begin c-alone
for h in "${HEADERS[@]}"; do
    printf '#include <%s>\ntypedef int translation_unit_not_empty;\n' "$h" >"$TMP/alone.c"
    for std in c89 c99 c11; do
        for unix in "" "-U__unix__ -Uunix"; do
            # shellcheck disable=SC2086 # $unix: two flags or none
            "$CC" -std=$std $unix -pedantic-errors "${WFLAGS[@]}" -Iinclude -fsyntax-only "$TMP/alone.c" \
                2>"$TMP/cc.log" || { err "$h alone, -std=$std $unix:"; current_errors+=("$(excerpt "$TMP/cc.log")"); }
        done
    done
done
end "${#HEADERS[@]} headers x C89/C99/C11, with and without the unix macros"

begin cxx-alone
for h in "${HEADERS[@]}"; do
    printf '#include <%s>\n' "$h" >"$TMP/alone.cpp"
    for std in c++98 c++11 c++17; do
        for unix in "" "-U__unix__ -Uunix"; do
            # shellcheck disable=SC2086 # $unix: two flags or none
            "$CXX" -std=$std $unix -pedantic-errors "${WFLAGS[@]}" -Iinclude -fsyntax-only "$TMP/alone.cpp" \
                2>"$TMP/cc.log" || { err "$h alone, -std=$std $unix:"; current_errors+=("$(excerpt "$TMP/cc.log")"); }
        done
    done
done
end "${#HEADERS[@]} headers x C++98/C++11/C++17, with and without the unix macros"

# --- linux-only: the epoll-based calls are marked -----------------------------------
# The doc comment just before each declaration (cbindgen's copy of the Rust one).
begin linux-only
awk '
    /^\/\*/ { doc = ""; incomment = 1 }
    incomment { doc = doc " " $0; if ($0 ~ /\*\//) incomment = 0; next }
    /^MODBUS_API/ { decl = "" }
    /^MODBUS_API/ || decl != "" {
        decl = decl " " $0
        if (decl ~ /\(/) {
            sub(/\(.*/, "", decl)
            n = split(decl, w, /[ *]+/)
            print w[n], (doc ~ /Linux only \(epoll\)\./ ? "marked" : "unmarked")
            decl = ""; doc = ""
        }
    }' include/modbus.h >"$TMP/linux-only"
nlinux=0
while read -r name marked; do
    case $name in modbus_multi_* | modbus_server_* | modbus_get_pollfd) ;; *) continue ;; esac
    nlinux=$((nlinux + 1))
    [[ $marked == marked ]] ||
        err "$name: its comment in include/modbus.h does not say \"Linux only (epoll).\" (add it to its doc comment in src/ffi/, then RSMODBUS_UPDATE_HEADERS=1 cargo build --release)"
done <"$TMP/linux-only"
[[ $nlinux -gt 0 ]] || err "no modbus_multi_*, modbus_server_* or modbus_get_pollfd declaration found in include/modbus.h"
end "$nlinux epoll-based calls, each marked \"Linux only (epoll).\""

# --- readme: the header list README.md gives is the one in include/ -------------------
begin readme
in_readme=$(grep -o '`modbus[-a-z]*\.h`' README.md | tr -d '`' | sort -u)
in_include=$(cd include && ls -- *.h | sort)
in_script=$(printf '%s\n' "${HEADERS[@]}" | sort)
[[ $in_readme == "$in_include" ]] ||
    err "README.md names:" $in_readme "include/ has:" $in_include
[[ $in_script == "$in_include" ]] ||
    err "HEADERS in this script:" $in_script "include/ has:" $in_include
end "$(wc -w <<<"$in_include") headers, each named in README.md"

# --- cxx-linkage: extern "C" guards ------------------------------------------------
begin cxx-linkage
cat >"$TMP/linkage.cpp" <<'EOF'
// Uses the API from C++ the way an application would.
#include <modbus.h>
#include <cstdio>

static void custom_rts(modbus_t *ctx, int on) { (void) ctx; (void) on; }

int main()
{
    uint16_t regs[4] = {0x1234, 0x5678, 0, 0};
    uint8_t bytes[2];
    modbus_t *tcp = modbus_new_tcp("127.0.0.1", MODBUS_TCP_DEFAULT_PORT);
    modbus_t *rtu = modbus_new_rtu("/dev/null", 19200, 'N', 8, 1);
    modbus_mapping_t *map = modbus_mapping_new(1, 1, 1, 1);

    MODBUS_SET_INT16_TO_INT8(bytes, 0, 0x1234);
    MODBUS_SET_INT32_TO_INT16(regs, 2, MODBUS_GET_INT32_FROM_INT16(regs, 0));
    if (rtu != NULL) {
        modbus_rtu_set_custom_rts(rtu, custom_rts);
        modbus_free(rtu);
    }
    if (tcp != NULL) {
        modbus_set_error_recovery(tcp, MODBUS_ERROR_RECOVERY_LINK);
        modbus_free(tcp);
    }
    modbus_mapping_free(map);
    std::printf("%s %u %x %s\n", LIBMODBUS_VERSION_STRING, libmodbus_version_micro,
                (unsigned) MODBUS_GET_INT16_FROM_INT8(bytes, 0), modbus_strerror(EMBBADCRC));
    return 0;
}
EOF
if "$CXX" -std=c++11 "${WFLAGS[@]}" -Iinclude -c "$TMP/linkage.cpp" -o "$TMP/linkage.o" 2>"$TMP/cc.log"; then
    nm -u "$TMP/linkage.o" >"$TMP/linkage.undef"
    for fn in modbus_new_tcp modbus_new_rtu modbus_rtu_set_custom_rts modbus_set_error_recovery \
        modbus_mapping_new modbus_free modbus_strerror libmodbus_version_micro; do
        grep -qw "$fn" "$TMP/linkage.undef" || err "C++ does not reference $fn by its C name"
    done
    if grep -E '_Z[A-Za-z0-9_]*(modbus|libmodbus)' "$TMP/linkage.undef" >"$TMP/mangled"; then
        err "C++ references mangled names: $(tr -s ' \n' ' ' <"$TMP/mangled")"
    fi
    if $have_lib; then
        if "$CXX" "$TMP/linkage.o" -o "$TMP/linkage" -L"$LIBDIR" -lmodbus -Wl,-rpath,"$LIBDIR" \
            2>"$TMP/cc.log"; then
            "$TMP/linkage" >"$TMP/linkage.out" 2>&1 || err "the C++ program failed: $(cat "$TMP/linkage.out")"
        else
            err "the C++ program does not link against $LIBDIR:"
            current_errors+=("$(excerpt "$TMP/cc.log")")
        fi
    fi
else
    err "the C++ program does not compile:"
    current_errors+=("$(excerpt "$TMP/cc.log")")
fi
end "$($have_lib && echo "compiled, linked and ran" || echo "compiled (no library built, link skipped)")"

# --- examples: Debian's libmodbus programs compile unchanged -------------------------
begin examples
nex=0
if [[ ! -d $EXAMPLES ]]; then
    err "Debian's examples not found in $EXAMPLES (apt-get install libmodbus-dev)"
else
    for src in "$EXAMPLES"/*.c; do
        base=$(basename "$src" .c)
        nex=$((nex + 1))
        if ! "$CC" -std=gnu11 "${WFLAGS[@]}" -Iinclude -I"$EXAMPLES" -c "$src" -o "$TMP/$base.o" \
            2>"$TMP/cc.log"; then
            err "$base.c does not compile against include/:"
            current_errors+=("$(excerpt "$TMP/cc.log")")
            continue
        fi
        if $have_lib && ! "$CC" "$TMP/$base.o" -o "$TMP/$base" -L"$LIBDIR" -lmodbus \
            -Wl,-rpath,"$LIBDIR" 2>"$TMP/cc.log"; then
            err "$base does not link against $LIBDIR/libmodbus.so:"
            current_errors+=("$(excerpt "$TMP/cc.log")")
        fi
    done
fi
end "$nex programs$($have_lib && echo " compiled and linked" || echo " compiled (link skipped)")"

# --- pkg-config --------------------------------------------------------------------
begin pkg-config
header_version=$(sed -n 's/^#define LIBMODBUS_VERSION_STRING "\(.*\)"$/\1/p' include/modbus-version.h)
if ! command -v pkg-config >/dev/null; then
    err "pkg-config not installed"
elif [[ ! -f "$LIBDIR/libmodbus.pc" || ! -f "$LIBDIR/libmodbus-uninstalled.pc" ]]; then
    err "$LIBDIR/libmodbus.pc or libmodbus-uninstalled.pc missing (written by build.rs)"
else
    pc() { PKG_CONFIG_PATH="$LIBDIR" PKG_CONFIG_DISABLE_UNINSTALLED=1 pkg-config "$@" libmodbus | sed 's/ *$//'; }
    v=$(pc --modversion)
    [[ $v == "$header_version" ]] || err "libmodbus.pc version $v != LIBMODBUS_VERSION_STRING $header_version"
    cflags=$(pc --cflags)
    libs=$(pc --libs)
    [[ $cflags == -I*/include/modbus ]] || err "libmodbus.pc Cflags '$cflags' do not end in include/modbus"
    [[ $libs == "-L"*" -lmodbus" ]] || err "libmodbus.pc Libs '$libs' are not '-L\${libdir} -lmodbus'"
    # The uninstalled variant must build and run a libmodbus program against this tree.
    tree_flags=$(PKG_CONFIG_PATH="$LIBDIR" pkg-config --cflags --libs libmodbus)
    if $have_lib && [[ -f "$EXAMPLES/version.c" ]]; then
        # shellcheck disable=SC2086 # word splitting of pkg-config output is intended
        if "$CC" "${WFLAGS[@]}" "$EXAMPLES/version.c" -o "$TMP/version" $tree_flags \
            -Wl,-rpath,"$LIBDIR" 2>"$TMP/cc.log"; then
            out=$("$TMP/version" 2>&1 || true)
            [[ $out == *"$header_version"* ]] ||
                err "version.c built with pkg-config flags printed: $out"
        else
            err "version.c does not build with \`pkg-config --cflags --libs libmodbus\` ($tree_flags):"
            current_errors+=("$(excerpt "$TMP/cc.log")")
        fi
    fi
    # Static linking: libmodbus.a plus the Libs.private of libmodbus.pc.
    private=$(pc --static --libs-only-l | sed -E 's/(^| )-lmodbus( |$)/ /; s/^ +//')
    static=skipped
    if $have_lib && [[ -f "$LIBDIR/libmodbus.a" && -f "$EXAMPLES/version.c" ]]; then
        # shellcheck disable=SC2086 # word splitting of pkg-config output is intended
        if "$CC" "${WFLAGS[@]}" -Iinclude "$EXAMPLES/version.c" -o "$TMP/version-static" \
            "$LIBDIR/libmodbus.a" $private 2>"$TMP/cc.log"; then
            static=ok
            out=$("$TMP/version-static" 2>&1 || true)
            [[ $out == *"$header_version"* ]] || err "statically linked version.c printed: $out"
            if objdump -p "$TMP/version-static" | grep -q 'NEEDED.*libmodbus'; then
                err "statically linked version.c still needs a shared libmodbus"
            fi
        else
            err "version.c does not link statically with libmodbus.a and Libs.private ($private):"
            current_errors+=("$(excerpt "$TMP/cc.log")")
        fi
    fi
fi
end "Version $header_version; Cflags ${cflags:-?}; Libs ${libs:-?}; Libs.private ${private:-?} (static link: $static)"

# --- abi-probe ---------------------------------------------------------------------
begin abi-probe
if c-tests/suites/abi.sh >"$TMP/abi.log" 2>&1; then
    end "$(sed -n 's/^PASS: check-abi: //p' "$TMP/abi.log")"
else
    err "c-tests/suites/abi.sh failed:"
    current_errors+=("$(sed 's/^/         | /' "$TMP/abi.log" | head -n 60)")
    end
fi

# --- verdict -----------------------------------------------------------------------
echo "$NAME: $passed passed, $failed failed"
[ -z "${MBT_COUNTS:-}" ] || echo "$passed $failed" >"$MBT_COUNTS"
if [[ $failed -gt 0 ]]; then
    echo "FAIL: $NAME: ${failures[*]}"
    exit 1
fi
echo "PASS: $NAME: headers generated by cbindgen, libmodbus-compatible, compile unchanged"
