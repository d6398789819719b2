//! Integration tests of vibrocomp: one binary, a module per topic.

mod common;
mod estimate;
mod identify;
mod model;
mod sim;
