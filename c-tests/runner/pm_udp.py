#!/usr/bin/env python3
# Modbus/UDP helpers for c-tests/suites/runner.sh, both sides of pymodbus and a lossy
# path between them:
#
#   pm_udp.py server PORT              a pymodbus UDP server: unit 1, holding register i
#                                      and input register i hold i, coil i is i % 3 == 0;
#                                      prints READY
#   pm_udp.py client PORT              a pymodbus UDP client against our server
#                                      (runner-server udp): reads, writes, reads back,
#                                      an exception; "N passed, M failed" last
#   pm_udp.py proxy PORT TARGET LOSS DUP
#                                      relays datagrams between clients on PORT and the
#                                      server on TARGET, dropping every LOSS-th datagram
#                                      each way and sending every DUP-th twice (0: never);
#                                      prints READY, then counts on SIGTERM
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import asyncio
import os
import signal
import socket
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pm_runner import check, finish  # noqa: E402


async def server(port):
    from pymodbus.server import ModbusUdpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    n = 1000
    dev = SimDevice(
        id=1,
        simdata=(
            [SimData(0, values=[i % 3 == 0 for i in range(n)], datatype=DataType.BITS)],
            [SimData(0, values=[i % 3 == 0 for i in range(n)], datatype=DataType.BITS)],
            [SimData(0, values=list(range(n)), datatype=DataType.REGISTERS)],
            [SimData(0, values=list(range(n)), datatype=DataType.REGISTERS)],
        ),
    )
    srv = ModbusUdpServer(dev, address=("127.0.0.1", port))
    await srv.serve_forever(background=True)
    print("READY", flush=True)
    await srv.serving


def client(port):
    from pymodbus.client import ModbusUdpClient

    c = ModbusUdpClient("127.0.0.1", port=port, timeout=2, retries=1)
    check(c.connect(), "pymodbus udp: connect")
    r = c.read_holding_registers(300, count=10, device_id=1)
    check(not r.isError() and r.registers == list(range(300, 310)), "pymodbus udp: read 10 registers")
    r = c.write_registers(600, [11, 22, 33], device_id=1)
    check(not r.isError(), "pymodbus udp: write 3 registers")
    r = c.read_holding_registers(600, count=3, device_id=1)
    check(not r.isError() and r.registers == [11, 22, 33], "pymodbus udp: read them back")
    r = c.read_coils(0, count=9, device_id=1)
    check(not r.isError() and r.bits[:9] == [i % 3 == 0 for i in range(9)], "pymodbus udp: read 9 coils")
    r = c.read_holding_registers(995, count=10, device_id=1)
    check(r.isError() and r.exception_code == 2, "pymodbus udp: a read past the table: exception 02")
    ok = 0
    for i in range(200):
        r = c.read_input_registers(i, count=1, device_id=1)
        ok += (not r.isError()) and r.registers == [i]
    check(ok == 200, "pymodbus udp: 200 reads in a row (%d right)" % ok)
    c.close()
    finish()


def proxy(port, target, loss, dup):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    up.connect(("127.0.0.1", target))
    counts = {"relayed": 0, "dropped": 0, "doubled": 0}
    client = [None]
    n = [0]

    def relay(data, send):
        n[0] += 1
        if loss and n[0] % loss == 0:
            counts["dropped"] += 1
            return
        send(data)
        counts["relayed"] += 1
        if dup and n[0] % dup == 0:
            send(data)
            counts["doubled"] += 1

    def done(*_):
        print("proxy: %(relayed)d relayed, %(dropped)d dropped, %(doubled)d doubled" % counts, flush=True)
        sys.exit(0)

    signal.signal(signal.SIGTERM, done)
    import select

    print("READY", flush=True)
    while True:
        r, _, _ = select.select([s, up], [], [])
        if s in r:
            data, addr = s.recvfrom(4096)
            client[0] = addr
            relay(data, up.send)
        if up in r:
            data = up.recv(4096)
            if client[0] is not None:
                relay(data, lambda d: s.sendto(d, client[0]))


def main():
    what, port = sys.argv[1], int(sys.argv[2])
    if what == "server":
        asyncio.run(server(port))
    elif what == "client":
        client(port)
    elif what == "proxy":
        proxy(port, int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
    else:
        sys.exit("unknown " + what)


main()
