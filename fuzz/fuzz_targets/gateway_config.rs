//! libFuzzer target `gateway_config`: see `rsmodbus_fuzz::gateway_config` for the
//! input and the properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::gateway_config(data));
