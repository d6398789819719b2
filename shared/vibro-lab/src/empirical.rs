//! Beyond the library: an empirical correction for a residual that no physical effect
//! explains (docs/lab.md, "Beyond the library").
//!
//! When the diagnosis ends `unexplained`, the residual left after the effects found is
//! fitted by a low-order smooth function of the condition's vibration and flight
//! acceleration, `sum_k c_k phi_k`, its terms from `vibro_effects::empirical::TERMS`
//! (vibration second moments times low powers of `aL3` or of the tone frequency; all
//! vanish without vibration). The terms are chosen by forward selection on the
//! leave-one-out cross-validated chi-square (PRESS, Allen 1974): for weighted linear
//! least squares with `y_i = r_i / u_i` and design `A_ik = phi_k(i) / u_i`, the
//! residual of row `i` predicted without it is `e_i / (1 - h_ii)`, `h_ii` the hat
//! matrix's diagonal, so the whole cross-validation costs one fit per term set. A term
//! is added while it lowers the cross-validated chi-square by at least
//! [`CV_SUPPORT`] (the same strength of evidence as the search's `bic_support`), at
//! most [`MAX_TERMS`]. Uncertainties are `sqrt(diag((A^T A)^-1))`, times the Birge
//! ratio when the chi-square per dof exceeds 1.
//!
//! The correction is **not physical**: it says how the VE the library misses follows
//! the flight's variables over the conditions measured, nothing about why, and it is
//! only offered when the verdict is `unexplained` (never when a physical effect
//! explains the data). Outside the tested ranges it is an extrapolation.

use crate::fit::Prepared;
use crate::table::CampaignTable;
use crate::{Error, Result};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use vibro_effects::empirical::{Empirical, TERMS};
use vibro_effects::model::LabModel;

/// Lowest drop of the cross-validated chi-square that adds a term.
pub const CV_SUPPORT: f64 = 10.0;

/// Most terms a correction takes.
pub const MAX_TERMS: usize = 6;

/// A correction is offered only when it at least halves the cross-validated
/// chi-square.
pub const OFFER_FRACTION: f64 = 0.5;

/// One term of the correction.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EmpiricalTerm {
    /// The coefficient's key in the `[[effect]]` table.
    pub key: String,
    pub meaning: String,
    /// g per unit of the term.
    pub value: f64,
    pub sigma: f64,
    /// The cross-validated chi-square once this term was added.
    pub cv_chi2: f64,
}

/// An empirical correction fitted to a residual.
#[derive(Debug, Clone, Serialize)]
pub struct EmpiricalFit {
    /// Always "not physical": shown wherever the correction is.
    pub nature: &'static str,
    pub terms: Vec<EmpiricalTerm>,
    /// The condition variables the chosen terms follow.
    pub variables: Vec<String>,
    /// The `[[effect]]` table (`kind = "empirical"`) with the fitted coefficients.
    #[serde(skip)]
    pub table: toml::Table,
    pub n: usize,
    pub chi2_before: f64,
    pub chi2_after: f64,
    pub chi2_per_dof_after: f64,
    pub p_value_after: f64,
    /// Leave-one-out cross-validated chi-square without a term and with the chosen.
    pub cv_chi2_before: f64,
    pub cv_chi2_after: f64,
    pub rms_residual_before_g: f64,
    pub rms_residual_after_g: f64,
    /// The correction per condition, g.
    pub shift_g: Vec<f64>,
    pub residual_after_g: Vec<f64>,
    /// The physical effects found, refitted jointly with the correction (their
    /// parameters free, the correction's terms refitted in turn: backfitting, a few
    /// rounds): a physical effect that took part of what the correction describes
    /// gives it back.
    pub found: Vec<crate::fit::FittedParam>,
    /// Their `[[effect]]` tables as refitted.
    #[serde(skip)]
    pub found_tables: Vec<toml::Table>,
    /// Effects found by the search that the correction makes unnecessary, and why.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub dropped: Vec<String>,
}

/// Rounds of backfitting between the physical effects and the correction.
const BACKFIT_ROUNDS: usize = 3;

/// The empirical correction of what `model` (its effects fixed) with the physical
/// effects `terms` at `values` (`found_params`: as the search fitted them) leaves on
/// `table`, the effects refitted jointly with it.
/// Each round: the correction's terms chosen for the effects as they stand
/// ([`fit_empirical`]); the effects refitted with the correction's coefficients free
/// (variable projection, `fit::fit_joint_projected`, all parameters from their
/// values); an effect the correction makes unnecessary (removing it costs less than
/// 10 in BIC, counting the correction's terms as parameters) dropped. Rounds stop when
/// the terms and the chi-square settle, at most [`BACKFIT_ROUNDS`].
pub(crate) fn backfit(
    model: &LabModel,
    table: &CampaignTable,
    terms: &[&'static crate::library::Candidate],
    values: &[Vec<f64>],
    found_params: &[crate::fit::FittedParam],
    meter: &crate::fit::Meter,
) -> Result<Option<EmpiricalFit>> {
    let mut terms: Vec<&'static crate::library::Candidate> = terms.to_vec();
    let mut values: Vec<Vec<f64>> = values.to_vec();
    let tables_of = |terms: &[&'static crate::library::Candidate], values: &[Vec<f64>]| {
        terms
            .iter()
            .zip(values)
            .map(|(c, v)| crate::fit::effect_table(c, v))
            .collect::<Vec<_>>()
    };
    let Some(mut best) = fit_empirical(model, table, &tables_of(&terms, &values))? else {
        return Ok(None);
    };
    best.found = found_params.to_vec();
    let n = table.conditions.len() as f64;
    let bic = |e: &EmpiricalFit, terms: &[&'static crate::library::Candidate]| {
        let k: usize = terms.iter().map(|c| c.params.len()).sum::<usize>() + e.terms.len();
        e.chi2_after + k as f64 * n.ln()
    };
    let mut dropped: Vec<String> = Vec::new();
    for _ in 0..BACKFIT_ROUNDS {
        if terms.is_empty() {
            break;
        }
        let tables = tables_of(&terms, &values);
        let d = design(model, table, &tables)?;
        let set: Vec<usize> = best
            .terms
            .iter()
            .filter_map(|t| TERMS.iter().position(|x| x.key == t.key))
            .collect();
        let a = DMatrix::from_fn(d.u_g.len(), set.len(), |i, j| d.phi[i][set[j]] / d.u_g[i]);
        let q = a.qr().q();
        let mut prep = Prepared::new(model, table)?;
        prep.reweight(model, table, &tables)?;
        let known: Vec<Option<Vec<f64>>> = values.iter().cloned().map(Some).collect();
        let g =
            crate::fit::fit_joint_projected(model, table, &prep, &terms, &known, meter, Some(&q))?;
        values = terms.iter().map(|c| g.values_of(c.kind)).collect();
        let Some(mut next) = fit_empirical(model, table, &tables_of(&terms, &values))? else {
            break;
        };
        next.found = g.params.clone();
        next.found_tables = tables_of(&terms, &values);
        // Backward check: the effect whose removal costs least, if under 10 in BIC.
        let mut cheapest: Option<(usize, f64, EmpiricalFit)> = None;
        for drop in 0..terms.len() {
            let kept: Vec<_> = (0..terms.len()).filter(|&i| i != drop).collect();
            let t: Vec<_> = kept.iter().map(|&i| terms[i]).collect();
            let v: Vec<_> = kept.iter().map(|&i| values[i].clone()).collect();
            if let Some(e) = fit_empirical(model, table, &tables_of(&t, &v))? {
                let cost = bic(&e, &t) - bic(&next, &terms);
                if cheapest.as_ref().is_none_or(|c| cost < c.1) {
                    cheapest = Some((drop, cost, e));
                }
            }
        }
        next.dropped = dropped.clone();
        let same_terms = next
            .terms
            .iter()
            .map(|t| &t.key)
            .eq(best.terms.iter().map(|t| &t.key));
        let settled =
            same_terms && (next.chi2_after - best.chi2_after).abs() <= 1e-3 * best.chi2_after;
        best = next;
        if let Some((drop, cost, mut e)) = cheapest.filter(|c| c.1 < BIC_SUPPORT) {
            let gone = terms.remove(drop);
            values.remove(drop);
            dropped.push(format!(
                "{} (removing it costs {cost:.1} in BIC)",
                gone.kind
            ));
            e.dropped = dropped.clone();
            e.found = best
                .found
                .iter()
                .filter(|p| p.effect != gone.kind)
                .cloned()
                .collect();
            e.found_tables = tables_of(&terms, &values);
            best = e;
            continue;
        }
        if settled {
            break;
        }
    }
    Ok(Some(best))
}

/// An effect beside the correction must lower the BIC by at least this to stay (the
/// search's `bic_support`).
const BIC_SUPPORT: f64 = 10.0;

/// The residual left, its uncertainty and each term's value per condition, for the
/// model `model` with the effects `found` added.
struct Design {
    residual_g: Vec<f64>,
    u_g: Vec<f64>,
    /// `[row][term]`.
    phi: Vec<Vec<f64>>,
}

fn design(model: &LabModel, table: &CampaignTable, found: &[toml::Table]) -> Result<Design> {
    let mut full = model.clone();
    full.effects.extend(found.iter().cloned());
    let prep = Prepared::new(&full, table)?;
    let phi = table
        .conditions
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let (vib, _) = prep.seen_of(i);
            TERMS.iter().map(|t| (t.value)(vib, c.a_l_g)).collect()
        })
        .collect();
    Ok(Design {
        residual_g: prep.residual_g(),
        u_g: prep.uncertainty_g.clone(),
        phi,
    })
}

/// A weighted linear fit of the residual on the terms `set`.
struct Linear {
    /// Coefficients, g per unit of the term.
    beta: Vec<f64>,
    /// `(A^T A)^-1`'s diagonal in the terms' units.
    var: Vec<f64>,
    chi2: f64,
    /// Leave-one-out chi-square.
    press: f64,
}

fn linear(d: &Design, set: &[usize]) -> Option<Linear> {
    let n = d.residual_g.len();
    let k = set.len();
    let y = DVector::from_iterator(n, (0..n).map(|i| d.residual_g[i] / d.u_g[i]));
    if k == 0 {
        let chi2 = y.norm_squared();
        return Some(Linear {
            beta: Vec::new(),
            var: Vec::new(),
            chi2,
            press: chi2,
        });
    }
    // Columns scaled to unit norm: the terms span many orders of magnitude.
    let mut a = DMatrix::from_fn(n, k, |i, j| d.phi[i][set[j]] / d.u_g[i]);
    let mut scale = vec![0.0; k];
    for j in 0..k {
        let norm = a.column(j).norm();
        if !(norm.is_finite() && norm > 0.0) {
            return None;
        }
        scale[j] = norm;
        a.column_mut(j).unscale_mut(norm);
    }
    if !a.iter().all(|x| x.is_finite()) || !y.iter().all(|x| x.is_finite()) {
        return None;
    }
    let ata = a.transpose() * &a;
    let inv = ata.try_inverse()?;
    // A term set whose columns are (nearly) dependent has no unique fit.
    if inv.iter().any(|x| !x.is_finite()) || inv.diagonal().max() > 1e12 {
        return None;
    }
    let beta = &inv * a.transpose() * &y;
    let e = &y - &a * &beta;
    let mut press = 0.0;
    for i in 0..n {
        let row = a.row(i);
        let h = (row * &inv * row.transpose())[(0, 0)];
        if h >= 1.0 - 1e-9 {
            // One row alone determines a coefficient: it cannot be predicted without.
            return None;
        }
        press += (e[i] / (1.0 - h)).powi(2);
    }
    Some(Linear {
        beta: (0..k).map(|j| beta[j] / scale[j]).collect(),
        var: (0..k)
            .map(|j| inv[(j, j)] / (scale[j] * scale[j]))
            .collect(),
        chi2: e.norm_squared(),
        press,
    })
}

/// The empirical correction of the residual that `model` with the effects `found`
/// leaves on `table`, terms chosen by cross-validation; `None` when no term lowers the
/// cross-validated chi-square by [`CV_SUPPORT`], or the terms chosen do not bring it
/// below [`OFFER_FRACTION`] of its value without them (no smooth function of the
/// flight's variables predicts the residual out of sample).
pub fn fit_empirical(
    model: &LabModel,
    table: &CampaignTable,
    found: &[toml::Table],
) -> Result<Option<EmpiricalFit>> {
    let d = design(model, table, found)?;
    let n = d.residual_g.len();
    if n < 3 {
        return Err(Error::Invalid(format!(
            "an empirical correction needs at least 3 conditions, the table has {n}"
        )));
    }
    let none = linear(&d, &[]).ok_or_else(|| Error::Numeric {
        what: table.path.display().to_string(),
        reason: "the residual over its uncertainty is not finite".into(),
    })?;
    let mut set: Vec<usize> = Vec::new();
    let (chi2_before, cv_chi2_before) = (none.chi2, none.press);
    let mut best = none;
    let mut path: Vec<f64> = Vec::new();
    while set.len() < MAX_TERMS.min(n.saturating_sub(2)) {
        let mut next: Option<(usize, Linear)> = None;
        for k in 0..TERMS.len() {
            if set.contains(&k) || d.phi.iter().all(|p| p[k] == 0.0) {
                continue;
            }
            let mut s = set.clone();
            s.push(k);
            if let Some(f) = linear(&d, &s) {
                if next.as_ref().is_none_or(|(_, g)| f.press < g.press) {
                    next = Some((k, f));
                }
            }
        }
        match next {
            Some((k, f)) if best.press - f.press >= CV_SUPPORT => {
                set.push(k);
                path.push(f.press);
                best = f;
            }
            _ => break,
        }
    }
    // Offered only when it predicts most of the residual out of sample: a few terms
    // that shave a little off a residual they do not follow are no correction.
    if set.is_empty() || best.press > OFFER_FRACTION * cv_chi2_before {
        return Ok(None);
    }
    let dof = (n - set.len()) as f64;
    let birge = (best.chi2 / dof).max(1.0).sqrt();
    let mut terms: Vec<EmpiricalTerm> = set
        .iter()
        .zip(&best.beta)
        .zip(&best.var)
        .zip(&path)
        .map(|(((k, b), v), cv)| EmpiricalTerm {
            key: TERMS[*k].key.into(),
            meaning: TERMS[*k].meaning.into(),
            value: *b,
            sigma: v.sqrt() * birge,
            cv_chi2: *cv,
        })
        .collect();
    let correction = Empirical {
        terms: set.iter().copied().zip(best.beta.iter().copied()).collect(),
    };
    let shift_g: Vec<f64> = d
        .phi
        .iter()
        .map(|p| set.iter().zip(&best.beta).map(|(k, b)| b * p[*k]).sum())
        .collect();
    let residual_after_g: Vec<f64> = d
        .residual_g
        .iter()
        .zip(&shift_g)
        .map(|(r, s)| r - s)
        .collect();
    let mut variables: Vec<String> = set
        .iter()
        .flat_map(|k| TERMS[*k].variables.iter().map(|v| v.to_string()))
        .collect();
    variables.sort();
    variables.dedup();
    terms.sort_by_key(|t| TERMS.iter().position(|x| x.key == t.key));
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let p_value_after = ChiSquared::new(dof).map_or(f64::NAN, |c| c.sf(best.chi2));
    Ok(Some(EmpiricalFit {
        nature: "not physical",
        terms,
        variables,
        table: correction.to_table(),
        n,
        chi2_before,
        chi2_after: best.chi2,
        chi2_per_dof_after: best.chi2 / dof,
        p_value_after,
        cv_chi2_before,
        cv_chi2_after: best.press,
        rms_residual_before_g: rms(&d.residual_g),
        rms_residual_after_g: rms(&residual_after_g),
        shift_g,
        residual_after_g,
        found: Vec::new(),
        found_tables: found.to_vec(),
        dropped: Vec::new(),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// PRESS against leave-one-out done by hand: refit without each row, predict it.
    #[test]
    fn press_is_the_leave_one_out_chi_square() {
        let n = 12;
        let d = Design {
            residual_g: (0..n)
                .map(|i| 1e-6 * (0.3 * i as f64 + (i as f64 * 1.7).sin()))
                .collect(),
            u_g: (0..n).map(|i| 1e-7 * (1.0 + 0.1 * i as f64)).collect(),
            phi: (0..n)
                .map(|i| {
                    let x = i as f64;
                    let mut row = vec![0.0; TERMS.len()];
                    row[0] = 1.0 + x;
                    row[5] = (1.0 + x) * (x - 4.0);
                    row
                })
                .collect(),
        };
        let set = [0, 5];
        let full = linear(&d, &set).unwrap();
        let mut press = 0.0;
        for out in 0..n {
            let keep: Vec<usize> = (0..n).filter(|&i| i != out).collect();
            let sub = Design {
                residual_g: keep.iter().map(|&i| d.residual_g[i]).collect(),
                u_g: keep.iter().map(|&i| d.u_g[i]).collect(),
                phi: keep.iter().map(|&i| d.phi[i].clone()).collect(),
            };
            let f = linear(&sub, &set).unwrap();
            let pred: f64 = set
                .iter()
                .zip(&f.beta)
                .map(|(k, b)| b * d.phi[out][*k])
                .sum();
            press += ((d.residual_g[out] - pred) / d.u_g[out]).powi(2);
        }
        assert!(
            (full.press - press).abs() < 1e-9 * press,
            "{} vs {press}",
            full.press
        );
        assert!(full.press > full.chi2);
    }
}
