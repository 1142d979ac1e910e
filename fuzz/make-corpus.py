#!/usr/bin/env python3
"""Writes the seed corpus of every fuzz target into fuzz/corpus/<target>/.

The well-formed frames are the worked examples of the seed documents
(shared/seeds/004_*.txt: the classic slave-17 request/response pairs of FC 01, 02,
03, 04, 05, 06, 0F, 10; the other FCs from the same family of examples), re-framed
for RTU (with CRC) and TCP (MBAP). The malformed frames are the classes of the
libmodbus CVEs and bugs (reference section 3.12) and of the server issue:
CVE-2019-14462/14463 (quantity vs byte count), CVE-2022-0367 (FC 17 write address
below the mapping start), CVE-2024-10918 (req_length lies for FC 05/06/16), #837
(1-byte PDUs with a short req_length), counts 0 and max+1, unknown and >= 0x80
function codes, oversized byte counts, lying MBAP lengths and protocol ids.

Each target's input layout is documented in fuzz/src/lib.rs and fuzz/src/ffi.rs.
Run: python3 fuzz/make-corpus.py   (idempotent; file names are content hashes)

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import hashlib
import os
import struct

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


def crc16(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def rtu(slave, pdu):
    f = bytes([slave]) + bytes(pdu)
    return f + struct.pack("<H", crc16(f))


def tcp(tid, unit, pdu, length=None, proto=0):
    pdu = bytes(pdu)
    if length is None:
        length = len(pdu) + 1
    return struct.pack(">HHHB", tid, proto, length, unit) + pdu


def lrc(data):
    return (-sum(data)) & 0xFF


def ascii_frame(slave, pdu):
    b = bytes([slave]) + bytes(pdu)
    b += bytes([lrc(b)])
    return b":" + b.hex().upper().encode() + b"\r\n"


def h(s):
    return bytes.fromhex(s.replace(" ", ""))


# Worked examples of the seed document (slave 0x11): (request PDU, response PDU).
EXAMPLES = [
    (h("01 0013 0025"), h("01 05 CD6BB20E1B")),
    (h("02 00C4 0016"), h("02 03 ACDB35")),
    (h("03 006B 0003"), h("03 06 AE41 5652 4340")),
    (h("04 0008 0001"), h("04 02 000A")),
    (h("05 00AC FF00"), h("05 00AC FF00")),
    (h("06 0001 0003"), h("06 0001 0003")),
    (h("0F 0013 000A 02 CD01"), h("0F 0013 000A")),
    (h("10 0001 0002 04 000A 0102"), h("10 0001 0002")),
    (h("11"), h("11 0B B4 FF 4C4D42 332E312E3132")),
    (h("16 0004 00F2 0025"), h("16 0004 00F2 0025")),
    (h("17 0003 0006 000E 0003 06 00FF 00FF 00FF"), h("17 0C 00FE 0ACD 0001 0003 000D 00FF")),
]

# Malformed or hostile requests (PDUs), by class.
HOSTILE = [
    h("0F 0000 07B0 01 FF"),               # CVE-2019-14462: 1968 coils, 1 byte
    h("0F 0000 07B0 06 FFFFFFFFFFFF"),     # the unit test's variant
    h("10 0000 007B 06 000100020003"),     # CVE-2019-14463: 123 regs, 6 bytes
    h("10 0000 0002 03 000100"),           # odd byte count
    h("17 0000 0001 FFF0 0001 02 BEEF"),   # CVE-2022-0367: write below/above start
    h("17 0100 0001 0000 0001 02 BEEF"),
    h("17 0000 0000 0000 0001 02 0001"),   # read 0
    h("17 0000 007E 0000 0001 02 0001"),   # read 126
    h("17 0000 0001 0000 0000 00"),        # write 0
    h("17 0000 0001 0000 007C F8") + bytes(248),  # write 124
    h("01 0000 0000"), h("01 0000 07D1"),  # counts 0 and 2001
    h("02 0000 0000"), h("02 0000 07D1"),
    h("03 0000 0000"), h("03 0000 007E"),
    h("04 0000 0000"), h("04 0000 007E"),
    h("10 0000 0000 00"), h("10 0000 007C F8") + bytes(248),
    h("0F 0000 0000 00"), h("0F 0000 07B1 F7") + bytes(247),
    h("05 0000 1234"),                     # illegal coil value
    h("05 FFFF FF00"), h("06 FFFF 0001"), h("16 FFFF 00F2 0025"),
    h("07"), h("11"), h("08 0000 A537"), h("2B 0E 01 00"), h("42"), h("83 0000 0001"), h("00"),
    h("14 0E 06 0003 0004 0000 0002"),
    h("10 0000 0002 FF") + bytes(255),     # byte count beyond the ADU
]

SERVER_CONFIGS = [
    # starts (bits, input bits, regs, input regs), bit size, reg size, req_length mode, flags
    bytes([0, 0, 0, 0, 0xFF, 0xFF, 0, 0]),
    bytes([0x52, 0x5A, 0x54, 0x4F, 5, 4, 0, 0]),        # unit-test-like start offsets
    bytes([0x41, 0x41, 0x41, 0x41, 0xFE, 0xFD, 0, 0x02]),  # bytes one at a time
    bytes([0, 0, 0x8F, 0, 0x10, 0x10, 0x80, 0x80]),     # req_length -1, reply on bad CRC
    bytes([0, 0, 0, 0, 0xFF, 0xFF, 0xC2, 0x01]),        # req_length + 2 (CVE-2024-10918)
    bytes([0, 0, 0, 0, 0xFF, 0xFF, 0xA0, 0x31]),        # req_length far too short, any slave
    bytes([0xC1, 0xC4, 0xC2, 0xC0, 0x20, 0x20, 0, 0]),  # odd C ints as starts
]

FFI_SERVER_CONFIGS = [
    # flags (bits 0-1: TCP, RTU, ASCII; bit 2: quirk broadcast), starts x4, bits, regs, slave, mode
    bytes([0, 0, 0, 0, 0, 0xFF, 0xFF, 0, 0]),
    bytes([1, 0, 0, 0, 0, 0xFF, 0xFF, 0, 0]),
    bytes([2, 0, 0, 0, 0, 0xFF, 0xFF, 0, 0]),
    bytes([0, 0x52, 0x5A, 0x54, 0x4F, 5, 4, 0, 0]),
    bytes([1, 0x52, 0x5A, 0x54, 0x4F, 5, 4, 0, 0x80]),
    bytes([6, 0, 0, 0x8F, 0, 0x10, 0x10, 0x30, 0xC2]),
]


def framed(kind, tid, slave, pdu):
    if kind == 0:
        return tcp(tid, slave, pdu)
    if kind == 1:
        return rtu(slave, pdu)
    return ascii_frame(slave, pdu)

CLIENT_SELECTOR = {fc: i for i, fc in enumerate([1, 2, 3, 4, 5, 6, 0x0F, 0x10, 0x11, 0x16, 0x17])}


def client_call(fc, addr, nb, value=0):
    """[selector][addr 2][nb 2][value 2] so that ClientCall::from gives fc, addr, nb."""
    if fc in (1, 2):
        raw = nb - 1
    elif fc in (3, 4, 0x0F, 0x10):
        raw = nb - 1
    elif fc == 0x17:
        raw = ((nb[0] + 1) << 8) | (nb[1] - 1)
    else:
        raw = 0
    return bytes([CLIENT_SELECTOR[fc]]) + struct.pack(">HHH", addr, raw, value)


written = {}


def put(target, data, tag):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    name = tag + "-" + hashlib.sha1(data).hexdigest()[:12]
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)
    written[target] = written.get(target, 0) + 1


def main():
    requests = [(f"ex{i:02d}", req) for i, (req, _) in enumerate(EXAMPLES)]
    requests += [(f"bad{i:02d}", pdu) for i, pdu in enumerate(HOSTILE)]
    # Server targets: one request per file under each config, plus streams.
    for ci, cfg in enumerate(SERVER_CONFIGS):
        for tag, pdu in requests:
            put("server_rtu", cfg + rtu(0x11, pdu), f"c{ci}-{tag}")
            put("server_tcp", cfg + tcp(0x1234, 0xFF, pdu), f"c{ci}-{tag}")
            put("server_ascii", cfg + ascii_frame(0x11, pdu), f"c{ci}-{tag}")
        stream_rtu = b"".join(rtu(0x11, req) for req, _ in EXAMPLES)
        stream_tcp = b"".join(tcp(i, 1, req) for i, (req, _) in enumerate(EXAMPLES))
        stream_ascii = b"".join(ascii_frame(0x11, req) for req, _ in EXAMPLES)
        put("server_rtu", cfg + stream_rtu, f"c{ci}-stream")
        put("server_tcp", cfg + stream_tcp, f"c{ci}-stream")
        put("server_ascii", cfg + stream_ascii, f"c{ci}-stream")
    # ASCII specifics: noise before ':', lower-case digits, a restart, odd digits,
    # CR without LF, a frame too long, a bad LRC, broadcast.
    cfg = SERVER_CONFIGS[0]
    good = ascii_frame(0x11, h("03 0000 0002"))
    put("server_ascii", cfg + b"xx\r\n" + good, "noise")
    put("server_ascii", cfg + good.lower().replace(b"\r\n", b"\r\n"), "lower-case")
    put("server_ascii", cfg + b":1103" + good, "restart")
    put("server_ascii", cfg + b":110300000\r\n" + good, "odd-digits")
    put("server_ascii", cfg + b":11030000000200\rX" + good, "cr-without-lf")
    put("server_ascii", cfg + b":" + b"11" * 300 + b"\r\n" + good, "too-long")
    put("server_ascii", cfg + good[:-4] + b"00\r\n", "bad-lrc")
    put("server_ascii", cfg + ascii_frame(0, h("06 0001 0003")), "broadcast")
    put("server_ascii", cfg + b":\r\n:11\r\n" + good, "short-frames")
    # RTU specifics: broadcast, another slave, bad CRC; TCP: lying MBAP header.
    cfg = SERVER_CONFIGS[0]
    put("server_rtu", cfg + rtu(0, h("06 0001 0003")), "broadcast")
    put("server_rtu", bytes([0, 0, 0, 0, 0xFF, 0xFF, 0, 1]) + rtu(0, h("06 0001 0003")), "broadcast-quirk")
    put("server_rtu", cfg + rtu(0x12, h("03 0000 0001")) + rtu(0x11, h("03 0000 0001")), "other-slave")
    put("server_rtu", cfg + rtu(0x11, h("03 0000 0001"))[:-1] + b"\x00", "bad-crc")
    put("server_tcp", cfg + tcp(1, 1, h("03 0000 0001"), length=99), "mbap-length-99")
    put("server_tcp", cfg + tcp(1, 1, h("03 0000 0001"), proto=5), "protocol-5")
    put("server_tcp", cfg + tcp(1, 0, h("05 0001 FF00")), "unit-0")

    # Client targets: config, then the response (raw), or structured mode.
    for i, (req, rsp) in enumerate(EXAMPLES):
        fc = req[0]
        if fc in (1, 2, 3, 4):
            addr, nb = struct.unpack(">HH", req[1:5])
            call = client_call(fc, addr, nb)
        elif fc in (0x0F, 0x10):
            addr, nb = struct.unpack(">HH", req[1:5])
            call = client_call(fc, addr, nb, 0)
        elif fc in (5, 6, 0x16):
            addr, val = struct.unpack(">HH", req[1:5])
            call = client_call(fc, addr, 1, val)
        elif fc == 0x17:
            call = client_call(fc, 0x03, (3, 6))
        else:
            call = client_call(fc, 0, 1)
        for mode in (0x00, 0x01, 0x03, 0x11):
            tail = b"" if mode & 1 else None
            put("client_ascii", call + bytes([0x11]) + struct.pack(">H", 0) + bytes([mode]) + (tail if tail is not None else ascii_frame(0x11, rsp)), f"ex{i:02d}-m{mode:02x}")
            put("client_rtu", call + bytes([0x11]) + struct.pack(">H", 0) + bytes([mode]) + (tail if tail is not None else rtu(0x11, rsp)), f"ex{i:02d}-m{mode:02x}")
            put("client_tcp", call + bytes([0x11]) + struct.pack(">H", 7) + bytes([mode]) + (tail if tail is not None else tcp(7, 0x11, rsp)), f"ex{i:02d}-m{mode:02x}")
        # Structured with edits: truncate, wrong byte count, bad CRC, extra bytes.
        for j, ops in enumerate([h("03 05 00"), h("00 02 FF 05 00 00"), h("04 03 01"), h("06 07 AA"), h("00 07 12 05 00 00")]):
            put("client_rtu", call + bytes([0x11, 0, 0, 0x01]) + ops, f"ex{i:02d}-ops{j}")
            put("client_tcp", call + bytes([0x11, 0, 7, 0x01]) + ops, f"ex{i:02d}-ops{j}")
            put("client_ascii", call + bytes([0x11, 0, 0, 0x01]) + ops, f"ex{i:02d}-ops{j}")
    # Hostile responses to a read of 3 registers.
    call = client_call(3, 0x6B, 3)
    for j, pdu in enumerate([h("83 02"), h("83 00"), h("83 0C"), h("83 FF"), h("84 02"), h("83 02 00"),
                             h("03 FF") + bytes(255), h("03 04 0000 0000"), h("04 06 AE41 5652 4340"),
                             h("03 06 AE41 5652")]):
        put("client_rtu", call + bytes([0x11, 0, 0, 0]) + rtu(0x11, pdu), f"hostile{j:02d}")
        put("client_tcp", call + bytes([0x11, 0, 7, 0]) + tcp(7, 0x11, pdu), f"hostile{j:02d}")
        put("client_ascii", call + bytes([0x11, 0, 0, 0]) + ascii_frame(0x11, pdu), f"hostile{j:02d}")
    put("client_rtu", call + bytes([0x11, 0, 0, 0]) + rtu(0x12, h("03 06 AE41 5652 4340")), "other-slave")
    put("client_tcp", call + bytes([0x11, 0, 7, 0]) + tcp(8, 0x11, h("03 06 AE41 5652 4340")), "wrong-tid")
    put("client_tcp", call + bytes([0x11, 0, 7, 0]) + tcp(7, 0x11, h("03 06 AE41 5652 4340"), proto=1), "protocol-1")

    # The function codes rsmodbus adds (selectors 11-18): spec-style answers.
    EXT = [
        (11, 0, 1, 0, h("07 6D")),
        (12, 0, 1, 0, h("08 0000 A537")),
        (13, 0, 1, 0, h("0B FFFF 0108")),
        (14, 0, 1, 0, h("0C 08 0000 0108 0121 2000")),
        (15, 4, 2, 1, h("14 06 05 06 0DFE 0020")),
        (16, 4, 3, 7, h("15 0D 06 0004 0007 0003 06AF 04BE 100D")),
        (17, 0x04DE, 1, 0, h("18 0006 0002 01B8 1284")),
        (18, 0, 1, 0x0001, h("2B 0E 01 01 00 00 03 00 16") + b"Company identification"
         + h("01 0D") + b"Product code " + h("02 05") + b"V2.11"),
    ]
    for sel, addr, raw_nb, value, pdu in EXT:
        call = bytes([sel]) + struct.pack(">HHH", addr, raw_nb, value)
        put("client_rtu", call + bytes([0x11, 0, 0, 0]) + rtu(0x11, pdu), f"ext{sel}")
        put("client_tcp", call + bytes([0x11, 0, 7, 0]) + tcp(7, 0x11, pdu), f"ext{sel}")
        put("client_ascii", call + bytes([0x11, 0, 0, 0]) + ascii_frame(0x11, pdu), f"ext{sel}")
        for kind in (0, 1, 2):
            put("ffi_client", bytes([kind]) + call + bytes([0x11, 0]) + framed(kind, 1, 0x11, pdu), f"ext{sel}-{kind}")

    # FFI server: streams of requests, hostile ones among them.
    for ci, cfg in enumerate(FFI_SERVER_CONFIGS):
        kind = cfg[0] & 3
        frames = [framed(kind, i, 0x11, req) for i, (req, _) in enumerate(EXAMPLES)]
        put("ffi_server", cfg + b"".join(frames), f"c{ci}-examples")
        for k in range(0, len(HOSTILE), 6):
            chunk = HOSTILE[k:k + 6]
            frames = [framed(kind, k + i, 0x11, p) for i, p in enumerate(chunk)]
            put("ffi_server", cfg + b"".join(frames), f"c{ci}-hostile{k:02d}")

    # FFI client: correct responses (structured), and raw ones for TCP/RTU.
    for i, (req, rsp) in enumerate(EXAMPLES):
        fc = req[0]
        if fc in (1, 2, 3, 4, 0x0F, 0x10):
            addr, nb = struct.unpack(">HH", req[1:5])
            call = client_call(fc, addr, nb)
        elif fc == 0x17:
            call = client_call(fc, 3, (3, 6))
        else:
            call = client_call(fc, 0x10, 1, 3)
        for kind in (0, 1, 2):
            put("ffi_client", bytes([kind | 4]) + call + bytes([0x11, 0]), f"ex{i:02d}-ok{kind}")
            put("ffi_client", bytes([kind | 4]) + call + bytes([0x11, 1]) + h("03 04 00"), f"ex{i:02d}-cut{kind}")
            put("ffi_client", bytes([kind]) + call + bytes([0x11, 2]) + framed(kind, 1, 0x11, rsp) + framed(kind, 2, 0x11, rsp),
                f"ex{i:02d}-raw{kind}")

    for t, n in sorted(written.items()):
        print(f"{t}: {n} seeds")


if __name__ == "__main__":
    main()
