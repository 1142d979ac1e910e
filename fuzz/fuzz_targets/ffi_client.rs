//! libFuzzer target `ffi_client`: see `rsmodbus_fuzz::ffi_client` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::ffi_client(data));
