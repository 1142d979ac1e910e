//! modbus.h: `modbus_receive`, `modbus_reply` and `modbus_reply_exception`.

use std::ffi::{c_int, c_uint};
use std::slice;

use super::mapping::{CMapping, modbus_mapping_t};
use crate::error::Error;
use crate::ffi::{Modbus, fail, with_ctx};
use crate::proto::reply::{MappingData, request_extent};

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
            let caller = slice::from_raw_parts_mut(req, g.framing().max_adu_length());
            crate::server::receive(g, caller, None).map(|n| n as c_int)
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
            let extent = request_extent(g.framing(), g.session.extended, bound, |n| slice::from_raw_parts(req, n));
            // SAFETY: the same bytes, now as one slice.
            let req = slice::from_raw_parts(req, extent);
            let mut mapping = CMapping(mb_mapping);
            crate::server::reply(g, req, req_length, &mut MappingData(&mut mapping)).map(|n| n as c_int)
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
            let req = slice::from_raw_parts(req, g.framing().header_length() + 1);
            crate::server::reply_exception(g, req, exception_code).map(|n| n as c_int)
        })
    }
}
