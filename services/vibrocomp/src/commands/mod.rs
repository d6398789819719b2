//! One module per command.

pub mod demo;
pub mod estimate;
pub mod identify;
pub mod model;
pub mod require;
pub mod sim;
