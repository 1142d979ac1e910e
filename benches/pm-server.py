#!/usr/bin/env python3
# pm-server.py: pymodbus' asyncio TCP server for benches/server-many.sh, as its
# documentation starts one: StartAsyncTcpServer (pymodbus 3.16.1) over one device
# (unit 1) whose datastore holds 100 holding registers, register i holding i.
#
# usage: pm-server.py PORT
#
# Prints "LIBINFO: pymodbus VERSION" and, once the port accepts connections,
# "READY PORT"; runs until it is killed (SIGTERM).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import asyncio
import sys

import pymodbus
from pymodbus.server import StartAsyncTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice


async def main():
    port = int(sys.argv[1])
    device = SimDevice(id=1, simdata=[SimData(0, values=list(range(100)), datatype=DataType.REGISTERS)])
    print(f"LIBINFO: pymodbus {pymodbus.__version__}", flush=True)
    server = asyncio.create_task(StartAsyncTcpServer(context=device, address=("127.0.0.1", port)))
    # READY once the port takes a connection (the server task has bound it).
    for _ in range(200):
        if server.done():
            server.result()  # raises what stopped it
        try:
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.close()
            break
        except OSError:
            await asyncio.sleep(0.05)
    print(f"READY {port}", flush=True)
    await server


if __name__ == "__main__":
    asyncio.run(main())
