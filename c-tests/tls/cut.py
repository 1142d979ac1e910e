#!/usr/bin/env python3
# TLS connections cut in the middle of a record, and peers that never send
# close_notify (tls.sh). Python's ssl module drives TLS through memory BIOs,
# so that the encrypted bytes of a record can be cut anywhere.
#
#   cut.py clients PORT CERTDIR   against our poll-loop server (examples/tls-server.c):
#       1. half of a request's record, then FIN;
#       2. half of a request's record, then RST;
#       3. a whole request, its answer read, then FIN without close_notify;
#       4. after each, a normal client is served (the server dropped only the cut one).
#   cut.py server CERTDIR          a TLS server for our client: prints "READY PORT",
#       accepts one connection, completes the handshake, reads one request, sends the
#       first half of its answer's record and closes (FIN); then a second connection,
#       served whole (the client's next connect works). Exits after the second.
#
# Prints "PASS name" / "FAIL name: why" (clients mode).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import socket
import ssl
import struct
import sys
import time


def read_request(tid, address):
    """FC 03, one register: the MBAP header, unit 1."""
    return struct.pack(">HHHBBHH", tid, 0, 6, 1, 3, address, 1)


class Tls:
    """One TLS connection over a plain socket, through memory BIOs."""

    def __init__(self, sock, context, server_side, hostname=None):
        self.sock = sock
        self.inc, self.out = ssl.MemoryBIO(), ssl.MemoryBIO()
        self.obj = context.wrap_bio(self.inc, self.out, server_side=server_side, server_hostname=hostname)

    def flush(self):
        data = self.out.read()
        if data:
            self.sock.sendall(data)

    def pump(self):
        data = self.sock.recv(65536)
        if not data:
            raise ConnectionError("peer closed")
        self.inc.write(data)

    def handshake(self):
        while True:
            try:
                self.obj.do_handshake()
                self.flush()
                return
            except ssl.SSLWantReadError:
                self.flush()
                self.pump()

    def record(self, plaintext):
        """The encrypted bytes of `plaintext`, one record, not sent."""
        self.obj.write(plaintext)
        return self.out.read()

    def read(self, n):
        got = b""
        while len(got) < n:
            try:
                got += self.obj.read(n - len(got))
            except ssl.SSLWantReadError:
                self.flush()
                self.pump()
        return got


def client_context(certs):
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.load_verify_locations(f"{certs}/ca.pem")
    ctx.load_cert_chain(f"{certs}/operator.pem", f"{certs}/operator.key")
    return ctx


def clients(port, certs):
    ctx = client_context(certs)
    failures = 0

    def check(ok, name, why=""):
        nonlocal failures
        print(f"PASS {name}" if ok else f"FAIL {name}: {why}", flush=True)
        failures += not ok

    def served(after):
        """A normal client reads register 5 (1005)."""
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
                t = Tls(s, ctx, False, "127.0.0.1")
                t.handshake()
                s.sendall(t.record(read_request(7, 5)))
                answer = struct.unpack(">HHHBBBH", t.read(11))
            check(answer[0] == 7 and answer[6] == 1005, f"a client is served after {after}", str(answer))
        except OSError as e:
            check(False, f"a client is served after {after}", repr(e))

    for how in ("FIN", "RST"):
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        t = Tls(s, ctx, False, "127.0.0.1")
        t.handshake()
        record = t.record(read_request(1, 1))
        s.sendall(record[: len(record) // 2])
        if how == "RST":
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        else:
            # A FIN: a close with unread data (the server's session tickets) would
            # send a reset instead.
            s.shutdown(socket.SHUT_WR)
            time.sleep(0.2)
        s.close()
        served(f"half a request's record and {how}")
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    t = Tls(s, ctx, False, "127.0.0.1")
    t.handshake()
    s.sendall(t.record(read_request(2, 2)))
    answer = struct.unpack(">HHHBBBH", t.read(11))
    check(answer[0] == 2 and answer[6] == 1002, "a whole request answered before the cut", str(answer))
    s.shutdown(socket.SHUT_WR)  # FIN, no close_notify
    time.sleep(0.2)
    s.close()
    served("a client that left without close_notify")
    return 1 if failures else 0


def server(certs):
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(f"{certs}/server.pem", f"{certs}/server.key")
    ctx.load_verify_locations(f"{certs}/ca.pem")
    ctx.verify_mode = ssl.CERT_REQUIRED
    ls = socket.socket()
    ls.bind(("127.0.0.1", 0))
    ls.listen(2)
    print(f"READY {ls.getsockname()[1]}", flush=True)
    for cut in (True, False):
        s, _ = ls.accept()
        s.settimeout(10)
        t = Tls(s, ctx, True)
        t.handshake()
        req = t.read(12)
        tid, _, _, unit, fc, address, nb = struct.unpack(">HHHBBHH", req)
        answer = struct.pack(">HHHBBBH", tid, 0, 5, unit, fc, 2, 1000 + address)
        record = t.record(answer)
        if cut:
            s.sendall(record[: len(record) // 2])
        else:
            s.sendall(record)
            try:
                t.read(1)  # until the client goes away
            except (ConnectionError, ssl.SSLError, OSError):
                pass
        s.close()
    ls.close()
    return 0


if __name__ == "__main__":
    if sys.argv[1] == "clients":
        sys.exit(clients(int(sys.argv[2]), sys.argv[3]))
    sys.exit(server(sys.argv[2]))
