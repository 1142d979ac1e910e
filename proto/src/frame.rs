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
    #[inline]
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
    /// for TCP, the CRC for RTU. Returns the final length. TCP's two stores are
    /// inlined into every sender; the checksums are a call.
    #[inline(always)]
    pub fn seal(self, buf: &mut [u8], len: usize) -> usize {
        if self == Framing::Tcp {
            let mbap_len = (len - 6) as u16;
            buf[4..6].copy_from_slice(&mbap_len.to_be_bytes());
            return len;
        }
        self.seal_serial(buf, len)
    }

    /// [`Framing::seal`] of a serial framing: the CRC (RTU) or the LRC (ASCII).
    #[inline(never)]
    fn seal_serial(self, buf: &mut [u8], len: usize) -> usize {
        if self == Framing::Rtu {
            let crc = crc16(&buf[..len]);
            buf[len..len + 2].copy_from_slice(&crc.to_le_bytes());
            return len + 2;
        }
        buf[len] = crate::ascii::lrc(&buf[..len]);
        len + 1
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

/// How the bytes after a function code are laid out, as far as their length goes:
/// one row of the function-code table ([`layout`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// This many bytes follow the function code.
    Fixed(u8),
    /// This many bytes follow the function code, the last of them a count of the
    /// bytes after it.
    Counted(u8),
    /// A two-byte count of the bytes after it (FIFO queue responses).
    Counted16,
    /// At least this many bytes; the real length comes from outside the PDU (the
    /// MBAP length on TCP, the request's length for a serial response, the frame's
    /// delimiters on ASCII): diagnostics, and MEI types other than device
    /// identification.
    Known(u8),
    /// A device-identification response: MEI type, read code, conformity, more
    /// follows, next object, count, then `count` objects (id, length, value).
    DeviceId,
    /// A function code the table does not know (user-defined codes 65-72 and
    /// 100-110, vendors' own): nothing in the PDU tells its length. It comes from
    /// outside: the MBAP length on TCP, the frame's delimiters on ASCII; on RTU the
    /// frame ends at the first length whose CRC matches, or where the line goes
    /// quiet (see [`Rules::crc_search_step`]).
    Open,
}

/// The function-code table: the layout of `function`'s requests (`Indication`) or
/// responses (`Confirmation`). `extended` frames the function codes beyond libmodbus
/// by their own layouts; off, they are framed as libmodbus frames them (up to the
/// function code for a request, one byte more for a response: its issues #340, #343,
/// #493), so that a server not configured for them behaves exactly like libmodbus.
/// Unknown function codes (and exception responses) are libmodbus's too, but for the
/// requests a server beyond libmodbus takes whole.
pub const fn layout(kind: MsgKind, extended: bool, function: u8) -> Layout {
    use Layout::*;
    match kind {
        MsgKind::Indication => match function {
            0x00..=fc::WRITE_SINGLE_REGISTER => Fixed(4),
            fc::WRITE_MULTIPLE_COILS | fc::WRITE_MULTIPLE_REGISTERS => Counted(5),
            fc::MASK_WRITE_REGISTER => Fixed(6),
            fc::WRITE_AND_READ_REGISTERS => Counted(9),
            fc::DIAGNOSTICS if extended => Known(4),
            fc::READ_FILE_RECORD | fc::WRITE_FILE_RECORD if extended => Counted(1),
            fc::READ_FIFO_QUEUE if extended => Fixed(2),
            fc::ENCAPSULATED_INTERFACE if extended => Fixed(3),
            // Requests of nothing but their function code.
            fc::READ_EXCEPTION_STATUS | fc::GET_COMM_EVENT_COUNTER | fc::GET_COMM_EVENT_LOG | fc::REPORT_SLAVE_ID => {
                Fixed(0)
            }
            // A server beyond libmodbus takes a request it does not know whole (the
            // MBAP length on TCP, the frame on ASCII, the CRC on RTU) for the
            // application to answer.
            _ if extended => Open,
            _ => Fixed(0),
        },
        MsgKind::Confirmation => match function {
            0x00..=fc::READ_INPUT_REGISTERS | fc::REPORT_SLAVE_ID | fc::WRITE_AND_READ_REGISTERS => Counted(1),
            fc::WRITE_SINGLE_COIL
            | fc::WRITE_SINGLE_REGISTER
            | fc::WRITE_MULTIPLE_COILS
            | fc::WRITE_MULTIPLE_REGISTERS => Fixed(4),
            fc::MASK_WRITE_REGISTER => Fixed(6),
            fc::DIAGNOSTICS if extended => Known(4),
            fc::GET_COMM_EVENT_COUNTER if extended => Fixed(4),
            fc::GET_COMM_EVENT_LOG | fc::READ_FILE_RECORD | fc::WRITE_FILE_RECORD if extended => Counted(1),
            fc::READ_FIFO_QUEUE if extended => Counted16,
            fc::ENCAPSULATED_INTERFACE if extended => DeviceId,
            // Read Exception Status (a status byte), and every exception response
            // (its code): libmodbus's one byte.
            fc::READ_EXCEPTION_STATUS => Fixed(1),
            0x80..=0xFF => Fixed(1),
            // A code the table does not know: its answer is taken whole (libmodbus
            // cuts it to one byte after the function code).
            _ if extended => Open,
            _ => Fixed(1),
        },
    }
}

/// [`layout`] for every function code, kind and `extended`, computed at compile
/// time: the readers of messages look a row up instead of walking the match.
static TABLE: [[Layout; 256]; 4] = {
    let mut t = [[Layout::Fixed(0); 256]; 4];
    let mut i = 0;
    while i < 4 {
        let kind = if i < 2 { MsgKind::Indication } else { MsgKind::Confirmation };
        let mut f = 0;
        while f < 256 {
            t[i][f] = layout(kind, i % 2 == 1, f as u8);
            f += 1;
        }
        i += 1;
    }
    t
};

/// [`layout`], looked up.
#[inline(always)]
fn row(kind: MsgKind, extended: bool, function: u8) -> Layout {
    let i = (kind == MsgKind::Confirmation) as usize * 2 + extended as usize;
    TABLE[i][function as usize]
}

/// The function codes beyond libmodbus, as the table says: those whose requests or
/// responses the `extended` flag frames differently (see [`layout`]). The one list
/// of them; the response checks ask it.
pub fn beyond_libmodbus(function: u8) -> bool {
    let request = layout(MsgKind::Indication, true, function);
    let response = layout(MsgKind::Confirmation, true, function);
    let unknown = request == Layout::Open || response == Layout::Open;
    !unknown
        && (request != layout(MsgKind::Indication, false, function)
            || response != layout(MsgKind::Confirmation, false, function))
}

/// `MEI_READ_DEVICE_ID`: the MEI type of FC 0x2B that carries device identification.
pub const MEI_READ_DEVICE_ID: u8 = 0x0E;

/// How one incoming message is framed: what [`message_length`] needs besides its bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rules {
    pub framing: Framing,
    pub kind: MsgKind,
    /// Frame the function codes beyond libmodbus by their own layouts (see [`layout`]).
    pub extended: bool,
    /// The length of header + PDU known from elsewhere, for [`Layout::Known`]: on a
    /// serial line, the request's length for its response (every diagnostics answer
    /// is as long as its request), or an ASCII frame's decoded length. TCP uses the
    /// MBAP length field instead.
    pub known_total: Option<usize>,
}

impl Rules {
    /// Libmodbus's framing, with the extended responses read whole (a client).
    pub const fn new(framing: Framing, kind: MsgKind) -> Self {
        Rules { framing, kind, extended: matches!(kind, MsgKind::Confirmation), known_total: None }
    }

    /// An RTU message whose PDU does not tell its length ends where its CRC
    /// matches: this many bytes at a time past the least it can be (`None`: its
    /// length is known). A diagnostics request on a server that answers it ("return
    /// query data" may carry any number of words) goes one word at a time; a
    /// function code the table does not know ([`Layout::Open`]), one byte at a time.
    #[inline]
    pub fn crc_search_step(&self, msg: &[u8]) -> Option<usize> {
        if self.framing != Framing::Rtu || !self.extended {
            return None;
        }
        let &function = msg.get(self.framing.header_length())?;
        match row(self.kind, true, function) {
            Layout::Open => Some(1),
            _ if self.kind == MsgKind::Indication && function == fc::DIAGNOSTICS => Some(2),
            _ => None,
        }
    }

    /// See [`Rules::crc_search_step`].
    #[inline]
    pub fn searches_crc(&self, msg: &[u8]) -> bool {
        self.crc_search_step(msg).is_some()
    }
}

/// What the first bytes of a message tell of its length.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Length {
    /// The whole message (header, PDU, checksum) is this long.
    Total(usize),
    /// Nothing more can be told before this many bytes are there.
    Need(usize),
}

/// The message-length function: how long the message that starts `msg` is, as far
/// as its first `msg.len()` bytes tell, from the function-code table ([`layout`]).
/// Lengths come from the content, as libmodbus computes them (the MBAP length field
/// is only used where the PDU has no length of its own). Every reader of messages
/// asks this one function: the [`Assembler`], [`Assembler::whole`], the server's
/// `request_extent`.
#[inline]
pub fn message_length(rules: Rules, msg: &[u8]) -> Length {
    let h = rules.framing.header_length();
    let checksum = rules.framing.checksum_length();
    let Some(&function) = msg.get(h) else { return Length::Need(h + 1) };
    let fc_end = h + 1;
    let pdu_end = match row(rules.kind, rules.extended, function) {
        Layout::Fixed(n) => fc_end + n as usize,
        Layout::Counted(n) => {
            let meta_end = fc_end + n as usize;
            match msg.get(meta_end - 1) {
                Some(&count) if n > 0 => meta_end + count as usize,
                _ => return Length::Need(meta_end),
            }
        }
        Layout::Counted16 => match msg.get(fc_end..fc_end + 2) {
            Some(&[hi, lo]) => fc_end + 2 + u16::from_be_bytes([hi, lo]) as usize,
            _ => return Length::Need(fc_end + 2),
        },
        Layout::Known(min) => known_end(rules, msg, fc_end + min as usize),
        Layout::Open => open_end(rules, msg, fc_end),
        Layout::DeviceId => match msg.get(fc_end) {
            None => return Length::Need(fc_end + 1),
            Some(&mei) if mei != MEI_READ_DEVICE_ID => known_end(rules, msg, fc_end + 1),
            Some(_) => {
                // MEI type, read code, conformity, more follows, next object, count.
                let objects_at = fc_end + 6;
                let Some(&count) = msg.get(objects_at - 1) else { return Length::Need(objects_at) };
                let mut pos = objects_at;
                for _ in 0..count {
                    let Some(&len) = msg.get(pos + 1) else { return Length::Need(pos + 2) };
                    pos += 2 + len as usize;
                    if msg.len() < pos {
                        return Length::Need(pos);
                    }
                }
                pos
            }
        },
    };
    Length::Total(pdu_end + checksum)
}

/// The end of the PDU of a function code the table does not know
/// ([`Layout::Open`]): as [`known_end`], but a TCP message whose protocol identifier
/// is not Modbus's has no MBAP length to trust (bytes of another message, out of
/// step): libmodbus's one byte after the code. Apart, so that the usual messages'
/// length stays a short function.
#[cold]
#[inline(never)]
fn open_end(rules: Rules, msg: &[u8], fc_end: usize) -> usize {
    match (rules.framing, msg.get(2..4)) {
        (Framing::Tcp, Some(&[hi, lo])) if (hi, lo) != (0, 0) => fc_end + 1,
        _ => known_end(rules, msg, fc_end),
    }
}

/// The end of a PDU whose length comes from outside it ([`Layout::Known`]): the MBAP
/// length on TCP, else `known_total`; never below `floor`.
fn known_end(rules: Rules, msg: &[u8], floor: usize) -> usize {
    let known = match (rules.framing, msg.get(4..6)) {
        (Framing::Tcp, Some(&[hi, lo])) => Some(6 + u16::from_be_bytes([hi, lo]) as usize),
        _ => rules.known_total,
    };
    known.filter(|&t| t >= floor).unwrap_or(floor)
}

/// The length of the message `bytes` starts with, when `bytes` holds all of it (see
/// [`Assembler::whole`]).
#[inline]
pub fn whole_length(rules: Rules, bytes: &[u8]) -> Option<usize> {
    let max = rules.framing.max_adu_length();
    let Length::Total(mut total) = message_length(rules, bytes) else { return None };
    if let Some(step) = rules.crc_search_step(bytes) {
        while total <= bytes.len() && !crc_matches(&bytes[..total]) && total + step <= max {
            total += step;
        }
    }
    (total <= max && total <= bytes.len()).then_some(total)
}

/// The CRC of an RTU frame matches its content.
pub fn crc_matches(frame: &[u8]) -> bool {
    frame.len() >= 2 && stored_crc(frame) == Some(crc16(&frame[..frame.len() - 2]))
}

/// What the assembler knows after some bytes arrived.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Read up to this many more bytes.
    NeedMore(usize),
    /// The message is complete with this total length.
    Complete(usize),
}

/// Sans-I/O assembler of one incoming message.
///
/// The transport asks [`Assembler::wanted`] how many bytes to read at most, appends
/// what it got to the buffer, and reports it with [`Assembler::received`]. It never
/// asks for more than the message needs, so bytes of the next message stay in the
/// kernel (this is how libmodbus frames RTU without silence detection). The lengths
/// come from [`message_length`].
#[derive(Clone, Debug)]
pub struct Assembler {
    rules: Rules,
    /// An RTU message whose PDU does not tell its length: its CRC decides where it
    /// ends, searched this many bytes at a time (see [`Rules::crc_search_step`]); 0:
    /// no search.
    crc_search: usize,
    length: usize,
    wanted: usize,
}

impl Assembler {
    /// An assembler as libmodbus frames messages, except that responses of the
    /// function codes beyond libmodbus are read whole (libmodbus truncates them).
    /// Requests of those codes are framed as libmodbus does (up to the function
    /// code) unless [`Assembler::extended_requests`] says otherwise, so that a server
    /// not configured for them behaves exactly like libmodbus.
    pub fn new(framing: Framing, kind: MsgKind) -> Self {
        Assembler { rules: Rules::new(framing, kind), crc_search: 0, length: 0, wanted: framing.header_length() + 1 }
    }

    /// The length of header + PDU the response to a diagnostics request must have
    /// (the request's own), for serial framings where the PDU carries no length.
    pub fn expecting(mut self, total: Option<usize>) -> Self {
        self.rules.known_total = total;
        self
    }

    /// Frames requests of the function codes beyond libmodbus whole, for a server
    /// configured to answer them.
    pub fn extended_requests(mut self, on: bool) -> Self {
        if self.rules.kind == MsgKind::Indication {
            self.rules.extended = on;
        }
        self
    }

    /// True while an RTU message is waiting for the CRC that ends it: if the line
    /// goes quiet now, the frame ends here (and its CRC is bad).
    pub fn searching_crc(&self) -> bool {
        self.crc_search > 0
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

    /// The length of the message `bytes` starts with, when `bytes` holds all of it:
    /// what feeding `bytes` to this (fresh) assembler would complete at, in one go.
    /// `None` when more bytes are needed, or the message announces more than the
    /// framing's maximum (an error [`Assembler::received`] reports).
    #[inline]
    pub fn whole(&self, bytes: &[u8]) -> Option<usize> {
        whole_length(self.rules, bytes)
    }

    /// The length of the whole message when its first bytes `head` already tell it
    /// (no byte count or search needed); `None` otherwise.
    pub fn total_if_known(&self, head: &[u8]) -> Option<usize> {
        match message_length(self.rules, head) {
            Length::Total(total) if !self.rules.searches_crc(head) && total <= self.rules.framing.max_adu_length() => {
                Some(total)
            }
            _ => None,
        }
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
        let msg = &buf[..self.length];
        if self.crc_search > 0 {
            return Ok(self.search_crc(msg));
        }
        let max = self.rules.framing.max_adu_length();
        match message_length(self.rules, msg) {
            Length::Need(need) => {
                if need + self.rules.framing.checksum_length() > max {
                    return Err(Error::BAD_DATA);
                }
                self.wanted = need - self.length;
                Ok(Progress::NeedMore(self.wanted))
            }
            Length::Total(total) if total > max => Err(Error::BAD_DATA),
            Length::Total(total) => {
                self.crc_search = self.rules.crc_search_step(msg).unwrap_or(0);
                if total > self.length {
                    self.wanted = total - self.length;
                    return Ok(Progress::NeedMore(self.wanted));
                }
                if self.crc_search > 0 {
                    return Ok(self.search_crc(msg));
                }
                Ok(Progress::Complete(self.length))
            }
        }
    }

    /// A message searching its CRC ends where it matches; until then read one more
    /// step (a word, a byte), up to the largest ADU.
    fn search_crc(&mut self, frame: &[u8]) -> Progress {
        let step = self.crc_search;
        if crc_matches(frame) || self.length + step > self.rules.framing.max_adu_length() {
            self.crc_search = 0;
            return Progress::Complete(self.length);
        }
        self.wanted = step;
        Progress::NeedMore(step)
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

    /// `Assembler::whole` is the assembler in one go, and `total_if_known` agrees with
    /// it: for pseudo-random byte strings of every function code (the extended ones
    /// included, and the RTU diagnostics search for its CRC), `whole` gives the
    /// assembler's length or declines (`None`) exactly where the assembler would need
    /// more bytes or fail.
    #[test]
    fn the_codes_beyond_libmodbus_come_from_the_table() {
        let beyond: Vec<u8> = (0..=255u8).filter(|&f| beyond_libmodbus(f)).collect();
        assert_eq!(
            beyond,
            [
                fc::DIAGNOSTICS,
                fc::GET_COMM_EVENT_COUNTER,
                fc::GET_COMM_EVENT_LOG,
                fc::READ_FILE_RECORD,
                fc::WRITE_FILE_RECORD,
                fc::READ_FIFO_QUEUE,
                fc::ENCAPSULATED_INTERFACE
            ]
        );
    }

    #[test]
    fn whole_agrees_with_the_assembler() {
        let mut rng = crate::test_rng::XorShift::new(0x2545_F491_4F6C_DD1D);
        let mut next = || rng.next_u64();
        let mut whole = 0;
        for round in 0..60_000 {
            let framing = [Framing::Rtu, Framing::Tcp, Framing::Ascii][round % 3];
            let kind = if round % 2 == 0 { MsgKind::Indication } else { MsgKind::Confirmation };
            let extended = round % 5 != 0 || kind == MsgKind::Confirmation;
            let expecting = (round % 7 == 0).then(|| (next() % 40) as usize);
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
            if framing == Framing::Tcp && len > 6 && next() % 2 == 0 {
                bytes[4] = 0;
                bytes[5] = (next() % 40) as u8; // MBAP lengths that fit
            }
            if framing == Framing::Rtu && len > h + 12 && next() % 3 == 0 {
                // A CRC that matches somewhere (the diagnostics search stops there).
                let end = h + 4 + 2 * (next() % 4) as usize;
                let crc = crc16(&bytes[..end]).to_le_bytes();
                bytes[end..end + 2].copy_from_slice(&crc);
            }
            let asm = || Assembler::new(framing, kind).extended_requests(extended).expecting(expecting);
            if len > h {
                if let Some(total) = asm().total_if_known(&bytes[..h + 1]) {
                    let known = &bytes[..total.min(len)];
                    let expected = (known.len() == total).then_some(Ok(total));
                    assert_eq!(feed_available(asm(), known), expected, "{framing:?} {kind:?} {bytes:02x?}");
                }
            }
            let fast = asm().whole(&bytes);
            let slow = (len > 0).then(|| feed_available(asm(), &bytes)).flatten();
            match fast {
                Some(n) => {
                    whole += 1;
                    assert_eq!(slow, Some(Ok(n)), "{framing:?} {kind:?} {bytes:02x?}");
                }
                None => assert!(
                    !matches!(slow, Some(Ok(_))),
                    "declined a whole message: {framing:?} {kind:?} {bytes:02x?} -> {slow:?}"
                ),
            }
        }
        assert!(whole > 10_000, "too few whole messages generated: {whole}");
    }

    /// The function-code table as libmodbus frames messages (its
    /// `compute_meta_length_after_function` and `compute_data_length_after_meta`),
    /// written out independently: bytes after the function code before the data
    /// length is known, and whether the last of them is a byte count.
    #[test]
    fn the_table_is_libmodbus_s_where_libmodbus_frames() {
        for function in 0..=255u8 {
            let (meta, counted) = match function {
                0x00..=0x06 => (4, false),
                0x0F | 0x10 => (5, true),
                0x16 => (6, false),
                0x17 => (9, true),
                _ => (0, false),
            };
            let expected = if counted { Layout::Counted(meta) } else { Layout::Fixed(meta) };
            assert_eq!(layout(MsgKind::Indication, false, function), expected, "request {function:#x}");
            let (meta, counted) = match function {
                0x01..=0x04 | 0x11 | 0x17 | 0x00 => (1, true),
                0x05 | 0x06 | 0x0F | 0x10 => (4, false),
                0x16 => (6, false),
                _ => (1, false),
            };
            let expected = if counted { Layout::Counted(meta) } else { Layout::Fixed(meta) };
            assert_eq!(layout(MsgKind::Confirmation, false, function), expected, "response {function:#x}");
            // Extended framing changes only the codes beyond libmodbus, and takes the
            // requests libmodbus frames up to their code whole (from the line).
            let beyond = matches!(function, 0x08 | 0x0B | 0x0C | 0x14 | 0x15 | 0x18 | 0x2B);
            assert_eq!(beyond_libmodbus(function), beyond, "beyond libmodbus {function:#x}");
            for kind in [MsgKind::Indication, MsgKind::Confirmation] {
                if beyond {
                    continue;
                }
                let plain = layout(kind, false, function);
                // Unknown codes: a request libmodbus frames up to its code, an answer
                // that is no exception and no Read Exception Status.
                let whole = match kind {
                    MsgKind::Indication => plain == Layout::Fixed(0) && !matches!(function, 0x07 | 0x11),
                    MsgKind::Confirmation => function < 0x80 && function != 0x07 && plain == Layout::Fixed(1),
                };
                let expected = if whole { Layout::Open } else { plain };
                assert_eq!(layout(kind, true, function), expected, "{kind:?} {function:#x}");
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

    /// A function code the table does not know (user-defined 0x41): its answer is
    /// taken whole on every framing (libmodbus keeps the code and one byte): on RTU
    /// up to the first length whose CRC matches, one byte at a time; on TCP by the
    /// MBAP length; on ASCII by the frame. Exception answers keep libmodbus's length.
    #[test]
    fn unknown_function_codes_are_answered_whole() {
        let c = MsgKind::Confirmation;
        let answer = rtu(&[0x11, 0x41, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08]);
        assert_eq!(answer.len(), 12);
        for chunk in [1, 2, 3, 256] {
            assert_eq!(assemble(Framing::Rtu, c, &answer, chunk), Ok(12), "chunk {chunk}");
        }
        // Read whole with more behind it (a client reading ahead): the frame ends at
        // its CRC.
        let mut more = answer.clone();
        more.extend_from_slice(&[0x11, 0x03]);
        assert_eq!(Assembler::new(Framing::Rtu, c).whole(&more), Some(12));
        // An even and an empty PDU body too.
        for body in [&[0x41u8][..], &[0x41, 0xAA][..], &[0x64, 1, 2, 3, 4, 5, 6, 7][..]] {
            let mut adu = vec![0x05];
            adu.extend_from_slice(body);
            let frame = rtu(&adu);
            assert_eq!(assemble(Framing::Rtu, c, &frame, 1), Ok(frame.len()), "{frame:02X?}");
        }
        // The line goes quiet before a CRC matched: the assembler still searches.
        let mut a = Assembler::new(Framing::Rtu, c);
        a.received(&answer[..2], 2).unwrap();
        assert_eq!(a.received(&answer[..4], 2), Ok(Progress::NeedMore(1)));
        assert!(a.searching_crc());
        // TCP: the MBAP length says 10 (unit + 9 bytes of PDU): 16 bytes.
        let tcp = [0x00, 0x01, 0x00, 0x00, 0x00, 0x0A, 0xFF, 0x41, 1, 2, 3, 4, 5, 6, 7, 8];
        for chunk in [1, 7, 256] {
            assert_eq!(assemble(Framing::Tcp, c, &tcp, chunk), Ok(16), "chunk {chunk}");
        }
        // Out of step (a protocol identifier that is not 0): libmodbus's one byte.
        let garbage = [0x06, 0xFF, 0x03, 0x14, 0x00, 0x64, 0x01, 0x41, 1, 2, 3, 4, 5, 6, 7, 8];
        assert_eq!(assemble(Framing::Tcp, c, &garbage, 256), Ok(9));
        // Exception answers and Read Exception Status keep one byte after the code.
        let exception = rtu(&[0x11, 0xC1, 0x01]);
        assert_eq!(assemble(Framing::Rtu, c, &exception, 1), Ok(5));
        let status = rtu(&[0x11, 0x07, 0x6D]);
        assert_eq!(assemble(Framing::Rtu, c, &status, 1), Ok(5));
        // A server beyond libmodbus takes such a request whole on RTU too.
        let req = rtu(&[0x11, 0x41, 0x01, 0x02, 0x03]);
        assert_eq!(assemble_ext(Framing::Rtu, MsgKind::Indication, &req, 1), Ok(req.len()));
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
