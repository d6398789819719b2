//! Weighted least squares for any set of test positions: the six components at one
//! amplitude ([`wls_components`]) or the passport terms at any amplitudes
//! ([`wls_coefficients`]).

use crate::components::{
    sigma_from_covariance, Components, ComponentsEstimate, Method, UncertaintyBasis,
    COMPONENT_NAMES,
};
use crate::linalg::{solve_wls, LsFit};
use crate::positions::{validate_all, validate_k1, Amplitudes, TestPosition};
use crate::{Error, Result};
use nalgebra::DMatrix;
use serde::Serialize;

/// Options of the least-squares methods.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WlsOptions {
    /// Smallest accepted ratio of the smallest to the largest singular value of the
    /// column-scaled weighted design; below it the design is rank-deficient and the
    /// unknowns it cannot separate are named in the error. Default `1e-10`.
    pub rcond_min: f64,
    /// Relative tolerance within which two amplitudes count as the same (component-level
    /// WLS, closed form). Default `1e-9`: amplitudes are set values, typed the same.
    pub amplitude_rel_tol: f64,
}

impl Default for WlsOptions {
    fn default() -> Self {
        Self {
            rcond_min: 1e-10,
            amplitude_rel_tol: 1e-9,
        }
    }
}

impl WlsOptions {
    fn validate(&self) -> Result<()> {
        if !(self.rcond_min > 0.0 && self.rcond_min < 1.0) {
            return Err(Error::InvalidArgument {
                name: "rcond_min",
                value: self.rcond_min,
                rule: "must be within 0 < rcond_min < 1",
            });
        }
        if !(self.amplitude_rel_tol >= 0.0 && self.amplitude_rel_tol < 1.0) {
            return Err(Error::InvalidArgument {
                name: "amplitude_rel_tol",
                value: self.amplitude_rel_tol,
                rule: "must be within 0 <= amplitude_rel_tol < 1",
            });
        }
        Ok(())
    }
}

/// `d dV / d components` of a position: `(1, 1, 1, g3, g3^2, g3^3)` [P1 (21)].
pub(crate) fn position_gradient(g3_g: f64) -> [f64; 6] {
    [1.0, 1.0, 1.0, g3_g, g3_g * g3_g, g3_g * g3_g * g3_g]
}

/// Row of the component-level design [P1 (21)] generalised to any position:
/// `dU/K1 = d0(1)*[aB3>0] + d0(2)*[aB1>0] + d0(3)*[aB2>0] + delta(1)*g3 + delta(2)*g3^2
/// + delta(3)*g3^3` (every position of this method has `aB3 > 0`).
pub(crate) fn component_row(p: &TestPosition) -> [f64; 6] {
    let mut row = position_gradient(p.g3_g());
    let on = |a: f64| if a > 0.0 { 1.0 } else { 0.0 };
    row[0] *= on(p.amplitudes.a_b3_g);
    row[1] *= on(p.amplitudes.a_b1_g);
    row[2] *= on(p.amplitudes.a_b2_g);
    row
}

/// Checks that the non-zero amplitudes along one axis agree; returns the common value.
pub(crate) fn common_amplitude(
    positions: &[TestPosition],
    axis: &'static str,
    get: impl Fn(&Amplitudes) -> f64,
    rel_tol: f64,
) -> Result<f64> {
    let mut first: Option<(usize, f64)> = None;
    for (i, p) in positions.iter().enumerate() {
        let a = get(&p.amplitudes);
        if a == 0.0 {
            continue;
        }
        match first {
            None => first = Some((i, a)),
            Some((first_index, first_g)) => {
                if (a - first_g).abs() > rel_tol * first_g.abs().max(a.abs()) {
                    return Err(Error::MixedAmplitudes {
                        axis,
                        first_g,
                        first_index,
                        other_g: a,
                        other_index: i,
                    });
                }
            }
        }
    }
    Ok(first.map_or(0.0, |(_, a)| a))
}

/// Advice for unidentifiable components.
fn component_hint(unknowns: &[&'static str]) -> String {
    let mut advice = Vec::new();
    if unknowns.contains(&"d02_g") {
        advice.push(
            "d02_g needs a position with vibration along OA (TP9: IA horizontal, aB on IA and OA)",
        );
    }
    if unknowns.contains(&"d03_g") {
        advice.push(
            "d03_g needs a position with vibration along PA (TP10: IA horizontal, aB on IA and PA)",
        );
    }
    if unknowns
        .iter()
        .any(|u| matches!(*u, "d01_g" | "delta1" | "delta2_per_g" | "delta3_per_g2"))
    {
        advice.push(
            "d01_g and delta(1..3) need at least four distinct gravity projections \
             g3 = cos(angle) among the positions (e.g. TP1..TP8 at (k-1)*45 deg)",
        );
    }
    advice.join("; ")
}

/// Builds the covariance and basis of a fit in the units of its unknowns; `y` was
/// `dU/K1` so the residual scatter is converted back to volts with `|K1|`.
fn covariance_of(
    fit: &LsFit,
    given: bool,
    n: usize,
    p: usize,
    k1_v_per_g: f64,
) -> (Option<DMatrix<f64>>, UncertaintyBasis) {
    let dof = n - p;
    if given {
        return (
            Some(fit.cov_unscaled.clone()),
            UncertaintyBasis::Given {
                chi2: fit.weighted_rss,
                dof,
            },
        );
    }
    if dof == 0 {
        return (
            None,
            UncertaintyBasis::Unknown {
                reason: format!(
                    "no standard uncertainties of dU were given and the {n} positions \
                     exactly determine the {p} unknowns (0 degrees of freedom), so the \
                     residuals say nothing about the noise"
                ),
            },
        );
    }
    let variance = fit.weighted_rss / dof as f64;
    (
        Some(&fit.cov_unscaled * variance),
        UncertaintyBasis::ResidualScatter {
            dof,
            du_sigma_v: variance.sqrt() * k1_v_per_g.abs(),
        },
    )
}

fn to_array6(m: &DMatrix<f64>) -> [[f64; 6]; 6] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

fn to_array7(m: &DMatrix<f64>) -> [[f64; 7]; 7] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// The least-squares fit of the components at one amplitude, also used by the closed
/// form for its residual scatter.
pub(crate) struct ComponentFit {
    pub fit: LsFit,
    pub amplitudes: Amplitudes,
    pub sigma_y_g: Option<Vec<f64>>,
}

pub(crate) fn fit_components(
    positions: &[TestPosition],
    k1_v_per_g: f64,
    options: &WlsOptions,
) -> Result<ComponentFit> {
    options.validate()?;
    validate_k1(k1_v_per_g)?;
    let sigmas_v = validate_all(positions)?;
    for (index, p) in positions.iter().enumerate() {
        if p.amplitudes.a_b3_g <= 0.0 {
            return Err(Error::InvalidPosition {
                index,
                tp: p.tp,
                field: "aB3_g",
                value: p.amplitudes.a_b3_g,
                rule: "the component-level WLS needs vibration along IA (aB3 > 0) in every \
                       position; use the coefficient-level WLS for positions without it",
            });
        }
    }
    let tol = options.amplitude_rel_tol;
    let amplitudes = Amplitudes {
        a_b3_g: common_amplitude(positions, "IA (aB3_g)", |a| a.a_b3_g, tol)?,
        a_b1_g: common_amplitude(positions, "OA (aB1_g)", |a| a.a_b1_g, tol)?,
        a_b2_g: common_amplitude(positions, "PA (aB2_g)", |a| a.a_b2_g, tol)?,
    };
    let n = positions.len();
    let design = DMatrix::from_fn(n, 6, |i, j| component_row(&positions[i])[j]);
    let y: Vec<f64> = positions.iter().map(|p| p.du_v / k1_v_per_g).collect();
    let sigma_y_g: Option<Vec<f64>> =
        sigmas_v.map(|s| s.iter().map(|s| s / k1_v_per_g.abs()).collect());
    let fit = solve_wls(
        &design,
        &y,
        sigma_y_g.as_deref(),
        &COMPONENT_NAMES,
        options.rcond_min,
        component_hint,
    )?;
    Ok(ComponentFit {
        fit,
        amplitudes,
        sigma_y_g,
    })
}

/// The six VE components by weighted least squares over ANY set of test positions
/// (any angles, any subset, repeats), all at one vibration amplitude along IA
/// (and one along OA, one along PA where there is any), MODEL.md section 9.
///
/// Model: (21) generalised, `dU_k/K1 = d0(1) + d0(2)*[aB1>0] + d0(3)*[aB2>0] +
/// delta(1)*g3 + delta(2)*g3^2 + delta(3)*g3^3` with `g3 = cos(angle)`.
/// Weights are `1/sigma_k^2` when the positions carry standard uncertainties; otherwise
/// unit weights, with the covariance scaled by the residual variance
/// (`dof = n - 6`), and unknown (`None`) when `dof = 0`.
///
/// Errors: [`Error::MixedAmplitudes`] when amplitudes differ (the components scale
/// with them: use [`wls_coefficients`]), [`Error::Unidentifiable`] naming the
/// components the positions cannot separate (e.g. `d02_g` without TP9).
pub fn wls_components(
    positions: &[TestPosition],
    k1_v_per_g: f64,
    options: &WlsOptions,
) -> Result<ComponentsEstimate> {
    let ComponentFit {
        fit,
        amplitudes,
        sigma_y_g,
    } = fit_components(positions, k1_v_per_g, options)?;
    let (cov, basis) = covariance_of(&fit, sigma_y_g.is_some(), positions.len(), 6, k1_v_per_g);
    let covariance = cov.as_ref().map(to_array6);
    let components = Components::from_array(std::array::from_fn(|i| fit.x[i]));
    Ok(ComponentsEstimate {
        method: Method::Wls,
        amplitudes,
        components,
        sigma: covariance.as_ref().map(sigma_from_covariance),
        covariance,
        basis,
        n_positions: positions.len(),
        residuals_v: fit.residuals.iter().map(|r| r * k1_v_per_g).collect(),
        condition_number: Some(fit.condition),
    })
}

/// Names of the passport terms, in the order of [`PassportTerms::to_array`] and of the
/// rows and columns of [`CoefficientEstimate::covariance`].
pub const TERM_NAMES: [&str; 7] = [
    "c_asym",
    "k2_per_g",
    "k3_per_g2",
    "k4_per_g3",
    "k5_per_g4",
    "m31_per_g",
    "m32_per_g",
];

/// The passport terms that the deterministic VE of MODEL.md section 5 depends on
/// [P1 (15)-(16)]. Also used for their standard uncertainties (same units).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct PassportTerms {
    /// `c_asym = 0.637*lambda*k1*d1A`, dimensionless: the asymmetry term per g of IA
    /// vibration amplitude. The shake table sees only this product.
    pub c_asym: f64,
    pub k2_per_g: f64,
    pub k3_per_g2: f64,
    pub k4_per_g3: f64,
    pub k5_per_g4: f64,
    pub m31_per_g: f64,
    pub m32_per_g: f64,
}

impl PassportTerms {
    /// The terms in the order of [`TERM_NAMES`].
    pub fn to_array(&self) -> [f64; 7] {
        [
            self.c_asym,
            self.k2_per_g,
            self.k3_per_g2,
            self.k4_per_g3,
            self.k5_per_g4,
            self.m31_per_g,
            self.m32_per_g,
        ]
    }

    /// The inverse of [`PassportTerms::to_array`].
    pub fn from_array(x: [f64; 7]) -> Self {
        Self {
            c_asym: x[0],
            k2_per_g: x[1],
            k3_per_g2: x[2],
            k4_per_g3: x[3],
            k5_per_g4: x[4],
            m31_per_g: x[5],
            m32_per_g: x[6],
        }
    }

    /// The deterministic VE components at these amplitudes, MODEL.md section 5
    /// [P1 (13), (15)-(16)].
    pub fn components_at(&self, amplitudes: Amplitudes) -> Components {
        let j = terms_jacobian(amplitudes);
        let t = self.to_array();
        Components::from_array(std::array::from_fn(|i| {
            (0..7).map(|k| j[i][k] * t[k]).sum()
        }))
    }
}

/// `d components / d terms` at the given amplitudes: the components are linear in the
/// terms [P1 (15)-(16)]:
///
/// ```text
/// d0(1)    = c_asym*aB3 + 0.5*k2*aB3^2 + 0.375*k4*aB3^4
/// d0(2)    = 0.5*m31*aB3*aB1          d0(3) = 0.5*m32*aB3*aB2
/// delta(1) = 1.5*k3*aB3^2 + 1.875*k5*aB3^4
/// delta(2) = 3*k4*aB3^2               delta(3) = 5*k5*aB3^2
/// ```
fn terms_jacobian(a: Amplitudes) -> [[f64; 7]; 6] {
    let a3 = a.a_b3_g;
    let a3_2 = a3 * a3;
    let a3_4 = a3_2 * a3_2;
    [
        [a3, 0.5 * a3_2, 0.0, 0.375 * a3_4, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.5 * a3 * a.a_b1_g, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5 * a3 * a.a_b2_g],
        [0.0, 0.0, 1.5 * a3_2, 0.0, 1.875 * a3_4, 0.0, 0.0],
        [0.0, 0.0, 0.0, 3.0 * a3_2, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 5.0 * a3_2, 0.0, 0.0],
    ]
}

/// Advice for unidentifiable passport terms.
fn term_hint(unknowns: &[&'static str]) -> String {
    let mut advice = Vec::new();
    if unknowns.contains(&"c_asym") || unknowns.contains(&"k2_per_g") {
        advice.push(
            "c_asym (aB3) and k2 (0.5*aB3^2) are separated only by positions at two or \
             more distinct IA amplitudes aB3",
        );
    }
    if unknowns.contains(&"m31_per_g") {
        advice.push("m31 needs a position with vibration along IA and OA (TP9)");
    }
    if unknowns.contains(&"m32_per_g") {
        advice.push("m32 needs a position with vibration along IA and PA (TP10)");
    }
    if unknowns
        .iter()
        .any(|u| matches!(*u, "k3_per_g2" | "k4_per_g3" | "k5_per_g4"))
    {
        advice.push(
            "k3, k4, k5 need at least four distinct gravity projections g3 = cos(angle) \
             under IA vibration (e.g. TP1..TP8)",
        );
    }
    advice.join("; ")
}

/// The passport terms identified by [`wls_coefficients`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CoefficientEstimate {
    pub terms: PassportTerms,
    /// Standard uncertainties, same units; `None` when unknown (see `basis`).
    pub sigma: Option<PassportTerms>,
    /// Covariance in the order of [`TERM_NAMES`]; `None` when unknown.
    pub covariance: Option<[[f64; 7]; 7]>,
    pub basis: UncertaintyBasis,
    pub n_positions: usize,
    /// `dU_k - K1*(model)` for each position, in the order given, V.
    pub residuals_v: Vec<f64>,
    /// Condition number of the column-scaled weighted design.
    pub condition_number: f64,
    /// The distinct IA amplitudes among the positions, g, ascending.
    pub a_b3_levels_g: Vec<f64>,
}

impl CoefficientEstimate {
    /// The components at any amplitudes, with covariance `J C J^T` where `J` is the
    /// (exact, linear) map of section 5 from terms to components.
    pub fn components_at(&self, amplitudes: Amplitudes) -> ComponentsEstimate {
        let j = terms_jacobian(amplitudes);
        let covariance = self.covariance.map(|c| {
            std::array::from_fn(|r| {
                std::array::from_fn(|s| {
                    let mut sum = 0.0;
                    for a in 0..7 {
                        for b in 0..7 {
                            sum += j[r][a] * c[a][b] * j[s][b];
                        }
                    }
                    sum
                })
            })
        });
        ComponentsEstimate {
            method: Method::CoefficientWls,
            amplitudes,
            components: self.terms.components_at(amplitudes),
            sigma: covariance.as_ref().map(sigma_from_covariance),
            covariance,
            basis: self.basis.clone(),
            n_positions: self.n_positions,
            residuals_v: self.residuals_v.clone(),
            condition_number: Some(self.condition_number),
        }
    }
}

/// The passport terms of MODEL.md section 5 (`c_asym, k2, k3, k4, k5, m31, m32`) by
/// weighted least squares over test positions at ANY vibration amplitudes.
///
/// Each position contributes `dU_k/K1 = h(g3)^T J(aB) t`, i.e. section 5's components
/// at its own amplitudes summed as in (21), with `h = (1, 1, 1, g3, g3^2, g3^3)`; a
/// position without vibration along OA has `aB1 = 0` and so no `d0(2)`. Positions
/// with `aB3 = 0` carry no information on the terms but count in the residual scatter.
/// Weights and uncertainties as in [`wls_components`] (`dof = n - 7`).
///
/// Identifiability: `c_asym*aB3` and `0.5*k2*aB3^2` are separated only by two or more
/// distinct `aB3`; with one amplitude the error names both. With two amplitudes and
/// the ten positions at each, all seven terms are identifiable.
pub fn wls_coefficients(
    positions: &[TestPosition],
    k1_v_per_g: f64,
    options: &WlsOptions,
) -> Result<CoefficientEstimate> {
    options.validate()?;
    validate_k1(k1_v_per_g)?;
    let sigmas_v = validate_all(positions)?;
    let n = positions.len();
    let rows: Vec<[f64; 7]> = positions
        .iter()
        .map(|p| {
            let h = position_gradient(p.g3_g());
            let j = terms_jacobian(p.amplitudes);
            std::array::from_fn(|k| (0..6).map(|i| h[i] * j[i][k]).sum())
        })
        .collect();
    let design = DMatrix::from_fn(n, 7, |i, k| rows[i][k]);
    let y: Vec<f64> = positions.iter().map(|p| p.du_v / k1_v_per_g).collect();
    let sigma_y_g: Option<Vec<f64>> = sigmas_v
        .as_ref()
        .map(|s| s.iter().map(|s| s / k1_v_per_g.abs()).collect());
    let fit = solve_wls(
        &design,
        &y,
        sigma_y_g.as_deref(),
        &TERM_NAMES,
        options.rcond_min,
        term_hint,
    )?;
    let (cov, basis) = covariance_of(&fit, sigmas_v.is_some(), n, 7, k1_v_per_g);
    let covariance = cov.as_ref().map(to_array7);
    let mut levels: Vec<f64> = Vec::new();
    let tol = options.amplitude_rel_tol;
    for p in positions {
        let a = p.amplitudes.a_b3_g;
        if a > 0.0 && !levels.iter().any(|l| (l - a).abs() <= tol * l.max(a)) {
            levels.push(a);
        }
    }
    levels.sort_by(f64::total_cmp);
    Ok(CoefficientEstimate {
        terms: PassportTerms::from_array(std::array::from_fn(|i| fit.x[i])),
        sigma: covariance
            .as_ref()
            .map(|c| PassportTerms::from_array(std::array::from_fn(|i| c[i][i].max(0.0).sqrt()))),
        covariance,
        basis,
        n_positions: n,
        residuals_v: fit.residuals.iter().map(|r| r * k1_v_per_g).collect(),
        condition_number: fit.condition,
        a_b3_levels_g: levels,
    })
}
