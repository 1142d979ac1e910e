#!/usr/bin/env bash
# benches/reply-cost.sh: modbus_reply_dispatch against modbus_reply on the same
# mapping (benches/reply-cost.c), on the library the packages ship (the
# profile-guided build, target/pgo/release, when it is there and current (run
# scripts/build-pgo.sh first); else target/release). scripts/bench.sh --callbacks. About 20 s.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
LIB=target/release
if [ "${BENCH_PGO:-1}" = 1 ] && [ -e target/pgo/release/libmodbus.so ] &&
    grep -q ' T modbus_reply_dispatch$' <<<"$(nm -D target/pgo/release/libmodbus.so)"; then
    LIB=target/pgo/release
else
    cargo build --release --quiet
fi
[ -e "$LIB/libmodbus.so.5" ] || ln -sf libmodbus.so "$LIB/libmodbus.so.5"
mkdir -p target/bench
gcc -std=gnu11 -O2 -g -Wall -Wextra -Werror -Iinclude benches/reply-cost.c c-tests/common/libinfo.c \
    -o target/bench/reply-cost -L"$LIB" -lmodbus -ldl -lm
echo "library: $LIB/libmodbus.so.5"
LD_LIBRARY_PATH=$LIB target/bench/reply-cost "${BENCH_CYCLES:-300}"
