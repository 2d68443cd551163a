#![no_main]
//! See `povins_fuzz::rosbag1`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::rosbag1(data));
