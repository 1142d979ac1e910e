//! libFuzzer target `authorization`: see `rsmodbus_fuzz::authorization` for the input
//! layout and the properties checked.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| rsmodbus_fuzz::authorization(data));
