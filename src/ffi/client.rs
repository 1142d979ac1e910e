//! modbus.h: client calls. Argument checks and their order follow libmodbus 3.1.12;
//! NULL buffers that libmodbus would dereference give EINVAL here instead.

use std::ffi::c_int;
use std::slice;

use crate::engine::{self, AduBuf, Guard};
use crate::error::{Error, Result};
use crate::ffi::{Modbus, with_ctx};
use crate::proto::data::registers_from_be;
use crate::proto::fc;
use crate::proto::frame::MsgKind;
use crate::proto::limits::{MAX_PDU_LENGTH, MAX_READ_BITS, MAX_READ_REGISTERS};
use crate::proto::request::{Request, check_read_count, check_write_and_read_counts, check_write_count};
use crate::session::Received;

/// The request of a read of bits (FC 01, 02), its count checked as libmodbus checks it:
/// the blocking call's and its `_async` form's.
pub fn read_bits_request(g: &Guard<'_>, function: u8, addr: c_int, nb: c_int) -> Result<Request<'static>> {
    let what = if function == fc::READ_COILS { "bits" } else { "discrete inputs" };
    check_read_count(nb, MAX_READ_BITS, what, &mut g.diag())?;
    Ok(Request::ReadBits { function, addr, nb })
}

/// The request of a read of registers (FC 03, 04), its count checked (see
/// [`read_bits_request`]).
pub fn read_registers_request(g: &Guard<'_>, function: u8, addr: c_int, nb: c_int) -> Result<Request<'static>> {
    let what = if function == fc::READ_HOLDING_REGISTERS { "registers" } else { "input registers" };
    check_read_count(nb, MAX_READ_REGISTERS, what, &mut g.diag())?;
    Ok(Request::ReadRegisters { function, addr, nb })
}

/// The request of a write of `nb` coils from `src` (FC 0F), its count checked.
///
/// # Safety
/// `src` is non-NULL and valid for `nb` bytes for `'a` (when the count is valid).
pub unsafe fn write_bits_request<'a>(g: &Guard<'_>, addr: c_int, nb: c_int, src: *const u8) -> Result<Request<'a>> {
    check_write_count(fc::WRITE_MULTIPLE_COILS, nb, &mut g.diag())?;
    // SAFETY: `src` holds `nb` (1..=1968, checked) bytes per the contract.
    Ok(Request::WriteBits { addr, bits: unsafe { slice::from_raw_parts(src, nb as usize) } })
}

/// The request of a write of `nb` registers from `src` (FC 10), its count checked.
///
/// # Safety
/// `src` is non-NULL and valid for `nb` values for `'a` (when the count is valid).
pub unsafe fn write_registers_request<'a>(
    g: &Guard<'_>,
    addr: c_int,
    nb: c_int,
    src: *const u16,
) -> Result<Request<'a>> {
    check_write_count(fc::WRITE_MULTIPLE_REGISTERS, nb, &mut g.diag())?;
    // SAFETY: `src` holds `nb` (1..=123, checked) values per the contract.
    Ok(Request::WriteRegisters { addr, values: unsafe { slice::from_raw_parts(src, nb as usize) } })
}

/// Sends a read of bits and unpacks `nb` of them into `dest`, LSB first.
fn read_bits(g: &mut Guard<'_>, function: u8, addr: c_int, nb: c_int, dest: *mut u8) -> Result<c_int> {
    let req = read_bits_request(g, function, addr, nb)?;
    let mut rsp = g.spare.take();
    let done = engine::exchange(g, &req, &mut rsp);
    if let Ok(done) = &done {
        let h = g.framing().header_length();
        let packed = crate::proto::decode::counted_data(&rsp[h..], done.count as usize);
        // SAFETY: the caller provides `nb` writable bytes at `dest` (checked non-NULL).
        let dest = unsafe { slice::from_raw_parts_mut(dest, nb as usize) };
        crate::proto::data::set_bits_from_bytes(dest, packed);
    }
    g.spare.give(rsp);
    done.map(|_| nb)
}

/// Sends a read of registers and stores the values (host order) into `dest`.
fn read_registers(g: &mut Guard<'_>, function: u8, addr: c_int, nb: c_int, dest: *mut u16) -> Result<c_int> {
    let req = read_registers_request(g, function, addr, nb)?;
    let mut rsp = g.spare.take();
    let done = engine::exchange(g, &req, &mut rsp);
    if let Ok(done) = &done {
        store_registers(g, &rsp, done.count, dest);
    }
    g.spare.give(rsp);
    done.map(|done| done.count)
}

/// Copies `count` big-endian registers from a read response into `dest`.
fn store_registers(g: &Guard<'_>, rsp: &AduBuf, count: c_int, dest: *mut u16) {
    let h = g.framing().header_length();
    let data = crate::proto::decode::counted_data(&rsp[h..], 2 * count as usize);
    // SAFETY: the response count was checked to equal the requested count, for which
    // the caller provides room at `dest` (checked non-NULL).
    let dest = unsafe { slice::from_raw_parts_mut(dest, count as usize) };
    registers_from_be(data, dest);
}

/// Reads `nb` coils (FC 01) into `dest` (one byte per coil, 0 or 1). Returns `nb`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `nb` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_bits(ctx: *mut Modbus, addr: c_int, nb: c_int, dest: *mut u8) -> c_int {
    if dest.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| read_bits(g, fc::READ_COILS, addr, nb, dest)) }
}

/// Reads `nb` discrete inputs (FC 02) into `dest`. Returns `nb`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `nb` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_input_bits(ctx: *mut Modbus, addr: c_int, nb: c_int, dest: *mut u8) -> c_int {
    if dest.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| read_bits(g, fc::READ_DISCRETE_INPUTS, addr, nb, dest)) }
}

/// Reads `nb` holding registers (FC 03). Returns the number read.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_registers(ctx: *mut Modbus, addr: c_int, nb: c_int, dest: *mut u16) -> c_int {
    if dest.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| read_registers(g, fc::READ_HOLDING_REGISTERS, addr, nb, dest)) }
}

/// Reads `nb` input registers (FC 04). Returns the number read.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_input_registers(
    ctx: *mut Modbus,
    addr: c_int,
    nb: c_int,
    dest: *mut u16,
) -> c_int {
    if dest.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| read_registers(g, fc::READ_INPUT_REGISTERS, addr, nb, dest)) }
}

/// Writes one coil (FC 05): any non-zero `status` is ON. Returns 1.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_bit(ctx: *mut Modbus, coil_addr: c_int, status: c_int) -> c_int {
    let req = Request::WriteBit { addr: coil_addr, on: status != 0 };
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| exchange_count(g, &req)) }
}

/// Writes one holding register (FC 06). Returns 1.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_register(ctx: *mut Modbus, reg_addr: c_int, value: u16) -> c_int {
    let req = Request::WriteRegister { addr: reg_addr, value };
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| exchange_count(g, &req)) }
}

fn exchange_count(g: &mut Guard<'_>, req: &Request<'_>) -> Result<c_int> {
    let mut rsp = g.spare.take();
    let done = engine::exchange(g, req, &mut rsp);
    g.spare.give(rsp);
    done.map(|done| done.count)
}

/// Writes `nb` coils (FC 0F) from `data` (one byte per coil). Returns the count the
/// server confirmed.
///
/// # Safety
/// `ctx` must be NULL or a live context; `data` NULL or valid for `nb` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_bits(ctx: *mut Modbus, addr: c_int, nb: c_int, data: *const u8) -> c_int {
    if data.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            // SAFETY: `data` is non-NULL and holds `nb` bytes per the contract.
            let req = write_bits_request(g, addr, nb, data)?;
            exchange_count(g, &req)
        })
    }
}

/// Writes `nb` holding registers (FC 10) from `data`. Returns the count the server
/// confirmed.
///
/// # Safety
/// `ctx` must be NULL or a live context; `data` NULL or valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_registers(ctx: *mut Modbus, addr: c_int, nb: c_int, data: *const u16) -> c_int {
    if data.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            // SAFETY: `data` is non-NULL and holds `nb` values per the contract.
            let req = write_registers_request(g, addr, nb, data)?;
            exchange_count(g, &req)
        })
    }
}

/// Sets a register to `(current & and_mask) | (or_mask & ~and_mask)` (FC 16).
/// Returns 1.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_mask_write_register(
    ctx: *mut Modbus,
    addr: c_int,
    and_mask: u16,
    or_mask: u16,
) -> c_int {
    let req = Request::MaskWriteRegister { addr, and_mask, or_mask };
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| exchange_count(g, &req)) }
}

/// Writes `write_nb` registers then reads `read_nb` (FC 17). Returns the number read.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` valid for `write_nb` values and `dest`
/// for `read_nb` values when those counts are positive.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_and_read_registers(
    ctx: *mut Modbus,
    write_addr: c_int,
    write_nb: c_int,
    src: *const u16,
    read_addr: c_int,
    read_nb: c_int,
    dest: *mut u16,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let req = write_and_read_request(g, write_addr, write_nb, src, read_addr, read_nb, dest)?;
            let mut rsp = g.spare.take();
            let done = engine::exchange(g, &req, &mut rsp);
            if let Ok(done) = &done {
                if done.count > 0 {
                    store_registers(g, &rsp, done.count, dest);
                }
            }
            g.spare.give(rsp);
            done.map(|done| done.count)
        })
    }
}

/// The request of `modbus_write_and_read_registers[_async]`, its arguments checked
/// as libmodbus checks them.
///
/// # Safety
/// `src` valid for `write_nb` values (when positive) for `'a`.
pub unsafe fn write_and_read_request<'a>(
    g: &mut Guard<'_>,
    write_addr: c_int,
    write_nb: c_int,
    src: *const u16,
    read_addr: c_int,
    read_nb: c_int,
    dest: *mut u16,
) -> Result<Request<'a>> {
    check_write_and_read_counts(write_nb, read_nb, &mut g.diag())?;
    if (write_nb > 0 && src.is_null()) || (read_nb > 0 && dest.is_null()) {
        return Err(Error::INVALID);
    }
    let values: &[u16] = if write_nb > 0 {
        // SAFETY: `src` is non-NULL and holds `write_nb` (<= 121) values (contract).
        unsafe { slice::from_raw_parts(src, write_nb as usize) }
    } else {
        &[]
    };
    Ok(Request::WriteAndReadRegisters { write_addr, write_nb, values, read_addr, read_nb })
}

/// Asks the server for its id (FC 11). Copies at most `max_dest` bytes of the
/// answer (after its byte count) into `dest`; returns the byte count the server sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` NULL or valid for `max_dest` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_report_slave_id(ctx: *mut Modbus, max_dest: c_int, dest: *mut u8) -> c_int {
    if max_dest <= 0 || dest.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let mut rsp = AduBuf::new();
            let done = engine::exchange(g, &Request::ReportSlaveId, &mut rsp)?;
            let h = g.framing().header_length();
            let n = (done.count as usize).min(max_dest as usize);
            // SAFETY: `dest` is non-NULL and holds `max_dest` >= n bytes.
            let dest = slice::from_raw_parts_mut(dest, n);
            dest.copy_from_slice(crate::proto::decode::counted_data(&rsp[h..], n));
            Ok(done.count)
        })
    }
}

/// # Safety
/// `ctx` must be NULL or a live context; `raw_req` NULL or valid for
/// `raw_req_length` bytes.
unsafe fn raw_request(ctx: *mut Modbus, raw_req: *const u8, raw_req_length: c_int, tid: u16) -> c_int {
    if ctx.is_null() || raw_req.is_null() || !(2..=MAX_PDU_LENGTH as c_int + 1).contains(&raw_req_length) {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: `raw_req` is non-NULL and holds `raw_req_length` bytes, and `ctx` is live
    // (caller contract).
    unsafe {
        let raw = slice::from_raw_parts(raw_req, raw_req_length as usize);
        with_ctx(ctx, |g| engine::send_raw(g, raw, tid).map(|n| n as c_int))
    }
}

/// Sends `raw_req` (unit id, then the PDU) with transaction id 0 (TCP). Returns
/// the ADU length sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; `raw_req` valid for `raw_req_length` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_send_raw_request(ctx: *mut Modbus, raw_req: *const u8, raw_req_length: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { raw_request(ctx, raw_req, raw_req_length, 0) }
}

/// Like `modbus_send_raw_request` with the given transaction id (TCP).
///
/// # Safety
/// `ctx` must be NULL or a live context; `raw_req` valid for `raw_req_length` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_send_raw_request_tid(
    ctx: *mut Modbus,
    raw_req: *const u8,
    raw_req_length: c_int,
    tid: c_int,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { raw_request(ctx, raw_req, raw_req_length, tid as u16) }
}

/// Receives one response into `rsp` without checking it against a request.
/// Returns its length (0 for an RTU frame addressed to another slave).
///
/// # Safety
/// `ctx` must be NULL or a live context; `rsp` NULL or valid for
/// `MODBUS_MAX_ADU_LENGTH` bytes (only the received message is written).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_receive_confirmation(ctx: *mut Modbus, rsp: *mut u8) -> c_int {
    if rsp.is_null() {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let mut buf = AduBuf::new();
            let (len, rc) = match engine::receive_msg(g, &mut buf.room(), MsgKind::Confirmation)? {
                Received::Frame(len) => (len, len),
                Received::Ignored(len) => (len, 0),
            };
            // SAFETY: `rsp` is non-NULL with room for a whole ADU; len <= that.
            slice::from_raw_parts_mut(rsp, len).copy_from_slice(&buf[..len]);
            Ok(rc as c_int)
        })
    }
}
