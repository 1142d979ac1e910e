#!/usr/bin/env bash
# Builds the C programs of benches/ into DIR (default target/bench), against Debian's
# <modbus.h> and libmodbus.so (the library actually loaded is chosen at run time by
# LD_LIBRARY_PATH). Used by scripts/bench.sh, faults.sh and soak.sh.
# MB_CFLAGS and MB_LDFLAGS replace where <modbus.h> and libmodbus.so come from
# (scripts/build-pgo.sh: our include/ and its instrumented library).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/bench}
mkdir -p "$out"
CC=${CC:-gcc}
CFLAGS=(-std=gnu11 -O2 -g -Wall -Wextra -Werror)
read -r -a MB <<< "${MB_CFLAGS:--I/usr/include/modbus}"
read -r -a MB_LD <<< "${MB_LDFLAGS:-}"
LIBINFO=c-tests/common/libinfo.c
$CC "${CFLAGS[@]}" "${MB[@]}" benches/mb-server.c $LIBINFO -o "$out/mb-server" "${MB_LD[@]}" -lmodbus -ldl
$CC "${CFLAGS[@]}" "${MB[@]}" benches/bench-client.c $LIBINFO -o "$out/bench-client" "${MB_LD[@]}" -lmodbus -ldl
# -O3: the floor's conversions are to be as fast as a compiler makes them (vectorised).
$CC "${CFLAGS[@]}" -O3 benches/bench-floor.c -o "$out/bench-floor"
$CC "${CFLAGS[@]}" -fPIC -shared benches/alloc-count.c -o "$out/alloc-count.so"
