//! The main error (MODEL.md section 4) and the vibration error as published
//! (section 5): the papers' additive/multiplicative split for deterministic and
//! broadband random vibration.
//!
//! The papers' formulas hold for one tone, in phase on all axes. When a description
//! carries several tones they are replaced by the single tone of equal power on each
//! axis ([`Vibration::equivalent_amplitude_g`]); phases are ignored (`cos = 1`), as in
//! the papers. The exact model ([`crate::exact`]) has neither restriction.

use crate::passport::Passport;
use crate::vibration::Vibration;
use serde::Serialize;

/// The constants of the published model that the papers print differently.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Constants {
    /// Asymmetry factor under a sinusoid, 0.637 (about 2/pi) [P1 (15)]. [P2 (4)]
    /// prints 0.673, but both papers' numbers use 0.637 (MODEL.md section 5).
    pub asym_det: f64,
    /// Asymmetry factor under broadband random vibration, 0.125 [P1 (14)].
    pub asym_rand: f64,
    /// Factor of `k5*aB3^4` in `delta(1)` under a sinusoid: 1.875 [P1 (16)];
    /// [P2 (19)] prints 1.185 and its worked results use it (MODEL.md section 7).
    pub k5_delta1_det: f64,
}

impl Constants {
    /// The papers' model with the misprint fixed: [P1 (13)-(16)].
    pub const PAPER: Self = Self {
        asym_det: 0.637,
        asym_rand: 0.125,
        k5_delta1_det: 1.875,
    };
    /// The compensation algorithm exactly as printed in [P2 (19)] (1.185).
    pub const AS_PRINTED_P2: Self = Self {
        asym_det: 0.637,
        asym_rand: 0.125,
        k5_delta1_det: 1.185,
    };
}

/// The components of a vibration error, MODEL.md section 5:
/// `dV = d0(1) + d0(2) + d0(3) + delta(1)*aL3 + delta(2)*aL3^2 + delta(3)*aL3^3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct VeComponents {
    pub d01_g: f64,
    pub d02_g: f64,
    pub d03_g: f64,
    pub delta1: f64,
    pub delta2_per_g: f64,
    pub delta3_per_g2: f64,
    /// `d0(1) + d0(2) + d0(3)`.
    pub additive_g: f64,
    /// `delta(1)*aL3 + delta(2)*aL3^2 + delta(3)*aL3^3`.
    pub multiplicative_g: f64,
    pub total_g: f64,
}

impl VeComponents {
    /// Assembles the components and evaluates the parts at `a_l3_g` [P1 (13)].
    pub fn new(d0_g: [f64; 3], delta: [f64; 3], a_l3_g: f64) -> Self {
        let additive_g = d0_g[0] + d0_g[1] + d0_g[2];
        let multiplicative_g = a_l3_g * (delta[0] + a_l3_g * (delta[1] + a_l3_g * delta[2]));
        Self {
            d01_g: d0_g[0],
            d02_g: d0_g[1],
            d03_g: d0_g[2],
            delta1: delta[0],
            delta2_per_g: delta[1],
            delta3_per_g2: delta[2],
            additive_g,
            multiplicative_g,
            total_g: additive_g + multiplicative_g,
        }
    }

    /// The sum of two VEs at the same flight acceleration (the papers add the
    /// deterministic and random parts, [P1 (13)]).
    pub fn plus(&self, other: &Self, a_l3_g: f64) -> Self {
        Self::new(
            [
                self.d01_g + other.d01_g,
                self.d02_g + other.d02_g,
                self.d03_g + other.d03_g,
            ],
            [
                self.delta1 + other.delta1,
                self.delta2_per_g + other.delta2_per_g,
                self.delta3_per_g2 + other.delta3_per_g2,
            ],
            a_l3_g,
        )
    }
}

/// Main error `dO` at the flight acceleration `a_l_g = [aL1, aL2, aL3]`
/// [P1 (12)], [P2 (2)], with `lambda(0) = 1`. Includes the zero offset `a0`.
#[inline]
pub fn main_error_g(p: &Passport, a_l_g: [f64; 3]) -> f64 {
    p.a0_g + main_error_without_offset_g(p, a_l_g)
}

/// Main error without its zero offset: what stage (18) removes after (17) has
/// already subtracted `a0` (MODEL.md section 7).
#[inline]
pub fn main_error_without_offset_g(p: &Passport, a_l_g: [f64; 3]) -> f64 {
    let [a1, a2, a] = a_l_g;
    0.5 * p.k1 * p.d1a * a.abs()
        + a * a * (p.k[2] + a * (p.k[3] + a * (p.k[4] + a * p.k[5])))
        + p.m1 * a1
        + p.m2 * a2
        + a * (p.m31_per_g * a1 + p.m32_per_g * a2)
}

/// Deterministic VE as published [P1 (13), (15)-(16)]. `lambda` is taken at the
/// frequency of the tone with the largest IA amplitude.
pub fn published_det(p: &Passport, a_l_g: [f64; 3], vib: &Vibration, c: Constants) -> VeComponents {
    let [ab1, ab2, ab3] = vib.equivalent_amplitude_g();
    let freq_hz = vib
        .tones()
        .iter()
        .max_by(|x, y| x.amplitude_g[2].total_cmp(&y.amplitude_g[2]))
        .map_or(0.0, |t| t.freq_hz);
    let lambda = p.lambda_at(freq_hz);
    let (ab3_2, ab3_4) = (ab3 * ab3, ab3.powi(4));
    let d01 =
        c.asym_det * lambda * p.k1 * p.d1a * ab3 + 0.5 * p.k[2] * ab3_2 + 0.375 * p.k[4] * ab3_4;
    let d02 = 0.5 * p.m31_per_g * ab3 * ab1;
    let d03 = 0.5 * p.m32_per_g * ab3 * ab2;
    let delta1 = 1.5 * p.k[3] * ab3_2 + c.k5_delta1_det * p.k[5] * ab3_4;
    let delta2 = 3.0 * p.k[4] * ab3_2;
    let delta3 = 5.0 * p.k[5] * ab3_2;
    VeComponents::new([d01, d02, d03], [delta1, delta2, delta3], a_l_g[2])
}

/// Broadband random VE as published [P1 (14), (16)], with `lambda = 1` (the papers
/// give no band weighting of `lambda`).
pub fn published_rand(
    p: &Passport,
    a_l_g: [f64; 3],
    vib: &Vibration,
    c: Constants,
) -> VeComponents {
    let s2 = vib.covariance_g2[2][2].max(0.0);
    let s = s2.sqrt();
    let d01 = c.asym_rand * p.k1 * p.d1a * s + p.k[2] * s2 + p.k[4] * s2 * s2;
    let d02 = p.m31_per_g * vib.covariance_g2[2][0];
    let d03 = p.m32_per_g * vib.covariance_g2[2][1];
    let delta1 = 3.0 * p.k[3] * s2 + 5.0 * p.k[5] * s2 * s2;
    let delta2 = 6.0 * p.k[4] * s2;
    let delta3 = 10.0 * p.k[5] * s2;
    VeComponents::new([d01, d02, d03], [delta1, delta2, delta3], a_l_g[2])
}

/// Deterministic and random VE together, as the papers add them [P1 (13)].
pub fn published(p: &Passport, a_l_g: [f64; 3], vib: &Vibration, c: Constants) -> VeComponents {
    published_det(p, a_l_g, vib, c).plus(&published_rand(p, a_l_g, vib, c), a_l_g[2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::al15;

    /// [P1 Table 4], MODEL.md section 5: AL-15, aB3 = 0.42 g, aB1 = aB2 = 0.8..1.5 g,
    /// aL3 = 10 g. Printed: d0(1) = 13.39 ug, d0(2) = d0(3) = 1.95..3.65 ug,
    /// delta(1)aL3 = 0.2307 mg, delta(2)aL3^2 = 0.5292 mg, delta(3)aL3^3 = 0.7938 mg,
    /// total 1.571 mg.
    #[test]
    fn reproduces_p1_table_4() {
        let p = al15();
        let a_l = [0.0, 0.0, 10.0];
        let lo = published(
            &p,
            a_l,
            &Vibration::single_tone(12.0, [0.8, 0.8, 0.42]),
            Constants::PAPER,
        );
        let hi = published(
            &p,
            a_l,
            &Vibration::single_tone(12.0, [1.5, 1.5, 0.42]),
            Constants::PAPER,
        );
        let round = |x: f64, unit: f64, digits: i32| {
            (x / unit * 10f64.powi(digits)).round() / 10f64.powi(digits)
        };
        assert_eq!(round(lo.d01_g, 1e-6, 2), 13.39);
        assert_eq!(
            (round(lo.d02_g, 1e-6, 2), round(hi.d02_g, 1e-6, 2)),
            (1.95, 3.65)
        );
        assert_eq!(
            (round(lo.d03_g, 1e-6, 2), round(hi.d03_g, 1e-6, 2)),
            (1.95, 3.65)
        );
        assert_eq!(round(lo.delta1 * 10.0, 1e-3, 4), 0.2307);
        assert_eq!(round(lo.delta2_per_g * 100.0, 1e-3, 4), 0.5292);
        assert_eq!(round(lo.delta3_per_g2 * 1000.0, 1e-3, 4), 0.7938);
        assert_eq!(round(lo.total_g, 1e-3, 3), 1.571);
    }

    /// MODEL.md section 6: AL-15, sigma3^2 = 38.4 g^2, aL3 = 10 g: about 761 mg.
    #[test]
    fn random_band_gives_about_761_mg() {
        let mut v = Vibration::none();
        v.covariance_g2[2][2] = 38.4;
        let ve = published(&al15(), [0.0, 0.0, 10.0], &v, Constants::PAPER);
        assert_eq!((ve.total_g * 1e3).round(), 761.0);
    }

    #[test]
    fn main_error_is_the_passport_polynomial() {
        let p = al15();
        let a = -3.0;
        let want = 3.324e-3 + 0.5 * 15e-6 * 3.0 + 105e-6 * 9.0 - 87e-6 * 27.0 + 10e-6 * 81.0
            - 0.9e-6 * 243.0
            + 1.15e-3 * (0.5 + 0.25)
            + 11.6e-6 * a * (0.5 + 0.25);
        assert!((main_error_g(&p, [0.5, 0.25, a]) - want).abs() < 1e-15);
    }
}
