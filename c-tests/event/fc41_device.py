#!/usr/bin/env python3
# A device with a user-defined function code, for c-tests/suites/event.sh and
# c-tests/suites/gateway.sh (event-test fc41):
#   fc41_device.py rtu DEVICE      RTU on DEVICE (one end of a pty pair), 115200 8N1
#   fc41_device.py ascii DEVICE    Modbus ASCII on DEVICE
#   fc41_device.py tcp             Modbus/TCP (MBAP) on 127.0.0.1, a port the kernel picks
#   fc41_device.py rtutcp          RTU framing over TCP, the same
# Every request for function code 0x41, whatever its unit and data, is answered with
# the PDU 41 01 02 03 04 05 06 07 08 (function code 0x41 and 8 data bytes: 9 bytes),
# behind the request's unit id (and MBAP header: its transaction id, protocol 0,
# length 10), with its CRC (RTU) or LRC (ASCII), in one write. Other requests get no
# answer. No libmodbus here: the bytes are the test's.
# Prints "READY" (serial) or "READY <port>" (TCP), then one line per request seen;
# ends on SIGTERM.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import os
import select
import signal
import socket
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "common"))
from mbframe import crc_ok, lrc, open_raw, read_rtu_frame, rtu  # noqa: E402

PDU = bytes([0x41, 1, 2, 3, 4, 5, 6, 7, 8])


def ascii_frame(body):
    return (":" + (body + bytes([lrc(body)])).hex().upper() + "\r\n").encode()


def log(text):
    print(text, flush=True)


def serial(mode, path):
    fd = open_raw(path)
    log("READY")
    buf = b""
    while True:
        if mode == "rtu":
            # A frame ends with 5 ms of silence.
            req = read_rtu_frame(fd)
            if not crc_ok(req):
                log("rtu: garbage of %d bytes" % len(req))
                continue
            body = req[:-2]
        else:
            select.select([fd], [], [])
            buf += os.read(fd, 1024)
            if b"\n" not in buf:
                continue
            line, buf = buf.split(b"\n", 1)
            line = line.strip()
            try:
                raw = bytes.fromhex(line[1:].decode())
            except ValueError:
                log("ascii: garbage %r" % line)
                continue
            if not line.startswith(b":") or len(raw) < 3 or lrc(raw[:-1]) != raw[-1]:
                log("ascii: bad frame %r" % line)
                continue
            body = raw[:-1]
        log("%s: unit %d fc 0x%02X, %d bytes" % (mode, body[0], body[1], len(body)))
        if body[1] != 0x41:
            continue
        answer = bytes([body[0]]) + PDU
        os.write(fd, rtu(answer) if mode == "rtu" else ascii_frame(answer))


def tcp(mode):
    ls = socket.socket()
    ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    ls.bind(("127.0.0.1", 0))
    ls.listen(8)
    log("READY %d" % ls.getsockname()[1])
    clients = {}
    while True:
        r, _, _ = select.select([ls] + list(clients), [], [])
        for s in r:
            if s is ls:
                c, _ = ls.accept()
                c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                clients[c] = b""
                continue
            data = s.recv(1024)
            if not data:
                del clients[s]
                s.close()
                continue
            buf = clients[s] + data
            while True:
                if mode == "tcp":
                    if len(buf) < 7 or len(buf) < 6 + ((buf[4] << 8) | buf[5]):
                        break
                    n = 6 + ((buf[4] << 8) | buf[5])
                    req, buf = buf[:n], buf[n:]
                    unit, fc = req[6], req[7]
                    answer = req[:4] + bytes([0, 1 + len(PDU), unit]) + PDU
                else:
                    # RTU framing over TCP: the shortest prefix with a right CRC.
                    ends = (k for k in range(4, len(buf) + 1) if crc_ok(buf[:k]))
                    n = next(ends, 0)
                    if n == 0:
                        break
                    req, buf = buf[:n], buf[n:]
                    unit, fc = req[0], req[1]
                    answer = rtu(bytes([unit]) + PDU)
                log("%s: unit %d fc 0x%02X, %d bytes" % (mode, unit, fc, len(req)))
                if fc == 0x41:
                    s.sendall(answer)
            clients[s] = buf


def main():
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    mode = sys.argv[1]
    if mode in ("rtu", "ascii"):
        serial(mode, sys.argv[2])
    else:
        tcp(mode)


main()
