#!/usr/bin/env python3
# A raw RTU-over-TCP peer that sends every request back unchanged (a valid answer to
# Diagnostics 08/00, Return Query Data, whatever its length). pymodbus 3.16.1's RTU
# framer takes every FC 08 frame for 8 bytes, so it cannot check our client with more
# than one data word; this byte-level peer does.
#
# usage: pm_echo.py PORT [--timeout SECS]   prints READY, then RX:/TX: lines
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import argparse
import os
import select
import socket
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import pm_model as M  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("port", type=int)
ap.add_argument("--timeout", type=float, default=30.0)
a = ap.parse_args()
srv = socket.socket()
srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
srv.bind(("127.0.0.1", a.port))
srv.listen(1)
srv.settimeout(a.timeout)
print("READY", flush=True)
conn, _ = srv.accept()
while True:
    r, _, _ = select.select([conn], [], [], a.timeout)
    if not r:
        break
    data = conn.recv(512)
    if not data:
        break
    # the rest of the frame, if it comes in pieces: wait for 50 ms of silence
    while select.select([conn], [], [], 0.05)[0]:
        more = conn.recv(512)
        if not more:
            break
        data += more
    print("RX: " + M.hexs(data), flush=True)
    conn.sendall(data)
    print("TX: " + M.hexs(data), flush=True)
