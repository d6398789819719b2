//! Integration tests of vibro-mcap: one binary, a module per topic. Files go to
//! `CARGO_TARGET_TMPDIR`, one directory per test.

mod common;
mod python;
mod recording;
mod recover;
