//! Rig simulator (skeleton; being written).

pub mod effect;
pub mod effects;
mod error;

pub use effect::{BlockCtx, Effect, MeanContext};
pub use error::{Error, Result};
