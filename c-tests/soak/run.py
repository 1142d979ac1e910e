#!/usr/bin/env python3
"""Soak and memcheck tests of rsmodbus (called by c-tests/suites/soak.sh).

1. Soak: SOAK_TX verified transactions (default 20,000; 1,000,000 with SOAK_FULL=1),
   our client against our server, over TCP loopback and over a socat pty pair (RTU).
   Resident memory (VmRSS) and open descriptors (/proc/PID/fd) of both processes are
   sampled while it runs: descriptors must not change, and resident memory must stay
   flat after warm-up (growth from the 20% mark to the end at most SOAK_RSS_SLACK_KB).
2. valgrind memcheck (--leak-check=full --errors-for-leak-kinds=definite
   --error-exitcode=99) of our client and of our server over TCP and RTU
   (MEMCHECK_TX transactions), and of context/mapping life cycles with failed connects.
3. The life cycles with the descriptor count checked, Debian's libmodbus and ours.
Ends with "N passed, M failed".

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import re
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "common"))
import harness  # noqa: E402
from harness import ROOT, PtyPair, env_for, procs, start, stop, stop_all, summary, wait_output, wait_ready  # noqa: E402

harness.STOP_GRACE = 10  # seconds from SIGTERM to SIGKILL (the shared default is 5)
# The programs: c-tests/Makefile (target/c-tests-build/bin, or $CTEST_BUILD/bin).
BUILD = os.path.join(os.environ.get("CTEST_BUILD", os.path.join(ROOT, "target", "c-tests-build")), "bin")
FULL = os.environ.get("SOAK_FULL", "0") == "1"
SOAK_TX = int(os.environ.get("SOAK_TX", "1000000" if FULL else "20000"))
MEMCHECK_TX = int(os.environ.get("MEMCHECK_TX", "2000"))
RSS_SLACK_KB = int(os.environ.get("SOAK_RSS_SLACK_KB", "64"))
VALGRIND = ["valgrind", "--leak-check=full", "--errors-for-leak-kinds=definite", "--show-leak-kinds=definite",
            "--error-exitcode=99", "--quiet"]

results = []


def report(name, ok, detail):
    results.append(ok)
    print(f"{'PASS' if ok else 'FAIL'} {name}: {detail}", flush=True)


def sample(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            rss = int(re.search(r"VmRSS:\s+(\d+)", f.read()).group(1))
        fds = len(os.listdir(f"/proc/{pid}/fd"))
        return rss, fds
    except (OSError, AttributeError):
        return None


def requests_for(count):
    """Requests soak-client sends for `count` iterations (kinds 1 and 3 send two)."""
    return sum(2 if i % 7 in (1, 3) else 1 for i in range(count))


def run_case(name, transport, body, *args):
    """Runs body(name, transport, line, *args), line a pty pair for RTU (None for TCP). A
    RuntimeError (no READY, no pty pair) fails this case only, and what the case started
    and did not collect is stopped when it ends, so that nothing outlives it."""
    before = list(procs)
    line = None
    try:
        line = PtyPair("mbsoak-", 3) if transport == "rtu" else None
        body(name, transport, line, *args)
    except RuntimeError as e:
        report(name, False, str(e))
    finally:
        for p in [p for p in procs if p not in before]:
            stop(p)
        if line:
            line.close()


def soak(name, transport, line):
    srv = start([os.path.join(BUILD, "mb-server"), transport, "0" if transport == "tcp" else line.a],
                env_for("ours"))
    addr = wait_ready(srv, "server", 60)
    cli = start([os.path.join(BUILD, "soak-client"), transport, addr if transport == "tcp" else line.b,
                 str(SOAK_TX)], env_for("ours"))
    samples = []  # (progress, client rss, client fds, server rss, server fds)
    progress = 0
    t0 = time.time()
    # Both pipes are drained while the client runs: a client that fills one (64 kB of
    # error messages) must not block on it until the 3600 s limit.
    os.set_blocking(cli.stdout.fileno(), False)
    os.set_blocking(cli.stderr.fileno(), False)
    buf, err = "", ""
    while cli.poll() is None:
        try:
            err += cli.stderr.read() or ""
        except (BlockingIOError, TypeError):
            pass
        try:
            chunk = cli.stdout.read()
        except (BlockingIOError, TypeError):
            chunk = None
        if chunk:
            buf += chunk
            m = re.findall(r"PROGRESS (\d+)", buf)
            if m:
                progress = int(m[-1])
        c, s = sample(cli.pid), sample(srv.pid)
        if c and s:
            samples.append((progress, c[0], c[1], s[0], s[1]))
        time.sleep(0.1)
        if time.time() - t0 > 3600:
            stop(cli)
            report(name, False, f"client did not finish in 3600 s (stopped at {progress} transactions)")
            return
    rest = cli.stdout.read() or ""
    out = buf + rest
    err += cli.stderr.read() or ""
    elapsed = time.time() - t0
    stop(srv)
    if cli.returncode != 0 or "DONE" not in out:
        report(name, False, f"client exit {cli.returncode}: {err.strip()[:300]}")
        return
    samples = [x for x in samples if x[0] > 0] or samples
    if len(samples) < 2:
        report(name, False, "too few samples")
        return
    warm = [x for x in samples if x[0] >= SOAK_TX * 0.2] or samples[-1:]
    base = warm[0]
    end = samples[-1]
    c_growth = max(x[1] for x in warm) - base[1]
    s_growth = max(x[3] for x in warm) - base[3]
    fds_c = {x[2] for x in samples}
    fds_s = {x[4] for x in samples}
    ok = c_growth <= RSS_SLACK_KB and s_growth <= RSS_SLACK_KB and len(fds_c) == 1 and len(fds_s) == 1
    report(name, ok,
           f"{SOAK_TX / elapsed:,.0f} tx/s, {len(samples)} samples; client VmRSS {samples[0][1]} -> "
           f"{base[1]} (20%) -> {end[1]} kB (growth after warm-up {c_growth} kB), fds {sorted(fds_c)}; "
           f"server VmRSS {samples[0][3]} -> {base[3]} -> {end[3]} kB (growth {s_growth} kB), "
           f"fds {sorted(fds_s)}")


def memcheck_pair(name, transport, line, side):
    """Our client or server under memcheck, the peer ours without valgrind."""
    senv = env_for("ours")
    sprefix = VALGRIND if side == "server" else []
    cprefix = VALGRIND if side == "client" else []
    if transport == "tcp":
        senv["MB_EXIT_ON_CLOSE"] = "1"
        scmd = sprefix + [os.path.join(BUILD, "mb-server"), "tcp", "0"]
    else:
        scmd = sprefix + [os.path.join(BUILD, "mb-server"), "rtu", line.a, str(requests_for(MEMCHECK_TX))]
    srv = start(scmd, senv)
    addr = wait_ready(srv, "server", 120)
    cli = start(cprefix + [os.path.join(BUILD, "soak-client"), transport, addr if transport == "tcp" else line.b,
                           str(MEMCHECK_TX)], env_for("ours"))
    done = wait_output(cli, 900)
    if done is None:
        report(name, False, "client timed out")
        return
    cout, cerr = done
    done = wait_output(srv, 120)
    if done is None:
        report(name, False, "server did not exit")
        return
    sout, serr = done
    measured = (cli.returncode, cerr) if side == "client" else (srv.returncode, serr)
    ok = cli.returncode == 0 and srv.returncode == 0 and "DONE" in cout
    detail = f"client exit {cli.returncode}, server exit {srv.returncode}"
    if not ok:
        detail += ": " + measured[1].strip()[-1500:]
    report(name, ok, detail + (" (valgrind: no errors, no definite leaks)" if ok else ""))


def lifecycle(lib, under_valgrind, cycles):
    name = f"lifecycle {cycles} cycles ({lib}{', memcheck' if under_valgrind else ''})"
    cmd = (VALGRIND if under_valgrind else []) + [os.path.join(BUILD, "lifecycle"), str(cycles)]
    p = start(cmd, env_for(lib))
    done = wait_output(p, 600)
    if done is None:
        report(name, False, "timed out after 600 s (stopped)")
        return
    out, err = done
    m = re.search(r"FDS before=(\d+) after=(\d+)", out)
    ok = p.returncode == 0 and m is not None and m.group(1) == m.group(2)
    report(name, ok, (m.group(0) if m else "no FDS line") + ("" if ok else f"; exit {p.returncode}: {err.strip()[-1500:]}"))


def main():
    for transport in ("tcp", "rtu"):
        run_case(f"soak {transport.upper()} {SOAK_TX} transactions (ours/ours)", transport, soak)
    for transport in ("tcp", "rtu"):
        for side in ("client", "server"):
            run_case(f"memcheck {side} {transport.upper()} {MEMCHECK_TX} transactions", transport, memcheck_pair,
                     side)
    lifecycle("ours", True, 30)
    lifecycle("ours", False, 300)
    lifecycle("debian", False, 300)
    passed = sum(results)
    summary(passed, len(results) - passed)
    return 0 if passed == len(results) else 1


if __name__ == "__main__":
    code = 1
    try:
        code = main()
    finally:
        stop_all()
    sys.exit(code)
