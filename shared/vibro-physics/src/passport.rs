//! The accelerometer passport: every coefficient of the conversion function (FP),
//! MODEL.md section 2, [P1 (1)-(2)], [P2 (1)].
//!
//! The validated [`Passport`] holds coefficients in SI-like "acceleration units"
//! (dimensionless, 1/g, 1/g^2, ...) for the formulas, and remembers the quoted
//! passport units (ppm, ppm/g, ...) only in the names of its constructor fields
//! ([`PassportSpec`]). The two never mix: formulas read [`Passport`]'s getters.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// One point of the frequency dependence of the scale factor, `lambda(w)` (MODEL.md
/// section 1). `lambda(0) = 1` by definition and is implied.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LambdaPoint {
    pub freq_hz: f64,
    pub lambda: f64,
}

/// Maximum number of points in a `lambda` table (fixed so a passport is `Copy`-cheap
/// to clone into a real-time kernel).
pub const MAX_LAMBDA_POINTS: usize = 32;

/// A passport as written in its file, in the quoted units of MODEL.md section 1/5/7:
/// ppm for dimensionless small coefficients, ppm/g^(n-1) (= ug/g^n) for `k_n`.
/// Turned into a [`Passport`] by [`Passport::try_from_spec`], which checks every rule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PassportSpec {
    /// Short identifier, e.g. `AL-15`.
    pub id: String,
    /// Zero offset `a0`, g.
    pub a0_g: f64,
    /// Scale factor in acceleration units, dimensionless, ~1.
    pub k1: f64,
    /// Scale factor in output units, `K1`, V/g (or counts/g).
    #[serde(rename = "K1_v_per_g")]
    pub k1_v_per_g: f64,
    /// Scale-factor asymmetry `d1A`, ppm.
    pub d1a_ppm: f64,
    /// Second-order nonlinearity `k2`, ppm/g.
    pub k2_ppm_per_g: f64,
    /// Third-order nonlinearity `k3`, ppm/g^2.
    pub k3_ppm_per_g2: f64,
    /// Fourth-order nonlinearity `k4`, ppm/g^3.
    pub k4_ppm_per_g3: f64,
    /// Fifth-order nonlinearity `k5`, ppm/g^4.
    pub k5_ppm_per_g4: f64,
    /// Additive cross-sensitivity to OA, `m1`, ppm.
    pub m1_ppm: f64,
    /// Additive cross-sensitivity to PA, `m2`, ppm.
    pub m2_ppm: f64,
    /// Multiplicative cross-sensitivity IA x OA, `m31`, ppm/g.
    pub m31_ppm_per_g: f64,
    /// Multiplicative cross-sensitivity IA x PA, `m32`, ppm/g.
    pub m32_ppm_per_g: f64,
    /// Optional frequency dependence of the scale factor; empty means `lambda = 1`.
    #[serde(default)]
    pub lambda: Vec<LambdaPoint>,
}

/// A validated passport. All coefficients are in acceleration units (a in g):
/// `kn` in 1/g^(n-1), `m31` in 1/g, `d1a`, `m1`, `m2` dimensionless.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Passport {
    id: [u8; 32],
    id_len: usize,
    pub a0_g: f64,
    pub k1: f64,
    pub k1_v_per_g: f64,
    pub d1a: f64,
    /// `k[n]` is the coefficient of `a3^n`, n = 2..5 (`k[0]`, `k[1]` unused, zero).
    pub k: [f64; 6],
    pub m1: f64,
    pub m2: f64,
    pub m31_per_g: f64,
    pub m32_per_g: f64,
    lambda: [LambdaPoint; MAX_LAMBDA_POINTS],
    lambda_len: usize,
}

/// Parts per million: dividing by the exact 1e6 (not multiplying by the inexact 1e-6)
/// makes `11.6 ppm` the same double as the literal `11.6e-6`.
const PER_PPM: f64 = 1e6;

/// A rule a passport value must obey: a description for messages and a check.
struct Rule {
    key: &'static str,
    value: f64,
    ok: bool,
    rule: &'static str,
}

impl Passport {
    /// Validates a spec, reporting every broken rule at once (the caller adds the
    /// file name). Limits are far outside any navigation-grade unit, so they catch
    /// unit mix-ups (a coefficient written in g instead of ppm), not real units.
    pub fn try_from_spec(spec: &PassportSpec) -> Result<Self> {
        let finite_abs = |key, value: f64, limit: f64, rule| Rule {
            key,
            value,
            ok: value.is_finite() && value.abs() <= limit,
            rule,
        };
        let rules = [
            finite_abs("a0_g", spec.a0_g, 1.0, "must be finite and |a0| <= 1 g"),
            Rule {
                key: "k1",
                value: spec.k1,
                ok: spec.k1.is_finite() && spec.k1 > 0.5 && spec.k1 < 1.5,
                rule: "must be finite and within 0.5 < k1 < 1.5 (dimensionless, ~1)",
            },
            Rule {
                key: "K1_v_per_g",
                value: spec.k1_v_per_g,
                ok: spec.k1_v_per_g.is_finite()
                    && spec.k1_v_per_g.abs() >= 1e-9
                    && spec.k1_v_per_g.abs() <= 1e9,
                rule: "must be finite and 1e-9 <= |K1| <= 1e9 V/g",
            },
            finite_abs(
                "d1a_ppm",
                spec.d1a_ppm,
                1e5,
                "must be finite and |d1A| <= 1e5 ppm",
            ),
            finite_abs(
                "k2_ppm_per_g",
                spec.k2_ppm_per_g,
                1e4,
                "must be finite and |k2| <= 1e4 ppm/g",
            ),
            finite_abs(
                "k3_ppm_per_g2",
                spec.k3_ppm_per_g2,
                1e4,
                "must be finite and |k3| <= 1e4 ppm/g^2",
            ),
            finite_abs(
                "k4_ppm_per_g3",
                spec.k4_ppm_per_g3,
                1e4,
                "must be finite and |k4| <= 1e4 ppm/g^3",
            ),
            finite_abs(
                "k5_ppm_per_g4",
                spec.k5_ppm_per_g4,
                1e4,
                "must be finite and |k5| <= 1e4 ppm/g^4",
            ),
            finite_abs(
                "m1_ppm",
                spec.m1_ppm,
                1e5,
                "must be finite and |m1| <= 1e5 ppm",
            ),
            finite_abs(
                "m2_ppm",
                spec.m2_ppm,
                1e5,
                "must be finite and |m2| <= 1e5 ppm",
            ),
            finite_abs(
                "m31_ppm_per_g",
                spec.m31_ppm_per_g,
                1e4,
                "must be finite and |m31| <= 1e4 ppm/g",
            ),
            finite_abs(
                "m32_ppm_per_g",
                spec.m32_ppm_per_g,
                1e4,
                "must be finite and |m32| <= 1e4 ppm/g",
            ),
        ];
        let mut problems: Vec<String> = rules
            .iter()
            .filter(|r| !r.ok)
            .map(|r| format!("{} = {}: {}", r.key, r.value, r.rule))
            .collect();
        if spec.id.is_empty() || spec.id.len() > 32 {
            problems.push(format!("id = {:?}: must be 1 to 32 bytes long", spec.id));
        }
        if spec.lambda.len() > MAX_LAMBDA_POINTS {
            problems.push(format!(
                "lambda: {} points: at most {MAX_LAMBDA_POINTS} are allowed",
                spec.lambda.len()
            ));
        }
        let mut previous_hz = 0.0;
        for (i, p) in spec.lambda.iter().enumerate() {
            if !(p.freq_hz.is_finite() && p.freq_hz > previous_hz) {
                problems.push(format!(
                    "lambda[{i}].freq_hz = {}: must be finite, > 0 and strictly increasing",
                    p.freq_hz
                ));
            }
            if !(p.lambda.is_finite() && p.lambda > 0.0 && p.lambda <= 10.0) {
                problems.push(format!(
                    "lambda[{i}].lambda = {}: must be finite and 0 < lambda <= 10",
                    p.lambda
                ));
            }
            if p.freq_hz.is_finite() {
                previous_hz = p.freq_hz;
            }
        }
        if !problems.is_empty() {
            return Err(Error::InvalidPassport { problems });
        }
        let mut id = [0u8; 32];
        id[..spec.id.len()].copy_from_slice(spec.id.as_bytes());
        let mut lambda = [LambdaPoint {
            freq_hz: 0.0,
            lambda: 1.0,
        }; MAX_LAMBDA_POINTS];
        lambda[..spec.lambda.len()].copy_from_slice(&spec.lambda);
        Ok(Self {
            id,
            id_len: spec.id.len(),
            a0_g: spec.a0_g,
            k1: spec.k1,
            k1_v_per_g: spec.k1_v_per_g,
            d1a: spec.d1a_ppm / PER_PPM,
            k: [
                0.0,
                0.0,
                spec.k2_ppm_per_g / PER_PPM,
                spec.k3_ppm_per_g2 / PER_PPM,
                spec.k4_ppm_per_g3 / PER_PPM,
                spec.k5_ppm_per_g4 / PER_PPM,
            ],
            m1: spec.m1_ppm / PER_PPM,
            m2: spec.m2_ppm / PER_PPM,
            m31_per_g: spec.m31_ppm_per_g / PER_PPM,
            m32_per_g: spec.m32_ppm_per_g / PER_PPM,
            lambda,
            lambda_len: spec.lambda.len(),
        })
    }

    /// The passport back in its quoted units (for writing extended models and JSON).
    pub fn to_spec(&self) -> PassportSpec {
        PassportSpec {
            id: self.id().to_string(),
            a0_g: self.a0_g,
            k1: self.k1,
            k1_v_per_g: self.k1_v_per_g,
            d1a_ppm: self.d1a * PER_PPM,
            k2_ppm_per_g: self.k[2] * PER_PPM,
            k3_ppm_per_g2: self.k[3] * PER_PPM,
            k4_ppm_per_g3: self.k[4] * PER_PPM,
            k5_ppm_per_g4: self.k[5] * PER_PPM,
            m1_ppm: self.m1 * PER_PPM,
            m2_ppm: self.m2 * PER_PPM,
            m31_ppm_per_g: self.m31_per_g * PER_PPM,
            m32_ppm_per_g: self.m32_per_g * PER_PPM,
            lambda: self.lambda[..self.lambda_len].to_vec(),
        }
    }

    /// The passport's identifier, e.g. `AL-15`.
    pub fn id(&self) -> &str {
        // Built from a `&str` in `try_from_spec`, so always valid UTF-8.
        std::str::from_utf8(&self.id[..self.id_len]).unwrap_or("?")
    }

    /// `lambda(f)`: piecewise-linear interpolation of the table through `(0, 1)`,
    /// held constant beyond its last point. `lambda(0) = 1` (MODEL.md section 1).
    pub fn lambda_at(&self, freq_hz: f64) -> f64 {
        let table = &self.lambda[..self.lambda_len];
        let f = freq_hz.abs();
        let (mut f0, mut l0) = (0.0, 1.0);
        for p in table {
            if f <= p.freq_hz {
                let t = (f - f0) / (p.freq_hz - f0);
                return l0 + t * (p.lambda - l0);
            }
            f0 = p.freq_hz;
            l0 = p.lambda;
        }
        l0
    }

    /// A copy with every coefficient of the VE model set to zero but the linear
    /// ones (`a0`, `k1`, `K1`): the "ideal" unit, handy in tests and requirements.
    pub fn linear_only(&self) -> Self {
        Self {
            d1a: 0.0,
            k: [0.0; 6],
            m1: 0.0,
            m2: 0.0,
            m31_per_g: 0.0,
            m32_per_g: 0.0,
            ..*self
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::al15_spec;

    #[test]
    fn quoted_units_convert_to_acceleration_units() {
        let p = Passport::try_from_spec(&al15_spec()).unwrap();
        assert_eq!(p.k[2], 105e-6);
        assert_eq!(p.m1, 1.15e-3);
        assert_eq!(p.id(), "AL-15");
        assert_eq!(p.to_spec(), al15_spec());
    }

    #[test]
    fn every_broken_rule_is_reported_with_its_value() {
        let mut s = al15_spec();
        s.k2_ppm_per_g = -1e9;
        s.k1 = f64::NAN;
        s.lambda = vec![
            LambdaPoint {
                freq_hz: 100.0,
                lambda: 1.1,
            },
            LambdaPoint {
                freq_hz: 50.0,
                lambda: 1.0,
            },
        ];
        let Err(Error::InvalidPassport { problems }) = Passport::try_from_spec(&s) else {
            panic!("expected an invalid passport");
        };
        assert_eq!(problems.len(), 3, "{problems:?}");
        assert!(problems[0].starts_with("k1 = NaN"));
        assert!(problems[1].starts_with("k2_ppm_per_g = -1000000000: must be finite"));
        assert!(problems[2].starts_with("lambda[1].freq_hz = 50"));
    }

    #[test]
    fn lambda_interpolates_through_one_at_dc() {
        let mut s = al15_spec();
        s.lambda = vec![
            LambdaPoint {
                freq_hz: 100.0,
                lambda: 1.2,
            },
            LambdaPoint {
                freq_hz: 300.0,
                lambda: 1.0,
            },
        ];
        let p = Passport::try_from_spec(&s).unwrap();
        assert_eq!(p.lambda_at(0.0), 1.0);
        assert!((p.lambda_at(50.0) - 1.1).abs() < 1e-15);
        assert!((p.lambda_at(200.0) - 1.1).abs() < 1e-15);
        assert_eq!(p.lambda_at(1000.0), 1.0);
    }
}
