#![no_main]
//! See `povins_fuzz::ros_msgs`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| povins_fuzz::ros_msgs(data));
