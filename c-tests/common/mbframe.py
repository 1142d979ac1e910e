"""Modbus serial frames for the test programs that play a device
(c-tests/event/fc41_device.py, c-tests/gateway/fake_device.py): CRC-16 (RTU) and LRC
(ASCII), written from the specification's description; the pty they answer on, and
an RTU frame read up to its silence.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import os
import select
import termios
import tty


def crc16(data):
    """CRC-16/MODBUS of `data` (initial 0xFFFF, reflected polynomial 0xA001)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def rtu(body):
    """`body` (unit and PDU) with its CRC, low byte first."""
    c = crc16(body)
    return body + bytes([c & 0xFF, c >> 8])


def crc_ok(frame):
    """An RTU frame whose last two bytes are the CRC of the rest."""
    return len(frame) >= 4 and crc16(frame[:-2]) == frame[-2] | (frame[-1] << 8)


def lrc(body):
    """The LRC of an ASCII frame's bytes: the two's complement of their sum."""
    return (-sum(body)) & 0xFF


def open_raw(path):
    """`path` (a pty) opened raw at 115200 baud."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    attrs = termios.tcgetattr(fd)
    attrs[4] = attrs[5] = termios.B115200
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    return fd


def read_rtu_frame(fd, silence=0.005):
    """The bytes of the next RTU frame on `fd`: waits for the first, then reads until
    the line is quiet for `silence` seconds."""
    select.select([fd], [], [])
    frame = b""
    while True:
        r, _, _ = select.select([fd], [], [], silence)
        if not r:
            return frame
        frame += os.read(fd, 256)
