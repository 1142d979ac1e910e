#!/usr/bin/env bash
# stop.sh: stopping a context from a signal handler or from another thread,
# never a deadlock (issue 19). c-tests/stop/stop.c, one run per case x role x transport,
# first with Debian's libmodbus 3.1.6 (the oracle), then with ours; c-tests/stop/README.md
# lists the cases and what each library must do.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
#  1 term-parent, term-thread  SIGTERM, handler modbus_close + _exit(0): exit 0 < 1 s
#                              after the signal, the serial line's termios restored
#  2 free-exit                 handler modbus_close + modbus_free + _exit(0); also
#                              under valgrind (ours)
#  3 close-return              handler modbus_close, returns: -1 EBADF < 1 s, no
#                              descriptor left, termios back, the context works again
#  4 *-restart, *-norestart    flag-only handler (with and without SA_RESTART): the
#                              wait goes on within its timeout; modbus_tcp_accept too
#  5 thread-close, thread-free another thread closes / frees the context: the call
#                              returns < 100 ms, the waiting one -1 EBADF; free under
#                              valgrind (ours)
#  6 handler-call              calls from a handler on the interrupted context: EDEADLK
#  7 fork-thread               another thread forks during the call: the child's calls
#                              on the context return at once (no lock left held)
#  8 cancel, cancel-close      pthread_cancel of the thread in the call: ours lets the
#                              call end (timeout; modbus_close from another thread) and
#                              cancels at the next call; the context works after it
# Roles client (modbus_read_registers, silent peer) and server (modbus_receive, peer
# that sends nothing); transports tcp and rtu (socat pty pair), and for ours rtutcp
# and ascii. Every process started is stopped by its PID (the harness kills a hung
# child by its PID; the child dies with the harness, PR_SET_PDEATHSIG). Where Debian
# aborts or hangs, that is its recorded behaviour ("DIFF name"), not a failure.
#
# usage: c-tests/suites/stop.sh [--no-cargo] [--only REGEX] [--no-valgrind]
#          [--jobs N] [--ours DIR] [--debian-only | --ours-only]
#   --only REGEX  runs whose name matches, e.g. 'ours 3/' or '/rtu$' or 'close'
#   --jobs N      runs at the same time (6); each is mostly asleep
#   --ours DIR    where our libmodbus.so is (target/release); linked as
#                 target/stop/lib/libmodbus.so.5
# Logs: target/stop/logs/<run>.log. Last line "N passed, M failed"; non-zero exit on
# failure.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT" || exit 2
OUT=$ROOT/target/stop
LOGS=$OUT/logs
LIBDIR=$OUT/lib
OURS=$ROOT/target/release
SRC=$ROOT/c-tests/stop

# shellcheck source=c-tests/common/testlib.sh
. "$ROOT/c-tests/common/testlib.sh"
BIN=$(c_build_dir)

JOBS=6
LIBS="debian ours"
suite_flag() {
    case "$1" in
    --jobs) JOBS=$2; return 2 ;;
    --ours) OURS=$(cd "$2" && pwd) || exit 2; return 2 ;;
    --debian-only) LIBS=debian ;;
    --ours-only) LIBS=ours ;;
    *) return 1 ;;
    esac
}
parse_flags --only --no-valgrind -- "$@"

# ---------------------------------------------------------------- prerequisites
need=(gcc libmodbus-dev libmodbus5 socat)
[ "$VALGRIND" -eq 0 ] || need+=(valgrind)
missing=()
for p in "${need[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "installing: ${missing[*]}"
    [ "$(id -u)" = 0 ] || { echo "missing packages (${missing[*]}) and not root"; exit 2; }
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null 2>&1 ||
        { apt-get update -qq && apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null; } ||
        { echo "apt-get install ${missing[*]} failed"; exit 2; }
fi
mkdir -p "$BIN" "$LOGS" "$LIBDIR"
rm -f "$LOGS"/*.log
WORK=$OUT/run
rm -rf "$WORK"
mkdir -p "$WORK"

DEB_LIB=$(readlink -f "$(ldconfig -p | awk '$1 == "libmodbus.so.5" {print $NF; exit}')" 2>/dev/null)
if [ -z "$DEB_LIB" ] || [ ! -f "$DEB_LIB" ]; then
    echo "Debian's libmodbus.so.5 not found (apt-get install libmodbus5)"
    exit 2
fi
if [[ " $LIBS " == *" ours "* ]]; then
    if [ "$RUN_CARGO" = 1 ]; then
        if (cd "$ROOT" && cargo build --release) >"$LOGS/cargo.log" 2>&1; then
            ok "cargo build --release"
        else
            bad "cargo build --release" "$(tail -n 15 "$LOGS/cargo.log")"
        fi
    fi
    if [ ! -f "$OURS/libmodbus.so" ]; then
        bad "our libmodbus.so" "missing in $OURS"
        summary
        exit 1
    fi
    # the runs load it from this suite's own directory, as libmodbus.so.5
    ln -sfn "$(readlink -f "$OURS/libmodbus.so")" "$LIBDIR/libmodbus.so.5"
    OURS_LIB=$(readlink -f "$LIBDIR/libmodbus.so.5")
    echo "ours:   $OURS_LIB (as $LIBDIR/libmodbus.so.5)"
fi
echo "debian: $DEB_LIB"

# One binary for both libraries (c-tests/Makefile, group STOP): compiled against our
# headers, linked against Debian's libmodbus.so; the loader picks the library at run time
# (LD_LIBRARY_PATH). rsmodbus-only constructors are looked up with dlsym.
c_build_group STOP || { summary; exit 1; }

# ---------------------------------------------------------------- the runs
# name: "<lib> <n>/<case>/<role>/<transport>[/valgrind]"
declare -a R_NAME=() R_LIB=() R_CASE=() R_ROLE=() R_TR=() R_VG=()
add() { # LIB N CASE ROLE TRANSPORT [valgrind]
    local name="$1 $2/$3/$4/$5${6:+/$6}"
    selected "$name" || return 0
    [ -z "${6:-}" ] || [ "$VALGRIND" -eq 1 ] || return 0
    R_NAME+=("$name")
    R_LIB+=("$1")
    R_CASE+=("$3")
    R_ROLE+=("$4")
    R_TR+=("$5")
    R_VG+=("${6:-}")
}
transports() { if [ "$1" = ours ]; then echo tcp rtu rtutcp ascii; else echo tcp rtu; fi; }
# each case with Debian's library first, then with ours
add_case() { # N CASE ROLES [valgrind-for-ours]
    local n=$1 cs=$2 roles=$3 vg=${4:-} lib role tr
    for lib in $LIBS; do
        for role in $roles; do
            for tr in $(transports "$lib"); do
                if [ "$cs" = accept-restart ] || [ "$cs" = accept-norestart ]; then
                    [ "$tr" = tcp ] || [ "$tr" = rtutcp ] || continue
                fi
                add "$lib" "$n" "$cs" "$role" "$tr"
                if [ -n "$vg" ] && [ "$lib" = ours ]; then
                    add "$lib" "$n" "$cs" "$role" "$tr" valgrind
                fi
            done
        done
    done
}
add_case 1 term-parent "client server"
add_case 1 term-thread "client server"
add_case 2 free-exit "client server" valgrind
add_case 3 close-return "client server"
for r in restart norestart; do
    add_case 4 "client-timeout-$r" client
    add_case 4 "server-timeout-$r" server
    add_case 4 "server-forever-$r" server
    add_case 4 "accept-$r" server
done
add_case 5 thread-close "client server"
add_case 5 thread-free "client server" valgrind
add_case 6 handler-call "client server"
add_case 7 fork-thread "client server"
add_case 8 cancel "client server"
add_case 8 cancel-close "client server"

NRUNS=${#R_NAME[@]}
echo "$NRUNS runs, $JOBS at a time"
if [ "$NRUNS" -eq 0 ]; then
    bad "no run selected (--only ${ONLY:-})"
    summary
    exit 1
fi

declare -a R_PID=() R_SOCAT=() R_START=() R_RC=() R_LOG=() R_DONE=()
declare -A DIFFS=()

launch() { # I
    local i=$1 a=- b=- log
    log="$LOGS/$(echo "${R_NAME[$i]}" | tr ' /' '_-').log"
    R_LOG[i]=$log
    R_SOCAT[i]=""
    if [ "${R_TR[$i]}" = rtu ] || [ "${R_TR[$i]}" = ascii ]; then
        a=$WORK/pty$i-a
        b=$WORK/pty$i-b
        if ! socat_pair "$WORK/pty$i.log" "$WORK/pty$i.log" "$a" "$b" 10; then
            R_SOCAT[i]=$LAST_PID
            echo "socat pty pair did not come up" >"$log"
            R_PID[i]=""
            R_RC[i]=2
            return
        fi
        R_SOCAT[i]=$LAST_PID
    fi
    if [ "${R_LIB[$i]}" = ours ]; then
        start_bg "$log" "$log" env LD_LIBRARY_PATH="$LIBDIR" EXPECT_LIB=ours \
            STOP_VALGRIND="$([ -n "${R_VG[$i]}" ] && echo 1 || echo 0)" \
            "$BIN/stop" run "${R_CASE[$i]}" "${R_ROLE[$i]}" "${R_TR[$i]}" "$a" "$b"
    else
        start_bg "$log" "$log" env -u LD_LIBRARY_PATH -u LD_PRELOAD EXPECT_LIB=debian STOP_VALGRIND=0 \
            "$BIN/stop" run "${R_CASE[$i]}" "${R_ROLE[$i]}" "${R_TR[$i]}" "$a" "$b"
    fi
    R_PID[i]=$LAST_PID
    R_START[i]=$SECONDS
}

# libinfo_ok I: every process of the run (harness and child) reported the library it
# had to load; prints what is wrong
libinfo_ok() {
    local i=$1 want line path n=0 bad_lines=""
    if [ "${R_LIB[$i]}" = ours ]; then want=$OURS_LIB; else want=$DEB_LIB; fi
    while IFS= read -r line; do
        n=$((n + 1))
        path=${line#*libmodbus.so.5 = }
        path=${path%% (*}
        if [ "$(readlink -f "$path")" != "$want" ]; then
            bad_lines+="$line; "
        elif [ "${R_LIB[$i]}" = ours ] && [[ $line != *"(rsmodbus "* ]]; then
            bad_lines+="$line; "
        elif [ "${R_LIB[$i]}" = debian ] && [[ $line != *"(debian libmodbus"* ]]; then
            bad_lines+="$line; "
        fi
    done < <(grep -o 'LIBINFO: .*' "${R_LOG[$i]}")
    if [ "$n" -lt 2 ]; then
        echo "$n LIBINFO lines (harness and child expected)"
        return 1
    fi
    [ -z "$bad_lines" ] && return 0
    echo "expected $want: $bad_lines"
    return 1
}

report() { # I
    local i=$1 log rline detail why d
    log=${R_LOG[$i]}
    rline=$(grep -m1 '^RESULT ' "$log" 2>/dev/null)
    detail=""
    if [[ $rline == *"  ("*")" ]]; then
        detail=${rline#*  (}
        detail=${detail%)}
    fi
    if ! why=$(libinfo_ok "$i"); then
        bad "${R_NAME[$i]}: wrong or unproven library" "$why" "(see $log)"
        return
    fi
    if [ "${R_RC[$i]}" -eq 0 ] && [[ $rline == "RESULT PASS "* ]]; then
        result "${R_NAME[$i]}" PASS "$detail"
        while IFS= read -r d; do
            DIFFS[${d%%:*}]=$((${DIFFS[${d%%:*}]:-0} + 1))
        done < <(grep -oE '^(  child\| )?DIFF [a-z0-9-]+:' "$log" | sed 's/^.*DIFF //')
    else
        result "${R_NAME[$i]}" FAIL "${detail:-exit ${R_RC[$i]}, no RESULT line}"
        grep -E '^FAIL - |^  child\| FAIL - ' "$log" | head -n 6 | sed 's/^ */       /'
        echo "       (log: $log)"
    fi
}

next=0
printed=0
running=0
while [ "$printed" -lt "$NRUNS" ]; do
    while [ "$running" -lt "$JOBS" ] && [ "$next" -lt "$NRUNS" ]; do
        launch "$next"
        if [ -n "${R_PID[$next]}" ]; then
            running=$((running + 1))
        else
            R_DONE[next]=1
            stop_pid "${R_SOCAT[$next]}"
        fi
        next=$((next + 1))
    done
    for ((i = printed; i < next; i++)); do
        [ -z "${R_DONE[$i]:-}" ] || continue
        pid=${R_PID[$i]}
        if ! kill -0 "$pid" 2>/dev/null; then
            rc=0
            wait_pid "$pid" || rc=$?
            R_RC[i]=$rc
        elif [ $((SECONDS - R_START[i])) -gt 120 ]; then
            # the harness ends its child itself; this is the last resort
            echo "harness still running after 120 s: stopped" >>"${R_LOG[$i]}"
            stop_pid "$pid"
            R_RC[i]=124
        else
            continue
        fi
        R_DONE[i]=1
        running=$((running - 1))
        stop_pid "${R_SOCAT[$i]}"
    done
    while [ "$printed" -lt "$next" ] && [ -n "${R_DONE[$printed]:-}" ]; do
        report "$printed"
        printed=$((printed + 1))
    done
    [ "$printed" -lt "$NRUNS" ] && sleep 0.05
done

# ---------------------------------------------------------------- leftovers
# Nothing this run started may still be there: harnesses, children (also under
# valgrind) and socat pairs all carry $BIN/stop or $WORK in their command line.
ps_out=$(ps -eo pid=,args=)
left=$(grep -F -e "$BIN/stop" -e "$WORK/" <<<"$ps_out" || true)
if [ -z "$left" ]; then
    ok "no process left running"
else
    bad "processes left running" "$left"
fi

if [ ${#DIFFS[@]} -gt 0 ]; then
    echo
    echo "Named differences observed (Debian's libmodbus 3.1.6, recorded behaviour):"
    for d in $(printf '%s\n' "${!DIFFS[@]}" | sort); do
        printf '  %-28s %s run(s)\n' "$d" "${DIFFS[$d]}"
    done
fi
echo
summary
