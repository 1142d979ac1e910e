#!/usr/bin/env bash
# A short run of the benchmark suite (about 20 s: read 1 register, TCP and RTU), part
# of the test command so that the benchmark keeps working between full runs. It checks:
# every program loaded the library it was meant to (bench.py stops otherwise), the
# report has all its tables, and the targets judged on exact counts per transaction
# (system calls, instructions, heap allocations) are met. Throughput verdicts are
# printed, not judged: timing is never a pass/fail test here.
#
#   scripts/run-bench-smoke.sh    report in target/bench/smoke.md, log in target/bench/smoke.log
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p target/bench
report=target/bench/smoke.md
rm -f "$report"
status=0
BENCH_QUICK=1 BENCH_CASES=r1 BENCH_METRIC_CASES=r1 BENCH_RESULTS="$report" scripts/bench.sh \
    >/dev/null 2>target/bench/smoke.log || status=$?
if [ "$status" -ne 0 ]; then
    tail -n 20 target/bench/smoke.log
    echo "bench-smoke: scripts/bench.sh exited $status"
fi
python3 - "$report" <<'PY'
import os, re, sys

path = sys.argv[1]
text = open(path).read() if os.path.exists(path) else ""
checks = []


def check(ok, what):
    checks.append(ok)
    print(f"{'PASS' if ok else 'FAIL'} {what}")


for heading in ("### Transactions per second", "### CPU time per transaction",
                "### Cost per transaction (steady state)", "### Against the targets"):
    check(heading in text, f"report has '{heading}'")
for transport in ("TCP", "RTU"):
    check(re.search(rf"^\| {transport} \| read 1 register \| [0-9,]+ \| [0-9,]+ \|", text, re.M) is not None,
          f"{transport} throughput row with figures")
    for side in ("client", "server"):
        check(re.search(rf"^\| {transport} \| read 1 register \| {side} \| [0-9.]+ \| [0-9.]+ \|", text, re.M)
              is not None, f"{transport} {side} cost row")
# Verdicts on exact counts: system calls, instructions, allocations per transaction.
exact = [m for m in re.finditer(r"^\| ([^|]*(system calls|instructions|allocation)[^|]*) \| ([^|]+) \|", text, re.M)]
check(len(exact) == 10, f"10 verdicts on exact counts (found {len(exact)})")
for m in exact:
    check(m.group(3).strip() == "met", f"{m.group(1).strip()}: {m.group(3).strip()}")
failed = checks.count(False)
print(f"bench-smoke: {len(checks) - failed} passed, {failed} failed")
sys.exit(1 if failed else 0)
PY
[ "$status" -eq 0 ]
