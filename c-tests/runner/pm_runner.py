#!/usr/bin/env python3
# pymodbus clients against a server that runs itself (c-tests/runner/runner-server.c,
# with a mapping: register i holds i, coil i is i % 3 == 0).
#
# usage: pm_runner.py tcp|rtutcp PORT [N]
#   one synchronous client (MBAP framing, or RTU framing over TCP): reads, writes and
#   reads back registers and coils; then N asyncio clients at once (default 50), each
#   writing and reading back its own register, 20 times.
#
# Prints "ok   - name" / "FAIL - name: why" per check and "N passed, M failed" last;
# exits 1 on any failure.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import asyncio
import sys

from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient

passed = 0
failed = 0


def check(cond, name):
    global passed, failed
    if cond:
        passed += 1
        print("ok   - " + name, flush=True)
    else:
        failed += 1
        print("FAIL - " + name, flush=True)


def sync_client(framer, port):
    c = ModbusTcpClient("127.0.0.1", port=port, framer=framer, timeout=5)
    check(c.connect(), "pymodbus %s: connect" % framer.value)
    r = c.read_holding_registers(300, count=10, device_id=1)
    check(not r.isError() and r.registers == list(range(300, 310)), "pymodbus %s: read 10 registers" % framer.value)
    r = c.write_registers(600, [11, 22, 33], device_id=1)
    check(not r.isError(), "pymodbus %s: write 3 registers" % framer.value)
    r = c.read_holding_registers(600, count=3, device_id=1)
    check(not r.isError() and r.registers == [11, 22, 33], "pymodbus %s: read them back" % framer.value)
    r = c.read_coils(0, count=9, device_id=1)
    check(not r.isError() and r.bits[:9] == [i % 3 == 0 for i in range(9)], "pymodbus %s: read 9 coils" % framer.value)
    r = c.read_holding_registers(995, count=10, device_id=1)
    check(r.isError() and r.exception_code == 2, "pymodbus %s: a read past the table: exception 02" % framer.value)
    c.close()


async def one(port, k, rounds):
    c = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=10)
    await c.connect()
    good = 0
    for j in range(rounds):
        w = await c.write_register(700 + k, (k * 100 + j) & 0xFFFF, device_id=1)
        r = await c.read_holding_registers(700 + k, count=1, device_id=1)
        if not w.isError() and not r.isError() and r.registers[0] == (k * 100 + j) & 0xFFFF:
            good += 1
    c.close()
    return good


async def many(port, n, rounds):
    results = await asyncio.gather(*(one(port, k, rounds) for k in range(n)))
    check(sum(results) == n * rounds, "pymodbus asyncio: %d clients at once, %d of %d rounds right"
          % (n, sum(results), n * rounds))


def main():
    mode, port = sys.argv[1], int(sys.argv[2])
    n = int(sys.argv[3]) if len(sys.argv) > 3 else 50
    sync_client(FramerType.RTU if mode == "rtutcp" else FramerType.SOCKET, port)
    if mode == "tcp":
        asyncio.run(many(port, n, 20))
    finish()


def finish():
    print("%d passed, %d failed" % (passed, failed))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
