#![no_main]
//! `vibro_fuzz::mcap_recover`: what it feeds and checks is documented there.

libfuzzer_sys::fuzz_target!(|data: &[u8]| vibro_fuzz::mcap_recover(data));
