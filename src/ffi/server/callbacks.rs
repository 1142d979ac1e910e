//! modbus.h extensions: a server whose data is the application's code,
//! `modbus_reply_dispatch` and `modbus_receive_dispatch` over a
//! `modbus_server_callbacks_t`. The callbacks are [`Data`] on the one reply path of
//! `modbus_reply` (`crate::server::reply`), so every check, exception and debug line
//! of `modbus_reply` is theirs too.

use std::ffi::{c_char, c_int, c_void};
use std::{mem, ptr, slice};

use crate::error::Error;
use crate::ffi::{Modbus, fail, struct_size_ok, with_ctx};
use crate::proto::error::exception;
use crate::proto::frame::Framing;
use crate::proto::reply::{Data, Refusal, Request, pdu, request_extent};
use crate::transport::udp::Peer;

/// What a callback learns of the request it serves (`struct _modbus_request_info`).
/// Filled by the library, valid only during the callback's call (copy what you
/// need); `struct_size` is the size the library filled: a member past it is not
/// there (`ri->struct_size > offsetof(modbus_request_info_t, member)`).
#[repr(C)]
#[allow(non_camel_case_types)]
pub struct modbus_request_info_t {
    pub struct_size: usize,
    pub unit_id: c_int,
    pub function: c_int,
    /// The MBAP transaction id; 0 on a serial line.
    pub transaction_id: c_int,
    /// The context's descriptor: the client's connection on TCP, the serial line's,
    /// the one socket of a UDP server.
    pub socket: c_int,
    /// The client's role (Modbus/TCP Security), NULL on plain TCP and serial lines.
    pub tls_role: *const c_char,
    /// A server that runs itself (`modbus_server_new`): the request's id, for an
    /// answer given later with `modbus_server_answer`; 0 elsewhere.
    pub request_id: c_int,
    /// The client's connection, unique for the server's life (never reused: a
    /// descriptor number used again, each sender of a UDP server has its own); 0 on
    /// a serial line.
    pub connection_id: u64,
    /// The client's address: a TCP connection's peer, a UDP datagram's sender;
    /// NULL on a serial line.
    pub peer: *const libc::sockaddr,
    pub peer_length: u32,
    /// The request's PDU (function code first; no header, no checksum).
    pub pdu: *const u8,
    pub pdu_length: c_int,
}

/// `accept_unit`: 1 serves `unit_id`, 0 not.
pub type AcceptUnitFn =
    unsafe extern "C" fn(ri: *const modbus_request_info_t, unit_id: c_int, user_data: *mut c_void) -> c_int;
/// `read_bits`: fills `dest[0..nb]` with 0 or 1 each.
pub type ReadBitsFn = unsafe extern "C" fn(
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    dest: *mut u8,
    user_data: *mut c_void,
) -> c_int;
/// `read_registers`: fills `dest[0..nb]`.
pub type ReadRegistersFn = unsafe extern "C" fn(
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    dest: *mut u16,
    user_data: *mut c_void,
) -> c_int;
/// `write_bits`: `src[0..nb]`, 0 or 1 each.
pub type WriteBitsFn = unsafe extern "C" fn(
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    src: *const u8,
    user_data: *mut c_void,
) -> c_int;
/// `write_registers`: `src[0..nb]`.
pub type WriteRegistersFn = unsafe extern "C" fn(
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    src: *const u16,
    user_data: *mut c_void,
) -> c_int;
/// `other`: any other function code; the answer's PDU length, or
/// `MODBUS_REPLY_EXCEPTION(code)`.
pub type OtherFn = unsafe extern "C" fn(
    ri: *const modbus_request_info_t,
    pdu: *const u8,
    pdu_length: c_int,
    rsp_pdu: *mut u8,
    rsp_max: c_int,
    user_data: *mut c_void,
) -> c_int;

/// The application's callbacks (`struct _modbus_server_callbacks`). `struct_size`
/// says how much of it the application knows, under the rules of `struct_size_ok`.
#[repr(C)]
#[derive(Clone, Copy)]
#[allow(non_camel_case_types)]
pub struct modbus_server_callbacks_t {
    pub struct_size: usize,
    pub accept_unit: Option<AcceptUnitFn>,
    pub read_bits: Option<ReadBitsFn>,
    pub read_registers: Option<ReadRegistersFn>,
    pub write_bits: Option<WriteBitsFn>,
    pub write_registers: Option<WriteRegistersFn>,
    pub other: Option<OtherFn>,
    /// Every request, whatever its function code, as it came (a gateway's): the
    /// other callbacks and the reply's checks are not used. As `other` returns.
    pub raw: Option<OtherFn>,
}

/// The first published size of `modbus_server_callbacks_t` (every member up to
/// `raw`): a smaller `struct_size` is refused.
const FIRST_SIZE: usize = size_of::<modbus_server_callbacks_t>();

/// `MODBUS_REPLY_NONE`: a callback's "send no answer at all".
pub const REPLY_NONE: c_int = -0x100;
/// `MODBUS_REPLY_LATER`: a callback's "the answer comes later"
/// (`modbus_server_answer`, with the request's id); outside a server that runs
/// itself, as `MODBUS_REPLY_NONE`.
pub const REPLY_LATER: c_int = -0x101;

/// The callbacks as [`Data`], with what `modbus_request_info_t` tells beyond the
/// request (the socket, the role, the connection and its peer, the request's bytes).
pub(crate) struct Callbacks {
    cb: modbus_server_callbacks_t,
    user_data: *mut c_void,
    socket: c_int,
    role: *const c_char,
    connection_id: u64,
    peer: Option<Peer>,
    /// The request being answered (its whole ADU, valid during the reply), and its
    /// framing.
    req: *const u8,
    req_len: usize,
    framing: Framing,
    debug: bool,
    /// The id of the request being answered (a runner's; 0: none).
    pub(crate) request_id: c_int,
    /// A callback said `MODBUS_REPLY_LATER` for it.
    pub(crate) deferred: bool,
}

impl Callbacks {
    /// Copies `*cb` as the application declared it (see [`struct_size_ok`]): EINVAL
    /// when `cb` is NULL, its `struct_size` below the first published size or not at
    /// a member's end, or larger than this library knows with a member set there.
    ///
    /// # Safety
    /// `cb` must be NULL or valid for `cb->struct_size` bytes.
    pub(crate) unsafe fn new(
        cb: *const modbus_server_callbacks_t,
        user_data: *mut c_void,
    ) -> crate::error::Result<Callbacks> {
        // SAFETY: the caller's pointer, NULL or valid for its struct_size bytes.
        let size = unsafe { cb.as_ref() }.map(|c| c.struct_size).ok_or(Error::INVALID)?;
        let ends = crate::member_ends!(modbus_server_callbacks_t: struct_size, accept_unit, read_bits,
            read_registers, write_bits, write_registers, other, raw);
        // SAFETY: `cb` is valid for `size` bytes (the caller's contract).
        let n = unsafe { struct_size_ok(cb.cast(), size, FIRST_SIZE, &ends) }?;
        // SAFETY: all-zero is a valid value (a size and NULL function pointers).
        let mut copy: modbus_server_callbacks_t = unsafe { mem::zeroed() };
        // SAFETY: `n` bytes are readable at `cb` (its struct_size) and fit in `copy`;
        // every bit pattern read is a valid size or a nullable function pointer.
        unsafe { ptr::copy_nonoverlapping(cb.cast::<u8>(), (&raw mut copy).cast::<u8>(), n) };
        Ok(Callbacks {
            cb: copy,
            user_data,
            socket: -1,
            role: ptr::null(),
            connection_id: 0,
            peer: None,
            req: ptr::null(),
            req_len: 0,
            framing: Framing::Tcp,
            debug: false,
            request_id: 0,
            deferred: false,
        })
    }

    /// The request `req` (its whole ADU, which must outlive the reply) comes from
    /// the client of `g` (its socket, its TLS role, its connection).
    pub(crate) fn from(&mut self, g: &mut crate::engine::Guard<'_>, req: &[u8]) {
        self.socket = g.fd();
        self.role = g.line.peer_role().map_or(ptr::null(), |r| r.as_ptr());
        (self.connection_id, self.peer) = crate::server::connection(g);
        self.framing = g.framing();
        self.debug = g.debug;
        self.req = req.as_ptr();
        self.req_len = req.len();
    }

    /// The application chooses the units served (`accept_unit` is set).
    pub(crate) fn chooses_units(&self) -> bool {
        self.cb.accept_unit.is_some()
    }

    /// The request's whole ADU (see [`Callbacks::from`]).
    fn request(&self) -> &[u8] {
        if self.req.is_null() {
            return &[];
        }
        // SAFETY: set by `from` from a slice that outlives the reply under way.
        unsafe { slice::from_raw_parts(self.req, self.req_len) }
    }

    fn info(&self) -> modbus_request_info_t {
        let framing = self.framing;
        let req = self.request();
        let h = framing.header_length();
        let pdu = pdu(framing, req);
        let (peer, peer_length) = self.peer.as_ref().map_or((ptr::null(), 0), Peer::raw);
        modbus_request_info_t {
            struct_size: size_of::<modbus_request_info_t>(),
            unit_id: req.get(h.wrapping_sub(1)).map_or(0, |&u| u as c_int),
            function: req.get(h).map_or(0, |&f| f as c_int),
            transaction_id: if framing == Framing::Tcp && req.len() >= 2 {
                u16::from_be_bytes([req[0], req[1]]) as c_int
            } else {
                0
            },
            socket: self.socket,
            tls_role: self.role,
            request_id: self.request_id,
            connection_id: self.connection_id,
            peer,
            peer_length,
            pdu: pdu.as_ptr(),
            pdu_length: pdu.len() as c_int,
        }
    }

    /// A callback's "later": recorded for the runner (which keeps the request for
    /// `modbus_server_answer`); no answer now.
    fn later(&mut self) -> Refusal {
        self.deferred = self.request_id != 0;
        Refusal::Silent
    }

    /// What data callback `name`'s return value asks for: 0 done,
    /// `MODBUS_REPLY_EXCEPTION(code)` an exception, no answer, or later; anything
    /// else is the application's error, answered as a server device failure
    /// (exception 04) with a debug line naming the callback.
    fn verdict(&mut self, rc: c_int, name: &str) -> Result<(), Refusal> {
        match rc {
            0 => Ok(()),
            REPLY_NONE => Err(Refusal::Silent),
            REPLY_LATER => Err(self.later()),
            n if n < 0 && n > -(exception::MAX as c_int) => Err(Refusal::Exception((-n) as u8)),
            n => {
                self.misuse(name, n);
                Err(Refusal::Exception(exception::SLAVE_OR_SERVER_FAILURE))
            }
        }
    }

    fn misuse(&self, name: &str, rc: c_int) {
        use crate::proto::Diag;
        let mut diag = crate::stdio::DebugSink { enabled: self.debug };
        diag.err(format_args!(
            "ERROR Callback {name} returned {rc}: not 0, MODBUS_REPLY_EXCEPTION(code), MODBUS_REPLY_NONE \
             or MODBUS_REPLY_LATER (answered with exception 04)\n"
        ));
    }
}

/// A function code whose callback is NULL is one the server does not serve.
const UNSERVED: Refusal = Refusal::Exception(exception::ILLEGAL_FUNCTION);

// SAFETY (for every call below): the application's function pointers, called with
// its user data, a request info that lives across the call, and a buffer of exactly
// `nb` items (the length passed).
impl Data for Callbacks {
    fn accept_unit(&mut self, unit: u8, req: &[u8]) -> bool {
        let Some(f) = self.cb.accept_unit else { return true };
        let was = (self.req, self.req_len);
        (self.req, self.req_len) = (req.as_ptr(), req.len());
        let ri = self.info();
        // SAFETY: see the impl comment.
        let accepted = unsafe { f(&ri, unit as c_int, self.user_data) != 0 };
        (self.req, self.req_len) = was;
        accepted
    }

    fn read_bits(&mut self, _rq: &Request, address: u16, dest: &mut [u8]) -> Result<(), Refusal> {
        let f = self.cb.read_bits.ok_or(UNSERVED)?;
        let ri = self.info();
        // SAFETY: see the impl comment.
        let rc = unsafe { f(&ri, address as c_int, dest.len() as c_int, dest.as_mut_ptr(), self.user_data) };
        self.verdict(rc, "read_bits")
    }

    fn read_registers(&mut self, _rq: &Request, address: u16, dest: &mut [u16]) -> Result<(), Refusal> {
        let f = self.cb.read_registers.ok_or(UNSERVED)?;
        let ri = self.info();
        // SAFETY: see the impl comment.
        let rc = unsafe { f(&ri, address as c_int, dest.len() as c_int, dest.as_mut_ptr(), self.user_data) };
        self.verdict(rc, "read_registers")
    }

    fn write_bits(&mut self, _rq: &Request, address: u16, src: &[u8]) -> Result<(), Refusal> {
        let f = self.cb.write_bits.ok_or(UNSERVED)?;
        let ri = self.info();
        // SAFETY: see the impl comment.
        let rc = unsafe { f(&ri, address as c_int, src.len() as c_int, src.as_ptr(), self.user_data) };
        self.verdict(rc, "write_bits")
    }

    fn write_registers(&mut self, _rq: &Request, address: u16, src: &[u16]) -> Result<(), Refusal> {
        let f = self.cb.write_registers.ok_or(UNSERVED)?;
        let ri = self.info();
        // SAFETY: see the impl comment.
        let rc = unsafe { f(&ri, address as c_int, src.len() as c_int, src.as_ptr(), self.user_data) };
        self.verdict(rc, "write_registers")
    }

    fn takes_every_function(&self) -> bool {
        self.cb.raw.is_some()
    }

    fn other(&mut self, _rq: &Request, pdu: &[u8], rsp: &mut [u8]) -> Option<Result<usize, Refusal>> {
        let (f, name) = match (self.cb.raw, self.cb.other) {
            (Some(raw), _) => (raw, "raw"),
            (None, Some(other)) => (other, "other"),
            (None, None) => return None,
        };
        let ri = self.info();
        let max = rsp.len();
        // SAFETY: see the impl comment; `rsp` is writable for `rsp_max` bytes.
        let rc = unsafe { f(&ri, pdu.as_ptr(), pdu.len() as c_int, rsp.as_mut_ptr(), max as c_int, self.user_data) };
        Some(match rc {
            n if n > 0 && n as usize <= max => Ok(n as usize),
            0 => {
                self.misuse(name, 0);
                Err(Refusal::Exception(exception::SLAVE_OR_SERVER_FAILURE))
            }
            n if n > 0 => {
                self.misuse(name, n);
                Err(Refusal::Exception(exception::SLAVE_OR_SERVER_FAILURE))
            }
            n => self.verdict(n, name).map(|()| 0),
        })
    }
}

/// Answers the request `req` (as `modbus_receive` stored it) through the
/// application's callbacks `cb`, exactly as `modbus_reply` answers it from a
/// mapping: the same checks in the same order, the same exceptions and debug
/// lines. Values arrive in host order (registers as `uint16_t`, bits one per byte,
/// 0 or 1). FC 16 (mask write) reads then writes one register; FC 17 writes then
/// reads. A broadcast on a serial line runs the write callbacks and sends nothing.
///
/// Each data callback returns 0 (done), `MODBUS_REPLY_EXCEPTION(code)` (the
/// exception answer), `MODBUS_REPLY_NONE` (no answer at all) or, in a server that
/// runs itself, `MODBUS_REPLY_LATER`; any other value (a positive one: an exception
/// code without `MODBUS_REPLY_EXCEPTION`) is a programming error, answered with
/// exception 04 and a debug line naming the callback. A NULL data callback answers
/// its function codes with exception 01. `other` gets every function code the reply
/// does not serve from data (report slave id, read exception status, unknown codes;
/// the codes a context is configured to serve with `modbus_enable_diagnostics` and
/// its siblings keep their own handlers): it writes the response PDU, function code
/// first, to `rsp_pdu` (at most `rsp_max` bytes) and returns its length, or returns
/// `MODBUS_REPLY_EXCEPTION(code)`, `MODBUS_REPLY_NONE` or `MODBUS_REPLY_LATER`;
/// when NULL, those codes get `modbus_reply`'s answers. `accept_unit` (NULL: every
/// unit) says whether a unit is served: one that is not gets no answer on a serial
/// line and exception 0B (gateway target device failed to respond) on TCP. Every
/// callback gets the request's `modbus_request_info_t`, valid during its call only.
///
/// The callbacks run on the calling thread, with the context locked: they must
/// not block (an answer that needs time is sent later, with `modbus_reply`,
/// `modbus_reply_dispatch` or `modbus_reply_exception` on the stored request),
/// and a call on the same context from a callback fails with EDEADLK.
///
/// Returns the bytes sent, 0 when nothing was sent, -1 on error (EINVAL: `req`
/// or `cb` NULL, or `cb->struct_size` refused: below `sizeof` the struct as first
/// published, not at the end of a member, or larger than this library knows with a
/// byte past what it knows not zero).
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or holding a request as
/// `modbus_reply` requires (and `req_length` bytes when not negative); `cb` NULL or
/// valid for `cb->struct_size` bytes, its members NULL or functions of the types
/// declared.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_reply_dispatch(
    ctx: *mut Modbus,
    req: *const u8,
    req_length: c_int,
    cb: *const modbus_server_callbacks_t,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let mut data = match unsafe { Callbacks::new(cb, user_data) } {
        Ok(data) => data,
        Err(e) => return fail(e),
    };
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let framing = g.framing();
            let bound = if req_length < 0 { usize::MAX } else { req_length as usize };
            // SAFETY: request_extent only asks for prefixes of the request as its own
            // header describes it (and within a non-negative req_length).
            let extent = request_extent(framing, g.session.extended, bound, |n| slice::from_raw_parts(req, n));
            // `other` sees the whole request the caller vouches for, when it says how
            // long it is (a function code request_extent does not know).
            let len = if req_length < 0 { extent } else { extent.max(bound.min(framing.max_adu_length())) };
            // SAFETY: the same bytes, now as one slice.
            let req = slice::from_raw_parts(req, len);
            data.from(g, req);
            crate::server::reply(g, req, req_length, &mut data).map(|n| n as c_int)
        })
    }
}

/// `modbus_receive` for a server that answers through callbacks. Requests are framed
/// whole: the function codes beyond libmodbus by their own layouts, and unknown
/// codes by the MBAP length on TCP and the frame on ASCII (libmodbus reads only up
/// to their function code), so that `other` sees all of them. For a server that
/// answers several units: on a serial line, a
/// request is kept when `cb->accept_unit` says its unit is served (or it is a
/// broadcast), whatever the context's slave; a request for another unit returns 0
/// (and the answer of that unit that follows it on the bus is skipped, as
/// `modbus_receive` skips it). With `accept_unit` NULL, and on TCP, this is
/// `modbus_receive`.
///
/// # Safety
/// As `modbus_receive`; `cb` NULL or valid for `cb->struct_size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_receive_dispatch(
    ctx: *mut Modbus,
    req: *mut u8,
    cb: *const modbus_server_callbacks_t,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let mut data = match unsafe { Callbacks::new(cb, user_data) } {
        Ok(data) => data,
        Err(e) => return fail(e),
    };
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            // SAFETY: the caller's buffer holds the framing's maximum ADU.
            let caller = slice::from_raw_parts_mut(req, g.framing().max_adu_length());
            let units: Option<&mut dyn Data> = if data.cb.accept_unit.is_some() {
                data.from(g, &[]);
                Some(&mut data)
            } else {
                None
            };
            // Requests are framed as a server beyond libmodbus frames them: the
            // codes beyond libmodbus by their layouts, unknown codes whole where the
            // line says how long they are (TCP, ASCII), for `other`.
            let extended = mem::replace(&mut g.session.extended, true);
            let r = crate::server::receive(g, caller, units);
            g.session.extended = extended;
            r.map(|n| n as c_int)
        })
    }
}
