//! One module per command.

pub mod archive;
pub mod bridge;
pub mod demo;
pub mod estimate;
pub mod identify;
pub mod identify_measure;
pub mod lab;
pub mod lab_log;
pub mod lab_wave;
pub mod latency;
pub mod log;
pub mod model;
pub mod model_flight;
pub mod record;
pub mod replay;
pub mod require;
pub mod service;
pub mod sim;
pub mod up;
pub mod view;
