//! libFuzzer target `ffi_server`: see `rsmodbus_fuzz::ffi_server` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::ffi_server(data));
