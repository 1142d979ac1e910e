#!/usr/bin/env python3
"""rsmodbus benchmark runner (called by scripts/bench.sh; see benches/README.md).

Runs the same C client and server binaries with Debian's libmodbus.so.5 and with
rsmodbus (chosen by LD_LIBRARY_PATH), alternating within one run, and prints Markdown
tables: transactions/s and ratios for every case, transport and pairing, the bare
floor, and per-transaction system calls, user-space instructions and heap
allocations. It is a benchmark, not a test: it fails only if a program fails.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import platform
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "c-tests", "common"))
import harness  # noqa: E402
from harness import PtyPair, check_libinfo, start, stop, stop_all, wait_output, wait_ready  # noqa: E402

BUILD = os.path.join(ROOT, "target", "bench")
# scripts/bench.sh copies the library here so that a rebuild during the run cannot
# change (or truncate) the measured one.
OURS_DIR = os.environ.get("BENCH_OURS_DIR", os.path.join(ROOT, "target", "release"))
RESULTS = os.environ.get("BENCH_RESULTS", os.path.join(BUILD, "results.md"))  # the report's copy
QUICK = os.environ.get("BENCH_QUICK", "0") == "1"
CASES = os.environ.get("BENCH_CASES", "r125 c2000 w123 wr121 r1").split()
TRANSPORTS = os.environ.get("BENCH_TRANSPORTS", "tcp rtu").split()
ROUNDS = int(os.environ.get("BENCH_ROUNDS", "1" if QUICK else "5"))
SECONDS = float(os.environ.get("BENCH_SECONDS", "0.3" if QUICK else "1.5"))
METRIC_CASES = os.environ.get("BENCH_METRIC_CASES", "r125" if QUICK else " ".join(CASES)).split()
METRICS = os.environ.get("BENCH_METRICS", "strace callgrind allocs").split()
THROUGHPUT = os.environ.get("BENCH_THROUGHPUT", "1") == "1"
PIN = os.environ.get("BENCH_PIN", "")  # e.g. "1": every process of a measurement on that CPU set
# TCP: price the waiting floor's two waits one at a time (two more floors per case).
FLOOR_PARTS = os.environ.get("BENCH_FLOOR_PARTS", "0" if QUICK else "1") == "1"
if PIN:
    harness.COMMAND_PREFIX = ["taskset", "-c", PIN]
CASE_TITLES = {
    "r125": "read 125 registers",
    "c2000": "read 2000 coils",
    "w123": "write 123 registers",
    "wr121": "write 121 + read 125 (FC 23)",
    "r1": "read 1 register",
}

STALLS = []  # 32 consecutive transactions of a timed run taking over 50 ms


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def env_for(lib):
    e = harness.env_for(lib, OURS_DIR)
    e.pop("LD_PRELOAD", None)
    return e


def bin_(name):
    return os.path.join(BUILD, name)


def run_client(cmd, env, what, lib=None, timeout=120):
    p = start(cmd, env)
    done = wait_output(p, timeout)
    if done is None:
        raise RuntimeError(f"{what}: timed out")
    out, err = done
    if p.returncode != 0:
        raise RuntimeError(f"{what}: exit {p.returncode}: {err.strip()} {out.strip()}")
    if lib is not None:
        check_libinfo(out, lib, what)
    m = re.search(r"RESULT .*tps=([0-9.]+)", out)
    return float(m.group(1)) if m else None, out, err


def throughput(transport, case, server_lib, client_lib, seconds):
    """One alternating measurement: (transactions/s, CPU), or the floor when server_lib
    is None (client_lib "wait": the floor with the waits libmodbus's semantics need;
    "peek" or "timeout": with only one of them, on TCP).
    CPU is (user, system) seconds per transaction of all the measurement's processes
    (client, server, socat), from the rusage of children this process has reaped."""
    cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
    line = PtyPair("mbbench-", 2) if transport == "rtu" else None
    try:
        floor = server_lib is None
        if floor:
            fenv = dict(os.environ, FLOOR_WAIT={"wait": "1", "peek": "peek", "timeout": "timeout"}.get(client_lib, "0"))
            scmd = [bin_("bench-floor"), "server", "tcp" if transport == "tcp" else "pty",
                    "0" if transport == "tcp" else line.a]
            srv = start(scmd, fenv)
            addr = wait_ready(srv, "floor server", 30)
            ccmd = [bin_("bench-floor"), "client", "tcp" if transport == "tcp" else "pty",
                    addr if transport == "tcp" else line.b, case, str(seconds)]
            tps, out, _ = run_client(ccmd, fenv, "floor client")
        else:
            scmd = [bin_("mb-server"), transport, "0" if transport == "tcp" else line.a]
            srv = start(scmd, env_for(server_lib))
            addr = wait_ready(srv, "server", 30, server_lib)
            ccmd = [bin_("bench-client"), transport, addr if transport == "tcp" else line.b, case, "-t", str(seconds)]
            tps, out, _ = run_client(ccmd, env_for(client_lib), "client", client_lib)
            m = re.search(r"max_ms=([0-9.]+)", out)
            if m and float(m.group(1)) > 50:
                STALLS.append(f"{transport} {case} client={client_lib} server={server_lib}: "
                              f"slowest 32 transactions {float(m.group(1)):.0f} ms")
                log("STALL: " + STALLS[-1])
        stop(srv)
    finally:
        if line:
            line.close()
    cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
    tx = int(re.search(r"RESULT .*tx=([0-9]+)", out).group(1))
    return tps, ((cpu_after.ru_utime - cpu_before.ru_utime) / tx, (cpu_after.ru_stime - cpu_before.ru_stime) / tx)


DD, OD, DO, OO, FLOOR, WAIT = ("debian", "debian"), ("ours", "debian"), ("debian", "ours"), ("ours", "ours"), \
    (None, None), ("wait", None)
PEEK, TIMEOUT = ("peek", None), ("timeout", None)  # the bare floor plus one of the waiting floor's waits
PAIRING_NAMES = {DD: "Debian/Debian", OD: "ours/Debian", DO: "Debian/ours", OO: "ours/ours",
                 FLOOR: "bare floor", WAIT: "waiting floor", PEEK: "floor + peek", TIMEOUT: "floor + timeout"}


def tps_line(tps):
    """One line of tx/s per pairing (client/server, or a floor), for the log."""
    return ", ".join(f"{PAIRING_NAMES[c]}={v:.0f}" for c, v in tps.items())


class Run:
    """The throughput samples of one case: one per pairing per round. A ratio between
    two pairings is the median of its per-round values (the two ran seconds apart, at
    most, so a slow change of the machine's load cancels out), with the lowest and
    highest per-round values to show how far one round can stray."""

    def __init__(self, samples, cpu):
        self.samples = samples
        self.cpu = cpu

    def cpu_us(self, pairing):
        """Median user and system CPU microseconds per transaction (all processes)."""
        return tuple(statistics.median(c[i] for c in self.cpu[pairing]) * 1e6 for i in (0, 1))

    def tps(self, pairing):
        return statistics.median(self.samples[pairing])

    def per_round(self, a, b):
        return [x / y for x, y in zip(self.samples[a], self.samples[b])]

    def ratio(self, a, b):
        return statistics.median(self.per_round(a, b))

    def spread(self, a, b, percent=False):
        rs = self.per_round(a, b)
        if len(rs) < 2:
            return "-"
        if percent:
            return f"{min(rs):.0%}-{max(rs):.0%}"
        return f"{min(rs):.2f}-{max(rs):.2f}x"


# ---- per-transaction costs ------------------------------------------------------------

def tool_prefix(metric, out):
    if metric == "strace":
        return ["strace", "-f", "-c", "-U", "name,calls", "-o", out]
    if metric == "callgrind":
        return ["valgrind", "--tool=callgrind", "--callgrind-out-file=" + out, "--dump-instr=no", "--quiet"]
    return []


def parse_metric(metric, out):
    if metric == "strace":
        calls = {}
        with open(out) as f:
            for line in f:
                parts = line.split()
                if len(parts) == 2 and parts[1].isdigit():
                    calls[parts[0]] = int(parts[1])
        return calls
    if metric == "callgrind":
        return callgrind_costs(out)
    with open(out) as f:
        text = f.read()
    m = re.findall(r"allocs=(\d+)", text)
    return {"total": int(m[-1])} if m else {"total": 0}


def callgrind_costs(path):
    """Whole-process Ir and self Ir of the libmodbus object, from a callgrind file."""
    total = 0
    per_obj = {}
    names = {}
    obj = "?"
    skip_next = False
    with open(path) as f:
        for line in f:
            if line.startswith("summary:") or line.startswith("totals:"):
                total = int(line.split()[1])
                continue
            if line.startswith("ob="):
                v = line[3:].strip()
                m = re.match(r"\((\d+)\)(?:\s+(.*))?", v)
                if m:
                    if m.group(2):
                        names[m.group(1)] = m.group(2)
                    obj = names.get(m.group(1), "?")
                else:
                    obj = v
                continue
            if line.startswith("calls="):
                skip_next = True
                continue
            if line[:1].isdigit() or line[:1] in "+-*":
                if skip_next:
                    skip_next = False
                    continue
                parts = line.split()
                if len(parts) >= 2:
                    per_obj[obj] = per_obj.get(obj, 0) + int(parts[1])
                continue
            if line.startswith("cob="):
                # Names are compressed: an object may be named first in a cob= line.
                m = re.match(r"\((\d+)\)\s+(.*)", line[4:].strip())
                if m:
                    names[m.group(1)] = m.group(2)
                continue
            if line.startswith(("cfi=", "cfl=", "cfn=")):
                continue
    lib = sum(v for k, v in per_obj.items() if "libmodbus.so" in os.path.basename(k))
    return {"total": total, "lib": lib}


def cost_run(metric, side, transport, case, lib, n, warm=20):
    """Runs `side` (client or server) with `lib` under the metric's tool for n
    transactions against a Debian peer; returns the parsed counts."""
    tmp = tempfile.mkdtemp(prefix="mbcost-")
    out = os.path.join(tmp, "out")
    line = PtyPair("mbbench-", 2) if transport == "rtu" else None
    try:
        prefix = tool_prefix(metric, out)
        def measured_env():
            e = env_for(lib)
            if metric == "allocs":
                e["LD_PRELOAD"] = bin_("alloc-count.so")
                e["ALLOC_COUNT_OUT"] = out
            return e
        if side == "client":
            srv = start([bin_("mb-server"), transport, "0" if transport == "tcp" else line.a], env_for("debian"))
            addr = wait_ready(srv, "server", 30, "debian")
            ccmd = prefix + [bin_("bench-client"), transport, addr if transport == "tcp" else line.b, case,
                             "-n", str(n), "-w", str(warm)]
            run_client(ccmd, measured_env(), f"{metric} client", timeout=600)
            stop(srv)
        else:
            scmd = prefix + [bin_("mb-server"), transport, "0" if transport == "tcp" else line.a, str(n + warm)]
            srv = start(scmd, measured_env())
            addr = wait_ready(srv, f"{metric} server", 120)
            ccmd = [bin_("bench-client"), transport, addr if transport == "tcp" else line.b, case,
                    "-n", str(n), "-w", str(warm)]
            run_client(ccmd, env_for("debian"), "client", "debian", timeout=600)
            # It exits by itself after n + warm replies; its counts are written at exit.
            if wait_output(srv, 600) is None:
                raise RuntimeError(f"{metric} server: did not exit within 600 s of its last reply (stopped)")
        return parse_metric(metric, out)
    finally:
        if line:
            line.close()
        shutil.rmtree(tmp, ignore_errors=True)


METRIC_N = {"strace": 1000, "callgrind": 300, "allocs": 1000}


def per_tx(metric, side, transport, case, lib):
    n = METRIC_N[metric] // (2 if QUICK else 1)
    a = cost_run(metric, side, transport, case, lib, n)
    b = cost_run(metric, side, transport, case, lib, 2 * n)
    keys = set(a) | set(b)
    return {k: (b.get(k, 0) - a.get(k, 0)) / n for k in keys}


# ---- report ---------------------------------------------------------------------------

def command_output(cmd):
    """cmd's stdout, or "?" if it cannot run or takes over 30 s (subprocess.run kills it then)."""
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return "?"


def machine():
    cpu = "?"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    rustc = command_output(["rustc", "--version"]).strip()
    deb = command_output(["dpkg-query", "-W", "-f=${Version}", "libmodbus5"])
    load = open("/proc/loadavg").read().split()[:3]
    return (f"{os.cpu_count()} CPUs ({cpu}), Linux {platform.release()}, {rustc}, Debian libmodbus5 {deb}; "
            f"load average at start {' '.join(load)}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")


def fmt(x, digits=0):
    if x is None:
        return "-"
    return f"{x:,.{digits}f}"


# The performance targets: TCP ours/ours at least 1.5x Debian/Debian and 85% of the bare
# floor; RTU at least 1.2x; at most 3 system calls per side on TCP; fewer user-space
# instructions than libmodbus; no allocation per transaction.
TCP_RATIO, FLOOR_SHARE, RTU_RATIO, TCP_SYSCALLS = 1.5, 0.85, 1.2, 3


def throughput_verdict(target, ours, waiting, bare, share_of_waiting):
    """A throughput target (ratios to Debian/Debian): met, out of reach (the floor
    itself is below it: the measured proof), or not met. Ratios get three decimals, so
    that a miss by less than 0.005 does not print as the target itself."""
    if ours >= target:
        return "met", f"{ours:.3f}x"
    if waiting < target:
        return "out of reach", (f"the waiting floor itself is {waiting:.3f}x (bare floor {bare:.3f}x); "
                                f"ours {ours:.3f}x, {share_of_waiting:.0%} of it")
    if bare < target:
        return "out of reach", f"the bare floor itself is {bare:.3f}x; ours {ours:.3f}x"
    return "NOT MET", f"ours {ours:.3f}x, waiting floor {waiting:.3f}x, ours {share_of_waiting:.0%} of it"


def verdicts(results, costs):
    """Each target against this run's measurements, and a closing count."""
    rows = []
    for (transport, case), run in results.items():
        title = f"{transport.upper()} {CASE_TITLES[case]}"
        target = TCP_RATIO if transport == "tcp" else RTU_RATIO
        verdict, measured = throughput_verdict(target, run.ratio(OO, DD), run.ratio(WAIT, DD), run.ratio(FLOOR, DD),
                                               run.ratio(OO, WAIT))
        rows.append((f"{title}: >= {target}x Debian", verdict,
                     f"{measured}; per round: ours {run.spread(OO, DD)}, waiting floor {run.spread(WAIT, DD)}"))
        if transport == "tcp":
            share, waiting_share = run.ratio(OO, FLOOR), run.ratio(WAIT, FLOOR)
            if share >= FLOOR_SHARE:
                rows.append((f"{title}: >= {FLOOR_SHARE:.0%} of the bare floor", "met", f"{share:.0%}"))
            elif waiting_share < FLOOR_SHARE:
                rows.append((f"{title}: >= {FLOOR_SHARE:.0%} of the bare floor", "out of reach",
                             f"the waiting floor itself is {waiting_share:.0%} of it; ours {share:.0%}"))
            else:
                rows.append((f"{title}: >= {FLOOR_SHARE:.0%} of the bare floor", "NOT MET",
                             f"{share:.0%} (waiting floor {waiting_share:.0%})"))
    for (metric, transport, case, side), (theirs, ours) in costs.items():
        title = f"{transport.upper()} {CASE_TITLES[case]}, {side}"
        if metric == "syscalls" and transport == "tcp":
            rows.append((f"{title}: <= {TCP_SYSCALLS} system calls", "met" if ours <= TCP_SYSCALLS else "NOT MET",
                         f"{ours:.1f} (Debian {theirs:.1f})"))
        elif metric == "Ir":
            rows.append((f"{title}: fewer instructions than Debian", "met" if ours < theirs else "NOT MET",
                         f"{ours:,.0f} vs {theirs:,.0f}"))
        elif metric == "allocs":
            rows.append((f"{title}: no allocation per transaction", "met" if ours < 0.005 else "NOT MET",
                         f"{ours:.2f}"))
    if not rows:
        return []
    out = ["\n### Against the targets\n",
           "\"Out of reach\" is the measured proof that a target cannot be met on this machine by a library "
           "keeping libmodbus's semantics: the floor of the same run (see above) is below it.\n",
           "| target | verdict | measured |", "|---|---|---|"]
    out.extend(f"| {t} | {v} | {m} |" for t, v, m in rows)
    missed = sum(v == "NOT MET" for _, v, _ in rows)
    reach = sum(v == "out of reach" for _, v, _ in rows)
    out.append(f"\n{len(rows) - missed - reach} met, {reach} out of reach, {missed} not met.")
    return out


def main():
    if not os.path.exists(os.path.join(OURS_DIR, "libmodbus.so.5")):
        raise SystemExit(f"{OURS_DIR}/libmodbus.so.5 missing: run scripts/bench.sh")
    started = time.time()
    lines = []
    mode = "quick" if QUICK else "full"
    lines.append(f"## rsmodbus vs libmodbus: benchmark ({mode} mode)\n")
    lines.append(f"Machine: {machine()}.  ")
    if PIN:
        lines.append(f"All processes pinned to CPU(s) {PIN} (taskset).  ")
    lines.append(f"Method: each tx/s figure is the median of {ROUNDS} alternating run(s) of {SECONDS} s per pairing "
                 f"(order rotated every round); client and server are the same binaries, only "
                 f"LD_LIBRARY_PATH differs. RTU runs over a socat pty pair. A ratio is the median of its per-round "
                 f"ratios (the pairings of a round run seconds apart); in brackets, the lowest and "
                 f"highest per-round value.\n")

    results = {}
    for transport in TRANSPORTS if THROUGHPUT else []:
        combos = [DD, OD, DO, OO, FLOOR, WAIT] + ([PEEK, TIMEOUT] if transport == "tcp" and FLOOR_PARTS else [])
        for case in CASES:
            samples = {c: [] for c in combos}
            cpu = {c: [] for c in combos}
            for r in range(ROUNDS):
                order = combos[r % len(combos):] + combos[:r % len(combos)]
                for c in order:
                    client_lib, server_lib = c
                    tps, used = throughput(transport, case, server_lib, client_lib, SECONDS)
                    samples[c].append(tps)
                    cpu[c].append(used)
                log(f"  round {r + 1}: " + tps_line({c: samples[c][-1] for c in combos}))
            results[(transport, case)] = Run(samples, cpu)
            log(f"{transport} {case} (medians): " + tps_line({c: results[(transport, case)].tps(c) for c in combos}))

    if results:
        lines.append("### Transactions per second\n")
        lines.append("Pairings are client/server. \"client\" = our client against Debian's server; "
                     "\"server\" = Debian's client against our server; \"both\" = ours against ours.\n")
        lines.append("\"Waiting floor\": the bare floor plus the waits libmodbus's semantics need (TCP: the server "
                     "peeks before its exact read, the client's read waits by itself; pty: both sides poll with a "
                     "timeout before reading); its ratio to Debian/Debian is the most a library keeping those "
                     "semantics could reach.\n")
        lines.append("| transport | case | Debian/Debian tx/s | ours/ours tx/s | both ratio (per round) | "
                     "client ratio | server ratio | bare floor tx/s | ours/floor | Debian/floor | waiting floor tx/s | "
                     "waiting floor/Debian | ours/waiting floor (per round) |")
        lines.append("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        for (transport, case), run in results.items():
            lines.append(f"| {transport.upper()} | {CASE_TITLES[case]} | {fmt(run.tps(DD))} | {fmt(run.tps(OO))} | "
                         f"{run.ratio(OO, DD):.2f}x ({run.spread(OO, DD)}) | {run.ratio(OD, DD):.2f}x | "
                         f"{run.ratio(DO, DD):.2f}x | {fmt(run.tps(FLOOR))} | {run.ratio(OO, FLOOR):.0%} | "
                         f"{run.ratio(DD, FLOOR):.0%} | {fmt(run.tps(WAIT))} | {run.ratio(WAIT, DD):.2f}x | "
                         f"{run.ratio(OO, WAIT):.0%} ({run.spread(OO, WAIT, percent=True)}) |")
        priced = [(k, run) for k, run in results.items() if PEEK in run.samples]
        if priced:
            lines.append("\n### What each wait costs (TCP)\n")
            lines.append("The bare floor with only the server's peek before its exact read, with only the "
                         "client's `SO_RCVTIMEO`, and with both (the waiting floor); each as a share of the bare "
                         "floor (median of the per-round ratios, lowest and highest in brackets).\n")
            lines.append("| case | bare floor tx/s | + server peek | + client timeout | both: waiting floor |")
            lines.append("|---|---:|---:|---:|---:|")
            for (transport, case), run in priced:
                lines.append(f"| {CASE_TITLES[case]} | {fmt(run.tps(FLOOR))} | "
                             + " | ".join(f"{run.ratio(c, FLOOR):.1%} ({run.spread(c, FLOOR, percent=True)})"
                                          for c in (PEEK, TIMEOUT, WAIT)) + " |")
        lines.append("\n### CPU time per transaction\n")
        lines.append("User and system CPU time of all the processes of a measurement (client, server, and socat "
                     "on RTU), from the rusage of the reaped processes, divided by its transactions; medians over "
                     "the rounds. Start-up is included (a few ms per run), and a kernel that accounts CPU time by "
                     "sampling at its tick (CONFIG_TICK_CPU_ACCOUNTING, the usual) makes each figure rough. Where "
                     "ours/ours and the waiting floor make the same system calls, the difference in user time is the "
                     "library's own work.\n")
        lines.append("| transport | case | Debian/Debian user | ours/ours user | waiting floor user | bare floor user "
                     "| Debian/Debian system | ours/ours system | waiting floor system | bare floor system |")
        lines.append("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        for (transport, case), run in results.items():
            used = [run.cpu_us(c) for c in (DD, OO, WAIT, FLOOR)]
            lines.append(f"| {transport.upper()} | {CASE_TITLES[case]} | "
                         + " | ".join(f"{u[0]:.2f} µs" for u in used) + " | "
                         + " | ".join(f"{u[1]:.2f} µs" for u in used) + " |")

    costs = {}
    if STALLS:
        lines.append("\nStalls (32 consecutive transactions taking over 50 ms):\n")
        lines.extend(f"- {s}" for s in STALLS)
    if METRICS:
        lines.append("\n### Cost per transaction (steady state)\n")
        lines.append("Each side is measured against a Debian peer, for N and 2N transactions after the same "
                     "warm-up; the figure is (count(2N) - count(N)) / N, so start-up and teardown cancel out. "
                     "System calls: `strace -f -c` of the measured process. Instructions: `valgrind "
                     "--tool=callgrind`, total Ir of the whole process (program + libmodbus + libc), with the "
                     "libmodbus.so object's own share in brackets. Allocations: an LD_PRELOAD counter of "
                     "malloc/calloc/realloc/memalign calls.\n")
        header = "| transport | case | side |"
        sep = "|---|---|---|"
        if "strace" in METRICS:
            header += " syscalls/tx Debian | syscalls/tx ours | ours: calls |"
            sep += "---:|---:|---|"
        if "callgrind" in METRICS:
            header += " Ir/tx Debian | Ir/tx ours |"
            sep += "---:|---:|"
        if "allocs" in METRICS:
            header += " allocs/tx Debian | allocs/tx ours |"
            sep += "---:|---:|"
        lines.append(header)
        lines.append(sep)
        for transport in TRANSPORTS:
            for case in METRIC_CASES:
                for side in ("client", "server"):
                    row = f"| {transport.upper()} | {CASE_TITLES[case]} | {side} |"
                    if "strace" in METRICS:
                        d = per_tx("strace", side, transport, case, "debian")
                        o = per_tx("strace", side, transport, case, "ours")
                        dt = sum(d.values()) - d.get("total", 0)
                        ot = sum(o.values()) - o.get("total", 0)
                        detail = ", ".join(f"{k} {v:.1f}" for k, v in sorted(o.items(), key=lambda kv: -kv[1])
                                           if k != "total" and v >= 0.05)
                        dd_detail = ", ".join(f"{k} {v:.1f}" for k, v in sorted(d.items(), key=lambda kv: -kv[1])
                                              if k != "total" and v >= 0.05)
                        log(f"syscalls {transport} {case} {side}: debian {dd_detail} | ours {detail}")
                        row += f" {dt:.1f} | {ot:.1f} | {detail} |"
                        costs[("syscalls", transport, case, side)] = (dt, ot)
                    if "callgrind" in METRICS:
                        d = per_tx("callgrind", side, transport, case, "debian")
                        o = per_tx("callgrind", side, transport, case, "ours")
                        row += f" {fmt(d['total'])} ({fmt(d['lib'])}) | {fmt(o['total'])} ({fmt(o['lib'])}) |"
                        costs[("Ir", transport, case, side)] = (d["total"], o["total"])
                    if "allocs" in METRICS:
                        d = per_tx("allocs", side, transport, case, "debian")
                        o = per_tx("allocs", side, transport, case, "ours")
                        row += f" {d['total']:.2f} | {o['total']:.2f} |"
                        costs[("allocs", transport, case, side)] = (d["total"], o["total"])
                    lines.append(row)
                    log(row)
    lines.extend(verdicts(results, costs))
    lines.append(f"\n({time.time() - started:.0f} s; `scripts/bench.sh`{' with BENCH_QUICK=1' if QUICK else ''})")
    text = "\n".join(lines) + "\n"
    os.makedirs(BUILD, exist_ok=True)
    with open(RESULTS, "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    try:
        main()
    finally:
        stop_all()
