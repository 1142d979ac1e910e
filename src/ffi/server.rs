//! modbus.h / modbus-tcp.h: the server side. The data mapping (`modbus_mapping_t`
//! and its allocation), `modbus_receive`, `modbus_reply`, `modbus_reply_exception`,
//! and the TCP listen/accept calls.
//!
//! Where libmodbus would dereference a NULL pointer (request buffer, mapping, the
//! accept socket pointer) these give EINVAL, or an empty table for a NULL mapping.

use std::ffi::{CStr, c_char, c_int, c_uint};
use std::mem::{offset_of, size_of};
use std::ptr;
use std::slice;

use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::ffi::{Modbus, fail, with_ctx};
use crate::proto::diagnostics::Diagnostics;
use crate::proto::reply::{Mapping, Table, request_extent};
use crate::server_ext::ServerExt;
use crate::transport::listen;

/// The data a server exposes (`modbus_mapping_t`): four tables, each with its size
/// and first address. The field order is libmodbus's ABI (input registers before
/// holding registers); the tables are allocated with the C allocator, so a C
/// program may free or replace them itself.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct modbus_mapping_t {
    pub nb_bits: c_int,
    pub start_bits: c_int,
    pub nb_input_bits: c_int,
    pub start_input_bits: c_int,
    pub nb_input_registers: c_int,
    pub start_input_registers: c_int,
    pub nb_registers: c_int,
    pub start_registers: c_int,
    pub tab_bits: *mut u8,
    pub tab_input_bits: *mut u8,
    pub tab_input_registers: *mut u16,
    pub tab_registers: *mut u16,
}

#[cfg(target_pointer_width = "64")]
const _: () = {
    assert!(size_of::<modbus_mapping_t>() == 64);
    assert!(offset_of!(modbus_mapping_t, nb_bits) == 0);
    assert!(offset_of!(modbus_mapping_t, start_bits) == 4);
    assert!(offset_of!(modbus_mapping_t, nb_input_bits) == 8);
    assert!(offset_of!(modbus_mapping_t, start_input_bits) == 12);
    assert!(offset_of!(modbus_mapping_t, nb_input_registers) == 16);
    assert!(offset_of!(modbus_mapping_t, start_input_registers) == 20);
    assert!(offset_of!(modbus_mapping_t, nb_registers) == 24);
    assert!(offset_of!(modbus_mapping_t, start_registers) == 28);
    assert!(offset_of!(modbus_mapping_t, tab_bits) == 32);
    assert!(offset_of!(modbus_mapping_t, tab_input_bits) == 40);
    assert!(offset_of!(modbus_mapping_t, tab_input_registers) == 48);
    assert!(offset_of!(modbus_mapping_t, tab_registers) == 56);
};

/// A zero-filled C table of `nb` items, NULL for 0. `None` when the allocation failed.
fn alloc_table<T>(nb: c_uint) -> Option<*mut T> {
    if nb == 0 {
        return Some(ptr::null_mut());
    }
    // SAFETY: calloc checks `nb * size` for overflow and returns NULL or zeroed memory.
    let p = unsafe { libc::calloc(nb as usize, size_of::<T>()) }.cast::<T>();
    (!p.is_null()).then_some(p)
}

/// Allocates a mapping whose tables start at the given addresses. Every table is
/// zero-filled; a table of size 0 is NULL. Returns NULL with ENOMEM on failure.
#[allow(clippy::too_many_arguments)]
#[unsafe(no_mangle)]
pub extern "C" fn modbus_mapping_new_start_address(
    start_bits: c_uint,
    nb_bits: c_uint,
    start_input_bits: c_uint,
    nb_input_bits: c_uint,
    start_registers: c_uint,
    nb_registers: c_uint,
    start_input_registers: c_uint,
    nb_input_registers: c_uint,
) -> *mut modbus_mapping_t {
    let bits = alloc_table::<u8>(nb_bits);
    let input_bits = alloc_table::<u8>(nb_input_bits);
    let input_registers = alloc_table::<u16>(nb_input_registers);
    let registers = alloc_table::<u16>(nb_registers);
    // SAFETY: malloc has no preconditions; the result is checked for NULL.
    let m = unsafe { libc::malloc(size_of::<modbus_mapping_t>()) }.cast::<modbus_mapping_t>();
    let (Some(tab_bits), Some(tab_input_bits), Some(tab_input_registers), Some(tab_registers), false) =
        (bits, input_bits, input_registers, registers, m.is_null())
    else {
        let allocated = [
            bits.map(|p| p.cast::<libc::c_void>()),
            input_bits.map(|p| p.cast()),
            input_registers.map(|p| p.cast()),
            registers.map(|p| p.cast()),
            Some(m.cast()),
        ];
        for p in allocated.into_iter().flatten() {
            // SAFETY: each pointer is NULL or came from calloc/malloc above; freed once.
            unsafe { libc::free(p) };
        }
        crate::ffi::fail(Error::NO_MEMORY);
        return ptr::null_mut();
    };
    let mapping = modbus_mapping_t {
        nb_bits: nb_bits as c_int,
        start_bits: start_bits as c_int,
        nb_input_bits: nb_input_bits as c_int,
        start_input_bits: start_input_bits as c_int,
        nb_input_registers: nb_input_registers as c_int,
        start_input_registers: start_input_registers as c_int,
        nb_registers: nb_registers as c_int,
        start_registers: start_registers as c_int,
        tab_bits,
        tab_input_bits,
        tab_input_registers,
        tab_registers,
    };
    // SAFETY: `m` is a fresh, suitably aligned allocation of the struct's size.
    unsafe { m.write(mapping) };
    m
}

/// Allocates a mapping whose tables all start at address 0 (note the argument order:
/// bits, input bits, holding registers, input registers).
#[unsafe(no_mangle)]
pub extern "C" fn modbus_mapping_new(
    nb_bits: c_int,
    nb_input_bits: c_int,
    nb_registers: c_int,
    nb_input_registers: c_int,
) -> *mut modbus_mapping_t {
    modbus_mapping_new_start_address(
        0,
        nb_bits as c_uint,
        0,
        nb_input_bits as c_uint,
        0,
        nb_registers as c_uint,
        0,
        nb_input_registers as c_uint,
    )
}

/// Frees a mapping and its four tables. NULL is a no-op.
///
/// # Safety
/// `mb_mapping` must be NULL or a mapping from `modbus_mapping_new*` not yet freed;
/// its table pointers must be NULL or allocated with the C allocator.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_mapping_free(mb_mapping: *mut modbus_mapping_t) {
    if mb_mapping.is_null() {
        return;
    }
    // SAFETY: guaranteed by the caller: a live mapping with C-allocated tables.
    unsafe {
        let m = &*mb_mapping;
        libc::free(m.tab_bits.cast());
        libc::free(m.tab_input_bits.cast());
        libc::free(m.tab_input_registers.cast());
        libc::free(m.tab_registers.cast());
        libc::free(mb_mapping.cast());
    }
}

/// The tables of a C mapping, lent one at a time to the reply logic. A NULL mapping,
/// a NULL or misaligned table, or a size below 1 is an empty table.
struct CMapping(*mut modbus_mapping_t);

/// # Safety
/// `p` must be NULL or valid for `nb` items, not otherwise borrowed for `'a`.
unsafe fn c_table<'a, T>(start: c_int, nb: c_int, p: *mut T) -> Table<'a, T> {
    let data: &mut [T] = if p.is_null() || nb <= 0 || !p.is_aligned() {
        &mut []
    } else {
        // SAFETY: guaranteed by the caller.
        unsafe { slice::from_raw_parts_mut(p, nb as usize) }
    };
    Table { start, data }
}

impl CMapping {
    /// Reads the mapping's header (a copy: the tables are borrowed separately).
    fn fields(&self) -> Option<modbus_mapping_t> {
        // SAFETY: `self.0` is NULL or a live mapping (contract of modbus_reply); the
        // struct is plain data, copied out field by field.
        unsafe { self.0.as_ref() }.copied()
    }
}

// SAFETY (for every method): modbus_reply's contract makes each non-NULL table valid
// for its `nb` items; the trait lends one table at a time, so no two slices coexist.
impl Mapping for CMapping {
    fn bits(&mut self) -> Table<'_, u8> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_bits, m.nb_bits, m.tab_bits) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    fn input_bits(&mut self) -> Table<'_, u8> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_input_bits, m.nb_input_bits, m.tab_input_bits) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    fn registers(&mut self) -> Table<'_, u16> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_registers, m.nb_registers, m.tab_registers) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    fn input_registers(&mut self) -> Table<'_, u16> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_input_registers, m.nb_input_registers, m.tab_input_registers) },
            None => Table { start: 0, data: &mut [] },
        }
    }
}

/// Waits for one request and stores it in `req`. Returns its length, or 0 for a
/// frame filtered out (RTU: another slave's request, or the answer to it).
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or valid for
/// `MODBUS_TCP_MAX_ADU_LENGTH` (TCP) or `MODBUS_RTU_MAX_ADU_LENGTH` (RTU) bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_receive(ctx: *mut Modbus, req: *mut u8) -> c_int {
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            // SAFETY: the caller's buffer holds the framing's maximum ADU. The receive
            // writes only the bytes it reads, as libmodbus does (even on errors).
            let caller = slice::from_raw_parts_mut(req, g.framing.max_adu_length());
            crate::server::receive(g, caller).map(|n| n as c_int)
        })
    }
}

/// Answers the request `req` (as stored by `modbus_receive`) from `mb_mapping`.
/// Returns the bytes sent, 0 for an RTU broadcast (not answered), -1 on error
/// (ENOPROTOOPT for FC 0x07, which libmodbus 3.1.12 does not answer).
///
/// Only the bytes the request describes are read (its function code and byte counts,
/// at most one ADU), and never past `req_length` when it is not negative. For the
/// single-write functions `req_length` must be the request's exact length.
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or holding a request as described;
/// `mb_mapping` NULL or a mapping whose tables hold their `nb_*` items.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_reply(
    ctx: *mut Modbus,
    req: *const u8,
    req_length: c_int,
    mb_mapping: *mut modbus_mapping_t,
) -> c_int {
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let bound = if req_length < 0 { usize::MAX } else { req_length as usize };
            // SAFETY: request_extent only asks for prefixes of the request as its own
            // header describes it (and within a non-negative req_length).
            let extent = request_extent(g.framing, g.session.extended, bound, |n| slice::from_raw_parts(req, n));
            // SAFETY: the same bytes, now as one slice.
            let req = slice::from_raw_parts(req, extent);
            let mut mapping = CMapping(mb_mapping);
            crate::server::reply(g, req, req_length, &mut mapping).map(|n| n as c_int)
        })
    }
}

/// Sends exception `exception_code` (0..=11, else EINVAL) in answer to `req`.
/// Returns the bytes sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or holding at least the header
/// and function code of a request.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_reply_exception(ctx: *mut Modbus, req: *const u8, exception_code: c_uint) -> c_int {
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            // SAFETY: the caller's request holds its header and function code.
            let req = slice::from_raw_parts(req, g.framing.header_length() + 1);
            crate::server::reply_exception(g, req, exception_code).map(|n| n as c_int)
        })
    }
}

/// Opens an IPv4 listening socket on the context's address and port, for up to
/// `nb_connection` pending clients. Returns the socket; the caller owns it.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_listen(ctx: *mut Modbus, nb_connection: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| listen::listen_ipv4(&g.link, nb_connection, &mut g.diag())) }
}

/// Accepts one client on `*s` and makes it the context's socket (TCP contexts, and RTU
/// framing over TCP). The context is not locked while waiting; a close of the context
/// (from a signal handler or another thread) ends the wait with EBADF.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
unsafe fn accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    let check = |g: &mut Guard<'_>| if s.is_null() || !g.is_socket() { Err(Error::INVALID) } else { Ok(()) };
    // SAFETY: `s` is non-NULL and valid per the caller once `check` passed, which
    // comes first.
    let wait = |w: &crate::handle::Waiting<'_>| listen::accept(unsafe { *s }, w.wake_fd(), &|| w.closed());
    let then = |g: &mut Guard<'_>, accepted: Result<(c_int, Option<String>)>, closed: bool| match accepted {
        Ok((fd, _)) if closed => {
            // Closed while the client was being accepted.
            crate::transport::close(fd);
            Err(Error::STOPPED)
        }
        Ok((fd, peer)) => {
            g.set_descriptor(fd);
            listen::report_accept(&mut g.diag(), peer.as_deref());
            if g.tls.is_some() {
                // Modbus/TCP Security: the client is served only once it has
                // authenticated (a failure closes its socket).
                crate::engine::tls_handshake(g, crate::engine::Side::Server)?;
            }
            Ok(fd)
        }
        Err(e) => {
            // As libmodbus: the context's socket is accept's -1, unless the context
            // was closed while waiting (nothing left to change).
            if !closed {
                g.set_descriptor(-1);
            }
            Err(e)
        }
    };
    // errno after the wait's end: freeing the handle (when a `modbus_free` came
    // meanwhile) must not change it.
    // SAFETY: forwarded caller contract.
    crate::ffi::status(unsafe { crate::handle::wait_unlocked(ctx, check, wait, then) })
}

/// Accepts one client on the listening socket `*s`; the new socket becomes the
/// context's and is returned.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { accept(ctx, s) }
}

/// Opens a listening socket on the first address getaddrinfo gives for the context's
/// node and service (IPv4 or IPv6). Returns the socket; the caller owns it.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_pi_listen(ctx: *mut Modbus, nb_connection: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| listen::listen_pi(&g.link, nb_connection, g.debug, &mut g.diag())) }
}

/// Accepts one client (IPv4 or IPv6) on the listening socket `*s`; the new socket
/// becomes the context's and is returned.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_pi_accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { accept(ctx, s) }
}

// ---------------------------------------------------------------- beyond libmodbus

/// Runs `f` on the context's server extension (created on first use), then drops
/// it again if nothing is configured and updates how requests are framed.
fn configure(g: &mut Guard<'_>, f: impl FnOnce(&mut ServerExt) -> Result<c_int>) -> Result<c_int> {
    let ext = g.server_ext.get_or_insert_with(Default::default);
    let r = f(ext);
    if ext.is_idle() {
        g.server_ext = None;
    }
    g.session.extended = g.server_ext.as_ref().is_some_and(|e| e.needs_extended_framing());
    r
}

/// The diagnostics state, or EINVAL when diagnostics are off.
fn diagnostics<'a>(g: &'a mut Guard<'_>) -> Result<&'a mut Diagnostics> {
    g.server_ext.as_deref_mut().and_then(ServerExt::diagnostics_mut).ok_or(Error::INVALID)
}

/// rsmodbus extension (server): turns the serial-line diagnostics of this server
/// context on (`enable` != 0) or off. On, `modbus_receive` and `modbus_reply` keep
/// the eight bus counters, the comm event counter and the 64-entry event log, and
/// `modbus_reply` answers function codes 08 (every diagnostics sub-function,
/// listen-only mode included), 0B and 0C. Turning it on starts from zero; off
/// forgets everything and answers those codes as libmodbus does. Returns 0.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_enable_diagnostics(ctx: *mut Modbus, enable: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            configure(g, |e| {
                e.enable_diagnostics(enable != 0);
                Ok(0)
            })
        })
    }
}

/// rsmodbus extension (server): reads into `*value` what diagnostics sub-function
/// `sub_function` reports: 0x02 the diagnostic register, 0x03 the ASCII input
/// delimiter, 0x04 1 in listen-only mode (else 0), 0x0B to 0x12 the bus message,
/// bus communication error, bus exception error, server message, server no
/// response, server NAK, server busy and bus character overrun counters. Returns 0;
/// EINVAL when diagnostics are off or for another sub-function.
///
/// # Safety
/// `ctx` must be NULL or a live context; `value` NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_diagnostics(ctx: *mut Modbus, sub_function: c_int, value: *mut u16) -> c_int {
    if value.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let d = diagnostics(g)?;
            let sub = u16::try_from(sub_function).map_err(|_| Error::INVALID)?;
            // SAFETY: `value` is non-NULL and writable per the caller.
            *value = d.get(sub).ok_or(Error::INVALID)?;
            Ok(0)
        })
    }
}

/// rsmodbus extension (server): the comm event counter into `*event_count`, the
/// message count (bus messages) into `*message_count` (each may be NULL), and up to
/// `max_events` bytes of the event log, newest first, into `events`. Returns the
/// number of events in the log (0 to 64); EINVAL when diagnostics are off.
///
/// # Safety
/// `ctx` must be NULL or a live context; the counter pointers NULL or writable;
/// `events` valid for `max_events` bytes (or NULL when `max_events` is 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_event_log(
    ctx: *mut Modbus,
    event_count: *mut u16,
    message_count: *mut u16,
    events: *mut u8,
    max_events: c_int,
) -> c_int {
    if max_events < 0 || (max_events > 0 && events.is_null()) {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let d = diagnostics(g)?;
            if let Some(p) = event_count.as_mut() {
                *p = d.event_counter();
            }
            if let Some(p) = message_count.as_mut() {
                *p = d.message_count();
            }
            let log = d.events();
            let n = log.len().min(max_events as usize);
            if n > 0 {
                // SAFETY: `events` holds `max_events` >= n bytes per the caller.
                slice::from_raw_parts_mut(events, n).copy_from_slice(&log[..n]);
            }
            Ok(log.len() as c_int)
        })
    }
}

/// rsmodbus extension (server): sets the application's bits of the diagnostic
/// register that sub-function 0x02 returns (bit 0 also reads as 1 while the
/// character overrun flag is set). Sub-function 0x0A clears it. Returns 0; EINVAL
/// when diagnostics are off.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_diagnostic_register(ctx: *mut Modbus, value: u16) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            diagnostics(g)?.set_register(value);
            Ok(0)
        })
    }
}

/// rsmodbus extension (server): the byte function code 07 (read exception status)
/// answers, 0 to 255; -1 restores libmodbus's behaviour (no answer, `modbus_reply`
/// fails with ENOPROTOOPT). Returns 0; EINVAL for another value.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_exception_status(ctx: *mut Modbus, status: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let status = match status {
                -1 => None,
                0..=0xFF => Some(status as u8),
                _ => return Err(Error::INVALID),
            };
            configure(g, |e| {
                e.set_exception_status(status);
                Ok(0)
            })
        })
    }
}

/// rsmodbus extension (server): sets device identification object `object_id`
/// (function code 2B / MEI 0E) to the `length` bytes at `value`, or to the
/// NUL-terminated string `value` when `length` is -1; a NULL `value` removes the
/// object. Ids 0x00-0x02 are the basic objects (VendorName, ProductCode,
/// MajorMinorRevision; served empty while unset), 0x03-0x06 the regular ones,
/// 0x80-0xFF the extended ones; 0x07-0x7F are reserved. At most 244 bytes. The
/// first object enables device identification; removing the last disables it.
/// Returns 0; EINVAL for a bad id or length.
///
/// # Safety
/// `ctx` must be NULL or a live context; `value` NULL, a NUL-terminated string
/// (`length` -1), or valid for `length` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_device_identification(
    ctx: *mut Modbus,
    object_id: c_int,
    value: *const c_char,
    length: c_int,
) -> c_int {
    let bytes: Option<&[u8]> = if value.is_null() {
        None
    } else if length == -1 {
        // SAFETY: a NUL-terminated string per the caller.
        Some(unsafe { CStr::from_ptr(value) }.to_bytes())
    } else if length >= 0 {
        // SAFETY: `length` readable bytes per the caller.
        Some(unsafe { slice::from_raw_parts(value.cast::<u8>(), length as usize) })
    } else {
        return fail(Error::INVALID);
    };
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| configure(g, |e| e.set_device_identification(object_id, bytes).map(|()| 0))) }
}

/// rsmodbus extension (server): the conformity level device identification
/// answers: 0x01, 0x02, 0x03 (basic, regular, extended; stream access only) or
/// 0x81, 0x82, 0x83 (the same with individual access). Stream requests for a
/// higher category get the objects up to the declared one; without the 0x80 bit,
/// individual access is refused. 0 (the default) derives it from the objects set.
/// Returns 0; EINVAL for another value.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_conformity_level(ctx: *mut Modbus, level: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| configure(g, |e| e.set_conformity_level(level).map(|()| 0))) }
}

/// rsmodbus extension (server): writes `nb` registers from `src` (zeros when `src`
/// is NULL) into file `file` (1 to 65535) from record `record` (0 to 9999) of the
/// records function codes 14 and 15 serve. The file is created, or grown to
/// `record + nb` records (at most 10000), as needed. Returns `nb`; EINVAL for a bad
/// argument.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` NULL or valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_file_record(
    ctx: *mut Modbus,
    file: c_int,
    record: c_int,
    nb: c_int,
    src: *const u16,
) -> c_int {
    if nb < 1 {
        return fail(Error::INVALID);
    }
    // SAFETY: `nb` readable values per the caller.
    let values = (!src.is_null()).then(|| unsafe { slice::from_raw_parts(src, nb as usize) });
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| configure(g, |e| e.set_file_record(file, record, nb, values).map(|()| nb))) }
}

/// rsmodbus extension (server): copies `nb` registers of file `file` from record
/// `record` into `dest` (what clients wrote with function code 15, for example).
/// Returns `nb`; EINVAL when the file does not hold them.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_file_record(
    ctx: *mut Modbus,
    file: c_int,
    record: c_int,
    nb: c_int,
    dest: *mut u16,
) -> c_int {
    if dest.is_null() || nb < 1 {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let ext = g.server_ext.as_deref().ok_or(Error::INVALID)?;
            // SAFETY: `dest` holds `nb` values per the caller.
            let dest = slice::from_raw_parts_mut(dest, nb as usize);
            ext.get_file_record(file, record, dest).map(|()| nb)
        })
    }
}

/// rsmodbus extension (server): the FIFO queue function code 18 reads at pointer
/// address `addr` (0 to 65535): a copy of the `count` values at `values` (count 0
/// to 65535; `values` may be NULL when `count` is 0). A read of a queue of more
/// than 31 values gets ILLEGAL DATA VALUE, as the protocol says. Returns 0; EINVAL
/// for a bad argument.
///
/// # Safety
/// `ctx` must be NULL or a live context; `values` valid for `count` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_fifo_queue(
    ctx: *mut Modbus,
    addr: c_int,
    values: *const u16,
    count: c_int,
) -> c_int {
    if count < 0 || (count > 0 && values.is_null()) {
        return fail(Error::INVALID);
    }
    // SAFETY: `count` readable values per the caller.
    let values = if count > 0 { unsafe { slice::from_raw_parts(values, count as usize) } } else { &[] };
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| configure(g, |e| e.set_fifo_queue(addr, values).map(|()| 0))) }
}

/// rsmodbus extension (server): what function code 11 (report slave id) answers:
/// the byte `slave_id` (0 to 255), the run indicator (0xFF when `run_status` is
/// not 0, else 0x00) and the `length` bytes at `data` (0 to 249). A `slave_id` of
/// -1 restores libmodbus's answer ("LMB" and the version). Returns 0; EINVAL for a
/// bad argument.
///
/// # Safety
/// `ctx` must be NULL or a live context; `data` valid for `length` bytes (or NULL
/// when `length` is 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_report_slave_id(
    ctx: *mut Modbus,
    slave_id: c_int,
    run_status: c_int,
    data: *const u8,
    length: c_int,
) -> c_int {
    if !(-1..=0xFF).contains(&slave_id) || length < 0 || (length > 0 && data.is_null()) {
        return fail(Error::INVALID);
    }
    // SAFETY: `length` readable bytes per the caller.
    let data = if length > 0 { unsafe { slice::from_raw_parts(data, length as usize) } } else { &[] };
    let answer = (slave_id >= 0).then_some((slave_id as u8, run_status != 0, data));
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| configure(g, |e| e.set_report_slave_id(answer).map(|()| 0))) }
}
