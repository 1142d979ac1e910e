//! modbus.h: context life cycle and configuration.

use std::ffi::{c_char, c_int, c_uint};

use crate::context::{Context, Timeout};
use crate::error::{Error, strerror_modbus_c};
use crate::ffi::{Modbus, fail, with_ctx};
use crate::handle;

/// Frees a context. NULL is a no-op. The connection is not closed (call
/// `modbus_close` first), as in libmodbus, unless a call is inside the context (a
/// signal handler interrupted it, or another thread waits in it): then the context
/// is closed first, the call fails with EBADF, and the memory is freed when the call
/// has unwound.
///
/// # Safety
/// `ctx` must be NULL or a live context; it must not be used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_free(ctx: *mut Modbus) {
    // SAFETY: the caller hands back ownership of a context made by `into_handle`;
    // what the event-driven client has pending completes (EIDRM) first.
    unsafe {
        crate::ffi::event::cancel_pending(ctx);
        if let Some(m) = crate::api::Modbus::from_raw(ctx) {
            m.free();
        }
    }
}

/// Opens the serial line or TCP connection.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_connect(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| crate::session::connect(g).map(|()| 0)) }
}

/// Closes the connection. NULL is a no-op. Never waits for a call that waits on the
/// line: from a signal handler that interrupted a call on this context, or from
/// another thread while a call waits, the line is closed at once and that call fails
/// with EBADF. Never runs a callback: the event-driven client's pending requests
/// complete with ESHUTDOWN on the loop's thread (`modbus_process`, `modbus_free`).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_close(ctx: *mut Modbus) {
    // SAFETY: forwarded caller contract. What the event-driven client has pending
    // completes later, on the loop's thread (ESHUTDOWN): no callback runs here.
    unsafe { handle::close(ctx) }
}

/// Discards pending input. Returns the bytes discarded (TCP) or 0 (RTU).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_flush(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| crate::session::flush(g).map(|n| n as c_int)) }
}

/// Sets the slave (unit) id used for requests: 0..247 (0..255 with
/// `MODBUS_QUIRK_MAX_SLAVE`), or 0xFF on TCP.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_slave(ctx: *mut Modbus, slave: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| g.set_slave(slave).map(|()| 0)) }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_slave(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| Ok(g.session.slave)) }
}

/// The C enum `modbus_error_recovery_mode` (a bit set: NONE 0, LINK 2, PROTOCOL 4), as
/// passed by value. Declared by hand in modbus.h, so cbindgen only uses its name.
#[allow(non_camel_case_types)]
pub type modbus_error_recovery_mode = c_uint;

/// Stores the recovery mode bits (not validated, as in libmodbus).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_error_recovery(
    ctx: *mut Modbus,
    error_recovery: modbus_error_recovery_mode,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.session.recovery = error_recovery as u8 as i32;
            Ok(0)
        })
    }
}

/// rsmodbus extension: the error recovery mode of `ctx`, as `modbus_set_error_recovery`
/// left it: 0 (`MODBUS_ERROR_RECOVERY_NONE`) or the OR of `MODBUS_ERROR_RECOVERY_LINK`
/// and `MODBUS_ERROR_RECOVERY_PROTOCOL`. Like libmodbus, the context keeps the low 8
/// bits of the value set. -1 with EINVAL when `ctx` is NULL.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_error_recovery(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| Ok(g.session.recovery)) }
}

/// Uses `s` as the context's socket or serial descriptor (not validated).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_socket(ctx: *mut Modbus, s: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.set_descriptor(s);
            g.rx.clear();
            Ok(0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_socket(ctx: *mut Modbus) -> c_int {
    // SAFETY: `ctx` is NULL or live per the caller.
    match unsafe { ctx.as_ref() } {
        Some(handle) => handle.socket(),
        None => fail(Error::INVALID),
    }
}

/// Writes a timeout to the caller's pointers (NULL pointers are skipped; libmodbus
/// would crash on them).
///
/// # Safety
/// Each pointer must be NULL or valid for a `u32` write.
unsafe fn put_timeout(t: Timeout, to_sec: *mut u32, to_usec: *mut u32) {
    // SAFETY: guaranteed by the caller.
    unsafe {
        if let Some(s) = to_sec.as_mut() {
            *s = t.sec;
        }
        if let Some(u) = to_usec.as_mut() {
            *u = t.usec;
        }
    }
}

/// # Safety
/// `ctx` must be NULL or a live context; the pointers NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_response_timeout(ctx: *mut Modbus, to_sec: *mut u32, to_usec: *mut u32) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            put_timeout(g.session.timeouts.response, to_sec, to_usec);
            Ok(0)
        })
    }
}

/// Sets the response timeout; (0, 0) and `to_usec > 999999` give EINVAL.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_response_timeout(ctx: *mut Modbus, to_sec: u32, to_usec: u32) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| g.set_response_timeout(to_sec, to_usec).map(|()| 0)) }
}

/// # Safety
/// `ctx` must be NULL or a live context; the pointers NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_byte_timeout(ctx: *mut Modbus, to_sec: *mut u32, to_usec: *mut u32) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            put_timeout(g.session.timeouts.byte, to_sec, to_usec);
            Ok(0)
        })
    }
}

/// Sets the byte timeout; (0, 0) disables it.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_byte_timeout(ctx: *mut Modbus, to_sec: u32, to_usec: u32) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.session.timeouts.byte = Context::checked_timeout(to_sec, to_usec)?;
            Ok(0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context; the pointers NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_indication_timeout(ctx: *mut Modbus, to_sec: *mut u32, to_usec: *mut u32) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            put_timeout(g.session.timeouts.indication, to_sec, to_usec);
            Ok(0)
        })
    }
}

/// Sets the indication timeout of a server; (0, 0) waits forever.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_indication_timeout(ctx: *mut Modbus, to_sec: u32, to_usec: u32) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.session.timeouts.indication = Context::checked_timeout(to_sec, to_usec)?;
            Ok(0)
        })
    }
}

/// 1 for RTU, 7 for TCP.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_header_length(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| Ok(g.framing().header_length() as c_int)) }
}

/// rsmodbus extension: the length of the checksum that ends the messages this
/// library hands over and takes (`modbus_receive`, `modbus_receive_confirmation`,
/// the raw calls): 2 for RTU (and RTU over TCP), 1 for ASCII (its LRC, the frame
/// decoded), 0 for TCP, UDP and Modbus/TCP Security. With
/// `modbus_get_header_length`, what to cut off a message to get its PDU. -1 with
/// EINVAL when `ctx` is NULL.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_checksum_length(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| Ok(g.framing().checksum_length() as c_int)) }
}

/// Any non-zero flag turns the debug trace on (stdout and stderr).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_debug(ctx: *mut Modbus, flag: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.debug = flag != 0;
            Ok(0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_enable_quirks(ctx: *mut Modbus, quirks_mask: c_uint) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.quirks |= quirks_mask;
            Ok(0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_disable_quirks(ctx: *mut Modbus, quirks_mask: c_uint) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.quirks &= !quirks_mask;
            Ok(0)
        })
    }
}

/// The text of a libmodbus error code, or the C library's `strerror` for others.
#[unsafe(no_mangle)]
pub extern "C" fn modbus_strerror(errnum: c_int) -> *const c_char {
    match strerror_modbus_c(errnum) {
        Some(s) => s.as_ptr(),
        // SAFETY: strerror accepts any number and returns a C string.
        None => unsafe { libc::strerror(errnum) },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::context::{RECOVERY_LINK, RECOVERY_PROTOCOL};

    #[test]
    fn error_recovery_reads_back_as_set() {
        // SAFETY: the context is made here, used only here and freed once; NULL is a
        // valid argument.
        unsafe {
            let ctx = crate::ffi::tcp::modbus_new_tcp(c"127.0.0.1".as_ptr(), 1502);
            assert!(!ctx.is_null());
            assert_eq!(modbus_get_error_recovery(ctx), 0);
            let both = (RECOVERY_LINK | RECOVERY_PROTOCOL) as modbus_error_recovery_mode;
            assert_eq!(modbus_set_error_recovery(ctx, both), 0);
            assert_eq!(modbus_get_error_recovery(ctx), 6);
            // The low 8 bits are kept, as libmodbus keeps them.
            assert_eq!(modbus_set_error_recovery(ctx, 0x0104), 0);
            assert_eq!(modbus_get_error_recovery(ctx), RECOVERY_PROTOCOL);
            modbus_free(ctx);
            assert_eq!(modbus_get_error_recovery(std::ptr::null_mut()), -1);
            assert_eq!(crate::transport::errno(), libc::EINVAL);
        }
    }
}
