//! `empirical`: a correction of the VE fitted to a residual that no physical effect
//! of the library explains. **Not physical**: a low-order smooth function of the
//! vibration and the flight acceleration, chosen by cross-validation
//! (`vibro_lab::empirical`, docs/lab.md "Beyond the library"), usable by every
//! prediction (`vibrocomp model ve`, the compensator, the lab) like an effect, but
//! never simulated: the simulator's scenarios refuse it (it is not in
//! [`crate::catalogue`]), since it describes a mean, not a mechanism.
//!
//! The correction is `sum_k c_k phi_k`, each term `phi_k` a product of a second moment
//! of the vibration reaching the unit (so that it vanishes without vibration: a
//! campaign measures the vibrating record against the still ones, MODEL.md section 8,
//! and a static part cancels) with a low power of `aL3` or of the tone frequency. With
//! `P_i = sum_tones aB_i^2 / 2 + K_ii(0)` the vibration power along axis `i` and
//! `P_ij = sum_tones aB_i aB_j cos(phi_i - phi_j) / 2 + K_ij(0)` (MODEL.md section 6's
//! cross-term rule), the terms are [`TERMS`]; the frequency terms weight each tone's
//! IA power by `f / 100 Hz` (the random part has no single frequency and adds
//! nothing to them).
//!
//! ```toml
//! [[effect]]
//! kind = "empirical"
//! c_p3_al3_per_g2 = -1.2e-6
//! c_p1_al3_per_g2 = 3.0e-6
//! ```

use crate::effect::{Effect, MeanContext};
use crate::{Error, Result};
use vibro_physics::vibration::Vibration;

/// The `kind` of the correction's `[[effect]]` table.
pub const KIND: &str = "empirical";

/// One basis term of the correction: its coefficient's key (the coefficient's unit
/// is g of VE per unit of the term), what it is, and its value.
#[derive(Clone, Copy)]
pub struct Term {
    /// The coefficient's key in the `[[effect]]` table.
    pub key: &'static str,
    /// The term in words, with its unit.
    pub meaning: &'static str,
    /// The condition variables it follows (the lab's names).
    pub variables: &'static [&'static str],
    /// The term's value for the vibration at the unit and the flight acceleration.
    pub value: fn(&Vibration, [f64; 3]) -> f64,
}

impl std::fmt::Debug for Term {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Term").field("key", &self.key).finish()
    }
}

/// `P_i`, g^2.
fn power(v: &Vibration, i: usize) -> f64 {
    let tones: f64 = v
        .tones()
        .iter()
        .map(|t| 0.5 * t.amplitude_g[i] * t.amplitude_g[i])
        .sum();
    tones + v.covariance_g2[i][i]
}

/// `P_ij`, g^2.
fn cross(v: &Vibration, i: usize, j: usize) -> f64 {
    let tones: f64 = v
        .tones()
        .iter()
        .map(|t| {
            0.5 * t.amplitude_g[i] * t.amplitude_g[j] * (t.phase_rad[i] - t.phase_rad[j]).cos()
        })
        .sum();
    tones + v.covariance_g2[i][j]
}

/// `sum_tones aB3^2 / 2 (f / 100 Hz)^n`, g^2.
fn tone_power_f(v: &Vibration, n: i32) -> f64 {
    v.tones()
        .iter()
        .map(|t| 0.5 * t.amplitude_g[2] * t.amplitude_g[2] * (t.freq_hz / 100.0).powi(n))
        .sum()
}

/// The basis, lowest order first.
pub const TERMS: &[Term] = &[
    Term {
        key: "c_p3_per_g",
        meaning: "P3, the IA vibration power, g^2",
        variables: &["aB3_g", "sigma3_g"],
        value: |v, _| power(v, 2),
    },
    Term {
        key: "c_p1_per_g",
        meaning: "P1, the OA vibration power, g^2",
        variables: &["aB1_g", "sigma1_g"],
        value: |v, _| power(v, 0),
    },
    Term {
        key: "c_p2_per_g",
        meaning: "P2, the PA vibration power, g^2",
        variables: &["aB2_g", "sigma2_g"],
        value: |v, _| power(v, 1),
    },
    Term {
        key: "c_p13_per_g",
        meaning: "P13 = E[v1 v3], g^2",
        variables: &["aB1_g", "aB3_g", "phase31_deg"],
        value: |v, _| cross(v, 0, 2),
    },
    Term {
        key: "c_p23_per_g",
        meaning: "P23 = E[v2 v3], g^2",
        variables: &["aB2_g", "aB3_g", "phase32_deg"],
        value: |v, _| cross(v, 1, 2),
    },
    Term {
        key: "c_p3_al3_per_g2",
        meaning: "P3 aL3, g^3",
        variables: &["aB3_g", "sigma3_g", "aL3_g"],
        value: |v, a| power(v, 2) * a[2],
    },
    Term {
        key: "c_p1_al3_per_g2",
        meaning: "P1 aL3, g^3",
        variables: &["aB1_g", "sigma1_g", "aL3_g"],
        value: |v, a| power(v, 0) * a[2],
    },
    Term {
        key: "c_p2_al3_per_g2",
        meaning: "P2 aL3, g^3",
        variables: &["aB2_g", "sigma2_g", "aL3_g"],
        value: |v, a| power(v, 1) * a[2],
    },
    Term {
        key: "c_p3_al3sq_per_g3",
        meaning: "P3 aL3^2, g^4",
        variables: &["aB3_g", "sigma3_g", "aL3_g"],
        value: |v, a| power(v, 2) * a[2] * a[2],
    },
    Term {
        key: "c_p3sq_per_g3",
        meaning: "P3^2, g^4",
        variables: &["aB3_g", "sigma3_g"],
        value: |v, _| power(v, 2) * power(v, 2),
    },
    Term {
        key: "c_p3_f100_per_g",
        meaning: "sum over tones of aB3^2/2 (f / 100 Hz), g^2",
        variables: &["aB3_g", "freq_hz"],
        value: |v, _| tone_power_f(v, 1),
    },
    Term {
        key: "c_p3_f100sq_per_g",
        meaning: "sum over tones of aB3^2/2 (f / 100 Hz)^2, g^2",
        variables: &["aB3_g", "freq_hz"],
        value: |v, _| tone_power_f(v, 2),
    },
];

/// The largest coefficient accepted, g per unit of the term: a correction of 1 g per
/// g^2 of vibration is far beyond any VE (RIG.md's largest are tenths of a g at tens
/// of g^2).
pub const MAX_COEFFICIENT: f64 = 1.0;

/// An empirical correction: its terms' indices in [`TERMS`] and coefficients.
#[derive(Debug, Clone, PartialEq)]
pub struct Empirical {
    pub terms: Vec<(usize, f64)>,
}

impl Empirical {
    /// Reads and validates an `[[effect]]` table of kind `empirical`: every key a
    /// coefficient of [`TERMS`], finite, `|c| <= MAX_COEFFICIENT`; all problems at once.
    pub fn from_table(t: &toml::Table) -> Result<Self> {
        let mut problems = Vec::new();
        let mut terms = Vec::new();
        for (key, value) in t {
            if key == "kind" {
                continue;
            }
            let Some(k) = TERMS.iter().position(|term| term.key == key) else {
                let keys: Vec<&str> = TERMS.iter().map(|t| t.key).collect();
                problems.push(Error::Invalid {
                    key: format!("effect[{KIND}].{key}"),
                    value: value.to_string(),
                    rule: format!("unknown term; expected one of {}", keys.join(", ")),
                });
                continue;
            };
            let c = value
                .as_float()
                .or_else(|| value.as_integer().map(|i| i as f64));
            match c {
                Some(c) if c.is_finite() && c.abs() <= MAX_COEFFICIENT => terms.push((k, c)),
                _ => problems.push(Error::Invalid {
                    key: format!("effect[{KIND}].{key}"),
                    value: value.to_string(),
                    rule: format!(
                        "must be a finite number with |c| <= {MAX_COEFFICIENT} g per unit of \
                         the term"
                    ),
                }),
            }
        }
        if t.get("kind").and_then(|k| k.as_str()) != Some(KIND) {
            problems.push(Error::Invalid {
                key: "effect.kind".into(),
                value: format!("{:?}", t.get("kind").map(|k| k.to_string())),
                rule: format!("must be {KIND:?}"),
            });
        }
        match problems.len() {
            0 => {
                terms.sort_by_key(|(k, _)| *k);
                Ok(Self { terms })
            }
            1 => Err(problems.remove(0)),
            _ => Err(Error::Several(problems)),
        }
    }

    /// The `[[effect]]` table (what [`Empirical::from_table`] reads back).
    pub fn to_table(&self) -> toml::Table {
        let mut t = toml::Table::new();
        t.insert("kind".into(), toml::Value::String(KIND.into()));
        for (k, c) in &self.terms {
            t.insert(TERMS[*k].key.into(), toml::Value::Float(*c));
        }
        t
    }

    /// The correction for the vibration at the unit and the flight acceleration, g.
    pub fn value_g(&self, vibration: &Vibration, a_l_unit_g: [f64; 3]) -> f64 {
        self.terms
            .iter()
            .map(|(k, c)| c * (TERMS[*k].value)(vibration, a_l_unit_g))
            .sum()
    }
}

impl Effect for Empirical {
    fn kind(&self) -> &'static str {
        KIND
    }

    /// The correction under the vibration reaching the unit (after the model's effects
    /// on the vibration path, as every effect off the path sees it). Every term
    /// vanishes without vibration, so the change the correction makes is its value.
    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        Ok(self.value_g(ctx.vibration_unit, ctx.a_l_unit_g))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_physics::vibration::Tone;

    fn table(text: &str) -> toml::Table {
        toml::from_str(text).unwrap()
    }

    /// Each term against its closed form, written out by hand for a vibration with
    /// two tones (phases between the axes) and a random part with covariances.
    #[test]
    fn each_term_is_its_closed_form() {
        let mut v = Vibration::none();
        v.push_tone(Tone {
            freq_hz: 40.0,
            amplitude_g: [1.0, 0.5, 2.0],
            phase_rad: [0.3, -0.2, 0.0],
        })
        .unwrap();
        v.push_tone(Tone {
            freq_hz: 150.0,
            amplitude_g: [0.0, 1.5, 1.0],
            phase_rad: [0.0, 1.0, 0.5],
        })
        .unwrap();
        v.covariance_g2 = [[0.2, 0.01, 0.05], [0.01, 0.3, -0.04], [0.05, -0.04, 0.4]];
        let a = [0.1, -0.2, 1.5];
        let p1 = 0.5 * 1.0 + 0.2;
        let p2 = 0.5 * (0.25 + 2.25) + 0.3;
        let p3 = 0.5 * (4.0 + 1.0) + 0.4;
        let p13 = 0.5 * 1.0 * 2.0 * (0.3f64).cos() + 0.05;
        let p23 = 0.5 * 0.5 * 2.0 * (-0.2f64).cos() + 0.5 * 1.5 * 1.0 * (0.5f64).cos() - 0.04;
        let f1 = 0.5 * 4.0 * 0.4 + 0.5 * 1.0 * 1.5;
        let f2 = 0.5 * 4.0 * 0.16 + 0.5 * 1.0 * 2.25;
        let want = [
            p3,
            p1,
            p2,
            p13,
            p23,
            p3 * 1.5,
            p1 * 1.5,
            p2 * 1.5,
            p3 * 2.25,
            p3 * p3,
            f1,
            f2,
        ];
        assert_eq!(TERMS.len(), want.len());
        for (term, w) in TERMS.iter().zip(want) {
            let got = (term.value)(&v, a);
            assert!((got - w).abs() < 1e-14, "{}: {got} vs {w}", term.key);
            assert_eq!((term.value)(&Vibration::none(), a), 0.0, "{}", term.key);
        }
    }

    #[test]
    fn a_table_round_trips_and_bad_keys_are_named_at_once() {
        let t = table("kind = \"empirical\"\nc_p3_al3_per_g2 = -1.5e-6\nc_p1_per_g = 2e-6");
        let e = Empirical::from_table(&t).unwrap();
        assert_eq!(e.terms.len(), 2);
        assert_eq!(Empirical::from_table(&e.to_table()).unwrap(), e);
        let err = Empirical::from_table(&table(
            "kind = \"empirical\"\nc_p9_per_g = 1.0\nc_p3_per_g = 5.0",
        ))
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("effect[empirical].c_p9_per_g = 1.0: unknown term"),
            "{err}"
        );
        assert!(
            err.contains("effect[empirical].c_p3_per_g = 5.0: must be a finite"),
            "{err}"
        );
    }
}
