#![no_main]
//! `vibro_fuzz::config_parse`: what it feeds and checks is documented there.

libfuzzer_sys::fuzz_target!(|data: &[u8]| vibro_fuzz::config_parse(data));
