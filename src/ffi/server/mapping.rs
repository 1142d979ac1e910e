//! modbus.h: the data a server serves, `modbus_mapping_t`: its allocation, and the
//! adapter that lends its tables to the reply logic.

use std::ffi::{c_int, c_uint};
use std::mem::{offset_of, size_of};
use std::ptr;
use std::slice;

use crate::error::Error;
use crate::proto::reply::{Mapping, Table};

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
pub(super) struct CMapping(pub(super) *mut modbus_mapping_t);

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
    #[inline]
    fn fields(&self) -> Option<modbus_mapping_t> {
        // SAFETY: `self.0` is NULL or a live mapping (contract of modbus_reply); the
        // struct is plain data, copied out field by field.
        unsafe { self.0.as_ref() }.copied()
    }
}

// SAFETY (for every method): modbus_reply's contract makes each non-NULL table valid
// for its `nb` items; the trait lends one table at a time, so no two slices coexist.
impl Mapping for CMapping {
    #[inline]
    fn bits(&mut self) -> Table<'_, u8> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_bits, m.nb_bits, m.tab_bits) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    #[inline]
    fn input_bits(&mut self) -> Table<'_, u8> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_input_bits, m.nb_input_bits, m.tab_input_bits) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    #[inline]
    fn registers(&mut self) -> Table<'_, u16> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_registers, m.nb_registers, m.tab_registers) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    #[inline]
    fn input_registers(&mut self) -> Table<'_, u16> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_input_registers, m.nb_input_registers, m.tab_input_registers) },
            None => Table { start: 0, data: &mut [] },
        }
    }
}
