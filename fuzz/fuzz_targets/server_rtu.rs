//! libFuzzer target `server_rtu`: see `rsmodbus_fuzz::server_rtu` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::server_rtu(data));
