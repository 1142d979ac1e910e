#!/usr/bin/env bash
# man.sh: the manual pages, generated from man/src by man/gen-man.py.
#   - every row of abi/exports.txt (every exported symbol: c-tests/suites/symbols.sh
#     compares them with the library) has its section-3 page, the man/src page its
#     row names, and every page documents a row (fails when a function is added
#     without a page);
#   - each page has NAME, SYNOPSIS, DESCRIPTION, RETURN VALUE, ERRORS, EXAMPLE and
#     SEE ALSO; its SYNOPSIS prototypes equal the declarations of include/*.h;
#     cross references resolve (man/check-pages.py);
#   - `man --warnings=all -l` and `groff -ww` render every page without a warning,
#     and lexgrog(1) (what mandb and whatis use) reads its NAME line;
#   - every C block of every EXAMPLE section compiles against include/ with
#     -Wall -Wextra -Werror (a fragment is compiled as the body of a function that
#     receives `modbus_t *ctx`), and the complete programs link with the library;
#   - reachable: `man -M DIR PAGE` (the README's step after gen-man.py --out DIR) shows
#     modbus_new_tcp_tls(3), libmodbus(7) and rsmodbus-gateway(8), "rsmodbus Manual" in
#     the header and "rsmodbus VERSION" in the footer (Debian's say libmodbus); the
#     extensions' pages are not among Debian's libmodbus-dev pages (when installed);
#   - clean room: no page shares a run of 8 words of running text with libmodbus'
#     own page of the same name (from Debian's libmodbus-dev, when installed).
# Ends with "N passed, M failed".
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 1
ROOT=$PWD
WORK=$ROOT/target/check-man
rm -rf "$WORK"
mkdir -p "$WORK"
# shellcheck source=c-tests/common/testlib.sh
. c-tests/common/testlib.sh
CC=${CC:-gcc}
LIB=$ROOT/target/release

if ! cargo build --release --quiet; then
    bad "cargo build --release"
    summary
    exit 1
fi
if python3 man/gen-man.py --out "$WORK/man" >"$WORK/gen.log" 2>&1; then
    ok "man/gen-man.py: $(sed 's/^gen-man: //' "$WORK/gen.log")"
else
    bad "man/gen-man.py" "$(cat "$WORK/gen.log")"
    summary
    exit 1
fi

debian_man=()
if [ -e /usr/share/man/man3/modbus_read_registers.3.gz ]; then
    debian_man=(--debian-man /usr/share/man)
fi
python3 man/check-pages.py --exports abi/exports.txt --headers include --pages "$WORK/man" \
    "${debian_man[@]}" >"$WORK/pages.log" 2>&1
cat "$WORK/pages.log"
passed=$((passed + $(grep -c '^ok   - ' "$WORK/pages.log")))
failed=$((failed + $(grep -c '^FAIL - ' "$WORK/pages.log")))
grep -q -e '^ok   - ' -e '^FAIL - ' "$WORK/pages.log" || bad "man/check-pages.py ran" "$(tail -n 5 "$WORK/pages.log")"

# Reachable the README's way, and told from Debian's (same names, other header/footer).
version=$(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n 1)
for page in "3 modbus_new_tcp_tls" "3 modbus_read_registers" "7 libmodbus" "8 rsmodbus-gateway"; do
    read -r sec name <<<"$page"
    out=$(MANWIDTH=80 man -M "$WORK/man" -P cat "$sec" "$name" 2>&1)
    head_line=$(head -n 1 <<<"$out") foot_line=$(tail -n 1 <<<"$out")
    if [[ $head_line == *"rsmodbus Manual"* && $foot_line == *"rsmodbus $version"* ]]; then
        ok "man -M DIR $sec $name: our page (\"rsmodbus Manual\", \"rsmodbus $version\")"
    else
        bad "man -M DIR $sec $name: our page" "header: $head_line" "footer: $foot_line" "${out:0:300}"
    fi
done
if [ -e /usr/share/man/man3/modbus_read_registers.3.gz ]; then
    ours_only=(modbus_new_tcp_tls modbus_server_new modbus_multi_perform rsmodbus_version modbus_new_ascii)
    found=()
    for name in "${ours_only[@]}"; do
        [ ! -e "/usr/share/man/man3/$name.3.gz" ] || found+=("$name")
    done
    [ ${#found[@]} -eq 0 ] && ok "the extensions' pages exist only in ours (${#ours_only[@]} checked against Debian's libmodbus-dev)" ||
        bad "the extensions' pages exist only in ours" "Debian has: ${found[*]}"
    deb_head=$(MANWIDTH=80 man -P cat 3 modbus_read_registers 2>/dev/null | head -n 1)
    [[ $deb_head != *rsmodbus* ]] && ok "Debian's modbus_read_registers(3) does not say rsmodbus ($deb_head)" ||
        bad "Debian's page tells itself apart" "$deb_head"
fi

# Rendering: no warning from man-db or groff, a NAME line lexgrog can read.
pages=("$WORK"/man/man*/*)
render_bad=()
for page in "${pages[@]}"; do
    name=$(basename "$page")
    warn=$(MANWIDTH=80 man --warnings=all -l "$page" 2>&1 >"$WORK/rendered.txt")
    [ -z "$warn" ] || { render_bad+=("$name: man: ${warn:0:300}"); continue; }
    [ -s "$WORK/rendered.txt" ] || { render_bad+=("$name: renders empty"); continue; }
    warn=$(groff -ww -z -man -Tutf8 "$page" 2>&1)
    [ -z "$warn" ] || { render_bad+=("$name: groff: ${warn:0:300}"); continue; }
    lexgrog "$page" >/dev/null 2>&1 || render_bad+=("$name: lexgrog cannot parse the NAME section")
done
if [ ${#render_bad[@]} -eq 0 ]; then
    ok "${#pages[@]} pages render with man --warnings=all and groff -ww without a warning; lexgrog reads every NAME"
else
    bad "pages render without warnings" "${render_bad[@]}"
fi

# EXAMPLE blocks compile.
blocks=$WORK/blocks
python3 man/gen-man.py --blocks "$blocks" >/dev/null
compile_bad=()
ncompiled=0
nlinked=0
for src in "$blocks"/*.EXAMPLE.c; do
    [ -e "$src" ] || continue
    name=$(basename "$src" .c)
    unit=$WORK/$name.c
    if grep -q 'main(' "$src"; then
        cp "$src" "$unit"
        if "$CC" -std=gnu11 -Wall -Wextra -Werror -Iinclude "$unit" -o "$WORK/$name" \
            -L"$LIB" -lmodbus -Wl,-rpath,"$LIB" 2>"$WORK/$name.err"; then
            nlinked=$((nlinked + 1))
        else
            compile_bad+=("$name: $(head -c 600 "$WORK/$name.err")")
        fi
    else
        {
            printf '#include <errno.h>\n#include <stdio.h>\n#include <stdlib.h>\n'
            printf '#include <string.h>\n#include <unistd.h>\n#include <modbus.h>\n\n'
            if grep -q 'modbus_t \*ctx *=' "$src"; then
                printf 'void example(void);\nvoid example(void)\n{\n'
            else
                printf 'void example(modbus_t *ctx);\nvoid example(modbus_t *ctx)\n{\n'
            fi
            sed 's/^/    /' "$src"
            printf '}\n'
        } >"$unit"
        if "$CC" -std=gnu11 -Wall -Wextra -Werror -Wno-unused-parameter -Iinclude -c "$unit" \
            -o "$WORK/$name.o" 2>"$WORK/$name.err"; then
            ncompiled=$((ncompiled + 1))
        else
            compile_bad+=("$name: $(head -c 600 "$WORK/$name.err")")
        fi
    fi
done
if [ ${#compile_bad[@]} -eq 0 ] && [ $((ncompiled + nlinked)) -gt 0 ]; then
    ok "EXAMPLE code compiles with -Wall -Wextra -Werror: $ncompiled fragments, $nlinked programs linked"
else
    bad "EXAMPLE code compiles with -Wall -Wextra -Werror" "${compile_bad[@]}"
fi

# Two page examples whose output is stated in the text.
version_example=$(ls "$WORK"/rsmodbus_version.*.EXAMPLE 2>/dev/null | head -n 1)
if [ -n "$version_example" ] && [ -x "$version_example" ]; then
    out=$("$version_example" 2>&1)
    want="running on rsmodbus $(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n 1)"
    if grep -qxF "$want" <<<"$out"; then
        ok "rsmodbus_version(3) example prints \"$want\""
    else
        bad "rsmodbus_version(3) example" "expected: $want" "got: $out"
    fi
fi
cat >"$WORK/floats.c" <<'EOF'
#include <stdio.h>
#include <modbus.h>
int main(void)
{
    uint16_t r[2];
    modbus_set_float_abcd(123456.0f, r); printf("abcd 0x%04X 0x%04X\n", r[0], r[1]);
    modbus_set_float_dcba(123456.0f, r); printf("dcba 0x%04X 0x%04X\n", r[0], r[1]);
    modbus_set_float_badc(123456.0f, r); printf("badc 0x%04X 0x%04X\n", r[0], r[1]);
    modbus_set_float_cdab(123456.0f, r); printf("cdab 0x%04X 0x%04X\n", r[0], r[1]);
    const uint16_t be[2] = {0x47F1, 0x2000}, ws[2] = {0x2000, 0x47F1};
    printf("get %.1f %.1f\n", modbus_get_float_abcd(be), modbus_get_float_cdab(ws));
    return 0;
}
EOF
if "$CC" -Iinclude "$WORK/floats.c" -o "$WORK/floats" -L"$LIB" -lmodbus -Wl,-rpath,"$LIB"; then
    printf 'abcd 0x47F1 0x2000\ndcba 0x0020 0xF147\nbadc 0xF147 0x0020\ncdab 0x2000 0x47F1\nget 123456.0 123456.0\n' >"$WORK/floats.expected"
    if "$WORK/floats" | diff -u "$WORK/floats.expected" - >"$WORK/floats.diff"; then
        ok "the float byte orders stated in modbus_set_float_abcd(3) and modbus_get_float_abcd(3) hold"
    else
        bad "the float byte orders stated in the float pages hold" "$(cat "$WORK/floats.diff")"
    fi
else
    bad "compile the float check"
fi

summary
