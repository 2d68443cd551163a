#![no_main]
//! See `povins_fuzz::config_toml`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::config_toml(data));
