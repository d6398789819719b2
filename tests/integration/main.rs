//! Integration tests of vibrocomp: one binary, a module per topic.

mod bad_input;
mod common;
mod estimate;
mod faults;
mod identify;
mod lab;
mod latency;
mod log;
mod model;
mod processes;
mod python_client;
mod replay;
mod sim;
