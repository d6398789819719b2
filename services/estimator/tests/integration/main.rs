//! Integration tests of the estimator service: one binary, a module per topic. Each
//! test uses its own service-name prefix (`vct-est-<pid>-<n>/`) and releases its ports
//! by dropping them.

// Per-axis and per-unit index loops mirror the formulas' subscripts (and index several
// arrays at once); iterator chains would hide the indices.
#![allow(clippy::needless_range_loop)]

mod bad_input;
mod in_process;
mod process;
mod support;
