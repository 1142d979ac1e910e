//! rsmodbus-proto: the Modbus protocol of rsmodbus, without I/O.
//!
//! Framing (RTU, ASCII, TCP; RTU over TCP is RTU framing on a stream), CRC and LRC,
//! message lengths, request encoding, response checks, and the server's replies with
//! every extension beyond libmodbus (diagnostics, files, FIFO, device
//! identification). Pure functions over byte slices: nothing in here opens a
//! socket, reads a clock, calls libc or uses `unsafe` (forbidden below); time and I/O
//! are the library's business. Debug text that libmodbus would print is handed to a
//! [`Diag`] sink so that tests can read it.

#![forbid(unsafe_code)]

pub mod ascii;
pub mod confirm;
pub mod crc;
pub mod data;
pub mod decode;
pub mod diagnostics;
pub mod error;
pub mod frame;
pub mod reply;
pub mod request;
pub mod security;
#[cfg(test)]
mod seed_vectors;
pub mod server_ext;
pub mod session;
#[cfg(test)]
pub mod test_rng;

use core::fmt;

/// Function codes (the `MODBUS_FC_*` macros of modbus.h).
pub mod fc {
    pub const READ_COILS: u8 = 0x01;
    pub const READ_DISCRETE_INPUTS: u8 = 0x02;
    pub const READ_HOLDING_REGISTERS: u8 = 0x03;
    pub const READ_INPUT_REGISTERS: u8 = 0x04;
    pub const WRITE_SINGLE_COIL: u8 = 0x05;
    pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
    pub const READ_EXCEPTION_STATUS: u8 = 0x07;
    pub const WRITE_MULTIPLE_COILS: u8 = 0x0F;
    pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
    pub const REPORT_SLAVE_ID: u8 = 0x11;
    pub const MASK_WRITE_REGISTER: u8 = 0x16;
    pub const WRITE_AND_READ_REGISTERS: u8 = 0x17;
    // Beyond libmodbus.
    pub const DIAGNOSTICS: u8 = 0x08;
    pub const GET_COMM_EVENT_COUNTER: u8 = 0x0B;
    pub const GET_COMM_EVENT_LOG: u8 = 0x0C;
    pub const READ_FILE_RECORD: u8 = 0x14;
    pub const WRITE_FILE_RECORD: u8 = 0x15;
    pub const READ_FIFO_QUEUE: u8 = 0x18;
    pub const ENCAPSULATED_INTERFACE: u8 = 0x2B;
}

/// Protocol limits (the `MODBUS_MAX_*` macros of modbus.h).
pub mod limits {
    pub const MAX_READ_BITS: i32 = 2000;
    pub const MAX_WRITE_BITS: i32 = 1968;
    pub const MAX_READ_REGISTERS: i32 = 125;
    pub const MAX_WRITE_REGISTERS: i32 = 123;
    pub const MAX_WR_WRITE_REGISTERS: i32 = 121;
    pub const MAX_WR_READ_REGISTERS: i32 = 125;
    pub const MAX_PDU_LENGTH: usize = 253;
    pub const BROADCAST_ADDRESS: i32 = 0;
    pub const TCP_SLAVE: i32 = 0xFF;
}

/// Where libmodbus's debug text would go. libmodbus writes some lines to stdout and
/// some to stderr; the sink keeps that split.
pub trait Diag {
    fn out(&mut self, args: fmt::Arguments<'_>);
    fn err(&mut self, args: fmt::Arguments<'_>);
}

/// A sink that drops everything (debug off).
pub struct Silent;

impl Diag for Silent {
    fn out(&mut self, _: fmt::Arguments<'_>) {}
    fn err(&mut self, _: fmt::Arguments<'_>) {}
}

/// A sink that records lines, for tests.
#[cfg(test)]
#[derive(Default, Debug)]
pub struct Recorded {
    pub out: String,
    pub err: String,
}

#[cfg(test)]
impl Diag for Recorded {
    fn out(&mut self, args: fmt::Arguments<'_>) {
        fmt::Write::write_fmt(&mut self.out, args).unwrap();
    }
    fn err(&mut self, args: fmt::Arguments<'_>) {
        fmt::Write::write_fmt(&mut self.err, args).unwrap();
    }
}
