//! Requirements on the passport coefficients, MODEL.md section 10, [P2 (6)-(15)].
//!
//! The budget `D*` is split as the paper does (10)-(14): each additive term may use
//! `0.44 D*` (`m31`, `m32`: `0.22 D*`), the multiplicative terms linear in `aL3` use
//! `0.35 D*` and those in `aL3^2`, `aL3^3` use `0.24 D*`. The allowed modulus of a
//! coefficient is its share divided by the VE that a unit value of that coefficient
//! produces in its term.
//!
//! - [`paper`]: the printed formulas (13), (15).
//! - [`exact`]: the same shares, with each term's VE per unit coefficient from the exact
//!   means of MODEL.md section 6 (one tone of amplitude `aB3` and Gaussian random
//!   vibration of RMS `sigma3` on IA): `E[v^2] = aB3^2/2 + sigma3^2`,
//!   `E[v^4] = 3 aB3^4/8 + 3 aB3^2 sigma3^2 + 3 sigma3^4`, and the asymmetry term
//!   `0.5 (E|aL3 + v| - |aL3|)`. For `m31`, `m32` both use the paper's worst case
//!   `K_31(0) = sigma3^2` (random vibration fully correlated between the axes, equal RMS),
//!   so the two methods agree there. For `k2`, `k3`, `k4` (multiplicative) and `k5`
//!   (in `aL3^3`) the paper's formulas are already exact; they differ for `d1A`, `k4`
//!   (additive) and `k5` (in `aL3`).

use crate::abs_mean::AbsMean;
use crate::{Error, Result};
use serde::Serialize;

/// The environment and budget of a requirement (MODEL.md section 10).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Environment {
    /// Allowed VE `D*`, g.
    pub d_star_g: f64,
    /// Mean flight acceleration along IA, g.
    pub a_l3_g: f64,
    /// Deterministic vibration amplitudes `[aB1, aB2, aB3]`, g.
    pub ab_g: [f64; 3],
    /// RMS random vibration along IA seen by the unit, g.
    pub sigma3_g: f64,
}

impl Environment {
    fn validate(&self) -> Result<()> {
        let check = |name, value: f64, ok: bool, rule| {
            if ok {
                Ok(())
            } else {
                Err(Error::InvalidArgument { name, value, rule })
            }
        };
        check(
            "dstar_g",
            self.d_star_g,
            self.d_star_g.is_finite() && self.d_star_g > 0.0,
            "must be finite and > 0",
        )?;
        check(
            "aL3_g",
            self.a_l3_g,
            self.a_l3_g.is_finite(),
            "must be finite",
        )?;
        check(
            "sigma3_g",
            self.sigma3_g,
            self.sigma3_g.is_finite() && self.sigma3_g >= 0.0,
            "must be finite and >= 0",
        )?;
        for (name, v) in [
            ("aB1_g", self.ab_g[0]),
            ("aB2_g", self.ab_g[1]),
            ("aB3_g", self.ab_g[2]),
        ] {
            check(
                name,
                v,
                v.is_finite() && v >= 0.0,
                "must be finite and >= 0",
            )?;
        }
        Ok(())
    }
}

/// One allowed modulus.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Requirement {
    /// Coefficient and term, e.g. `k4 (additive)`.
    pub coefficient: &'static str,
    /// The key of the coefficient in a passport file, e.g. `k4_ppm_per_g3`.
    pub passport_key: &'static str,
    /// Share of `D*` given to the term.
    pub share: f64,
    /// VE of the term per unit coefficient (in acceleration units), g.
    pub ve_per_unit_g: f64,
    /// Allowed modulus in passport units (ppm, ppm/g, ...); infinite when the term
    /// vanishes in this environment.
    pub allowed: f64,
    /// The passport unit of `allowed`.
    pub unit: &'static str,
}

struct Term {
    coefficient: &'static str,
    passport_key: &'static str,
    share: f64,
    unit: &'static str,
}

const TERMS: [Term; 9] = [
    Term {
        coefficient: "d1A",
        passport_key: "d1a_ppm",
        share: 0.44,
        unit: "ppm",
    },
    Term {
        coefficient: "k2",
        passport_key: "k2_ppm_per_g",
        share: 0.44,
        unit: "ppm/g",
    },
    Term {
        coefficient: "k4 (additive)",
        passport_key: "k4_ppm_per_g3",
        share: 0.44,
        unit: "ppm/g^3",
    },
    Term {
        coefficient: "m31",
        passport_key: "m31_ppm_per_g",
        share: 0.22,
        unit: "ppm/g",
    },
    Term {
        coefficient: "m32",
        passport_key: "m32_ppm_per_g",
        share: 0.22,
        unit: "ppm/g",
    },
    Term {
        coefficient: "k3",
        passport_key: "k3_ppm_per_g2",
        share: 0.35,
        unit: "ppm/g^2",
    },
    Term {
        coefficient: "k5 (in aL3)",
        passport_key: "k5_ppm_per_g4",
        share: 0.35,
        unit: "ppm/g^4",
    },
    Term {
        coefficient: "k4 (in aL3^2)",
        passport_key: "k4_ppm_per_g3",
        share: 0.24,
        unit: "ppm/g^3",
    },
    Term {
        coefficient: "k5 (in aL3^3)",
        passport_key: "k5_ppm_per_g4",
        share: 0.24,
        unit: "ppm/g^4",
    },
];

fn assemble(env: &Environment, ve_per_unit_g: [f64; 9]) -> Vec<Requirement> {
    TERMS
        .iter()
        .zip(ve_per_unit_g)
        .map(|(t, ve)| Requirement {
            coefficient: t.coefficient,
            passport_key: t.passport_key,
            share: t.share,
            ve_per_unit_g: ve,
            allowed: if ve.abs() > 0.0 {
                t.share * env.d_star_g / ve.abs() * 1e6
            } else {
                f64::INFINITY
            },
            unit: t.unit,
        })
        .collect()
}

/// The paper's allowed moduli, [P2 (13), (15)].
pub fn paper(env: &Environment) -> Result<Vec<Requirement>> {
    env.validate()?;
    let [ab1, ab2, ab3] = env.ab_g;
    let (s, a) = (env.sigma3_g, env.a_l3_g);
    let (s2, ab3_2) = (s * s, ab3 * ab3);
    Ok(assemble(
        env,
        [
            0.637 * ab3 + 0.125 * s,
            0.5 * ab3_2 + s2,
            0.375 * ab3_2 * ab3_2 + s2 * s2,
            0.5 * ab3 * ab1 + s2,
            0.5 * ab3 * ab2 + s2,
            a * (1.5 * ab3_2 + 3.0 * s2),
            a * (1.875 * ab3_2 * ab3_2 + 5.0 * s2 * s2),
            3.0 * a * a * (ab3_2 + 2.0 * s2),
            5.0 * a.powi(3) * (ab3_2 + 2.0 * s2),
        ],
    ))
}

/// Allowed moduli from the exact model, same shares (see the module doc).
pub fn exact(env: &Environment) -> Result<Vec<Requirement>> {
    env.validate()?;
    let [ab1, ab2, ab3] = env.ab_g;
    let (s, a) = (env.sigma3_g, env.a_l3_g);
    let (s2, ab3_2) = (s * s, ab3 * ab3);
    let m2 = 0.5 * ab3_2 + s2;
    let m4 = 0.375 * ab3_2 * ab3_2 + 3.0 * ab3_2 * s2 + 3.0 * s2 * s2;
    let mut abs = AbsMean::new();
    abs.set_direct(&[ab3], s, 3.0)?;
    let asym = 0.5 * (abs.eval(a).0 - a.abs());
    Ok(assemble(
        env,
        [
            asym,
            m2,
            m4,
            0.5 * ab3 * ab1 + s2,
            0.5 * ab3 * ab2 + s2,
            3.0 * m2 * a,
            5.0 * m4 * a,
            6.0 * m2 * a * a,
            10.0 * m2 * a.powi(3),
        ],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exact::exact_ve;
    use crate::passport::Passport;
    use crate::testutil::al15;
    use crate::vibration::Vibration;

    /// MODEL.md section 10's example (Cyclone-4): D* = 5e-4 g, aL3 = 2 g, aB3 = 0.5 g,
    /// aB1 = aB2 = 1.2 g, sigma3 = 1.4 g give [d1A] = 445 ppm and [m31] = 48 ppm/g (the
    /// paper truncates: the formulas give 445.8 and 48.7).
    fn cyclone4() -> Environment {
        Environment {
            d_star_g: 5e-4,
            a_l3_g: 2.0,
            ab_g: [1.2, 1.2, 0.5],
            sigma3_g: 1.4,
        }
    }

    #[test]
    fn reproduces_the_papers_example() {
        let r = paper(&cyclone4()).unwrap();
        assert_eq!(r[0].allowed.floor(), 445.0);
        assert_eq!(r[3].allowed.floor(), 48.0);
        assert!((r[0].allowed - 0.44 * 5e-4 / (0.637 * 0.5 + 0.125 * 1.4) * 1e6).abs() < 1e-9);
    }

    /// Each exact limit is the largest coefficient for which its term of the exact VE
    /// stays within its share: a passport with only that coefficient, at the limit,
    /// produces exactly the share of D* in that term.
    #[test]
    fn exact_limits_spend_exactly_their_share() {
        let env = cyclone4();
        let r = exact(&env).unwrap();
        let mut vib = Vibration::single_tone(12.0, [1.2, 1.2, 0.5]);
        vib.covariance_g2[2][2] = 1.96;
        let mut only = al15().linear_only();
        // d1A: the whole VE of a passport with only d1A at its limit.
        only.d1a = r[0].allowed * 1e-6;
        let ve = exact_ve(&only, [0.0, 0.0, 2.0], &vib).unwrap();
        assert!(
            (ve.total_g - 0.44 * 5e-4).abs() < 1e-4 * 0.44 * 5e-4,
            "{}",
            ve.total_g
        );
        // k5: its aL3 term and its aL3^3 term.
        let mut only: Passport = al15().linear_only();
        only.k[5] = r[6].allowed * 1e-6;
        let ve = exact_ve(&only, [0.0, 0.0, 2.0], &vib).unwrap();
        assert!((ve.delta1 * 2.0 - 0.35 * 5e-4).abs() < 1e-12);
        only.k[5] = r[8].allowed * 1e-6;
        let ve = exact_ve(&only, [0.0, 0.0, 2.0], &vib).unwrap();
        assert!((ve.delta3_per_g2 * 8.0 - 0.24 * 5e-4).abs() < 1e-12);
        // k4 additive.
        let mut only = al15().linear_only();
        only.k[4] = r[2].allowed * 1e-6;
        let ve = exact_ve(&only, [0.0, 0.0, 2.0], &vib).unwrap();
        assert!((ve.d01_g - 0.44 * 5e-4).abs() < 1e-12);
        // Where the paper is exact, the two agree.
        let p = paper(&env).unwrap();
        for i in [1, 3, 4, 5, 7, 8] {
            assert!(
                (p[i].allowed - r[i].allowed).abs() < 1e-9 * p[i].allowed,
                "{}",
                p[i].coefficient
            );
        }
        // The paper's k4 sigma^4 (vs 3 sigma^4 + 3 aB^2 sigma^2) makes it too lenient.
        assert!(r[2].allowed < p[2].allowed / 2.5);
    }
}
