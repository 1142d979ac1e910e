#!/usr/bin/env python3
"""The training run of the profile-guided build (scripts/build-pgo.sh): the benchmark's
client and server, both loading the instrumented library in LIB_DIR, run every case of
the benchmark over TCP loopback, then the cases PGO_TLS_CASES (default read 125
registers and read 1 register) over Modbus/TCP Security (TLS) on loopback, with the
certificates of c-tests/tls/make-certs.sh (PGO_RTU_TX > 0: also every case as RTU over
a socat pty pair).

    python3 benches/pgo-train.py BIN_DIR LIB_DIR TLS_RAW_DIR
    python3 benches/pgo-train.py --round TEXT_IN TEXT_OUT

BIN_DIR holds mb-server and bench-client (benches/build.sh), LIB_DIR the instrumented
libmodbus.so.5. Both programs must end normally, since the profile is written at exit:
the server stops by itself after as many replies as the client makes requests. Each
program must also have loaded the library in LIB_DIR, or the run fails. A fixed number
of transactions, not a time, so that the same source gives the same profile, and the
same library: on loopback every read takes a whole frame. Not so on a pty, where how a
frame splits into reads varies from run to run; and a profile trained on RTU too gave
RTU no measurable gain (benches/README.md), so RTU is left out by default.

Over TLS a transaction is as fixed as over TCP (a record per request and per reply),
but a connection is not: the certificates are made anew, an ECDSA signature's encoding
varies in length, the handshake waits for the peer's flights a varying number of times
and the client's first read may take the session tickets alone. In three trainings
(2026-12-06), 109 of the TLS profile's 37,044 counts differed, by at most 24, and every
one of them was within 600 of a multiple of 20,000 (PGO_TLS_TX) but one (11,046 +- 5).
So the TLS processes write their profile to TLS_RAW_DIR of its own, and `--round`
(build-pgo.sh, on that profile in llvm-profdata's text form) rounds each count to the
nearest multiple of PGO_TLS_TX: the transactions' counts, multiples of it give or take
the handshake's few, come out exact; the handshake's own come to 0, as if it had not
run (as before TLS was trained). Four trainings gave the same profile byte for byte.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import shutil
import subprocess
import sys
import tempfile

# The benchmark's own helpers (with BENCH_PIN set, the training is pinned too).
from bench import CASE_TITLES, PtyPair, harness, reap_client, start, wait_ready, with_certs

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Transactions per case and transport.
COUNTS = {"tcp": int(os.environ.get("PGO_TCP_TX", "20000")), "tls": int(os.environ.get("PGO_TLS_TX", "20000")),
          "rtu": int(os.environ.get("PGO_RTU_TX", "0"))}
# The cases trained over TLS (TCP and RTU: every case).
TLS_CASES = os.environ.get("PGO_TLS_CASES", "r125 r1").split()
TIMEOUT = 120


def train(bin_dir, lib, transport, case, count, certs=None, tls_raw=None):
    """One case: a server for exactly `count` replies and a client for `count` requests."""
    env = harness.env_for(lib)
    env.pop("BENCH_COUNTER", None)
    server_env = client_env = env
    if transport == "tls":
        # The profile's own directory (see the top): %m the library's signature, %p the process.
        env = dict(env, LLVM_PROFILE_FILE=os.path.join(tls_raw, "%m_%p.profraw"))
        server_env, client_env = with_certs(env, certs, "server"), with_certs(env, certs, "client")
    pty = PtyPair("rsmodbus-pgo-", 5) if transport == "rtu" else None
    try:
        where = pty.a if pty else "0"
        server = start([os.path.join(bin_dir, "mb-server"), transport, where, str(count)], server_env)
        address = wait_ready(server, f"mb-server {transport}", 10, lib)
        client = start([os.path.join(bin_dir, "bench-client"), transport, pty.b if pty else address, case,
                        "-n", str(count), "-w", "0"], client_env)
        reap_client(client, f"bench-client {transport} {case}", lib, TIMEOUT)
        reap_client(server, f"mb-server {transport} {case}", None, TIMEOUT)
    finally:
        if pty:
            pty.close()


def round_counts(text, grain):
    """llvm-profdata's text form of a profile with every count (of a block, or of a value:
    an indirect call's target, a copy's length) rounded to the nearest multiple of
    `grain`; a value whose count comes to 0 is left out."""
    lines, out, i = text.split("\n"), [], 0

    def nearest(count):
        return (count + grain // 2) // grain * grain

    while i < len(lines):
        line = lines[i]
        out.append(line)
        i += 1
        if line == "# Counter Values:":
            for _ in range(int(out[-2])):  # "# Num Counters:", its number, then this line
                out.append(str(nearest(int(lines[i]))))
                i += 1
        elif line == "# NumValueSites:":
            out.append(lines[i])
            sites, i = int(lines[i]), i + 1
            for _ in range(sites):
                values, i = int(lines[i]), i + 1
                kept = []
                for value, count in (lines[j].rsplit(":", 1) for j in range(i, i + values)):
                    if nearest(int(count)) > 0:
                        kept.append((value, nearest(int(count))))
                i += values
                kept.sort(key=lambda vc: (-vc[1], vc[0]))
                out.append(str(len(kept)))
                out.extend(f"{value}:{count}" for value, count in kept)
    return "\n".join(out)


def main():
    if len(sys.argv) == 4 and sys.argv[1] == "--round":
        with open(sys.argv[2]) as f:
            text = round_counts(f.read(), max(COUNTS["tls"], 1))
        with open(sys.argv[3], "w") as f:
            f.write(text)
        return
    if len(sys.argv) != 4:
        raise SystemExit(__doc__)
    bin_dir, lib_dir, tls_raw = (os.path.abspath(d) for d in sys.argv[1:])
    lib = f"ours:{lib_dir}"
    certs = None
    try:
        for transport in ("tcp", "tls", "rtu"):
            cases = TLS_CASES if transport == "tls" else CASE_TITLES
            for case in cases if COUNTS[transport] > 0 else []:
                if transport == "tls" and certs is None:
                    certs = tempfile.mkdtemp(prefix="rsmodbus-pgo-certs-")
                    subprocess.run(["bash", os.path.join(ROOT, "c-tests", "tls", "make-certs.sh"), certs],
                                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                train(bin_dir, lib, transport, case, COUNTS[transport], certs, tls_raw)
                print(f"pgo-train: {transport} {case}: {COUNTS[transport]} transactions")
    finally:
        if certs:
            shutil.rmtree(certs, ignore_errors=True)


if __name__ == "__main__":
    try:
        main()
    finally:
        harness.stop_all()
