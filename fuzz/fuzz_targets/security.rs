//! libFuzzer target `security`: see `rsmodbus_fuzz::security` for the input layout and the
//! properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::security(data));
