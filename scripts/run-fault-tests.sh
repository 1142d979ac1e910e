#!/usr/bin/env bash
# Fault injection (c-tests/fault/): a proxy between client and server splits, delays,
# drops, duplicates and corrupts bytes, closes mid-frame and delivers a late response;
# the same scenario runs with Debian's libmodbus and with rsmodbus (TCP and RTU over
# pty pairs). Ends with "N passed, M failed"; exits non-zero on failure. ~1-2 minutes.
#   FAULTS="split late" scripts/run-fault-tests.sh     # a subset
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
out=target/fault
[ -e target/release/libmodbus.so ] || cargo build --release -q
[ -e target/release/libmodbus.so.5 ] || ln -sf libmodbus.so target/release/libmodbus.so.5
benches/build.sh "$out"
CFLAGS=(-std=gnu11 -O2 -g -Wall -Wextra -Werror)
gcc "${CFLAGS[@]}" c-tests/fault/fault-proxy.c -o "$out/fault-proxy" -lutil
gcc "${CFLAGS[@]}" -I/usr/include/modbus c-tests/fault/fault-client.c c-tests/common/libinfo.c \
    -o "$out/fault-client" -lmodbus -ldl
exec python3 c-tests/fault/run.py
