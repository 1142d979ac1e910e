#!/usr/bin/env bash
# Soak and memcheck (c-tests/soak/): many verified transactions client<->server over
# TCP and an RTU pty pair with VmRSS and open descriptors sampled (both must stay
# flat), valgrind memcheck of our client, our server and context life cycles (no
# errors, no definite leaks). Ends with "N passed, M failed"; non-zero on failure.
#   c-tests/suites/soak.sh               short: 20,000 transactions per transport (~1-2 min)
#   SOAK_FULL=1 c-tests/suites/soak.sh   1,000,000 transactions per transport
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/../.."
for tool in socat valgrind python3 gcc make; do
    command -v "$tool" >/dev/null || scripts/install-deps.sh >/dev/null
done
[ -e target/release/libmodbus.so ] || cargo build --release -q
[ -e target/release/libmodbus.so.5 ] || ln -sf libmodbus.so target/release/libmodbus.so.5
# soak-client, lifecycle and benches/mb-server.c: c-tests/Makefile (group SOAK).
mkdir -p "${CTEST_BUILD:-target/c-tests-build}"
flock -w 900 "${CTEST_BUILD:-target/c-tests-build}/.lock" make -s -C c-tests --no-print-directory soak
exec python3 c-tests/soak/run.py
