//! ADU framing: RTU (`[slave][pdu][crc lo][crc hi]`) and TCP (`[MBAP 7 bytes][pdu]`).
//!
//! Both framings carry the same PDU; they differ in the header in front of it and the
//! checksum behind it. Lengths of incoming messages are computed from their content in
//! three steps, exactly as libmodbus does (the MBAP length field is never trusted):
//! see [`Assembler`].

use crate::crc::{crc16, stored_crc};
use crate::error::{Error, Result};
use crate::fc;

/// Largest ADU of any framing (TCP: 7 + 253).
pub const MAX_ADU_LENGTH: usize = 260;
pub const RTU_MAX_ADU_LENGTH: usize = 256;
pub const TCP_MAX_ADU_LENGTH: usize = 260;

/// How a PDU is wrapped on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Framing {
    Rtu,
    Tcp,
    /// Modbus ASCII. Lengths and checksums here are those of the decoded binary
    /// frame `[slave][pdu][lrc]`; `core::ascii` turns it into characters and back.
    Ascii,
}

impl Framing {
    /// Bytes in front of the function code (`modbus_get_header_length`).
    pub const fn header_length(self) -> usize {
        match self {
            Framing::Rtu | Framing::Ascii => 1,
            Framing::Tcp => 7,
        }
    }

    pub const fn checksum_length(self) -> usize {
        match self {
            Framing::Rtu => 2,
            Framing::Ascii => 1,
            Framing::Tcp => 0,
        }
    }

    pub const fn max_adu_length(self) -> usize {
        match self {
            Framing::Rtu => RTU_MAX_ADU_LENGTH,
            Framing::Ascii => crate::ascii::MAX_DECODED,
            Framing::Tcp => TCP_MAX_ADU_LENGTH,
        }
    }

    /// Serial-line framings address a slave on a shared bus: they filter by slave id
    /// and never answer a broadcast.
    pub const fn is_serial(self) -> bool {
        !matches!(self, Framing::Tcp)
    }

    /// Writes the header of a request: slave (RTU) or MBAP with transaction id and
    /// unit (TCP; the length field is filled by [`Framing::seal`]). Returns its length.
    pub fn write_header(self, out: &mut [u8], unit: u8, tid: u16) -> usize {
        match self {
            Framing::Rtu | Framing::Ascii => {
                out[0] = unit;
                1
            }
            Framing::Tcp => {
                out[..2].copy_from_slice(&tid.to_be_bytes());
                out[2..6].fill(0);
                out[6] = unit;
                7
            }
        }
    }

    /// Completes an ADU of `len` bytes in `buf` before sending: the MBAP length field
    /// for TCP, the CRC for RTU. Returns the final length.
    pub fn seal(self, buf: &mut [u8], len: usize) -> usize {
        match self {
            Framing::Rtu => {
                let crc = crc16(&buf[..len]);
                buf[len..len + 2].copy_from_slice(&crc.to_le_bytes());
                len + 2
            }
            Framing::Ascii => {
                buf[len] = crate::ascii::lrc(&buf[..len]);
                len + 1
            }
            Framing::Tcp => {
                let mbap_len = (len - 6) as u16;
                buf[4..6].copy_from_slice(&mbap_len.to_be_bytes());
                len
            }
        }
    }

    /// The transaction id a reply must carry: copied from the request in TCP, 0 in RTU.
    pub fn response_tid(self, req: &[u8]) -> u16 {
        match (self, req) {
            (Framing::Tcp, [hi, lo, ..]) => u16::from_be_bytes([*hi, *lo]),
            _ => 0,
        }
    }
}

/// Which side of an exchange an incoming message is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MsgKind {
    /// A request arriving at a server.
    Indication,
    /// A response arriving at a client.
    Confirmation,
}

/// Bytes that follow the function code before the length of the data is known.
pub fn meta_length(kind: MsgKind, function: u8) -> usize {
    match kind {
        MsgKind::Indication => match function {
            0x00..=fc::WRITE_SINGLE_REGISTER => 4,
            fc::WRITE_MULTIPLE_COILS | fc::WRITE_MULTIPLE_REGISTERS => 5,
            fc::MASK_WRITE_REGISTER => 6,
            fc::WRITE_AND_READ_REGISTERS => 9,
            _ => 0,
        },
        MsgKind::Confirmation => match function {
            fc::WRITE_SINGLE_COIL
            | fc::WRITE_SINGLE_REGISTER
            | fc::WRITE_MULTIPLE_COILS
            | fc::WRITE_MULTIPLE_REGISTERS => 4,
            fc::MASK_WRITE_REGISTER => 6,
            _ => 1,
        },
    }
}

/// Bytes of data that follow the meta part, read from the byte count it carries.
/// `msg` holds the header, the function code and the meta bytes.
pub fn data_length(kind: MsgKind, header_length: usize, msg: &[u8]) -> usize {
    let h = header_length;
    let function = msg[h];
    match kind {
        MsgKind::Indication => match function {
            fc::WRITE_MULTIPLE_COILS | fc::WRITE_MULTIPLE_REGISTERS => msg[h + 5] as usize,
            fc::WRITE_AND_READ_REGISTERS => msg[h + 9] as usize,
            _ => 0,
        },
        MsgKind::Confirmation => match function {
            0x00..=fc::READ_INPUT_REGISTERS | fc::REPORT_SLAVE_ID | fc::WRITE_AND_READ_REGISTERS => msg[h + 1] as usize,
            _ => 0,
        },
    }
}

/// Whether [`data_length`] reads the meta bytes of this function code. When it does
/// not, the data length is 0 whatever they hold, so the meta bytes and the checksum
/// can be read as one piece: still never past the end of the message.
pub const fn data_needs_meta(kind: MsgKind, function: u8) -> bool {
    match kind {
        MsgKind::Indication => {
            matches!(function, fc::WRITE_MULTIPLE_COILS | fc::WRITE_MULTIPLE_REGISTERS | fc::WRITE_AND_READ_REGISTERS)
        }
        MsgKind::Confirmation => {
            matches!(function, 0x00..=fc::READ_INPUT_REGISTERS | fc::REPORT_SLAVE_ID | fc::WRITE_AND_READ_REGISTERS)
        }
    }
}

/// The bytes after the function code (meta bytes, data, checksum) when the function
/// code alone tells how many: every libmodbus-framed message whose data length does
/// not come from its meta bytes. `None` for the others and, when `extended`, for
/// the extended function codes.
pub fn length_after_function(framing: Framing, kind: MsgKind, extended: bool, function: u8) -> Option<usize> {
    if (extended && is_extended(kind, function)) || data_needs_meta(kind, function) {
        return None;
    }
    Some(meta_length(kind, function) + framing.checksum_length())
}

/// Function codes libmodbus does not frame (it reads only up to the function code
/// for them, so their requests and responses were truncated: its issues #340, #343,
/// #493). Their layouts come from the protocol; the helpers below give the length.
pub const fn is_extended(kind: MsgKind, function: u8) -> bool {
    match kind {
        MsgKind::Indication => matches!(function, 0x08 | 0x14 | 0x15 | 0x18 | 0x2B),
        MsgKind::Confirmation => matches!(function, 0x08 | 0x0B | 0x0C | 0x14 | 0x15 | 0x18 | 0x2B),
    }
}

/// `MEI_READ_DEVICE_ID`: the MEI type of FC 0x2B that carries device identification.
pub const MEI_READ_DEVICE_ID: u8 = 0x0E;

/// For an extended function code: the length of header + PDU as far as the first
/// `msg.len()` bytes tell it. When the result equals `msg.len()` the PDU is whole;
/// otherwise read up to the result and ask again. `known_total` is the length of
/// header + PDU known from elsewhere, used only where the PDU itself has no length
/// (FC 08 and MEI types other than device identification): 6 + the MBAP length field
/// on TCP, or, for a response on a serial line, the length of the request it answers
/// (every diagnostics answer is as long as its request).
pub fn extended_length(kind: MsgKind, h: usize, msg: &[u8], known_total: Option<usize>) -> usize {
    let mbap_total = known_total;
    let fc_end = h + 1;
    let at_least = |n: usize| n.max(msg.len());
    // Bytes up to a one-byte count at `at`, then the counted bytes.
    let counted8 = |at: usize| if msg.len() <= at { at + 1 } else { at + 1 + msg[at] as usize };
    let by_mbap = |floor: usize| mbap_total.filter(|&t| t >= floor).unwrap_or(floor);
    match (kind, msg[h]) {
        (_, 0x08) => by_mbap(fc_end + 4),
        (MsgKind::Confirmation, 0x0B) => fc_end + 4,
        (MsgKind::Confirmation, 0x0C) | (_, 0x14) | (_, 0x15) => counted8(fc_end),
        (MsgKind::Indication, 0x18) => fc_end + 2,
        (MsgKind::Confirmation, 0x18) => {
            if msg.len() < fc_end + 2 {
                fc_end + 2
            } else {
                fc_end + 2 + (((msg[fc_end] as usize) << 8) | msg[fc_end + 1] as usize)
            }
        }
        (MsgKind::Indication, 0x2B) => fc_end + 3,
        (MsgKind::Confirmation, 0x2B) => {
            if msg.len() <= fc_end {
                return fc_end + 1;
            }
            if msg[fc_end] != MEI_READ_DEVICE_ID {
                return by_mbap(fc_end + 1);
            }
            // MEI type, read code, conformity, more follows, next object, count.
            let objects_at = fc_end + 6;
            if msg.len() < objects_at {
                return objects_at;
            }
            let mut pos = objects_at;
            for _ in 0..msg[objects_at - 1] {
                if msg.len() < pos + 2 {
                    return pos + 2;
                }
                pos += 2 + msg[pos + 1] as usize;
                if msg.len() < pos {
                    return pos;
                }
            }
            pos
        }
        _ => at_least(fc_end),
    }
}

/// The length of the message at the start of `bytes` when `bytes` already holds all
/// of it and it is framed by libmodbus's three steps (function code, meta bytes, data
/// and checksum): what an [`Assembler`] fed with `bytes` would complete at, computed in
/// one go. `None` when the assembler must run: the message is not whole yet, its
/// function code is an extended one ([`is_extended`], when `extended`), or it announces
/// more than the framing's maximum ADU (an error the assembler reports).
pub fn complete_length(framing: Framing, kind: MsgKind, extended: bool, bytes: &[u8]) -> Option<usize> {
    let h = framing.header_length();
    let function = *bytes.get(h)?;
    if extended && is_extended(kind, function) {
        return None;
    }
    let meta_end = h + 1 + meta_length(kind, function);
    let head = bytes.get(..meta_end)?;
    let total = meta_end + data_length(kind, h, head) + framing.checksum_length();
    (total <= framing.max_adu_length() && total <= bytes.len()).then_some(total)
}

/// The three steps of reading one message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Step {
    Function,
    Meta,
    Data,
    /// An extended function code, its length found piece by piece.
    Extended,
}

/// Sans-I/O assembler of one incoming message.
///
/// The transport asks [`Assembler::wanted`] how many bytes to read at most, appends
/// what it got to the buffer, and reports it with [`Assembler::received`]. It never
/// asks for more than the message needs, so bytes of the next message stay in the
/// kernel (this is how libmodbus frames RTU without silence detection).
#[derive(Clone, Debug)]
pub struct Assembler {
    framing: Framing,
    kind: MsgKind,
    /// Frame the function codes beyond libmodbus whole (see [`is_extended`]).
    extended: bool,
    /// Length of header + PDU known from the request (see [`extended_length`]).
    known_total: Option<usize>,
    /// An RTU diagnostics request whose CRC did not match at its shortest length:
    /// reading on, two bytes (one data word) at a time.
    crc_search: bool,
    step: Step,
    length: usize,
    wanted: usize,
}

/// What the assembler knows after some bytes arrived.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Read up to this many more bytes.
    NeedMore(usize),
    /// The message is complete with this total length.
    Complete(usize),
}

impl Assembler {
    /// An assembler as libmodbus frames messages, except that responses of the
    /// function codes beyond libmodbus are read whole (libmodbus truncates them).
    /// Requests of those codes are framed as libmodbus does (up to the function
    /// code) unless [`Assembler::extended_requests`] says otherwise, so that a server
    /// not configured for them behaves exactly like libmodbus.
    pub fn new(framing: Framing, kind: MsgKind) -> Self {
        let extended = kind == MsgKind::Confirmation;
        Assembler {
            framing,
            kind,
            extended,
            known_total: None,
            crc_search: false,
            step: Step::Function,
            length: 0,
            wanted: framing.header_length() + 1,
        }
    }

    /// The length of header + PDU the response to a diagnostics request must have
    /// (the request's own), for serial framings where the PDU carries no length.
    pub fn expecting(mut self, total: Option<usize>) -> Self {
        self.known_total = total;
        self
    }

    /// True while an RTU diagnostics request is being extended in search of its CRC:
    /// if the line goes quiet now, the frame ends here (and its CRC is bad).
    pub fn searching_crc(&self) -> bool {
        self.crc_search
    }

    /// Frames requests of the function codes beyond libmodbus whole, for a server
    /// configured to answer them.
    pub fn extended_requests(mut self, on: bool) -> Self {
        if self.kind == MsgKind::Indication {
            self.extended = on;
        }
        self
    }

    /// A diagnostics request on RTU has no length field: "return query data" may
    /// carry any number of words. It ends where its CRC matches; until then read one
    /// more word, up to the largest ADU.
    fn search_crc(&mut self, buf: &[u8]) -> Progress {
        let frame = &buf[..self.length];
        let matches = crate::crc::stored_crc(frame) == Some(crate::crc::crc16(&frame[..frame.len() - 2]));
        if matches || self.length + 2 > self.framing.max_adu_length() {
            self.crc_search = false;
            return Progress::Complete(self.length);
        }
        self.wanted = 2;
        Progress::NeedMore(2)
    }

    /// Bytes received so far.
    pub fn len(&self) -> usize {
        self.length
    }

    pub fn is_empty(&self) -> bool {
        self.length == 0
    }

    /// Most bytes to read next (never past the end of the message).
    pub fn wanted(&self) -> usize {
        self.wanted
    }

    /// Accounts for `n` new bytes appended to `buf` (which holds the whole message so
    /// far). Fails with `EMBBADDATA` when the announced length exceeds the framing's
    /// maximum ADU: the caller's buffer is never written past that maximum.
    pub fn received(&mut self, buf: &[u8], n: usize) -> Result<Progress> {
        debug_assert!(n <= self.wanted);
        self.length += n;
        self.wanted -= n;
        if self.wanted > 0 {
            return Ok(Progress::NeedMore(self.wanted));
        }
        let h = self.framing.header_length();
        if self.step == Step::Function && self.extended && is_extended(self.kind, buf[h]) {
            self.step = Step::Extended;
        }
        if self.crc_search || self.step == Step::Extended {
            return self.received_extended(buf);
        }
        self.received_in_steps(buf)
    }

    /// The three libmodbus steps: function code, meta bytes, data and checksum.
    #[inline]
    fn received_in_steps(&mut self, buf: &[u8]) -> Result<Progress> {
        let h = self.framing.header_length();
        if self.step == Step::Function {
            let meta = meta_length(self.kind, buf[h]);
            if meta != 0 && !data_needs_meta(self.kind, buf[h]) {
                // No data: the meta bytes and the checksum end the message.
                self.step = Step::Data;
                self.wanted = meta + self.framing.checksum_length();
                return Ok(Progress::NeedMore(self.wanted));
            }
            if meta != 0 {
                self.step = Step::Meta;
                self.wanted = meta;
                return Ok(Progress::NeedMore(meta));
            }
            self.step = Step::Meta;
        }
        if self.step == Step::Meta {
            let data = data_length(self.kind, h, &buf[..self.length]) + self.framing.checksum_length();
            if self.length + data > self.framing.max_adu_length() {
                return Err(Error::BAD_DATA);
            }
            self.step = Step::Data;
            self.wanted = data;
            if data > 0 {
                return Ok(Progress::NeedMore(data));
            }
        }
        Ok(Progress::Complete(self.length))
    }

    /// An extended function code (its length found piece by piece), or an RTU
    /// diagnostics request searching for its CRC.
    #[inline(never)]
    fn received_extended(&mut self, buf: &[u8]) -> Result<Progress> {
        let h = self.framing.header_length();
        if self.crc_search {
            return Ok(self.search_crc(buf));
        }
        let known = match self.framing {
            Framing::Tcp => Some(6 + (((buf[4] as usize) << 8) | buf[5] as usize)),
            _ => self.known_total,
        };
        let body = extended_length(self.kind, h, &buf[..self.length], known);
        if body > self.length {
            if body + self.framing.checksum_length() > self.framing.max_adu_length() {
                return Err(Error::BAD_DATA);
            }
            self.wanted = body - self.length;
            return Ok(Progress::NeedMore(self.wanted));
        }
        // The PDU is whole: only the checksum is left.
        self.step = Step::Data;
        self.wanted = self.framing.checksum_length();
        self.crc_search = self.framing == Framing::Rtu && self.kind == MsgKind::Indication && buf[h] == fc::DIAGNOSTICS;
        if self.wanted > 0 {
            return Ok(Progress::NeedMore(self.wanted));
        }
        Ok(Progress::Complete(self.length))
    }
}

/// Result of checking an RTU frame's integrity (CRC first, then the slave filter, as
/// libmodbus 3.1.11+ does).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RtuIntegrity {
    Ok,
    /// CRC mismatch: (received, computed).
    BadCrc(u16, u16),
    /// Addressed to another slave: (frame's slave, ours).
    OtherSlave(u8, i32),
}

/// Checks a complete RTU frame. `our_slave` is the context's slave (-1 when unset);
/// slave 0 (broadcast) is always accepted.
pub fn rtu_integrity(frame: &[u8], our_slave: i32) -> RtuIntegrity {
    let Some(received) = stored_crc(frame) else {
        return RtuIntegrity::BadCrc(0, 0);
    };
    let computed = crc16(&frame[..frame.len() - 2]);
    if received != computed {
        return RtuIntegrity::BadCrc(received, computed);
    }
    if frame[0] as i32 != our_slave && frame[0] != 0 {
        return RtuIntegrity::OtherSlave(frame[0], our_slave);
    }
    RtuIntegrity::Ok
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feeds `msg` to an assembler in pieces of at most `chunk` bytes.
    fn assemble(framing: Framing, kind: MsgKind, msg: &[u8], chunk: usize) -> Result<usize> {
        feed(Assembler::new(framing, kind), msg, chunk)
    }

    /// The same with the extended function codes framed on the server side too.
    fn assemble_ext(framing: Framing, kind: MsgKind, msg: &[u8], chunk: usize) -> Result<usize> {
        feed(Assembler::new(framing, kind).extended_requests(true), msg, chunk)
    }

    fn feed(mut a: Assembler, msg: &[u8], chunk: usize) -> Result<usize> {
        let mut pos = 0;
        loop {
            let n = a.wanted().min(chunk).min(msg.len() - pos);
            assert!(n > 0, "assembler wants bytes the message does not have");
            pos += n;
            match a.received(&msg[..pos], n)? {
                Progress::NeedMore(_) => continue,
                Progress::Complete(len) => return Ok(len),
            }
        }
    }

    /// `complete_length` is the assembler in one go: for pseudo-random byte strings of
    /// every function code, it gives the assembler's length or declines (`None`) where
    /// the assembler would need more bytes, fail, or run its extended step.
    #[test]
    fn complete_length_agrees_with_the_assembler() {
        let mut rng = crate::test_rng::XorShift::new(0x2545_F491_4F6C_DD1D);
        let mut next = || rng.next_u64();
        let mut whole = 0;
        for round in 0..60_000 {
            let framing = [Framing::Rtu, Framing::Tcp, Framing::Ascii][round % 3];
            let kind = if round % 2 == 0 { MsgKind::Indication } else { MsgKind::Confirmation };
            let extended = round % 5 != 0 || kind == MsgKind::Confirmation;
            let len = (next() % 270) as usize;
            let mut bytes: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let h = framing.header_length();
            if len > h {
                bytes[h] = (next() % 0x30) as u8; // mostly known function codes
            }
            if len > h + 5 && next() % 2 == 0 {
                bytes[h + 5] = (next() % 40) as u8; // byte counts that fit
                bytes[h + 1] = (next() % 40) as u8;
            }
            if len > h {
                if let Some(rest) = length_after_function(framing, kind, extended, bytes[h]) {
                    let whole = &bytes[..(h + 1 + rest).min(len)];
                    let asm = Assembler::new(framing, kind).extended_requests(extended);
                    let expected = (whole.len() == h + 1 + rest).then_some(Ok(h + 1 + rest));
                    assert_eq!(feed_available(asm, whole), expected, "{framing:?} {kind:?} {bytes:02x?}");
                }
            }
            let fast = complete_length(framing, kind, extended, &bytes);
            let asm = Assembler::new(framing, kind).extended_requests(extended);
            let uses_extended = len > h && extended && is_extended(kind, bytes[h]);
            let slow = (len > 0).then(|| feed_available(asm, &bytes)).flatten();
            match fast {
                Some(n) => {
                    whole += 1;
                    assert_eq!(slow, Some(Ok(n)), "{framing:?} {kind:?} {bytes:02x?}");
                }
                None => assert!(
                    uses_extended || !matches!(slow, Some(Ok(_))),
                    "declined a whole message: {framing:?} {kind:?} {bytes:02x?} -> {slow:?}"
                ),
            }
        }
        assert!(whole > 10_000, "too few whole messages generated: {whole}");
    }

    #[test]
    fn data_needs_meta_is_exactly_where_data_length_reads_them() {
        for kind in [MsgKind::Indication, MsgKind::Confirmation] {
            for function in 0..=255u8 {
                for h in [1, 7] {
                    let mut msg = [0u8; 32];
                    msg[h] = function;
                    let zero = data_length(kind, h, &msg);
                    msg[h + 1..].fill(0x5A);
                    let filled = data_length(kind, h, &msg);
                    assert_eq!(zero, 0, "{kind:?} {function:#x}");
                    assert_eq!(filled != 0, data_needs_meta(kind, function), "{kind:?} {function:#x}");
                }
            }
        }
    }

    /// Feeds what `bytes` has; `None` when the message needs more.
    fn feed_available(mut a: Assembler, bytes: &[u8]) -> Option<Result<usize>> {
        let mut pos = 0;
        loop {
            let n = a.wanted().min(bytes.len() - pos);
            if n == 0 {
                return None;
            }
            pos += n;
            match a.received(&bytes[..pos], n) {
                Ok(Progress::NeedMore(_)) => continue,
                Ok(Progress::Complete(len)) => return Some(Ok(len)),
                Err(e) => return Some(Err(e)),
            }
        }
    }

    #[test]
    fn rtu_read_holding_request_and_response_lengths() {
        let req = [0x11, 0x03, 0x00, 0x6B, 0x00, 0x03, 0x76, 0x87];
        for chunk in [1, 2, 3, 256] {
            assert_eq!(assemble(Framing::Rtu, MsgKind::Indication, &req, chunk), Ok(8));
        }
        let mut rsp = vec![0x11, 0x03, 0x06, 0xAE, 0x41, 0x56, 0x52, 0x43, 0x40];
        let crc = crc16(&rsp);
        rsp.extend(crc.to_le_bytes());
        assert_eq!(assemble(Framing::Rtu, MsgKind::Confirmation, &rsp, 1), Ok(11));
    }

    #[test]
    fn tcp_lengths_ignore_mbap_length_field() {
        // MBAP length says 99; the PDU says write single coil (4 bytes after FC).
        let req = [0, 1, 0, 0, 0, 99, 0xFF, 0x05, 0x01, 0x30, 0xFF, 0x00];
        assert_eq!(assemble(Framing::Tcp, MsgKind::Indication, &req, 256), Ok(12));
        // Unknown function code: only header + FC is read, as libmodbus does.
        let req = [0, 1, 0, 0, 0, 2, 0xFF, 0x42, 0xAA, 0xBB];
        assert_eq!(assemble(Framing::Tcp, MsgKind::Indication, &req, 256), Ok(8));
        // Exception confirmation: header + FC + code.
        let rsp = [0, 1, 0, 0, 0, 3, 0xFF, 0x83, 0x02];
        assert_eq!(assemble(Framing::Tcp, MsgKind::Confirmation, &rsp, 1), Ok(9));
    }

    fn rtu(body: &[u8]) -> Vec<u8> {
        let mut v = body.to_vec();
        v.extend(crc16(body).to_le_bytes());
        v
    }

    #[test]
    fn extended_function_codes_are_read_whole() {
        let i = MsgKind::Indication;
        let c = MsgKind::Confirmation;
        let cases: Vec<(MsgKind, Vec<u8>)> = vec![
            // Diagnostics, return query data: sub-function + one word.
            (i, rtu(&[0x11, 0x08, 0x00, 0x00, 0xA5, 0x37])),
            (c, rtu(&[0x11, 0x08, 0x00, 0x00, 0xA5, 0x37])),
            // Comm event counter and log.
            (c, rtu(&[0x11, 0x0B, 0xFF, 0xFF, 0x01, 0x08])),
            (c, rtu(&[0x11, 0x0C, 0x08, 0x00, 0x00, 0x01, 0x08, 0x01, 0x21, 0x20, 0x00])),
            // Read file record: one sub-request; its response.
            (i, rtu(&[0x11, 0x14, 0x07, 0x06, 0x00, 0x04, 0x00, 0x01, 0x00, 0x02])),
            (c, rtu(&[0x11, 0x14, 0x06, 0x05, 0x06, 0x0D, 0xFE, 0x00, 0x20])),
            // Write file record request (echoed as the response).
            (i, rtu(&[0x11, 0x15, 0x09, 0x06, 0x00, 0x04, 0x00, 0x07, 0x00, 0x01, 0x06, 0xAF])),
            // FIFO queue: pointer address; response with a two-byte byte count.
            (i, rtu(&[0x11, 0x18, 0x04, 0xDE])),
            (c, rtu(&[0x11, 0x18, 0x00, 0x06, 0x00, 0x02, 0x01, 0xB8, 0x12, 0x84])),
            // Device identification request and a two-object response.
            (i, rtu(&[0x11, 0x2B, 0x0E, 0x01, 0x00])),
            (c, rtu(&[0x11, 0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x02, 0x00, 0x03, b'A', b'B', b'C', 0x01, 0x01, b'Z'])),
        ];
        for (kind, frame) in cases {
            for chunk in [1, 3, 256] {
                assert_eq!(assemble_ext(Framing::Rtu, kind, &frame, chunk), Ok(frame.len()), "{kind:?} {frame:02X?}");
            }
        }
        // A server not configured for them frames requests as libmodbus does: up to
        // the function code, then two bytes taken as the CRC.
        let req = rtu(&[0x11, 0x2B, 0x0E, 0x01, 0x00]);
        let mut a = Assembler::new(Framing::Rtu, MsgKind::Indication);
        a.received(&req[..2], 2).unwrap();
        assert_eq!(a.received(&req[..4], 2), Ok(Progress::Complete(4)));
    }

    #[test]
    fn rtu_diagnostics_of_any_length() {
        // Return query data with three words.
        let frame = rtu(&[0x11, 0x08, 0x00, 0x00, 0x12, 0x34, 0x56, 0x78, 0x9A, 0xBC]);
        // A client knows the answer's length from its request.
        let asm = Assembler::new(Framing::Rtu, MsgKind::Confirmation).expecting(Some(10));
        assert_eq!(feed(asm, &frame, 1), Ok(12));
        // A server reads on, a word at a time, until the CRC matches.
        for chunk in [1, 2, 256] {
            assert_eq!(assemble_ext(Framing::Rtu, MsgKind::Indication, &frame, chunk), Ok(12));
        }
        // A one-word request is complete at once.
        let short = rtu(&[0x11, 0x08, 0x00, 0x0B, 0x00, 0x00]);
        assert_eq!(assemble_ext(Framing::Rtu, MsgKind::Indication, &short, 256), Ok(8));
        // A corrupted one keeps searching (the engine ends it when the line goes
        // quiet, as a CRC error).
        let mut bad = short.clone();
        bad[7] ^= 0xFF;
        let mut a = Assembler::new(Framing::Rtu, MsgKind::Indication).extended_requests(true);
        a.received(&bad[..2], 2).unwrap();
        a.received(&bad[..6], 4).unwrap();
        assert_eq!(a.received(&bad, 2), Ok(Progress::NeedMore(2)));
        assert!(a.searching_crc());
    }

    #[test]
    fn tcp_diagnostics_use_the_mbap_length() {
        // Return query data with three words: the PDU has no count, MBAP says 10.
        let req = [0, 1, 0, 0, 0, 10, 0x11, 0x08, 0, 0, 1, 2, 3, 4, 5, 6];
        assert_eq!(assemble_ext(Framing::Tcp, MsgKind::Indication, &req, 256), Ok(16));
        assert_eq!(assemble(Framing::Tcp, MsgKind::Confirmation, &req, 1), Ok(16));
        // A length field that is too small falls back to one word.
        let short = [0, 1, 0, 0, 0, 1, 0x11, 0x08, 0, 0, 1, 2];
        assert_eq!(assemble_ext(Framing::Tcp, MsgKind::Indication, &short, 256), Ok(12));
        // One too large for the ADU is refused.
        let mut a = Assembler::new(Framing::Tcp, MsgKind::Indication).extended_requests(true);
        let huge = [0, 1, 0, 0, 1, 0, 0x11, 0x08];
        assert_eq!(a.received(&huge, 8), Err(Error::BAD_DATA));
    }

    #[test]
    fn device_identification_with_too_many_objects_is_refused() {
        let mut msg = vec![0x11, 0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0xFF];
        let mut a = Assembler::new(Framing::Rtu, MsgKind::Confirmation);
        let mut fed = 0;
        let err = loop {
            let want = a.wanted();
            while msg.len() < fed + want {
                msg.push(0xFF); // every object claims 255 bytes
            }
            fed += want;
            match a.received(&msg[..fed], want) {
                Ok(Progress::NeedMore(_)) => continue,
                other => break other,
            }
        };
        assert_eq!(err, Err(Error::BAD_DATA));
        assert!(fed <= RTU_MAX_ADU_LENGTH);
    }

    #[test]
    fn write_multiple_indication_uses_byte_count() {
        let req = [0, 1, 0, 0, 0, 11, 1, 0x10, 0, 0, 0, 2, 4, 0, 1, 0, 2];
        assert_eq!(assemble(Framing::Tcp, MsgKind::Indication, &req, 256), Ok(17));
        let req = [0, 1, 0, 0, 0, 0, 1, 0x17, 0, 0, 0, 1, 0, 0, 0, 1, 2, 0, 7];
        assert_eq!(assemble(Framing::Tcp, MsgKind::Indication, &req, 3), Ok(19));
    }

    #[test]
    fn too_many_data_is_refused_before_reading_it() {
        // RTU response claiming 255 data bytes: 3 + 255 + 2 > 256.
        let rsp = [0x01, 0x03, 0xFF];
        let mut a = Assembler::new(Framing::Rtu, MsgKind::Confirmation);
        assert_eq!(a.received(&rsp[..2], 2), Ok(Progress::NeedMore(1)));
        assert_eq!(a.received(&rsp, 1), Err(Error::BAD_DATA));
        // TCP indication: write registers with byte count 255 fits 260 only up to 248.
        let mut req = vec![0, 1, 0, 0, 0, 0, 1, 0x10, 0, 0, 0, 2, 249];
        let mut a = Assembler::new(Framing::Tcp, MsgKind::Indication);
        assert_eq!(a.received(&req[..8], 8), Ok(Progress::NeedMore(5)));
        assert_eq!(a.received(&req, 5), Err(Error::BAD_DATA));
        req[12] = 247;
        let mut a = Assembler::new(Framing::Tcp, MsgKind::Indication);
        a.received(&req[..8], 8).unwrap();
        assert_eq!(a.received(&req, 5), Ok(Progress::NeedMore(247)));
    }

    #[test]
    fn seal_writes_mbap_length_and_crc() {
        let mut buf = [0u8; 16];
        let n = Framing::Tcp.write_header(&mut buf, 0xFF, 0x0102);
        buf[n..n + 5].copy_from_slice(&[0x05, 0x01, 0x30, 0xFF, 0x00]);
        assert_eq!(Framing::Tcp.seal(&mut buf, n + 5), 12);
        assert_eq!(buf[..12], [1, 2, 0, 0, 0, 6, 0xFF, 0x05, 0x01, 0x30, 0xFF, 0x00]);
        let n = Framing::Rtu.write_header(&mut buf, 0x11, 7);
        buf[n..n + 5].copy_from_slice(&[0x05, 0x01, 0x30, 0xFF, 0x00]);
        assert_eq!(Framing::Rtu.seal(&mut buf, n + 5), 8);
        assert_eq!(buf[..8], [0x11, 0x05, 0x01, 0x30, 0xFF, 0x00, 0x8F, 0x59]);
    }

    #[test]
    fn rtu_integrity_checks_crc_before_slave() {
        let good = [0x11, 0x05, 0x01, 0x30, 0xFF, 0x00, 0x8F, 0x59];
        assert_eq!(rtu_integrity(&good, 0x11), RtuIntegrity::Ok);
        assert_eq!(rtu_integrity(&good, 0x12), RtuIntegrity::OtherSlave(0x11, 0x12));
        let mut bad = good;
        bad[7] ^= 1;
        // 3.1.11+: a corrupted frame for another slave is a CRC error, not ignored.
        assert!(matches!(rtu_integrity(&bad, 0x12), RtuIntegrity::BadCrc(..)));
        let mut broadcast = [0x00, 0x05, 0x01, 0x30, 0xFF, 0x00, 0, 0];
        let crc = crc16(&broadcast[..6]);
        broadcast[6..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(rtu_integrity(&broadcast, 0x11), RtuIntegrity::Ok);
    }
}
