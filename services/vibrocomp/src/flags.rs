//! Checks of command-line values against the rules the files obey, every problem
//! named as `--flag = value: rule` and all of them reported at once (STYLE.md, Errors).
//!
//! The rules are the libraries': a vibration's values are
//! `vibro_physics::vibration::rules` (what `Vibration::validate` applies to a file), a
//! scenario's length `vibro_sim::scenario::Rates::length_problem`, a paced replay's
//! rate `vibro_log::Pace::rate_problem`, a duration `vibro_service::check_seconds` (the
//! rule of every duration in the services' configuration files), a flight acceleration
//! `rules::flight_accel_g` (a scenario profile's rule).

use crate::output::fmt_num;
use std::fmt::Display;
use std::time::Duration;
use vibro_physics::vibration::rules;

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

    /// A flight acceleration: the physics' rule.
    pub fn accel_g(&mut self, flag: &str, value_g: f64) {
        self.rule(flag, value_g, rules::flight_accel_g(value_g));
    }

    /// Records `--flag = value: rule` when a library's rule function found one.
    pub fn rule(&mut self, flag: &str, value: f64, problem: Option<impl Display>) {
        if let Some(rule) = problem {
            self.push(flag, value, rule);
        }
    }

    /// Records `--flag = n: rule` for a count when a library's rule found one.
    pub fn count(&mut self, flag: &str, n: u64, problem: Option<impl Display>) {
        if let Some(rule) = problem {
            self.0.push(format!("{flag} = {n}: {rule}"));
        }
    }

    /// A tone amplitude: the physics' rule.
    pub fn amplitude_g(&mut self, flag: &str, value_g: f64) {
        self.rule(flag, value_g, rules::amplitude_g(value_g));
    }

    /// A random vibration RMS: the physics' rule on its variance.
    pub fn sigma_g(&mut self, flag: &str, value_g: f64) {
        self.rule(flag, value_g, rules::sigma_g(value_g));
    }

    /// A paced rate, times real time: a paced replay's rule.
    pub fn rate(&mut self, flag: &str, rate: f64) {
        self.rule(flag, rate, vibro_log::Pace::rate_problem(rate));
    }

    /// A duration with no file key, within `lo_s..=hi_s`: the services' files' rule
    /// for durations (`vibro_service::check_seconds`), with the bounds of the flag.
    /// `Some` when it holds.
    pub fn seconds(&mut self, flag: &str, value_s: f64, lo_s: f64, hi_s: f64) -> Option<Duration> {
        let mut scratch = Vec::new();
        let d = vibro_service::check_seconds(flag, value_s, lo_s, hi_s, &mut scratch);
        if d.is_none() {
            // check_seconds' own wording, the value in engineering form.
            self.push(
                flag,
                value_s,
                format_args!(
                    "must be finite and {} <= s <= {}",
                    fmt_num(lo_s),
                    fmt_num(hi_s)
                ),
            );
        }
        d
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
        p.sigma_g("--sigma3-g", 1000.000001);
        p.sigma_g("--sigma1-g", 1000.0);
        assert!(p.seconds("--wait-s", 1e300, 0.01, 3600.0).is_none());
        p.accel_g("--aL1-g", 2.0);
        let e = p.finish().unwrap_err().to_string();
        assert_eq!(
            e,
            "4 bad values:\n  --aL3-g = 1e300: must be finite and within +-1000 g\n  \
             --aB3-g = -1: must be finite and 0 <= aB <= 1000 g\n  \
             --sigma3-g = 1000.000001: must be finite and 0 <= sigma^2 <= 1e6 g^2 (sigma <= 1000 g)\n  \
             --wait-s = 1e300: must be finite and 0.01 <= s <= 3600"
        );
        assert!(FlagProblems::new().finish().is_ok());
    }
}
