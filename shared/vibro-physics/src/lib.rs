//! # vibro-physics
//!
//! The physics core of vibrocomp: the conversion function (FP) of a pendulous
//! navigation accelerometer, its main error, its vibration error (VE) as published in
//! the source papers and exactly, the in-flight compensation algorithm, and the
//! requirements on the passport coefficients. No I/O, no IPC, no allocation in the
//! per-sample paths.
//!
//! ```
//! use vibro_physics::{passport::{Passport, PassportSpec}, vibration::Vibration, ve};
//! let spec = PassportSpec {
//!     id: "AL-15".into(), a0_g: 3.324e-3, k1: 1.0, k1_v_per_g: -1.6698,
//!     d1a_ppm: 15.0, k2_ppm_per_g: 105.0, k3_ppm_per_g2: 87.0, k4_ppm_per_g3: 10.0,
//!     k5_ppm_per_g4: 0.9, m1_ppm: 1150.0, m2_ppm: 1150.0, m31_ppm_per_g: 11.6,
//!     m32_ppm_per_g: 11.6, lambda: vec![],
//! };
//! let p = Passport::try_from_spec(&spec).unwrap();
//! // [P1 Table 4]: aB3 = 0.42 g, aB1 = aB2 = 0.8 g, aL3 = 10 g.

//! ```
//!
//! References: MODEL.md (equation numbers `[P1 (n)]`, `[P2 (n)]` are the papers').

// Index loops mirror the formulas' subscripts (a_ij, K_3j) and read better here.
#![allow(clippy::needless_range_loop)]

pub mod abs_mean;
pub mod compensation;
pub mod exact;
pub mod fp;
pub mod montecarlo;
pub mod passport;
pub mod report;
pub mod requirements;
pub mod triad;
pub mod ve;
pub mod vibration;

#[cfg(test)]
pub(crate) mod testutil;

/// Errors of the physics core. Messages carry the offending values.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum Error {
    #[error("invalid passport: {}", problems.join("; "))]
    InvalidPassport { problems: Vec<String> },
    #[error("invalid triad: {0}")]
    InvalidTriad(String),
    #[error("invalid vibration: {0}")]
    InvalidVibration(String),
    #[error("invalid argument {name} = {value}: {rule}")]
    InvalidArgument {
        name: &'static str,
        value: f64,
        rule: &'static str,
    },
}

/// Result of the physics core.
pub type Result<T> = std::result::Result<T, Error>;
