//! Integration tests of vibrocomp: one binary, a module per topic.

mod common;
mod identify;
mod model;
