#!/usr/bin/env bash
# Runs every test of the project from a clean clone on Debian 12 (as root): installs
# what it needs, then runs every suite of c-tests/suites.txt with c-tests/run: lints,
# unit tests, the build, the headers and exported symbols, the C suites against Debian's
# libmodbus and ours, the packages, the suites past libmodbus, fuzzing and the demo.
# Ends with the runner's line "N passed, M failed" summing all suites (logs in
# target/test-logs/). Options go to c-tests/run (--list, --from NAME, NAME...).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh || { echo "installing dependencies failed"; exit 1; }
exec c-tests/run "$@"
