#!/usr/bin/env python3
"""The training run of the profile-guided build (scripts/build-pgo.sh): the benchmark's
client and server, both loading the instrumented library in LIB_DIR, run every case of
the benchmark over TCP loopback (PGO_RTU_TX > 0: also as RTU over a socat pty pair).

    python3 benches/pgo-train.py BIN_DIR LIB_DIR

BIN_DIR holds mb-server and bench-client (benches/build.sh), LIB_DIR the instrumented
libmodbus.so.5. Both programs must end normally, since the profile is written at exit:
the server stops by itself after as many replies as the client makes requests. Each
program must also have loaded the library in LIB_DIR, or the run fails. A fixed number
of transactions, not a time, so that the same source gives the same profile, and the
same library: on loopback every read takes a whole frame. Not so on a pty, where how a
frame splits into reads varies from run to run; and a profile trained on RTU too gave
RTU no measurable gain (benches/README.md), so RTU is left out by default.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import sys

# The benchmark's own helpers (with BENCH_PIN set, the training is pinned too).
from bench import CASE_TITLES, PtyPair, harness, reap_client, start, wait_ready

# Transactions per case and transport.
COUNTS = {"tcp": int(os.environ.get("PGO_TCP_TX", "20000")), "rtu": int(os.environ.get("PGO_RTU_TX", "0"))}
TIMEOUT = 120


def train(bin_dir, lib, transport, case, count):
    """One case: a server for exactly `count` replies and a client for `count` requests."""
    env = harness.env_for(lib)
    env.pop("BENCH_COUNTER", None)
    pty = PtyPair("rsmodbus-pgo-", 5) if transport == "rtu" else None
    try:
        where = pty.a if pty else "0"
        server = start([os.path.join(bin_dir, "mb-server"), transport, where, str(count)], env)
        address = wait_ready(server, f"mb-server {transport}", 10, lib)
        client = start([os.path.join(bin_dir, "bench-client"), transport, pty.b if pty else address, case,
                        "-n", str(count), "-w", "0"], env)
        reap_client(client, f"bench-client {transport} {case}", lib, TIMEOUT)
        reap_client(server, f"mb-server {transport} {case}", None, TIMEOUT)
    finally:
        if pty:
            pty.close()


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    bin_dir, lib_dir = (os.path.abspath(d) for d in sys.argv[1:])
    lib = f"ours:{lib_dir}"
    for transport in ("tcp", "rtu"):
        for case in CASE_TITLES if COUNTS[transport] > 0 else []:
            train(bin_dir, lib, transport, case, COUNTS[transport])
            print(f"pgo-train: {transport} {case}: {COUNTS[transport]} transactions")


if __name__ == "__main__":
    try:
        main()
    finally:
        harness.stop_all()
