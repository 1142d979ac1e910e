#!/usr/bin/env python3
"""A/B throughput of two builds of rsmodbus, measured the way the benchmark measures
(bench.interleaved): ours/ours with build A, ours/ours with build B, Debian/Debian and
the waiting floor take turns in slices of BENCH_SLICE s, in a new random order every
cycle, pinned to BENCH_PIN when set.

    python3 benches/ab.py A_DIR B_DIR [CASE ...]      (benches/ab.sh builds the DIRs)

A_DIR and B_DIR each hold a libmodbus.so.5. BENCH_SECONDS (default 30) is the time per
pairing, BENCH_TRANSPORTS the transports (default tcp; `tls`: Modbus/TCP Security, the
pairings A and B only, as Debian's libmodbus has no TLS and the floors no TLS either;
its cases include `conn`, a resumed handshake per transaction, and `conn-full`). Prints per case each pairing's
median tx/s and ratio to Debian/Debian, CPU per transaction, and B/A: the median of the
per-cycle ratios with its 95% confidence interval. A change whose interval holds 1.000
made no difference this method can see.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import sys

import bench
from bench import DD, WAIT, interleaved, log


def main():
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    dirs = [os.path.abspath(d) for d in sys.argv[1:3]]
    for d in dirs:
        if not os.path.exists(os.path.join(d, "libmodbus.so.5")):
            raise SystemExit(f"{d}/libmodbus.so.5 missing")
    if os.path.realpath(dirs[0]) == os.path.realpath(dirs[1]):
        raise SystemExit("A_DIR and B_DIR are the same directory: copy the library to measure a build against itself")
    cases = sys.argv[3:] or ["wr121"]
    seconds = float(os.environ.get("BENCH_SECONDS", "30"))
    transports = os.environ.get("BENCH_TRANSPORTS", "tcp").split()
    a, b = ((f"ours:{d}", f"ours:{d}") for d in dirs)
    bench.PAIRING_NAMES.update({a: "A", b: "B"})
    tcp_combos, tls_combos = [DD, a, b, WAIT], [a, b]
    print(f"A = {dirs[0]}\nB = {dirs[1]}\n{seconds:g} s per pairing in slices of {bench.SLICE} s"
          + (f", pinned to CPU(s) {bench.PIN}" if bench.PIN else ""))
    for transport in transports:
        for case in cases:
            combos = tls_combos if transport == "tls" else tcp_combos
            log(f"{transport} {case}: A/B")
            run = interleaved(transport, case, combos, seconds, bench.SLICE)
            print(f"\n{transport} {case}")
            for c in combos:
                cpu = run.cpu_us(c)
                vs_debian = "" if DD not in combos else (f", {run.ratio(c, DD):.3f}x"
                                                        + ("" if c == DD else f" ({run.spread(c, DD)})") + " Debian/Debian")
                print(f"  {bench.PAIRING_NAMES[c]:>15}: {run.tps(c):8.0f} tx/s{vs_debian}, "
                      f"CPU {' + '.join(f'{x:.2f}' for x in cpu)} us/tx")
            floors = "" if WAIT not in combos else \
                f"; A/waiting floor {run.ratio(a, WAIT):.1%}, B/waiting floor {run.ratio(b, WAIT):.1%}"
            print(f"  B/A: {run.ratio(b, a):.4f} ({run.spread(b, a)}){floors}")
    if bench.STALLS:
        print("slow slices: " + "; ".join(bench.STALLS))


if __name__ == "__main__":
    bench.run_main(main)
