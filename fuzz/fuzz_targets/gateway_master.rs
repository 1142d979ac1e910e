//! libFuzzer target `gateway_master`: see `rsmodbus_fuzz::gateway_master` for the
//! input and the properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::gateway_master(data));
