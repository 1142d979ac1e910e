# shellcheck shell=bash
# Shared helpers for scripts/check-examples.sh, check-package.sh and check-man.sh.
# Source it; it defines:
#   ok/bad/check NAME ...   count one check (check runs a command, quietly)
#   expect_line NAME FILE LINE    FILE must contain exactly the line LINE
#   start NAME CMD...       start CMD in the background (output in $WORK/NAME.log),
#                           remember its PID; every one is killed at exit
#   stop NAME               stop that process by its PID and wait for it
#   wait_exit NAME [SECS]   wait for it to end by itself; sets $rc to its exit code
#   wait_for FILE TEXT [SECS]   wait until FILE contains TEXT
#   wait_ready NAME TEXT [SECS] wait until started process NAME prints TEXT; fails
#                           at once if it has exited
#   free_port               print a free TCP port on 127.0.0.1
#   pty_pair NAME A B       socat pty pair, links $A and $B (waits until both exist)
#   summary                 print "N passed, M failed" and return non-zero on failure
# The caller sets WORK (a scratch directory) before sourcing.
# SPDX-License-Identifier: MIT OR Apache-2.0

passed=0
failed=0
declare -A _pids=()

ok() { passed=$((passed + 1)); echo "ok   - $1"; }
bad() {
    failed=$((failed + 1))
    echo "FAIL - $1"
    shift
    local line
    for line in "$@"; do echo "       $line"; done
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

_cleanup_pids() {
    local name
    for name in "${!_pids[@]}"; do
        kill "${_pids[$name]}" 2>/dev/null || true
    done
    for name in "${!_pids[@]}"; do
        wait "${_pids[$name]}" 2>/dev/null || true
    done
    _pids=()
}

start() {
    local name=$1
    shift
    "$@" >"$WORK/$name.log" 2>&1 &
    _pids[$name]=$!
}

stop() {
    local pid=${_pids[$1]:-}
    [ -n "$pid" ] || return 0
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
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
    wait "$pid" 2>/dev/null
    # shellcheck disable=SC2034 # read by the caller
    rc=$?
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

pty_pair() {
    local name=$1 a=$2 b=$3 i
    rm -f "$a" "$b"
    start "$name" socat pty,raw,echo=0,link="$a" pty,raw,echo=0,link="$b"
    for ((i = 0; i < 50; i++)); do
        [ -e "$a" ] && [ -e "$b" ] && return 0
        sleep 0.1
    done
    return 1
}

summary() {
    echo "$passed passed, $failed failed"
    [ "$failed" -eq 0 ]
}

trap _cleanup_pids EXIT
