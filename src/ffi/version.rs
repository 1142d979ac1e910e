//! The version objects of libmodbus and this library's own version.

use std::ffi::{c_char, c_uint};

/// API level: libmodbus 3.1.12.
#[unsafe(no_mangle)]
pub static libmodbus_version_major: c_uint = 3;
#[unsafe(no_mangle)]
pub static libmodbus_version_minor: c_uint = 1;
#[unsafe(no_mangle)]
pub static libmodbus_version_micro: c_uint = 12;

/// The libmodbus version string this library implements (the report-slave-id
/// payload carries it after "LMB").
pub const LIBMODBUS_VERSION_STRING: &str = "3.1.12";

const RSMODBUS_VERSION: &std::ffi::CStr =
    match std::ffi::CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
        Ok(s) => s,
        Err(_) => panic!("package version contains a NUL byte"),
    };

/// rsmodbus extension: the version of this library (e.g. "0.1.0"). A program can
/// look this symbol up to tell rsmodbus from libmodbus at run time.
#[unsafe(no_mangle)]
pub extern "C" fn rsmodbus_version() -> *const c_char {
    RSMODBUS_VERSION.as_ptr()
}
