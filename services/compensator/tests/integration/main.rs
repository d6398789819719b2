//! Integration tests of the compensator service: one binary, a module per topic. Each
//! test uses its own service-name prefix (`vct-cmp-<pid>-<n>/`) and temporary
//! directory, and releases its ports by dropping them.

// Per-axis and per-unit index loops mirror the formulas' subscripts.
#![allow(clippy::needless_range_loop)]

mod bad_input;
mod extended_model;
mod faults;
mod in_process;
mod process;
mod reload;
mod support;
mod waveform_rig;
