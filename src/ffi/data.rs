//! modbus.h: data helpers (bits in bytes, floats in two registers).

use std::ffi::{c_int, c_uint};
use std::slice;

use crate::proto::data::{self, FloatOrder};

/// Sets `dest[idx..idx + 8]` to the bits of `value`, LSB first.
///
/// # Safety
/// `dest + idx` must be valid for 8 bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_bits_from_byte(dest: *mut u8, idx: c_int, value: u8) {
    if dest.is_null() {
        return;
    }
    // SAFETY: guaranteed by the caller.
    let dest = unsafe { slice::from_raw_parts_mut(dest.offset(idx as isize), 8) };
    data::set_bits_from_byte(dest, value);
}

/// Unpacks `nb_bits` bits of `tab_byte` (LSB first) into `dest[idx..idx + nb_bits]`.
///
/// # Safety
/// `dest + idx` must be valid for `nb_bits` bytes and `tab_byte` for
/// `ceil(nb_bits / 8)` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_bits_from_bytes(dest: *mut u8, idx: c_int, nb_bits: c_uint, tab_byte: *const u8) {
    if dest.is_null() || tab_byte.is_null() || nb_bits == 0 {
        return;
    }
    // SAFETY: guaranteed by the caller.
    let (dest, packed) = unsafe {
        (
            slice::from_raw_parts_mut(dest.offset(idx as isize), nb_bits as usize),
            slice::from_raw_parts(tab_byte, (nb_bits as usize).div_ceil(8)),
        )
    };
    data::set_bits_from_bytes(dest, packed);
}

/// Packs `src[idx..idx + nb_bits]` (at most 8 values of 0 or 1) into a byte.
/// libmodbus aborts on more than 8; this library uses the first 8.
///
/// # Safety
/// `src + idx` must be valid for `min(nb_bits, 8)` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_byte_from_bits(src: *const u8, idx: c_int, nb_bits: c_uint) -> u8 {
    if src.is_null() {
        return 0;
    }
    // SAFETY: guaranteed by the caller.
    let src = unsafe { slice::from_raw_parts(src.offset(idx as isize), nb_bits.min(8) as usize) };
    data::byte_from_bits(src)
}

/// # Safety
/// `src` must be valid for two values.
unsafe fn regs(src: *const u16) -> [u16; 2] {
    // SAFETY: guaranteed by the caller.
    unsafe { [*src, *src.add(1)] }
}

/// # Safety
/// `dest` must be valid for two values.
unsafe fn put_regs(dest: *mut u16, r: [u16; 2]) {
    // SAFETY: guaranteed by the caller.
    unsafe {
        *dest = r[0];
        *dest.add(1) = r[1];
    }
}

macro_rules! float_doc {
    () => {
        "The float stored in `src[0..2]`; see the byte-order names in modbus_get_float_abcd(3)."
    };
}

/// Deprecated alias of `modbus_get_float_cdab`.
///
/// # Safety
/// `src` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_float(src: *const u16) -> f32 {
    // SAFETY: forwarded caller contract.
    data::get_float(unsafe { regs(src) }, FloatOrder::Cdab)
}

#[doc = float_doc!()]
///
/// # Safety
/// `src` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_float_abcd(src: *const u16) -> f32 {
    // SAFETY: forwarded caller contract.
    data::get_float(unsafe { regs(src) }, FloatOrder::Abcd)
}

#[doc = float_doc!()]
///
/// # Safety
/// `src` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_float_dcba(src: *const u16) -> f32 {
    // SAFETY: forwarded caller contract.
    data::get_float(unsafe { regs(src) }, FloatOrder::Dcba)
}

#[doc = float_doc!()]
///
/// # Safety
/// `src` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_float_badc(src: *const u16) -> f32 {
    // SAFETY: forwarded caller contract.
    data::get_float(unsafe { regs(src) }, FloatOrder::Badc)
}

#[doc = float_doc!()]
///
/// # Safety
/// `src` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_float_cdab(src: *const u16) -> f32 {
    // SAFETY: forwarded caller contract.
    data::get_float(unsafe { regs(src) }, FloatOrder::Cdab)
}

/// Deprecated alias of `modbus_set_float_cdab`.
///
/// # Safety
/// `dest` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_float(f: f32, dest: *mut u16) {
    // SAFETY: forwarded caller contract.
    unsafe { put_regs(dest, data::set_float(f, FloatOrder::Cdab)) }
}

/// Stores `f` in `dest[0..2]` with bytes A B C D (big-endian), 3.1.11+ semantics.
///
/// # Safety
/// `dest` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_float_abcd(f: f32, dest: *mut u16) {
    // SAFETY: forwarded caller contract.
    unsafe { put_regs(dest, data::set_float(f, FloatOrder::Abcd)) }
}

/// Stores `f` with bytes D C B A.
///
/// # Safety
/// `dest` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_float_dcba(f: f32, dest: *mut u16) {
    // SAFETY: forwarded caller contract.
    unsafe { put_regs(dest, data::set_float(f, FloatOrder::Dcba)) }
}

/// Stores `f` with bytes B A D C.
///
/// # Safety
/// `dest` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_float_badc(f: f32, dest: *mut u16) {
    // SAFETY: forwarded caller contract.
    unsafe { put_regs(dest, data::set_float(f, FloatOrder::Badc)) }
}

/// Stores `f` with bytes C D A B.
///
/// # Safety
/// `dest` must be valid for two values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_float_cdab(f: f32, dest: *mut u16) {
    // SAFETY: forwarded caller contract.
    unsafe { put_regs(dest, data::set_float(f, FloatOrder::Cdab)) }
}
