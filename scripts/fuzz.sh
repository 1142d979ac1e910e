#!/usr/bin/env bash
# Fuzzing rsmodbus on the stable toolchain (no nightly, no cargo-fuzz needed).
#
#   scripts/fuzz.sh --smoke [SECONDS]    every target SECONDS (default 25) under libFuzzer,
#                                        each starting with its corpus + regressions
#                                        (without libFuzzer: the replay tool replays them,
#                                        then drives each target); ends with
#                                        "N passed, M failed"
#   scripts/fuzz.sh TARGET SECONDS       one target (libFuzzer), e.g. server_tcp 600
#   scripts/fuzz.sh --all SECONDS        every target in turn
#   scripts/fuzz.sh --replay [PATH...]   replay inputs (default: corpus + regressions)
#   scripts/fuzz.sh --list               target names
#   scripts/fuzz.sh --build              only build what --smoke runs (the targets; without
#                                        libFuzzer, the replay tool)
#   FUZZ_NO_BUILD=1 ...                  reuse the last build (a campaign while src/ changes)
#
# How: the targets in fuzz/fuzz_targets/ use libfuzzer-sys (libFuzzer compiled from its
# C++ sources by the crate). Coverage instrumentation uses only stable rustc flags
# (-Cpasses=sancov-module and -Cllvm-args=-sanitizer-coverage-*). FUZZ_ASAN=1 adds
# AddressSanitizer, which needs -Zsanitizer: set through RUSTC_BOOTSTRAP=1 on stable.
# If libFuzzer cannot be built, the plain Rust driver `replay --random` (mutations of
# the corpus, each batch in a forked child) runs instead. `cargo fuzz` works on the
# same layout too: RUSTC_BOOTSTRAP=1 cargo fuzz run server_tcp (from the repo root).
#
# New coverage goes to fuzz/target/corpus-work/TARGET (not committed); crashes to
# fuzz/artifacts/TARGET/. A finding becomes a regression input in
# fuzz/regressions/TARGET/ (replayed by --smoke and --replay).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
FUZZ=$ROOT/fuzz
TRIPLE=$(rustc -vV | sed -n 's/^host: //p')
TARGETS=(server_rtu server_tcp server_ascii client_rtu client_tcp client_ascii ffi_server ffi_client ffi_async security authorization gateway_config gateway_master)
SANCOV="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing"
BIN=$FUZZ/target/$TRIPLE/release
if [ "${FUZZ_ASAN:-0}" = 1 ]; then
    # A separate build directory: the instrumented binaries differ.
    BIN=$FUZZ/target/asan/$TRIPLE/release
fi
REPLAY=$FUZZ/target/release/replay
pids=()
cleanup() { for p in "${pids[@]:-}"; do [ -n "$p" ] && kill "$p" 2>/dev/null; done; }
trap cleanup EXIT INT TERM

# FUZZ_NO_BUILD=1: use the binaries of the last build (long campaigns while src/ changes).
build_replay() {
    [ "${FUZZ_NO_BUILD:-0}" = 1 ] && [ -x "$REPLAY" ] && return 0
    (cd "$FUZZ" && cargo build --release --bin replay -q) || { echo "building the replay tool failed"; return 1; }
}

LIBFUZZER_OK=0
build_targets() {
    if [ "${FUZZ_NO_BUILD:-0}" = 1 ] && [ -x "$BIN/${TARGETS[0]}" ]; then
        LIBFUZZER_OK=1
        return 0
    fi
    local flags=$SANCOV
    local env=()
    if [ "${FUZZ_ASAN:-0}" = 1 ]; then
        flags="$flags -Zsanitizer=address"
        env=(RUSTC_BOOTSTRAP=1)
    fi
    local args=() name
    for name in "${TARGETS[@]}"; do args+=(--bin "$name"); done
    # --target keeps RUSTFLAGS away from build scripts and proc macros.
    local dir=()
    [ "${FUZZ_ASAN:-0}" = 1 ] && dir=(--target-dir "$FUZZ/target/asan")
    if (cd "$FUZZ" && env "${env[@]}" RUSTFLAGS="$flags" cargo build --release -q --target "$TRIPLE" "${dir[@]}" "${args[@]}"); then
        LIBFUZZER_OK=1
    else
        echo "libFuzzer targets did not build: falling back to the plain Rust driver"
    fi
}

# run_target NAME SECONDS: fuzz one target; returns non-zero on a finding.
run_target() {
    local t=$1 secs=$2
    local work=$FUZZ/target/corpus-work/$t art=$FUZZ/artifacts/$t
    mkdir -p "$work" "$art"
    if [ "$LIBFUZZER_OK" = 1 ]; then
        local log=$FUZZ/target/fuzz-$t.log
        local dirs=("$work" "$FUZZ/corpus/$t")
        [ -d "$FUZZ/regressions/$t" ] && dirs+=("$FUZZ/regressions/$t")
        # -timeout: an input running 10 s is a hang; -rss_limit_mb keeps leaks visible.
        "$BIN/$t" -max_total_time="$secs" -timeout=10 -rss_limit_mb=1024 -print_final_stats=1 \
            -artifact_prefix="$art/" "${dirs[@]}" >"$log" 2>&1 &
        local pid=$!
        pids+=("$pid")
        wait "$pid"
        local rc=$?
        local execs cov
        execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
        cov=$(grep -Eo 'cov: [0-9]+ ft: [0-9]+' "$log" | tail -1)
        local seeds
        seeds=$(sed -n 's/^INFO: seed corpus: files: \([0-9]*\).*/\1/p' "$log" | head -1)
        echo "fuzz $t: ${secs}s, ${seeds:-?} saved inputs run first (corpus, regressions, earlier finds), ${execs:-?} execs, ${cov:-?}, rc=$rc (log: ${log#"$ROOT"/})"
        if [ "$rc" -ne 0 ]; then
            grep -E 'panicked at|assertion|SUMMARY|Test unit written|ERROR' "$log" | head -8
            return 1
        fi
    else
        "$REPLAY" --random "$t" "$secs" "$FUZZ/corpus/$t" || return 1
    fi
}

replay_all() {
    local paths=("$@")
    if [ ${#paths[@]} -eq 0 ]; then
        paths=("$FUZZ/corpus")
        [ -d "$FUZZ/regressions" ] && paths+=("$FUZZ/regressions")
    fi
    "$REPLAY" "${paths[@]}"
}

case "${1:-}" in
--list)
    printf '%s\n' "${TARGETS[@]}"
    ;;
--build)
    # (c-tests/suites/builds.sh builds it beside the other builds; --smoke then finds it built)
    build_targets
    [ "$LIBFUZZER_OK" = 1 ] || build_replay
    ;;
--replay)
    shift
    build_replay || exit 1
    replay_all "$@"
    ;;
--smoke)
    secs=${2:-25}
    passed=0
    failed=0
    build_targets
    if [ "$LIBFUZZER_OK" != 1 ]; then
        # Without libFuzzer, the replay tool replays every input, then drives each
        # target with random mutations (run_target's fallback). With it, each
        # target's run begins by executing its whole corpus and regression inputs
        # (libFuzzer reads the directories run_target gives it before fuzzing), so
        # a separate replay (and the separate build of the replay tool: about a
        # minute) would repeat that.
        build_replay || { echo "0 passed, 1 failed"; exit 1; }
        out=$(replay_all)
        echo "$out" | grep -v '^replay:'
        line=$(echo "$out" | grep '^replay:' | tail -1)
        echo "$line"
        p=$(echo "$line" | sed -E 's/.* ([0-9]+) passed, ([0-9]+) failed/\1/')
        f=$(echo "$line" | sed -E 's/.* ([0-9]+) passed, ([0-9]+) failed/\2/')
        passed=$((passed + ${p:-0}))
        failed=$((failed + ${f:-1}))
    fi
    for t in "${TARGETS[@]}"; do
        if run_target "$t" "$secs"; then passed=$((passed + 1)); else failed=$((failed + 1)); fi
    done
    echo "$passed passed, $failed failed"
    # (the counts of c-tests/run, when it runs this as its suite fuzz-smoke)
    [ -z "${MBT_COUNTS:-}" ] || echo "$passed $failed" >"$MBT_COUNTS"
    [ "$failed" -eq 0 ]
    ;;
--all)
    secs=${2:?seconds}
    build_replay || exit 1
    build_targets
    rc=0
    for t in "${TARGETS[@]}"; do run_target "$t" "$secs" || rc=1; done
    exit $rc
    ;;
"" | -h | --help)
    sed -n '2,27p' "$0"
    ;;
*)
    t=$1
    secs=${2:?seconds}
    grep -qx "$t" <<<"$(printf '%s\n' "${TARGETS[@]}")" || { echo "unknown target $t"; exit 2; }
    build_replay || exit 1
    build_targets
    run_target "$t" "$secs"
    ;;
esac
