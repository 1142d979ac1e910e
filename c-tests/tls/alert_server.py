#!/usr/bin/env python3
"""alert_server.py: a TLS 1.2 server that refuses the client's certificate while the
client is still writing its flight (issue 39, item 12), for c-tests/suites/tls.sh.

    alert_server.py CERTDIR PORT N

For each of N connections: the handshake runs through Python's ssl module over
memory buffers (so that this program decides what is read from the socket), up to
the server's flight (ServerHello .. ServerHelloDone, with a CertificateRequest). From
then on nothing more is read: the client's flight (its Certificate, made several
megabytes long by the test's certificate chain, then the rest) fills the server's small
receive window and the client's send buffer, so the client is blocked in the middle
of writing it. The server then sends a fatal unknown_ca alert (a plaintext record:
no ChangeCipherSpec yet) and closes with the client's bytes unread, which resets the
connection (RST). The client's next write fails (ECONNRESET or EPIPE) before it has
read anything after the server's flight: it must still report the alert
(EMBTLSUNKNOWNCA), which is waiting in its receive queue.

Prints "READY PORT" once listening, one "# connection I: ..." line per client.
SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import select
import socket
import ssl
import sys
import time

# TLS 1.2 record: alert (21), version 3.3, length 2: fatal (2), unknown_ca (48).
ALERT_UNKNOWN_CA = bytes([21, 3, 3, 0, 2, 2, 48])


def serve_one(ctx, listener, i):
    conn, _ = listener.accept()
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    tls = ctx.wrap_bio(incoming, outgoing, server_side=True)
    flight = b""
    deadline = time.monotonic() + 10
    # The ClientHello, until the server has its flight to send.
    while not flight and time.monotonic() < deadline:
        r, _, _ = select.select([conn], [], [], 1)
        if not r:
            continue
        data = conn.recv(16384)
        if not data:
            print(f"# connection {i}: closed before its hello", flush=True)
            conn.close()
            return
        incoming.write(data)
        try:
            tls.do_handshake()
        except ssl.SSLWantReadError:
            pass
        flight = outgoing.read()
    conn.sendall(flight)
    # The client's flight starts to arrive; it is never read.
    r, _, _ = select.select([conn], [], [], 10)
    arrived = bool(r)
    # Long enough for the client to fill both buffers and wait for room.
    time.sleep(0.3)
    conn.sendall(ALERT_UNKNOWN_CA)
    conn.close()  # unread bytes: the kernel resets the connection
    print(f"# connection {i}: flight sent, client's flight {'arriving' if arrived else 'NOT seen'}, "
          "alert sent, reset", flush=True)


def main():
    certs, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.maximum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_cert_chain(os.path.join(certs, "server.pem"), os.path.join(certs, "server.key"))
    ctx.load_verify_locations(os.path.join(certs, "ca.pem"))
    ctx.verify_mode = ssl.CERT_REQUIRED
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # Accepted sockets inherit it: a small window the client's flight soon fills.
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    listener.bind(("127.0.0.1", port))
    listener.listen(4)
    print(f"READY {port}", flush=True)
    for i in range(n):
        serve_one(ctx, listener, i)
    listener.close()


if __name__ == "__main__":
    main()
