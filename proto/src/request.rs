//! Client requests: argument checks and encoding, as libmodbus 3.1.12 does them.

use crate::data::registers_to_be;
use crate::error::{Error, Result};
use crate::frame::Framing;
use crate::limits::*;
use crate::{Diag, fc};

/// A request a client can send. Addresses and counts are the C `int`s the caller
/// gave; on the wire they are truncated to 16 bits as libmodbus does.
#[derive(Clone, Copy, Debug)]
pub enum Request<'a> {
    /// FC 01 / 02.
    ReadBits { function: u8, addr: i32, nb: i32 },
    /// FC 03 / 04.
    ReadRegisters { function: u8, addr: i32, nb: i32 },
    /// FC 05: any non-zero status is ON (0xFF00).
    WriteBit { addr: i32, on: bool },
    /// FC 06.
    WriteRegister { addr: i32, value: u16 },
    /// FC 0F: one byte per coil, non-zero is ON.
    WriteBits { addr: i32, bits: &'a [u8] },
    /// FC 10.
    WriteRegisters { addr: i32, values: &'a [u16] },
    /// FC 16.
    MaskWriteRegister { addr: i32, and_mask: u16, or_mask: u16 },
    /// FC 17: `write_nb` may be negative or zero (libmodbus does not check it).
    WriteAndReadRegisters { write_addr: i32, write_nb: i32, values: &'a [u16], read_addr: i32, read_nb: i32 },
    /// FC 11.
    ReportSlaveId,
    /// FC 07 (serial line only).
    ReadExceptionStatus,
    /// FC 08: sub-function and its data words.
    Diagnostics { sub_function: u16, data: &'a [u16] },
    /// FC 0B.
    GetCommEventCounter,
    /// FC 0C.
    GetCommEventLog,
    /// FC 14 with one sub-request (reference type 6).
    ReadFileRecord { file: u16, record: u16, nb: u16 },
    /// FC 15 with one sub-request.
    WriteFileRecord { file: u16, record: u16, values: &'a [u16] },
    /// FC 18.
    ReadFifoQueue { addr: u16 },
    /// FC 2B / MEI 0E.
    ReadDeviceId { read_code: u8, object_id: u8 },
    /// A request as given (`modbus_send_raw_request_async`): its unit, and its PDU
    /// (function code first, at least one byte), whatever the context's slave.
    Raw { unit: u8, pdu: &'a [u8] },
}

/// Reference type of every file record sub-request.
pub const FILE_RECORD_REFERENCE: u8 = 6;
/// Most registers one read file record sub-request can return (PDU limit).
pub const MAX_FILE_READ_REGISTERS: i32 = 124;
/// Most registers one write file record sub-request can carry (PDU limit).
pub const MAX_FILE_WRITE_REGISTERS: i32 = 122;
/// Largest record number of a file (0x270F).
pub const MAX_FILE_RECORD: i32 = 9999;
/// Most values a FIFO queue answer may hold.
pub const MAX_FIFO_COUNT: usize = 31;
/// Most data words of a diagnostics request (PDU limit).
pub const MAX_DIAGNOSTICS_WORDS: i32 = 125;

/// Checks a read count against its limit. `what` names the table in the debug line.
pub fn check_read_count(nb: i32, max: i32, what: &str, diag: &mut dyn Diag) -> Result<()> {
    if !(1..=max).contains(&nb) {
        diag.err(format_args!("ERROR Too many {what} requested ({nb} > {max})\n"));
        return Err(Error::TOO_MANY_DATA);
    }
    Ok(())
}

/// Checks the counts of the write functions; the messages are libmodbus's.
pub fn check_write_count(function: u8, nb: i32, diag: &mut dyn Diag) -> Result<()> {
    let (max, text) = match function {
        fc::WRITE_MULTIPLE_COILS => (MAX_WRITE_BITS, "Writing too many bits"),
        _ => (MAX_WRITE_REGISTERS, "Trying to write to too many registers"),
    };
    if !(1..=max).contains(&nb) {
        diag.err(format_args!("ERROR {text} ({nb} > {max})\n"));
        return Err(Error::TOO_MANY_DATA);
    }
    Ok(())
}

/// Checks FC 17 counts: only upper bounds, as in libmodbus.
pub fn check_write_and_read_counts(write_nb: i32, read_nb: i32, diag: &mut dyn Diag) -> Result<()> {
    if write_nb > MAX_WR_WRITE_REGISTERS {
        diag.err(format_args!("ERROR Too many registers to write ({write_nb} > {MAX_WR_WRITE_REGISTERS})\n"));
        return Err(Error::TOO_MANY_DATA);
    }
    if read_nb > MAX_WR_READ_REGISTERS {
        diag.err(format_args!("ERROR Too many registers requested ({read_nb} > {MAX_WR_READ_REGISTERS})\n"));
        return Err(Error::TOO_MANY_DATA);
    }
    Ok(())
}

fn put_u16(out: &mut [u8], at: usize, v: i32) {
    out[at] = (v >> 8) as u8;
    out[at + 1] = v as u8;
}

impl Request<'_> {
    pub fn function(&self) -> u8 {
        match *self {
            Request::ReadBits { function, .. } | Request::ReadRegisters { function, .. } => function,
            Request::WriteBit { .. } => fc::WRITE_SINGLE_COIL,
            Request::WriteRegister { .. } => fc::WRITE_SINGLE_REGISTER,
            Request::WriteBits { .. } => fc::WRITE_MULTIPLE_COILS,
            Request::WriteRegisters { .. } => fc::WRITE_MULTIPLE_REGISTERS,
            Request::MaskWriteRegister { .. } => fc::MASK_WRITE_REGISTER,
            Request::WriteAndReadRegisters { .. } => fc::WRITE_AND_READ_REGISTERS,
            Request::ReportSlaveId => fc::REPORT_SLAVE_ID,
            Request::ReadExceptionStatus => fc::READ_EXCEPTION_STATUS,
            Request::Diagnostics { .. } => fc::DIAGNOSTICS,
            Request::GetCommEventCounter => fc::GET_COMM_EVENT_COUNTER,
            Request::GetCommEventLog => fc::GET_COMM_EVENT_LOG,
            Request::ReadFileRecord { .. } => fc::READ_FILE_RECORD,
            Request::WriteFileRecord { .. } => fc::WRITE_FILE_RECORD,
            Request::ReadFifoQueue { .. } => fc::READ_FIFO_QUEUE,
            Request::ReadDeviceId { .. } => fc::ENCAPSULATED_INTERFACE,
            Request::Raw { pdu, .. } => pdu[0],
        }
    }

    /// The unit a request names itself (a raw request's), in place of the
    /// context's slave.
    pub fn own_unit(&self) -> Option<u8> {
        match *self {
            Request::Raw { unit, .. } => Some(unit),
            _ => None,
        }
    }

    /// Encodes the ADU (header + PDU, not yet sealed) into `out`, which must hold
    /// `MAX_ADU_LENGTH` bytes. Returns the length before [`Framing::seal`].
    pub fn encode(&self, framing: Framing, unit: u8, tid: u16, out: &mut [u8]) -> usize {
        let h = framing.write_header(out, self.own_unit().unwrap_or(unit), tid);
        out[h] = self.function();
        let p = h + 1;
        match *self {
            Request::ReadBits { addr, nb, .. } | Request::ReadRegisters { addr, nb, .. } => {
                put_u16(out, p, addr);
                put_u16(out, p + 2, nb);
                p + 4
            }
            Request::WriteBit { addr, on } => {
                put_u16(out, p, addr);
                put_u16(out, p + 2, if on { 0xFF00 } else { 0 });
                p + 4
            }
            Request::WriteRegister { addr, value } => {
                put_u16(out, p, addr);
                put_u16(out, p + 2, value as i32);
                p + 4
            }
            Request::WriteBits { addr, bits } => {
                put_u16(out, p, addr);
                put_u16(out, p + 2, bits.len() as i32);
                let byte_count = bits.len().div_ceil(8);
                out[p + 4] = byte_count as u8;
                let packed = &mut out[p + 5..p + 5 + byte_count];
                packed.fill(0);
                for (i, &bit) in bits.iter().enumerate() {
                    if bit != 0 {
                        packed[i / 8] |= 1 << (i % 8);
                    }
                }
                p + 5 + byte_count
            }
            Request::WriteRegisters { addr, values } => {
                put_u16(out, p, addr);
                put_u16(out, p + 2, values.len() as i32);
                out[p + 4] = (values.len() * 2) as u8;
                registers_to_be(values, &mut out[p + 5..]);
                p + 5 + values.len() * 2
            }
            Request::MaskWriteRegister { addr, and_mask, or_mask } => {
                put_u16(out, p, addr);
                put_u16(out, p + 2, and_mask as i32);
                put_u16(out, p + 4, or_mask as i32);
                p + 6
            }
            Request::WriteAndReadRegisters { write_addr, write_nb, values, read_addr, read_nb } => {
                put_u16(out, p, read_addr);
                put_u16(out, p + 2, read_nb);
                put_u16(out, p + 4, write_addr);
                put_u16(out, p + 6, write_nb);
                out[p + 8] = write_nb.wrapping_mul(2) as u8;
                registers_to_be(values, &mut out[p + 9..]);
                p + 9 + values.len() * 2
            }
            Request::ReportSlaveId
            | Request::ReadExceptionStatus
            | Request::GetCommEventCounter
            | Request::GetCommEventLog => p,
            Request::Diagnostics { sub_function, data } => {
                put_u16(out, p, sub_function as i32);
                registers_to_be(data, &mut out[p + 2..]);
                p + 2 + data.len() * 2
            }
            Request::ReadFileRecord { file, record, nb } => {
                out[p] = 7;
                out[p + 1] = FILE_RECORD_REFERENCE;
                put_u16(out, p + 2, file as i32);
                put_u16(out, p + 4, record as i32);
                put_u16(out, p + 6, nb as i32);
                p + 8
            }
            Request::WriteFileRecord { file, record, values } => {
                out[p] = (7 + values.len() * 2) as u8;
                out[p + 1] = FILE_RECORD_REFERENCE;
                put_u16(out, p + 2, file as i32);
                put_u16(out, p + 4, record as i32);
                put_u16(out, p + 6, values.len() as i32);
                registers_to_be(values, &mut out[p + 8..]);
                p + 8 + values.len() * 2
            }
            Request::ReadFifoQueue { addr } => {
                put_u16(out, p, addr as i32);
                p + 2
            }
            Request::Raw { pdu, .. } => {
                out[p..p + pdu.len() - 1].copy_from_slice(&pdu[1..]);
                p + pdu.len() - 1
            }
            Request::ReadDeviceId { read_code, object_id } => {
                out[p] = crate::frame::MEI_READ_DEVICE_ID;
                out[p + 1] = read_code;
                out[p + 2] = object_id;
                p + 3
            }
        }
    }
}

/// Transaction id of the next request: incremented before use, 65535 wraps to 0.
pub fn next_tid(tid: u16) -> u16 {
    if tid < u16::MAX { tid + 1 } else { 0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Recorded;
    use crate::frame::MAX_ADU_LENGTH;

    fn encode(framing: Framing, req: Request<'_>) -> Vec<u8> {
        let mut buf = [0u8; MAX_ADU_LENGTH];
        let n = req.encode(framing, 0x11, 1, &mut buf);
        let n = framing.seal(&mut buf, n);
        buf[..n].to_vec()
    }

    #[test]
    fn seed_read_holding_registers_frame() {
        // Seed 004: 11 03 006B 0003 7687.
        let f = encode(Framing::Rtu, Request::ReadRegisters { function: 3, addr: 0x6B, nb: 3 });
        assert_eq!(f, [0x11, 0x03, 0x00, 0x6B, 0x00, 0x03, 0x76, 0x87]);
    }

    #[test]
    fn every_encoding() {
        let t = Framing::Tcp;
        let h = [0, 1, 0, 0];
        let cases: Vec<(Request<'_>, Vec<u8>)> = vec![
            (Request::ReadBits { function: 1, addr: 0x13, nb: 0x25 }, vec![0, 6, 0x11, 1, 0, 0x13, 0, 0x25]),
            (Request::ReadBits { function: 2, addr: 0xC4, nb: 0x16 }, vec![0, 6, 0x11, 2, 0, 0xC4, 0, 0x16]),
            (Request::ReadRegisters { function: 4, addr: 8, nb: 1 }, vec![0, 6, 0x11, 4, 0, 8, 0, 1]),
            (Request::WriteBit { addr: 0xAC, on: true }, vec![0, 6, 0x11, 5, 0, 0xAC, 0xFF, 0]),
            (Request::WriteBit { addr: 0xAC, on: false }, vec![0, 6, 0x11, 5, 0, 0xAC, 0, 0]),
            (Request::WriteRegister { addr: 1, value: 3 }, vec![0, 6, 0x11, 6, 0, 1, 0, 3]),
            (
                Request::WriteBits { addr: 0x13, bits: &[1, 0, 1, 1, 0, 0, 1, 1, 1, 0] },
                vec![0, 9, 0x11, 0x0F, 0, 0x13, 0, 0x0A, 2, 0xCD, 0x01],
            ),
            (
                Request::WriteRegisters { addr: 1, values: &[0x000A, 0x0102] },
                vec![0, 11, 0x11, 0x10, 0, 1, 0, 2, 4, 0, 0x0A, 1, 2],
            ),
            (
                Request::MaskWriteRegister { addr: 4, and_mask: 0xF2, or_mask: 0x25 },
                vec![0, 8, 0x11, 0x16, 0, 4, 0, 0xF2, 0, 0x25],
            ),
            (
                Request::WriteAndReadRegisters {
                    write_addr: 0x0E,
                    write_nb: 3,
                    values: &[0xFF, 0xFF, 0xFF],
                    read_addr: 3,
                    read_nb: 6,
                },
                vec![0, 17, 0x11, 0x17, 0, 3, 0, 6, 0, 0x0E, 0, 3, 6, 0, 0xFF, 0, 0xFF, 0, 0xFF],
            ),
            (Request::ReportSlaveId, vec![0, 2, 0x11, 0x11]),
            (Request::ReadExceptionStatus, vec![0, 2, 0x11, 0x07]),
            (Request::Diagnostics { sub_function: 0, data: &[0xA537] }, vec![0, 6, 0x11, 8, 0, 0, 0xA5, 0x37]),
            (Request::GetCommEventCounter, vec![0, 2, 0x11, 0x0B]),
            (Request::GetCommEventLog, vec![0, 2, 0x11, 0x0C]),
            (Request::ReadFileRecord { file: 4, record: 1, nb: 2 }, vec![0, 10, 0x11, 0x14, 7, 6, 0, 4, 0, 1, 0, 2]),
            (
                Request::WriteFileRecord { file: 4, record: 7, values: &[0x06AF, 0x04BE] },
                vec![0, 14, 0x11, 0x15, 11, 6, 0, 4, 0, 7, 0, 2, 0x06, 0xAF, 0x04, 0xBE],
            ),
            (Request::ReadFifoQueue { addr: 0x04DE }, vec![0, 4, 0x11, 0x18, 0x04, 0xDE]),
            (Request::ReadDeviceId { read_code: 1, object_id: 0 }, vec![0, 5, 0x11, 0x2B, 0x0E, 1, 0]),
        ];
        for (req, tail) in cases {
            let mut want = h.to_vec();
            want.extend(tail);
            assert_eq!(encode(t, req), want, "{req:?}");
        }
    }

    #[test]
    fn addresses_truncate_like_c() {
        let f = encode(Framing::Tcp, Request::ReadRegisters { function: 3, addr: 0x1_2345, nb: -1 });
        assert_eq!(f[8..], [0x23, 0x45, 0xFF, 0xFF]);
    }

    #[test]
    fn count_checks() {
        let mut d = Recorded::default();
        assert_eq!(check_read_count(2001, 2000, "bits", &mut d), Err(Error::TOO_MANY_DATA));
        assert_eq!(d.err, "ERROR Too many bits requested (2001 > 2000)\n");
        assert_eq!(check_read_count(0, 125, "registers", &mut d), Err(Error::TOO_MANY_DATA));
        assert!(check_read_count(125, 125, "registers", &mut d).is_ok());
        assert!(check_write_count(0x0F, 1968, &mut d).is_ok());
        assert_eq!(check_write_count(0x0F, 1969, &mut d), Err(Error::TOO_MANY_DATA));
        assert_eq!(check_write_count(0x10, 0, &mut d), Err(Error::TOO_MANY_DATA));
        assert_eq!(check_write_and_read_counts(122, 1, &mut d), Err(Error::TOO_MANY_DATA));
        assert_eq!(check_write_and_read_counts(1, 126, &mut d), Err(Error::TOO_MANY_DATA));
        assert!(check_write_and_read_counts(-5, 0, &mut d).is_ok());
    }

    #[test]
    fn tid_wraps_through_zero() {
        assert_eq!(next_tid(0), 1);
        assert_eq!(next_tid(65534), 65535);
        assert_eq!(next_tid(65535), 0);
    }
}
