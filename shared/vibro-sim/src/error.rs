//! Errors of the simulator.

/// What can go wrong building or running a simulation.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scenario or effect parameter breaks its rule.
    #[error("{key} = {value}: {rule}")]
    Invalid {
        key: String,
        value: String,
        rule: String,
    },
    /// The physics core refused an input.
    #[error(transparent)]
    Physics(#[from] vibro_physics::Error),
}

/// Result of the simulator.
pub type Result<T> = std::result::Result<T, Error>;
