#!/usr/bin/env python3
# pymodbus on the other side of the Modbus/TCP Security tests (tls.sh), mutual TLS:
#
#   pm_tls.py server HOST PORT CERTDIR     a pymodbus TLS server requiring a client certificate
#                                          of the test CA; holding register i = 1000 + i
#   pm_tls.py client HOST PORT CERTDIR WHO a pymodbus TLS client with certificate WHO
#                                          (operator or reader) against our tls-server: every
#                                          libmodbus function code; a reader's writes must get
#                                          exception 01 and change nothing
#
# Prints "ok   - name" / "FAIL - name: why" per check and "N passed, M failed" last.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import asyncio
import os
import ssl
import sys

from pymodbus.client import AsyncModbusTlsClient
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusTlsServer
from pymodbus.simulator import DataType, SimData, SimDevice

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "interop"))
import pm_client as report  # noqa: E402  (the interop tests' ok/FAIL lines and counters)


def check(cond, name, why=""):
    if cond:
        report.ok(name)
    else:
        report.fail(name, why)


def context(certdir, who, server):
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER if server else ssl.PROTOCOL_TLS_CLIENT)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_verify_locations(os.path.join(certdir, "ca.pem"))
    ctx.load_cert_chain(os.path.join(certdir, who + ".pem"), os.path.join(certdir, who + ".key"))
    ctx.verify_mode = ssl.CERT_REQUIRED
    if not server:
        ctx.check_hostname = False  # pymodbus passes no server name; the chain is still verified
    return ctx


async def serve(host, port, certdir):
    n = 100
    dev = SimDevice(
        id=255,
        simdata=(
            [SimData(0, values=[False] * n, datatype=DataType.BITS)],
            [SimData(0, values=[False] * n, datatype=DataType.BITS)],
            [SimData(0, values=[1000 + i for i in range(n)], datatype=DataType.REGISTERS)],
            [SimData(0, values=[0] * n, datatype=DataType.REGISTERS)],
        ),
    )
    server = ModbusTlsServer(dev, address=(host, port), sslctx=context(certdir, "server", True))
    await server.serve_forever(background=True)
    print("READY", flush=True)
    try:
        await asyncio.wait_for(server.serving, 120)
    except asyncio.TimeoutError:
        pass
    await server.shutdown()


async def client(host, port, certdir, who):
    # The asynchronous client: pymodbus 3.16's synchronous TLS client is IPv4 only.
    c = AsyncModbusTlsClient(host, port=port, sslctx=context(certdir, who, False), timeout=3, retries=0)
    check(await c.connect(), "%s: pymodbus TLS client connects to our server" % who)
    dev = 255
    r = await c.read_holding_registers(0, count=5, device_id=dev)
    check(not r.isError() and r.registers[1:] == [1001, 1002, 1003, 1004], "%s: FC 03" % who, r)
    r = await c.read_input_registers(0, count=3, device_id=dev)
    check(not r.isError() and r.registers == [0, 0, 0], "%s: FC 04" % who, r)
    r = await c.read_coils(0, count=10, device_id=dev)
    check(not r.isError() and not any(r.bits[:10]), "%s: FC 01" % who, r)
    r = await c.read_discrete_inputs(0, count=10, device_id=dev)
    check(not r.isError() and not any(r.bits[:10]), "%s: FC 02" % who, r)
    writes = [
        ("FC 05", lambda: c.write_coil(20, True, device_id=dev)),
        ("FC 06", lambda: c.write_register(20, 0x1234, device_id=dev)),
        ("FC 0F", lambda: c.write_coils(21, [True, False, True], device_id=dev)),
        ("FC 10", lambda: c.write_registers(21, [7, 8, 9], device_id=dev)),
        ("FC 16", lambda: c.mask_write_register(address=22, and_mask=0x00F0, or_mask=0x0101, device_id=dev)),
    ]
    for name, fn in writes:
        try:
            r = await fn()
        except Exception as e:  # pylint: disable=broad-except
            r = e
        if who == "operator":
            check(not r.isError(), "%s: %s" % (who, name), r)
        else:
            check(isinstance(r, ExceptionResponse) and r.exception_code == 1,
                  "%s: %s refused with exception 01" % (who, name), r)
    r = await c.readwrite_registers(read_address=20, read_count=4, write_address=24, values=[0xBEEF], device_id=dev)
    if who == "operator":
        want = [0x1234, 7, (8 & 0x00F0) | (0x0101 & ~0x00F0 & 0xFFFF), 9]
        check(not r.isError() and r.registers == want, "operator: FC 17 (and what 06, 10, 16 wrote)", r)
        r = await c.read_coils(20, count=4, device_id=dev)
        check(not r.isError() and r.bits[:4] == [True, True, False, True], "operator: coils 05 and 0F wrote", r)
    else:
        check(isinstance(r, ExceptionResponse) and r.exception_code == 1, "reader: FC 17 refused", r)
        r = await c.read_holding_registers(20, count=5, device_id=dev)
        check(not r.isError() and r.registers == [1020, 1021, 1022, 1023, 1024], "reader: nothing changed", r)
    c.close()


def main():
    if len(sys.argv) < 5:
        sys.exit(__doc__)
    mode, host, port, certdir = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    if mode == "server":
        asyncio.run(serve(host, port, certdir))
        return
    asyncio.run(client(host, port, certdir, sys.argv[5]))
    print("%d passed, %d failed" % (report.passed, report.failed), flush=True)
    sys.exit(1 if report.failed else 0)


if __name__ == "__main__":
    main()
