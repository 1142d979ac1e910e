#!/usr/bin/env python3
# A pymodbus server with the data of pm_model.py, for our C client (our_client.c).
#
# usage: pm_server.py tcp|rtutcp PORT [--host ADDR] | ascii|rtu DEVICE [--bits 7|8 --parity N|E|O]
#                     [--timeout SECS]
#
# pymodbus does the framing and the PDU encoding. Its datastore handlers for the
# device-state function codes are placeholders (fixed dummy file records, a fixed FIFO,
# a status byte that cannot hold its nine counters), so those few handlers are
# replaced here by ones that serve pm_model.py; the request decoding and the response
# encoding stay pymodbus's own, except the decoding of FC 14 requests (see
# decode_read_file_record: pymodbus 3.16.1 misreads their record length). Two behaviours are made to follow the protocol where
# pymodbus 3.16.1 does not: it answers Force Listen Only Mode (08/04) and keeps
# answering afterwards; here it stays silent until Restart Communications (08/01), which
# it does not answer either ("in listen only mode no response is expected").
#
# Every frame received and sent is printed as "RX: .." / "TX: .." (hex).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
import argparse
import asyncio
import os
import struct
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import pm_model as M  # noqa: E402

from pymodbus import FramerType  # noqa: E402
from pymodbus.constants import ExcCodes  # noqa: E402
from pymodbus.pdu import ExceptionResponse  # noqa: E402
from pymodbus.pdu import diag_message as diag  # noqa: E402
from pymodbus.pdu import file_message as fm  # noqa: E402
from pymodbus.pdu import other_message as om  # noqa: E402
from pymodbus.pdu.device import ModbusControlBlock, ModbusDeviceIdentification  # noqa: E402
from pymodbus.server import ModbusSerialServer, ModbusTcpServer  # noqa: E402
from pymodbus.server.requesthandler import ServerRequestHandler  # noqa: E402
from pymodbus.simulator import DataType, SimData, SimDevice  # noqa: E402

MCB = ModbusControlBlock()
FILES = {f: {} for f in M.FILES}  # written registers: file -> {index: value}
STATE = {"listen_only": False, "silent_once": False}


def file_value(f, r):
    return FILES[f].get(r, M.file_reg(f, r))


def exc(fc, code):
    return ExceptionResponse(fc, code)


async def read_exception_status(self, context, device_id):
    _ = context
    return om.ReadExceptionStatusResponse(
        status=M.EXCEPTION_STATUS, dev_id=device_id, transaction_id=self.transaction_id
    )


async def get_comm_event_counter(self, context, device_id):
    _ = context
    return om.GetCommEventCounterResponse(
        count=M.EVENT_COUNT, dev_id=device_id, transaction_id=self.transaction_id
    )


async def get_comm_event_log(self, context, device_id):
    _ = context
    return om.GetCommEventLogResponse(
        status=True,
        message_count=M.COUNTERS[0x0B],
        event_count=M.EVENT_COUNT,
        events=list(M.EVENTS),
        dev_id=device_id,
        transaction_id=self.transaction_id,
    )


async def read_file_record(self, context, device_id):
    _ = context
    out = []
    for rec in self.records:
        f, r, n = rec.file_number, rec.record_number, rec.record_length
        if f not in FILES or r > 9999 or r + n > 10000:
            return exc(0x14, ExcCodes.ILLEGAL_ADDRESS)
        data = b"".join(file_value(f, r + k).to_bytes(2, "big") for k in range(n))
        out.append(fm.FileRecord(file_number=f, record_number=r, record_data=data))
    return fm.ReadFileRecordResponse(
        records=out, dev_id=device_id, transaction_id=self.transaction_id
    )


async def write_file_record(self, context, device_id):
    _ = context
    for rec in self.records:
        f, r = rec.file_number, rec.record_number
        if f not in FILES or r > 9999:
            return exc(0x15, ExcCodes.ILLEGAL_ADDRESS)
        data = rec.record_data
        for k in range(len(data) // 2):
            FILES[f][r + k] = int.from_bytes(data[2 * k : 2 * k + 2], "big")
    return fm.WriteFileRecordResponse(
        records=self.records, dev_id=device_id, transaction_id=self.transaction_id
    )


async def read_fifo_queue(self, context, device_id):
    _ = context
    if self.address not in M.FIFOS:
        return exc(0x18, ExcCodes.ILLEGAL_ADDRESS)
    return fm.ReadFifoQueueResponse(
        values=list(M.FIFOS[self.address]),
        dev_id=device_id,
        transaction_id=self.transaction_id,
    )


def decode_read_file_record(self, data):
    # pymodbus 3.16.1 passes the wire's record length (registers) to FileRecord's
    # record_length=, which takes bytes and rejects odd values: a request for 3 registers
    # fails to decode (it answers function code 0x80) and one for 10 reads 5. Decode the
    # seven-byte sub-requests here instead.
    self.records = []
    count = int(data[0])
    for at in range(1, count, 7):
        _, f, r, n = struct.unpack(">BHHH", data[at : at + 7])
        rec = fm.FileRecord(file_number=f, record_number=r)
        rec.record_length = n
        self.records.append(rec)


_orig_diag_update = diag.DiagnosticBase.datastore_update
_orig_listen_update = diag.ForceListenOnlyModeRequest.datastore_update


async def restart_communications(self, context, device_id):
    # "In listen only mode no response is expected": leave it, silently
    STATE["silent_once"] = STATE["listen_only"]
    STATE["listen_only"] = False
    return await _orig_diag_update(self, context, device_id)


async def force_listen_only(self, context, device_id):
    STATE["listen_only"] = True
    return await _orig_listen_update(self, context, device_id)


_orig_server_send = ServerRequestHandler.server_send


def server_send(self, pdu, addr):
    if isinstance(pdu, diag.ForceListenOnlyModeResponse) or STATE["listen_only"] or STATE["silent_once"]:
        STATE["silent_once"] = False
        print("NO-REPLY (listen only mode)", flush=True)
        return
    _orig_server_send(self, pdu, addr)


om.ReadExceptionStatusRequest.datastore_update = read_exception_status
om.GetCommEventCounterRequest.datastore_update = get_comm_event_counter
om.GetCommEventLogRequest.datastore_update = get_comm_event_log
fm.ReadFileRecordRequest.datastore_update = read_file_record
fm.ReadFileRecordRequest.decode = decode_read_file_record
fm.WriteFileRecordRequest.datastore_update = write_file_record
fm.ReadFifoQueueRequest.datastore_update = read_fifo_queue
diag.RestartCommunicationsOptionRequest.datastore_update = restart_communications
diag.ForceListenOnlyModeRequest.datastore_update = force_listen_only
ServerRequestHandler.server_send = server_send


def set_counters():
    c = MCB.Counter
    c.BusMessage = M.COUNTERS[0x0B]
    c.BusCommunicationError = M.COUNTERS[0x0C]
    c.BusExceptionError = M.COUNTERS[0x0D]
    c.DeviceMessage = M.COUNTERS[0x0E]
    c.DeviceNoResponse = M.COUNTERS[0x0F]
    c.DeviceNAK = M.COUNTERS[0x10]
    c.DEVICE_BUSY = M.COUNTERS[0x11]
    c.BusCharacterOverrun = M.COUNTERS[0x12]
    # diagnostic register bits 1, 3 and 9: pymodbus packs bit 0 first
    MCB.setDiagnostic({1: True, 3: True, 9: True})


def trace(sending, data):
    print(("TX: " if sending else "RX: ") + M.hexs(data), flush=True)
    return data


def device():
    n = M.SIZE
    return SimDevice(
        id=M.SLAVE,
        simdata=(
            [SimData(0, values=[M.coil(i) for i in range(n)], datatype=DataType.BITS)],
            [SimData(0, values=[M.discrete(i) for i in range(n)], datatype=DataType.BITS)],
            [SimData(0, values=[M.holding(i) for i in range(n)], datatype=DataType.REGISTERS)],
            [SimData(0, values=[M.input_reg(i) for i in range(n)], datatype=DataType.REGISTERS)],
        ),
    )


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("transport", choices=["tcp", "rtutcp", "ascii", "rtu"])
    ap.add_argument("where")
    ap.add_argument("--bits", type=int, default=8)
    ap.add_argument("--parity", default="N")
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--host", default="127.0.0.1")
    a = ap.parse_args()
    set_counters()
    identity = ModbusDeviceIdentification(info=dict(M.DEVICE_ID))
    common = {"identity": identity, "trace_packet": trace}
    if a.transport in ("tcp", "rtutcp"):
        framer = FramerType.SOCKET if a.transport == "tcp" else FramerType.RTU
        server = ModbusTcpServer(
            device(), framer=framer, address=(a.host, int(a.where)), **common
        )
    else:
        framer = FramerType.ASCII if a.transport == "ascii" else FramerType.RTU
        server = ModbusSerialServer(
            device(),
            framer=framer,
            port=a.where,
            baudrate=115200,
            bytesize=a.bits,
            parity=a.parity,
            stopbits=1,
            **common,
        )
    await server.serve_forever(background=True)
    print("READY", flush=True)
    try:
        await asyncio.wait_for(server.serving, a.timeout)
    except asyncio.TimeoutError:
        print("server timeout: exiting", flush=True)
    await server.shutdown()


if __name__ == "__main__":
    asyncio.run(main())
