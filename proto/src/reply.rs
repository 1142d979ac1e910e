//! Server side: the answer to one request (libmodbus's `modbus_reply`, 3.1.12
//! semantics), as a pure function over the request bytes and a data mapping.
//!
//! The request is a byte slice that may be shorter than its own fields claim: bytes
//! past its end read as 0, so no request can make this code index outside it. The
//! C caller's `req_length` is only ever *compared* (the write-request length checks
//! that fixed CVE-2024-10918, and the #837 rule for reading the address); it is never
//! used to index anything. Tables are reached through the [`Mapping`] trait, one at a
//! time, and every index is checked against the table's slice.
//!
//! The outcome tells the caller what to do in which order, exactly as libmodbus does
//! it: the debug message (already printed here, on the stderr side of the sink), then
//! the sleep-and-flush for "illegal number of values" and unknown functions, then the
//! send, unless an RTU broadcast suppresses it.

use crate::data::{registers_from_be, registers_to_be};
use crate::error::{Error, exception};
use crate::frame::{Framing, Length, MAX_ADU_LENGTH, MsgKind, Rules, crc_matches, message_length};
use crate::limits::*;
use crate::{Diag, fc};

/// The version libmodbus reports in the report-slave-id payload (`"LMB" + version`).
pub const VERSION_STRING: &str = "3.1.12";

/// The "slave id" byte of libmodbus's report-slave-id response (`_REPORT_SLAVE_ID`).
pub const REPORT_SLAVE_ID_BYTE: u8 = 180;

/// `MODBUS_QUIRK_REPLY_TO_BROADCAST`: an RTU server answers requests to slave 0.
pub const QUIRK_REPLY_TO_BROADCAST: u32 = 1 << 2;

/// One table of a mapping: `data[i]` holds the item at address `start + i`.
#[derive(Debug)]
pub struct Table<'a, T> {
    pub start: i32,
    pub data: &'a mut [T],
}

impl<T> Table<'_, T> {
    fn nb(&self) -> i64 {
        self.data.len() as i64
    }

    /// Index of the first of `nb` items from `address`, when all of them are in the table.
    fn range(&self, address: u16, nb: i64) -> Option<usize> {
        let first = address as i64 - self.start as i64;
        (first >= 0 && first + nb <= self.nb()).then_some(first as usize)
    }
}

impl<'a, T> Table<'a, T> {
    /// The `nb` items from `address`, when all of them are in the table.
    #[inline]
    fn items(self, address: u16, nb: usize) -> Option<&'a mut [T]> {
        let first = self.range(address, nb as i64)?;
        Some(&mut self.data[first..first + nb])
    }
}

/// Access to a server's four tables. Each call lends one table; the reply logic
/// never holds two at once, so a C mapping whose tables overlap is still sound.
pub trait Mapping {
    fn bits(&mut self) -> Table<'_, u8>;
    fn input_bits(&mut self) -> Table<'_, u8>;
    fn registers(&mut self) -> Table<'_, u16>;
    fn input_registers(&mut self) -> Table<'_, u16>;
}

/// A mapping made of four borrowed tables.
#[derive(Debug)]
pub struct Tables<'a> {
    pub bits: Table<'a, u8>,
    pub input_bits: Table<'a, u8>,
    pub registers: Table<'a, u16>,
    pub input_registers: Table<'a, u16>,
}

impl Mapping for Tables<'_> {
    fn bits(&mut self) -> Table<'_, u8> {
        Table { start: self.bits.start, data: self.bits.data }
    }
    fn input_bits(&mut self) -> Table<'_, u8> {
        Table { start: self.input_bits.start, data: self.input_bits.data }
    }
    fn registers(&mut self) -> Table<'_, u16> {
        Table { start: self.registers.start, data: self.registers.data }
    }
    fn input_registers(&mut self) -> Table<'_, u16> {
        Table { start: self.input_registers.start, data: self.input_registers.data }
    }
}

/// What `modbus_reply` does after the mapping has been read or written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// `out[..len]` holds the response (unsealed: no CRC, no MBAP length). First, when
    /// `flush_first`, sleep the response timeout and flush the link; then send it, or,
    /// when `suppressed` (RTU broadcast), send nothing and return 0.
    Respond { len: usize, exception: Option<u8>, flush_first: bool, suppressed: bool },
    /// Nothing is sent; `modbus_reply` returns -1 with this errno (FC 0x07).
    Fail(Error),
}

/// The request, read defensively: bytes past its end read as 0.
struct Req<'a>(&'a [u8]);

impl Req<'_> {
    fn u8(&self, i: usize) -> u8 {
        self.0.get(i).copied().unwrap_or(0)
    }
    fn u16(&self, i: usize) -> u16 {
        match self.0.get(i..i + 2) {
            Some(&[hi, lo]) => u16::from_be_bytes([hi, lo]),
            _ => (self.u8(i) as u16) << 8,
        }
    }
    /// Big-endian registers from byte `at` into `regs` (bytes past the end read as 0).
    fn registers_to(&self, at: usize, regs: &mut [u16]) {
        match self.0.get(at..at + 2 * regs.len()) {
            Some(bytes) => registers_from_be(bytes, regs),
            None => {
                for (k, reg) in regs.iter_mut().enumerate() {
                    *reg = self.u16(at + 2 * k);
                }
            }
        }
    }
    /// The first `n` bytes, zero-extended.
    fn copy_to(&self, out: &mut [u8], n: usize) {
        for (i, o) in out[..n].iter_mut().enumerate() {
            *o = self.u8(i);
        }
    }
}

/// Writes the response header (`build_response_basis`): TCP `[tid][0 0][0 0][unit][fc]`
/// with the length left for sealing, RTU `[slave][fc]`. Returns its length.
#[inline]
fn response_basis(framing: Framing, tid: u16, slave: u8, function: u8, out: &mut [u8]) -> usize {
    let h = framing.write_header(out, slave, tid);
    out[h] = function;
    h + 1
}

/// Builds the exception response `[header with (fc + 0x80) & 0xFF][code]` for `req`
/// (`modbus_reply_exception` and the exceptions of `modbus_reply`). Returns its length.
pub fn exception_response(framing: Framing, req: &[u8], code: u8, out: &mut [u8; MAX_ADU_LENGTH]) -> usize {
    let r = Req(req);
    let h = framing.header_length();
    let tid = framing.response_tid(req);
    let n = response_basis(framing, tid, r.u8(h - 1), r.u8(h).wrapping_add(0x80), out);
    out[n] = code;
    n + 1
}

/// How many bytes of a caller's request buffer the reply may read: the length of the
/// indication its own bytes describe (as `modbus_receive` frames it, from the function
/// code and the byte counts), capped by the framing's maximum ADU and by `bound`.
/// `extended` says that the server frames the function codes beyond libmodbus whole
/// (`Context::serves_extended`); their length then comes from their own layout.
/// `prefix(n)` gives the request's first `n` bytes; it is only called for `n` up to
/// the returned length, so an FFI caller can lend the buffer piece by piece without
/// ever going past what it vouches for.
pub fn request_extent<'a>(framing: Framing, extended: bool, bound: usize, prefix: impl Fn(usize) -> &'a [u8]) -> usize {
    let cap = bound.min(framing.max_adu_length());
    let h = framing.header_length();
    if cap <= h {
        return cap;
    }
    let rules = Rules { framing, kind: MsgKind::Indication, extended, known_total: None };
    let head = prefix(h + 1);
    if let Some(step) = rules.crc_search_step(head) {
        // An RTU request whose PDU does not tell its length ends where its CRC
        // matches (as `modbus_receive` frames it), bounded by the ADU.
        let Length::Total(mut len) = message_length(rules, head) else { return cap };
        while len <= cap {
            if crc_matches(prefix(len)) {
                return len;
            }
            len += step;
        }
        return cap;
    }
    if extended && framing == Framing::Ascii && head[h] == fc::DIAGNOSTICS && bound != usize::MAX {
        // An ASCII frame is delimited by its characters, so the received length is
        // the request's. (A negative `req_length` gives no received length: the
        // one-word layout then applies.)
        return cap;
    }
    let mut have = h + 1;
    loop {
        match message_length(rules, prefix(have)) {
            Length::Total(total) => return total.min(cap),
            Length::Need(need) => {
                let need = need.min(cap);
                if need <= have {
                    return cap;
                }
                have = need;
            }
        }
    }
}

/// Expected length of a write request with a fixed size (05, 06: 5 bytes after the
/// header; 16: 7), checksum included (libmodbus's `compute_response_length_from_request`).
fn fixed_request_length(framing: Framing, after_header: usize) -> i64 {
    (framing.header_length() + after_header + framing.checksum_length()) as i64
}

/// Packs bits LSB first the way libmodbus does: table values are OR-ed in unmasked
/// (a value of 2 sets the next bit too) and each byte keeps the low 8 bits.
fn pack_bits(bits: &[u8], out: &mut [u8]) -> usize {
    let whole = bits.len() / 8;
    let (eights, rest) = bits.split_at(whole * 8);
    for (byte, eight) in out[..whole].iter_mut().zip(eights.chunks_exact(8)) {
        let word = u64::from_le_bytes(eight.try_into().unwrap_or_default());
        *byte = if word & !ONES == 0 { gather_ones(word) } else { pack_unmasked(eight) };
    }
    if rest.is_empty() {
        return whole;
    }
    out[whole] = pack_unmasked(rest);
    whole + 1
}

/// Bit 0 of every byte of a word.
const ONES: u64 = 0x0101_0101_0101_0101;

/// Eight values of 0 or 1 (the usual table), byte i of `word` holding value i, as
/// the bits of one byte: one multiplication gathers bit 0 of byte i into bit 56 + i,
/// with no carries between them.
#[inline]
fn gather_ones(word: u64) -> u8 {
    (word.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u8
}

fn pack_unmasked(chunk: &[u8]) -> u8 {
    let mut byte: u32 = 0;
    for (shift, &b) in chunk.iter().enumerate() {
        byte |= (b as u32) << shift;
    }
    byte as u8
}

/// Why a data access was not carried out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Answer with this exception code.
    Exception(u8),
    /// Send no answer at all.
    Silent,
}

/// The request a data access serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Request {
    pub unit: u8,
    pub function: u8,
    /// The MBAP transaction id (0 on a serial line).
    pub transaction_id: u16,
}

/// `nb` items from `address`: a range a request touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Range {
    pub address: u16,
    pub nb: u16,
}

/// What a server serves, as the accesses a request makes: `modbus_reply`'s mapping
/// ([`MappingData`]) and `modbus_reply_dispatch`' callbacks are the two kinds, on
/// the one path of [`Server::answer`]. Values are in host order: registers as
/// `u16`, bits one per byte (0 or 1). Which table an access reaches is the
/// request's function code: reads of bits are coils (01) or discrete inputs (02);
/// reads of registers are input registers (04) or holding registers (03, 16, 17).
pub trait Data {
    /// Whether the server answers requests for `unit` (a serial broadcast is never
    /// asked about); `req` is the request's ADU.
    fn accept_unit(&mut self, _unit: u8, _req: &[u8]) -> bool {
        true
    }
    /// Where libmodbus checks a request's ranges against its tables, before any
    /// access: a mapping refuses ranges outside its tables here, with libmodbus's
    /// message (so that the order of libmodbus's checks holds). Callbacks refuse when
    /// they are called.
    fn check(&mut self, _rq: &Request, _ranges: &[Range], _diag: &mut dyn Diag) -> Result<(), Refusal> {
        Ok(())
    }
    fn read_bits(&mut self, rq: &Request, address: u16, dest: &mut [u8]) -> Result<(), Refusal>;
    fn read_registers(&mut self, rq: &Request, address: u16, dest: &mut [u16]) -> Result<(), Refusal>;
    /// `nb` bits from `address`, packed into the response (`wire`, LSB first); returns
    /// the bytes written. By default through [`Data::read_bits`] and a buffer; a
    /// mapping packs straight from its table.
    fn read_bits_wire(
        &mut self,
        rq: &Request,
        address: u16,
        nb: u16,
        wire: &mut [u8],
        _diag: &mut dyn Diag,
    ) -> Result<usize, Refusal> {
        let mut bits = [0u8; MAX_READ_BITS as usize];
        let bits = &mut bits[..nb as usize];
        self.read_bits(rq, address, bits)?;
        Ok(pack_bits(bits, wire))
    }
    /// `nb` registers from `address`, big-endian into the response (`wire`, 2 x `nb`
    /// bytes). By default through [`Data::read_registers`] and a buffer; a mapping
    /// converts straight from its table.
    fn read_registers_wire(
        &mut self,
        rq: &Request,
        address: u16,
        nb: u16,
        wire: &mut [u8],
        _diag: &mut dyn Diag,
    ) -> Result<(), Refusal> {
        let mut regs = [0u16; MAX_READ_REGISTERS as usize];
        let regs = &mut regs[..nb as usize];
        self.read_registers(rq, address, regs)?;
        registers_to_be(regs, &mut wire[..2 * regs.len()]);
        Ok(())
    }
    fn write_bits(&mut self, rq: &Request, address: u16, src: &[u8]) -> Result<(), Refusal>;
    fn write_registers(&mut self, rq: &Request, address: u16, src: &[u16]) -> Result<(), Refusal>;
    /// A function code the reply does not serve from data (report slave id, read
    /// exception status, unknown codes): `Some` is the answer, the response PDU's
    /// length written to `rsp` (function code first), or a refusal; `None` leaves
    /// libmodbus's own answer.
    fn other(&mut self, _rq: &Request, _pdu: &[u8], _rsp: &mut [u8]) -> Option<Result<usize, Refusal>> {
        None
    }
    /// Every request goes to [`Data::other`] as it came, whatever its function code:
    /// no check, no data access of the reply's own (a gateway that passes requests
    /// through). After the unit and the authorization, nothing of the reply's runs.
    #[inline(always)]
    fn takes_every_function(&self) -> bool {
        false
    }
}

/// A [`Mapping`] as [`Data`]: what `modbus_reply` serves.
pub struct MappingData<'a, M: Mapping + ?Sized>(pub &'a mut M);

impl<M: Mapping + ?Sized> MappingData<'_, M> {
    /// The bit table a function code reads or writes: discrete inputs for 02, else coils.
    #[inline]
    fn bit_table(&mut self, function: u8) -> Table<'_, u8> {
        if function == fc::READ_DISCRETE_INPUTS { self.0.input_bits() } else { self.0.bits() }
    }

    /// The register table a function code reads or writes: input registers for 04,
    /// else holding registers.
    #[inline]
    fn register_table(&mut self, function: u8) -> Table<'_, u16> {
        if function == fc::READ_INPUT_REGISTERS { self.0.input_registers() } else { self.0.registers() }
    }

    /// The table a function code reads or writes (`check`'s start and size).
    #[inline]
    fn bounds(&mut self, function: u8) -> (i32, i64) {
        match function {
            fc::READ_COILS | fc::READ_DISCRETE_INPUTS | fc::WRITE_SINGLE_COIL | fc::WRITE_MULTIPLE_COILS => {
                let t = self.bit_table(function);
                (t.start, t.nb())
            }
            _ => {
                let t = self.register_table(function);
                (t.start, t.nb())
            }
        }
    }
}

/// The refusal of an access outside a table (which `check` has already refused).
const OUTSIDE: Refusal = Refusal::Exception(exception::ILLEGAL_DATA_ADDRESS);

impl<M: Mapping + ?Sized> Data for MappingData<'_, M> {
    #[inline(always)]
    fn check(&mut self, rq: &Request, ranges: &[Range], diag: &mut dyn Diag) -> Result<(), Refusal> {
        if rq.function <= fc::READ_INPUT_REGISTERS {
            // A read's range is checked by the read itself (nothing comes between).
            return Ok(());
        }
        let (start, size) = self.bounds(rq.function);
        let covered = |r: &Range| {
            let first = r.address as i64 - start as i64;
            first >= 0 && first + r.nb as i64 <= size
        };
        if ranges.iter().all(covered) {
            return Ok(());
        }
        outside(rq, ranges, start, diag)
    }

    #[inline]
    fn read_bits(&mut self, rq: &Request, address: u16, dest: &mut [u8]) -> Result<(), Refusal> {
        dest.copy_from_slice(self.bit_table(rq.function).items(address, dest.len()).ok_or(OUTSIDE)?);
        Ok(())
    }

    #[inline]
    fn read_registers(&mut self, rq: &Request, address: u16, dest: &mut [u16]) -> Result<(), Refusal> {
        dest.copy_from_slice(self.register_table(rq.function).items(address, dest.len()).ok_or(OUTSIDE)?);
        Ok(())
    }

    #[inline(always)]
    fn read_bits_wire(
        &mut self,
        rq: &Request,
        address: u16,
        nb: u16,
        wire: &mut [u8],
        diag: &mut dyn Diag,
    ) -> Result<usize, Refusal> {
        let table = self.bit_table(rq.function);
        let start = table.start;
        match table.items(address, nb as usize) {
            Some(bits) => Ok(pack_bits(bits, wire)),
            None => outside(rq, &[Range { address, nb }], start, diag).map(|()| 0),
        }
    }

    #[inline(always)]
    fn read_registers_wire(
        &mut self,
        rq: &Request,
        address: u16,
        nb: u16,
        wire: &mut [u8],
        diag: &mut dyn Diag,
    ) -> Result<(), Refusal> {
        let table = self.register_table(rq.function);
        let start = table.start;
        match table.items(address, nb as usize) {
            Some(regs) => {
                registers_to_be(regs, &mut wire[..2 * nb as usize]);
                Ok(())
            }
            None => outside(rq, &[Range { address, nb }], start, diag),
        }
    }

    #[inline]
    fn write_bits(&mut self, _rq: &Request, address: u16, src: &[u8]) -> Result<(), Refusal> {
        self.0.bits().items(address, src.len()).ok_or(OUTSIDE)?.copy_from_slice(src);
        Ok(())
    }

    #[inline]
    fn write_registers(&mut self, _rq: &Request, address: u16, src: &[u16]) -> Result<(), Refusal> {
        self.0.registers().items(address, src.len()).ok_or(OUTSIDE)?.copy_from_slice(src);
        Ok(())
    }
}

/// The refusal of ranges outside a mapping's table (starting at `start`), with
/// libmodbus's message.
#[cold]
#[inline(never)]
fn outside(rq: &Request, ranges: &[Range], start: i32, diag: &mut dyn Diag) -> Result<(), Refusal> {
    // libmodbus shows the address when it lies below the table, else the end.
    let shown = |r: &Range| {
        if (r.address as i64) < start as i64 { r.address as i64 } else { r.address as i64 + r.nb as i64 }
    };
    let first = ranges.first().copied().unwrap_or(Range { address: 0, nb: 0 });
    let (address, what) = match rq.function {
        fc::READ_COILS => (shown(&first), "read_bits"),
        fc::READ_DISCRETE_INPUTS => (shown(&first), "read_input_bits"),
        fc::READ_HOLDING_REGISTERS => (shown(&first), "read_registers"),
        fc::READ_INPUT_REGISTERS => (shown(&first), "read_input_registers"),
        fc::WRITE_SINGLE_COIL => (first.address as i64, "write bit"),
        fc::WRITE_MULTIPLE_COILS => (shown(&first), "write_bits"),
        fc::WRITE_MULTIPLE_REGISTERS => (shown(&first), "write_registers"),
        fc::WRITE_AND_READ_REGISTERS => {
            let write = ranges.get(1).copied().unwrap_or(first);
            diag.err(format_args!(
                "Illegal data read address 0x{:X} or write address 0x{:X} write_and_read_registers\n",
                shown(&first),
                shown(&write)
            ));
            return Err(OUTSIDE);
        }
        // 06 and 16 (mask write).
        _ => (first.address as i64, "write_register"),
    };
    diag.err(format_args!("Illegal data address 0x{address:X} in {what}\n"));
    Err(OUTSIDE)
}

/// Nothing sent, 0 returned: an answer withheld.
pub const SILENT: Outcome = Outcome::Respond { len: 0, exception: None, flush_first: false, suppressed: true };

/// The server's state that shapes a reply.
#[derive(Clone, Copy, Debug)]
pub struct Server {
    pub framing: Framing,
    /// `MODBUS_QUIRK_*` bits of the context.
    pub quirks: u32,
}

/// An answer as built: the response's length, its exception code, and whether the
/// link is flushed (after the response timeout) before it is sent.
type Built = (usize, Option<u8>, bool);

impl Server {
    /// `modbus_reply`: answers `req` (the request as received; see
    /// [`request_extent`]) from `mapping`. `req_length` is the C caller's value, which
    /// may be anything.
    #[inline]
    pub fn reply(
        &self,
        req: &[u8],
        req_length: i32,
        mapping: &mut dyn Mapping,
        diag: &mut dyn Diag,
        out: &mut [u8; MAX_ADU_LENGTH],
    ) -> Outcome {
        self.answer(req, req_length, &mut MappingData(mapping), diag, out)
    }

    /// Answers `req` from `data`, in libmodbus's order of checks: the request's
    /// quantities, then its ranges ([`Data::check`]), then its lengths and values,
    /// then the accesses; FC 16 (mask write) reads then writes the register, FC 17
    /// writes then reads. Inlined: where `data` is a known type (the mapping of
    /// `modbus_reply`), its accesses are direct calls.
    #[inline(always)]
    pub fn answer<D: Data + ?Sized>(
        &self,
        req: &[u8],
        req_length: i32,
        data: &mut D,
        diag: &mut dyn Diag,
        out: &mut [u8; MAX_ADU_LENGTH],
    ) -> Outcome {
        let framing = self.framing;
        let r = Req(req);
        let h = framing.header_length();
        let slave = r.u8(h - 1);
        let function = r.u8(h);
        // 3.1.12 (#837): the address is read only when the caller's length covers it.
        // The comparison is unsigned in C, so a negative length counts as large.
        let address = if req_length < 0 || req_length as i64 >= (h + 3) as i64 { r.u16(h + 1) } else { 0 };
        let tid = framing.response_tid(req);
        let rq = Request { unit: slave, function, transaction_id: tid };

        // Prints the message (stderr side), then builds the exception response.
        macro_rules! exception {
            ($code:expr, $flush:expr, $($fmt:tt)*) => {{
                diag.err(format_args!($($fmt)*));
                Ok((exception_response(framing, req, $code, out), Some($code), $flush))
            }};
        }
        // The response to a read of registers: `[header][byte count][values]`.
        macro_rules! respond_registers {
            ($address:expr, $nb:expr) => {{
                let n = response_basis(framing, tid, slave, function, out);
                out[n] = ($nb * 2) as u8;
                data.read_registers_wire(&rq, $address, $nb, &mut out[n + 1..], diag)?;
                Ok((n + 1 + 2 * $nb as usize, None, false))
            }};
        }
        // A multiple write's response: its header, then the request's address and
        // quantity.
        macro_rules! echo {
            () => {{
                let n = response_basis(framing, tid, slave, function, out);
                for k in n..n + 4 {
                    out[k] = r.u8(k);
                }
                Ok((n + 4, None, false))
            }};
        }
        // A single write's response: the request's first `len` bytes, as they came.
        macro_rules! copy {
            ($len:expr) => {{
                r.copy_to(out, $len);
                Ok(($len, None, false))
            }};
        }

        let built: Result<Built, Refusal> = if data.takes_every_function() {
            match data.other(&rq, pdu(framing, req), &mut out[h..h + MAX_PDU_LENGTH]) {
                Some(answered) => self.answered(answered, &rq, out),
                None => {
                    exception!(exception::ILLEGAL_FUNCTION, false, "Unknown Modbus function code: 0x{function:X}\n")
                }
            }
        } else {
            match function {
                fc::READ_COILS | fc::READ_DISCRETE_INPUTS => {
                    let name = if function == fc::READ_DISCRETE_INPUTS { "read_input_bits" } else { "read_bits" };
                    let nb = r.u16(h + 3);
                    if !(1..=MAX_READ_BITS as i64).contains(&(nb as i64)) {
                        exception!(
                            exception::ILLEGAL_DATA_VALUE,
                            true,
                            "Illegal nb of values {nb} in {name} (max {MAX_READ_BITS})\n"
                        )
                    } else {
                        data.check(&rq, &[Range { address, nb }], diag).and_then(
                            #[inline(always)]
                            |()| {
                                let n = response_basis(framing, tid, slave, function, out);
                                out[n] = nb.div_ceil(8) as u8;
                                let packed = data.read_bits_wire(&rq, address, nb, &mut out[n + 1..], diag)?;
                                Ok((n + 1 + packed, None, false))
                            },
                        )
                    }
                }
                fc::READ_HOLDING_REGISTERS | fc::READ_INPUT_REGISTERS => {
                    let is_input = function == fc::READ_INPUT_REGISTERS;
                    let name = if is_input { "read_input_registers" } else { "read_registers" };
                    let nb = r.u16(h + 3);
                    if !(1..=MAX_READ_REGISTERS as i64).contains(&(nb as i64)) {
                        exception!(
                            exception::ILLEGAL_DATA_VALUE,
                            true,
                            "Illegal nb of values {nb} in {name} (max {MAX_READ_REGISTERS})\n"
                        )
                    } else {
                        data.check(&rq, &[Range { address, nb }], diag).and_then(
                            #[inline(always)]
                            |()| respond_registers!(address, nb),
                        )
                    }
                }
                fc::WRITE_SINGLE_COIL => data.check(&rq, &[Range { address, nb: 1 }], diag).and_then(
                    #[inline(always)]
                    |()| {
                        let value = r.u16(h + 3);
                        if req_length as i64 != fixed_request_length(framing, 5) {
                            exception!(
                                exception::ILLEGAL_DATA_VALUE,
                                false,
                                "Invalid request length in modbus_reply to write bit ({req_length})\n"
                            )
                        } else if value != 0xFF00 && value != 0 {
                            exception!(
                                exception::ILLEGAL_DATA_VALUE,
                                false,
                                "Illegal data value 0x{value:X} in write_bit request at address {address:X}\n"
                            )
                        } else {
                            data.write_bits(&rq, address, &[(value != 0) as u8]).and_then(
                                #[inline(always)]
                                |()| copy!(h + 5),
                            )
                        }
                    },
                ),
                fc::WRITE_SINGLE_REGISTER => data.check(&rq, &[Range { address, nb: 1 }], diag).and_then(
                    #[inline(always)]
                    |()| {
                        if req_length as i64 != fixed_request_length(framing, 5) {
                            exception!(
                                exception::ILLEGAL_DATA_VALUE,
                                false,
                                "Invalid request length in modbus_reply to write register ({req_length})\n"
                            )
                        } else {
                            data.write_registers(&rq, address, &[r.u16(h + 3)]).and_then(
                                #[inline(always)]
                                |()| copy!(h + 5),
                            )
                        }
                    },
                ),
                fc::WRITE_MULTIPLE_COILS => {
                    let nb = r.u16(h + 3);
                    let byte_count = r.u8(h + 5) as i64;
                    if !(1..=MAX_WRITE_BITS as i64).contains(&(nb as i64)) || byte_count * 8 < nb as i64 {
                        // CVE-2019-14462: the byte count must cover the quantity.
                        exception!(
                            exception::ILLEGAL_DATA_VALUE,
                            true,
                            "Illegal number of values {nb} in write_bits (max {MAX_WRITE_BITS})\n"
                        )
                    } else {
                        data.check(&rq, &[Range { address, nb }], diag).and_then(
                            #[inline(always)]
                            |()| {
                                let mut bits = [0u8; MAX_WRITE_BITS as usize];
                                let bits = &mut bits[..nb as usize];
                                match req.get(h + 6..h + 6 + bits.len().div_ceil(8)) {
                                    Some(packed) => crate::data::set_bits_from_bytes(bits, packed),
                                    None => {
                                        for (k, bit) in bits.iter_mut().enumerate() {
                                            *bit = (r.u8(h + 6 + k / 8) >> (k % 8)) & 1;
                                        }
                                    }
                                }
                                data.write_bits(&rq, address, bits).and_then(
                                    #[inline(always)]
                                    |()| echo!(),
                                )
                            },
                        )
                    }
                }
                fc::WRITE_MULTIPLE_REGISTERS => {
                    let nb = r.u16(h + 3);
                    let byte_count = r.u8(h + 5) as i64;
                    if !(1..=MAX_WRITE_REGISTERS as i64).contains(&(nb as i64)) || byte_count != nb as i64 * 2 {
                        // CVE-2019-14463: the byte count must be exactly two per register.
                        exception!(
                            exception::ILLEGAL_DATA_VALUE,
                            true,
                            "Illegal number of values {nb} in write_registers (max {MAX_WRITE_REGISTERS})\n"
                        )
                    } else {
                        data.check(&rq, &[Range { address, nb }], diag).and_then(
                            #[inline(always)]
                            |()| {
                                let mut regs = [0u16; MAX_WRITE_REGISTERS as usize];
                                let regs = &mut regs[..nb as usize];
                                r.registers_to(h + 6, regs);
                                data.write_registers(&rq, address, regs).and_then(
                                    #[inline(always)]
                                    |()| echo!(),
                                )
                            },
                        )
                    }
                }
                fc::REPORT_SLAVE_ID => match data.other(&rq, pdu(framing, req), &mut out[h..h + MAX_PDU_LENGTH]) {
                    Some(answered) => self.answered(answered, &rq, out),
                    None => {
                        let mut n = response_basis(framing, tid, slave, function, out);
                        let count_at = n;
                        n += 1;
                        out[n] = REPORT_SLAVE_ID_BYTE;
                        out[n + 1] = 0xFF; // run indicator ON
                        n += 2;
                        for part in [b"LMB".as_slice(), VERSION_STRING.as_bytes()] {
                            out[n..n + part.len()].copy_from_slice(part);
                            n += part.len();
                        }
                        out[count_at] = (n - count_at - 1) as u8;
                        Ok((n, None, false))
                    }
                },
                fc::READ_EXCEPTION_STATUS => {
                    match data.other(&rq, pdu(framing, req), &mut out[h..h + MAX_PDU_LENGTH]) {
                        Some(answered) => self.answered(answered, &rq, out),
                        None => {
                            // libmodbus through 3.1.12 answers nothing at all.
                            diag.err(format_args!("FIXME Not implemented\n"));
                            return Outcome::Fail(Error(crate::error::errno::ENOPROTOOPT));
                        }
                    }
                }
                fc::MASK_WRITE_REGISTER => data.check(&rq, &[Range { address, nb: 1 }], diag).and_then(
                    #[inline(always)]
                    |()| {
                        // libmodbus modifies the register before checking the length.
                        let mut value = [0u16];
                        data.read_registers(&rq, address, &mut value)?;
                        let and = r.u16(h + 3);
                        let or = r.u16(h + 5);
                        data.write_registers(&rq, address, &[(value[0] & and) | (or & !and)])?;
                        if req_length as i64 != fixed_request_length(framing, 7) {
                            exception!(
                                exception::ILLEGAL_DATA_VALUE,
                                false,
                                "Invalid request length in modbus_reply to mask write register ({req_length})\n"
                            )
                        } else {
                            copy!(h + 7)
                        }
                    },
                ),
                fc::WRITE_AND_READ_REGISTERS => {
                    let nb = r.u16(h + 3);
                    let address_write = r.u16(h + 5);
                    let nb_write = r.u16(h + 7);
                    let write_bytes = r.u8(h + 9) as i64;
                    if !(1..=MAX_WR_WRITE_REGISTERS as i64).contains(&(nb_write as i64))
                        || !(1..=MAX_WR_READ_REGISTERS as i64).contains(&(nb as i64))
                        || write_bytes != nb_write as i64 * 2
                    {
                        exception!(
                            exception::ILLEGAL_DATA_VALUE,
                            true,
                            "Illegal nb of values (W{nb_write}, R{nb}) in write_and_read_registers \
                             (max W{MAX_WR_WRITE_REGISTERS}, R{MAX_WR_READ_REGISTERS})\n"
                        )
                    } else {
                        let ranges = [Range { address, nb }, Range { address: address_write, nb: nb_write }];
                        data.check(&rq, &ranges, diag).and_then(
                            #[inline(always)]
                            |()| {
                                // CVE-2022-0367: both ranges are checked. Write first, then read.
                                let mut written = [0u16; MAX_WR_WRITE_REGISTERS as usize];
                                let written = &mut written[..nb_write as usize];
                                r.registers_to(h + 10, written);
                                data.write_registers(&rq, address_write, written)?;
                                respond_registers!(address, nb)
                            },
                        )
                    }
                }
                _ => match data.other(&rq, pdu(framing, req), &mut out[h..h + MAX_PDU_LENGTH]) {
                    Some(answered) => self.answered(answered, &rq, out),
                    None => {
                        exception!(exception::ILLEGAL_FUNCTION, true, "Unknown Modbus function code: 0x{function:X}\n")
                    }
                },
            }
        };

        let (len, exc, flush_first) = match built {
            Ok(built) => built,
            Err(Refusal::Silent) => return SILENT,
            Err(Refusal::Exception(code)) => (exception_response(framing, req, code, out), Some(code), false),
        };
        let suppressed =
            framing.is_serial() && slave as i32 == BROADCAST_ADDRESS && self.quirks & QUIRK_REPLY_TO_BROADCAST == 0;
        Outcome::Respond { len, exception: exc, flush_first, suppressed }
    }

    /// The response of [`Data::other`]'s answer: its PDU (already in place after the
    /// header) behind the header.
    fn answered(&self, answered: Result<usize, Refusal>, rq: &Request, out: &mut [u8]) -> Result<Built, Refusal> {
        let len = answered?;
        let h = self.framing.header_length();
        self.framing.write_header(out, rq.unit, rq.transaction_id);
        Ok((h + len, None, false))
    }
}

/// An answer given later for a request (`modbus_server_answer_registers`,
/// `_bits`, or `modbus_server_answer` with rc 0 for a write).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Given<'a> {
    /// The values a register read (03, 04, 17) answers, host order.
    Registers(&'a [u16]),
    /// The bits a bit read (01, 02) answers, one per byte.
    Bits(&'a [u8]),
    /// The write is done (05, 06, 0F, 10, 16): the usual answer.
    Done,
}

/// How many items a read request answers (`head`: its PDU, at least 5 bytes): 01
/// to 04 and 17 (its read quantity); 0 for any other request.
pub fn read_quantity(head: &[u8]) -> u16 {
    match head.first() {
        Some(&(fc::READ_COILS | fc::READ_DISCRETE_INPUTS | fc::READ_HOLDING_REGISTERS | fc::READ_INPUT_REGISTERS))
        | Some(&fc::WRITE_AND_READ_REGISTERS)
            if head.len() >= 5 =>
        {
            u16::from_be_bytes([head[3], head[4]])
        }
        _ => 0,
    }
}

/// Whether `given` answers a request whose PDU begins with function code
/// `function` and reads `nb` items ([`read_quantity`]).
pub fn given_fits(function: u8, nb: u16, given: Given<'_>) -> bool {
    match given {
        Given::Registers(v) => {
            matches!(function, fc::READ_HOLDING_REGISTERS | fc::READ_INPUT_REGISTERS | fc::WRITE_AND_READ_REGISTERS)
                && v.len() == nb as usize
        }
        Given::Bits(v) => matches!(function, fc::READ_COILS | fc::READ_DISCRETE_INPUTS) && v.len() == nb as usize,
        Given::Done => matches!(
            function,
            fc::WRITE_SINGLE_COIL
                | fc::WRITE_SINGLE_REGISTER
                | fc::WRITE_MULTIPLE_COILS
                | fc::WRITE_MULTIPLE_REGISTERS
                | fc::MASK_WRITE_REGISTER
        ),
    }
}

/// The answer's PDU for `given`, to the request whose PDU begins with `head` (up to
/// 7 bytes are read), written to `out`: its length, or `None` when `given` does not
/// answer that request.
pub fn given_pdu(head: &[u8], given: Given<'_>, out: &mut [u8]) -> Option<usize> {
    let function = *head.first()?;
    if !given_fits(function, read_quantity(head), given) {
        return None;
    }
    out[0] = function;
    match given {
        Given::Registers(v) => {
            out[1] = (2 * v.len()) as u8;
            crate::data::registers_to_be(v, &mut out[2..2 + 2 * v.len()]);
            Some(2 + 2 * v.len())
        }
        Given::Bits(v) => {
            let n = pack_bits(v, &mut out[2..]);
            out[1] = n as u8;
            Some(2 + n)
        }
        Given::Done => {
            // The echo: address and value or quantity (and the masks of 16).
            let n = if function == fc::MASK_WRITE_REGISTER { 7 } else { 5 };
            out[..n].copy_from_slice(head.get(..n)?);
            Some(n)
        }
    }
}

/// The PDU of a request (without its header and checksum).
pub fn pdu(framing: Framing, req: &[u8]) -> &[u8] {
    let h = framing.header_length();
    let end = req.len().saturating_sub(framing.checksum_length());
    if end <= h { &[] } else { &req[h..end] }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Recorded;
    use crate::crc::crc16;
    use crate::error::*;

    const T: Framing = Framing::Tcp;
    const R: Framing = Framing::Rtu;

    /// The unit-test-server mapping of libmodbus's tests.
    struct Fixture {
        starts: [i32; 4],
        bits: Vec<u8>,
        input_bits: Vec<u8>,
        registers: Vec<u16>,
        input_registers: Vec<u16>,
    }

    impl Fixture {
        fn unit_test() -> Fixture {
            Fixture {
                starts: [0x130, 0x1C4, 0x160, 0x108],
                bits: vec![0; 0x25],
                input_bits: vec![0; 0x16],
                registers: vec![0; 0x20],
                input_registers: vec![0x000A],
            }
        }
        fn zero_based(nb: usize) -> Fixture {
            Fixture {
                starts: [0; 4],
                bits: vec![0; nb],
                input_bits: vec![0; nb],
                registers: vec![0; nb],
                input_registers: vec![0; nb],
            }
        }
        fn tables(&mut self) -> Tables<'_> {
            Tables {
                bits: Table { start: self.starts[0], data: &mut self.bits },
                input_bits: Table { start: self.starts[1], data: &mut self.input_bits },
                registers: Table { start: self.starts[2], data: &mut self.registers },
                input_registers: Table { start: self.starts[3], data: &mut self.input_registers },
            }
        }
    }

    /// A request ADU: TCP with TID 0x1234 and an MBAP length as a client would send it,
    /// RTU with its CRC.
    fn adu(framing: Framing, unit: u8, pdu: &[u8]) -> Vec<u8> {
        let mut v = match framing {
            Framing::Tcp => {
                let len = (pdu.len() + 1) as u16;
                vec![0x12, 0x34, 0, 0, (len >> 8) as u8, len as u8, unit]
            }
            Framing::Rtu | Framing::Ascii => vec![unit],
        };
        v.extend_from_slice(pdu);
        if framing == Framing::Rtu {
            let crc = crc16(&v);
            v.extend(crc.to_le_bytes());
        }
        v
    }

    /// What the test saw: the outcome, the sealed ADU that would be sent, and the
    /// debug text.
    struct Seen {
        outcome: Outcome,
        sent: Vec<u8>,
        diag: Recorded,
    }

    impl Seen {
        fn pdu(&self, framing: Framing) -> &[u8] {
            let h = framing.header_length();
            &self.sent[h..self.sent.len() - framing.checksum_length()]
        }
        fn exception(&self) -> Option<u8> {
            match self.outcome {
                Outcome::Respond { exception, .. } => exception,
                Outcome::Fail(_) => None,
            }
        }
        fn flushed(&self) -> bool {
            matches!(self.outcome, Outcome::Respond { flush_first: true, .. })
        }
    }

    fn run_with(framing: Framing, quirks: u32, req: &[u8], req_length: i32, fx: &mut Fixture) -> Seen {
        let mut diag = Recorded::default();
        let mut out = [0u8; MAX_ADU_LENGTH];
        let server = Server { framing, quirks };
        let outcome = server.reply(req, req_length, &mut fx.tables(), &mut diag, &mut out);
        let sent = match outcome {
            Outcome::Respond { len, .. } => {
                let n = framing.seal(&mut out, len);
                out[..n].to_vec()
            }
            Outcome::Fail(_) => Vec::new(),
        };
        Seen { outcome, sent, diag }
    }

    fn run(framing: Framing, req: &[u8], fx: &mut Fixture) -> Seen {
        run_with(framing, 0, req, req.len() as i32, fx)
    }

    fn exc(framing: Framing, pdu: &[u8], fx: &mut Fixture) -> Seen {
        run(framing, &adu(framing, 0x11, pdu), fx)
    }

    fn be(v: u16) -> [u8; 2] {
        v.to_be_bytes()
    }

    fn read_pdu(function: u8, addr: u16, nb: u16) -> Vec<u8> {
        let mut p = vec![function];
        p.extend(be(addr));
        p.extend(be(nb));
        p
    }

    fn assert_exception(s: &Seen, framing: Framing, function: u8, code: u8, flush: bool, msg: &str) {
        assert_eq!(s.exception(), Some(code), "{}", s.diag.err);
        assert_eq!(s.pdu(framing), [function.wrapping_add(0x80), code]);
        assert_eq!(s.flushed(), flush);
        assert_eq!(s.diag.err, msg);
    }

    // ---------------------------------------------------------------- FC 01 / 02

    #[test]
    fn answers_given_later() {
        let mut out = [0u8; 260];
        let read = [0x03, 0, 10, 0, 2];
        assert_eq!(given_pdu(&read, Given::Registers(&[0x1234, 0xABCD]), &mut out), Some(6));
        assert_eq!(&out[..6], &[0x03, 4, 0x12, 0x34, 0xAB, 0xCD]);
        assert_eq!(given_pdu(&read, Given::Registers(&[1]), &mut out), None, "one value for two");
        assert_eq!(given_pdu(&read, Given::Done, &mut out), None, "a read is not done");
        assert_eq!(given_pdu(&read, Given::Bits(&[1, 0]), &mut out), None, "bits for registers");
        let wr = [0x17, 0, 1, 0, 1, 0, 5, 0, 1, 2, 0, 7];
        assert_eq!(given_pdu(&wr, Given::Registers(&[9]), &mut out), Some(4));
        assert_eq!(&out[..4], &[0x17, 2, 0, 9]);
        let bits = [0x01, 0, 0, 0, 10];
        assert_eq!(given_pdu(&bits, Given::Bits(&[1, 0, 0, 0, 0, 0, 0, 0, 1, 1]), &mut out), Some(4));
        assert_eq!(&out[..4], &[0x01, 2, 0x01, 0x03]);
        let write = [0x06, 0, 3, 0xBE, 0xEF];
        assert_eq!(given_pdu(&write, Given::Done, &mut out), Some(5));
        assert_eq!(&out[..5], &write);
        let mask = [0x16, 0, 3, 0, 0xFF, 0x12, 0];
        assert_eq!(given_pdu(&mask, Given::Done, &mut out), Some(7));
        assert_eq!(&out[..7], &mask);
        assert_eq!(given_pdu(&[0x41], Given::Done, &mut out), None, "an unknown code");
    }

    #[test]
    fn pack_bits_matches_the_bit_by_bit_rule() {
        let mut rng = crate::test_rng::XorShift::new(0x9E37_79B9_7F4A_7C15);
        for round in 0..9_000 {
            let seed = rng.next_u64();
            // Short tables, then long ones.
            let len = (seed % [40, 300, 2001][round % 3]) as usize;
            let stray = (rng.next_u64() % (len as u64 + 1)) as usize;
            // Mostly 0/1 tables; sometimes unmasked values everywhere, or in one place
            // only (2 sets the next bit).
            let bits: Vec<u8> = (0..len)
                .map(|i| {
                    let r = (seed >> (i % 56)) as u8;
                    match round % 4 {
                        0 => r,
                        1 if i == stray => r | 2,
                        _ => r & 1,
                    }
                })
                .collect();
            let mut fast = [0u8; 251];
            let n = pack_bits(&bits, &mut fast);
            let slow: Vec<u8> = bits.chunks(8).map(pack_unmasked).collect();
            assert_eq!(&fast[..n], &slow[..], "{bits:?}");
            let mut back = vec![0xAAu8; len];
            crate::data::set_bits_from_bytes(&mut back, &slow);
            let expected: Vec<u8> = (0..len).map(|i| (slow[i / 8] >> (i % 8)) & 1).collect();
            assert_eq!(back, expected);
            // Fewer packed bytes than the bits asked for: the rest is left alone.
            let short = &slow[..slow.len() / 2];
            let mut back = vec![0xAAu8; len];
            crate::data::set_bits_from_bytes(&mut back, short);
            let covered = (short.len() * 8).min(len);
            assert_eq!(back[..covered], expected[..covered]);
            assert!(back[covered..].iter().all(|&b| b == 0xAA));
        }
    }

    #[test]
    fn read_bits_first_last_and_packing() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            fx.bits.iter_mut().enumerate().for_each(|(i, b)| *b = (i % 3 == 0) as u8);
            // Whole table from the first address: 37 bits in 5 bytes.
            let s = exc(framing, &read_pdu(1, 0x130, 0x25), &mut fx);
            assert_eq!(s.exception(), None);
            assert_eq!(s.pdu(framing), [1, 5, 0x49, 0x92, 0x24, 0x49, 0x12]);
            // The last bit alone.
            let s = exc(framing, &read_pdu(1, 0x154, 1), &mut fx);
            assert_eq!(s.pdu(framing), [1, 1, 1]);
            assert!(s.diag.err.is_empty());
        }
    }

    #[test]
    fn read_bits_headers_echo_tid_and_unit() {
        let mut fx = Fixture::unit_test();
        let s = run(T, &adu(T, 0x2A, &read_pdu(1, 0x130, 8)), &mut fx);
        assert_eq!(s.sent, [0x12, 0x34, 0, 0, 0, 4, 0x2A, 1, 1, 0]);
        let s = run(R, &adu(R, 0x2A, &read_pdu(1, 0x130, 8)), &mut fx);
        let mut want = vec![0x2A, 1, 1, 0];
        let crc = crc16(&want);
        want.extend(crc.to_le_bytes());
        assert_eq!(s.sent, want);
    }

    #[test]
    fn read_bits_keeps_libmodbus_unmasked_packing() {
        // libmodbus ORs table values in without masking them to one bit.
        let mut fx = Fixture::zero_based(16);
        fx.bits[0] = 2;
        fx.bits[7] = 1;
        fx.bits[8] = 0xFF;
        let s = exc(T, &read_pdu(1, 0, 9), &mut fx);
        assert_eq!(s.pdu(T), [1, 2, 0x82, 0xFF]);
    }

    #[test]
    fn read_bits_counts_and_ranges() {
        let mut fx = Fixture::zero_based(4000);
        for framing in [T, R] {
            let s = exc(framing, &read_pdu(2, 0, 2000), &mut fx);
            assert_eq!(s.pdu(framing).len(), 2 + 250);
            assert_eq!(s.pdu(framing)[1], 250);
            let s = exc(framing, &read_pdu(2, 0, 2001), &mut fx);
            assert_exception(
                &s,
                framing,
                2,
                exception::ILLEGAL_DATA_VALUE,
                true,
                "Illegal nb of values 2001 in read_input_bits (max 2000)\n",
            );
            let s = exc(framing, &read_pdu(1, 0, 0), &mut fx);
            assert_exception(
                &s,
                framing,
                1,
                exception::ILLEGAL_DATA_VALUE,
                true,
                "Illegal nb of values 0 in read_bits (max 2000)\n",
            );
            let s = exc(framing, &read_pdu(1, 0xFFFF, 0xFFFF), &mut fx);
            assert_eq!(s.diag.err, "Illegal nb of values 65535 in read_bits (max 2000)\n");
        }
        // Table of 4000: 2001 bits at 1999 end at 4000, inside; 2000 at 2001 too.
        let s = exc(T, &read_pdu(1, 2000, 2000), &mut fx);
        assert_eq!(s.exception(), None);
        let s = exc(T, &read_pdu(1, 2001, 2000), &mut fx);
        assert_exception(&s, T, 1, 2, false, "Illegal data address 0xFA1 in read_bits\n");
    }

    #[test]
    fn read_bits_address_errors_name_the_table() {
        let mut fx = Fixture::unit_test();
        // Below the start: the address itself is printed.
        let s = exc(T, &read_pdu(1, 0x12F, 1), &mut fx);
        assert_exception(&s, T, 1, exception::ILLEGAL_DATA_ADDRESS, false, "Illegal data address 0x12F in read_bits\n");
        // One past the end: address + nb.
        let s = exc(T, &read_pdu(1, 0x130, 0x26), &mut fx);
        assert_exception(&s, T, 1, 2, false, "Illegal data address 0x156 in read_bits\n");
        let s = exc(T, &read_pdu(2, 0x1C4 + 0x16, 1), &mut fx);
        assert_exception(&s, T, 2, 2, false, "Illegal data address 0x1DB in read_input_bits\n");
        let s = exc(T, &read_pdu(2, 0, 1), &mut fx);
        assert_exception(&s, T, 2, 2, false, "Illegal data address 0x0 in read_input_bits\n");
        // The last input bit is fine.
        let s = exc(R, &read_pdu(2, 0x1C4 + 0x15, 1), &mut fx);
        assert_eq!(s.pdu(R), [2, 1, 0]);
    }

    // ---------------------------------------------------------------- FC 03 / 04

    #[test]
    fn read_registers() {
        let mut fx = Fixture::unit_test();
        fx.registers[0] = 0x022B;
        fx.registers[0x1F] = 0xBEEF;
        for framing in [T, R] {
            let s = exc(framing, &read_pdu(3, 0x160, 2), &mut fx);
            assert_eq!(s.pdu(framing), [3, 4, 0x02, 0x2B, 0, 0]);
            let s = exc(framing, &read_pdu(3, 0x17F, 1), &mut fx);
            assert_eq!(s.pdu(framing), [3, 2, 0xBE, 0xEF]);
            let s = exc(framing, &read_pdu(4, 0x108, 1), &mut fx);
            assert_eq!(s.pdu(framing), [4, 2, 0, 0x0A]);
            let s = exc(framing, &read_pdu(3, 0x160, 0x21), &mut fx);
            assert_exception(&s, framing, 3, 2, false, "Illegal data address 0x181 in read_registers\n");
            let s = exc(framing, &read_pdu(4, 0x107, 1), &mut fx);
            assert_exception(&s, framing, 4, 2, false, "Illegal data address 0x107 in read_input_registers\n");
            let s = exc(framing, &read_pdu(4, 0x108, 2), &mut fx);
            assert_exception(&s, framing, 4, 2, false, "Illegal data address 0x10A in read_input_registers\n");
        }
    }

    #[test]
    fn read_registers_counts() {
        let mut fx = Fixture::zero_based(200);
        fx.registers.iter_mut().enumerate().for_each(|(i, r)| *r = i as u16 * 0x0101);
        for framing in [T, R] {
            let s = exc(framing, &read_pdu(3, 0, 125), &mut fx);
            assert_eq!(s.pdu(framing).len(), 2 + 250);
            assert_eq!(s.pdu(framing)[..6], [3, 250, 0, 0, 1, 1]);
            // The largest response still fits: TCP 259 bytes, RTU 255 with the CRC.
            assert_eq!(s.sent.len(), if framing == T { 259 } else { 255 });
            let s = exc(framing, &read_pdu(3, 0, 126), &mut fx);
            assert_exception(&s, framing, 3, 3, true, "Illegal nb of values 126 in read_registers (max 125)\n");
            let s = exc(framing, &read_pdu(4, 0, 0), &mut fx);
            assert_exception(&s, framing, 4, 3, true, "Illegal nb of values 0 in read_input_registers (max 125)\n");
        }
    }

    #[test]
    fn start_offsets_and_empty_tables() {
        // A mapping that starts at 0xFFFF with one register; all other tables empty.
        let mut fx = Fixture {
            starts: [0, 0, 0xFFFF, -5],
            bits: vec![],
            input_bits: vec![],
            registers: vec![7],
            input_registers: vec![1; 10],
        };
        let s = exc(T, &read_pdu(3, 0xFFFF, 1), &mut fx);
        assert_eq!(s.pdu(T), [3, 2, 0, 7]);
        let s = exc(T, &read_pdu(3, 0xFFFF, 2), &mut fx);
        assert_exception(&s, T, 3, 2, false, "Illegal data address 0x10001 in read_registers\n");
        let s = exc(T, &read_pdu(1, 0, 1), &mut fx);
        assert_exception(&s, T, 1, 2, false, "Illegal data address 0x1 in read_bits\n");
        // A negative start (a C caller may store anything): addresses 0..4 are items 5..9.
        let s = exc(T, &read_pdu(4, 0, 5), &mut fx);
        assert_eq!(s.exception(), None);
        let s = exc(T, &read_pdu(4, 0, 6), &mut fx);
        assert_eq!(s.exception(), Some(2));
        let mut fx = Fixture { starts: [i32::MIN, i32::MAX, i32::MIN, i32::MAX], ..Fixture::zero_based(3) };
        for f in [1, 2, 3, 4] {
            assert_eq!(exc(T, &read_pdu(f, 0, 1), &mut fx).exception(), Some(2));
        }
        assert_eq!(exc(T, &[5, 0, 0, 0xFF, 0], &mut fx).exception(), Some(2));
        assert_eq!(exc(T, &[6, 0, 0, 0, 1], &mut fx).exception(), Some(2));
    }

    // ---------------------------------------------------------------- FC 05

    #[test]
    fn write_bit() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            let req = adu(framing, 0x11, &[5, 0x01, 0x30, 0xFF, 0x00]);
            let s = run(framing, &req, &mut fx);
            assert_eq!(s.exception(), None);
            // The response is the request (a new CRC for RTU, the same bytes).
            assert_eq!(s.sent, req);
            assert_eq!(fx.bits[0], 1);
            let req = adu(framing, 0x11, &[5, 0x01, 0x54, 0x00, 0x00]);
            fx.bits[0x24] = 1;
            let s = run(framing, &req, &mut fx);
            assert_eq!(s.sent, req);
            assert_eq!(fx.bits[0x24], 0);
            // Values other than FF00 / 0000.
            fx.bits[0] = 1;
            let s = exc(framing, &[5, 0x01, 0x30, 0x00, 0x01], &mut fx);
            assert_exception(&s, framing, 5, 3, false, "Illegal data value 0x1 in write_bit request at address 130\n");
            let s = exc(framing, &[5, 0x01, 0x30, 0xFF, 0xFF], &mut fx);
            assert_eq!(s.diag.err, "Illegal data value 0xFFFF in write_bit request at address 130\n");
            assert_eq!(fx.bits[0], 1);
            // Outside the table.
            let s = exc(framing, &[5, 0x01, 0x2F, 0xFF, 0x00], &mut fx);
            assert_exception(&s, framing, 5, 2, false, "Illegal data address 0x12F in write bit\n");
            let s = exc(framing, &[5, 0x01, 0x55, 0xFF, 0x00], &mut fx);
            assert_exception(&s, framing, 5, 2, false, "Illegal data address 0x155 in write bit\n");
        }
    }

    #[test]
    fn write_bit_echoes_raw_mbap() {
        // The response is a copy of the request header: protocol id included.
        let mut fx = Fixture::unit_test();
        let mut req = adu(T, 0x11, &[5, 0x01, 0x30, 0xFF, 0x00]);
        req[2] = 0x00;
        req[3] = 0x05;
        req[4] = 0x00;
        req[5] = 0x63;
        let s = run(T, &req, &mut fx);
        assert_eq!(s.sent[..6], [0x12, 0x34, 0, 5, 0, 6]);
    }

    #[test]
    fn write_single_length_checks_cve_2024_10918() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            let req = adu(framing, 0x11, &[5, 0x01, 0x32, 0xFF, 0x00]);
            // The unit-test-server injects 34 for write_bit and 45 for write_register.
            let s = run_with(framing, 0, &req, 34, &mut fx);
            assert_exception(&s, framing, 5, 3, false, "Invalid request length in modbus_reply to write bit (34)\n");
            assert_eq!(fx.bits[2], 0);
            // A length below header + 3 hides the address (3.1.12): address 0 is outside.
            assert_eq!(run_with(framing, 0, &req, 0, &mut fx).exception(), Some(2));
            for bad in [-1, req.len() as i32 - 1, req.len() as i32 + 1, i32::MAX, i32::MIN] {
                let s = run_with(framing, 0, &req, bad, &mut fx);
                assert_eq!(s.exception(), Some(3), "req_length {bad}");
                assert_eq!(s.diag.err, format!("Invalid request length in modbus_reply to write bit ({bad})\n"));
            }
            let req = adu(framing, 0x11, &[6, 0x01, 0x70, 0x12, 0x34]);
            let s = run_with(framing, 0, &req, 45, &mut fx);
            assert_exception(
                &s,
                framing,
                6,
                3,
                false,
                "Invalid request length in modbus_reply to write register (45)\n",
            );
            assert_eq!(fx.registers[0x10], 0);
            // The address check comes first.
            let req = adu(framing, 0x11, &[6, 0x00, 0x00, 0x12, 0x34]);
            let s = run_with(framing, 0, &req, 45, &mut fx);
            assert_eq!(s.exception(), Some(2));
        }
    }

    // ---------------------------------------------------------------- FC 06

    #[test]
    fn write_register() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            let req = adu(framing, 0x11, &[6, 0x01, 0x7F, 0xAB, 0xCD]);
            let s = run(framing, &req, &mut fx);
            assert_eq!(s.sent, req);
            assert_eq!(fx.registers[0x1F], 0xABCD);
            let s = exc(framing, &[6, 0x01, 0x80, 0, 1], &mut fx);
            assert_exception(&s, framing, 6, 2, false, "Illegal data address 0x180 in write_register\n");
            let s = exc(framing, &[6, 0x01, 0x5F, 0, 1], &mut fx);
            assert_exception(&s, framing, 6, 2, false, "Illegal data address 0x15F in write_register\n");
        }
    }

    // ---------------------------------------------------------------- FC 0F

    fn write_bits_pdu(addr: u16, nb: u16, byte_count: u8, data: &[u8]) -> Vec<u8> {
        let mut p = vec![0x0F];
        p.extend(be(addr));
        p.extend(be(nb));
        p.push(byte_count);
        p.extend_from_slice(data);
        p
    }

    #[test]
    fn write_bits() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            let s = exc(framing, &write_bits_pdu(0x130, 0x25, 5, &[0xCD, 0x6B, 0xB2, 0x0E, 0x1B]), &mut fx);
            assert_eq!(s.pdu(framing), [0x0F, 0x01, 0x30, 0x00, 0x25]);
            assert_eq!(fx.bits[..8], [1, 0, 1, 1, 0, 0, 1, 1]);
            assert_eq!(fx.bits[32..], [1, 1, 0, 1, 1]);
            // Bits past nb in the last byte are not written.
            let mut fx = Fixture::unit_test();
            let s = exc(framing, &write_bits_pdu(0x153, 2, 1, &[0xFF]), &mut fx);
            assert_eq!(s.exception(), None);
            assert_eq!(fx.bits[0x21..], [0, 0, 1, 1]);
        }
    }

    #[test]
    fn write_bits_limits_cve_2019_14462() {
        let mut fx = Fixture::zero_based(2000);
        for framing in [T, R] {
            let data = [0xFFu8; 246];
            let s = exc(framing, &write_bits_pdu(0, 1968, 246, &data), &mut fx);
            assert_eq!(s.exception(), None);
            assert!(fx.bits[..1968].iter().all(|&b| b == 1));
            assert_eq!(fx.bits[1968], 0);
            let s = exc(framing, &write_bits_pdu(0, 1969, 247, &[0; 247]), &mut fx);
            assert_exception(&s, framing, 0x0F, 3, true, "Illegal number of values 1969 in write_bits (max 1968)\n");
            let s = exc(framing, &write_bits_pdu(0, 0, 0, &[]), &mut fx);
            assert_exception(&s, framing, 0x0F, 3, true, "Illegal number of values 0 in write_bits (max 1968)\n");
            // A large quantity with a small byte count (the CVE): refused before reading.
            fx.bits.fill(0);
            let s = exc(framing, &write_bits_pdu(0, 1968, 6, &[0xFF; 6]), &mut fx);
            assert_exception(&s, framing, 0x0F, 3, true, "Illegal number of values 1968 in write_bits (max 1968)\n");
            assert!(fx.bits.iter().all(|&b| b == 0));
            // 9 bits need 2 bytes.
            let s = exc(framing, &write_bits_pdu(0, 9, 1, &[0xFF]), &mut fx);
            assert_eq!(s.exception(), Some(3));
            // A byte count larger than needed is accepted.
            let s = exc(framing, &write_bits_pdu(0, 9, 3, &[0xFF, 0xFF, 0xFF]), &mut fx);
            assert_eq!(s.exception(), None);
        }
    }

    #[test]
    fn write_bits_range_after_counts() {
        let mut fx = Fixture::unit_test();
        let s = exc(T, &write_bits_pdu(0x12F, 1, 1, &[1]), &mut fx);
        assert_exception(&s, T, 0x0F, 2, false, "Illegal data address 0x12F in write_bits\n");
        let s = exc(T, &write_bits_pdu(0x150, 6, 1, &[1]), &mut fx);
        assert_exception(&s, T, 0x0F, 2, false, "Illegal data address 0x156 in write_bits\n");
        assert!(fx.bits.iter().all(|&b| b == 0));
    }

    // ---------------------------------------------------------------- FC 10

    fn write_regs_pdu(addr: u16, nb: u16, byte_count: u8, values: &[u16]) -> Vec<u8> {
        let mut p = vec![0x10];
        p.extend(be(addr));
        p.extend(be(nb));
        p.push(byte_count);
        values.iter().for_each(|v| p.extend(be(*v)));
        p
    }

    #[test]
    fn write_registers() {
        let mut fx = Fixture::unit_test();
        for framing in [T, R] {
            let s = exc(framing, &write_regs_pdu(0x160, 3, 6, &[0x022B, 1, 0x64]), &mut fx);
            assert_eq!(s.pdu(framing), [0x10, 0x01, 0x60, 0x00, 0x03]);
            assert_eq!(fx.registers[..4], [0x022B, 1, 0x64, 0]);
            let s = exc(framing, &write_regs_pdu(0x17F, 2, 4, &[1, 2]), &mut fx);
            assert_exception(&s, framing, 0x10, 2, false, "Illegal data address 0x181 in write_registers\n");
            let s = exc(framing, &write_regs_pdu(0x15F, 2, 4, &[1, 2]), &mut fx);
            assert_exception(&s, framing, 0x10, 2, false, "Illegal data address 0x15F in write_registers\n");
        }
    }

    #[test]
    fn write_registers_limits_cve_2019_14463() {
        let mut fx = Fixture::zero_based(200);
        for framing in [T, R] {
            let values: Vec<u16> = (0..123).collect();
            let s = exc(framing, &write_regs_pdu(0, 123, 246, &values), &mut fx);
            assert_eq!(s.exception(), None);
            assert_eq!(fx.registers[122], 122);
            let s = exc(framing, &write_regs_pdu(0, 124, 248, &[0; 124]), &mut fx);
            assert_exception(&s, framing, 0x10, 3, true, "Illegal number of values 124 in write_registers (max 123)\n");
            let s = exc(framing, &write_regs_pdu(0, 0, 0, &[]), &mut fx);
            assert_eq!(s.exception(), Some(3));
            // Byte count that disagrees with the quantity, smaller or larger (the CVE).
            fx.registers.fill(0);
            let s = exc(framing, &write_regs_pdu(0, 123, 6, &[9, 9, 9]), &mut fx);
            assert_exception(&s, framing, 0x10, 3, true, "Illegal number of values 123 in write_registers (max 123)\n");
            let s = exc(framing, &write_regs_pdu(0, 1, 4, &[9, 9]), &mut fx);
            assert_eq!(s.exception(), Some(3));
            // 3.1.5's wrong rule (nb_bytes * 8 < nb) would have accepted this one.
            let s = exc(framing, &write_regs_pdu(0, 3, 1, &[9]), &mut fx);
            assert_eq!(s.exception(), Some(3));
            assert!(fx.registers.iter().all(|&r| r == 0));
        }
    }

    // ---------------------------------------------------------------- FC 11 / 07

    #[test]
    fn report_slave_id() {
        let mut fx = Fixture::unit_test();
        let s = exc(T, &[0x11], &mut fx);
        assert_eq!(
            s.sent,
            [
                0x12, 0x34, 0, 0, 0, 0x0E, 0x11, 0x11, 0x0B, 0xB4, 0xFF, b'L', b'M', b'B', b'3', b'.', b'1', b'.',
                b'1', b'2'
            ]
        );
        let s = exc(R, &[0x11], &mut fx);
        assert_eq!(s.pdu(R), [0x11, 0x0B, 0xB4, 0xFF, b'L', b'M', b'B', b'3', b'.', b'1', b'.', b'1', b'2']);
        assert!(s.diag.err.is_empty());
    }

    #[test]
    fn one_byte_pdus_in_short_buffers_issue_837() {
        // MBAP + function only, in a buffer of exactly 8 bytes: nothing past it is read.
        let mut fx = Fixture::unit_test();
        let req = &adu(T, 0xFF, &[0x11])[..];
        assert_eq!(req.len(), 8);
        let s = run(T, req, &mut fx);
        assert_eq!(s.pdu(T)[..2], [0x11, 0x0B]);
        let s = run(T, &adu(T, 0xFF, &[0x07]), &mut fx);
        assert_eq!(s.outcome, Outcome::Fail(Error(crate::error::errno::ENOPROTOOPT)));
        // A bare 7-byte header, and nothing at all: function 0 (unknown).
        let s = run(T, &req[..7], &mut fx);
        assert_exception(&s, T, 0, 1, true, "Unknown Modbus function code: 0x0\n");
        assert_eq!(s.sent[..7], [0x12, 0x34, 0, 0, 0, 3, 0xFF]);
        let s = run(T, &[], &mut fx);
        assert_eq!(s.sent, [0, 0, 0, 0, 0, 3, 0, 0x80, 1]);
        let s = run(R, &[], &mut fx);
        assert_eq!(s.exception(), Some(1));
        assert!(matches!(s.outcome, Outcome::Respond { suppressed: true, .. }));
    }

    #[test]
    fn read_exception_status_sends_nothing() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            let s = exc(framing, &[0x07], &mut fx);
            assert_eq!(s.outcome, Outcome::Fail(Error(crate::error::errno::ENOPROTOOPT)));
            assert_eq!(s.diag.err, "FIXME Not implemented\n");
            assert!(s.sent.is_empty());
            // Even as an RTU broadcast: the failure comes before the suppression.
            let s = run(framing, &adu(framing, 0, &[0x07]), &mut fx);
            assert_eq!(s.outcome, Outcome::Fail(Error(crate::error::errno::ENOPROTOOPT)));
        }
    }

    // ---------------------------------------------------------------- FC 16

    #[test]
    fn mask_write_register() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            fx.registers[0] = 0x12;
            let req = adu(framing, 0x11, &[0x16, 0x01, 0x60, 0x00, 0xF2, 0x00, 0x25]);
            let s = run(framing, &req, &mut fx);
            assert_eq!(s.sent, req);
            assert_eq!(fx.registers[0], 0x17);
            // Wrong length: the register is modified anyway, then the exception.
            fx.registers[0] = 0x12;
            let s = run_with(framing, 0, &req, req.len() as i32 + 1, &mut fx);
            let msg = format!("Invalid request length in modbus_reply to mask write register ({})\n", req.len() + 1);
            assert_exception(&s, framing, 0x16, 3, false, &msg);
            assert_eq!(fx.registers[0], 0x17);
            let s = exc(framing, &[0x16, 0x01, 0x80, 0, 0, 0, 0], &mut fx);
            assert_exception(&s, framing, 0x16, 2, false, "Illegal data address 0x180 in write_register\n");
        }
    }

    // ---------------------------------------------------------------- FC 17

    fn wr_pdu(raddr: u16, rnb: u16, waddr: u16, wnb: u16, byte_count: u8, values: &[u16]) -> Vec<u8> {
        let mut p = vec![0x17];
        p.extend(be(raddr));
        p.extend(be(rnb));
        p.extend(be(waddr));
        p.extend(be(wnb));
        p.push(byte_count);
        values.iter().for_each(|v| p.extend(be(*v)));
        p
    }

    #[test]
    fn write_and_read_writes_first() {
        for framing in [T, R] {
            let mut fx = Fixture::unit_test();
            fx.registers[..4].copy_from_slice(&[1, 2, 3, 4]);
            let s = exc(framing, &wr_pdu(0x160, 4, 0x161, 2, 4, &[0xAAAA, 0xBBBB]), &mut fx);
            assert_eq!(s.pdu(framing), [0x17, 8, 0, 1, 0xAA, 0xAA, 0xBB, 0xBB, 0, 4]);
        }
    }

    #[test]
    fn write_and_read_limits() {
        let mut fx = Fixture::zero_based(200);
        let s = exc(T, &wr_pdu(0, 125, 0, 121, 242, &[7; 121]), &mut fx);
        assert_eq!(s.exception(), None);
        assert_eq!(s.sent.len(), 7 + 2 + 250);
        let cases: [(u16, u16, u8, &str); 5] = [
            (126, 1, 2, "(W1, R126)"),
            (0, 1, 2, "(W1, R0)"),
            (1, 122, 244, "(W122, R1)"),
            (1, 0, 0, "(W0, R1)"),
            (1, 2, 2, "(W2, R1)"),
        ];
        for (rnb, wnb, bc, what) in cases {
            let s = exc(T, &wr_pdu(0, rnb, 0, wnb, bc, &vec![0; wnb as usize]), &mut fx);
            let msg = format!("Illegal nb of values {what} in write_and_read_registers (max W121, R125)\n");
            assert_exception(&s, T, 0x17, 3, true, &msg);
        }
    }

    #[test]
    fn write_and_read_address_below_start_cve_2022_0367() {
        let mut fx = Fixture::unit_test();
        // Read range fine, write address below start_registers.
        let s = exc(T, &wr_pdu(0x160, 1, 0x100, 2, 4, &[0xDEAD, 0xBEEF]), &mut fx);
        assert_exception(
            &s,
            T,
            0x17,
            2,
            false,
            "Illegal data read address 0x161 or write address 0x100 write_and_read_registers\n",
        );
        assert!(fx.registers.iter().all(|&r| r == 0));
        // Write range past the end.
        let s = exc(T, &wr_pdu(0x160, 1, 0x17F, 2, 4, &[1, 2]), &mut fx);
        assert_eq!(s.diag.err, "Illegal data read address 0x161 or write address 0x181 write_and_read_registers\n");
        // Read range below start.
        let s = exc(R, &wr_pdu(0x15F, 1, 0x160, 1, 2, &[1]), &mut fx);
        assert_eq!(s.diag.err, "Illegal data read address 0x15F or write address 0x161 write_and_read_registers\n");
        assert!(fx.registers.iter().all(|&r| r == 0));
        // Last register for both.
        let s = exc(R, &wr_pdu(0x17F, 1, 0x17F, 1, 2, &[0x4242]), &mut fx);
        assert_eq!(s.pdu(R), [0x17, 2, 0x42, 0x42]);
    }

    // ---------------------------------------------------------------- others

    #[test]
    fn unknown_functions() {
        for framing in [T, R] {
            for (function, rsp_fc) in
                [(0x00, 0x80), (0x08, 0x88), (0x2B, 0xAB), (0x42, 0xC2), (0x83, 0x03), (0xFF, 0x7F)]
            {
                let mut fx = Fixture::unit_test();
                let s = exc(framing, &[function, 1, 2, 3, 4], &mut fx);
                assert_exception(
                    &s,
                    framing,
                    function,
                    exception::ILLEGAL_FUNCTION,
                    true,
                    &format!("Unknown Modbus function code: 0x{function:X}\n"),
                );
                assert_eq!(s.pdu(framing)[0], rsp_fc);
            }
        }
        // Every code libmodbus does not serve.
        let served = [1, 2, 3, 4, 5, 6, 7, 0x0F, 0x10, 0x11, 0x16, 0x17];
        for function in 0..=255u8 {
            let mut fx = Fixture::unit_test();
            let s = exc(T, &[function], &mut fx);
            if !served.contains(&function) {
                assert_eq!(s.exception(), Some(1));
                assert!(s.flushed());
            }
        }
    }

    #[test]
    fn rtu_broadcast_is_suppressed_after_the_writes() {
        let mut fx = Fixture::unit_test();
        let req = adu(R, 0, &[6, 0x01, 0x60, 0x12, 0x34]);
        let s = run(R, &req, &mut fx);
        assert!(matches!(s.outcome, Outcome::Respond { suppressed: true, exception: None, .. }));
        assert_eq!(fx.registers[0], 0x1234);
        // An exception to a broadcast: still flushed first, still not sent.
        let s = run(R, &adu(R, 0, &read_pdu(3, 0, 0)), &mut fx);
        assert!(matches!(s.outcome, Outcome::Respond { suppressed: true, flush_first: true, .. }));
        // With MODBUS_QUIRK_REPLY_TO_BROADCAST the answer goes out.
        let s = run_with(R, QUIRK_REPLY_TO_BROADCAST, &req, req.len() as i32, &mut fx);
        assert!(matches!(s.outcome, Outcome::Respond { suppressed: false, .. }));
        assert_eq!(s.sent, req);
        // Other quirk bits do not matter.
        let s = run_with(R, 1 << 1, &req, req.len() as i32, &mut fx);
        assert!(matches!(s.outcome, Outcome::Respond { suppressed: true, .. }));
        // TCP never suppresses: unit 0 gets an answer.
        let req = adu(T, 0, &[6, 0x01, 0x60, 0x43, 0x21]);
        let s = run(T, &req, &mut fx);
        assert!(matches!(s.outcome, Outcome::Respond { suppressed: false, .. }));
        assert_eq!(s.sent, req);
        // Other RTU slaves are answered (the receive side filters them, not the reply).
        let req = adu(R, 5, &[6, 0x01, 0x60, 0x43, 0x21]);
        assert!(matches!(run(R, &req, &mut fx).outcome, Outcome::Respond { suppressed: false, .. }));
    }

    #[test]
    fn address_is_read_only_when_the_length_covers_it() {
        let mut fx = Fixture::unit_test();
        let req = adu(T, 0xFF, &read_pdu(3, 0x160, 1));
        // 3.1.12: req_length below header + 3 means address 0.
        let s = run_with(T, 0, &req, 9, &mut fx);
        assert_eq!(s.diag.err, "Illegal data address 0x0 in read_registers\n");
        let s = run_with(T, 0, &req, 10, &mut fx);
        assert_eq!(s.exception(), None);
        // A negative length compares as a huge unsigned one in C: the address is read
        // (the unit-test-server replies with -1 after a CRC error).
        let s = run_with(T, 0, &req, -1, &mut fx);
        assert_eq!(s.exception(), None);
        let req = adu(R, 0x11, &read_pdu(3, 0x160, 1));
        let s = run_with(R, 0, &req, 3, &mut fx);
        assert_eq!(s.diag.err, "Illegal data address 0x0 in read_registers\n");
        let s = run_with(R, 0, &req, 4, &mut fx);
        assert_eq!(s.exception(), None);
    }

    #[test]
    fn truncated_requests_read_zeros() {
        let mut fx = Fixture::zero_based(10);
        // FC 03 cut after the address: nb reads as 0.
        let req = adu(T, 1, &read_pdu(3, 1, 2));
        let s = run(T, &req[..10], &mut fx);
        assert_exception(&s, T, 3, 3, true, "Illegal nb of values 0 in read_registers (max 125)\n");
        // FC 10 whose values are missing: written as zeros, as far as the checks allow.
        fx.registers.fill(9);
        let req = adu(T, 1, &write_regs_pdu(0, 2, 4, &[1, 2]));
        let s = run(T, &req[..13], &mut fx);
        assert_eq!(s.exception(), None);
        assert_eq!(fx.registers[..3], [0, 0, 9]);
        // FC 05 cut short fails the length check.
        let req = adu(T, 1, &[5, 0, 1, 0xFF, 0]);
        assert_eq!(run(T, &req[..10], &mut fx).exception(), Some(3));
    }

    #[test]
    fn exception_response_shapes() {
        let mut out = [0u8; MAX_ADU_LENGTH];
        let req = adu(T, 9, &read_pdu(3, 0, 1));
        let n = exception_response(T, &req, 6, &mut out);
        assert_eq!(out[..n], [0x12, 0x34, 0, 0, 0, 0, 9, 0x83, 6]);
        let req = adu(R, 9, &[0x83]);
        let n = exception_response(R, &req, 0, &mut out);
        assert_eq!(out[..n], [9, 0x03, 0]);
        let n = exception_response(R, &[], 11, &mut out);
        assert_eq!(out[..n], [0, 0x80, 11]);
    }

    #[test]
    fn request_extent_follows_the_indication_parser() {
        let ext = |framing: Framing, req: &[u8], bound: usize| {
            request_extent(framing, false, bound, |n| {
                assert!(n <= req.len().min(bound), "read past the bound: {n}");
                &req[..n]
            })
        };
        let big = usize::MAX;
        assert_eq!(ext(T, &adu(T, 1, &read_pdu(3, 0, 1)), big), 12);
        assert_eq!(ext(R, &adu(R, 1, &read_pdu(3, 0, 1)), big), 8);
        assert_eq!(ext(T, &adu(T, 1, &[0x11]), big), 8);
        assert_eq!(ext(R, &adu(R, 1, &[0x11]), big), 4);
        assert_eq!(ext(T, &adu(T, 1, &write_regs_pdu(0, 2, 4, &[1, 2])), big), 17);
        assert_eq!(ext(R, &adu(R, 1, &wr_pdu(0, 1, 0, 1, 2, &[1])), big), 1 + 10 + 2 + 2);
        assert_eq!(ext(T, &adu(T, 1, &[0x16, 0, 0, 0, 0, 0, 0]), big), 14);
        // Bounded by the caller's length, even inside the header or the meta bytes.
        assert_eq!(ext(T, &adu(T, 1, &read_pdu(3, 0, 1)), 12), 12);
        assert_eq!(ext(T, &adu(T, 1, &read_pdu(3, 0, 1)), 9), 9);
        assert_eq!(ext(T, &adu(T, 1, &read_pdu(3, 0, 1)), 5), 5);
        assert_eq!(ext(T, &adu(T, 1, &write_regs_pdu(0, 2, 4, &[1, 2])), 13), 13);
        assert_eq!(ext(T, &adu(T, 1, &write_regs_pdu(0, 2, 4, &[1, 2])), 12), 12);
        assert_eq!(ext(R, &[], 0), 0);
        // Byte counts are capped at the framing's largest ADU.
        let mut huge = adu(T, 1, &write_bits_pdu(0, 1968, 255, &[0; 255]));
        assert_eq!(ext(T, &huge, big), 260);
        huge.truncate(260);
        let mut fx = Fixture::zero_based(2000);
        let s = run_with(T, 0, &huge, -1, &mut fx);
        assert_eq!(s.exception(), None);
        let rtu = adu(R, 1, &wr_pdu(0, 1, 0, 1, 255, &[0; 128]));
        assert_eq!(ext(R, &rtu, big), 256);
    }

    #[test]
    fn request_extent_of_extended_requests() {
        let ext = |framing: Framing, extended: bool, req: &[u8], bound: usize| {
            request_extent(framing, extended, bound, |n| {
                assert!(n <= req.len().min(bound), "read past the bound: {n}");
                &req[..n]
            })
        };
        let big = usize::MAX;
        // Diagnostics: RTU one word; TCP as the MBAP length says.
        let rtu = adu(R, 1, &[0x08, 0, 0, 0xA5, 0x37]);
        assert_eq!(ext(R, true, &rtu, big), 8);
        assert_eq!(ext(R, false, &rtu, big), 4, "libmodbus framing when not served");
        let tcp = adu(T, 1, &[0x08, 0, 0, 1, 2, 3, 4, 5, 6]);
        assert_eq!(ext(T, true, &tcp, big), 16);
        assert_eq!(ext(T, false, &tcp, big), 8);
        // File records by their byte count, FIFO and device identification fixed.
        let rd = adu(R, 1, &[0x14, 7, 6, 0, 1, 0, 0, 0, 2]);
        assert_eq!(ext(R, true, &rd, big), rd.len());
        let wr = adu(T, 1, &[0x15, 9, 6, 0, 1, 0, 0, 0, 1, 0xAB, 0xCD]);
        assert_eq!(ext(T, true, &wr, big), wr.len());
        assert_eq!(ext(T, true, &adu(T, 1, &[0x18, 0, 1]), big), 10);
        assert_eq!(ext(R, true, &adu(R, 1, &[0x2B, 0x0E, 1, 0]), big), 7);
        // Bounded by the caller's length and by the ADU.
        assert_eq!(ext(R, true, &rd, 5), 5);
        assert_eq!(ext(R, true, &rd, 2), 2);
        assert_eq!(ext(T, true, &tcp, 13), 13);
        let mut huge = adu(T, 1, &[0x08, 0, 0]);
        huge[4] = 0xFF;
        huge.resize(300, 0);
        assert_eq!(ext(T, true, &huge, big), 260);
        let mut counted = adu(R, 1, &[0x15, 255]);
        counted.resize(300, 0);
        assert_eq!(ext(R, true, &counted, big), 256);
        // Other function codes are unaffected.
        assert_eq!(ext(T, true, &adu(T, 1, &read_pdu(3, 0, 1)), big), 12);
        // RTU diagnostics: where the CRC matches, within the caller's length.
        let three_words = adu(R, 1, &[0x08, 0, 0, 1, 2, 3, 4, 5, 6]);
        assert_eq!(ext(R, true, &three_words, three_words.len()), 12);
        let mut padded = three_words.clone();
        padded.extend([0xEE; 20]);
        assert_eq!(ext(R, true, &padded, padded.len()), 12);
        assert_eq!(ext(R, true, &three_words, 11), 11, "no match: the caller's length");
        assert_eq!(ext(R, true, &three_words, 7), 7);
        assert_eq!(ext(R, true, &three_words, big), 12, "no length given: the CRC search, as modbus_receive frames it");
        // ASCII diagnostics: the received length when the caller gives it.
        let mut ascii = vec![1, 0x08, 0, 0, 1, 2, 3, 4];
        ascii.push(crate::ascii::lrc(&ascii));
        assert_eq!(ext(Framing::Ascii, true, &ascii, ascii.len()), 9);
        assert_eq!(ext(Framing::Ascii, true, &ascii, big), 7);
        assert_eq!(ext(Framing::Ascii, false, &ascii, ascii.len()), 3);
    }

    /// Deterministic pseudo-random requests of every shape: the reply never panics,
    /// never answers with more than the framing allows, and only the exceptions
    /// libmodbus uses come out.
    #[test]
    fn random_requests_never_misbehave() {
        let mut rng = crate::test_rng::XorShift::new(0x2545_F491_4F6C_DD1D);
        let mut next = || rng.next_u64();
        let functions = [0u8, 1, 2, 3, 4, 5, 6, 7, 8, 0x0F, 0x10, 0x11, 0x16, 0x17, 0x2B, 0x83];
        for round in 0..20_000 {
            let framing = if round % 2 == 0 { T } else { R };
            let len = (next() % 262) as usize;
            let mut req: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let h = framing.header_length();
            if req.len() > h {
                req[h] = functions[(next() % functions.len() as u64) as usize];
            }
            if req.len() > h + 4 && next() % 2 == 0 {
                // Small quantities so that the success paths run too.
                req[h + 3] = 0;
                req[h + 1] = 0;
            }
            let req_length = match next() % 4 {
                0 => -1,
                1 => (next() % 300) as i32,
                _ => req.len() as i32,
            };
            let mut fx = Fixture::zero_based(300);
            let s = run_with(framing, 0, &req, req_length, &mut fx);
            if let Outcome::Respond { len, exception, .. } = s.outcome {
                assert!(len + framing.checksum_length() <= framing.max_adu_length());
                assert!(matches!(exception, None | Some(1..=3)));
            }
        }
    }

    /// A data set that takes every function code (a gateway's) sees each request's
    /// PDU as it came, FC 03 included, and its answer goes out behind the header.
    #[test]
    fn every_function_through_other_when_asked() {
        struct All(Vec<u8>);
        impl Data for All {
            fn accept_unit(&mut self, _unit: u8, _req: &[u8]) -> bool {
                true
            }
            fn check(
                &mut self,
                _rq: &Request,
                _ranges: &[Range],
                _diag: &mut dyn Diag,
            ) -> core::result::Result<(), Refusal> {
                panic!("no check for a request passed through")
            }
            fn read_bits(&mut self, _rq: &Request, _a: u16, _d: &mut [u8]) -> core::result::Result<(), Refusal> {
                panic!("no data access")
            }
            fn read_registers(&mut self, _rq: &Request, _a: u16, _d: &mut [u16]) -> core::result::Result<(), Refusal> {
                panic!("no data access")
            }
            fn write_bits(&mut self, _rq: &Request, _a: u16, _s: &[u8]) -> core::result::Result<(), Refusal> {
                panic!("no data access")
            }
            fn write_registers(&mut self, _rq: &Request, _a: u16, _s: &[u16]) -> core::result::Result<(), Refusal> {
                panic!("no data access")
            }
            fn other(
                &mut self,
                _rq: &Request,
                pdu: &[u8],
                rsp: &mut [u8],
            ) -> Option<core::result::Result<usize, Refusal>> {
                self.0 = pdu.to_vec();
                rsp[..3].copy_from_slice(&[pdu[0], 0xAB, 0xCD]);
                Some(Ok(3))
            }
            fn takes_every_function(&self) -> bool {
                true
            }
        }
        let server = Server { framing: T, quirks: 0 };
        // A read of 2000 registers (past every limit): passed through as it came.
        let req = [0x00, 0x07, 0x00, 0x00, 0x00, 0x06, 0x11, 0x03, 0x00, 0x10, 0x07, 0xD0];
        let mut data = All(Vec::new());
        let mut out = [0u8; MAX_ADU_LENGTH];
        let outcome = server.answer(&req, req.len() as i32, &mut data, &mut Recorded::default(), &mut out);
        assert_eq!(data.0, vec![0x03, 0x00, 0x10, 0x07, 0xD0]);
        let Outcome::Respond { len, suppressed: false, .. } = outcome else { panic!("{outcome:?}") };
        assert_eq!(&out[..len], &[0x00, 0x07, 0x00, 0x00, 0x00, 0x00, 0x11, 0x03, 0xAB, 0xCD][..len]);
    }
}
