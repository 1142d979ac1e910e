#!/usr/bin/env bash
# A short run of the benchmark suite (read 1 register over TCP and RTU, and read 125
# registers and new connections over TLS against plain TCP), part
# of the test command so that the benchmark keeps working between full runs. It checks:
# every program loaded the library it was meant to (bench.py stops otherwise), the
# report has all its tables, and the targets judged on counts per transaction are met:
# system calls and heap allocations, and instructions over TCP (on a pty, how the
# bytes of a frame are split between reads depends on timing). Throughput verdicts
# are printed, not judged: timing is never a pass/fail test here. Then two short runs
# of the between-runs measurement (benches/repeat.py), whose report is checked too.
#
#   c-tests/suites/bench-smoke.sh    report in target/bench/smoke.md, log in target/bench/smoke.log
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p target/bench
report=target/bench/smoke.md
rm -f "$report"
status=0
BENCH_QUICK=1 BENCH_FLOOR_PARTS=1 BENCH_CASES=r1 BENCH_METRIC_CASES=r1 BENCH_TLS_METRICS="strace allocs" \
    BENCH_RESULTS="$report" scripts/bench.sh \
    >/dev/null 2>target/bench/smoke.log || status=$?
if [ "$status" -ne 0 ]; then
    tail -n 20 target/bench/smoke.log
    echo "bench-smoke: scripts/bench.sh exited $status"
fi
# The between-runs measurement (scripts/bench.sh --repeat), two short runs on the
# library bench.sh just measured.
repeat_out=target/bench/smoke-repeat.txt
BENCH_SECONDS=0.3 BENCH_OURS_DIR=$PWD/target/bench/ours python3 benches/repeat.py 2 r1 \
    >"$repeat_out" 2>>target/bench/smoke.log || { status=$?; echo "bench-smoke: benches/repeat.py exited $status"; }
python3 - "$report" "$repeat_out" <<'PY'
import os, re, sys

path = sys.argv[1]
text = open(path).read() if os.path.exists(path) else ""
repeat = open(sys.argv[2]).read() if os.path.exists(sys.argv[2]) else ""
checks = []


def check(ok, what):
    checks.append(ok)
    print(f"{'PASS' if ok else 'FAIL'} {what}")


for heading in ("### Transactions per second", "### What each wait costs (TCP)", "### The data floor (TCP)",
                "### CPU time per transaction",
                "### Cost per transaction (steady state)", "### Against the targets"):
    check(heading in text, f"report has '{heading}'")
for transport in ("TCP", "RTU"):
    check(re.search(rf"^\| {transport} \| read 1 register \| [0-9,]+ \| [0-9,]+ \|", text, re.M) is not None,
          f"{transport} throughput row with figures")
    check(re.search(rf"^\| {transport} \| read 1 register \|( [0-9.]+ µs \|){{4}} [-+][0-9.]+ \+ [-+][0-9.]+ µs \|$",
                    text, re.M) is not None, f"{transport} CPU time row with figures")
    for side in ("client", "server"):
        check(re.search(rf"^\| {transport} \| read 1 register \| {side} \| [0-9.]+ \| [0-9.]+ \|", text, re.M)
              is not None, f"{transport} {side} cost row")
# Modbus/TCP Security: TLS against plain TCP, new connections (full and resumed
# handshakes), costs per TLS transaction.
check("### Modbus/TCP Security (TLS)" in text, "report has the TLS section")
check(re.search(r"^\| read 125 registers \|( [0-9,]+ \|){3} [0-9.]+% \([^)]*\) \| [0-9.]+x \|", text, re.M)
      is not None, "TLS throughput row (read 125 registers) with figures")
for pairing in ("plain TCP, ours/ours", "TLS, resumed handshakes", "TLS, full handshakes"):
    check(re.search(rf"^\| {re.escape(pairing)} \| [0-9,]+ \| [0-9.]+% ", text, re.M) is not None,
          f"connections per second: {pairing}")
for side in ("client", "server"):
    check(re.search(rf"^\| read 125 registers \| {side} \| [0-9.]+ \| [0-9.]+ \| [a-z]", text, re.M) is not None,
          f"TLS {side} cost row")
check(re.search(r"^\| read 1 register \| [0-9,]+ \|( [0-9.]+% \([^)]*\) \|){3}$", text, re.M) is not None,
      "TCP row of the priced waits (floor + peek, floor + timeout, waiting floor)")
check(re.search(r"^\| read 1 register \| [0-9.]+x( \| [0-9.]+x \([^)]*\)){2} \| [0-9.]+% \([^)]*\) \|$", text, re.M)
      is not None, "TCP row of the data floor")
# Verdicts on counts per transaction: system calls, instructions, allocations. On a
# pty the bytes of a frame may arrive in more reads when the machine is busy, which
# adds instructions to either library: RTU instruction verdicts are shown, not judged.
counted = [m for m in re.finditer(r"^\| ([^|]*(system calls|instructions|allocation)[^|]*) \| ([^|]+) \|", text, re.M)]
# TCP and RTU: 2 sides x (system calls on TCP, instructions, allocations) = 10; TLS:
# system calls per side = 2.
check(len(counted) == 12, f"12 verdicts on counts per transaction (found {len(counted)})")
for m in counted:
    target, verdict = m.group(1).strip(), m.group(3).strip()
    if target.startswith("RTU") and m.group(2) == "instructions":
        print(f"INFO {target}: {verdict}")
    else:
        check(verdict == "met", f"{target}: {verdict}")
check(len(re.findall(r"^  run [12]: ours/ours [0-9.]+x \(", repeat, re.M)) == 2, "repeat: two runs with their ratios")
check(len(re.findall(r"^ +(ours/ours|waiting floor|data floor): mean [0-9.]+x, sd [0-9.]+, 95% CI of the mean ",
                     repeat, re.M)) == 3, "repeat: mean, sd and CI over the runs for ours/ours and the two floors")
failed = checks.count(False)
print(f"bench-smoke: {len(checks) - failed} passed, {failed} failed")
if os.environ.get("MBT_COUNTS"):
    with open(os.environ["MBT_COUNTS"], "w") as f:
        f.write(f"{len(checks) - failed} {failed}\n")
sys.exit(1 if failed else 0)
PY
[ "$status" -eq 0 ]
