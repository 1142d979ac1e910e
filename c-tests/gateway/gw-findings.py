#!/usr/bin/env python3
# Masters for the security review's findings (issue 40) in c-tests/suites/gateway.sh:
# plain sockets on loopback, the bytes are the test's (no libmodbus). The line's device
# answers FC 03 of unit 1 with holding register i = 3 * i (benches/mb-server.c and
# c-tests/gateway/fake_device.py alike).
#
#   gw-findings.py proto PORT UNIT      MBAP protocol id 1: the connection is dropped,
#                                       no answer (finding 16)
#   gw-findings.py full PORT N          N masters connected and answered; one more is
#                                       accepted and closed at once (-C N; finding 16)
#   gw-findings.py fds PLAIN RTUTCP N   N connections to the plain front (descriptors
#                                       exhausted), one to the RTU-over-TCP front, all
#                                       closed: the RTU-over-TCP front answers again
#                                       (finding 5)
#   gw-findings.py flood PORT UNIT N    N requests for UNIT (no device) pipelined on one
#                                       connection: all but the queue's refused, 0x06
#                                       (finding 6; the suite checks the log's size)
#   gw-findings.py udp PORT             one UDP sender floods unit 9 (no device), another
#                                       sender's read of unit 1 is answered (finding 10)
#   gw-findings.py udpdeny PORT SRC     a sender from address SRC (outside udp_allow)
#                                       gets no answer (finding 10)
#   gw-findings.py dns PORT UNIT BOUND  a request for UNIT (a line whose host name does
#                                       not resolve) pending; meanwhile reads of unit 1
#                                       each answered within BOUND seconds (finding 7)
#   gw-findings.py longfc PORT          user-defined FC 0x64, a 201-byte request, the
#                                       device's 251-byte answer whole (finding 11)
#   gw-findings.py queue PORT UNIT N    N writes for UNIT (no device) in one send, then
#                                       the master leaves (finding 14; the suite counts
#                                       what the device saw)
#   gw-findings.py ready PORT SECS      waits until unit 1 is answered (exit 0), at most
#                                       SECS seconds (exit 1); no check
#   gw-findings.py rtutcp PORT UNIT EXC  RTU over TCP: a read of UNIT gets exception EXC
#                                       (hex; finding 4's plain_units)
#
# Each prints "ok   - ..." / "FAIL - ..." lines and "N passed, M failed"; exit 0 when
# all passed.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import os
import socket
import struct
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "common"))
from mbframe import crc_ok, rtu  # noqa: E402

counts = {"passed": 0, "failed": 0}


def check(cond, what):
    counts["passed" if cond else "failed"] += 1
    print(("ok   - " if cond else "FAIL - ") + what, flush=True)
    return cond


def note(text):
    print("# " + text, flush=True)


def mbap(tid, unit, pdu, proto=0):
    return struct.pack(">HHHB", tid, proto, len(pdu) + 1, unit) + pdu


def read03(addr, n):
    return struct.pack(">BHH", 3, addr, n)


def connect(port, timeout=10.0):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def recv_exact(s, n):
    data = b""
    while len(data) < n:
        chunk = s.recv(n - len(data))
        if not chunk:
            return data
        data += chunk
    return data


def recv_adu(s):
    """One MBAP answer: (tid, unit, pdu), or None on EOF / timeout."""
    try:
        head = recv_exact(s, 7)
        if len(head) < 7:
            return None
        tid, _, length, unit = struct.unpack(">HHHB", head)
        pdu = recv_exact(s, length - 1)
        return (tid, unit, pdu) if len(pdu) == length - 1 else None
    except (socket.timeout, OSError):
        return None


def ask(port, unit, pdu, timeout=10.0, tid=1):
    """One request on a new connection: its answer's PDU, or None."""
    try:
        with connect(port, timeout) as s:
            s.settimeout(timeout)
            s.sendall(mbap(tid, unit, pdu))
            a = recv_adu(s)
            return a[2] if a else None
    except OSError:
        return None


def regs_ok(pdu, addr, n):
    want = bytes([3, 2 * n]) + b"".join(struct.pack(">H", 3 * (addr + i)) for i in range(n))
    return pdu == want


def eof_within(s, secs):
    """True when the peer closes (EOF or reset) within secs, with no bytes first.
    Returns (closed, bytes seen)."""
    s.settimeout(secs)
    seen = b""
    end = time.monotonic() + secs
    while time.monotonic() < end:
        try:
            chunk = s.recv(4096)
        except socket.timeout:
            return False, seen
        except ConnectionResetError:
            return True, seen
        if not chunk:
            return True, seen
        seen += chunk
    return False, seen


def proto(port, unit):
    s = connect(port)
    s.sendall(mbap(0x4242, unit, read03(10, 2), proto=1))
    closed, seen = eof_within(s, 10)
    check(closed and not seen, "a request with MBAP protocol id 1: the connection dropped, no answer "
          "(closed %s, %d bytes back)" % (closed, len(seen)))
    s.close()
    a = ask(port, 1, read03(10, 2))
    check(a is not None and regs_ok(a, 10, 2), "a new connection is served after it (%r)" % a)


def full(port, n):
    held = []
    answered = 0
    for i in range(n):
        s = connect(port)
        s.settimeout(10)
        s.sendall(mbap(i + 1, 1, read03(10, 2)))
        a = recv_adu(s)
        answered += a is not None and regs_ok(a[2], 10, 2)
        held.append(s)
    check(answered == n, "%d masters connected and answered (%d)" % (n, answered))
    t0 = time.monotonic()
    extra = connect(port)
    extra.sendall(mbap(99, 1, read03(10, 2)))
    closed, seen = eof_within(extra, 5)
    check(closed and not seen, "one more at maxconn: accepted and closed at once, not left in the backlog "
          "(closed %s after %.1f s, %d bytes)" % (closed, time.monotonic() - t0, len(seen)))
    extra.close()
    for s in held:
        s.close()


def rtutcp_read(port, unit, addr, n, timeout):
    """RTU over TCP: the answer frame (CRC checked), or None."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
            s.settimeout(timeout)
            s.sendall(rtu(struct.pack(">BBHH", unit, 3, addr, n)))
            frame = b""
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                chunk = s.recv(512)
                if not chunk:
                    return None
                frame += chunk
                if crc_ok(frame):
                    return frame
    except OSError:
        return None
    return None


def fds(plain, rtutcp, n):
    socks = []
    for _ in range(n):
        try:
            socks.append(socket.create_connection(("127.0.0.1", plain), timeout=5))
        except OSError:
            break
    note("%d connections to the plain front" % len(socks))
    time.sleep(1.0)
    # While the descriptors are gone: a master of the RTU-over-TCP front (its accept fails).
    try:
        r = socket.create_connection(("127.0.0.1", rtutcp), timeout=5)
        r.sendall(rtu(struct.pack(">BBHH", 1, 3, 10, 2)))
        time.sleep(1.0)
        r.close()
    except OSError as e:
        note("RTU-over-TCP connection while exhausted: %s" % e)
    for s in socks:
        s.close()
    time.sleep(1.0)
    end = time.monotonic() + 20
    frame = None
    while time.monotonic() < end and frame is None:
        frame = rtutcp_read(rtutcp, 1, 10, 2, 3)
    want = rtu(bytes([1, 3, 4, 0, 30, 0, 33]))
    check(frame == want, "after the plain front's connections are closed, the RTU-over-TCP front answers "
          "again (%r)" % frame)


def flood(port, unit, n):
    s = connect(port)
    got = {"busy": 0, "other": 0, "bytes": 0}
    done = threading.Event()

    def reader():
        s.settimeout(2)
        buf = b""
        while not done.is_set():
            try:
                chunk = s.recv(65536)
            except socket.timeout:
                continue
            except OSError:
                break
            if not chunk:
                break
            got["bytes"] += len(chunk)
            buf += chunk
            while len(buf) >= 7:
                length = struct.unpack(">H", buf[4:6])[0]
                if len(buf) < 6 + length:
                    break
                pdu, buf = buf[7:6 + length], buf[6 + length:]
                if pdu == bytes([0x83, 0x06]):
                    got["busy"] += 1
                else:
                    got["other"] += 1

    t = threading.Thread(target=reader, daemon=True)
    t.start()
    data = b"".join(mbap(i & 0xFFFF, unit, read03(0, 1)) for i in range(n))
    s.sendall(data)
    end = time.monotonic() + 60
    while time.monotonic() < end and got["busy"] < n - 16:
        time.sleep(0.2)
    done.set()
    note("%d bytes of requests sent: %d refused (0x06), %d other answers" % (len(data), got["busy"], got["other"]))
    check(got["busy"] >= n - 16, "%d requests pipelined into a full queue: at least %d refused, exception 0x06 (%d)"
          % (n, n - 16, got["busy"]))
    s.close()


def udp(port):
    flood_s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for i in range(200):
        flood_s.sendto(mbap(i, 9, read03(0, 1)), ("127.0.0.1", port))
    time.sleep(0.2)
    b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    b.settimeout(20)
    b.sendto(mbap(0x7777, 1, read03(10, 2)), ("127.0.0.1", port))
    pdu = None
    t0 = time.monotonic()
    try:
        while True:
            data, _ = b.recvfrom(512)
            if data[:2] == b"\x77\x77":
                pdu = data[7:]
                break
    except socket.timeout:
        pass
    check(pdu is not None and regs_ok(pdu, 10, 2), "a sender flooding unit 9 (200 requests) over UDP; another "
          "sender's read of unit 1 is answered, right, not refused (%r after %.1f s)" % (pdu, time.monotonic() - t0))
    flood_s.close()
    b.close()


def udpdeny(port, src):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((src, 0))
    s.settimeout(3)
    s.sendto(mbap(0x5151, 1, read03(10, 2)), ("127.0.0.1", port))
    try:
        data, _ = s.recvfrom(512)
    except (socket.timeout, ConnectionRefusedError):
        data = None
    check(data is None, "a UDP sender from %s (outside udp_allow) gets no answer (%r)" % (src, data))
    # And one from inside: answered (the front works).
    t = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t.settimeout(10)
    t.sendto(mbap(0x5252, 1, read03(10, 2)), ("127.0.0.1", port))
    try:
        data, _ = t.recvfrom(512)
    except socket.timeout:
        data = None
    check(data is not None and regs_ok(data[7:], 10, 2), "a UDP sender from 127.0.0.1 (inside) is answered (%r)"
          % data)


def dns(port, unit, bound):
    pending = connect(port)
    pending.sendall(mbap(0x0D05, unit, read03(0, 1)))
    got = {}

    def wait_pending():
        pending.settimeout(60)
        t0 = time.monotonic()
        a = recv_adu(pending)
        got["pending"] = (a[2] if a else None, time.monotonic() - t0)

    t = threading.Thread(target=wait_pending, daemon=True)
    t.start()
    time.sleep(0.5)
    worst = 0.0
    answered = 0
    with connect(port) as s:
        s.settimeout(60)
        for i in range(5):
            t0 = time.monotonic()
            s.sendall(mbap(i + 1, 1, read03(10, 2)))
            a = recv_adu(s)
            took = time.monotonic() - t0
            worst = max(worst, took)
            answered += a is not None and regs_ok(a[2], 10, 2)
            time.sleep(0.2)
    check(answered == 5 and worst <= bound, "a request for unit %d waits on a host name being resolved; meanwhile "
          "unit 1 on another line answered 5 times, each within %.0f s (%d answered, slowest %.2f s)"
          % (unit, bound, answered, worst))
    t.join(30)
    note("the request for unit %d: %r" % (unit, got.get("pending")))
    pending.close()


def longfc(port):
    req = bytes([0x64]) + bytes(range(200))
    want = bytes([0x64]) + bytes((i * 7 + 3) & 0xFF for i in range(250))
    s = connect(port)
    s.settimeout(10)
    s.sendall(mbap(0x6464, 1, req))
    a = recv_adu(s)
    check(a is not None and a[2] == want, "FC 0x64 (user-defined), a %d-byte request: the device's %d-byte answer "
          "whole (got %s)" % (len(req), len(want), "nothing" if a is None else "%d bytes" % len(a[2])))
    s.sendall(mbap(0x0303, 1, read03(10, 2)))
    a = recv_adu(s)
    check(a is not None and a[0] == 0x0303 and regs_ok(a[2], 10, 2), "the next request on the connection is "
          "answered, right (%r)" % (a,))
    s.close()


def queue(port, unit, n):
    s = connect(port)
    s.sendall(b"".join(mbap(i + 1, unit, struct.pack(">BHH", 6, 100 + i, i)) for i in range(n)))
    time.sleep(0.05)
    s.close()
    note("%d writes for unit %d sent, the master left" % (n, unit))


def rtutcp_exc(port, unit, exc):
    frame = rtutcp_read(port, unit, 10, 2, 10)
    want = rtu(bytes([unit, 0x83, exc]))
    check(frame == want, "RTU over TCP: a read of unit %d: exception 0x%02X (%r)" % (unit, exc, frame))


def ready(port, secs):
    end = time.monotonic() + secs
    while time.monotonic() < end:
        a = ask(port, 1, read03(10, 2), timeout=3)
        if a is not None and regs_ok(a, 10, 2):
            sys.exit(0)
        time.sleep(0.5)
    sys.exit(1)


def main():
    a = sys.argv[1:]
    cmd = a[0] if a else ""
    if cmd == "ready":
        ready(int(a[1]), float(a[2]))
    elif cmd == "proto":
        proto(int(a[1]), int(a[2]))
    elif cmd == "full":
        full(int(a[1]), int(a[2]))
    elif cmd == "fds":
        fds(int(a[1]), int(a[2]), int(a[3]))
    elif cmd == "flood":
        flood(int(a[1]), int(a[2]), int(a[3]))
    elif cmd == "udp":
        udp(int(a[1]))
    elif cmd == "udpdeny":
        udpdeny(int(a[1]), a[2])
    elif cmd == "dns":
        dns(int(a[1]), int(a[2]), float(a[3]))
    elif cmd == "longfc":
        longfc(int(a[1]))
    elif cmd == "queue":
        queue(int(a[1]), int(a[2]), int(a[3]))
    elif cmd == "rtutcp":
        rtutcp_exc(int(a[1]), int(a[2]), int(a[3], 16))
    else:
        sys.stderr.write("usage: see the header of %s\n" % sys.argv[0])
        sys.exit(2)
    print("%(passed)d passed, %(failed)d failed" % counts, flush=True)
    sys.exit(1 if counts["failed"] else 0)


main()
