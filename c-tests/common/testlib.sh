# shellcheck shell=bash
# Shared helpers of the test suites (c-tests/suites/*.sh, run by c-tests/run).
# Source it; it defines:
#
# Counting: passed, failed, and FAILED (what failed, for a closing list)
#   ok/bad/check NAME ...   count one check, printed "ok   - NAME" / "FAIL - NAME"
#                           (check runs a command, quietly)
#   result NAME PASS|FAIL [DETAIL]  count one check, printed "PASS NAME  (DETAIL)"
#   tally PASS|FAIL WHAT    count one check, print nothing
#   expect_line NAME FILE LINE    FILE must contain exactly the line LINE
#   section TITLE           print a "=== TITLE ===" heading
#   summary                 print "N passed, M failed", write the counts for c-tests/run
#                           (write_counts) and return non-zero on failure
#   write_counts P F        "P F" into the file $MBT_COUNTS (when c-tests/run set it)
#   begin NAME; err TEXT; err_file FILE [N]; end [DETAIL]   one check made of several
#                           findings: err (or err_file: FILE's first N (40) lines,
#                           indented) records a problem; end counts NAME as ok, or as
#                           bad with every line recorded since begin
#
# Command line and our library (the run-*.sh suites; they set ROOT)
#   parse_flags [FLAG...] -- "$@"   every suite takes -h/--help (prints the script's
#                           header comment) and --no-cargo (RUN_CARGO=0, else 1); the
#                           FLAGs before -- are the other common ones it takes:
#                           --only REGEX (ONLY, else empty), --no-valgrind (VALGRIND=0,
#                           else 1). Other flags go to the suite's suite_flag "$@"
#                           (if any): it returns 0 when it used $1, 2 when it used $1
#                           and $2, 1 for a flag it does not take
#   selected NAME           true when NAME matches $ONLY (or --only was not given)
#   our_lib_result DIR TAIL cargo build --release (unless --no-cargo; its last TAIL
#                           lines shown) as a result, then DIR/libmodbus.so.5; sets
#                           OURS_LIB; ends the run when there is no library
#   prepare_run TOOL...     $BIN and $LOGS (last run's logs removed), WORK=$OUT/run,
#                           cargo build --release (unless --no-cargo; output in
#                           $LOGS/cargo.log); exit 2 when a TOOL or
#                           $OURS/libmodbus.so(.5) is missing or the build fails
#   link_so5 DIR            DIR/libmodbus.so.5 -> libmodbus.so; fails without the .so
#   loaded_ours NAME LOG LIB  the "LOADED path (rsmodbus ...)" line in LOG
#                           (c-tests/interop/interop.c) names LIB
#   libinfo_ours NAME LOG   the first LIBINFO line in LOG (c-tests/common/libinfo.c)
#                           names $OURS_LIB, and rsmodbus (one check)
#   program_checks NAME LOG RC  adds the checks a C program counted itself
#                           (c-tests/common/check.h: its "N passed, M failed" line in
#                           LOG; its FAIL lines shown) and one check "NAME: exit 0";
#                           no summary line is one failure
#   valgrind_clean NAME DIR  one check: no valgrind.*.log of DIR has a line
#   pymodbus_venv VENV REQS LOGDIR INSTALL  PY=VENV/bin/python, a venv of Debian's
#                           python3 holding the pinned versions of REQS (pip install
#                           when INSTALL is 1); returns non-zero, saying why, if not.
#                           Under a lock (VENV.lock): suites run side by side
#
# Building the C programs: c-tests/Makefile, the one build of them all (run-*.sh; ROOT set)
#   c_build_dir [SAN]       where the Makefile puts a variant's programs: $CTEST_BUILD
#                           (default target/c-tests-build) /bin, /asan (SAN=address)
#                           or /tsan (SAN=thread)
#   c_build [VAR=VALUE...] TARGET...  make -C c-tests TARGET, one check per TARGET
#                           ("build TARGET (c-tests/Makefile[, SAN=...])"), counted with
#                           $C_BUILD_RESULT NAME PASS|FAIL [DETAIL] (default: result);
#                           make's output in $LOGS/build-TARGET[-SAN].log (LOGS unset:
#                           in the build directory); one build at a time (flock); a
#                           TARGET that failed is removed (no stale program runs);
#                           returns 1 when a TARGET failed
#   c_build_group GROUP [VAR=VALUE...]  c_build of every target of the Makefile's GROUP
#                           (CLIENT_TESTS, SERVER_TESTS, TLS, ...: make -s print-GROUP)
#
# Processes: every one started here is remembered by its PID and stopped by it; what
# still runs when the script exits or is interrupted is stopped then.
#   start_bg OUT ERR CMD... CMD in the background, stdout to OUT, stderr to ERR (ERR
#                           may be OUT); sets LAST_PID; PIDS lists the running ones
#   session_pids SID        the live processes of session SID (c-tests/common/session.sh)
#   stop_pid PID            TERM, KILL after STOP_GRACE seconds (3), reap
#   wait_pid PID            wait for it to end by itself; returns its exit status
#   start NAME CMD...       start_bg with output in $WORK/NAME.log, known by NAME
#   stop NAME               stop_pid that process
#   wait_exit NAME [SECS]   wait for it to end by itself; sets $rc to its exit code
#   wait_for FILE TEXT [SECS]   wait until FILE contains TEXT
#   wait_ready NAME TEXT [SECS] wait until started process NAME prints TEXT; fails
#                           at once if it has exited
#   free_port               print a free TCP port on 127.0.0.1
#   socat_pair OUT ERR A B [SECS]  start_bg a socat pty pair linked at A and B; fails
#                           when the links are not there within SECS (5)
#   pty_pair NAME A B       the same, known by NAME (output in $WORK/NAME.log)
# The caller sets WORK (a scratch directory) before using start or pty_pair.
# SPDX-License-Identifier: MIT OR Apache-2.0

passed=0
failed=0
declare -a FAILED=()

tally() {
    if [ "$1" = PASS ]; then
        passed=$((passed + 1))
    else
        failed=$((failed + 1))
        FAILED+=("$2")
    fi
}

ok() { tally PASS "$1"; echo "ok   - $1"; }
bad() {
    tally FAIL "$1"
    echo "FAIL - $1"
    shift
    local line
    for line in "$@"; do echo "       $line"; done
}

result() {
    tally "$2" "$1${3:+: $3}"
    printf '%-4s %s%s\n' "$2" "$1" "${3:+  ($3)}"
}

# check NAME CMD...: runs CMD; passes when it exits 0 (its output goes to the log).
check() {
    local name=$1
    shift
    local out
    if out=$("$@" 2>&1); then
        ok "$name"
    else
        bad "$name" "command: $*" "${out:0:2000}"
    fi
}

expect_line() {
    local name=$1 file=$2 line=$3
    if grep -qxF -- "$line" "$file" 2>/dev/null; then
        ok "$name"
    else
        bad "$name" "expected line: $line" "in $file:" "$(tail -n 20 "$file" 2>/dev/null)"
    fi
}

section() { printf '\n=== %s ===\n' "$*"; }

summary() {
    echo "$passed passed, $failed failed"
    write_counts "$passed" "$failed"
    [ "$failed" -eq 0 ]
}

CHECK_NAME=
CHECK_ERRORS=()
begin() {
    CHECK_NAME=$1
    CHECK_ERRORS=()
}
err() { CHECK_ERRORS+=("$*"); }
err_file() {
    local line
    while IFS= read -r line; do CHECK_ERRORS+=("  | $line"); done < <(head -n "${2:-40}" "$1")
}
end() {
    if [ ${#CHECK_ERRORS[@]} -eq 0 ]; then
        ok "$CHECK_NAME${1:+: $1}"
    else
        bad "$CHECK_NAME" "${CHECK_ERRORS[@]}"
    fi
}

# write_counts PASSED FAILED: the counts c-tests/run adds to its totals, into the file
# $MBT_COUNTS names (set by the runner; unset: nothing is written).
write_counts() {
    [ -z "${MBT_COUNTS:-}" ] || echo "$1 $2" >"$MBT_COUNTS"
}

# ------------------------------------------------------------ command line, library
# shellcheck disable=SC2034 # VALGRIND is read by the suites
parse_flags() {
    local takes=" " rc
    while [ "$1" != -- ]; do
        takes+="$1 "
        shift
    done
    shift
    RUN_CARGO=1
    [[ $takes != *" --only "* ]] || ONLY=""
    [[ $takes != *" --no-valgrind "* ]] || VALGRIND=1
    while [ $# -gt 0 ]; do
        case "$1" in
        -h | --help) sed -n '2,/^set -u/p' "$0" | sed '$d'; exit 0 ;;
        --no-cargo) RUN_CARGO=0; shift; continue ;;
        esac
        rc=1
        if [[ $takes == *" $1 "* ]]; then
            case "$1" in
            --only) ONLY=$2; rc=2 ;;
            --no-valgrind) VALGRIND=0; rc=0 ;;
            esac
        elif declare -F suite_flag >/dev/null; then
            rc=0
            suite_flag "$@" || rc=$?
        fi
        case $rc in
        0) shift ;;
        2) shift 2 ;;
        *) echo "unknown option $1" >&2; exit 2 ;;
        esac
    done
}

selected() { [ -z "$ONLY" ] || [[ $1 =~ $ONLY ]]; }

link_so5() {
    [ -f "$1/libmodbus.so" ] || return 1
    [ -e "$1/libmodbus.so.5" ] || ln -sf libmodbus.so "$1/libmodbus.so.5"
}

our_lib_result() {
    local dir=$1 lines=$2
    if [ "$RUN_CARGO" = 1 ]; then
        if (cd "$ROOT" && cargo build --release 2>&1 | tail -n "$lines"); then
            result "cargo build --release" PASS
        else
            result "cargo build --release" FAIL
        fi
    fi
    link_so5 "$dir"
    OURS_LIB=$(readlink -f "$dir/libmodbus.so.5" 2>/dev/null || true)
    if [ -z "$OURS_LIB" ] || [ ! -f "$OURS_LIB" ]; then
        # Nothing else can run without it.
        result "our libmodbus.so.5" FAIL "missing in $dir"
        summary
        exit 1
    fi
}

prepare_run() {
    local tool
    mkdir -p "$BIN" "$LOGS"
    rm -f "$LOGS"/*.log
    WORK=$OUT/run
    mkdir -p "$WORK"
    for tool in "$@"; do
        command -v "$tool" >/dev/null || { echo "missing $tool (scripts/install-deps.sh)"; exit 2; }
    done
    if [ "$RUN_CARGO" -eq 1 ]; then
        (cd "$ROOT" && cargo build --release) >"$LOGS/cargo.log" 2>&1 ||
            { tail -n 30 "$LOGS/cargo.log"; echo "cargo build failed"; exit 2; }
    fi
    link_so5 "$OURS" || { echo "no $OURS/libmodbus.so"; exit 2; }
}

loaded_ours() {
    local name=$1 log=$2 lib=$3 line path
    line=$(grep -m1 '^LOADED ' "$log")
    path=${line#LOADED }
    path=${path%% (*}
    if [ -n "$path" ] && [ "$(readlink -f "$path")" = "$(readlink -f "$lib")" ] &&
        [[ $line == *"(rsmodbus "* ]]; then
        ok "$name: loaded $path"
    else
        bad "$name: wrong library" "${line:-no LOADED line}" "expected $lib"
    fi
}

libinfo_ours() {
    local name=$1 log=$2 lib
    lib=$(sed -n 's/^LIBINFO: pid [0-9]* libmodbus.so.5 = \([^ ]*\) .*/\1/p' "$log" | head -n 1)
    if [ -n "$lib" ] && [ "$(readlink -f "$lib")" = "$OURS_LIB" ] && grep -q '^LIBINFO: .*(rsmodbus ' "$log"; then
        result "$name: loaded our libmodbus.so.5 ($lib)" PASS
    else
        result "$name: loaded our libmodbus.so.5" FAIL "LIBINFO says '${lib:-nothing}'"
    fi
}

program_checks() {
    local name=$1 log=$2 rc=$3 n p f
    n=$(grep -E '^[0-9]+ passed, [0-9]+ failed$' "$log" | tail -n 1)
    grep '^FAIL - ' "$log" | cut -c1-300 | sed 's/^/    | /'
    if [ -z "$n" ]; then
        result "$name" FAIL "no summary line (exit $rc; see $log)"
        return 1
    fi
    p=$(echo "$n" | awk '{print $1}')
    f=$(echo "$n" | awk '{print $3}')
    passed=$((passed + p))
    failed=$((failed + f))
    [ "$f" = 0 ] || FAILED+=("$name: $f checks (see $log)")
    if [ "$rc" = 0 ] && [ "$f" = 0 ]; then
        result "$name: $p checks, exit 0" PASS
    else
        result "$name: $p passed, $f failed, exit $rc" FAIL "see $log"
        return 1
    fi
}

valgrind_clean() {
    if grep -q . <<<"$(cat "$2"/valgrind.*.log 2>/dev/null)"; then
        result "$1: valgrind memcheck clean" FAIL "see $2/valgrind.*.log"
        cat "$2"/valgrind.*.log | head -n 30 | sed 's/^/    | /'
    else
        result "$1: valgrind memcheck clean" PASS
    fi
}

pymodbus_venv() {
    local venv=$1 reqs=$2 logs=$3 install=$4 lock rc
    mkdir -p "$(dirname "$venv")"
    # One suite at a time makes or completes the venv (c-tests/run runs suites side
    # by side): the others wait for the lock, then find it done.
    exec {lock}>"$venv.lock"
    flock "$lock"
    _pymodbus_venv "$venv" "$reqs" "$logs" "$install"
    rc=$?
    exec {lock}>&-
    return $rc
}
_pymodbus_venv() {
    local venv=$1 reqs=$2 logs=$3 install=$4
    PY=$venv/bin/python
    if [ ! -x "$PY" ]; then
        # Debian's interpreter (python3-venv), not whatever python3 comes first on PATH.
        /usr/bin/python3 -m venv "$venv" >"$logs/venv.log" 2>&1 ||
            { cat "$logs/venv.log"; echo "python3 -m venv failed (apt-get install python3-venv)"; return 1; }
    fi
    _want_versions() {
        "$PY" - "$reqs" 2>/dev/null <<'EOF'
import sys
from importlib.metadata import version
for line in open(sys.argv[1]):
    line = line.split("#")[0].strip()
    if line:
        name, want = line.split("==")
        if version(name) != want:
            sys.exit(1)
EOF
    }
    _want_versions && return 0
    if [ "$install" -eq 0 ]; then
        echo "$venv lacks the versions of $reqs (run without --no-install)"
        return 1
    fi
    "$PY" -m pip install -q --disable-pip-version-check -r "$reqs" >"$logs/pip.log" 2>&1 ||
        { cat "$logs/pip.log"; echo "pip install failed"; return 1; }
    _want_versions || { echo "pip installed other versions than $reqs"; return 1; }
}

# ------------------------------------------------------------ C programs
C_BUILD_RESULT=result

# tsan_library LOG: the ThreadSanitizer build of the library (cargo -Zsanitizer=thread,
# into target/tsan; cargo's output to LOG), with its libmodbus.so.5 link. The
# directory is $TSAN_LIB_DIR (set for the suites that define ROOT).
TSAN_LIB_DIR=${ROOT:+$ROOT/target/tsan/x86_64-unknown-linux-gnu/release}
tsan_library() {
    RUSTC_BOOTSTRAP=1 RUSTFLAGS="-Zsanitizer=thread -Cunsafe-allow-abi-mismatch=sanitizer" \
        cargo build --release --lib --target x86_64-unknown-linux-gnu --target-dir "$ROOT/target/tsan" \
        >"$1" 2>&1 && ln -sf libmodbus.so "$TSAN_LIB_DIR/libmodbus.so.5"
}

c_build_dir() {
    local base=${CTEST_BUILD:-$ROOT/target/c-tests-build}
    case "${1:-}" in
    address) echo "$base/asan" ;;
    thread) echo "$base/tsan" ;;
    *) echo "$base/bin" ;;
    esac
}

c_build() {
    local vars=() san="" t log name rc=0
    while [ $# -gt 0 ] && [[ $1 == *=* ]]; do
        vars+=("$1")
        [[ $1 != SAN=* ]] || san=${1#SAN=}
        shift
    done
    local base=${CTEST_BUILD:-$ROOT/target/c-tests-build}
    mkdir -p "$base"
    for t in "$@"; do
        log=${LOGS:-$base}/build-$t${san:+-$san}.log
        name="build $t (c-tests/Makefile${san:+, SAN=$san})"
        # fd 9 is client.sh's lock: make must not hold it.
        if flock -w 900 "$base/.lock" make -C "$ROOT/c-tests" --no-print-directory "${vars[@]}" "$t" \
            >"$log" 2>&1 9>&-; then
            "$C_BUILD_RESULT" "$name" PASS
        else
            "$C_BUILD_RESULT" "$name" FAIL "see $log"
            head -n 20 "$log" | sed 's/^/    | /'
            # No program left from an earlier build runs in its place.
            rm -f "$(c_build_dir "$san")/$t"
            rc=1
        fi
    done
    return $rc
}

c_build_group() {
    local group=$1 targets
    shift
    targets=$(make -s -C "$ROOT/c-tests" --no-print-directory "$@" "print-$group" 2>&1) || {
        "$C_BUILD_RESULT" "build $group (c-tests/Makefile)" FAIL "$targets"
        return 1
    }
    # shellcheck disable=SC2086 # a list of target names
    c_build "$@" $targets
}

# ------------------------------------------------------------ processes
# shellcheck source=c-tests/common/session.sh
. "$(dirname "${BASH_SOURCE[0]}")/session.sh"
declare -a PIDS=()
declare -A _pids=()
LAST_PID=
STOP_GRACE=3

start_bg() {
    local o=$1 e=$2
    shift 2
    # Emptied here, not by the background job's redirection: a wait_ready right after
    # would otherwise find the previous run's READY in the file before the job opens it.
    : >"$o"
    : >"$e"
    # fd 9 is client.sh's lock: a process left behind must not hold it.
    if [ "$e" = "$o" ]; then
        "$@" >"$o" 2>&1 9>&- &
    else
        "$@" >"$o" 2>"$e" 9>&- &
    fi
    LAST_PID=$!
    PIDS+=("$LAST_PID")
}

forget_pid() {
    local keep=() p
    for p in "${PIDS[@]}"; do [ "$p" = "$1" ] || keep+=("$p"); done
    PIDS=("${keep[@]}")
}

stop_pid() {
    local pid=$1 i
    [ -n "$pid" ] || return 0
    if kill -0 "$pid" 2>/dev/null; then
        kill "$pid" 2>/dev/null || true
        for ((i = 0; i < STOP_GRACE * 10; i++)); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 0.1
        done
        kill -9 "$pid" 2>/dev/null || true
    fi
    wait "$pid" 2>/dev/null || true
    forget_pid "$pid"
}

wait_pid() {
    local rc=0
    wait "$1" || rc=$?
    forget_pid "$1"
    return $rc
}

start() {
    local name=$1
    shift
    start_bg "$WORK/$name.log" "$WORK/$name.log" "$@"
    _pids[$name]=$LAST_PID
}

stop() {
    stop_pid "${_pids[$1]:-}"
    unset "_pids[$1]"
}

# wait_exit NAME [SECS]: waits for NAME to exit (kills it after SECS, default 20).
wait_exit() {
    local pid=${_pids[$1]:-} secs=${2:-20} i
    rc=255
    [ -n "$pid" ] || return 0
    for ((i = 0; i < secs * 10; i++)); do
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.1
    done
    if kill -0 "$pid" 2>/dev/null; then
        kill "$pid" 2>/dev/null || true
        echo "       ($1 still running after ${secs}s: killed)"
    fi
    # shellcheck disable=SC2034 # read by the caller
    rc=0
    wait_pid "$pid" 2>/dev/null || rc=$?
    unset "_pids[$1]"
}

wait_for() {
    local file=$1 text=$2 secs=${3:-10} i
    for ((i = 0; i < secs * 10; i++)); do
        grep -qF -- "$text" "$file" 2>/dev/null && return 0
        sleep 0.1
    done
    return 1
}

wait_ready() {
    local name=$1 text=$2 secs=${3:-10} i pid=${_pids[$1]:-}
    for ((i = 0; i < secs * 10; i++)); do
        grep -qF -- "$text" "$WORK/$name.log" 2>/dev/null && return 0
        [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null || return 1
        sleep 0.1
    done
    return 1
}

free_port() {
    python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

socat_pair() {
    local o=$1 e=$2 a=$3 b=$4 secs=${5:-5} i
    rm -f "$a" "$b"
    start_bg "$o" "$e" socat -d -d "pty,raw,echo=0,link=$a" "pty,raw,echo=0,link=$b"
    for ((i = 0; i < secs * 10; i++)); do
        [ -e "$a" ] && [ -e "$b" ] && return 0
        sleep 0.1
    done
    return 1
}

pty_pair() {
    local rc=0
    socat_pair "$WORK/$1.log" "$WORK/$1.log" "$2" "$3" || rc=$?
    _pids[$1]=$LAST_PID
    return $rc
}

# Stops what is still running: TERM to all at once, then each one as stop_pid does.
_cleanup_pids() {
    local p
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
    for p in "${PIDS[@]}"; do stop_pid "$p"; done
    _pids=()
}
trap _cleanup_pids EXIT
trap 'echo "interrupted"; exit 130' INT TERM
