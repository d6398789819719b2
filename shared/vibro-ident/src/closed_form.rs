//! The closed-form identification (22) over the ten standard test positions.

use crate::components::{
    sigma_from_covariance, Components, ComponentsEstimate, Method, UncertaintyBasis,
};
use crate::positions::{cos_deg, validate_all, validate_k1, Amplitudes, TestPosition};
use crate::wls::{common_amplitude, component_row, fit_components, WlsOptions};
use crate::{Error, Result};
use std::f64::consts::FRAC_1_SQRT_2 as R;

/// The closed form (22) [P1 (22)] as a matrix: `component_i = sum_k C[i][k]*dU_k/K1`
/// (with `g = 1 g`), rows in the order of [`crate::COMPONENT_NAMES`], columns TP1..TP10:
///
/// ```text
/// d0(1)    = (dU3 + dU7)/(2 K1)
/// d0(2)    = (dU9  - 0.5 (dU3 + dU7))/K1
/// d0(3)    = (dU10 - 0.5 (dU3 + dU7))/K1
/// delta(1) = ((dU2 + dU8 - dU4 - dU6)/sqrt2 - 0.5 (dU1 - dU5))/(K1 g)
/// delta(2) = (dU1 + dU2 + dU4 + dU5 + dU6 + dU8 - 3 (dU3 + dU7))/(4 K1 g^2)
/// delta(3) = (dU1 - dU5 - (dU2 + dU8 - dU4 - dU6)/sqrt2)/(K1 g^3)
/// ```
pub const CLOSED_FORM_COEFFICIENTS: [[f64; 10]; 6] = [
    [0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0],
    [0.0, 0.0, -0.5, 0.0, 0.0, 0.0, -0.5, 0.0, 1.0, 0.0],
    [0.0, 0.0, -0.5, 0.0, 0.0, 0.0, -0.5, 0.0, 0.0, 1.0],
    [-0.5, R, 0.0, -R, 0.5, -R, 0.0, R, 0.0, 0.0],
    [0.25, 0.25, -0.75, 0.25, 0.25, 0.25, -0.75, 0.25, 0.0, 0.0],
    [1.0, -R, 0.0, R, -1.0, R, 0.0, -R, 0.0, 0.0],
];

/// Angle tolerance for recognising a standard position, deg.
const ANGLE_TOL_DEG: f64 = 1e-6;

/// Finds TP1..TP10 among the positions (by geometry, in any order): returns the index
/// of each in `positions`, and the amplitudes.
fn standard_slots(positions: &[TestPosition]) -> Result<([usize; 10], Amplitudes)> {
    let not_standard = |reason: String| Error::NotStandardPositions { reason };
    if positions.len() != 10 {
        return Err(not_standard(format!(
            "got {} positions; use the least-squares methods for other sets",
            positions.len()
        )));
    }
    let tol = WlsOptions::default().amplitude_rel_tol;
    let a_b3_g = common_amplitude(positions, "IA (aB3_g)", |a| a.a_b3_g, tol)
        .map_err(|e| not_standard(e.to_string()))?;
    let mut slots: [Option<usize>; 10] = [None; 10];
    for (i, p) in positions.iter().enumerate() {
        let a = p.amplitudes;
        if a.a_b3_g <= 0.0 {
            return Err(not_standard(format!(
                "position #{i} (TP{}) has no vibration along IA (aB3_g = {})",
                p.tp, a.a_b3_g
            )));
        }
        let slot = match (a.a_b1_g > 0.0, a.a_b2_g > 0.0) {
            (false, false) => {
                let reduced_deg = p.angle_deg.rem_euclid(360.0);
                let k = (reduced_deg / 45.0).round();
                if (reduced_deg - 45.0 * k).abs() > ANGLE_TOL_DEG {
                    return Err(not_standard(format!(
                        "position #{i} (TP{}) at {} deg is not a multiple of 45 deg",
                        p.tp, p.angle_deg
                    )));
                }
                // k is in 0..=8 here; 8 is 360 deg = TP1.
                (k as usize) % 8
            }
            (true, false) | (false, true) => {
                if cos_deg(p.angle_deg).abs() > 1e-9 {
                    return Err(not_standard(format!(
                        "position #{i} (TP{}) has vibration along {} but IA is not \
                         horizontal (angle {} deg; TP9/TP10 need 90 or 270 deg)",
                        p.tp,
                        if a.a_b1_g > 0.0 { "OA" } else { "PA" },
                        p.angle_deg
                    )));
                }
                if a.a_b1_g > 0.0 {
                    8
                } else {
                    9
                }
            }
            (true, true) => {
                return Err(not_standard(format!(
                    "position #{i} (TP{}) has vibration along both OA and PA",
                    p.tp
                )));
            }
        };
        if let Some(j) = slots[slot] {
            return Err(not_standard(format!(
                "positions #{j} (TP{}) and #{i} (TP{}) are both TP{}",
                positions[j].tp,
                p.tp,
                slot + 1
            )));
        }
        slots[slot] = Some(i);
    }
    let mut index = [0usize; 10];
    for (k, slot) in slots.iter().enumerate() {
        match slot {
            Some(i) => index[k] = *i,
            // Ten positions in ten distinct slots fill them all; kept for safety.
            None => return Err(not_standard(format!("TP{} is missing", k + 1))),
        }
    }
    let amplitudes = Amplitudes {
        a_b3_g,
        a_b1_g: positions[index[8]].amplitudes.a_b1_g,
        a_b2_g: positions[index[9]].amplitudes.a_b2_g,
    };
    Ok((index, amplitudes))
}

/// The six VE components by the paper's closed form (22) [P1 (22)] from the ten
/// standard positions of MODEL.md section 9 (TP1..TP8 at `(k-1)*45 deg` with
/// vibration along IA, TP9 and TP10 with IA horizontal and vibration also along OA or
/// PA), given in any order: positions are recognised by angle and vibration axes.
///
/// Uncertainties by linear propagation: `C diag(sigma_k^2) C^T / K1^2` with
/// [`CLOSED_FORM_COEFFICIENTS`]. Without given uncertainties, one common `sigma` is
/// estimated from the least-squares residuals of the same ten positions (4 degrees of
/// freedom; the residuals of (22) itself would overestimate it, as (22) is not the
/// least-squares fit).
///
/// Departure from MODEL.md: section 9 calls (22) "equivalent to least squares over the
/// eight positions". It is unbiased, and for `delta(1)`, `delta(3)` it is the
/// least-squares solution (the odd part is exactly determined by TP1, TP2, TP4, TP5,
/// TP6, TP8); but `d0(1)` uses only TP3 and TP7 and `delta(2)` weights the positions
/// unequally, so with equal noise its variances are `0.5` and `1.5 (sigma/K1)^2`
/// where least squares ([`crate::wls_components`]) gets `0.375` and `1.0`. The closed
/// form has one virtue kept here: `d0(1)` comes only from positions with no gravity on
/// IA, where the published asymmetry term is exact (MODEL.md section 6).
pub fn closed_form(positions: &[TestPosition], k1_v_per_g: f64) -> Result<ComponentsEstimate> {
    validate_k1(k1_v_per_g)?;
    let sigmas_v = validate_all(positions)?;
    let (index, amplitudes) = standard_slots(positions)?;
    let du_v: [f64; 10] = std::array::from_fn(|k| positions[index[k]].du_v);
    let x: [f64; 6] = std::array::from_fn(|i| {
        let sum_v: f64 = (0..10)
            .map(|k| CLOSED_FORM_COEFFICIENTS[i][k] * du_v[k])
            .sum();
        sum_v / k1_v_per_g
    });
    let components = Components::from_array(x);
    let residuals_v: Vec<f64> = positions
        .iter()
        .map(|p| {
            let row = component_row(p);
            let model_g: f64 = row.iter().zip(&x).map(|(r, x)| r * x).sum();
            p.du_v - k1_v_per_g * model_g
        })
        .collect();
    // Variance of dU_k in slot order, V^2, and the basis it rests on.
    let (variance_v2, basis): ([f64; 10], UncertaintyBasis) = match &sigmas_v {
        Some(s) => {
            let chi2 = positions
                .iter()
                .zip(&residuals_v)
                .zip(s)
                .map(|((_, r), s)| (r / s) * (r / s))
                .sum();
            (
                std::array::from_fn(|k| s[index[k]] * s[index[k]]),
                UncertaintyBasis::Given { chi2, dof: 4 },
            )
        }
        None => {
            let ls = fit_components(positions, k1_v_per_g, &WlsOptions::default())?;
            let dof = 4;
            let du_sigma_v = (ls.fit.weighted_rss / dof as f64).sqrt() * k1_v_per_g.abs();
            (
                [du_sigma_v * du_sigma_v; 10],
                UncertaintyBasis::ResidualScatter { dof, du_sigma_v },
            )
        }
    };
    let k1_2 = k1_v_per_g * k1_v_per_g;
    let covariance: [[f64; 6]; 6] = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            (0..10)
                .map(|k| {
                    CLOSED_FORM_COEFFICIENTS[i][k] * variance_v2[k] * CLOSED_FORM_COEFFICIENTS[j][k]
                })
                .sum::<f64>()
                / k1_2
        })
    });
    Ok(ComponentsEstimate {
        method: Method::ClosedForm,
        amplitudes,
        components,
        sigma: Some(sigma_from_covariance(&covariance)),
        covariance: Some(covariance),
        basis,
        n_positions: 10,
        residuals_v,
        condition_number: None,
    })
}
