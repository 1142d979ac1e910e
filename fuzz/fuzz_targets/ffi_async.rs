//! libFuzzer target `ffi_async`: see `rsmodbus_fuzz::ffi_async` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::ffi_async(data));
