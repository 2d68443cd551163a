#![no_main]
//! See `povins_fuzz::kalibr_yaml`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::kalibr_yaml(data));
