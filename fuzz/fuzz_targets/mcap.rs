#![no_main]
//! See `povins_fuzz::mcap`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::mcap(data));
