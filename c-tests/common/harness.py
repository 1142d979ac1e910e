"""Process helpers shared by the Python runners: c-tests/fault/run.py, c-tests/soak/run.py
and benches/bench.py. They import it after putting this directory on sys.path.

Every process is started in its own session, so that stopping it also ends its children
(valgrind, strace, taskset); `procs` lists those not stopped yet, for stop_all() at exit.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OURS_DIR = os.path.join(ROOT, "target", "release")

# Runner settings, changed before anything is started.
COMMAND_PREFIX = []  # put before every command (benches/bench.py: taskset for BENCH_PIN)
STOP_GRACE = 5  # seconds from SIGTERM to SIGKILL

procs = []

LIBINFO = re.compile(r"LIBINFO: pid \d+ libmodbus\.so\.5 = (\S+) \((.*?)\)")


def start(cmd, env, stdout=subprocess.PIPE):
    """Starts cmd in its own session (stderr piped, text mode) and records it in procs."""
    p = subprocess.Popen(COMMAND_PREFIX + cmd, env=env, stdout=stdout, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    procs.append(p)
    return p


def _signal_and_wait(p, sig):
    """Sends sig to p's session and waits up to STOP_GRACE s: True if p has exited."""
    try:
        os.killpg(p.pid, sig)
    except ProcessLookupError:
        pass
    try:
        p.wait(STOP_GRACE)
        return True
    except subprocess.TimeoutExpired:
        return False


def stop(p):
    """Ends p's session (SIGTERM, SIGKILL after STOP_GRACE s) unless it has exited; forgets p."""
    if p.poll() is None and not _signal_and_wait(p, signal.SIGTERM):
        if not _signal_and_wait(p, signal.SIGKILL):
            # SIGKILL cannot be caught, but a process stuck in the kernel (a pty close,
            # a dead NFS mount) can still outlive it: say so rather than hang.
            sys.stderr.write(f"harness: pid {p.pid} ({p.args!r:.80}) survived SIGKILL for {STOP_GRACE} s; "
                             "left behind\n")
    if p in procs:
        procs.remove(p)


def stop_all():
    """Stops every process still recorded (a runner's last step, even after an exception)."""
    for p in list(procs):
        stop(p)


def summary(passed, failed):
    """Prints the runner's last line "N passed, M failed" and writes "N M" to the file
    $MBT_COUNTS names (c-tests/run's counts; unset: nothing written)."""
    print(f"\n{passed} passed, {failed} failed")
    counts = os.environ.get("MBT_COUNTS")
    if counts:
        with open(counts, "w") as f:
            f.write(f"{passed} {failed}\n")


def wait_output(p, timeout):
    """Waits up to timeout s for p to exit: (stdout, stderr), or None after stopping it."""
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        stop(p)
        return None
    procs.remove(p)
    return out, err


def env_for(lib, ours_dir=OURS_DIR):
    """The environment that makes a program load `lib`: "ours" from ours_dir, "debian",
    or "ours:DIR", a build of ours in DIR (the benchmarks' A/B runs)."""
    kind, _, where = lib.partition(":")
    e = dict(os.environ)
    e.pop("LD_LIBRARY_PATH", None)
    if kind == "ours":
        e["LD_LIBRARY_PATH"] = where or ours_dir
    e["EXPECT_LIB"] = kind  # libinfo.c exits 97 if another libmodbus.so.5 is loaded
    return e


def loaded_lib(text):
    """("ours" or "debian", path) from the LIBINFO line in text, or None if it has none."""
    m = LIBINFO.search(text)
    if not m:
        return None
    return ("ours" if m.group(2).startswith("rsmodbus") else "debian"), m.group(1)


def check_libinfo(text, lib, what):
    """Raises RuntimeError unless the LIBINFO line in text names `lib` ("ours", "debian",
    or "ours:DIR": ours, loaded from DIR)."""
    kind, _, where = lib.partition(":")
    found = loaded_lib(text)
    if found is None:
        raise RuntimeError(f"{what}: no LIBINFO line")
    if found[0] != kind:
        raise RuntimeError(f"{what}: expected {kind} but loaded {found[1]}")
    if where and os.path.realpath(os.path.dirname(found[1])) != os.path.realpath(where):
        raise RuntimeError(f"{what}: expected ours from {where} but loaded {found[1]}")


def wait_ready(p, what, timeout, lib=None):
    """Reads p's stdout up to its READY line and returns the word after READY; with lib, checks LIBINFO too.
    Stops p and raises RuntimeError if it exits first or no READY comes within timeout s."""
    deadline = time.monotonic() + timeout
    fd = p.stdout.fileno()
    line = b""
    seen = ""
    # Byte by byte from the descriptor, each read after select() with the time left: a
    # readline() blocks past the deadline when p hangs mid-line or silent, and a buffered
    # read could take output after READY that a later communicate() would then not see.
    while True:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            stop(p)
            raise RuntimeError(f"{what}: no READY in {timeout}s (stopped): {seen + line.decode(errors='replace')}")
        b = os.read(fd, 1)
        if not b:
            stop(p)
            raise RuntimeError(f"{what} exited before READY (exit {p.returncode}): "
                               f"{seen + line.decode(errors='replace')} {p.stderr.read()}")
        line += b
        if b != b"\n":
            continue
        text = line.decode(errors="replace")
        seen += text
        line = b""
        if text.startswith("READY "):
            if lib is not None:
                check_libinfo(seen, lib, what)
            return text.split()[1]


class PtyPair:
    """A serial line: a socat pty pair linked as .a and .b in a new temporary directory."""

    def __init__(self, tmp_prefix, timeout):
        self.dir = tempfile.mkdtemp(prefix=tmp_prefix)
        self.a = os.path.join(self.dir, "ttyA")
        self.b = os.path.join(self.dir, "ttyB")
        self.p = start(["socat", "pty,raw,echo=0,link=" + self.a, "pty,raw,echo=0,link=" + self.b],
                       dict(os.environ), stdout=subprocess.DEVNULL)
        for _ in range(int(timeout * 100)):
            if os.path.exists(self.a) and os.path.exists(self.b):
                return
            time.sleep(0.01)
        self.close()
        raise RuntimeError("socat pty pair did not appear")

    def close(self):
        """Stops socat and removes the directory."""
        stop(self.p)
        shutil.rmtree(self.dir, ignore_errors=True)
