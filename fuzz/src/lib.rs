//! Fuzz harnesses for rsmodbus, shared by the libFuzzer targets (`fuzz_targets/`) and
//! the `replay` tool (corpus and regression replay, random drive without libFuzzer).
//!
//! Targets (one function each, `fn(&[u8])`; a panic or abort is a finding):
//!
//! | target       | path exercised                                                        |
//! |--------------|-----------------------------------------------------------------------|
//! | `server_rtu` | bytes -> `Assembler` (indication) -> RTU integrity -> `Server::reply` -> sealed bytes out |
//! | `server_tcp` | the same with MBAP framing                                            |
//! | `client_rtu` | request of every function code -> response bytes -> `Assembler` (confirmation) -> `confirm::check` |
//! | `client_tcp` | the same with MBAP framing                                            |
//! | `ffi_server` | the C ABI: `modbus_receive` + `modbus_reply` over a socket pair, mapping with start offsets |
//! | `ffi_client` | the C ABI: every client call against pre-written response bytes      |
//! | `ffi_async`  | the event-driven client: requests pipelined, answers in chunks       |
//! | `server_ascii`, `client_ascii` | the same paths with Modbus ASCII: characters -> `ascii::Decoder` -> LRC -> ... |
//! | `security`   | Modbus/TCP Security: TLS record boundaries of a server's reads, the role of a certificate, what a request asks the authorization callback |
//! | `gateway_config` | the gateway's configuration file and command line -> `rsmodbus_gateway::config::load` (`gateway_config.rs`) |
//! | `gateway_master` | masters' Modbus/TCP bytes -> the gateway's core (`rsmodbus_gateway::core`) -> two simulated lines (`gateway_master.rs`) |
//!
//! The FFI targets choose TCP, RTU or ASCII contexts from their first byte.
//!
//! Every input is "config bytes, then wire bytes"; the layouts are documented on each
//! function and produced for the seeds by `fuzz/make-corpus.py`.

use std::fmt;

use modbus::error::{Error, MODBUS_ENOBASE};
use modbus::proto::confirm::{self, Rejection};
use modbus::proto::crc::crc16;
use modbus::proto::frame::{Assembler, Framing, MAX_ADU_LENGTH, MsgKind, Progress, RtuIntegrity, rtu_integrity};
use modbus::proto::reply::{Outcome, QUIRK_REPLY_TO_BROADCAST, Server, Table, Tables, request_extent};
use modbus::proto::request::Request;
use modbus::proto::{Diag, ascii};

pub mod ffi;
mod gateway_config;
mod gateway_master;

pub use ffi::{authorization, ffi_async, ffi_client, ffi_server};
pub use gateway_config::gateway_config;
pub use gateway_master::gateway_master;

/// A debug sink that really formats every message (so formatting code runs too) and
/// keeps memory bounded.
#[derive(Default)]
pub struct Sink(String);

impl Diag for Sink {
    fn out(&mut self, args: fmt::Arguments<'_>) {
        self.write(args);
    }
    fn err(&mut self, args: fmt::Arguments<'_>) {
        self.write(args);
    }
}

impl Sink {
    fn write(&mut self, args: fmt::Arguments<'_>) {
        if self.0.len() > 4096 {
            self.0.clear();
        }
        fmt::Write::write_fmt(&mut self.0, args).expect("formatting a debug message failed");
    }
}

/// Reads config bytes; missing bytes read as 0.
pub struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Cursor { data, pos: 0 }
    }
    pub fn u8(&mut self) -> u8 {
        let b = self.data.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b
    }
    pub fn u16(&mut self) -> u16 {
        u16::from_be_bytes([self.u8(), self.u8()])
    }
    pub fn rest(&self) -> &'a [u8] {
        &self.data[self.pos.min(self.data.len())..]
    }
}

/// A table start address from one config byte: 0, small, near 0xFFFF, or odd C ints
/// (the C fields are `int`s filled from `unsigned int` arguments).
pub fn start_of(b: u8) -> i32 {
    let v = (b & 0x3F) as i32;
    match b >> 6 {
        0 => 0,
        1 => v * 17,
        2 => 0xFFFF - v * 37,
        _ => [i32::MIN, -1, 0x10000, i32::MAX, -v, 0x7FFF, 0x8000, 1][(v & 7) as usize],
    }
}

/// A table size from one config byte: 0 (no table), up to 2100 items.
pub fn size_of(b: u8) -> usize {
    match b {
        0 => 0,
        0xFF => 2100,
        0xFE => 2000,
        0xFD => 125,
        _ => b as usize * 8 + 1,
    }
}

/// Chunk size of reads from the config: how the bytes trickle in.
pub fn chunk_of(bits: u8) -> usize {
    [usize::MAX, 1, 2, 3, 5, 8, 13, 64][(bits & 7) as usize]
}

/// An RTU slave id for a context from a selector.
pub fn slave_of(sel: u8) -> i32 {
    [0x11, -1, 1, 0, 247, 255, 0x12, 2][(sel & 7) as usize]
}

/// Decodes one ASCII frame from a character stream, as the engine does (noise before
/// ':' skipped, CR LF ends it). Returns what happened and the characters consumed.
pub fn assemble_ascii(stream: &[u8], buf: &mut [u8; MAX_ADU_LENGTH]) -> (Assembled, usize) {
    let mut d = ascii::Decoder::new();
    for (i, &c) in stream.iter().enumerate() {
        match d.feed(c, buf) {
            Ok(ascii::Step::NeedMore) => assert!(d.len() <= ascii::MAX_DECODED),
            Ok(ascii::Step::Complete(len)) => {
                assert!(len <= ascii::MAX_DECODED);
                return (Assembled::Frame(len), i + 1);
            }
            Err(e) => {
                assert_eq!(e, Error::BAD_DATA, "ASCII decoder failed with an unexpected error");
                return (Assembled::TooLong, i + 1);
            }
        }
    }
    (Assembled::Eof, stream.len())
}

/// How the engine frames a message: whether a server frames the function codes
/// beyond libmodbus whole (`Context::serves_extended`), and the length of the
/// diagnostics request a serial client sent (`Context::diagnostics_sent`).
#[derive(Clone, Copy, Default)]
pub struct Framed {
    pub extended: bool,
    pub expecting: Option<usize>,
}

/// Frames one message of `framing` from `stream` (binary or ASCII characters).
pub fn frame_one(
    framing: Framing,
    kind: MsgKind,
    how: Framed,
    stream: &[u8],
    chunk: usize,
    buf: &mut [u8; MAX_ADU_LENGTH],
) -> (Assembled, usize) {
    match framing {
        Framing::Ascii => assemble_ascii(stream, buf),
        _ => assemble(framing, kind, how, stream, chunk, buf),
    }
}

/// The slave filter of the serial framings after their checksum (RTU: CRC first, as
/// 3.1.11+; ASCII: LRC first). `None` = the frame is fine; `Some(true)` = bad
/// checksum; `Some(false)` = another slave's frame.
pub fn serial_integrity(framing: Framing, frame: &[u8], slave: i32) -> Option<bool> {
    match framing {
        Framing::Tcp => None,
        Framing::Rtu => match rtu_integrity(frame, slave) {
            RtuIntegrity::Ok => None,
            RtuIntegrity::BadCrc(..) => Some(true),
            RtuIntegrity::OtherSlave(..) => Some(false),
        },
        Framing::Ascii => {
            if frame.len() < 2 || ascii::check_lrc(frame).is_err() {
                Some(true)
            } else if frame[0] as i32 != slave && frame[0] != 0 {
                Some(false)
            } else {
                None
            }
        }
    }
}

/// A sealed binary ADU as it goes on the wire (ASCII: encoded to characters).
pub fn wire(framing: Framing, adu: &[u8]) -> Vec<u8> {
    match framing {
        Framing::Ascii => {
            let mut out = vec![0u8; ascii::MAX_ENCODED.max(1 + 2 * adu.len() + 2)];
            let n = ascii::encode(adu, &mut out);
            out.truncate(n);
            out
        }
        _ => adu.to_vec(),
    }
}

/// What happened to one message fed through an assembler.
pub enum Assembled {
    /// A complete message of this length, `consumed` bytes taken from the stream.
    Frame(usize),
    /// The assembler refused the announced length after `consumed` bytes.
    TooLong,
    /// The stream ended mid-message (the peer closed: ECONNRESET).
    Eof,
}

/// Feeds `stream` to a fresh assembler in chunks of at most `chunk` bytes, the way the
/// engine's receive loop does. Returns what happened and the bytes consumed. Checks
/// that the assembler never asks for bytes past the framing's maximum ADU and that its
/// bookkeeping is consistent.
pub fn assemble(
    framing: Framing,
    kind: MsgKind,
    how: Framed,
    stream: &[u8],
    chunk: usize,
    buf: &mut [u8; MAX_ADU_LENGTH],
) -> (Assembled, usize) {
    let mut asm = Assembler::new(framing, kind).extended_requests(how.extended).expecting(how.expecting);
    let mut pos = 0;
    loop {
        let want = asm.wanted();
        assert!(want > 0, "assembler wants 0 bytes before completion");
        assert!(
            asm.len() + want <= framing.max_adu_length(),
            "assembler asks past the maximum ADU: {} + {} > {}",
            asm.len(),
            want,
            framing.max_adu_length()
        );
        let n = want.min(chunk).min(stream.len() - pos);
        if n == 0 {
            return (Assembled::Eof, pos);
        }
        let have = asm.len();
        buf[have..have + n].copy_from_slice(&stream[pos..pos + n]);
        pos += n;
        match asm.received(&buf[..have + n], n) {
            Ok(Progress::NeedMore(k)) => {
                assert_eq!(k, asm.wanted(), "NeedMore disagrees with wanted()");
                assert!(k > 0);
            }
            Ok(Progress::Complete(len)) => {
                assert_eq!(len, pos, "completed length differs from the bytes fed");
                assert!(len > framing.header_length(), "complete message without a function code");
                return (Assembled::Frame(len), pos);
            }
            Err(e) => {
                assert_eq!(e, Error::BAD_DATA, "assembler failed with an unexpected error");
                return (Assembled::TooLong, pos);
            }
        }
    }
}

/// Four owned tables with given starts, filled with a recognisable pattern (bits 0/1).
pub struct Model {
    pub starts: [i32; 4],
    pub bits: Vec<u8>,
    pub input_bits: Vec<u8>,
    pub registers: Vec<u16>,
    pub input_registers: Vec<u16>,
}

impl Model {
    pub fn new(starts: [i32; 4], sizes: [usize; 4]) -> Model {
        Model {
            starts,
            bits: (0..sizes[0]).map(|i| (i % 3 == 0) as u8).collect(),
            input_bits: (0..sizes[1]).map(|i| (i % 5 < 2) as u8).collect(),
            registers: (0..sizes[2]).map(|i| (i as u16).wrapping_mul(0x9E37) ^ 0x5A5A).collect(),
            input_registers: (0..sizes[3]).map(|i| (i as u16).wrapping_mul(0x3B1D).wrapping_add(7)).collect(),
        }
    }
    pub fn tables(&mut self) -> Tables<'_> {
        Tables {
            bits: Table { start: self.starts[0], data: &mut self.bits },
            input_bits: Table { start: self.starts[1], data: &mut self.input_bits },
            registers: Table { start: self.starts[2], data: &mut self.registers },
            input_registers: Table { start: self.starts[3], data: &mut self.input_registers },
        }
    }
    fn snapshot(&self) -> (Vec<u8>, Vec<u8>, Vec<u16>, Vec<u16>) {
        (self.bits.clone(), self.input_bits.clone(), self.registers.clone(), self.input_registers.clone())
    }
    /// Index of `nb` items from `addr` in a table of `len` items starting at `start`.
    fn range(start: i32, len: usize, addr: u16, nb: usize) -> Option<usize> {
        let first = addr as i64 - start as i64;
        (first >= 0 && first + nb as i64 <= len as i64).then_some(first as usize)
    }
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

/// Finding F1 (open, reported): with `0 <= req_length <= header length`, the C shim
/// hands the core fewer bytes than the header and function code, so the reply reads
/// the slave/unit and function as 0 (exception FC 0x80, and in RTU a "broadcast"
/// that is suppressed). libmodbus always reads `req[offset-1]` and `req[offset]`.
/// More generally, any `req_length` shorter than the request makes the bytes past it
/// read as 0 (e.g. the count of a read), where libmodbus reads them from the buffer.
/// Unless `FUZZ_STRICT=1` is set, the harness keeps such lengths out of the way so
/// that fuzzing goes on; the inputs are fuzz/regressions-open/server_*/f1-* (they
/// fail under `FUZZ_STRICT=1` until F1 is fixed, then move to fuzz/regressions/).
pub fn mask_known_findings() -> bool {
    static STRICT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    !*STRICT.get_or_init(|| std::env::var_os("FUZZ_STRICT").is_some_and(|v| v == "1"))
}

/// Server path. Input layout:
/// `[start bits][start input bits][start regs][start input regs][bit tables size]`
/// `[register tables size][req_length mode][flags]` then the byte stream, which may
/// hold several requests. Flags: bit 0 quirk REPLY_TO_BROADCAST, bits 1-3 chunk size,
/// bits 4-6 RTU slave, bit 7 reply even after a CRC error (as unit-test-server does).
pub fn server(framing: Framing, data: &[u8]) {
    let mut c = Cursor::new(data);
    let starts = [start_of(c.u8()), start_of(c.u8()), start_of(c.u8()), start_of(c.u8())];
    let bit_size = size_of(c.u8());
    let reg_size = size_of(c.u8());
    let mode = c.u8();
    let flags = c.u8();
    let quirks = if flags & 1 != 0 { QUIRK_REPLY_TO_BROADCAST } else { 0 };
    let chunk = chunk_of(flags >> 1);
    let slave = slave_of(flags >> 4);
    let reply_bad_crc = flags & 0x80 != 0;
    // A server that serves the extended function codes frames their requests whole.
    let extended = (64..128).contains(&mode);
    let how = Framed { extended, expecting: None };
    let mut model = Model::new(starts, [bit_size, bit_size / 2 + 1, reg_size, reg_size / 2 + 1]);
    let server = Server { framing, quirks };
    let mut sink = Sink::default();

    let mut stream = c.rest();
    let mut buf = [0u8; MAX_ADU_LENGTH];
    for _ in 0..64 {
        if stream.is_empty() {
            break;
        }
        let (what, consumed) = frame_one(framing, MsgKind::Indication, how, stream, chunk, &mut buf);
        stream = &stream[consumed..];
        let len = match what {
            Assembled::Frame(len) => len,
            Assembled::TooLong => continue,
            Assembled::Eof => break,
        };
        if framing == Framing::Ascii && len < 2 {
            continue; // the engine refuses it (EMBBADDATA)
        }
        // Bytes past the message read as 0 (a C caller's buffer may hold anything
        // there; the model needs them fixed).
        buf[len..].fill(0);
        let full = &buf[..];
        let frame = &buf[..len];

        let mut req_length = match mode {
            0..=127 => len as i32,
            128 => -1,
            129 => i32::MIN,
            130 => i32::MAX,
            m => len as i32 + (m as i32 - 192),
        };
        if mask_known_findings() && (0..=framing.header_length() as i32).contains(&req_length) {
            req_length = framing.header_length() as i32 + 1;
        }
        // F1, second form: a req_length shorter than the request cuts what the reply
        // reads (the rest reads as 0), so the reply answers another request than the
        // one on the wire; only the structural checks apply then.
        let truncated = mask_known_findings() && req_length >= 0 && (req_length as usize) < len;
        match serial_integrity(framing, frame, slave) {
            None => {}
            Some(true) if reply_bad_crc => req_length = -1,
            Some(_) => continue,
        }

        // What the C shim hands to the core: never more than the request describes.
        let bound = if req_length < 0 { usize::MAX } else { req_length as usize };
        let extent = request_extent(framing, extended, bound, |n| {
            // ASCII frames are delimited, not length-parsed: the content may describe
            // more bytes than arrived, which then come from the (zeroed) buffer.
            assert!(n <= len || framing == Framing::Ascii, "request_extent read {n} bytes of a {len}-byte request");
            assert!(n <= bound, "request_extent read {n} bytes past req_length {bound}");
            &full[..n]
        });
        assert!(extent <= bound && extent <= framing.max_adu_length());
        if framing != Framing::Ascii {
            assert_eq!(extent, len.min(bound), "request_extent disagrees with the assembler");
        }
        let req = &full[..extent];

        let before = model.snapshot();
        let mut out = [0u8; MAX_ADU_LENGTH];
        let outcome = server.reply(req, req_length, &mut model.tables(), &mut sink, &mut out);
        if std::env::var_os("FUZZ_DEBUG").is_some() {
            eprintln!("frame {frame:02x?} req_length {req_length} extent {extent} -> {outcome:?} {:02x?}", &out[..12]);
        }
        check_reply(framing, frame, full, req, req_length, quirks, truncated, &before, &model, outcome, &mut out);
    }
}

/// The properties of one reply (see [`server`]).
#[allow(clippy::too_many_arguments)]
fn check_reply(
    framing: Framing,
    frame: &[u8],
    full: &[u8],
    req: &[u8],
    req_length: i32,
    quirks: u32,
    truncated: bool,
    before: &(Vec<u8>, Vec<u8>, Vec<u16>, Vec<u16>),
    model: &Model,
    outcome: Outcome,
    out: &mut [u8; MAX_ADU_LENGTH],
) {
    let h = framing.header_length();
    let cs = framing.checksum_length();
    let function = frame[h];
    let (len, exception, suppressed) = match outcome {
        Outcome::Fail(e) => {
            assert_eq!(function, 0x07, "only FC 0x07 fails without a response");
            assert_eq!(e.0, libc::ENOPROTOOPT);
            assert!(*before == model.snapshot(), "a failed reply changed the mapping");
            return;
        }
        Outcome::Respond { len, exception, suppressed, .. } => (len, exception, suppressed),
    };
    assert!(len >= h + 2, "reply shorter than header + fc + 1: {len}");
    assert!(len + cs <= framing.max_adu_length(), "reply too long: {len}");
    let expect_suppressed = framing.is_serial() && frame[0] == 0 && quirks & QUIRK_REPLY_TO_BROADCAST == 0;
    assert_eq!(suppressed, expect_suppressed, "broadcast suppression");

    let sealed = framing.seal(out, len);
    let rsp = &out[..sealed];
    if truncated {
        return;
    }
    match framing {
        Framing::Tcp => {
            assert_eq!(rsp[..2], frame[..2], "TID not echoed");
            // FC 05/06/16 replies are the request copied (libmodbus memcpy's it, MBAP
            // header included), so a non-zero protocol id is echoed there.
            let echoed = exception.is_none() && matches!(function, 0x05 | 0x06 | 0x16);
            let protocol = if echoed { [frame[2], frame[3]] } else { [0, 0] };
            assert_eq!(rsp[2..4], protocol, "protocol id");
            assert_eq!(be16(rsp, 4) as usize, sealed - 6, "MBAP length");
            assert_eq!(rsp[6], frame[6], "unit not echoed");
        }
        Framing::Rtu => {
            assert_eq!(rsp[0], frame[0], "slave not echoed");
            assert_eq!(crc16(&rsp[..sealed - 2]).to_le_bytes(), rsp[sealed - 2..], "CRC");
        }
        Framing::Ascii => {
            assert_eq!(rsp[0], frame[0], "slave not echoed");
            assert!(ascii::check_lrc(rsp).is_ok(), "LRC");
        }
    }
    match exception {
        Some(code) => {
            assert_eq!(len, h + 2, "exception reply length");
            assert_eq!(rsp[h], function.wrapping_add(0x80));
            assert_eq!(rsp[h + 1], code);
            assert!((1..=3).contains(&code), "modbus_reply only raises codes 1-3: {code}");
            if function != 0x16 {
                assert!(*before == model.snapshot(), "an exception reply changed the mapping (fc {function:#x})");
            }
        }
        None => {
            assert_eq!(rsp[h], function);
            check_mapping_effect(framing, req, req_length, before, model, rsp);
        }
    }

    // A libmodbus client that sent this request frames the reply exactly and accepts
    // it (or reports the exception), whatever the request was.
    if function >= 0x80 {
        return; // the "exception" FC wraps below 0x80: libmodbus answers nonsense there too
    }
    if framing == Framing::Tcp && rsp[2..4] != [0, 0] {
        return; // an echoed non-zero protocol id: a 3.1.12 client refuses it, as it should
    }
    let mut cbuf = [0u8; MAX_ADU_LENGTH];
    let on_wire = wire(framing, rsp);
    let (what, used) = frame_one(framing, MsgKind::Confirmation, Framed::default(), &on_wire, usize::MAX, &mut cbuf);
    match what {
        Assembled::Frame(n) => {
            assert_eq!(n, sealed, "a client frames the reply with another length");
            assert_eq!(used, on_wire.len());
            assert_eq!(cbuf[..n], *rsp, "the reply decodes to other bytes");
        }
        _ => panic!("a client cannot frame the reply"),
    }
    let mut sink = Sink::default();
    let checked = confirm::check(framing, full, rsp, &mut sink);
    match exception {
        None => {
            assert!(checked.is_ok(), "the client refuses a normal reply: {checked:?} ({})", sink.0);
        }
        Some(code) => assert_eq!(checked, Err(Rejection::Exception(Error::from_exception(code)))),
    }
}

/// The mapping changed exactly as the request says, and read replies carry the
/// mapping's values.
fn check_mapping_effect(
    framing: Framing,
    req: &[u8],
    req_length: i32,
    before: &(Vec<u8>, Vec<u8>, Vec<u16>, Vec<u16>),
    model: &Model,
    rsp: &[u8],
) {
    let h = framing.header_length();
    let at = |i: usize| req.get(i).copied().unwrap_or(0);
    let u16_at = |i: usize| u16::from_be_bytes([at(i), at(i + 1)]);
    let function = at(h);
    let addr = u16_at(h + 1);
    let nb = u16_at(h + 3) as usize;
    let unchanged_bits = before.0 == model.bits;
    let unchanged_regs = before.2 == model.registers;
    assert!(before.1 == model.input_bits && before.3 == model.input_registers, "input tables written");
    match function {
        0x01 | 0x02 => {
            assert!(unchanged_bits && unchanged_regs);
            let (table, start) =
                if function == 1 { (&model.bits, model.starts[0]) } else { (&model.input_bits, model.starts[1]) };
            let first = Model::range(start, table.len(), addr, nb).expect("read bits replied outside the table");
            assert_eq!(rsp[h + 1] as usize, nb.div_ceil(8));
            for k in 0..nb {
                assert_eq!((rsp[h + 2 + k / 8] >> (k % 8)) & 1, table[first + k] & 1, "bit {k} of the reply");
            }
        }
        0x03 | 0x04 => {
            assert!(unchanged_bits && unchanged_regs);
            let (table, start) = if function == 3 {
                (&model.registers, model.starts[2])
            } else {
                (&model.input_registers, model.starts[3])
            };
            let first = Model::range(start, table.len(), addr, nb).expect("read registers replied outside the table");
            assert_eq!(rsp[h + 1] as usize, nb * 2);
            for k in 0..nb {
                assert_eq!(be16(rsp, h + 2 + 2 * k), table[first + k], "register {k} of the reply");
            }
        }
        0x05 => {
            assert!(unchanged_regs);
            assert_eq!(req_length as usize, h + 5 + framing.checksum_length());
            let i = Model::range(model.starts[0], model.bits.len(), addr, 1).expect("write bit outside the table");
            assert_eq!(model.bits[i], (u16_at(h + 3) == 0xFF00) as u8);
            let mut expect = before.0.clone();
            expect[i] = model.bits[i];
            assert!(expect == model.bits, "write bit changed other bits");
        }
        0x06 => {
            assert!(unchanged_bits);
            assert_eq!(req_length as usize, h + 5 + framing.checksum_length());
            let i = Model::range(model.starts[2], model.registers.len(), addr, 1).expect("write register outside");
            let mut expect = before.2.clone();
            expect[i] = u16_at(h + 3);
            assert!(expect == model.registers, "write register");
        }
        0x0F => {
            assert!(unchanged_regs);
            let first = Model::range(model.starts[0], model.bits.len(), addr, nb).expect("write bits outside");
            let mut expect = before.0.clone();
            for k in 0..nb {
                expect[first + k] = (at(h + 6 + k / 8) >> (k % 8)) & 1;
            }
            assert!(expect == model.bits, "write bits");
            assert_eq!(rsp[h + 1..h + 5], [at(h + 1), at(h + 2), at(h + 3), at(h + 4)]);
        }
        0x10 => {
            assert!(unchanged_bits);
            let first = Model::range(model.starts[2], model.registers.len(), addr, nb).expect("write regs outside");
            let mut expect = before.2.clone();
            for k in 0..nb {
                expect[first + k] = u16_at(h + 6 + 2 * k);
            }
            assert!(expect == model.registers, "write registers");
        }
        0x11 => assert!(unchanged_bits && unchanged_regs),
        0x16 => {
            assert!(unchanged_bits);
            let i = Model::range(model.starts[2], model.registers.len(), addr, 1).expect("mask write outside");
            let (and, or) = (u16_at(h + 3), u16_at(h + 5));
            let mut expect = before.2.clone();
            expect[i] = (before.2[i] & and) | (or & !and);
            assert!(expect == model.registers, "mask write register");
        }
        0x17 => {
            assert!(unchanged_bits);
            let (waddr, wnb) = (u16_at(h + 5), u16_at(h + 7) as usize);
            let wfirst = Model::range(model.starts[2], model.registers.len(), waddr, wnb).expect("fc17 write outside");
            let rfirst = Model::range(model.starts[2], model.registers.len(), addr, nb).expect("fc17 read outside");
            let mut expect = before.2.clone();
            for k in 0..wnb {
                expect[wfirst + k] = u16_at(h + 10 + 2 * k);
            }
            assert!(expect == model.registers, "fc17 write");
            for k in 0..nb {
                assert_eq!(be16(rsp, h + 2 + 2 * k), model.registers[rfirst + k], "fc17 reads after writing");
            }
        }
        f => panic!("normal reply to function {f:#x}"),
    }
}

pub fn server_rtu(data: &[u8]) {
    server(Framing::Rtu, data)
}

pub fn server_tcp(data: &[u8]) {
    server(Framing::Tcp, data)
}

pub fn server_ascii(data: &[u8]) {
    server(Framing::Ascii, data)
}

/// Function codes the client side can send, in selector order: libmodbus's, then
/// the ones rsmodbus adds (07, 08, 0B, 0C, 14, 15, 18, 2B/0E).
pub const CLIENT_FUNCTIONS: [u8; 19] =
    [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F, 0x10, 0x11, 0x16, 0x17, 0x07, 0x08, 0x0B, 0x0C, 0x14, 0x15, 0x18, 0x2B];

/// True for the function codes rsmodbus adds to libmodbus's.
pub fn is_extension(function: u8) -> bool {
    matches!(function, 0x07 | 0x08 | 0x0B | 0x0C | 0x14 | 0x15 | 0x18 | 0x2B)
}

/// A client request chosen by config bytes, with its owned write data.
pub struct ClientCall {
    pub function: u8,
    pub addr: i32,
    pub nb: i32,
    pub read_nb: i32,
    pub value: u16,
    pub bits: Vec<u8>,
    pub regs: Vec<u16>,
}

impl ClientCall {
    /// Reads `[selector][addr 2][nb 2][value 2]`. Counts are kept inside what the C
    /// functions accept (their own checks run before anything is sent), except FC 17's
    /// write count, which libmodbus does not bound below.
    pub fn from(c: &mut Cursor<'_>, in_range: bool) -> ClientCall {
        let function = CLIENT_FUNCTIONS[c.u8() as usize % CLIENT_FUNCTIONS.len()];
        let raw_addr = c.u16();
        let addr = if in_range { (raw_addr % 256) as i32 } else { raw_addr as i32 };
        let raw_nb = c.u16() as i32;
        let value = c.u16();
        let (nb, read_nb) = match function {
            0x01 | 0x02 => (1 + raw_nb % 2000, 0),
            0x03 | 0x04 => (1 + raw_nb % 125, 0),
            0x0F => (1 + raw_nb % 1968, 0),
            0x10 => (1 + raw_nb % 123, 0),
            0x17 => ((raw_nb >> 8) % 123 - 1, 1 + (raw_nb & 0xFF) % 125),
            0x08 => (raw_nb % 5, 0),
            0x14 => (1 + raw_nb % 124, 0),
            0x15 => (1 + raw_nb % 122, 0),
            _ => (1, 0),
        };
        let bits = (0..nb.max(0)).map(|i| ((value as i32 >> (i % 16)) & 1) as u8).collect();
        let regs = (0..nb.max(0)).map(|i| value.wrapping_add(i as u16).rotate_left(i as u32)).collect();
        ClientCall { function, addr, nb, read_nb, value, bits, regs }
    }

    pub fn request(&self) -> Request<'_> {
        match self.function {
            0x01 | 0x02 => Request::ReadBits { function: self.function, addr: self.addr, nb: self.nb },
            0x03 | 0x04 => Request::ReadRegisters { function: self.function, addr: self.addr, nb: self.nb },
            0x05 => Request::WriteBit { addr: self.addr, on: self.value & 1 != 0 },
            0x06 => Request::WriteRegister { addr: self.addr, value: self.value },
            0x0F => Request::WriteBits { addr: self.addr, bits: &self.bits },
            0x10 => Request::WriteRegisters { addr: self.addr, values: &self.regs },
            0x11 => Request::ReportSlaveId,
            0x16 => Request::MaskWriteRegister { addr: self.addr, and_mask: self.value, or_mask: !self.value },
            0x07 => Request::ReadExceptionStatus,
            0x08 => Request::Diagnostics { sub_function: self.value % 24, data: &self.regs },
            0x0B => Request::GetCommEventCounter,
            0x0C => Request::GetCommEventLog,
            0x14 => Request::ReadFileRecord { file: self.addr as u16, record: self.value % 10000, nb: self.nb as u16 },
            0x15 => Request::WriteFileRecord { file: self.addr as u16, record: self.value % 10000, values: &self.regs },
            0x18 => Request::ReadFifoQueue { addr: self.addr as u16 },
            0x2B => Request::ReadDeviceId { read_code: 1 + (self.value % 4) as u8, object_id: (self.value >> 8) as u8 },
            _ => Request::WriteAndReadRegisters {
                write_addr: self.addr,
                write_nb: self.nb,
                values: &self.regs,
                read_addr: (self.addr + 7) % 256,
                read_nb: self.read_nb,
            },
        }
    }
}

/// Applies edit operations `[op][pos][value]` to `msg` (set, insert, delete, truncate,
/// xor), then optionally re-seals it so that length and CRC are right again.
pub fn mutate(framing: Framing, msg: &mut Vec<u8>, ops: &[u8]) {
    let mut reseal = false;
    for op in ops.chunks_exact(3) {
        let (kind, pos, val) = (op[0], op[1] as usize, op[2]);
        let len = msg.len();
        match kind & 7 {
            0 if len > 0 => msg[pos % len] = val,
            1 if len < 300 => msg.insert(pos % (len + 1), val),
            2 if len > 0 => {
                msg.remove(pos % len);
            }
            3 => msg.truncate(pos % (len + 1)),
            4 if len > 0 => msg[pos % len] ^= val,
            5 => reseal = !reseal,
            6 if len < 300 => msg.extend(std::iter::repeat_n(val, pos % 8)),
            _ => {}
        }
    }
    if reseal {
        match framing {
            Framing::Rtu if msg.len() >= 2 => {
                let n = msg.len() - 2;
                let crc = crc16(&msg[..n]);
                msg[n..].copy_from_slice(&crc.to_le_bytes());
            }
            Framing::Tcp if msg.len() >= 6 => {
                let l = (msg.len() - 6) as u16;
                msg[4..6].copy_from_slice(&l.to_be_bytes());
            }
            Framing::Ascii if !msg.is_empty() => {
                let n = msg.len() - 1;
                msg[n] = ascii::lrc(&msg[..n]);
            }
            _ => {}
        }
    }
}

/// The correct response (sealed binary ADU) of a zero-based server holding 2400
/// items per table.
pub fn correct_response(framing: Framing, sealed_req: &[u8]) -> Vec<u8> {
    let mut model = Model::new([0; 4], [2400; 4]);
    let mut out = [0u8; MAX_ADU_LENGTH];
    let server = Server { framing, quirks: QUIRK_REPLY_TO_BROADCAST };
    match server.reply(sealed_req, sealed_req.len() as i32, &mut model.tables(), &mut Sink::default(), &mut out) {
        Outcome::Respond { len, .. } => {
            let n = framing.seal(&mut out, len);
            out[..n].to_vec()
        }
        Outcome::Fail(_) => Vec::new(),
    }
}

/// Client response path. Input layout:
/// `[selector][addr 2][nb 2][value 2][unit][tid 2][mode]` then either raw response
/// bytes (mode bit 0 clear) or edit operations applied to the correct response
/// (mode bit 0 set; see [`mutate`]). Mode bits 1-3: chunk size; bit 4: addresses
/// inside the 256 first items.
pub fn client(framing: Framing, data: &[u8]) {
    let mut c = Cursor::new(data);
    let head = c.rest();
    let mut peek = Cursor::new(head);
    for _ in 0..10 {
        peek.u8();
    }
    let mode = peek.u8();
    let call = ClientCall::from(&mut c, mode & 0x10 != 0);
    let unit = c.u8();
    let tid = c.u16();
    let _ = c.u8();
    let chunk = chunk_of(mode >> 1);
    let req = call.request();
    let mut reqbuf = [0u8; MAX_ADU_LENGTH];
    let n = req.encode(framing, unit, tid, &mut reqbuf);
    let n = framing.seal(&mut reqbuf, n);
    let sealed_req = &reqbuf[..n];
    assert!(n <= framing.max_adu_length(), "request longer than the maximum ADU");

    let (stream, pristine) = if mode & 1 != 0 {
        let mut rsp = correct_response(framing, sealed_req);
        // FC 07: a libmodbus server answers nothing, so there is no correct response.
        let pristine = c.rest().is_empty() && !rsp.is_empty();
        let ops = c.rest();
        mutate(framing, &mut rsp, ops);
        (wire(framing, &rsp), pristine)
    } else {
        (c.rest().to_vec(), false)
    };

    let mut buf = [0u8; MAX_ADU_LENGTH];
    // The engine remembers the length of a serial diagnostics request to frame its answer.
    let expecting = (framing != Framing::Tcp && call.function == 0x08).then_some(n - framing.checksum_length());
    let (what, _) =
        frame_one(framing, MsgKind::Confirmation, Framed { extended: false, expecting }, &stream, chunk, &mut buf);
    let len = match what {
        Assembled::Frame(len) => len,
        _ => {
            assert!(!pristine, "the correct response did not assemble");
            return;
        }
    };
    let rsp = &buf[..len];
    if framing == Framing::Ascii && len < 2 {
        assert!(!pristine);
        return;
    }
    if let Some(bad_checksum) = serial_integrity(framing, rsp, unit as i32) {
        assert!(!pristine || unit == 0, "the correct response failed integrity (bad checksum: {bad_checksum})");
        return;
    }
    let mut sink = Sink::default();
    let checked = confirm::check(framing, sealed_req, rsp, &mut sink);
    let h = framing.header_length();
    let cs = framing.checksum_length();
    match checked {
        Ok(count) => {
            if let Some(expected) = confirm::expected_length(framing, sealed_req) {
                assert_eq!(len, expected, "accepted a response of the wrong length");
            }
            assert_eq!(rsp[h], call.function, "accepted another function");
            // What the C layer then copies out of the response must be inside it.
            match call.function {
                0x01 | 0x02 => {
                    assert_eq!(count as usize, (call.nb as usize).div_ceil(8));
                    assert!(len >= h + 2 + count as usize + cs);
                }
                0x03 | 0x04 => {
                    assert_eq!(count, call.nb);
                    assert!(len >= h + 2 + 2 * count as usize + cs);
                }
                0x17 => {
                    assert_eq!(count, call.read_nb);
                    assert!(len >= h + 2 + 2 * count as usize + cs);
                }
                0x11 => assert_eq!(len, h + 2 + count as usize + cs, "report slave id length"),
                0x0F | 0x10 => assert_eq!(count, call.nb),
                f if is_extension(f) => assert!((0..=MAX_ADU_LENGTH as i32).contains(&count), "count {count}"),
                _ => assert_eq!(count, 1),
            }
        }
        Err(Rejection::Exception(e)) => {
            assert!(rsp[h] >= 0x80);
            assert!(e.0 >= MODBUS_ENOBASE && e.0 <= MODBUS_ENOBASE + 11 || e == Error::BAD_EXCEPTION, "{e:?}");
        }
        Err(Rejection::Mismatch(e) | Rejection::Foreign(e)) => {
            assert!(e == Error::BAD_DATA || e == Error::BAD_SLAVE, "{e:?}");
            assert!(
                !pristine || (framing.is_serial() && unit == 0),
                "the correct response was refused: {e:?} {}",
                sink.0
            );
        }
    }
}

pub fn client_rtu(data: &[u8]) {
    client(Framing::Rtu, data)
}

pub fn client_tcp(data: &[u8]) {
    client(Framing::Tcp, data)
}

pub fn client_ascii(data: &[u8]) {
    client(Framing::Ascii, data)
}

/// `security`: Modbus/TCP Security's pure paths. Layout: `[chunk seed][bytes...]`.
/// - The TLS record stream a server reads (`RecordCut`): `bytes` read in pieces of
///   sizes drawn from the seed, never past a record's end; every place the cut says
///   "between records" is where a plain parse of the headers puts a boundary.
/// - The role of `bytes` as a certificate: none, or 1 to 255 bytes of UTF-8
///   without NUL.
/// - What `bytes` as a request PDU asks the authorization callback: its function
///   code and one or two ranges.
pub fn security(data: &[u8]) {
    use modbus::proto::security::{MAX_ROLE_LENGTH, RecordCut, access, role};
    let Some((&seed, bytes)) = data.split_first() else { return };
    // Boundaries by a plain parse of the headers.
    let mut expected = Vec::new();
    let mut at = 0usize;
    while at + 5 <= bytes.len() {
        let end = at + 5 + u16::from_be_bytes([bytes[at + 3], bytes[at + 4]]) as usize;
        if end > bytes.len() {
            break;
        }
        expected.push(end);
        at = end;
    }
    let mut cut = RecordCut::default();
    let (mut at, mut i, mut seen) = (0usize, 0usize, Vec::new());
    while at < bytes.len() {
        let want = 1 + (seed as usize).wrapping_mul(i + 7) % 97;
        let n = cut.limit().min(want).min(bytes.len() - at);
        assert!(n > 0, "a read of nothing before the end of the stream");
        cut.advance(&bytes[at..at + n]);
        at += n;
        i += 1;
        if cut.at_boundary() {
            seen.push(at);
        }
    }
    assert_eq!(seen, expected, "record boundaries");
    if let Some(r) = role(bytes) {
        assert!(!r.is_empty() && r.len() <= MAX_ROLE_LENGTH && !r.contains('\0'));
    }
    let a = access(bytes);
    assert_eq!(a.function, bytes.first().copied().unwrap_or(0));
    let n = a.ranges().count();
    if matches!(a.function, 0x14 | 0x15) {
        // One per sub-request, the first always: each takes 7 bytes at least.
        assert!(n >= 1 && n <= 1 + bytes.len().saturating_sub(2) / 7, "{n} file ranges");
    } else {
        assert!((1..=2).contains(&n));
    }
}

/// A fuzz target.
pub type Target = fn(&[u8]);

/// Every target by name, for the replay tool.
pub const TARGETS: [(&str, Target); 13] = [
    ("server_rtu", server_rtu),
    ("server_tcp", server_tcp),
    ("server_ascii", server_ascii),
    ("client_rtu", client_rtu),
    ("client_tcp", client_tcp),
    ("client_ascii", client_ascii),
    ("ffi_server", ffi_server),
    ("ffi_client", ffi_client),
    ("ffi_async", ffi_async),
    ("security", security),
    ("authorization", authorization),
    ("gateway_config", gateway_config),
    ("gateway_master", gateway_master),
];

pub fn target(name: &str) -> Option<Target> {
    TARGETS.iter().find(|(n, _)| *n == name).map(|(_, f)| *f)
}
