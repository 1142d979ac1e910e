//! modbus-rtu.h: serial contexts, RS-485 and RTS control.

use std::ffi::{c_char, c_int};

use crate::context::RtsHook;
use crate::context::{Context, RTU_RTS_DOWN, RTU_RTS_NONE, RTU_RTS_UP};
use crate::engine::{self, Guard};
use crate::error::{Error, Result};
use crate::ffi::{Modbus, into_handle, opt_cstr, with_ctx};
use crate::transport::rtu;
use std::sync::Arc;

/// Creates an RTU context for `device` ("/dev/ttyS0"...). `parity` is 'N', 'E' or
/// 'O'. Returns NULL with EINVAL on a NULL/empty device, a zero baud rate or another
/// parity.
///
/// # Safety
/// `device` must be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_rtu(
    device: *const c_char,
    baud: c_int,
    parity: c_char,
    data_bit: c_int,
    stop_bit: c_int,
) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let device = unsafe { opt_cstr(device) };
    into_handle(Context::new_rtu(device, baud, parity as u8, data_bit, stop_bit))
}

/// rsmodbus extension: a Modbus ASCII context on a serial line: frames are ':',
/// hexadecimal digits, an LRC and CR LF. Same arguments and checks as
/// `modbus_new_rtu`; 7 or 8 data bits. The byte timeout defaults to 1 s, the gap
/// ASCII allows between characters. The RTU serial functions (RS-485, RTS) apply.
///
/// # Safety
/// `device` must be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_ascii(
    device: *const c_char,
    baud: c_int,
    parity: c_char,
    data_bit: c_int,
    stop_bit: c_int,
) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let device = unsafe { opt_cstr(device) };
    into_handle(Context::new_ascii(device, baud, parity as u8, data_bit, stop_bit))
}

/// Runs `f` on an RTU context; other backends give EINVAL.
///
/// # Safety
/// `ctx` must be NULL or a live context.
unsafe fn with_rtu(ctx: *mut Modbus, f: impl FnOnce(&mut Guard<'_>) -> Result<c_int>) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            if g.rtu().is_none() {
                return Err(Error::INVALID);
            }
            f(g)
        })
    }
}

/// Switches the line between RS-232 (0) and RS-485 (1) with `TIOCSRS485`. Must be
/// called after `modbus_connect` (EBADF before); most USB adapters and ptys answer
/// ENOTTY.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_set_serial_mode(ctx: *mut Modbus, mode: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_rtu(ctx, |g| {
            let fd = g.fd();
            let Some(link) = g.rtu_mut() else { return Err(Error::INVALID) };
            rtu::set_serial_mode(fd, link, mode).map(|()| 0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_get_serial_mode(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_rtu(ctx, |g| Ok(g.rtu().map_or(0, |l| l.serial_mode))) }
}

/// Sets the RTS mode (NONE, UP, DOWN) and puts the line in its idle state at once.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_set_rts(ctx: *mut Modbus, mode: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_rtu(ctx, |g| {
            if !matches!(mode, RTU_RTS_NONE | RTU_RTS_UP | RTU_RTS_DOWN) {
                return Err(Error::INVALID);
            }
            if let Some(l) = g.rtu_mut() {
                l.rts = mode;
            }
            engine::set_rts(g, mode != RTU_RTS_UP);
            Ok(0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_get_rts(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_rtu(ctx, |g| Ok(g.rtu().map_or(0, |l| l.rts))) }
}

/// Replaces the built-in RTS ioctl with the application's function (NULL restores
/// the built-in one). The function is called with the context unlocked.
///
/// # Safety
/// `ctx` must be NULL or a live context; `set_rts` NULL or a function safe to call
/// with this context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_set_custom_rts(
    ctx: *mut Modbus,
    set_rts: Option<unsafe extern "C" fn(ctx: *mut Modbus, on: c_int)>,
) -> c_int {
    // The handle's address: a plain number, so that the hook may cross threads.
    let handle = ctx as usize;
    let hook = set_rts.map(|f| -> RtsHook {
        // SAFETY: the application registered `f` for this context and it receives
        // the context pointer it was registered on, as in libmodbus.
        Arc::new(move |on: bool| unsafe { f(handle as *mut Modbus, on as c_int) })
    });
    // SAFETY: forwarded caller contract.
    unsafe {
        with_rtu(ctx, |g| {
            if let Some(l) = g.rtu_mut() {
                l.custom_rts = hook;
            }
            Ok(0)
        })
    }
}

/// Delay in microseconds around a transmission with RTS; negative gives EINVAL.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_set_rts_delay(ctx: *mut Modbus, us: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_rtu(ctx, |g| {
            if us < 0 {
                return Err(Error::INVALID);
            }
            if let Some(l) = g.rtu_mut() {
                l.rts_delay = us;
            }
            Ok(0)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_rtu_get_rts_delay(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_rtu(ctx, |g| Ok(g.rtu().map_or(0, |l| l.rts_delay))) }
}
