//! libFuzzer target `server_ascii`: see `rsmodbus_fuzz::server_ascii` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::server_ascii(data));
