#![no_main]
//! `vibro_fuzz::stream_sequence`: what it feeds and checks is documented there.

libfuzzer_sys::fuzz_target!(|data: &[u8]| vibro_fuzz::stream_sequence(data));
