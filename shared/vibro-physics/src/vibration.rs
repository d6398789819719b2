//! Descriptions of the vibration seen by one accelerometer, in its own axes
//! (MODEL.md section 3): deterministic tones and broadband random vibration.
//!
//! Axis indices follow MODEL.md: index 0 is axis 1 (OA), 1 is axis 2 (PA), 2 is
//! axis 3 (IA, the measured axis). Types are fixed-size (`Copy`) so the compensation
//! kernel never allocates.

use crate::{Error, Result};

/// Most tones one description holds.
pub const MAX_TONES: usize = 8;

/// A deterministic vibration component `aB_i * sin(w t + phi_i)` on each axis
/// (MODEL.md section 3), sharing one frequency.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Tone {
    pub freq_hz: f64,
    /// `aB_i`, per axis `[1, 2, 3]`, g (amplitude, not RMS).
    pub amplitude_g: [f64; 3],
    /// `phi_i`, per axis, rad.
    pub phase_rad: [f64; 3],
}

/// One band of a piecewise-constant PSD table (RIG.md's random-vibration tables).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsdBand {
    pub f_lo_hz: f64,
    pub f_hi_hz: f64,
    /// `S_i` per axis `[1, 2, 3]`, g^2/Hz.
    pub psd_g2_per_hz: [f64; 3],
}

/// The vibration seen by one unit: up to [`MAX_TONES`] tones, broadband random
/// vibration with a full covariance, and the kurtosis of the random part per axis.
///
/// Tones are taken as mutually independent (incommensurate frequencies, or phases
/// that drift between them): the exact model averages each over its own phase. Two
/// tones locked in phase at harmonic frequencies are outside this description.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vibration {
    tones: [Tone; MAX_TONES],
    n_tones: usize,
    /// Covariance of the broadband random part, `K_ij(0)`, g^2 (MODEL.md section 3).
    pub covariance_g2: [[f64; 3]; 3],
    /// Kurtosis `E[x^4]/sigma^4` of the random part per axis; 3 for Gaussian.
    pub kurtosis: [f64; 3],
}

impl Default for Vibration {
    fn default() -> Self {
        Self::none()
    }
}

impl Vibration {
    /// No vibration.
    pub const fn none() -> Self {
        Self {
            tones: [Tone {
                freq_hz: 0.0,
                amplitude_g: [0.0; 3],
                phase_rad: [0.0; 3],
            }; MAX_TONES],
            n_tones: 0,
            covariance_g2: [[0.0; 3]; 3],
            kurtosis: [3.0; 3],
        }
    }

    /// One tone, in phase on all axes (the papers' assumption, `phi_i = 0`).
    pub fn single_tone(freq_hz: f64, amplitude_g: [f64; 3]) -> Self {
        let mut v = Self::none();
        v.tones[0] = Tone {
            freq_hz,
            amplitude_g,
            phase_rad: [0.0; 3],
        };
        v.n_tones = 1;
        v
    }

    /// Uncorrelated Gaussian random vibration with the given RMS per axis.
    pub fn random_rms(sigma_g: [f64; 3]) -> Self {
        let mut v = Self::none();
        for (i, s) in sigma_g.iter().enumerate() {
            v.covariance_g2[i][i] = s * s;
        }
        v
    }

    /// Adds a tone. Fails when [`MAX_TONES`] are already present.
    pub fn push_tone(&mut self, tone: Tone) -> Result<()> {
        if self.n_tones == MAX_TONES {
            return Err(Error::InvalidVibration(format!(
                "more than {MAX_TONES} tones: at most {MAX_TONES} are supported"
            )));
        }
        self.tones[self.n_tones] = tone;
        self.n_tones += 1;
        Ok(())
    }

    /// The tones present.
    pub fn tones(&self) -> &[Tone] {
        &self.tones[..self.n_tones]
    }

    /// Removes every tone (keeps the random part).
    pub fn clear_tones(&mut self) {
        self.n_tones = 0;
    }

    /// The deterministic part alone.
    pub fn deterministic_part(&self) -> Self {
        Self {
            covariance_g2: [[0.0; 3]; 3],
            kurtosis: [3.0; 3],
            ..*self
        }
    }

    /// The random part alone.
    pub fn random_part(&self) -> Self {
        Self {
            n_tones: 0,
            ..*self
        }
    }

    /// Sets the random part from a band PSD table: `sigma_i^2 = sum S_i * df`
    /// (MODEL.md section 3). Bands carry no cross-spectra, so off-diagonal terms are 0.
    pub fn set_random_from_psd(&mut self, bands: &[PsdBand]) {
        self.covariance_g2 = [[0.0; 3]; 3];
        for b in bands {
            let df_hz = b.f_hi_hz - b.f_lo_hz;
            for i in 0..3 {
                self.covariance_g2[i][i] += b.psd_g2_per_hz[i] * df_hz;
            }
        }
    }

    /// RMS of the random part along axis `i` (0-based), g.
    pub fn sigma_g(&self, i: usize) -> f64 {
        self.covariance_g2[i][i].max(0.0).sqrt()
    }

    /// Equivalent single-tone amplitude per axis, `sqrt(sum aB^2)`: the tone with the
    /// same power, used by the papers' one-tone formulas when several tones are given.
    pub fn equivalent_amplitude_g(&self) -> [f64; 3] {
        let mut p = [0.0; 3];
        for t in self.tones() {
            for i in 0..3 {
                p[i] += t.amplitude_g[i] * t.amplitude_g[i];
            }
        }
        p.map(f64::sqrt)
    }

    /// Whether there is any vibration at all.
    pub fn is_none(&self) -> bool {
        self.tones().iter().all(|t| t.amplitude_g == [0.0; 3])
            && self.covariance_g2.iter().flatten().all(|c| *c == 0.0)
    }

    /// Checks every value, reporting all problems at once. The rule of each value
    /// alone is one of [`rules`]' functions (the command line's flags use them too).
    pub fn validate(&self) -> Result<()> {
        let mut problems = Vec::new();
        for (k, t) in self.tones().iter().enumerate() {
            if let Some(rule) = rules::freq_hz(t.freq_hz) {
                problems.push(format!("tone[{k}].freq_hz = {}: {rule}", t.freq_hz));
            }
            for i in 0..3 {
                let a = t.amplitude_g[i];
                if let Some(rule) = rules::amplitude_g(a) {
                    problems.push(format!("tone[{k}].aB{}_g = {a}: {rule}", i + 1));
                }
                if let Some(rule) = rules::phase(t.phase_rad[i]) {
                    problems.push(format!(
                        "tone[{k}].phase{}_rad = {}: {rule}",
                        i + 1,
                        t.phase_rad[i]
                    ));
                }
            }
        }
        let c = &self.covariance_g2;
        for i in 0..3 {
            if let Some(rule) = rules::variance_g2(c[i][i]) {
                problems.push(format!("sigma{}^2 = {} g^2: {rule}", i + 1, c[i][i]));
            }
            let k = self.kurtosis[i];
            if let Some(rule) = rules::kurtosis(k) {
                problems.push(format!("kurtosis{} = {k}: {rule}", i + 1));
            }
            for j in 0..3 {
                if i == j {
                    continue;
                }
                let cij = c[i][j];
                if rules::covariance_g2(cij).is_some() || cij != c[j][i] {
                    problems.push(format!(
                        "cov{}{} = {cij} g^2: must be finite and equal to cov{}{} = {}",
                        i + 1,
                        j + 1,
                        j + 1,
                        i + 1,
                        c[j][i]
                    ));
                } else if i > j && cij.abs() > (c[i][i] * c[j][j]).max(0.0).sqrt() * (1.0 + 1e-9) {
                    // Named as MODEL.md's K_31, K_32: the higher axis first.
                    problems.push(format!(
                        "cov{}{} = {cij} g^2: |cov| must not exceed sigma{} * sigma{} = {}",
                        i + 1,
                        j + 1,
                        j + 1,
                        i + 1,
                        (c[i][i] * c[j][j]).max(0.0).sqrt()
                    ));
                }
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(Error::InvalidVibration(problems.join("; ")))
        }
    }
}

/// The vibration one unit sees, in its own axes (1 = OA, 2 = PA, 3 = IA), as the
/// values of `vibrocomp model`'s flags give it: one tone, and broadband random
/// vibration by RMS per axis or by a band PSD table, with the IA covariances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitVibration {
    /// Tone amplitudes `[aB1, aB2, aB3]`, g; no tone when all are 0.
    pub amplitude_g: [f64; 3],
    /// Tone frequency, Hz (0: `lambda = 1`).
    pub freq_hz: f64,
    /// Phases of the IA vibration relative to OA and PA, `phi3 - phi1` and
    /// `phi3 - phi2`, deg (the papers take 0).
    pub phase31_deg: f64,
    pub phase32_deg: f64,
    /// RMS of the random vibration per axis `[OA, PA, IA]`, g (absent: 0); unused
    /// when a PSD table is given.
    pub sigma_g: [Option<f64>; 3],
    /// Covariances `K_31(0)` and `K_32(0)` of the random vibration, g^2.
    pub cov31_g2: f64,
    pub cov32_g2: f64,
    /// Kurtosis of the random vibration along IA (3 = Gaussian).
    pub kurtosis3: f64,
}

impl UnitVibration {
    /// The vibration description, not yet validated ([`Vibration::validate`] checks
    /// the rules across values, such as a covariance within the sigmas). `psd`, when
    /// given, replaces the sigmas by the bands' variances.
    pub fn to_vibration(&self, psd: Option<&[PsdBand]>) -> Result<Vibration> {
        let mut vib = Vibration::none();
        if self.amplitude_g.iter().any(|a| *a != 0.0) {
            vib.push_tone(Tone {
                freq_hz: self.freq_hz,
                amplitude_g: self.amplitude_g,
                // Only the differences phi3 - phi1 and phi3 - phi2 matter: set phi3 = 0.
                phase_rad: [
                    -self.phase31_deg.to_radians(),
                    -self.phase32_deg.to_radians(),
                    0.0,
                ],
            })?;
        }
        if let Some(bands) = psd {
            vib.set_random_from_psd(bands);
        } else {
            for (i, s) in self.sigma_g.iter().enumerate() {
                let s = s.unwrap_or(0.0);
                if !(s.is_finite() && s >= 0.0) {
                    return Err(Error::InvalidVibration(format!(
                        "sigma{} = {s}: must be finite and >= 0",
                        i + 1
                    )));
                }
                vib.covariance_g2[i][i] = s * s;
            }
        }
        vib.covariance_g2[2][0] = self.cov31_g2;
        vib.covariance_g2[0][2] = self.cov31_g2;
        vib.covariance_g2[2][1] = self.cov32_g2;
        vib.covariance_g2[1][2] = self.cov32_g2;
        vib.kurtosis[2] = self.kurtosis3;
        Ok(vib)
    }
}

/// The rule of each value of a [`Vibration`] on its own: `None` when the value keeps
/// it, else the rule it breaks (without the value's name, which the caller knows: a
/// file's key, a command-line flag). [`Vibration::validate`] applies them, plus the
/// rules across values (a covariance within the sigmas, a symmetric matrix).
pub mod rules {
    /// Largest tone amplitude, g.
    pub const MAX_AMPLITUDE_G: f64 = 1e3;
    /// Largest variance of the random part, g^2 (sigma <= 1000 g).
    pub const MAX_VARIANCE_G2: f64 = 1e6;
    /// Kurtosis range (Gaussian: 3).
    pub const KURTOSIS_RANGE: std::ops::RangeInclusive<f64> = 1.0..=30.0;

    /// Largest flight acceleration along an axis, g (a scenario's profile, the
    /// command line's and the Python package's flight accelerations).
    pub const MAX_FLIGHT_ACCEL_G: f64 = 1e3;

    /// A flight acceleration along one axis, g.
    pub fn flight_accel_g(a_g: f64) -> Option<&'static str> {
        (!(a_g.is_finite() && a_g.abs() <= MAX_FLIGHT_ACCEL_G))
            .then_some("must be finite and within +-1000 g")
    }

    /// A tone's frequency, Hz.
    pub fn freq_hz(f_hz: f64) -> Option<&'static str> {
        (!(f_hz.is_finite() && f_hz >= 0.0)).then_some("must be finite and >= 0")
    }

    /// A tone's amplitude, g.
    pub fn amplitude_g(a_g: f64) -> Option<&'static str> {
        (!(a_g.is_finite() && (0.0..=MAX_AMPLITUDE_G).contains(&a_g)))
            .then_some("must be finite and 0 <= aB <= 1000 g")
    }

    /// A phase (any unit).
    pub fn phase(x: f64) -> Option<&'static str> {
        (!x.is_finite()).then_some("must be finite")
    }

    /// A variance of the random part, g^2.
    pub fn variance_g2(v_g2: f64) -> Option<&'static str> {
        (!(v_g2.is_finite() && (0.0..=MAX_VARIANCE_G2).contains(&v_g2)))
            .then_some("must be finite and 0 <= sigma^2 <= 1e6 g^2")
    }

    /// An RMS of the random part, g: [`variance_g2`] of its square, and not negative.
    pub fn sigma_g(s_g: f64) -> Option<&'static str> {
        if !(s_g.is_finite() && s_g >= 0.0) {
            return Some("must be finite and >= 0");
        }
        variance_g2(s_g * s_g)
            .map(|_| "must be finite and 0 <= sigma^2 <= 1e6 g^2 (sigma <= 1000 g)")
    }

    /// A covariance between two axes, g^2, on its own (its bound by the sigmas is
    /// [`super::Vibration::validate`]'s).
    pub fn covariance_g2(c_g2: f64) -> Option<&'static str> {
        (!c_g2.is_finite()).then_some("must be finite")
    }

    /// The kurtosis of an axis.
    pub fn kurtosis(k: f64) -> Option<&'static str> {
        (!(k.is_finite() && KURTOSIS_RANGE.contains(&k)))
            .then_some("must be finite and 1 <= kurtosis <= 30")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psd_table_integrates_to_variance() {
        let mut v = Vibration::none();
        // RIG.md's 320..640 Hz band at 0.12 g^2/Hz: sigma^2 = 38.4 g^2 (MODEL.md section 6).
        v.set_random_from_psd(&[PsdBand {
            f_lo_hz: 320.0,
            f_hi_hz: 640.0,
            psd_g2_per_hz: [0.0, 0.0, 0.12],
        }]);
        assert!((v.covariance_g2[2][2] - 38.4).abs() < 1e-12);
    }

    #[test]
    fn per_value_rules_are_the_ones_validate_applies() {
        // sigma <= 1000 g is sigma^2 <= 1e6 g^2, on both sides of the boundary.
        assert!(rules::sigma_g(1000.0).is_none());
        assert!(rules::sigma_g(1000.000001).is_some());
        assert!(rules::sigma_g(-1e-300).is_some());
        for (variance_g2, ok) in [(1e6, true), (1e6 + 1.0, false), (f64::NAN, false)] {
            let mut v = Vibration::none();
            v.covariance_g2[2][2] = variance_g2;
            assert_eq!(v.validate().is_ok(), ok, "{variance_g2}");
            assert_eq!(
                rules::variance_g2(variance_g2).is_none(),
                ok,
                "{variance_g2}"
            );
        }
        for (k, ok) in [(1.0, true), (30.0, true), (30.5, false), (0.99, false)] {
            let mut v = Vibration::none();
            v.kurtosis[2] = k;
            assert_eq!(v.validate().is_ok(), ok, "{k}");
            assert_eq!(rules::kurtosis(k).is_none(), ok, "{k}");
        }
    }

    #[test]
    fn validation_reports_every_problem() {
        let mut v = Vibration::single_tone(-1.0, [1.0, f64::NAN, 0.5]);
        v.covariance_g2[2][0] = 5.0;
        v.covariance_g2[0][2] = 5.0;
        let e = v.validate().unwrap_err().to_string();
        assert!(e.contains("tone[0].freq_hz = -1"), "{e}");
        assert!(e.contains("tone[0].aB2_g = NaN"), "{e}");
        assert!(
            e.contains("cov31 = 5 g^2: |cov| must not exceed sigma1 * sigma3"),
            "{e}"
        );
    }

    #[test]
    fn a_unit_vibration_has_its_tone_sigmas_and_covariances() {
        let u = UnitVibration {
            amplitude_g: [0.0, 0.0, 2.0],
            freq_hz: 30.0,
            phase31_deg: 90.0,
            phase32_deg: 0.0,
            sigma_g: [None, Some(0.5), Some(2.0)],
            cov31_g2: 0.0,
            cov32_g2: 0.25,
            kurtosis3: 4.5,
        };
        let v = u.to_vibration(None).unwrap();
        assert_eq!(v.tones().len(), 1);
        // phi1 = -(phi3 - phi1) with phi3 = 0: -pi/2.
        assert_eq!(
            v.tones()[0].phase_rad,
            [-std::f64::consts::FRAC_PI_2, 0.0, 0.0]
        );
        assert_eq!(v.covariance_g2[0][0], 0.0);
        assert_eq!(v.covariance_g2[1][1], 0.25);
        assert_eq!(v.covariance_g2[2][2], 4.0);
        assert_eq!((v.covariance_g2[2][1], v.covariance_g2[1][2]), (0.25, 0.25));
        assert_eq!(v.kurtosis[2], 4.5);
        let still = UnitVibration {
            amplitude_g: [0.0; 3],
            sigma_g: [None, Some(-1.0), None],
            ..u
        };
        assert!(still
            .to_vibration(None)
            .unwrap_err()
            .to_string()
            .contains("sigma2 = -1"));
    }
}
