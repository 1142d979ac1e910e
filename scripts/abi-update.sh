#!/usr/bin/env bash
# abi-update.sh: regenerates the ABI baseline, abi/libmodbus.abi and abi/headers.abi,
# which c-tests/suites/abi-check.sh compares the tree with (libabigail's abidiff).
#
#   abi/libmodbus.abi  abidw of the built library with its debug information dropped:
#                      the SONAME and every exported ELF symbol (functions; objects
#                      with their sizes; symbol versions, were there any). The Rust
#                      library's own DWARF would describe Rust types, not the C API's,
#                      so it is not used.
#   abi/headers.abi    abidw of the "witness", a C shared object compiled with -g from
#                      the public headers (scripts/abi-witness.py): the type of every
#                      exported function and object as the header declares it, every
#                      typedef and struct/union/enum tag with its members, sizes and
#                      offsets, and the values of the integer constants (macros and
#                      anonymous enumerators).
#
# Run it after a change of the API that is intended, and commit the two files with the
# change (docs/abi.md). Needs: the built library (cargo build --release), abigail-tools
# (abidw), gcc, python3.
#
# Usage: scripts/abi-update.sh [--out DIR] [LIBRARY]
#   --out DIR  write the two files into DIR instead of abi/ (the check uses this)
#   LIBRARY    default ${CARGO_TARGET_DIR:-target}/${PROFILE:-release}/libmodbus.so
# Env: ABI_CC (gcc): the compiler of the witness; the baseline is Debian 12's gcc's
#      DWARF, another compiler's differs in details abidiff reports
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

OUT=abi
LIB=
while [ $# -gt 0 ]; do
    case $1 in
    --out) OUT=${2:?--out DIR}; shift ;;
    -h | --help) sed -n '2,/^# SPDX/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    -*) echo "abi-update.sh: unknown option $1 (--help)" >&2; exit 2 ;;
    *) LIB=$1 ;;
    esac
    shift
done
LIB=${LIB:-${CARGO_TARGET_DIR:-target}/${PROFILE:-release}/libmodbus.so}
CC=${ABI_CC:-gcc}

fail() { echo "abi-update.sh: $*" >&2; exit 1; }
for tool in abidw python3 "$CC" objcopy; do
    command -v "$tool" >/dev/null || fail "$tool not found (abidw: apt-get install abigail-tools; scripts/install-deps.sh)"
done
[[ -f $LIB ]] || fail "$LIB not found (cargo build --release)"
mkdir -p "$OUT"

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

# The same flags for both: no paths, no source locations, no DT_NEEDED (symbols.sh
# checks those), so that the files depend on the ABI only.
ABIDW=(abidw --no-corpus-path --no-comp-dir-path --no-show-locs --no-elf-needed)

# The library: its ELF symbols only. Without the alias attributes: abidw names the
# symbols at one address (functions the linker folded because their code is the same,
# e.g. modbus_get_float and modbus_get_float_cdab), which the code decides, not the ABI.
objcopy --strip-debug "$LIB" "$TMP/libmodbus.so"
"${ABIDW[@]}" --out-file "$TMP/libmodbus-aliases.abi" "$TMP/libmodbus.so" ||
    fail "abidw failed on $LIB"
sed "s/ alias='[^']*'//" "$TMP/libmodbus-aliases.abi" >"$TMP/libmodbus.abi"

# The headers: the witness, compiled with -g.
python3 scripts/abi-witness.py include abi/exports.txt "$CC" >"$TMP/abi-witness.c"
# Compiled in its directory under a fixed name: the dump records the file's name.
(cd "$TMP" && "$CC" -std=gnu11 -g -O0 -fPIC -shared -Wall -Wextra -Werror -I"$ROOT/include" \
    -ffile-prefix-map="$ROOT"=. -o witness.so abi-witness.c 2>cc.log) || {
    cat "$TMP/cc.log" >&2
    fail "the witness does not compile against include/ (generated: scripts/abi-witness.py)"
}
"${ABIDW[@]}" --out-file "$TMP/headers.abi" "$TMP/witness.so" ||
    fail "abidw failed on the witness"
grep -q '<var-decl name=.fn_modbus_new_tcp.' "$TMP/headers.abi" ||
    fail "the witness's dump has no type information (is abidw reading DWARF?)"

cp "$TMP/libmodbus.abi" "$TMP/headers.abi" "$OUT/"
[[ $OUT != abi ]] || echo "abi-update.sh: wrote abi/libmodbus.abi ($(grep -c '<elf-symbol ' abi/libmodbus.abi) symbols) and abi/headers.abi ($(grep -c '<elf-symbol ' abi/headers.abi) witness variables); commit them with the change"
