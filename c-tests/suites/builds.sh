#!/usr/bin/env bash
# builds.sh: the release build and the builds later rows make for themselves, side by
# side, before any suite runs a test:
#   release  cargo build --release (the next row, build, then has nothing to do);
#   tsan     the library for ThreadSanitizer in target/tsan (testlib.sh's tsan_library:
#            the threads and event suites);
#   fuzz     what fuzz-smoke runs (scripts/fuzz.sh --build: the libFuzzer targets);
#   deb      the gateway debian/rules builds (BUILD_GATEWAY: target/deb-cargo), in the
#            environment dpkg-buildpackage gives it: dpkg-buildflags' flags (ring's C
#            code reads CFLAGS) and SOURCE_DATE_EPOCH from debian/changelog.
# Why: a release build spends much of its time in one rustc at a time (rustls, the
# library and the gateway: codegen-units = 1 and LTO), one core of two idle, and so
# do these builds one after another. Side by side they fill the idle core. The rows
# that need them still run their own builds, and their checks of them: cargo finds
# them fresh (or, if a build's inputs differ, builds again). Only compilers run here.
# Logs: target/builds/NAME.log (their tail shown on failure). Last line "N passed, M failed".
# Usage: c-tests/suites/builds.sh
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT" || exit 2
# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"
LOGS=$ROOT/target/builds
mkdir -p "$LOGS"
command -v cargo >/dev/null || export PATH="$HOME/.cargo/bin:$PATH"

# deb_gateway: debian/rules' BUILD_GATEWAY as dpkg-buildpackage runs it.
deb_gateway() {
    local gw
    gw=$(sed -n 's/^BUILD_GATEWAY = \$(CARGO) //p' debian/rules)
    [ -n "$gw" ] || { echo "no 'BUILD_GATEWAY = \$(CARGO) ...' line in debian/rules"; return 1; }
    . scripts/deb-build-env.sh
    deb_build_env || return 1
    # shellcheck disable=SC2086 # the arguments of the rules' line
    cargo $gw
}

names=(release tsan fuzz deb)
declare -A WHAT=(
    [release]="cargo build --release"
    [tsan]="cargo build -Zsanitizer=thread (target/tsan)"
    [fuzz]="scripts/fuzz.sh --build (what fuzz-smoke runs)"
    [deb]="debian/rules' gateway build, with dpkg-buildflags (target/deb-cargo)"
) PID=()
started=$SECONDS
cargo build --release >"$LOGS/release.log" 2>&1 &
PID[release]=$!
tsan_library "$LOGS/tsan.log" &
PID[tsan]=$!
scripts/fuzz.sh --build >"$LOGS/fuzz.log" 2>&1 &
PID[fuzz]=$!
deb_gateway >"$LOGS/deb.log" 2>&1 &
PID[deb]=$!
for name in "${names[@]}"; do
    if wait "${PID[$name]}"; then
        ok "${WHAT[$name]}"
    else
        bad "${WHAT[$name]}" "$(tail -n 15 "$LOGS/$name.log")"
    fi
done
echo "       ${#names[@]} builds side by side: $((SECONDS - started)) s"
summary
