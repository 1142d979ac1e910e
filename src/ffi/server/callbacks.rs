//! modbus.h extensions: a server whose data is the application's code,
//! `modbus_reply_callbacks` and `modbus_receive_callbacks` over a
//! `modbus_server_callbacks_t`. The callbacks are [`Data`] on the one reply path of
//! `modbus_reply` (`crate::server::reply`), so every check, exception and debug line
//! of `modbus_reply` is theirs too.

use std::ffi::{c_char, c_int, c_void};
use std::{mem, ptr, slice};

use crate::error::Error;
use crate::ffi::{Modbus, fail, struct_size_ok, with_ctx};
use crate::proto::error::exception;
use crate::proto::reply::{Data, Refusal, Request, request_extent};

/// What a callback learns of the request it serves.
#[repr(C)]
#[allow(non_camel_case_types)]
pub struct modbus_request_info_t {
    pub unit_id: c_int,
    pub function: c_int,
    /// The MBAP transaction id; 0 on a serial line.
    pub transaction_id: c_int,
    /// The context's descriptor: the client's connection on TCP, the serial line's.
    pub socket: c_int,
    /// The client's role (Modbus/TCP Security), NULL on plain TCP and serial lines.
    pub tls_role: *const c_char,
    /// A server that runs itself (`modbus_server_new`): the request's id, for an
    /// answer given later with `modbus_server_answer`; 0 elsewhere.
    pub request_id: u32,
}

/// `accept_unit`: 1 serves `unit_id`, 0 not.
pub type AcceptUnitFn = unsafe extern "C" fn(user_data: *mut c_void, unit_id: c_int) -> c_int;
/// `read_bits`: fills `dest[0..nb]` with 0 or 1 each.
pub type ReadBitsFn = unsafe extern "C" fn(
    user_data: *mut c_void,
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    dest: *mut u8,
) -> c_int;
/// `read_registers`: fills `dest[0..nb]`.
pub type ReadRegistersFn = unsafe extern "C" fn(
    user_data: *mut c_void,
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    dest: *mut u16,
) -> c_int;
/// `write_bits`: `src[0..nb]`, 0 or 1 each.
pub type WriteBitsFn = unsafe extern "C" fn(
    user_data: *mut c_void,
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    src: *const u8,
) -> c_int;
/// `write_registers`: `src[0..nb]`.
pub type WriteRegistersFn = unsafe extern "C" fn(
    user_data: *mut c_void,
    ri: *const modbus_request_info_t,
    addr: c_int,
    nb: c_int,
    src: *const u16,
) -> c_int;
/// `other`: any other function code; the answer's PDU length, or -code.
pub type OtherFn = unsafe extern "C" fn(
    user_data: *mut c_void,
    ri: *const modbus_request_info_t,
    pdu: *const u8,
    pdu_length: c_int,
    rsp_pdu: *mut u8,
    rsp_max: c_int,
) -> c_int;

/// The application's callbacks (`modbus_server_callbacks_t`). `struct_size` says
/// how much of it the application knows, under the rules of `struct_size_ok`.
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
/// request (the socket, the role).
pub(crate) struct Callbacks {
    cb: modbus_server_callbacks_t,
    user_data: *mut c_void,
    socket: c_int,
    role: *const c_char,
    /// The id of the request being answered (a runner's; 0: none).
    pub(crate) request_id: u32,
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
        Ok(Callbacks { cb: copy, user_data, socket: -1, role: ptr::null(), request_id: 0, deferred: false })
    }

    /// The request comes from the client of `g` (its socket, its TLS role).
    pub(crate) fn from(&mut self, g: &crate::engine::Guard<'_>) {
        self.socket = g.fd();
        self.role = g.line.peer_role().map_or(ptr::null(), |r| r.as_ptr());
    }

    /// The application chooses the units served (`accept_unit` is set).
    pub(crate) fn chooses_units(&self) -> bool {
        self.cb.accept_unit.is_some()
    }

    fn info(&self, rq: &Request) -> modbus_request_info_t {
        modbus_request_info_t {
            unit_id: rq.unit as c_int,
            function: rq.function as c_int,
            transaction_id: rq.transaction_id as c_int,
            socket: self.socket,
            tls_role: self.role,
            request_id: self.request_id,
        }
    }

    /// A callback's "later": recorded for the runner (which keeps the request for
    /// `modbus_server_answer`); no answer now.
    fn later(&mut self) -> Refusal {
        self.deferred = self.request_id != 0;
        Refusal::Silent
    }

    /// What a data callback's return value asks for (see [`verdict`]), "later"
    /// included.
    fn data_verdict(&mut self, rc: c_int) -> Result<(), Refusal> {
        if rc == REPLY_LATER {
            return Err(self.later());
        }
        verdict(rc)
    }
}

/// What a data callback's return value asks for: 0 done, an exception code, or no
/// answer; anything else is the application's error, answered as a server device
/// failure (exception 04).
fn verdict(rc: c_int) -> Result<(), Refusal> {
    match rc {
        0 => Ok(()),
        REPLY_NONE => Err(Refusal::Silent),
        code if code > 0 && code < exception::MAX as c_int => Err(Refusal::Exception(code as u8)),
        _ => Err(Refusal::Exception(exception::SLAVE_OR_SERVER_FAILURE)),
    }
}

/// A function code whose callback is NULL is one the server does not serve.
const UNSERVED: Refusal = Refusal::Exception(exception::ILLEGAL_FUNCTION);

// SAFETY (for every call below): the application's function pointers, called with
// its user data, a request info that lives across the call, and a buffer of exactly
// `nb` items (the length passed).
impl Data for Callbacks {
    fn accept_unit(&mut self, unit: u8) -> bool {
        match self.cb.accept_unit {
            // SAFETY: see the impl comment.
            Some(f) => unsafe { f(self.user_data, unit as c_int) != 0 },
            None => true,
        }
    }

    fn read_bits(&mut self, rq: &Request, address: u16, dest: &mut [u8]) -> Result<(), Refusal> {
        let f = self.cb.read_bits.ok_or(UNSERVED)?;
        let ri = self.info(rq);
        // SAFETY: see the impl comment.
        let rc = unsafe { f(self.user_data, &ri, address as c_int, dest.len() as c_int, dest.as_mut_ptr()) };
        self.data_verdict(rc)
    }

    fn read_registers(&mut self, rq: &Request, address: u16, dest: &mut [u16]) -> Result<(), Refusal> {
        let f = self.cb.read_registers.ok_or(UNSERVED)?;
        let ri = self.info(rq);
        // SAFETY: see the impl comment.
        let rc = unsafe { f(self.user_data, &ri, address as c_int, dest.len() as c_int, dest.as_mut_ptr()) };
        self.data_verdict(rc)
    }

    fn write_bits(&mut self, rq: &Request, address: u16, src: &[u8]) -> Result<(), Refusal> {
        let f = self.cb.write_bits.ok_or(UNSERVED)?;
        let ri = self.info(rq);
        // SAFETY: see the impl comment.
        let rc = unsafe { f(self.user_data, &ri, address as c_int, src.len() as c_int, src.as_ptr()) };
        self.data_verdict(rc)
    }

    fn write_registers(&mut self, rq: &Request, address: u16, src: &[u16]) -> Result<(), Refusal> {
        let f = self.cb.write_registers.ok_or(UNSERVED)?;
        let ri = self.info(rq);
        // SAFETY: see the impl comment.
        let rc = unsafe { f(self.user_data, &ri, address as c_int, src.len() as c_int, src.as_ptr()) };
        self.data_verdict(rc)
    }

    fn takes_every_function(&self) -> bool {
        self.cb.raw.is_some()
    }

    fn other(&mut self, rq: &Request, pdu: &[u8], rsp: &mut [u8]) -> Option<Result<usize, Refusal>> {
        let f = self.cb.raw.or(self.cb.other)?;
        let ri = self.info(rq);
        let max = rsp.len();
        // SAFETY: see the impl comment; `rsp` is writable for `rsp_max` bytes.
        let rc = unsafe { f(self.user_data, &ri, pdu.as_ptr(), pdu.len() as c_int, rsp.as_mut_ptr(), max as c_int) };
        Some(match rc {
            n if n > 0 && n as usize <= max => Ok(n as usize),
            REPLY_NONE => Err(Refusal::Silent),
            REPLY_LATER => Err(self.later()),
            n if n < 0 && -n < exception::MAX as c_int => Err(Refusal::Exception((-n) as u8)),
            _ => Err(Refusal::Exception(exception::SLAVE_OR_SERVER_FAILURE)),
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
/// Each data callback returns 0, a `MODBUS_EXCEPTION_*` code (sent as the
/// exception answer), or `MODBUS_REPLY_NONE` (no answer at all); any other value is
/// answered with exception 04. A NULL data callback answers its function codes with
/// exception 01. `other` gets every function code the reply does not serve from
/// data (report slave id, read exception status, unknown codes; the codes a
/// context is configured to serve with `modbus_enable_diagnostics` and its
/// siblings keep their own handlers): it writes the response PDU, function code
/// first, to `rsp_pdu` (at most `rsp_max` bytes) and returns its length, or returns
/// -code for an exception, or `MODBUS_REPLY_NONE`; when NULL, those codes get
/// `modbus_reply`'s answers. `accept_unit` (NULL: every unit) says whether a unit
/// is served: one that is not gets no answer on a serial line and exception 0B
/// (gateway target device failed to respond) on TCP.
///
/// The callbacks run on the calling thread, with the context locked: they must
/// not block (an answer that needs time is sent later, with `modbus_reply`,
/// `modbus_reply_callbacks` or `modbus_reply_exception` on the stored request),
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
pub unsafe extern "C" fn modbus_reply_callbacks(
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
            data.from(g);
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
pub unsafe extern "C" fn modbus_receive_callbacks(
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
            let units: Option<&mut dyn Data> = if data.cb.accept_unit.is_some() { Some(&mut data) } else { None };
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
