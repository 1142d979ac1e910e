#!/usr/bin/env bash
# run-self.sh: the test runner itself (c-tests/run), on tables of its own (TEST_TABLE)
# whose rows are small shell commands:
#   - counts: a suite's "PASSED FAILED" file, cargo's "test result:" lines, a row that
#     reports nothing (one check by its exit status), an exit status that is not 0 with
#     no failure counted (one failure), and the closing line summing them all;
#   - a process a row leaves running is named, stopped by its PID and counted as a
#     failure;
#   - & rows run beside each other: each waits for a file the other writes (it gives up
#     after 60 s, failing, when run one after the other); never more than TEST_JOBS at
#     once; a row without & runs alone; TEST_JOBS=1 runs them one after the other;
#   - a & row's output is shown whole, after its start line;
#   - an interrupted run (TERM) stops the suites running beside each other and leaves
#     no process of its own (the background rows' shells, their timeout watchers).
# Ends with "N passed, M failed".
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 1
ROOT=$PWD
# shellcheck source=c-tests/common/testlib.sh
. c-tests/common/testlib.sh
W=$ROOT/target/run-self
rm -rf "$W"
mkdir -p "$W"

# alive PID: PID runs (a zombie has ended: its parent, init here, has not reaped it yet).
alive() { local s; s=$(ps -o stat= -p "$1" 2>/dev/null) && [[ $s != Z* ]]; }

# run TABLE OUT [VAR=VALUE...]: c-tests/run on TABLE, two rows at a time (whatever
# TEST_JOBS the run of this suite has) unless VAR=VALUE says, its logs in W/logs-OUT,
# its output in W/OUT.
run() {
    local table=$1 out=$2
    shift 2
    env TEST_JOBS=2 "$@" TEST_TABLE="$table" TEST_LOGS="$W/logs-$out" c-tests/run >"$W/$out" 2>&1
}

# --- counts, failures, a process left running ----------------------------------------
cat >"$W/counts.txt" <<EOF
counted   suite&  echo "3 1" >"\$MBT_COUNTS"
cargoish  cargo&  printf 'test result: ok. 4 passed; 0 failed\ntest result: ok. 2 passed; 1 failed\n'
silent    suite   true
exits     suite&  exit 3
leaves    suite&  sleep 300 & echo \$! >"$W/left.pid"
EOF
run "$W/counts.txt" counts
rc=$?
# Each row's counts and one check of what it left running: counted 3+1 passed, 1
# failed (its "PASSED FAILED"); cargoish 6+1 / 1 (two "test result:" lines); silent
# 1+1 / 0 (its exit status); exits 0+1 / 1 (exit 3 counts a failure); leaves 1+0 / 1.
expect_line "the closing line sums every row's counts" "$W/counts" "15 passed, 4 failed"
if [ "$rc" -ne 0 ]; then ok "a run with failures exits non-zero ($rc)"; else bad "a run with failures exits non-zero" "it exited 0"; fi
# (in the order they ended: & rows end in any order)
named=$(sed -n 's/^failed suites: //p' "$W/counts" | tr ' ' '\n' | sort | paste -sd' ')
if [ "$named" = "cargoish counted exits leaves" ]; then
    ok "the failed suites are named"
else
    bad "the failed suites are named" "$(grep '^failed suites' "$W/counts")"
fi
left=$(cat "$W/left.pid" 2>/dev/null)
if grep -q "^FAIL - leaves: left no process running; stopped:" "$W/counts" && grep -q "^ *$left sleep 300" "$W/counts"; then
    ok "a process a row left running is named (PID $left)"
else
    bad "a process a row left running is named" "$(grep -A2 'left no process' "$W/counts")"
fi
if [ -n "$left" ] && ! alive "$left"; then
    ok "it is stopped"
else
    bad "it is stopped" "PID '$left' still runs"
    [ -z "$left" ] || kill "$left" 2>/dev/null
fi

# --- side by side ------------------------------------------------------------------------
# meet ME OTHER: ME's file, then OTHER's awaited (60 s at most); every & row also notes
# how many rows were running when it started (their files in W/running).
mkdir -p "$W/running"
cat >"$W/meet.sh" <<EOF
me=\$1 other=\$2
touch "$W/running/\$me"
ls "$W/running" | wc -l >"$W/started-with.\$me"
touch "$W/here.\$me"
for i in \$(seq 600); do [ -e "$W/here.\$other" ] && break; sleep 0.1; done
echo "\$me met \$other: \$([ -e "$W/here.\$other" ] && echo yes || echo no)"
rm -f "$W/running/\$me"
[ -e "$W/here.\$other" ]
EOF
cat >"$W/beside.txt" <<EOF
a      suite&  bash $W/meet.sh a b
b      suite&  bash $W/meet.sh b a
alone  suite   ls $W/running | wc -l | grep -qx 0
c      suite&  bash $W/meet.sh c d
d      suite&  bash $W/meet.sh d c
e      suite&  bash $W/meet.sh e e
EOF
run "$W/beside.txt" beside
expect_line "& rows run beside each other: every pair met" "$W/beside" "12 passed, 0 failed"
most=$(cat "$W"/started-with.* 2>/dev/null | sort -n | tail -n 1)
if [ "$most" = 2 ]; then
    ok "never more than TEST_JOBS (2) rows at once (at most $most)"
else
    bad "never more than TEST_JOBS (2) rows at once" "a row started with $most running"
fi
if grep -q '^a met b: yes$' "$W/beside" && awk '/^=== a: its output/ { s = 1; next } s && /^a met b: yes$/ { f = 1 } END { exit !f }' "$W/beside"; then
    ok "a & row's output is shown after its start line"
else
    bad "a & row's output is shown after its start line" "$(head -n 20 "$W/beside")"
fi
rm -f "$W"/here.* "$W"/started-with.*
printf 'a suite& bash %s a b\nb suite& bash %s b a\n' "$W/meet.sh" "$W/meet.sh" >"$W/serial.txt"
sed -i 's/600/20/' "$W/meet.sh"
run "$W/serial.txt" serial TEST_JOBS=1
if grep -q '^a met b: no$' "$W/serial" && grep -q '^b met a: yes$' "$W/serial"; then
    ok "TEST_JOBS=1 runs & rows one after the other"
else
    bad "TEST_JOBS=1 runs & rows one after the other" "$(grep ' met ' "$W/serial")"
fi

# --- a suite past SUITE_TIMEOUT ---------------------------------------------------------------
printf 'slow suite& sleep 300 & echo $! >%s/slow.pid; wait\nquick suite& true\n' "$W" >"$W/timeout.txt"
run "$W/timeout.txt" timeout SUITE_TIMEOUT=2
p=$(cat "$W/slow.pid" 2>/dev/null)
if grep -q '^=== slow: still running after 2s: stopped$' "$W/timeout" && grep -q '^3 passed, 1 failed$' "$W/timeout" &&
    [ -n "$p" ] && ! alive "$p"; then
    ok "a suite still running after SUITE_TIMEOUT is stopped and fails; the others pass"
else
    bad "a suite still running after SUITE_TIMEOUT is stopped and fails" "$(tail -n 8 "$W/timeout")"
    [ -z "$p" ] || kill "$p" 2>/dev/null
fi

# --- interrupted -------------------------------------------------------------------------
# The runner in a session of its own (setsid: its PID is the session's ID), so that
# what it leaves behind is found: its sessions' processes (the rows' sleeps, each in a
# session the runner made) and its own (the background rows' shells, their watchers).
printf 'x suite& sleep 300 & echo $! >%s/x.pid; wait\ny suite& sleep 300 & echo $! >%s/y.pid; wait\n' "$W" "$W" >"$W/stop.txt"
TEST_JOBS=2 TEST_TABLE=$W/stop.txt TEST_LOGS=$W/logs-stop setsid c-tests/run >"$W/stop" 2>&1 &
runner=$!
for _ in $(seq 300); do [ -s "$W/x.pid" ] && [ -s "$W/y.pid" ] && break; sleep 0.1; done
kill -TERM "$runner"
wait "$runner"
rc=$?
still=()
for f in x y; do
    p=$(cat "$W/$f.pid" 2>/dev/null)
    if [ -z "$p" ]; then still+=("$f: never started"); elif alive "$p"; then still+=("$f: $p"); kill "$p"; fi
done
# Its own processes: gone when it has exited (zombies aside: init reaps them).
own=$(ps -o pid=,args= -p "$(session_pids "$runner" | paste -sd, -)" 2>/dev/null)
if [ "$rc" = 130 ] && [ ${#still[@]} -eq 0 ] && [ -z "$own" ]; then
    ok "an interrupted run stops the suites running beside each other and leaves nothing (exit 130)"
else
    bad "an interrupted run stops the suites running beside each other and leaves nothing" \
        "exit $rc; rows' processes left: ${still[*]}" "the runner's: $own"
    # shellcheck disable=SC2046 # PIDs
    [ -z "$own" ] || kill $(awk '{ print $1 }' <<<"$own") 2>/dev/null
fi

summary
