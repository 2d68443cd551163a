#![no_main]
//! See `povins_fuzz::image`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::image(data));
