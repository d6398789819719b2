//! Vibration estimation (being built).
