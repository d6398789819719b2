//! Integration tests of vibrocomp: one binary, a module per topic.

mod bad_input;
mod bridge;
mod cli_flags;
mod closed_pipe;
mod common;
mod conventions;
mod counts;
mod estimate;
mod extreme_lab;
mod faults;
mod file_safety;
mod flag_rules;
mod identify;
mod interrupted;
mod lab;
mod lab_flight;
mod latency;
mod line_cap;
mod log;
mod model;
mod processes;
mod python_client;
mod replay;
mod shared_prefix;
mod sim;
mod soak;
