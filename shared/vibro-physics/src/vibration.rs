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

    /// Checks every value, reporting all problems at once.
    pub fn validate(&self) -> Result<()> {
        let mut problems = Vec::new();
        for (k, t) in self.tones().iter().enumerate() {
            if !(t.freq_hz.is_finite() && t.freq_hz >= 0.0) {
                problems.push(format!(
                    "tone[{k}].freq_hz = {}: must be finite and >= 0",
                    t.freq_hz
                ));
            }
            for i in 0..3 {
                let a = t.amplitude_g[i];
                if !(a.is_finite() && (0.0..=1e3).contains(&a)) {
                    problems.push(format!(
                        "tone[{k}].aB{}_g = {a}: must be finite and 0 <= aB <= 1000 g",
                        i + 1
                    ));
                }
                if !t.phase_rad[i].is_finite() {
                    problems.push(format!(
                        "tone[{k}].phase{}_rad = {}: must be finite",
                        i + 1,
                        t.phase_rad[i]
                    ));
                }
            }
        }
        let c = &self.covariance_g2;
        for i in 0..3 {
            if !(c[i][i].is_finite() && c[i][i] >= 0.0 && c[i][i] <= 1e6) {
                problems.push(format!(
                    "sigma{}^2 = {} g^2: must be finite and 0 <= sigma^2 <= 1e6 g^2",
                    i + 1,
                    c[i][i]
                ));
            }
            let k = self.kurtosis[i];
            if !(k.is_finite() && (1.0..=30.0).contains(&k)) {
                problems.push(format!(
                    "kurtosis{} = {k}: must be finite and 1 <= kurtosis <= 30",
                    i + 1
                ));
            }
            for j in 0..3 {
                if i == j {
                    continue;
                }
                let cij = c[i][j];
                if !cij.is_finite() || cij != c[j][i] {
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
}
