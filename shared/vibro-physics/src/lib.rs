//! Physics core (being built).
