# shellcheck shell=bash
# session_pids SID: the processes of session SID (its leader's and what they started),
# zombies left out (dead already; reaping them is their parent's or init's business).
# Sourced by c-tests/run and c-tests/common/testlib.sh (the suites).
# SPDX-License-Identifier: MIT OR Apache-2.0
session_pids() { ps -eo pid=,sid=,stat= | awk -v s="$1" '$2 == s && $3 !~ /^Z/ { print $1 }'; }
