#!/usr/bin/env python3
"""How far a ratio moves between runs: the benchmark's interleaved measurement
(bench.interleaved) of ours/ours, Debian/Debian and the floors, repeated RUNS times,
each time with new processes (new address-space layouts, new connections).

    python3 benches/repeat.py RUNS [CASE ...]   (scripts/bench.sh --repeat RUNS [CASE ...] builds first)

The confidence interval the benchmark prints is computed from the cycles of one run,
whose processes live for the whole run; it cannot show what changes when they are
started again. This prints, per case, every run's ratios to Debian/Debian (ours/ours,
the waiting floor and, over TCP, the data floor), then their mean, standard deviation
and the 95% confidence interval of the mean over the runs (Student's t).
BENCH_SECONDS (default 10) is the time per pairing in each run, BENCH_TRANSPORTS the
transports (default tcp), BENCH_OURS_DIR the library measured.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import math
import os
import statistics
import sys

import bench
from bench import DATA, DD, OO, WAIT, interleaved, log

# Two-sided 95% quantiles of Student's t for 1..30 degrees of freedom.
T95 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
       2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
       2.052, 2.048, 2.045, 2.042]


def mean_ci(values):
    """Mean, standard deviation and the 95% confidence interval of the mean."""
    m, sd = statistics.mean(values), statistics.stdev(values)
    half = T95[min(len(values) - 1, len(T95)) - 1] * sd / math.sqrt(len(values))
    return m, sd, (m - half, m + half)


def main():
    if len(sys.argv) < 2 or not sys.argv[1].isdigit() or int(sys.argv[1]) < 2:
        raise SystemExit(__doc__)
    runs = int(sys.argv[1])
    cases = sys.argv[2:] or ["wr121"]
    unknown = [c for c in cases if c not in bench.CASE_TITLES]
    if unknown:
        raise SystemExit(f"unknown case(s) {' '.join(unknown)}: one of {' '.join(bench.CASE_TITLES)}")
    seconds = float(os.environ.get("BENCH_SECONDS", "10"))
    transports = os.environ.get("BENCH_TRANSPORTS", "tcp").split()
    if not os.path.exists(os.path.join(bench.OURS_DIR, "libmodbus.so.5")):
        raise SystemExit(f"{bench.OURS_DIR}/libmodbus.so.5 missing")
    print(f"Ours: {os.environ.get('BENCH_OURS_BUILD', bench.OURS_DIR)}; {runs} runs of {seconds:g} s per pairing "
          f"in slices of {bench.SLICE} s" + (f", pinned to CPU(s) {bench.PIN}" if bench.PIN else ""))
    for transport in transports:
        for case in cases:
            combos = [DD, OO, WAIT] + ([DATA] if transport == "tcp" else [])
            measured = [c for c in combos if c != DD]
            ratios = {c: [] for c in measured}
            print(f"\n{transport} {bench.CASE_TITLES[case]}: ratio to Debian/Debian per run "
                  f"(median of the cycles, with the run's own 95% CI)")
            for k in range(runs):
                log(f"{transport} {case}: run {k + 1} of {runs}")
                run = interleaved(transport, case, combos, seconds, bench.SLICE)
                for c in measured:
                    ratios[c].append(run.ratio(c, DD))
                print(f"  run {k + 1}: " + "; ".join(
                    f"{bench.PAIRING_NAMES[c]} {run.ratio(c, DD):.3f}x ({run.spread(c, DD)})" for c in measured)
                    + f"; ours/ours {run.ratio(OO, measured[-1]):.1%} of the {bench.PAIRING_NAMES[measured[-1]]}",
                    flush=True)
            for c in measured:
                m, sd, (lo, hi) = mean_ci(ratios[c])
                print(f"  {bench.PAIRING_NAMES[c]:>15}: mean {m:.4f}x, sd {sd:.4f}, 95% CI of the mean "
                      f"{lo:.4f}-{hi:.4f}x (runs: {min(ratios[c]):.3f}-{max(ratios[c]):.3f}x)")
    if bench.STALLS:
        print("slow slices: " + "; ".join(bench.STALLS))


if __name__ == "__main__":
    bench.run_main(main)
