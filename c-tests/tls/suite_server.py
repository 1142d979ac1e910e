#!/usr/bin/env python3
"""suite_server.py CERTS VERSION [CIPHER]: a Modbus/TCP Security server of Python's ssl
(OpenSSL) for one client: TLS VERSION (1.2 with the OpenSSL cipher CIPHER, or 1.3, whose
session tickets OpenSSL sends after the handshake), the client's certificate required.
Register A holds A; a write of one register is echoed. Prints its port, then, at the
client's end, the version and suite it served and the requests it answered."""
# SPDX-License-Identifier: MIT OR Apache-2.0
import socket
import ssl
import struct
import sys

certs, version = sys.argv[1], sys.argv[2]
ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
if version == "1.2":
    ctx.maximum_version = ssl.TLSVersion.TLSv1_2
    ctx.set_ciphers(sys.argv[3])
else:
    ctx.minimum_version = ssl.TLSVersion.TLSv1_3
ctx.load_cert_chain(f"{certs}/server.pem", f"{certs}/server.key")
ctx.load_verify_locations(f"{certs}/ca.pem")
ctx.verify_mode = ssl.CERT_REQUIRED
listener = socket.create_server(("127.0.0.1", 0))
print(listener.getsockname()[1], flush=True)
listener.settimeout(20)
conn, _ = listener.accept()
conn.settimeout(20)
s = ctx.wrap_socket(conn, server_side=True)
served, held = 0, b""
while True:
    try:
        data = s.recv(4096)
    except (ssl.SSLError, OSError):
        break
    if not data:
        break
    held += data
    while len(held) >= 12:
        tid, _, _, unit, fc, addr, n = struct.unpack(">HHHBBHH", held[:12])
        if fc == 3:
            s.sendall(struct.pack(">HHHBBB", tid, 0, 3 + 2 * n, unit, fc, 2 * n)
                      + b"".join(struct.pack(">H", addr + i) for i in range(n)))
        else:
            s.sendall(held[:12])
        held = held[12:]
        served += 1
print(f"served {s.version()} {s.cipher()[0]}: {served} requests", flush=True)
