//! Wire types (skeleton; being written).
