//! The flags `vibrocomp model ve`, `compensate` and `check` share: the unit and the
//! vibration it sees, and the flight acceleration, each checked against the rule a
//! file's value obeys (`vibro_physics::vibration::rules`, every problem at once) and
//! turned into a passport and a `Vibration` (`vibro_physics::vibration::UnitVibration`).

use anyhow::Context;
use clap::Args;
use std::path::PathBuf;
use vibro_physics::passport::Passport;
use vibro_physics::vibration::{rules, PsdBand, UnitVibration, Vibration};

use crate::flags::FlagProblems;

/// The unit and the vibration it sees, in its own axes (1 = OA, 2 = PA, 3 = IA).
#[derive(Debug, Args)]
pub struct VibrationArgs {
    /// Passport: a TOML file or a shipped id (AL-15, AL-1M, AKS-05).
    #[arg(long)]
    pub passport: String,
    /// Deterministic vibration amplitude along IA, g.
    #[arg(long = "aB3-g", alias = "ab3-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub ab3_g: f64,
    /// Deterministic vibration amplitude along OA, g.
    #[arg(long = "aB1-g", alias = "ab1-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub ab1_g: f64,
    /// Deterministic vibration amplitude along PA, g.
    #[arg(long = "aB2-g", alias = "ab2-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub ab2_g: f64,
    /// Vibration frequency, Hz (selects lambda(f) from the passport; 0 means lambda = 1).
    #[arg(long = "freq-hz", default_value_t = 0.0, allow_negative_numbers = true)]
    pub freq_hz: f64,
    /// Phase of the IA vibration relative to OA, phi3 - phi1, deg (the papers take 0).
    #[arg(long = "phase31-deg", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub phase31_deg: f64,
    /// Phase of the IA vibration relative to PA, phi3 - phi2, deg.
    #[arg(long = "phase32-deg", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub phase32_deg: f64,
    /// RMS of broadband random vibration along IA, g.
    #[arg(long = "sigma3-g", conflicts_with = "psd")]
    #[arg(allow_negative_numbers = true)]
    pub sigma3_g: Option<f64>,
    /// RMS of broadband random vibration along OA, g.
    #[arg(long = "sigma1-g", conflicts_with = "psd")]
    #[arg(allow_negative_numbers = true)]
    pub sigma1_g: Option<f64>,
    /// RMS of broadband random vibration along PA, g.
    #[arg(long = "sigma2-g", conflicts_with = "psd")]
    #[arg(allow_negative_numbers = true)]
    pub sigma2_g: Option<f64>,
    /// Covariance K_31(0) of the random vibration along IA and OA, g^2.
    #[arg(long = "cov31-g2", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub cov31_g2: f64,
    /// Covariance K_32(0) of the random vibration along IA and PA, g^2.
    #[arg(long = "cov32-g2", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub cov32_g2: f64,
    /// Band PSD table (CSV: f_lo_hz, f_hi_hz, psd3_g2_per_hz [, psd1.., psd2..]) instead of
    /// the sigmas, e.g. config/vibration/p1-table3.csv.
    #[arg(long)]
    pub psd: Option<PathBuf>,
    /// Kurtosis of the random vibration along IA (3 = Gaussian).
    #[arg(long = "kurtosis3", default_value_t = 3.0)]
    #[arg(allow_negative_numbers = true)]
    pub kurtosis3: f64,
}

impl VibrationArgs {
    /// The rules of a vibration file on each flag, every problem at once; the rules
    /// across flags (a covariance within the sigmas) are `Vibration::validate`'s.
    pub(super) fn check_flags(&self) -> anyhow::Result<()> {
        let mut p = FlagProblems::new();
        self.check_into(&mut p);
        p.finish()
    }

    pub(super) fn check_into(&self, p: &mut FlagProblems) {
        let amplitudes = [("--aB1-g", self.ab1_g), ("--aB2-g", self.ab2_g)];
        for (flag, v) in amplitudes.into_iter().chain([("--aB3-g", self.ab3_g)]) {
            p.amplitude_g(flag, v);
        }
        p.rule("--freq-hz", self.freq_hz, rules::freq_hz(self.freq_hz));
        for (flag, v) in [
            ("--phase31-deg", self.phase31_deg),
            ("--phase32-deg", self.phase32_deg),
        ] {
            p.rule(flag, v, rules::phase(v));
        }
        let sigmas = [("--sigma1-g", self.sigma1_g), ("--sigma2-g", self.sigma2_g)];
        for (flag, sigma) in sigmas.into_iter().chain([("--sigma3-g", self.sigma3_g)]) {
            if let Some(s) = sigma {
                p.sigma_g(flag, s);
            }
        }
        for (flag, v) in [("--cov31-g2", self.cov31_g2), ("--cov32-g2", self.cov32_g2)] {
            p.rule(flag, v, rules::covariance_g2(v));
        }
        p.rule(
            "--kurtosis3",
            self.kurtosis3,
            rules::kurtosis(self.kurtosis3),
        );
    }

    /// Validates the flags into a passport and a vibration description.
    pub(super) fn resolve(&self) -> anyhow::Result<(Passport, Vibration)> {
        self.resolve_with_psd().map(|(p, v, _)| (p, v))
    }

    /// [`Self::resolve`] and the random part's band PSD in the unit's axes (empty
    /// without `--psd`): what the extended model's filtering effects weigh.
    pub(super) fn resolve_with_psd(&self) -> anyhow::Result<(Passport, Vibration, Vec<PsdBand>)> {
        self.check_flags()?;
        let passport = vibro_config::resolve_passport(&self.passport)?;
        let psd = match &self.psd {
            Some(path) => Some(vibro_config::load_psd_table(path)?),
            None => None,
        };
        let unit = UnitVibration {
            amplitude_g: [self.ab1_g, self.ab2_g, self.ab3_g],
            freq_hz: self.freq_hz,
            phase31_deg: self.phase31_deg,
            phase32_deg: self.phase32_deg,
            sigma_g: [self.sigma1_g, self.sigma2_g, self.sigma3_g],
            cov31_g2: self.cov31_g2,
            cov32_g2: self.cov32_g2,
            kurtosis3: self.kurtosis3,
        };
        let vib = unit.to_vibration(psd.as_deref())?;
        vib.validate().context("the vibration flags")?;
        Ok((passport, vib, psd.unwrap_or_default()))
    }
}

/// Flight acceleration along the unit's axes.
#[derive(Debug, Args)]
pub struct FlightArgs {
    /// Flight acceleration along IA, g.
    #[arg(long = "aL3-g", alias = "al3-g", allow_negative_numbers = true)]
    pub al3_g: f64,
    /// Flight acceleration along OA, g.
    #[arg(long = "aL1-g", alias = "al1-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub al1_g: f64,
    /// Flight acceleration along PA, g.
    #[arg(long = "aL2-g", alias = "al2-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub al2_g: f64,
}

/// Rejects every flight acceleration outside the rule, naming the flag, its value and
/// the rule.
pub(super) fn check_accels(flags: &[(&str, f64)]) -> anyhow::Result<()> {
    let mut p = FlagProblems::new();
    for (name, v) in flags {
        p.accel_g(name, *v);
    }
    p.finish()
}

impl FlightArgs {
    /// The flight and the vibration flags' problems, all at once.
    pub(super) fn check_with(&self, vibration: &VibrationArgs) -> anyhow::Result<()> {
        self.problems_with(vibration).finish()
    }

    /// The flight and the vibration flags' problems, for more to be added.
    pub(super) fn problems_with(&self, vibration: &VibrationArgs) -> FlagProblems {
        let mut p = FlagProblems::new();
        for (name, v) in self.flags() {
            p.accel_g(name, v);
        }
        vibration.check_into(&mut p);
        p
    }

    /// The flags with their values, in the order their problems are listed.
    fn flags(&self) -> [(&'static str, f64); 3] {
        [
            ("--aL1-g", self.al1_g),
            ("--aL2-g", self.al2_g),
            ("--aL3-g", self.al3_g),
        ]
    }

    pub(super) fn a_l_g(&self) -> anyhow::Result<[f64; 3]> {
        check_accels(&self.flags())?;
        Ok([self.al1_g, self.al2_g, self.al3_g])
    }
}
