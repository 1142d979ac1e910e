//! modbus.h extensions: the event-driven client. Each `_async` call queues a request
//! and returns its id at once; the application waits on the descriptor
//! `modbus_get_pollfd` names and calls `modbus_process`, which does the I/O that is
//! ready and calls each completed request's callback with what the blocking call
//! would have returned. The driver is `crate::event`; here are the arguments, the
//! values written out, and the callbacks (run with the context unlocked, so that
//! they may call the library on it, free it included).

use std::ffi::{c_int, c_short, c_void};
use std::slice;

use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::event;
use crate::ffi::client::{read_bits_request, read_registers_request, write_bits_request, write_registers_request};
use crate::ffi::{Modbus, fail, with_ctx};
use crate::outstanding::{Completion, Deliver, Done, RawCallback, Ready, Streamed};
use crate::proto::data::{registers_from_be, set_bits_from_bytes};
use crate::proto::fc;
use crate::proto::request::Request;

/// `modbus_callback_t`: called once per request, from `modbus_process` (or
/// `modbus_cancel`, `modbus_free`) on the calling thread, never from `modbus_close`
/// (which a signal handler may call). `rc` is what the blocking call returns, or -1
/// with `error` the errno it would set: ECANCELED for a cancelled request, ESHUTDOWN
/// for one a close left, EIDRM for one `modbus_free` ended.
pub type Callback = Option<CallbackFn>;

/// The function behind a non-NULL [`Callback`].
pub type CallbackFn =
    unsafe extern "C" fn(ctx: *mut Modbus, request_id: c_int, rc: c_int, error: c_int, user_data: *mut c_void);

fn completion(cb: Callback, user_data: *mut c_void, deliver: Deliver) -> Completion {
    // SAFETY: the same C function pointer type but for the first argument's pointee
    // (`modbus_t *` and `void *` are passed alike); it is called back with the
    // context's `modbus_t *`.
    let callback = cb.map(|f| unsafe { std::mem::transmute::<CallbackFn, RawCallback>(f) });
    Completion { callback, user_data, deliver }
}

/// Writes a completed request's values where its call said, then calls its callback
/// with the context unlocked; one at a time, until none is left (a callback may
/// close the context: what is left is then completed with ESHUTDOWN, by the next
/// `modbus_process`; or free it: by that free, with EIDRM).
///
/// # Safety
/// `ctx` is the live handle `g` locks; the pointers of each request are the
/// application's, valid until its callback (the `_async` calls' contract).
unsafe fn fire(ctx: *mut Modbus, g: &mut Guard<'_>) -> c_int {
    let mut fired = 0;
    while let Some(done) = event::take_done(g) {
        let (rc, error) = match (done.result, done.completion.deliver) {
            (Ok(rc), Deliver::Stream { decode, mut args }) => {
                // SAFETY: the decoder writes to the call's pointers, valid until its
                // last round completes.
                match unsafe { decode(&done.data, rc, &mut args) } {
                    Streamed::Done(rc) => (rc, 0),
                    Streamed::Next(req) => {
                        let c = Completion { deliver: Deliver::Stream { decode, args }, ..done.completion };
                        match event::resubmit(g, done.id, &req, c, done.timeout) {
                            Ok(_) => continue,
                            Err(e) => (-1, e.errno()),
                        }
                    }
                }
            }
            // SAFETY: forwarded caller contract.
            _ => unsafe { deliver(&done) },
        };
        fired += 1;
        let user = done.completion.user_data;
        match done.completion.callback {
            // SAFETY: the application's callback, with its own user data.
            Some(cb) => crate::engine::call_unlocked(g, || unsafe { cb(ctx.cast(), done.id, rc, error, user) }),
            // Pull-style: read by `modbus_completion_read`.
            None => event::ready(g, Ready { id: done.id, rc, error, user_data: user }),
        }
    }
    fired
}

/// The values of a completed request into the application's buffers; (rc, errno).
///
/// # Safety
/// The request's pointers are valid for the counts its call gave.
unsafe fn deliver(done: &Done) -> (c_int, c_int) {
    match done.result {
        Err(errno) => (-1, errno),
        Ok(rc) => {
            match done.completion.deliver {
                Deliver::Bits { dest, nb } => {
                    // SAFETY: `dest` holds `nb` bytes (the call's contract).
                    let dest = unsafe { slice::from_raw_parts_mut(dest, nb as usize) };
                    set_bits_from_bytes(dest, &done.data);
                }
                Deliver::Registers { dest } if !done.data.is_empty() => {
                    // SAFETY: the count was checked to be the requested one, for
                    // which `dest` has room.
                    let dest = unsafe { slice::from_raw_parts_mut(dest, done.data.len() / 2) };
                    registers_from_be(&done.data, dest);
                }
                Deliver::Bytes { dest, .. } if !done.data.is_empty() => {
                    // SAFETY: at most `max` bytes, the room `dest` has.
                    let dest = unsafe { slice::from_raw_parts_mut(dest, done.data.len()) };
                    dest.copy_from_slice(&done.data);
                }
                Deliver::Raw { dest } if !done.data.is_empty() => {
                    // SAFETY: an answer's ADU, at most MODBUS_MAX_ADU_LENGTH bytes: the
                    // room `dest` has.
                    let dest = unsafe { slice::from_raw_parts_mut(dest, done.data.len()) };
                    dest.copy_from_slice(&done.data);
                }
                Deliver::Decode { decode, args } => {
                    // SAFETY: the decoder writes to the call's pointers, valid until now.
                    return (unsafe { decode(&done.data, rc, &args) }, 0);
                }
                _ => {}
            }
            (rc, 0)
        }
    }
}

/// Queues a request on `ctx` and returns its id (C convention).
///
/// # Safety
/// `ctx` NULL or live; the request's destination valid until its callback.
pub(crate) unsafe fn submit<'a>(
    ctx: *mut Modbus,
    cb: Callback,
    user_data: *mut c_void,
    deliver: Deliver,
    req: impl FnOnce(&mut Guard<'_>) -> Result<Request<'a>>,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { submit_expecting(ctx, cb, user_data, deliver, true, req) }
}

/// [`submit`]; `answered` false: a request no device answers (see
/// `event::submit_expecting`).
///
/// # Safety
/// As [`submit`].
pub(crate) unsafe fn submit_expecting<'a>(
    ctx: *mut Modbus,
    cb: Callback,
    user_data: *mut c_void,
    deliver: Deliver,
    answered: bool,
    req: impl FnOnce(&mut Guard<'_>) -> Result<Request<'a>>,
) -> c_int {
    let c = completion(cb, user_data, deliver);
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let r = req(g)?;
            event::submit_expecting(g, &r, c, answered)
        })
    }
}

/// Reads `nb` coils (FC 01) into `dest` (one byte per coil), without waiting: returns
/// a request id (>= 0), or -1 with errno. `dest` must stay valid until `cb` runs,
/// which gets `rc` = `nb` or -1 with the error. With a NULL `cb` the completion is
/// queued for `modbus_completion_read` instead.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `nb` bytes until the
/// request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_bits_async(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    dest: *mut u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { read_bits(ctx, fc::READ_COILS, addr, nb, dest, cb, user_data) }
}

/// Reads `nb` discrete inputs (FC 02) into `dest`, without waiting (see
/// `modbus_read_bits_async`).
///
/// # Safety
/// As `modbus_read_bits_async`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_input_bits_async(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    dest: *mut u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { read_bits(ctx, fc::READ_DISCRETE_INPUTS, addr, nb, dest, cb, user_data) }
}

/// # Safety
/// As `modbus_read_bits_async`.
unsafe fn read_bits(
    ctx: *mut Modbus,
    function: u8,
    addr: c_int,
    nb: c_int,
    dest: *mut u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if dest.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, Deliver::Bits { dest, nb }, |g| read_bits_request(g, function, addr, nb)) }
}

/// Reads `nb` holding registers (FC 03) into `dest`, without waiting: `rc` is the
/// number read.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `nb` values until
/// the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_registers_async(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    dest: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { read_registers(ctx, fc::READ_HOLDING_REGISTERS, addr, nb, dest, cb, user_data) }
}

/// Reads `nb` input registers (FC 04) into `dest`, without waiting.
///
/// # Safety
/// As `modbus_read_registers_async`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_input_registers_async(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    dest: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { read_registers(ctx, fc::READ_INPUT_REGISTERS, addr, nb, dest, cb, user_data) }
}

/// # Safety
/// As `modbus_read_registers_async`.
unsafe fn read_registers(
    ctx: *mut Modbus,
    function: u8,
    addr: c_int,
    nb: c_int,
    dest: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if dest.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        submit(ctx, cb, user_data, Deliver::Registers { dest }, |g| read_registers_request(g, function, addr, nb))
    }
}

/// Writes one coil (FC 05), without waiting: `rc` is 1.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_bit_async(
    ctx: *mut Modbus,
    addr: c_int,
    status: c_int,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, Deliver::Count, |_| Ok(Request::WriteBit { addr, on: status != 0 })) }
}

/// Writes one holding register (FC 06), without waiting: `rc` is 1.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_register_async(
    ctx: *mut Modbus,
    addr: c_int,
    value: u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, Deliver::Count, |_| Ok(Request::WriteRegister { addr, value })) }
}

/// Writes `nb` coils (FC 0F) from `src`, without waiting (the values are copied at
/// once): `rc` is the count the server confirmed.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` NULL or valid for `nb` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_bits_async(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    src: *const u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if src.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        // SAFETY: `src` is non-NULL and holds `nb` bytes (contract).
        submit(ctx, cb, user_data, Deliver::Count, |g| write_bits_request(g, addr, nb, src))
    }
}

/// Writes `nb` holding registers (FC 10) from `src`, without waiting (the values
/// are copied at once): `rc` is the count the server confirmed.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` NULL or valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_registers_async(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    src: *const u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if src.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        // SAFETY: `src` is non-NULL and holds `nb` values (contract).
        submit(ctx, cb, user_data, Deliver::Count, |g| write_registers_request(g, addr, nb, src))
    }
}

/// Sets a register to `(current & and_mask) | (or_mask & ~and_mask)` (FC 16),
/// without waiting: `rc` is 1.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_mask_write_register_async(
    ctx: *mut Modbus,
    addr: c_int,
    and_mask: u16,
    or_mask: u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    let req = Request::MaskWriteRegister { addr, and_mask, or_mask };
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, Deliver::Count, |_| Ok(req)) }
}

/// Writes `write_nb` registers then reads `read_nb` (FC 17), without waiting: `rc`
/// is the number read.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` valid for `write_nb` values, `dest`
/// for `read_nb` values until the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_and_read_registers_async(
    ctx: *mut Modbus,
    write_addr: c_int,
    write_nb: c_int,
    src: *const u16,
    read_addr: c_int,
    read_nb: c_int,
    dest: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        submit(ctx, cb, user_data, Deliver::Registers { dest }, |g| {
            crate::ffi::client::write_and_read_request(g, write_addr, write_nb, src, read_addr, read_nb, dest)
        })
    }
}

/// Asks the server for its id (FC 11), without waiting: at most `max_dest` bytes of
/// the answer go to `dest`; `rc` is the byte count the server sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `max_dest` bytes
/// until the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_report_slave_id_async(
    ctx: *mut Modbus,
    max_dest: c_int,
    dest: *mut u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if max_dest <= 0 || dest.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, Deliver::Bytes { dest, max: max_dest }, |_| Ok(Request::ReportSlaveId)) }
}

/// Sends `raw_req` (unit id, then the PDU, as `modbus_send_raw_request` takes it) and
/// receives its answer without waiting: returns a request id (>= 0), or -1 with
/// errno. When the answer comes, its whole ADU (header, PDU, checksum), exception
/// answers included, is written to `rsp` (`MODBUS_MAX_ADU_LENGTH` bytes, valid until
/// `cb` runs) and `cb` gets `rc` = its length; an answer from another unit (a serial
/// line) or of another function fails with EMBBADSLAVE or EMBBADDATA; a request to
/// unit 0 on a serial line completes once sent, with rc as the write it is. The
/// unit is `raw_req[0]`, whatever the context's slave. A gateway forwards requests
/// this way. EINVAL: `raw_req` NULL or not 2 to 254 bytes, `rsp` NULL.
///
/// # Safety
/// `ctx` must be NULL or a live context; `raw_req` valid for `raw_req_length` bytes;
/// `rsp` NULL or valid for `MODBUS_MAX_ADU_LENGTH` bytes until the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_send_raw_request_async(
    ctx: *mut Modbus,
    raw_req: *const u8,
    raw_req_length: c_int,
    rsp: *mut u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    let length_ok = usize::try_from(raw_req_length).is_ok_and(crate::api::raw_length_ok);
    if raw_req.is_null() || rsp.is_null() || !length_ok {
        return fail(Error::INVALID);
    }
    // SAFETY: the caller's request, `raw_req_length` bytes (copied by the queue).
    let raw = unsafe { slice::from_raw_parts(raw_req, raw_req_length as usize) };
    let c = completion(cb, user_data, Deliver::Raw { dest: rsp });
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| crate::api::submit_raw(g, raw, c)) }
}

/// What to wait for: `pfd->fd` is the context's wake descriptor (an epoll set made
/// by the first call, the same for the context's life), readable when the line has
/// I/O ready, when a request is given (from any thread) and when the deadline
/// comes; `pfd->events` is `POLLIN`. `*timeout_ms` (may be NULL) gets the
/// milliseconds until `modbus_process` is due even without an event (-1: no
/// deadline; 0: call it now, the descriptor may not be readable). Returns the number
/// of requests pending, or -1 with errno.
///
/// Linux only (epoll).
///
/// # Safety
/// `ctx` must be NULL or a live context; `pfd` NULL or writable; `timeout_ms` NULL or
/// writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_pollfd(ctx: *mut Modbus, pfd: *mut libc::pollfd, timeout_ms: *mut c_int) -> c_int {
    if pfd.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let (fd, until) = event::wake_interest(g)?;
            // SAFETY: `pfd` is non-NULL and writable (contract).
            *pfd = libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
            if !timeout_ms.is_null() {
                *timeout_ms = match until {
                    None => -1,
                    Some(t) => {
                        let left = t.saturating_sub(crate::transport::now());
                        // Rounded up: a wake-up before the deadline would find nothing due.
                        let ms = left.as_nanos().div_ceil(1_000_000);
                        ms.min(i32::MAX as u128) as c_int
                    }
                };
            }
            Ok(event::pending(g) as c_int)
        })
    }
}

/// Does the I/O that is ready and what the clock says is due, without blocking, and
/// calls the callbacks of the requests that completed. `revents` (from `poll` on the
/// descriptor of `modbus_get_pollfd`) is only a hint: when it is not 0 the context
/// asks its descriptor what is ready; 0 (the wait timed out) saves the asking (what
/// became ready meanwhile keeps the descriptor readable). Returns how many
/// completed, or -1 with errno.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_process(ctx: *mut Modbus, revents: c_short) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { process(ctx, revents, true) }
}

/// `modbus_process` for the multi handle, which knows the line's `revents`.
///
/// # Safety
/// `ctx` must be NULL or a live context.
pub(crate) unsafe fn process_member(ctx: *mut Modbus, revents: c_short) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { process(ctx, revents, false) }
}

/// # Safety
/// `ctx` must be NULL or a live context.
unsafe fn process(ctx: *mut Modbus, revents: c_short, app: bool) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            event::process(g, revents, app)?;
            let fired = fire(ctx, g);
            event::closed(g);
            event::watch(g);
            Ok(fired)
        })
    }
}

/// The requests queued and in flight on `ctx`, or -1 with errno.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_pending(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| Ok(event::pending(g) as c_int)) }
}

/// Completes request `request_id` with ECANCELED (its callback runs before this
/// returns); its answer, should it come, is dropped. Returns 0, or -1 with errno
/// (EINVAL: no such request pending).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_cancel(ctx: *mut Modbus, request_id: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            event::cancel(g, request_id)?;
            fire(ctx, g);
            event::closed(g);
            Ok(0)
        })
    }
}

/// Request `request_id`'s response timeout becomes `to_sec` s + `to_usec` µs, counted
/// from its send (a request takes the context's response timeout when it is queued).
/// Returns 0, or -1 with errno (EINVAL: no such request pending, `to_usec` of a
/// second or more, or both 0).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_request_timeout(
    ctx: *mut Modbus,
    request_id: c_int,
    to_sec: u32,
    to_usec: u32,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| event::set_request_timeout(g, request_id, to_sec, to_usec).map(|()| 0)) }
}

/// The number of requests that may be on the wire at once on `ctx`
/// (`modbus_set_max_in_flight`; always 1 on a serial line), or -1 with errno.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_max_in_flight(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| event::max_in_flight(g)) }
}

/// `modbus_completion_t`: a completion of a request given without a callback, as
/// `modbus_completion_read` fills it. The application sets `struct_size` to
/// `sizeof(modbus_completion_t)` before the call; the library sets it to the size it
/// filled.
#[repr(C)]
#[allow(non_camel_case_types)]
pub struct modbus_completion_t {
    pub struct_size: usize,
    pub ctx: *mut Modbus,
    pub request_id: c_int,
    pub rc: c_int,
    pub error: c_int,
    pub user_data: *mut c_void,
}

impl modbus_completion_t {
    /// The ends of its members (the `struct_size` rule: `ffi::struct_size_ok`).
    const ENDS: [usize; 7] =
        crate::member_ends!(modbus_completion_t: struct_size, ctx, request_id, rc, error, user_data);
    /// The first published size: the whole struct.
    const FIRST: usize = std::mem::size_of::<Self>();

    /// Checks the application's `*c` by the `struct_size` rule.
    ///
    /// # Safety
    /// `c` NULL or valid for its `struct_size` bytes.
    pub(crate) unsafe fn check(c: *mut Self) -> Result<()> {
        // SAFETY: NULL or valid (contract); `struct_size` is its first member.
        let Some(size) = (unsafe { c.as_ref() }).map(|c| c.struct_size) else { return Err(Error::INVALID) };
        // SAFETY: the application's struct, `size` bytes (contract).
        unsafe { crate::ffi::struct_size_ok(c.cast(), size, Self::FIRST, &Self::ENDS) }.map(|_| ())
    }

    /// Fills the members this library knows with `r` of context `ctx`.
    ///
    /// # Safety
    /// `c` passed [`modbus_completion_t::check`].
    pub(crate) unsafe fn fill(c: *mut Self, ctx: *mut Modbus, r: Ready) {
        // SAFETY: at least the whole struct is the application's (checked).
        unsafe {
            c.write(modbus_completion_t {
                struct_size: std::mem::size_of::<Self>(),
                ctx,
                request_id: r.id,
                rc: r.rc,
                error: r.error,
                user_data: r.user_data,
            })
        };
    }
}

/// Pull-style completion: the oldest completion of a request `ctx` was given without
/// a callback (cb NULL), into `*c`: returns 1, or 0 when none is waiting, or -1 with
/// errno (EINVAL: `ctx` or `c` NULL, or `c->struct_size` refused). A context in a
/// multi handle queues its completions there (`modbus_multi_completion_read`).
///
/// # Safety
/// `ctx` must be NULL or a live context; `c` NULL or valid for `c->struct_size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_completion_read(ctx: *mut Modbus, c: *mut modbus_completion_t) -> c_int {
    // SAFETY: forwarded caller contract.
    if let Err(e) = unsafe { modbus_completion_t::check(c) } {
        return fail(e);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            Ok(match event::take_ready(g)? {
                Some(r) => {
                    // SAFETY: checked above.
                    modbus_completion_t::fill(c, ctx, r);
                    1
                }
                None => 0,
            })
        })
    }
}

/// How many requests may be on the wire at once on a TCP context (pipelining):
/// 1..=256, default 1; a serial line always has one. Returns 0, or -1 with errno.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_max_in_flight(ctx: *mut Modbus, n: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| event::set_max_in_flight(g, n).map(|()| 0)) }
}

/// `modbus_free`: what is pending completes (`event::free`: EIDRM, or ESHUTDOWN for
/// what a close left), each callback run before the free returns, a submission from
/// them refused (EIDRM); the context leaves its multi handle first. Nothing waits:
/// when a call holds the context (another thread's, or one a signal handler
/// interrupted), `handle::free` does it once that call lets go (`finish_free`).
///
/// # Safety
/// `ctx` must be NULL or a live context.
pub unsafe fn cancel_pending(ctx: *mut Modbus) {
    // SAFETY: forwarded caller contract (`try_call` takes NULL).
    unsafe {
        crate::handle::try_call(ctx, |g| complete_on_free(ctx, g, false));
    }
}

/// What `modbus_free` does to the event-driven client's requests (see
/// [`cancel_pending`]); `by_handler`: the free closed the context under a call (a
/// signal handler's, another thread's), a close that is part of it (EIDRM, not
/// ESHUTDOWN).
///
/// # Safety
/// `ctx` is the live handle `g` locks.
pub(crate) unsafe fn complete_on_free(ctx: *mut Modbus, g: &mut Guard<'_>, by_handler: bool) {
    let o = match g.async_state() {
        Ok(Some(o)) => o,
        Ok(None) => return,
        Err(_) => {
            // `modbus_process` has the requests (this free comes while its RTS hook
            // runs, with the lock released): it completes them (EIDRM) as it ends,
            // and the handle lives until then (that call holds a reference).
            g.set_shut(crate::context::Shut::Freed);
            return;
        }
    };
    if let Some((members, key)) = o.multi.take() {
        // (Its completions not read yet go with it.)
        members.remove(key);
    }
    if by_handler {
        event::closed_by_free(g);
    }
    event::free(g);
    // SAFETY: forwarded caller contract.
    unsafe { fire(ctx, g) };
}
