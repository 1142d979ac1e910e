# The data both sides of the interoperability tests agree on (the C programs compute
# the same values from the same formulas: keep in step with interop.h).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
"""Shared test data model for the pymodbus interoperability tests."""

SLAVE = 17
SIZE = 200  # addresses 0..199 of every table


def coil(i):
    return i % 3 == 0


def discrete(i):
    return i % 4 == 1


def holding(i):
    return (0x1000 + i * 0x0101) & 0xFFFF


def input_reg(i):
    return (0x8000 + i * 7) & 0xFFFF


# FC 07
EXCEPTION_STATUS = 0xA5

# FC 08 counters (sub-functions 0x0B..0x12 in this order)
COUNTERS = {
    0x0B: 0x0102,  # bus message
    0x0C: 3,  # bus communication error (CRC)
    0x0D: 4,  # bus exception error
    0x0E: 5,  # server (device) message
    0x0F: 6,  # no response
    0x10: 7,  # NAK
    0x11: 8,  # busy
    0x12: 9,  # bus character overrun
}

# FC 0B / 0C
EVENT_COUNT = 0x0A0B
EVENTS = bytes([0x00, 0x04, 0xC0, 0x42, 0x81])  # newest first

# FC 14 / 15: a file is a sequence of registers, the record number is the index
FILES = (1, 2, 3)


def file_reg(file, record):
    return (file * 0x1000 + record * 3) & 0xFFFF


# FC 18: pointer address -> queue
FIFOS = {
    0x04DE: [0x01B8, 0x1284],
    0x0005: [(i * 11) & 0xFFFF for i in range(31)],
    0x0006: [],
}

# FC 2B / 0E: 0..2 basic, 3..6 regular, 0x80.. extended (enough to need "more follows")
DEVICE_ID = {
    0x00: "rsmodbus-interop",
    0x01: "PM-3",
    0x02: "V3.16",
    0x03: "http://localhost/",
    0x04: "interop-device",
    0x05: "model-5",
    0x06: "pymodbus-peer",
}
for _k in range(16):
    DEVICE_ID[0x80 + _k] = "extended-object-%02d-xxxxxxxx" % _k


def hexs(data):
    return " ".join("%02X" % b for b in data)
