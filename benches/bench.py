#!/usr/bin/env python3
"""rsmodbus benchmark runner (called by scripts/bench.sh; see benches/README.md).

Runs the same C client and server binaries with Debian's libmodbus.so.5 and with
rsmodbus (chosen by LD_LIBRARY_PATH), taking turns within one run (interleaved()),
and prints Markdown tables: transactions/s and ratios for every case, transport and
pairing, the bare floor, and per-transaction system calls, user-space instructions
and heap allocations. It is a benchmark, not a test: it fails only if a program fails.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import math
import mmap
import os
import platform
import random
import re
import shutil
import signal
import socket
import statistics
import struct
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
TRANSPORTS = os.environ.get("BENCH_TRANSPORTS", "tcp rtu tls").split()
# Modbus/TCP Security (transport "tls", ours only: Debian's libmodbus has no TLS):
# these cases against plain TCP of the same library, then new connections per second.
TLS_CASES = os.environ.get("BENCH_TLS_CASES", "r125" if QUICK else "r125 r1").split()
# Every pairing of a case runs SECONDS in all, in slices of SLICE seconds taking turns
# with the others (see interleaved()).
SECONDS = float(os.environ.get("BENCH_SECONDS", "0.6" if QUICK else "10"))
SLICE = float(os.environ.get("BENCH_SLICE", "0.1"))
METRIC_CASES = os.environ.get("BENCH_METRIC_CASES", "r125" if QUICK else " ".join(CASES)).split()
METRICS = os.environ.get("BENCH_METRICS", "strace callgrind allocs").split()
# The costs per TLS transaction measured (default: those of BENCH_METRICS).
TLS_METRICS = os.environ.get("BENCH_TLS_METRICS", " ".join(METRICS)).split()
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
    "conn": "new connection + read 1 register",
}

STALLS = []  # per case, the slices of each pairing at under half its median rate


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def env_for(lib):
    e = harness.env_for(lib, OURS_DIR)
    e.pop("LD_PRELOAD", None)
    return e


def bin_(name):
    return os.path.join(BUILD, name)


def reap_client(p, what, lib=None, timeout=120):
    """Waits for client p to exit; raises unless it exited 0 (and, with lib, loaded
    that library). Returns (stdout, stderr)."""
    done = wait_output(p, timeout)
    if done is None:
        raise RuntimeError(f"{what}: timed out")
    out, err = done
    if p.returncode != 0:
        raise RuntimeError(f"{what}: exit {p.returncode}: {err.strip()} {out.strip()}")
    if lib is not None:
        check_libinfo(out, lib, what)
    return out, err


def run_client(cmd, env, what, lib=None, timeout=120):
    return reap_client(start(cmd, env), what, lib, timeout)


DD, OD, DO, OO, FLOOR, WAIT = ("debian", "debian"), ("ours", "debian"), ("debian", "ours"), ("ours", "ours"), \
    (None, None), ("wait", None)
PEEK, TIMEOUT = ("peek", None), ("timeout", None)  # the bare floor plus one of the waiting floor's waits
DATA = ("data", None)  # the waiting floor plus the conversions of the values (FLOOR_DATA=1)
# Modbus/TCP Security, ours/ours: over TLS; and with a full handshake per new connection
# (bench-client's case conn-full instead of conn, whose handshakes resume).
TLS, TLS_FULL = ("tls", "ours"), ("tls-full", "ours")
# What users deploy for Modbus/TCP Security today: Debian's libmodbus server behind stunnel
# (Debian's stunnel4: TLS 1.3, the same certificates, the client's verified), our TLS client.
STUNNEL = ("ours", "stunnel")
PAIRING_NAMES = {DD: "Debian/Debian", OD: "ours/Debian", DO: "Debian/ours", OO: "ours/ours",
                 FLOOR: "bare floor", WAIT: "waiting floor", PEEK: "floor + peek", TIMEOUT: "floor + timeout",
                 DATA: "data floor", TLS: "TLS ours/ours", TLS_FULL: "TLS ours/ours, full handshakes",
                 STUNNEL: "TLS ours -> stunnel -> Debian"}
TLS_CERTS = None  # the directory of c-tests/tls/make-certs.sh's certificates, once made


def tls_certs():
    """The test certificates, made anew once per run with openssl (in target/bench/tls-certs)."""
    global TLS_CERTS
    if TLS_CERTS is None:
        d = os.path.join(BUILD, "tls-certs")
        shutil.rmtree(d, ignore_errors=True)
        subprocess.run(["bash", os.path.join(ROOT, "c-tests", "tls", "make-certs.sh"), d], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        TLS_CERTS = d
    return TLS_CERTS


def with_certs(env, d, side):
    """env plus the certificates in `d` (make-certs.sh's) of `side` ("client": role
    Operator; "server")."""
    name = "operator" if side == "client" else "server"
    return dict(env, MB_TLS_CA=os.path.join(d, "ca.pem"), MB_TLS_CERT=os.path.join(d, f"{name}.pem"),
                MB_TLS_KEY=os.path.join(d, f"{name}.key"))


def with_tls(env, transport, side):
    """env plus the certificates of `side` on TLS (this run's: tls_certs)."""
    return with_certs(env, tls_certs(), side) if transport == "tls" else env


def tps_line(tps):
    """One line of tx/s per pairing (client/server, or a floor), for the log."""
    return ", ".join(f"{PAIRING_NAMES[c]}={v:.0f}" for c, v in tps.items())


def cpu_ns(pid):
    """Nanoseconds pid has spent on a CPU (user and system: /proc/PID/task/*/schedstat, its
    threads that run: stunnel serves a connection in a thread of its own)."""
    total = 0
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/schedstat") as f:
                total += int(f.read().split()[0])
        except OSError:
            pass  # a thread that ended meanwhile
    return total


def start_stunnel(pairing, port):
    """stunnel (foreground) accepting TLS 1.3 on a free port with the server's certificate,
    requiring a client certificate of the CA, forwarding to 127.0.0.1:port; returns its port."""
    d = tls_certs()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        front = s.getsockname()[1]
    conf = os.path.join(BUILD, f"stunnel-{front}.conf")
    with open(conf, "w") as f:
        f.write(f"foreground = yes\npid =\nsyslog = no\ndebug = 3\n[modbus]\naccept = 127.0.0.1:{front}\n"
                f"connect = 127.0.0.1:{port}\ncert = {d}/server.pem\nkey = {d}/server.key\n"
                f"CAfile = {d}/ca.pem\nverifyChain = yes\nrequireCert = yes\nsslVersionMin = TLSv1.3\n"
                f"socket = r:TCP_NODELAY=1\nsocket = l:TCP_NODELAY=1\n")
    pairing.stunnel = start(["stunnel", conf], os.environ.copy())
    deadline = time.monotonic() + 30
    while True:
        try:
            socket.create_connection(("127.0.0.1", front), timeout=1).close()
            return str(front)
        except OSError:
            if pairing.stunnel.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"stunnel did not start: {pairing.stunnel.stderr.read().strip()!r:.300}")
            time.sleep(0.05)


class Pairing:
    """One pairing (client/server libraries, or a floor) of an interleaved measurement:
    a server and a client that runs until told to stop, paused (SIGSTOP) except during
    its slices. The client publishes its transaction count in a shared file
    (benches/bench-counter.h)."""

    def __init__(self, transport, case, combo, counter_path, limit_s):
        """limit_s: the wall-clock seconds after which the client ends by itself (paused
        time included), should the runner die without telling it to stop."""
        self.name = PAIRING_NAMES[combo]
        self.srv = self.client = self.line = self.counter = self.stunnel = None
        try:
            self._start(transport, case, combo, counter_path, limit_s)
        except BaseException:
            self.close()
            raise

    def _start(self, transport, case, combo, counter_path, limit_s):
        client_lib, server_lib = combo
        if combo in (TLS, TLS_FULL):
            transport, client_lib = "tls", server_lib
            case = "conn-full" if combo == TLS_FULL else case
        self.client_lib = client_lib
        self.line = PtyPair("mbbench-", 2) if transport == "rtu" else None
        with open(counter_path, "wb") as f:
            f.write(bytes(16))
        fd = os.open(counter_path, os.O_RDWR)
        try:
            self.counter = mmap.mmap(fd, 16)
        finally:
            os.close(fd)
        net = transport != "rtu"
        where = "0" if net else self.line.a
        if server_lib is None:
            # A floor: client_lib None is the bare one, else the waits it makes.
            env = dict(os.environ,
                       FLOOR_WAIT={"wait": "1", "peek": "peek", "timeout": "timeout", "data": "1"}.get(client_lib, "0"),
                       FLOOR_DATA="1" if client_lib == "data" else "0", BENCH_COUNTER=counter_path)
            self.srv = start([bin_("bench-floor"), "server", "tcp" if transport == "tcp" else "pty", where], env)
            addr = wait_ready(self.srv, "floor server", 30)
            self.client_lib = None
            ccmd = [bin_("bench-floor"), "client", "tcp" if transport == "tcp" else "pty",
                    addr if transport == "tcp" else self.line.b, case, str(limit_s)]
        elif combo == STUNNEL:
            self.srv = start([bin_("mb-server"), "tcp", "0"], env_for("debian"))
            addr = start_stunnel(self, wait_ready(self.srv, "server", 30, "debian"))
            env = dict(with_tls(env_for(client_lib), "tls", "client"), BENCH_COUNTER=counter_path)
            ccmd = [bin_("bench-client"), "tls", addr, case, "-t", str(limit_s)]
        else:
            self.srv = start([bin_("mb-server"), transport, where], with_tls(env_for(server_lib), transport, "server"))
            addr = wait_ready(self.srv, "server", 30, server_lib)
            env = dict(with_tls(env_for(client_lib), transport, "client"), BENCH_COUNTER=counter_path)
            ccmd = [bin_("bench-client"), transport, addr if net else self.line.b, case, "-t", str(limit_s)]
        self.client = start(ccmd, env)
        # Running once its count moves: connected, warmed up, in its timed loop.
        deadline = time.monotonic() + 60
        while self.count() == 0:
            if self.client.poll() is not None or time.monotonic() > deadline:
                stop(self.client)  # before reading its stderr to the end
                raise RuntimeError(f"{self.name} client: did not start ({self.client.stderr.read().strip()!r:.300})")
            time.sleep(0.01)
        self.pause()
        self.procs = [p.pid for p in (self.client, self.srv, self.line.p if self.line else self.stunnel) if p]
        self.base_count, self.base_cpu = self.count(), self.cpu()

    def count(self):
        return struct.unpack_from("=Q", self.counter, 0)[0]

    def cpu(self):
        """CPU nanoseconds of the client, the server, and socat on a pty (stunnel in front of a server)."""
        return [cpu_ns(pid) for pid in self.procs]

    def pause(self):
        os.kill(self.client.pid, signal.SIGSTOP)
        _, status = os.waitpid(self.client.pid, os.WUNTRACED)
        if not os.WIFSTOPPED(status):
            self.client.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
            raise RuntimeError(f"{self.name} client: exit {self.client.returncode}: "
                               f"{self.client.stderr.read().strip()!r:.300}")

    def resume(self):
        os.kill(self.client.pid, signal.SIGCONT)

    def cpu_per_tx(self):
        """Microseconds of CPU per transaction since the first pause: client, server, socat."""
        tx = max(1, self.count() - self.base_count)
        return [(b - a) / tx / 1e3 for a, b in zip(self.base_cpu, self.cpu())]

    def finish(self):
        """Ends the client's run, checks it exited well and loaded the right library."""
        struct.pack_into("=Q", self.counter, 8, 1)
        self.resume()
        reap_client(self.client, f"{self.name} client", self.client_lib, 60)

    def close(self):
        """Stops whatever still runs (also after an error) and releases the line and the counter."""
        if self.client is not None and self.client.returncode is None:
            try:
                os.kill(self.client.pid, signal.SIGCONT)  # a stopped process would hold SIGTERM back
            except ProcessLookupError:
                pass
            stop(self.client)
        if self.srv is not None:
            stop(self.srv)
        if self.stunnel is not None:
            stop(self.stunnel)
        if self.line:
            self.line.close()
        if self.counter is not None:
            self.counter.close()


def interleaved(transport, case, combos, seconds, slice_s):
    """Throughput of every pairing of combos, which take turns: in each cycle every
    pairing's client runs for one slice of slice_s seconds while the others are paused
    (in a new random order every cycle), for seconds per pairing in all. One sample per
    pairing per cycle (transactions of the slice / its length): pairings compared within
    a cycle ran a fraction of a second apart, so changes of the machine's load cancel out
    of their ratio. CPU time per transaction comes from the processes' schedstat."""
    # The counters in memory (tmpfs): a page of a disk file could be write-protected
    # for writeback, and the client's next store would fault.
    tmp = tempfile.mkdtemp(prefix="mbinter-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
    pairings = {}
    runner_cpus = os.sched_getaffinity(0)
    cycles = max(1, round(seconds / slice_s))
    # A client ends by itself long after the measurement should have (a dead runner
    # must not leave it running); the runner ends it before then.
    limit_s = 60 + 2 * seconds * len(combos)
    order = random.Random(f"{transport} {case}")  # the same orders in every run
    try:
        pinned = cpu_list(PIN)
        if pinned and runner_cpus - pinned:
            os.sched_setaffinity(0, runner_cpus - pinned)  # the runner keeps off the measured CPUs
        elif pinned:
            log(f"the runner shares CPU(s) {PIN} with the measurement (no other CPU allowed)")
        for k, c in enumerate(combos):
            pairings[c] = Pairing(transport, case, c, os.path.join(tmp, f"counter{k}"), limit_s)
        samples = {c: [] for c in combos}
        for k in range(cycles):
            # A new random order every cycle: no pairing always follows the same one
            # (the one before leaves its code and data in the caches).
            for c in order.sample(combos, len(combos)):
                p = pairings[c]
                before, t0 = p.count(), time.monotonic()
                p.resume()
                time.sleep(slice_s)
                p.pause()
                samples[c].append((p.count() - before) / (time.monotonic() - t0))
            if k % 20 == 19:
                log(f"  cycle {k + 1}: " + tps_line({c: samples[c][-1] for c in combos}))
        cpu = {c: pairings[c].cpu_per_tx() for c in combos}
        for c in combos:
            pairings[c].finish()
    finally:
        for p in pairings.values():
            p.close()
        shutil.rmtree(tmp, ignore_errors=True)
        os.sched_setaffinity(0, runner_cpus)
    medians = {c: statistics.median(rates) for c, rates in samples.items()}
    slow = {c: sum(r < medians[c] / 2 for r in rates) for c, rates in samples.items()}
    if any(slow.values()):
        STALLS.append(f"{transport} {case}: " + ", ".join(f"{PAIRING_NAMES[c]} {n}" for c, n in slow.items() if n)
                      + f" of {len(samples[combos[0]])}")
        log("SLOW SLICES: " + STALLS[-1])
    return Run(samples, cpu)


def median_ci(values):
    """The 95% confidence interval of the median of values (distribution-free, from
    order statistics: the ranks (n - 1) / 2 -+ 1.96 sqrt(n) / 2, widened to whole
    ranks), or None with fewer than 6 values. It takes the per-cycle values as
    independent; a slow drift of the machine makes them less so, and the interval
    somewhat optimistic."""
    v = sorted(values)
    n = len(v)
    if n < 6:
        return None
    lo = max(0, math.floor((n - 1) / 2 - 0.98 * math.sqrt(n)))
    return v[lo], v[n - 1 - lo]


def cpu_list(spec):
    """The CPUs of a taskset-style list ("1", "0,2", "0-3", "0-7:2"); empty for ""."""
    cpus = set()
    for part in filter(None, spec.split(",")):
        span, _, stride = part.partition(":")
        first, _, last = span.partition("-")
        cpus.update(range(int(first), int(last or first) + 1, int(stride or 1)))
    return cpus


class Run:
    """The throughput samples of one case: one per pairing per cycle. A ratio between
    two pairings is the median of its per-cycle values, given with the 95% confidence
    interval of that median."""

    def __init__(self, samples, cpu):
        self.samples = samples
        self.cpu = cpu

    def cpu_us(self, pairing):
        """Microseconds of CPU per transaction: client, server, socat (RTU)."""
        return self.cpu[pairing]

    def tps(self, pairing):
        return statistics.median(self.samples[pairing])

    def per_cycle(self, a, b):
        return [x / y for x, y in zip(self.samples[a], self.samples[b])]

    def ratio(self, a, b):
        return statistics.median(self.per_cycle(a, b))

    def spread(self, a, b, percent=False):
        """The ratio's confidence interval, as text."""
        ci = median_ci(self.per_cycle(a, b))
        if ci is None:
            return "-"
        if percent:
            return f"{ci[0]:.1%}-{ci[1]:.1%}"
        return f"{ci[0]:.3f}-{ci[1]:.3f}x"


# ---- per-transaction costs ------------------------------------------------------------

def tool_prefix(metric, out):
    if metric == "strace":
        return ["strace", "-f", "-o", out]
    if metric == "callgrind":
        return ["valgrind", "--tool=callgrind", "--callgrind-out-file=" + out, "--dump-instr=no", "--quiet"]
    return []


def parse_metric(metric, out):
    if metric == "strace":
        return calls_after_mark(out)
    if metric == "callgrind":
        return callgrind_costs(out)
    with open(out) as f:
        text = f.read()
    m = re.findall(r"allocs=(\d+)", text)
    return {"total": int(m[-1])} if m else {"total": 0}


# The measured program's mark (MB_MARK_SETUP: mb-server and bench-client call getppid()
# once their connection is set up), after which its system calls are counted.
SETUP_MARK = "getppid"


def calls_after_mark(path):
    """System calls by name in an `strace -f -o` log after the measured program's set-up
    mark: those of the transactions and the exit (a server's also of the client's
    warm-up), not those of the start and of the connection, whose number depends on
    timing. A TLS handshake makes an EAGAIN read and a ppoll each time the peer's next
    flight has not arrived yet: the server waits 0 to 3 times (the ClientHello, the
    client's ChangeCipherSpec, its Finished flight), so that the set-ups of two runs
    differ by up to 6 calls, which the difference of the runs (`per_tx`) would count as
    the transactions'. A TLS client's first read may take the server's session tickets
    alone (a read with no data, a wait, a read): bench-client marks after its warm-up."""
    calls, marked = {}, False
    with open(path) as f:
        for line in f:
            # "PID name(args) = result", or "name(..." <unfinished ...>; not the
            # "<... name resumed>" halves, signals ("---") or exits ("+++").
            m = re.match(r"(?:\d+ +)?([a-z_][a-z0-9_]*)\(", line)
            if m is None:
                continue
            if marked:
                calls[m.group(1)] = calls.get(m.group(1), 0) + 1
            elif m.group(1) == SETUP_MARK:
                marked = True
    if not marked:
        raise RuntimeError(f"{path}: the measured program made no set-up mark ({SETUP_MARK}())")
    return calls


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


def cost_run(metric, side, transport, case, lib, n, warm=20, peer="debian"):
    """Runs `side` (client or server) with `lib` under the metric's tool for n
    transactions against a `peer` (Debian's library by default); returns the parsed counts."""
    tmp = tempfile.mkdtemp(prefix="mbcost-")
    out = os.path.join(tmp, "out")
    line = PtyPair("mbbench-", 2) if transport == "rtu" else None
    net = transport != "rtu"
    try:
        prefix = tool_prefix(metric, out)
        def measured_env():
            e = with_tls(env_for(lib), transport, side)
            if metric == "allocs":
                e["LD_PRELOAD"] = bin_("alloc-count.so")
                e["ALLOC_COUNT_OUT"] = out
            if metric == "strace":
                e["MB_MARK_SETUP"] = "1"
            return e
        if side == "client":
            srv = start([bin_("mb-server"), transport, "0" if net else line.a],
                        with_tls(env_for(peer), transport, "server"))
            addr = wait_ready(srv, "server", 30, peer)
            ccmd = prefix + [bin_("bench-client"), transport, addr if net else line.b, case,
                             "-n", str(n), "-w", str(warm)]
            run_client(ccmd, measured_env(), f"{metric} client", timeout=600)
            stop(srv)
        else:
            scmd = prefix + [bin_("mb-server"), transport, "0" if net else line.a, str(n + warm)]
            srv = start(scmd, measured_env())
            addr = wait_ready(srv, f"{metric} server", 120)
            ccmd = [bin_("bench-client"), transport, addr if net else line.b, case,
                    "-n", str(n), "-w", str(warm)]
            run_client(ccmd, with_tls(env_for(peer), transport, "client"), "client", peer, timeout=600)
            # It exits by itself after n + warm replies; its counts are written at exit.
            if wait_output(srv, 600) is None:
                raise RuntimeError(f"{metric} server: did not exit within 600 s of its last reply (stopped)")
        return parse_metric(metric, out)
    finally:
        if line:
            line.close()
        shutil.rmtree(tmp, ignore_errors=True)


METRIC_N = {"strace": 1000, "callgrind": 300, "allocs": 1000}


def cost_header(lead, metrics, a, b):
    """The header and separator of a cost table: the `lead` columns, then per metric
    the figures of pairing `a` and `b` (and, for system calls, b's calls)."""
    header, sep = "| " + " | ".join(lead) + " |", "|" + "---|" * len(lead)
    if "strace" in metrics:
        header += f" syscalls/tx {a} | syscalls/tx {b} | {b}: calls |"
        sep += "---:|---:|---|"
    if "callgrind" in metrics:
        header += f" Ir/tx {a} | Ir/tx {b} |"
        sep += "---:|---:|"
    if "allocs" in metrics:
        header += f" allocs/tx {a} | allocs/tx {b} |"
        sep += "---:|---:|"
    return header, sep


def syscalls(counts):
    """System calls per transaction from strace's counts: the total, and the calls
    (most frequent first) as text."""
    total = sum(v for k, v in counts.items() if k != "total")
    calls = ", ".join(f"{k} {v:.1f}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])
                      if k != "total" and v >= 0.05)
    return total, calls


def within_calls(measured, bound):
    """A system-call count per transaction from `per_tx` meets `bound`. The count is
    exact: the calls after the set-up mark (`calls_after_mark`) are the same in every
    run of a length (30 runs each, TLS and TCP, client and server, also beside two
    busy loops), so that the bound needs no allowance for the set-up."""
    return measured <= bound


def per_tx(metric, side, transport, case, lib, peer="debian"):
    n = METRIC_N[metric] // (2 if QUICK else 1)
    a = cost_run(metric, side, transport, case, lib, n, peer=peer)
    b = cost_run(metric, side, transport, case, lib, 2 * n, peer=peer)
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
                                f"ours {ours:.3f}x, {share_of_waiting:.1%} of it")
    if bare < target:
        return "out of reach", f"the bare floor itself is {bare:.3f}x; ours {ours:.3f}x"
    return "NOT MET", f"ours {ours:.3f}x, waiting floor {waiting:.3f}x, ours {share_of_waiting:.1%} of it"


def verdicts(results, costs, rows):
    """Each target against this run's measurements (plus `rows`, judged already), and a closing count."""
    rows = list(rows)
    for (transport, case), run in results.items():
        title = f"{transport.upper()} {CASE_TITLES[case]}"
        target = TCP_RATIO if transport == "tcp" else RTU_RATIO
        verdict, measured = throughput_verdict(target, run.ratio(OO, DD), run.ratio(WAIT, DD), run.ratio(FLOOR, DD),
                                               run.ratio(OO, WAIT))
        if verdict == "NOT MET" and PIN and transport == "tcp":
            # TCP on one CPU is CPU-bound (a transaction takes its CPU time): the shortfall in CPU time.
            ours_cpu, library = sum(run.cpu_us(OO)), sum(run.cpu_us(OO)) - sum(run.cpu_us(WAIT))
            measured += (f"; to meet it, ours/ours needs about {ours_cpu * (1 - run.ratio(OO, DD) / target):.2f} µs "
                         f"less CPU per transaction (its library work costs {library:.2f} µs over the waiting floor)")
        if DATA in run.samples:
            measured += f"; the data floor is {run.ratio(DATA, DD):.3f}x ({run.spread(DATA, DD)}), ours {run.ratio(OO, DATA):.1%} of it"
        rows.append((f"{title}: >= {target}x Debian", verdict,
                     f"{measured}; 95% confidence intervals: ours {run.spread(OO, DD)}, waiting floor {run.spread(WAIT, DD)}"))
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
            met = within_calls(ours, TCP_SYSCALLS)
            rows.append((f"{title}: <= {TCP_SYSCALLS} system calls", "met" if met else "NOT MET",
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
    lines.append(f"Ours: {os.environ.get('BENCH_OURS_BUILD', OURS_DIR)}.  ")
    if PIN:
        lines.append(f"All processes pinned to CPU(s) {PIN} (taskset).  ")
    cycles = max(1, round(SECONDS / SLICE))
    lines.append(f"Method: the pairings of a case take turns: in each of {cycles} cycle(s) every pairing runs for "
                 f"{SLICE} s while the others are paused (SIGSTOP), in a new random order every cycle. A tx/s figure "
                 f"is the median over the cycles; a ratio is the median of its per-cycle ratios (the two pairings "
                 f"ran within a second of each other), in brackets its 95% confidence interval. Client and server "
                 f"are the same binaries, only LD_LIBRARY_PATH differs. RTU runs over a socat pty pair.\n")

    results = {}
    for transport in [t for t in TRANSPORTS if t != "tls"] if THROUGHPUT else []:
        combos = [DD, OD, DO, OO, FLOOR, WAIT] + ([DATA] if transport == "tcp" else []) \
            + ([PEEK, TIMEOUT] if transport == "tcp" and FLOOR_PARTS else [])
        # In random orders a client may run first in one cycle and last in the next.
        if 2 * SLICE * (len(combos) - 1) > 3:
            raise SystemExit(f"BENCH_SLICE={SLICE}: a client could wait over 3 s paused (the floor's timeouts are 5 s)")
        for case in CASES:
            log(f"{transport} {case}: {len(combos)} pairings, {cycles} cycles of {SLICE} s each")
            results[(transport, case)] = run = interleaved(transport, case, combos, SECONDS, SLICE)
            log(f"{transport} {case} (medians): " + tps_line({c: run.tps(c) for c in combos}))

    if results:
        lines.append("### Transactions per second\n")
        lines.append("Pairings are client/server. \"client\" = our client against Debian's server; "
                     "\"server\" = Debian's client against our server; \"both\" = ours against ours.\n")
        lines.append("\"Waiting floor\": the bare floor plus the waits libmodbus's semantics need (TCP: the server "
                     "peeks before its exact read, the client's read waits by itself; pty: both sides poll with a "
                     "timeout before reading); its ratio to Debian/Debian is the most a library keeping those "
                     "semantics could reach.\n")
        lines.append("| transport | case | Debian/Debian tx/s | ours/ours tx/s | both ratio (95% CI) | "
                     "client ratio | server ratio | bare floor tx/s | ours/floor | Debian/floor | waiting floor tx/s | "
                     "waiting floor/Debian | ours/waiting floor (95% CI) |")
        lines.append("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        for (transport, case), run in results.items():
            lines.append(f"| {transport.upper()} | {CASE_TITLES[case]} | {fmt(run.tps(DD))} | {fmt(run.tps(OO))} | "
                         f"{run.ratio(OO, DD):.3f}x ({run.spread(OO, DD)}) | {run.ratio(OD, DD):.2f}x | "
                         f"{run.ratio(DO, DD):.2f}x | {fmt(run.tps(FLOOR))} | {run.ratio(OO, FLOOR):.0%} | "
                         f"{run.ratio(DD, FLOOR):.0%} | {fmt(run.tps(WAIT))} | {run.ratio(WAIT, DD):.2f}x | "
                         f"{run.ratio(OO, WAIT):.1%} ({run.spread(OO, WAIT, percent=True)}) |")
        priced = [(k, run) for k, run in results.items() if PEEK in run.samples]
        if priced:
            lines.append("\n### What each wait costs (TCP)\n")
            lines.append("The bare floor with only the server's peek before its exact read, with only the "
                         "client's `SO_RCVTIMEO`, and with both (the waiting floor); each as a share of the bare "
                         "floor (median of the per-cycle ratios, 95% confidence interval in brackets).\n")
            lines.append("| case | bare floor tx/s | + server peek | + client timeout | both: waiting floor |")
            lines.append("|---|---:|---:|---:|---:|")
            for (transport, case), run in priced:
                lines.append(f"| {CASE_TITLES[case]} | {fmt(run.tps(FLOOR))} | "
                             + " | ".join(f"{run.ratio(c, FLOOR):.1%} ({run.spread(c, FLOOR, percent=True)})"
                                          for c in (PEEK, TIMEOUT, WAIT)) + " |")
        with_data = [(k, run) for k, run in results.items() if DATA in run.samples]
        if with_data:
            lines.append("\n### The data floor (TCP)\n")
            lines.append("The waiting floor plus the conversions of the case's values between arrays and the wire on "
                         "both sides (registers byte-swapped, vectorised by the compiler; coils packed with SSE2 and "
                         "unpacked from a table): the least a library has to do with the values, and nothing else "
                         "(no header, no check). 95% confidence intervals in brackets.\n")
            lines.append("| case | waiting floor/Debian | data floor/Debian | ours/Debian | ours/data floor |")
            lines.append("|---|---:|---:|---:|---:|")
            for (transport, case), run in with_data:
                lines.append(f"| {CASE_TITLES[case]} | {run.ratio(WAIT, DD):.3f}x | {run.ratio(DATA, DD):.3f}x "
                             f"({run.spread(DATA, DD)}) | {run.ratio(OO, DD):.3f}x ({run.spread(OO, DD)}) | "
                             f"{run.ratio(OO, DATA):.1%} ({run.spread(OO, DATA, percent=True)}) |")
        lines.append("\n### CPU time per transaction\n")
        lines.append("CPU time (user and system) of the measurement's processes per transaction, from "
                     "/proc/PID/schedstat over all the cycles: client + server (+ socat on RTU). Ours/ours and the "
                     "waiting floor make the same system calls, so the difference between them, split by side in "
                     "the last column, is what the library's own work costs.\n")
        lines.append("| transport | case | Debian/Debian | ours/ours | waiting floor | bare floor | "
                     "ours - waiting floor: client + server |")
        lines.append("|---|---|---:|---:|---:|---:|---:|")
        for (transport, case), run in results.items():
            ours, wait = run.cpu_us(OO), run.cpu_us(WAIT)
            lines.append(f"| {transport.upper()} | {CASE_TITLES[case]} | "
                         + " | ".join(f"{sum(run.cpu_us(c)):.2f} µs" for c in (DD, OO, WAIT, FLOOR))
                         + f" | {ours[0] - wait[0]:+.2f} + {ours[1] - wait[1]:+.2f} µs |")

    costs = {}
    if STALLS:
        lines.append("\nSlow slices (at under half their pairing's median rate; when the floors have them too, "
                     "the machine or the pty caused them, not a library):\n")
        lines.extend(f"- {s}" for s in STALLS)
    if METRICS and any(t != "tls" for t in TRANSPORTS):
        lines.append("\n### Cost per transaction (steady state)\n")
        lines.append("Each side is measured against a Debian peer, for N and 2N transactions after the same "
                     "warm-up; the figure is (count(2N) - count(N)) / N, so start-up and teardown cancel out. "
                     "System calls: `strace -f` of the measured process, the calls after its mark that the "
                     "connection is set up (the client's after its warm-up): a TLS handshake's calls depend on "
                     "timing. Instructions: `valgrind "
                     "--tool=callgrind`, total Ir of the whole process (program + libmodbus + libc), with the "
                     "libmodbus.so object's own share in brackets. Allocations: an LD_PRELOAD counter of "
                     "malloc/calloc/realloc/memalign calls.\n")
        lines.extend(cost_header(("transport", "case", "side"), METRICS, "Debian", "ours"))
        for transport in [t for t in TRANSPORTS if t != "tls"]:
            for case in METRIC_CASES:
                for side in ("client", "server"):
                    row = f"| {transport.upper()} | {CASE_TITLES[case]} | {side} |"
                    if "strace" in METRICS:
                        d = per_tx("strace", side, transport, case, "debian")
                        o = per_tx("strace", side, transport, case, "ours")
                        dt, dd_detail = syscalls(d)
                        ot, detail = syscalls(o)
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
    tls_rows = []
    if "tls" in TRANSPORTS:
        tls_lines, tls_rows = tls_section()
        lines.extend(tls_lines)
    lines.extend(verdicts(results, costs, tls_rows))
    lines.append(f"\n({time.time() - started:.0f} s; `scripts/bench.sh`{' with BENCH_QUICK=1' if QUICK else ''})")
    text = "\n".join(lines) + "\n"
    os.makedirs(BUILD, exist_ok=True)
    with open(RESULTS, "w") as f:
        f.write(text)
    print(text)


# The targets of Modbus/TCP Security: ours over TLS at least 80% of ours over plain TCP
# (read 125 registers), at most 3 system calls per side per transaction.
TLS_SHARE, TLS_SYSCALLS = 0.8, 3
# Against stunnel in front of Debian's libmodbus: at least 2x its transactions per second,
# at most half its serving side's CPU per transaction (stunnel + the server).
STUNNEL_RATIO, STUNNEL_CPU = 2.0, 0.5
STUNNEL_ON = os.environ.get("BENCH_STUNNEL", "1") == "1" and shutil.which("stunnel") is not None


def tls_resumption_check():
    """Proof that the connection cases measure what they say: the client's debug trace
    shows every handshake of case conn after the first resumed, and none of conn-full."""
    srv = start([bin_("mb-server"), "tls", "0"], with_tls(env_for("ours"), "tls", "server"))
    try:
        addr = wait_ready(srv, "TLS server", 30, "ours")
        seen = {}
        for case in ("conn", "conn-full"):
            # The trace starts after the first connect; the warm-up's connection cannot
            # resume (the first one read nothing, so it never took its ticket); the 3 after it must.
            out, _ = run_client([bin_("bench-client"), "tls", addr, case, "-n", "3", "-w", "1"],
                                dict(with_tls(env_for("ours"), "tls", "client"), MB_DEBUG="1"),
                                f"TLS {case} client", "ours")
            seen[case] = (out.count("TLS handshake done"), out.count(", resumed"))
    finally:
        stop(srv)
    if seen != {"conn": (4, 3), "conn-full": (4, 0)}:
        raise RuntimeError(f"TLS handshakes (done, resumed) per case: {seen}; expected conn (4, 3), conn-full (4, 0)")


def tls_section():
    """Modbus/TCP Security: ours over TLS against ours over plain TCP (and Debian's plain
    TCP for scale), interleaved as above; new connections per second with full and
    resumed handshakes; system calls, instructions and allocations per transaction.
    Returns the report's lines and the judged target rows."""
    lines, rows = ["\n### Modbus/TCP Security (TLS)\n"], []
    lines.append("Ours against ours over TLS 1.3 (rustls, TLS13_AES_128_GCM_SHA256, P-256 certificates, mutual "
                 "authentication; the client's certificate has a role), against the same library over plain TCP "
                 "and Debian's plain TCP (Debian's libmodbus has no TLS). Same binaries, same method as above.\n")
    if THROUGHPUT:
        lines.append("| case | Debian/Debian TCP tx/s | ours/ours TCP tx/s | ours/ours TLS tx/s | TLS/TCP (95% CI) | "
                     "TLS/Debian TCP | CPU/tx client TCP, TLS | CPU/tx server TCP, TLS |")
        lines.append("|---|---:|---:|---:|---:|---:|---:|---:|")
        stunnel_lines = []
        for case in TLS_CASES:
            combos = [OO, TLS, DD] + ([STUNNEL] if STUNNEL_ON else [])
            log(f"tls {case}: {len(combos)} pairings")
            run = interleaved("tcp", case, combos, SECONDS, SLICE)
            log(f"tls {case} (medians): " + tps_line({c: run.tps(c) for c in combos}))
            tcp_cpu, tls_cpu = run.cpu_us(OO), run.cpu_us(TLS)
            share = run.ratio(TLS, OO)
            lines.append(f"| {CASE_TITLES[case]} | {fmt(run.tps(DD))} | {fmt(run.tps(OO))} | {fmt(run.tps(TLS))} | "
                         f"{share:.1%} ({run.spread(TLS, OO, percent=True)}) | {run.ratio(TLS, DD):.2f}x | "
                         f"{tcp_cpu[0]:.2f}, {tls_cpu[0]:.2f} µs | {tcp_cpu[1]:.2f}, {tls_cpu[1]:.2f} µs |")
            rows.append((f"TLS {CASE_TITLES[case]}: >= {TLS_SHARE:.0%} of plain TCP (ours/ours)",
                         "met" if share >= TLS_SHARE else "NOT MET",
                         f"{share:.1%} ({run.spread(TLS, OO, percent=True)})"))
            if STUNNEL_ON:
                st_cpu = run.cpu_us(STUNNEL)
                serving, ours = st_cpu[1] + st_cpu[2], tls_cpu[1]
                ratio = run.ratio(TLS, STUNNEL)
                stunnel_lines.append(
                    f"| {CASE_TITLES[case]} | {fmt(run.tps(STUNNEL))} | {fmt(run.tps(TLS))} | {ratio:.2f}x "
                    f"({run.spread(TLS, STUNNEL)}) | {st_cpu[0]:.2f}, {tls_cpu[0]:.2f} µs | "
                    f"{st_cpu[1]:.2f} + {st_cpu[2]:.2f} = {serving:.2f} µs | {ours:.2f} µs ({ours / serving:.0%}) |")
                rows.append((f"TLS {CASE_TITLES[case]}: >= {STUNNEL_RATIO:.0f}x stunnel + Debian's server",
                             "met" if ratio >= STUNNEL_RATIO else "NOT MET", f"{ratio:.2f}x ({run.spread(TLS, STUNNEL)})"))
                rows.append((f"TLS {CASE_TITLES[case]}: serving CPU/tx <= {STUNNEL_CPU:.0%} of stunnel + Debian's server",
                             "met" if ours <= STUNNEL_CPU * serving else "NOT MET",
                             f"{ours:.2f} µs against {serving:.2f} µs ({ours / serving:.0%})"))
        if stunnel_lines:
            lines.append("\nAgainst what is deployed for Modbus/TCP Security today: Debian's libmodbus server behind "
                         "Debian's stunnel (TLS 1.3, the same certificates, the client's certificate required), our TLS "
                         "client in front, interleaved with the pairings above. CPU per transaction of the serving side: "
                         "stunnel's process plus the libmodbus server behind it, against our TLS server.\n")
            lines.append("| case | stunnel + Debian tx/s | ours TLS tx/s | ours/stunnel (95% CI) | CPU/tx client "
                         "(stunnel pairing, ours) | CPU/tx serving: Debian server + stunnel | CPU/tx serving: ours |")
            lines.append("|---|---:|---:|---:|---:|---:|---:|")
            lines.extend(stunnel_lines)
        tls_resumption_check()
        combos = [OO, TLS, TLS_FULL, DD]
        log("tls conn: 4 pairings")
        run = interleaved("tcp", "conn", combos, SECONDS, SLICE)
        log("tls conn (medians): " + tps_line({c: run.tps(c) for c in combos}))
        lines.append("\nNew connections per second, each: connect (with the TLS handshake), read 1 register, close "
                     "(bench-client cases `conn` and `conn-full`). A TLS client context keeps its session: its next "
                     "connection resumes it (TLS 1.3 ticket: no certificate is sent or verified); a full handshake is "
                     "measured by setting a TLS setting again before each connect (which drops the session, and makes the "
                     "client build its configuration again: part of the figure). Before "
                     "the measurement, the client's debug trace proved every `conn` handshake after the first "
                     "resumed and no `conn-full` one.\n")
        lines.append("| pairing | connections/s | vs plain TCP, ours (95% CI) | CPU per connection: client + server |")
        lines.append("|---|---:|---:|---:|")
        titles = {OO: "plain TCP, ours/ours", TLS: "TLS, resumed handshakes", TLS_FULL: "TLS, full handshakes",
                  DD: "plain TCP, Debian/Debian"}
        for c in combos:
            cpu = run.cpu_us(c)
            lines.append(f"| {titles[c]} | {fmt(run.tps(c))} | {run.ratio(c, OO):.1%} "
                         f"({run.spread(c, OO, percent=True)}) | {cpu[0]:.0f} + {cpu[1]:.0f} µs |")
        lines.append(f"\nHandshakes per second (each with a read and a close): full {fmt(run.tps(TLS_FULL))}, "
                     f"resumed {fmt(run.tps(TLS))}; plain TCP connections {fmt(run.tps(OO))}.")
    if TLS_METRICS:
        lines.append("\nCost per transaction, each side measured against our other side (the only TLS peer), "
                     "the method of the costs above.\n")
        lines.extend(cost_header(("case", "side"), TLS_METRICS, "TCP", "TLS"))
        for case in TLS_CASES:
            for side in ("client", "server"):
                row = f"| {CASE_TITLES[case]} | {side} |"
                for metric in ("strace", "callgrind", "allocs"):
                    if metric not in TLS_METRICS:
                        continue
                    tcp = per_tx(metric, side, "tcp", case, "ours", peer="ours")
                    tls = per_tx(metric, side, "tls", case, "ours", peer="ours")
                    if metric == "strace":
                        t_tcp, _ = syscalls(tcp)
                        t_tls, detail = syscalls(tls)
                        row += f" {t_tcp:.1f} | {t_tls:.1f} | {detail} |"
                        rows.append((f"TLS {CASE_TITLES[case]}, {side}: <= {TLS_SYSCALLS} system calls",
                                     "met" if within_calls(t_tls, TLS_SYSCALLS) else "NOT MET", f"{t_tls:.1f} ({detail})"))
                    elif metric == "callgrind":
                        row += f" {fmt(tcp['total'])} | {fmt(tls['total'])} |"
                    else:
                        row += f" {tcp['total']:.2f} | {tls['total']:.2f} |"
                lines.append(row)
                log(row)
    return lines, rows


def run_main(main_fn):
    """Runs main_fn. SIGTERM (a CI timeout, kill) unwinds like an error, so that the
    clients paused with SIGSTOP are resumed and stopped on the way out."""
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        main_fn()
    finally:
        stop_all()


if __name__ == "__main__":
    run_main(main)
