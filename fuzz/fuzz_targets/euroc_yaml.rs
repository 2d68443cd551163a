#![no_main]
//! See `povins_fuzz::euroc_yaml`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::euroc_yaml(data));
