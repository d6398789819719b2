//! Integration tests of vibrocomp: one binary, a module per topic.

mod bad_input;
mod closed_pipe;
mod common;
mod estimate;
mod extreme_lab;
mod faults;
mod file_safety;
mod identify;
mod lab;
mod latency;
mod log;
mod model;
mod processes;
mod python_client;
mod replay;
mod sim;
