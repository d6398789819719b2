//! Checks of command-line values against the rules the files obey, every problem
//! named as `--flag = value: rule` and all of them reported at once (STYLE.md, Errors).
//!
//! Where a library exposes its rule (a scenario's length:
//! `vibro_sim::scenario::Rates::length_problem`), the commands call it; the rules below
//! are those the libraries apply inside their file validation without exposing them,
//! kept here in one place for every command.

use crate::output::fmt_num;
use std::fmt::Display;

/// A flight acceleration's bound, g: a scenario profile's `accel_g` rule
/// (shared/vibro-sim/src/scenario/validate.rs, `validate_flight`).
pub const ACCEL_LIMIT_G: f64 = 1000.0;
/// A vibration amplitude's bound, g: `Vibration::validate`'s tone rule
/// (shared/vibro-physics/src/vibration.rs), also a scenario's tone rule.
pub const AMPLITUDE_LIMIT_G: f64 = 1000.0;
/// A random vibration RMS's bound, g: `Vibration::validate`'s `sigma^2 <= 1e6 g^2`.
pub const SIGMA_LIMIT_G: f64 = 1000.0;

/// The problems of a command line's values.
#[derive(Debug, Default)]
pub struct FlagProblems(Vec<String>);

impl FlagProblems {
    pub fn new() -> Self {
        Self::default()
    }

    /// Records `--flag = value: rule` unless `ok`.
    pub fn check(&mut self, flag: &str, value: f64, ok: bool, rule: impl Display) {
        if !ok {
            self.push(flag, value, rule);
        }
    }

    pub fn push(&mut self, flag: &str, value: f64, rule: impl Display) {
        self.0.push(format!("{flag} = {}: {rule}", fmt_num(value)));
    }

    /// A flight acceleration: finite and within +-[`ACCEL_LIMIT_G`].
    pub fn accel_g(&mut self, flag: &str, value_g: f64) {
        self.check(
            flag,
            value_g,
            value_g.is_finite() && value_g.abs() <= ACCEL_LIMIT_G,
            "must be finite and within +-1000 g",
        );
    }

    /// A vibration amplitude: finite and 0..=[`AMPLITUDE_LIMIT_G`].
    pub fn amplitude_g(&mut self, flag: &str, value_g: f64) {
        self.check(
            flag,
            value_g,
            value_g.is_finite() && (0.0..=AMPLITUDE_LIMIT_G).contains(&value_g),
            "must be finite and 0 <= aB <= 1000 g",
        );
    }

    /// A random vibration RMS: finite and 0..=[`SIGMA_LIMIT_G`].
    pub fn sigma_g(&mut self, flag: &str, value_g: f64) {
        self.check(
            flag,
            value_g,
            value_g.is_finite() && (0.0..=SIGMA_LIMIT_G).contains(&value_g),
            "must be finite and 0 <= sigma <= 1000 g",
        );
    }

    /// A value with no bound but finiteness (a phase, a reading).
    pub fn finite(&mut self, flag: &str, value: f64) {
        self.check(flag, value, value.is_finite(), "must be finite");
    }

    /// `Ok` when no problem was recorded; otherwise every problem, one per line.
    pub fn finish(self) -> anyhow::Result<()> {
        match self.0.len() {
            0 => Ok(()),
            1 => anyhow::bail!("{}", self.0[0]),
            n => anyhow::bail!("{n} bad values:\n  {}", self.0.join("\n  ")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_problem_is_reported_with_flag_value_and_rule() {
        let mut p = FlagProblems::new();
        p.accel_g("--aL3-g", 1e300);
        p.amplitude_g("--aB3-g", -1.0);
        p.accel_g("--aL1-g", 2.0);
        let e = p.finish().unwrap_err().to_string();
        assert_eq!(
            e,
            "2 bad values:\n  --aL3-g = 1e300: must be finite and within +-1000 g\n  \
             --aB3-g = -1: must be finite and 0 <= aB <= 1000 g"
        );
        assert!(FlagProblems::new().finish().is_ok());
    }
}
