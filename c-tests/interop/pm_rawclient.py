#!/usr/bin/env python3
# A byte-level RTU-over-TCP client for what pymodbus's RTU framer cannot send and read
# back: Diagnostics 08/00 (Return Query Data) with 1, 3, 10 and 60 data words, whose
# answer must be the request itself. Then a read of holding register 0 must still work
# (the server found the frame boundaries again).
#
# usage: pm_rawclient.py PORT [--host ADDR]   prints TX:/RX: lines, ok/FAIL lines and
# "N passed, M failed"
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import argparse
import os
import socket
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import pm_model as M  # noqa: E402


def crc16(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def frame(pdu):
    f = bytes([M.SLAVE]) + pdu
    return f + crc16(f)


def exchange(s, req, timeout=1.0):
    print("TX: " + M.hexs(req), flush=True)
    try:
        s.sendall(req)
    except OSError as e:
        print("send: %s" % e, flush=True)
        return b""
    s.settimeout(timeout)
    got = b""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            chunk = s.recv(512)
        except socket.timeout:
            break
        if not chunk:
            break
        got += chunk
        s.settimeout(0.1)  # the rest of the answer, if split
    print("RX: " + M.hexs(got), flush=True)
    return got


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("port", type=int)
    ap.add_argument("--host", default="127.0.0.1")
    a = ap.parse_args()
    passed = failed = 0
    s = socket.create_connection((a.host, a.port))
    for words in (1, 3, 10, 60):
        data = b"".join(((0x0101 * (i + 1)) & 0xFFFF).to_bytes(2, "big") for i in range(words))
        req = frame(b"\x08\x00\x00" + data)
        got = exchange(s, req)
        name = "08/00 return query data, %d words, over RTU framing" % words
        if got == req:
            passed += 1
            print("ok   - " + name, flush=True)
        else:
            failed += 1
            print("FAIL - %s: sent %s, got %s" % (name, M.hexs(req), M.hexs(got) or "nothing"), flush=True)
        time.sleep(0.1)
    want = frame(b"\x03\x02" + M.holding(0).to_bytes(2, "big"))
    got = exchange(s, frame(b"\x03\x00\x00\x00\x01"))
    if got == want:
        passed += 1
        print("ok   - read_holding_registers(0, 1) afterwards", flush=True)
    else:
        failed += 1
        print("FAIL - read_holding_registers(0, 1) afterwards: got %s" % M.hexs(got), flush=True)
    s.close()
    print("%d passed, %d failed" % (passed, failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
