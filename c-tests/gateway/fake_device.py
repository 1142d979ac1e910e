#!/usr/bin/env python3
# A serial Modbus RTU line with misbehaving devices, for c-tests/suites/gateway.sh:
#   fake_device.py DEVICE
# reads request frames (ended by 5 ms of silence) from DEVICE (one end of a pty pair)
# and answers FC 03 (holding register i holds 3 * i) as:
#   unit 1: rightly
#   unit 6: with a wrong CRC, every time
#   unit 8: with garbage (bytes that are no frame)
#   any other unit: not at all
# and FC 0x64 (user-defined) of unit 1 with the PDU 64 followed by 250 bytes (byte i:
# 7 * i + 3, modulo 256; no shorter prefix of the frame has a right CRC).
# Prints READY, then one line per request it saw; counts on SIGTERM.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import os
import signal
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "common"))
from mbframe import crc_ok, open_raw, read_rtu_frame  # noqa: E402
from mbframe import rtu as frame  # noqa: E402


def main():
    fd = open_raw(sys.argv[1])
    seen = {"requests": 0}

    def done(*_):
        print("fake device: %(requests)d requests" % seen, flush=True)
        sys.exit(0)

    signal.signal(signal.SIGTERM, done)
    print("READY", flush=True)
    while True:
        req = read_rtu_frame(fd)
        if not crc_ok(req):
            print("garbage of %d bytes" % len(req), flush=True)
            continue
        seen["requests"] += 1
        unit, fc = req[0], req[1]
        print("unit %d fc %d" % (unit, fc), flush=True)
        if fc == 0x64 and unit == 1:
            os.write(fd, frame(bytes([1, 0x64]) + bytes((i * 7 + 3) & 0xFF for i in range(250))))
            continue
        if fc != 3 or unit not in (1, 6, 8):
            continue
        addr = (req[2] << 8) | req[3]
        nb = (req[4] << 8) | req[5]
        body = bytes([unit, 3, 2 * nb]) + b"".join(((3 * (addr + i)) & 0xFFFF).to_bytes(2, "big") for i in range(nb))
        if unit == 1:
            os.write(fd, frame(body))
        elif unit == 6:
            bad = bytearray(frame(body))
            bad[-1] ^= 0x55
            os.write(fd, bytes(bad))
        else:
            os.write(fd, bytes([0x00, 0xFF, 0x13, 0x37, 0x00]))


main()
