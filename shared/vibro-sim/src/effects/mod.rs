//! The effects library (being written).
