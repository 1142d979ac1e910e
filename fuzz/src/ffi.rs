//! Fuzzing through the exported C ABI: the same calls a C program makes, over a
//! socket pair whose peer has already written the fuzz bytes and shut its write side
//! (so every read ends in data or EOF, never a wait). Buffers handed to the library
//! are exactly the size the API promises plus a canary, checked after every call.

use std::ffi::c_int;

use modbus::ffi::Modbus;
use modbus::ffi::client::*;
use modbus::ffi::context::*;
use modbus::ffi::extensions::*;
use modbus::ffi::rtu::{modbus_new_ascii, modbus_new_rtu};
use modbus::ffi::server::*;
use modbus::ffi::tcp::modbus_new_tcp;
use modbus::proto::frame::{Framing, MAX_ADU_LENGTH};
use modbus::transport::errno;

use crate::{ClientCall, Cursor, correct_response, mutate, size_of, slave_of, start_of, wire};

/// Framing from the low two bits of a selector: TCP, RTU, ASCII (3 = TCP).
fn framing_of(b: u8) -> Framing {
    match b & 3 {
        1 => Framing::Rtu,
        2 => Framing::Ascii,
        _ => Framing::Tcp,
    }
}

const CANARY: u8 = 0xA5;

/// A socket pair: `ours` goes to the library, `peer` holds the fuzz bytes.
struct Pair {
    ours: c_int,
    peer: c_int,
}

impl Pair {
    /// Writes `bytes` into the peer side and shuts it for writing. Bytes that do not
    /// fit the socket buffer are dropped (inputs are small).
    fn with_bytes(bytes: &[u8]) -> Pair {
        let mut fds = [0 as c_int; 2];
        // SAFETY: fds has room for two descriptors.
        let rc =
            unsafe { libc::socketpair(libc::AF_UNIX, libc::SOCK_STREAM | libc::SOCK_CLOEXEC, 0, fds.as_mut_ptr()) };
        assert_eq!(rc, 0, "socketpair failed: {}", errno());
        let pair = Pair { ours: fds[0], peer: fds[1] };
        let mut off = 0;
        while off < bytes.len() {
            // SAFETY: writing from a live slice.
            let n = unsafe {
                libc::send(
                    pair.peer,
                    bytes[off..].as_ptr().cast(),
                    bytes.len() - off,
                    libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
                )
            };
            if n <= 0 {
                break;
            }
            off += n as usize;
        }
        // SAFETY: plain shutdown of our own socket.
        unsafe { libc::shutdown(pair.peer, libc::SHUT_WR) };
        pair
    }
}

impl Drop for Pair {
    fn drop(&mut self) {
        // SAFETY: closing our own descriptor (ours is closed by modbus_close already:
        // closing it again gives EBADF, harmless; -1 is skipped).
        unsafe { libc::close(self.peer) };
    }
}

/// A context on the pair's library side with timeouts short enough that the
/// server's sleep-before-flush does not slow the fuzzer.
fn context(framing: Framing, fd: c_int) -> *mut Modbus {
    // SAFETY: valid C strings; the returned context is checked.
    let ctx = unsafe {
        match framing {
            Framing::Tcp => modbus_new_tcp(c"127.0.0.1".as_ptr(), 1502),
            Framing::Rtu => modbus_new_rtu(c"/dev/null".as_ptr(), 9600, b'N' as _, 8, 1),
            Framing::Ascii => modbus_new_ascii(c"/dev/null".as_ptr(), 9600, b'E' as _, 7, 1),
        }
    };
    assert!(!ctx.is_null());
    // SAFETY: live context.
    unsafe {
        assert_eq!(modbus_set_socket(ctx, fd), 0);
        assert_eq!(modbus_set_response_timeout(ctx, 0, 1), 0);
        assert_eq!(modbus_set_byte_timeout(ctx, 0, 1000), 0);
        assert_eq!(modbus_set_indication_timeout(ctx, 0, 1000), 0);
    }
    ctx
}

fn free_context(ctx: *mut Modbus) {
    // SAFETY: live context, freed once.
    unsafe {
        modbus_close(ctx);
        modbus_free(ctx);
    }
}

/// A buffer of `n` items followed by a canary.
struct Guarded<T: Copy> {
    v: Vec<T>,
    n: usize,
    canary: T,
}

impl<T: Copy + PartialEq + std::fmt::Debug> Guarded<T> {
    fn new(n: usize, fill: T, canary: T) -> Self {
        let mut v = vec![fill; n];
        v.extend(std::iter::repeat_n(canary, 8));
        Guarded { v, n, canary }
    }
    fn ptr(&mut self) -> *mut T {
        self.v.as_mut_ptr()
    }
    fn check(&self, what: &str) {
        for (i, x) in self.v[self.n..].iter().enumerate() {
            assert_eq!(*x, self.canary, "{what} wrote past its {} items (canary {i})", self.n);
        }
    }
}

/// errno values a client call may fail with here.
fn client_errno_ok(e: i32) -> bool {
    use modbus::error::*;
    e == libc::ECONNRESET || e == libc::ETIMEDOUT || e == libc::EINVAL || (MODBUS_ENOBASE..=EMBBADSLAVE).contains(&e)
}

/// Client side. Input: `[framing + mode][selector][addr 2][nb 2][value 2][unit]`
/// `[calls]`, then response bytes (mode bit 2 clear) or edit operations on the
/// correct response to the first call (bit 2 set). Bits 0-1 of the first byte: TCP,
/// RTU, ASCII; bit 3: addresses in the first 256.
/// Up to 3 calls read the same stream, so stale bytes meet later requests.
pub fn ffi_client(data: &[u8]) {
    let mut c = Cursor::new(data);
    let mode = c.u8();
    let framing = framing_of(mode);
    let call = ClientCall::from(&mut c, mode & 8 != 0);
    let unit = c.u8();
    let calls = 1 + (c.u8() % 3) as usize;
    let stream = if mode & 4 != 0 {
        // The first request this context sends has TID 1.
        let req = call.request();
        let mut buf = [0u8; MAX_ADU_LENGTH];
        let n = req.encode(framing, unit, 1, &mut buf);
        let n = framing.seal(&mut buf, n);
        let mut rsp = correct_response(framing, &buf[..n]);
        mutate(framing, &mut rsp, c.rest());
        wire(framing, &rsp)
    } else {
        c.rest().to_vec()
    };
    let pair = Pair::with_bytes(&stream);
    let ctx = context(framing, pair.ours);
    // SAFETY: live context.
    unsafe { modbus_set_slave(ctx, unit as c_int) };
    for _ in 0..calls {
        let (rc, e) = one_client_call(ctx, &call);
        if rc < 0 {
            assert!(client_errno_ok(e), "client call fc {:#x} failed with errno {e}", call.function);
        }
    }
    free_context(ctx);
}

/// Makes the C call for `call`; returns its result and errno. Checks canaries and
/// the documented return values.
fn one_client_call(ctx: *mut Modbus, call: &ClientCall) -> (c_int, i32) {
    let nb = call.nb.max(0) as usize;
    modbus::transport::set_errno(0);
    // SAFETY: every buffer holds at least what the call is told.
    let rc = unsafe {
        match call.function {
            0x01 | 0x02 => {
                let mut dest = Guarded::new(nb, 0xEEu8, CANARY);
                let f = if call.function == 1 { modbus_read_bits } else { modbus_read_input_bits };
                let rc = f(ctx, call.addr, call.nb, dest.ptr());
                dest.check("read bits");
                if rc >= 0 {
                    assert_eq!(rc, call.nb);
                    assert!(dest.v[..nb].iter().all(|&b| b <= 1), "read bits stored a value other than 0/1");
                }
                rc
            }
            0x03 | 0x04 => {
                let mut dest = Guarded::new(nb, 0xEEEEu16, 0xA5A5);
                let f = if call.function == 3 { modbus_read_registers } else { modbus_read_input_registers };
                let rc = f(ctx, call.addr, call.nb, dest.ptr());
                dest.check("read registers");
                if rc >= 0 {
                    assert_eq!(rc, call.nb);
                }
                rc
            }
            0x05 => {
                let rc = modbus_write_bit(ctx, call.addr, (call.value & 1) as c_int);
                assert!(rc == -1 || rc == 1);
                rc
            }
            0x06 => {
                let rc = modbus_write_register(ctx, call.addr, call.value);
                assert!(rc == -1 || rc == 1);
                rc
            }
            0x0F => {
                let rc = modbus_write_bits(ctx, call.addr, call.nb, call.bits.as_ptr());
                assert!(rc == -1 || rc == call.nb, "write bits returned {rc}");
                rc
            }
            0x10 => {
                let rc = modbus_write_registers(ctx, call.addr, call.nb, call.regs.as_ptr());
                assert!(rc == -1 || rc == call.nb, "write registers returned {rc}");
                rc
            }
            0x11 => {
                let max_dest = 1 + (call.value % 20) as usize;
                let mut dest = Guarded::new(max_dest, 0u8, CANARY);
                let rc = modbus_report_slave_id(ctx, max_dest as c_int, dest.ptr());
                dest.check("report slave id");
                rc
            }
            0x16 => {
                let rc = modbus_mask_write_register(ctx, call.addr, call.value, !call.value);
                assert!(rc == -1 || rc == 1);
                rc
            }
            0x07 => {
                let mut st = Guarded::new(1, 0u8, CANARY);
                let rc = modbus_read_exception_status(ctx, st.ptr());
                st.check("read exception status");
                assert!(rc == -1 || rc == 1);
                rc
            }
            0x08 => {
                let max_dest = (call.value >> 8) as usize % 130;
                let mut dest = Guarded::new(max_dest, 0xEEEEu16, 0xA5A5);
                let data = if call.nb > 0 { call.regs.as_ptr() } else { std::ptr::null() };
                let rc =
                    modbus_diagnostics(ctx, (call.value % 24) as c_int, data, call.nb, dest.ptr(), max_dest as c_int);
                dest.check("diagnostics");
                rc
            }
            0x0B => {
                let (mut st, mut ev) = (Guarded::new(1, 0u16, 0xA5A5), Guarded::new(1, 0u16, 0xA5A5));
                let rc = modbus_get_comm_event_counter(ctx, st.ptr(), ev.ptr());
                st.check("event counter status");
                ev.check("event counter count");
                rc
            }
            0x0C => {
                let max_events = (call.value as usize) % 80;
                let mut ev = Guarded::new(max_events, 0u8, CANARY);
                let (mut a, mut b, mut c) =
                    (Guarded::new(1, 0u16, 0xA5A5), Guarded::new(1, 0u16, 0xA5A5), Guarded::new(1, 0u16, 0xA5A5));
                let rc = modbus_get_comm_event_log(ctx, a.ptr(), b.ptr(), c.ptr(), ev.ptr(), max_events as c_int);
                ev.check("event log events");
                a.check("event log status");
                b.check("event log count");
                c.check("event log messages");
                rc
            }
            0x14 => {
                let mut dest = Guarded::new(nb, 0xEEEEu16, 0xA5A5);
                let rc = modbus_read_file_record(ctx, call.addr, (call.value % 10000) as c_int, call.nb, dest.ptr());
                dest.check("read file record");
                assert!(rc == -1 || rc == call.nb, "read file record returned {rc}");
                rc
            }
            0x15 => {
                let rc = modbus_write_file_record(
                    ctx,
                    call.addr,
                    (call.value % 10000) as c_int,
                    call.nb,
                    call.regs.as_ptr(),
                );
                assert!(rc == -1 || rc == call.nb, "write file record returned {rc}");
                rc
            }
            0x18 => {
                let mut dest = Guarded::new(31, 0xEEEEu16, 0xA5A5);
                let rc = modbus_read_fifo_queue(ctx, call.addr, dest.ptr());
                dest.check("read fifo queue");
                assert!(rc <= 31, "read fifo queue returned {rc}");
                rc
            }
            0x2B => {
                let max_objects = (call.value >> 8) as usize % 6;
                let mut objects: Vec<modbus_device_id_object_t> = (0..max_objects + 2)
                    .map(|i| {
                        if i < max_objects {
                            modbus_device_id_object_t { id: 0xEE, length: 0xEE, value: [0x11; 256] }
                        } else {
                            modbus_device_id_object_t { id: 0xA5, length: 0xA5, value: [0x5A; 256] }
                        }
                    })
                    .collect();
                let mut conformity = Guarded::new(1, 0 as c_int, 0x5A5A5A5A);
                let rc = modbus_read_device_identification(
                    ctx,
                    1 + (call.value % 4) as c_int,
                    (call.value & 0xFF) as c_int,
                    objects.as_mut_ptr(),
                    max_objects as c_int,
                    conformity.ptr(),
                );
                conformity.check("device id conformity");
                for o in &objects[max_objects..] {
                    assert!(
                        o.id == 0xA5 && o.length == 0xA5 && o.value.iter().all(|&c| c == 0x5A),
                        "device id wrote past max_objects"
                    );
                }
                assert!(rc <= max_objects as c_int, "read device identification returned {rc}");
                rc
            }
            _ => {
                let read_nb = call.read_nb.max(0) as usize;
                let mut dest = Guarded::new(read_nb, 0xEEEEu16, 0xA5A5);
                let src = if call.nb > 0 { call.regs.as_ptr() } else { std::ptr::null() };
                let rc = modbus_write_and_read_registers(
                    ctx,
                    call.addr,
                    call.nb,
                    src,
                    (call.addr + 7) % 256,
                    call.read_nb,
                    dest.ptr(),
                );
                dest.check("write and read registers");
                if rc >= 0 {
                    assert_eq!(rc, call.read_nb);
                }
                rc
            }
        }
    };
    (rc, errno())
}

/// Server side through the C ABI. Input: `[framing + flags][start bits][start input
/// bits][start regs][start input regs][bits size][regs size][slave][req_length mode]`
/// then the byte stream. Flags: bits 0-1 TCP/RTU/ASCII, bit 2 quirk REPLY_TO_BROADCAST. The
/// request buffer is exactly the framing's maximum ADU, as the API requires.
pub fn ffi_server(data: &[u8]) {
    let mut c = Cursor::new(data);
    let flags = c.u8();
    let framing = framing_of(flags);
    let starts = [c.u8(), c.u8(), c.u8(), c.u8()].map(start_of);
    let bits = size_of(c.u8());
    let regs = size_of(c.u8());
    let slave = slave_of(c.u8());
    let mode = c.u8();
    let pair = Pair::with_bytes(c.rest());
    let ctx = context(framing, pair.ours);
    let mapping = modbus_mapping_new_start_address(
        starts[0] as u32,
        bits as u32,
        starts[1] as u32,
        (bits / 2) as u32,
        starts[2] as u32,
        regs as u32,
        starts[3] as u32,
        (regs / 2) as u32,
    );
    assert!(!mapping.is_null());
    // SAFETY: live context.
    unsafe {
        if framing.is_serial() {
            modbus_set_slave(ctx, slave);
        }
        if flags & 4 != 0 {
            modbus_enable_quirks(ctx, modbus::proto::reply::QUIRK_REPLY_TO_BROADCAST);
        }
    }
    // The documented buffer size: MODBUS_TCP_MAX_ADU_LENGTH or MODBUS_RTU_MAX_ADU_LENGTH.
    let cap = if framing == Framing::Tcp { 260 } else { 256 };
    let mut req = Guarded::new(cap, 0u8, CANARY);
    for _ in 0..48 {
        modbus::transport::set_errno(0);
        // SAFETY: `req` holds the framing's maximum ADU.
        let rc = unsafe { modbus_receive(ctx, req.ptr()) };
        let e = errno();
        req.check("modbus_receive");
        if rc < 0 {
            use modbus::error::*;
            assert!(
                [libc::ECONNRESET, libc::ETIMEDOUT, EMBBADDATA, EMBBADCRC].contains(&e),
                "modbus_receive failed with errno {e}"
            );
            if e == libc::ECONNRESET || e == libc::ETIMEDOUT {
                break;
            }
            if e != EMBBADCRC {
                continue;
            }
        }
        if rc == 0 {
            continue;
        }
        let req_length = match mode {
            0..=127 => rc,
            128 => -1,
            129 => i32::MIN,
            130 => i32::MAX,
            m => rc + (m as i32 - 192),
        };
        modbus::transport::set_errno(0);
        // SAFETY: `req` holds the ADU just received; the mapping is live.
        let sent = unsafe { modbus_reply(ctx, req.ptr(), req_length, mapping) };
        let e = errno();
        if sent < 0 {
            assert!(
                e == libc::ENOPROTOOPT || e == libc::EPIPE || e == libc::ECONNRESET || e == libc::EBADF,
                "modbus_reply failed with errno {e}"
            );
        } else {
            assert!(sent as usize <= cap, "modbus_reply sent {sent} bytes");
        }
    }
    // SAFETY: the mapping was allocated above and is freed once.
    unsafe { modbus_mapping_free(mapping) };
    free_context(ctx);
    drop(pair);
}

/// What the authorization callback of [`authorization`] was asked, and how it answers.
struct Asked {
    /// (role was NULL, unit id, function, address, nb) of every call, in order.
    calls: Vec<(bool, c_int, c_int, c_int, c_int)>,
    /// Bit k set: the k-th call (mod 8) is refused.
    deny: u8,
    /// The value a refusal returns: 0, or another value that is not 1.
    refusal: c_int,
}

unsafe extern "C" fn decide(
    _ctx: *mut Modbus,
    role: *const std::ffi::c_char,
    unit_id: c_int,
    function: c_int,
    address: c_int,
    nb: c_int,
    user_data: *mut std::ffi::c_void,
) -> c_int {
    // SAFETY: user_data is the `Asked` that `authorization` keeps alive for the call.
    let asked = unsafe { &mut *user_data.cast::<Asked>() };
    let k = asked.calls.len();
    asked.calls.push((role.is_null(), unit_id, function, address, nb));
    if asked.deny & (1 << (k % 8)) != 0 { asked.refusal } else { 1 }
}

/// The state a request can change: the mapping's coils and holding registers (the
/// input tables are compared too), and the records of files 1 to 4.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Served {
    bits: Vec<u8>,
    input_bits: Vec<u8>,
    registers: Vec<u16>,
    input_registers: Vec<u16>,
    files: Vec<Vec<u16>>,
}

const AUTH_ITEMS: usize = 64;
const AUTH_FILES: c_int = 4;
const AUTH_RECORDS: c_int = 16;

/// A server context (TLS or plain TCP) with files 1 to 4 of 16 records, and a mapping
/// of 64 items per table from address 0, all with distinct values.
fn auth_server(tls: bool, fd: c_int) -> (*mut Modbus, *mut modbus::ffi::server::modbus_mapping_t) {
    // SAFETY: valid C strings; the returned context is checked.
    let ctx = unsafe {
        if tls {
            modbus::ffi::tls::modbus_new_tcp_tls(c"127.0.0.1".as_ptr(), 802)
        } else {
            modbus_new_tcp(c"127.0.0.1".as_ptr(), 502)
        }
    };
    assert!(!ctx.is_null());
    let n = AUTH_ITEMS as u32;
    let mapping = modbus_mapping_new_start_address(0, n, 0, n, 0, n, 0, n);
    assert!(!mapping.is_null());
    // SAFETY: live context and mapping; the tables hold AUTH_ITEMS items each.
    unsafe {
        assert_eq!(modbus_set_socket(ctx, fd), 0);
        // Short, so that the sleep before a flush does not slow the fuzzer.
        assert_eq!(modbus_set_response_timeout(ctx, 0, 1), 0);
        let m = &*mapping;
        for i in 0..AUTH_ITEMS {
            *m.tab_bits.add(i) = (i % 3 == 0) as u8;
            *m.tab_input_bits.add(i) = (i % 5 == 0) as u8;
            *m.tab_registers.add(i) = 0x1000 + i as u16;
            *m.tab_input_registers.add(i) = 0x2000 + i as u16;
        }
        for file in 1..=AUTH_FILES {
            let values: Vec<u16> = (0..AUTH_RECORDS).map(|r| (file * 0x100 + r) as u16).collect();
            assert_eq!(modbus_set_file_record(ctx, file, 0, AUTH_RECORDS, values.as_ptr()), AUTH_RECORDS);
        }
    }
    (ctx, mapping)
}

fn served(ctx: *mut Modbus, mapping: *mut modbus::ffi::server::modbus_mapping_t) -> Served {
    // SAFETY: live mapping whose tables hold AUTH_ITEMS items; live context.
    unsafe {
        let m = &*mapping;
        let files = (1..=AUTH_FILES)
            .map(|file| {
                let mut records = vec![0u16; AUTH_RECORDS as usize];
                assert_eq!(modbus_get_file_record(ctx, file, 0, AUTH_RECORDS, records.as_mut_ptr()), AUTH_RECORDS);
                records
            })
            .collect();
        Served {
            bits: std::slice::from_raw_parts(m.tab_bits, AUTH_ITEMS).to_vec(),
            input_bits: std::slice::from_raw_parts(m.tab_input_bits, AUTH_ITEMS).to_vec(),
            registers: std::slice::from_raw_parts(m.tab_registers, AUTH_ITEMS).to_vec(),
            input_registers: std::slice::from_raw_parts(m.tab_input_registers, AUTH_ITEMS).to_vec(),
            files,
        }
    }
}

/// The ranges a served request touched, read from its PDU independently of the
/// library: (address, count) of reads and writes, the written then the read range
/// of FC 0x17, (file, record count) of each file record sub-request.
fn served_ranges(pdu: &[u8]) -> Vec<(c_int, c_int)> {
    let word = |at: usize| pdu.get(at..at + 2).map_or(0, |w| u16::from_be_bytes([w[0], w[1]]) as c_int);
    match pdu.first() {
        Some(0x01..=0x04 | 0x0F | 0x10) => vec![(word(1), word(3))],
        Some(0x05 | 0x06 | 0x16) => vec![(word(1), 1)],
        Some(0x17) => vec![(word(5), word(7)), (word(1), word(3))],
        Some(&fc @ (0x14 | 0x15)) => {
            // The sub-requests fill the byte count (a served request's; bytes past it
            // are not part of the request).
            let end = (2 + pdu.get(1).copied().unwrap_or(0) as usize).min(pdu.len());
            let mut ranges = Vec::new();
            let mut at = 2;
            while at + 7 <= end {
                let nb = word(at + 5);
                ranges.push((word(at + 1), nb));
                at += 7 + if fc == 0x15 { 2 * nb as usize } else { 0 };
            }
            ranges
        }
        _ => Vec::new(),
    }
}

/// `authorization`: the server's authorization path through the C API
/// (`modbus_set_tls_authorization`, `modbus_reply`) on a Modbus/TCP Security context.
/// Layout: `[deny mask][refusal][unit id][request PDU...]`.
///
/// The same request goes to a TLS server context, whose callback refuses the calls
/// the deny mask picks, and to a plain TCP context with the same mapping and files.
/// Checked:
/// - every call is given the request's function code and unit id, and a NULL role
///   (the socket has no TLS session: no certificate);
/// - a refused request changes nothing (mapping, files), and its exception cannot
///   go out as plaintext: modbus_reply fails with EMBTLS and nothing reaches the peer;
/// - an allowed request changes exactly what the plain server changes, and each
///   coil, register or file record it changed lies in a range the callback allowed
///   for a function code that writes that table (a request cannot write past what
///   it was authorized for);
/// - when the plain server answered it normally, every range the request names (an
///   independent reading of its PDU: reads, writes, each file record sub-request)
///   was asked about;
/// - calls stop at the first refusal.
pub fn authorization(data: &[u8]) {
    let mut c = Cursor::new(data);
    let deny = c.u8();
    let refusal = match c.u8() % 3 {
        0 => 0,
        1 => 2,
        _ => -1,
    };
    let unit = c.u8();
    let pdu = &c.rest()[..c.rest().len().min(253)];
    let mut adu = vec![0x12, 0x34, 0, 0];
    adu.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    adu.push(unit);
    adu.extend_from_slice(pdu);

    let tls_pair = Pair::with_bytes(&[]);
    let plain_pair = Pair::with_bytes(&[]);
    let (tls, tls_map) = auth_server(true, tls_pair.ours);
    let (plain, plain_map) = auth_server(false, plain_pair.ours);
    let before = served(tls, tls_map);
    assert_eq!(before, served(plain, plain_map));
    let mut asked = Asked { calls: Vec::new(), deny, refusal };
    let mut req = adu.clone();
    // SAFETY: live contexts and mappings; `asked` outlives every call that can reach
    // the callback (it is unset before `asked` goes away); `req` holds the ADU.
    let (rc, e) = unsafe {
        assert_eq!(
            modbus::ffi::tls::modbus_set_tls_authorization(
                tls,
                Some(decide),
                (&raw mut asked).cast::<std::ffi::c_void>()
            ),
            0
        );
        modbus::transport::set_errno(0);
        let rc = modbus_reply(tls, req.as_mut_ptr(), req.len() as c_int, tls_map);
        let e = errno();
        assert_eq!(modbus::ffi::tls::modbus_set_tls_authorization(tls, None, std::ptr::null_mut()), 0);
        (rc, e)
    };
    let after = served(tls, tls_map);
    let function = pdu.first().copied().unwrap_or(0) as c_int;
    assert!(!asked.calls.is_empty(), "the callback was not asked");
    for &(role_null, u, f, address, nb) in &asked.calls {
        assert!(role_null, "a role without a certificate");
        assert_eq!((u, f), (unit as c_int, function), "unit or function code");
        assert!((0..=0xFFFF).contains(&address) && (0..=0xFFFF).contains(&nb), "range {address} {nb}");
    }
    let refused = asked.calls.iter().enumerate().position(|(k, _)| deny & (1 << (k % 8)) != 0);
    if let Some(k) = refused {
        assert_eq!(k + 1, asked.calls.len(), "calls after a refusal");
        assert_eq!(after, before, "a refused request changed the server's data");
        assert_eq!((rc, e), (-1, modbus::error::EMBTLS), "the refusal's exception on a socket without a session");
    } else {
        let mut preq = adu.clone();
        // SAFETY: live context and mapping; `preq` holds the ADU.
        let prc = unsafe { modbus_reply(plain, preq.as_mut_ptr(), preq.len() as c_int, plain_map) };
        assert_eq!(after, served(plain, plain_map), "an allowed request served unlike plain TCP");
        if prc > 0 {
            assert_eq!((rc, e), (-1, modbus::error::EMBTLS), "an answer on a socket without a session");
        }
        let allowed = |writes: &[c_int], at: usize| {
            asked.calls.iter().any(|&(_, _, f, address, nb)| {
                writes.contains(&f) && (address as usize..address as usize + nb as usize).contains(&at)
            })
        };
        for i in 0..AUTH_ITEMS {
            if after.bits[i] != before.bits[i] {
                assert!(allowed(&[0x05, 0x0F], i), "coil {i} changed outside the authorized ranges");
            }
            if after.registers[i] != before.registers[i] {
                // FC 0x17 asks about the written range first: the only one it writes.
                let by_17 = function == 0x17 && {
                    let (_, _, _, address, nb) = asked.calls[0];
                    (address as usize..address as usize + nb as usize).contains(&i)
                };
                assert!(allowed(&[0x06, 0x10, 0x16], i) || by_17, "register {i} changed outside the authorized ranges");
            }
        }
        // Every range the plain server served must have been asked about, as an
        // independent reading of the request names it (reads included: a read that
        // was served unasked changes nothing, so only this sees it).
        let mut answer = [0u8; 300];
        // SAFETY: reading into a live buffer from our own socket.
        let n = unsafe { libc::recv(plain_pair.peer, answer.as_mut_ptr().cast(), answer.len(), libc::MSG_DONTWAIT) };
        if prc > 0 && n > 7 && answer[7] as c_int == function {
            for (address, nb) in served_ranges(pdu) {
                assert!(
                    asked.calls.iter().any(|&(_, _, f, a, b)| f == function && (a, b) == (address, nb)),
                    "FC {function:#04x} served {nb} item(s) at {address} without asking: {:?}",
                    asked.calls
                );
            }
        }
        assert_eq!(after.input_bits, before.input_bits);
        assert_eq!(after.input_registers, before.input_registers);
        for (k, (a, b)) in after.files.iter().zip(&before.files).enumerate() {
            if a != b {
                let file = k as c_int + 1;
                assert!(
                    asked.calls.iter().any(|&(_, _, f, address, _)| f == 0x15 && address == file),
                    "file {file} written without being asked about"
                );
            }
        }
    }
    // Nothing went out in plaintext on the TLS context's socket.
    let mut probe = [0u8; 1];
    // SAFETY: reading into a live one-byte buffer from our own socket.
    let n = unsafe { libc::recv(tls_pair.peer, probe.as_mut_ptr().cast(), 1, libc::MSG_DONTWAIT) };
    assert!(n < 0 && errno() == libc::EAGAIN, "the TLS context wrote plaintext ({n})");
    // SAFETY: allocated above, freed once.
    unsafe {
        modbus_mapping_free(tls_map);
        modbus_mapping_free(plain_map);
    }
    free_context(tls);
    free_context(plain);
    drop((tls_pair, plain_pair));
}

// ---------------------------------------------------------------- the event-driven client

/// What the callback of one asynchronous request saw.
#[derive(Default)]
struct Seen {
    calls: u32,
    rc: c_int,
    error: c_int,
}

unsafe extern "C" fn seen_cb(_ctx: *mut Modbus, _id: c_int, rc: c_int, error: c_int, user: *mut std::ffi::c_void) {
    // SAFETY: `user` is the `Seen` of this request, alive until the target ends.
    let s = unsafe { &mut *user.cast::<Seen>() };
    s.calls += 1;
    s.rc = rc;
    s.error = error;
}

/// The event-driven client (`modbus_*_async`, `modbus_process`). Input:
/// `[framing + depth][selector][addr 2][nb 2][value 2][unit][requests][chunking]`,
/// then response bytes (mode bit 2 clear) or edit operations on the correct
/// responses to the requests, concatenated (bit 2 set). Bits 0-1: TCP, RTU, ASCII;
/// bit 3: timeouts of 1 µs (everything may time out); bits 4-7: the pipelining depth.
/// The bytes arrive in chunks (sizes from the chunking byte), each followed by a
/// `modbus_process`; then the peer's end of stream. Every request's callback runs
/// exactly once, with what the blocking call could return; no buffer is written
/// past its end; nothing stays pending.
pub fn ffi_async(data: &[u8]) {
    use modbus::ffi::event::*;
    let mut c = Cursor::new(data);
    let mode = c.u8();
    let framing = framing_of(mode);
    let call = ClientCall::from(&mut c, true);
    let unit = c.u8();
    let requests = 1 + (c.u8() % 8) as usize;
    let chunking = 1 + c.u8() as usize;
    let stream = if mode & 4 != 0 {
        let req = call.request();
        let mut all = Vec::new();
        for tid in 1..=requests as u16 {
            let mut buf = [0u8; MAX_ADU_LENGTH];
            let n = req.encode(framing, unit, tid, &mut buf);
            let n = framing.seal(&mut buf, n);
            all.extend(wire(framing, &correct_response(framing, &buf[..n])));
        }
        mutate(framing, &mut all, c.rest());
        all
    } else {
        c.rest().to_vec()
    };
    let pair = Pair::with_bytes(&[]);
    let ctx = context(framing, pair.ours);
    let nb = call.nb.max(1) as usize;
    // SAFETY: live context; every buffer outlives its request (freed at the end).
    unsafe {
        modbus_set_slave(ctx, unit as c_int);
        modbus_set_max_in_flight(ctx, 1 + (mode >> 4) as c_int);
        if mode & 8 == 0 {
            assert_eq!(modbus_set_response_timeout(ctx, 5, 0), 0);
            assert_eq!(modbus_set_byte_timeout(ctx, 5, 0), 0);
        }
    }
    let mut seen: Vec<Box<Seen>> = (0..requests).map(|_| Box::default()).collect();
    let mut bits: Vec<Guarded<u8>> = (0..requests).map(|_| Guarded::new(nb, 0xEE, CANARY)).collect();
    let mut regs: Vec<Guarded<u16>> = (0..requests).map(|_| Guarded::new(nb, 0xEEEE, 0xA5A5)).collect();
    let mut submitted = 0;
    for i in 0..requests {
        let user = (&mut *seen[i] as *mut Seen).cast();
        // SAFETY: the buffers hold `nb` items and live until the end.
        let id = unsafe {
            match call.function {
                0x01 => modbus_read_bits_async(ctx, call.addr, call.nb, bits[i].ptr(), Some(seen_cb), user),
                0x02 => modbus_read_input_bits_async(ctx, call.addr, call.nb, bits[i].ptr(), Some(seen_cb), user),
                0x04 => modbus_read_input_registers_async(ctx, call.addr, call.nb, regs[i].ptr(), Some(seen_cb), user),
                0x05 => modbus_write_bit_async(ctx, call.addr, (call.value & 1) as c_int, Some(seen_cb), user),
                0x06 => modbus_write_register_async(ctx, call.addr, call.value, Some(seen_cb), user),
                0x0F => modbus_write_bits_async(ctx, call.addr, call.nb, call.bits.as_ptr(), Some(seen_cb), user),
                0x10 => modbus_write_registers_async(ctx, call.addr, call.nb, call.regs.as_ptr(), Some(seen_cb), user),
                _ => modbus_read_registers_async(
                    ctx,
                    call.addr,
                    call.nb.clamp(1, 125),
                    regs[i].ptr(),
                    Some(seen_cb),
                    user,
                ),
            }
        };
        if id >= 0 {
            submitted += 1;
        } else {
            seen[i].calls = u32::MAX; // refused at once: no callback may run
        }
    }
    let _ = submitted;
    // The answers arrive in chunks, each followed by a process call.
    let mut off = 0;
    let mut k = 0usize;
    while off < stream.len() {
        let size = 1 + (chunking * (k + 1) * 7) % 64;
        let end = (off + size).min(stream.len());
        // SAFETY: writing from a live slice into our own socket.
        unsafe {
            libc::send(pair.peer, stream[off..end].as_ptr().cast(), end - off, libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL)
        };
        off = end;
        k += 1;
        // SAFETY: live context.
        let rc = unsafe { modbus_process(ctx, libc::POLLIN) };
        assert!(rc >= 0, "modbus_process failed: {}", errno());
    }
    // SAFETY: our own socket.
    unsafe { libc::shutdown(pair.peer, libc::SHUT_WR) };
    for _ in 0..4 * requests + 8 {
        // SAFETY: live context.
        if unsafe { modbus_pending(ctx) } == 0 {
            break;
        }
        // SAFETY: live context.
        unsafe { modbus_process(ctx, libc::POLLIN) };
        if mode & 8 != 0 {
            std::thread::sleep(std::time::Duration::from_micros(2));
        }
    }
    // SAFETY: live context.
    let left = unsafe { modbus_pending(ctx) };
    free_context(ctx);
    for (i, s) in seen.iter().enumerate() {
        bits[i].check("async read bits");
        regs[i].check("async read registers");
        if s.calls == u32::MAX {
            continue;
        }
        assert_eq!(s.calls, 1, "request {i}: its callback ran {} times ({left} left pending)", s.calls);
        if s.rc < 0 {
            assert!(
                client_errno_ok(s.error)
                    || s.error == libc::ECANCELED
                    || s.error == libc::ESHUTDOWN
                    || s.error == libc::EIDRM
                    || s.error == libc::EPIPE
                    || s.error == libc::EBADF,
                "request {i} failed with errno {}",
                s.error
            );
        }
    }
}
