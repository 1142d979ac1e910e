//! The rsmodbus extensions of a server (modbus.h, extensions section): the
//! diagnostics counters and event log, and what function codes 07, 11, 14/15, 18 and
//! 2B/0E answer. An unconfigured server answers as libmodbus does.

use std::ffi::{CStr, c_char, c_int};
use std::slice;

use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::ffi::{Modbus, fail, with_ctx};
use crate::proto::diagnostics::Diagnostics;
use crate::server_ext::ServerExt;

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
