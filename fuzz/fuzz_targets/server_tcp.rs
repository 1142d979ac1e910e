//! libFuzzer target `server_tcp`: see `rsmodbus_fuzz::server_tcp` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::server_tcp(data));
