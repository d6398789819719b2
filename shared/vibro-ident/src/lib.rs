//! Shake-table measurement and identification (being built).
