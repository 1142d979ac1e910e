#!/usr/bin/env bash
# Fault injection (c-tests/fault/): a proxy between client and server splits, delays,
# drops, duplicates and corrupts bytes, closes mid-frame and delivers a late response;
# the same scenario runs with Debian's libmodbus and with rsmodbus (TCP and RTU over
# pty pairs). Ends with "N passed, M failed"; exits non-zero on failure. ~1-2 minutes.
#   FAULTS="split late" c-tests/suites/faults.sh     # a subset
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/../.."
[ -e target/release/libmodbus.so ] || cargo build --release -q
[ -e target/release/libmodbus.so.5 ] || ln -sf libmodbus.so target/release/libmodbus.so.5
# fault-proxy, fault-client and benches/mb-server.c: c-tests/Makefile (group FAULT).
mkdir -p "${CTEST_BUILD:-target/c-tests-build}"
flock -w 900 "${CTEST_BUILD:-target/c-tests-build}/.lock" make -s -C c-tests --no-print-directory fault
exec python3 c-tests/fault/run.py
