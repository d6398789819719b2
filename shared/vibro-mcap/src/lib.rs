//! MCAP codec (skeleton; being written).
