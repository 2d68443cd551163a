#![no_main]
//! See `povins_fuzz::ouster_packets`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::ouster_packets(data));
