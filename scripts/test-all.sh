#!/usr/bin/env bash
# Runs every test of the project from a clean clone on Debian 12 (as root):
# installs what it needs, lints, unit tests, builds, checks the headers and the
# exported symbols, then runs the C suites against Debian's libmodbus and ours.
# Ends with one line "N passed, M failed" summing all suites.
set -uo pipefail
cd "$(dirname "$0")/.."
logdir=target/test-logs
mkdir -p "$logdir"
passed=0
failed=0
failures=()
timings=()

# run NAME CMD...: runs one stage; adds its "N passed, M failed" line when it prints
# one (cargo's "test result:" lines too), else counts the stage itself.
run() {
    local name=$1
    shift
    echo "=== $name: $*"
    local log="$logdir/$name.log"
    local started=$SECONDS
    "$@" 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    timings+=("$(printf '%-12s %4ss' "$name" $((SECONDS - started)))")
    local p f
    p=$(grep -E '^([A-Za-z-]+: )?[0-9]+ passed, [0-9]+ failed' "$log" | tail -n 1 | sed -E 's/^([A-Za-z-]+: )?([0-9]+) passed, ([0-9]+) failed.*/\2/')
    f=$(grep -E '^([A-Za-z-]+: )?[0-9]+ passed, [0-9]+ failed' "$log" | tail -n 1 | sed -E 's/^([A-Za-z-]+: )?([0-9]+) passed, ([0-9]+) failed.*/\3/')
    if [ -z "$p" ]; then
        p=$(grep -E '^test result: ' "$log" | sed -E 's/.* ([0-9]+) passed; ([0-9]+) failed.*/\1/' | paste -sd+ | bc 2>/dev/null || true)
        f=$(grep -E '^test result: ' "$log" | sed -E 's/.* ([0-9]+) passed; ([0-9]+) failed.*/\2/' | paste -sd+ | bc 2>/dev/null || true)
    fi
    if [ -z "$p" ]; then
        if [ "$rc" -eq 0 ]; then p=1; f=0; else p=0; f=1; fi
    fi
    if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
    passed=$((passed + p))
    failed=$((failed + f))
    if [ "$rc" -ne 0 ]; then failures+=("$name"); fi
    echo "=== $name: exit $rc ($p passed, $f failed)"
}

scripts/install-deps.sh || { echo "installing dependencies failed"; exit 1; }
command -v bc >/dev/null || { apt-get install -y -qq bc >/dev/null 2>&1 || true; }

run fmt cargo fmt --all --check
run clippy cargo clippy --workspace --all-targets -- -D warnings
run unit-tests cargo test --workspace
run build cargo build --release
ln -sf libmodbus.so target/release/libmodbus.so.5
[ -x scripts/check-headers.sh ] && run headers scripts/check-headers.sh
[ -x scripts/check-symbols.sh ] && run symbols scripts/check-symbols.sh
[ -x scripts/run-c-tests.sh ] && run c-client scripts/run-c-tests.sh --valgrind
# Debian's unit-test-client x unit-test-server, every library combination: section 3.
[ -x scripts/run-server-tests.sh ] && run c-server scripts/run-server-tests.sh --no-cargo
# The profile-guided build is the one the packages ship: Debian's unit tests run
# against it too (TCP, TCP-PI and RTU; it as client, server and both). The package
# stage runs the examples and mbpoll on it, TCP and RTU.
run pgo-build scripts/build-pgo.sh
run pgo-unit env MBTEST_OURS_DIR=target/pgo/release SRVTEST_OUT=target/server-tests-pgo \
    scripts/run-server-tests.sh --no-cargo --only '^unit-test '
[ -x scripts/check-examples.sh ] && run examples scripts/check-examples.sh
[ -x scripts/check-man.sh ] && run man scripts/check-man.sh
[ -x scripts/check-package.sh ] && run package scripts/check-package.sh
[ -x scripts/run-interop-tests.sh ] && run interop scripts/run-interop-tests.sh --no-cargo
[ -x scripts/run-thread-tests.sh ] && run threads scripts/run-thread-tests.sh --no-cargo
# Stopping a waiting call from a signal handler or another thread (issue 19).
[ -x scripts/run-stop-tests.sh ] && run stop scripts/run-stop-tests.sh --no-cargo
# Modbus/TCP Security: TLS, roles, refusals, many clients, faults (issue 21).
[ -x scripts/run-tls-tests.sh ] && run tls scripts/run-tls-tests.sh --no-cargo
[ -x scripts/run-extended-tests.sh ] && run c-extended scripts/run-extended-tests.sh
[ -x scripts/run-fault-tests.sh ] && run faults scripts/run-fault-tests.sh
[ -x scripts/run-soak.sh ] && run soak scripts/run-soak.sh
[ -x scripts/run-bench-smoke.sh ] && run bench-smoke scripts/run-bench-smoke.sh
[ -x scripts/fuzz.sh ] && run fuzz-smoke scripts/fuzz.sh --smoke 3
run demo scripts/demo.sh

echo
echo "stage times:"
printf '  %s\n' "${timings[@]}"
echo "total: ${SECONDS}s"
if [ ${#failures[@]} -gt 0 ]; then echo "failed stages: ${failures[*]}"; fi
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
