//! Weighted linear least squares by SVD of the column-scaled design, with a
//! rank check that names the unknowns the data cannot separate.

use crate::{Error, Result};
use nalgebra::{DMatrix, DVector};

/// A least-squares solution of `y = A x` with weights `w_k = 1/sigma_k^2`.
pub(crate) struct LsFit {
    pub x: Vec<f64>,
    /// `(A^T W A)^-1`: the covariance of `x` when the `sigma_k` are the true standard
    /// deviations of `y_k`; to be scaled by the residual variance for unit weights.
    pub cov_unscaled: DMatrix<f64>,
    /// `sum_k w_k * r_k^2`.
    pub weighted_rss: f64,
    /// `r_k = y_k - (A x)_k`, unweighted.
    pub residuals: Vec<f64>,
    /// Condition number of the column-scaled weighted design.
    pub condition: f64,
}

/// Solves the weighted least-squares problem `min sum_k w_k (y_k - (A x)_k)^2`.
///
/// The weighted design is first scaled to unit column norms, so that the condition
/// number measures how well the data separate the unknowns rather than how their
/// units differ (`c_asym` multiplies `aB3` while `k5` multiplies `aB3^4`). When the
/// smallest singular value is below `rcond_min` times the largest, the design is
/// rank-deficient in practice: the right singular vectors of the small singular values
/// span the combinations of unknowns the data cannot see, and an unknown is named
/// unidentifiable when it has a non-negligible component in that null space.
/// `hint` turns the names into advice for the error message.
pub(crate) fn solve_wls(
    design: &DMatrix<f64>,
    y: &[f64],
    sigma_y: Option<&[f64]>,
    names: &[&'static str],
    rcond_min: f64,
    hint: impl Fn(&[&'static str]) -> String,
) -> Result<LsFit> {
    let (n, p) = design.shape();
    if n < p {
        return Err(Error::TooFewPositions {
            n_positions: n,
            n_unknowns: p,
            unknowns: names.join(", "),
        });
    }
    let sqrt_w: Vec<f64> = match sigma_y {
        Some(s) => s.iter().map(|s| 1.0 / s).collect(),
        None => vec![1.0; n],
    };
    let mut a_w = design.clone();
    for (mut row, w) in a_w.row_iter_mut().zip(&sqrt_w) {
        row *= *w;
    }
    let b_w = DVector::from_iterator(n, y.iter().zip(&sqrt_w).map(|(y, w)| y * w));
    // A zero column keeps scale 1: it stays zero and shows up as a zero singular value.
    let scale: Vec<f64> = a_w
        .column_iter()
        .map(|c| {
            let norm = c.norm();
            if norm > 0.0 {
                norm
            } else {
                1.0
            }
        })
        .collect();
    let mut a_s = a_w;
    for (mut col, s) in a_s.column_iter_mut().zip(&scale) {
        col /= *s;
    }
    let failed = Error::SvdFailed { rows: n, cols: p };
    // max_niter = 0: iterate until convergence.
    let svd = nalgebra::SVD::try_new(a_s, true, true, f64::EPSILON, 0).ok_or(failed.clone())?;
    let (Some(u), Some(v_t)) = (svd.u.as_ref(), svd.v_t.as_ref()) else {
        return Err(failed);
    };
    let s = &svd.singular_values;
    let s_max = s.iter().copied().fold(0.0, f64::max);
    let s_min = s.iter().copied().fold(f64::INFINITY, f64::min);
    let condition = if s_min > 0.0 {
        s_max / s_min
    } else {
        f64::INFINITY
    };
    let threshold = rcond_min * s_max;
    if s_min <= threshold {
        let mut null_weight = vec![0.0; p];
        for (i, &s_i) in s.iter().enumerate() {
            if s_i <= threshold {
                for (j, w) in null_weight.iter_mut().enumerate() {
                    *w += v_t[(i, j)] * v_t[(i, j)];
                }
            }
        }
        // An identifiable unknown is orthogonal to the null space; 1e-6 of its
        // squared norm leaves room for rounding in the singular vectors.
        let unknowns: Vec<&'static str> = names
            .iter()
            .zip(&null_weight)
            .filter(|(_, w)| **w > 1e-6)
            .map(|(name, _)| *name)
            .collect();
        return Err(Error::Unidentifiable {
            hint: hint(&unknowns),
            unknowns,
            condition,
            limit: 1.0 / rcond_min,
        });
    }
    let mut x_s = DVector::zeros(p);
    let mut cov_s = DMatrix::zeros(p, p);
    for (i, &s_i) in s.iter().enumerate() {
        let v_i = v_t.row(i).transpose();
        let coef = u.column(i).dot(&b_w) / s_i;
        x_s += &v_i * coef;
        cov_s += &v_i * v_i.transpose() / (s_i * s_i);
    }
    let x: Vec<f64> = x_s.iter().zip(&scale).map(|(x, s)| x / s).collect();
    let cov_unscaled = DMatrix::from_fn(p, p, |i, j| cov_s[(i, j)] / (scale[i] * scale[j]));
    let x_vec = DVector::from_column_slice(&x);
    let fitted = design * &x_vec;
    let residuals: Vec<f64> = y.iter().zip(fitted.iter()).map(|(y, f)| y - f).collect();
    let weighted_rss = residuals
        .iter()
        .zip(&sqrt_w)
        .map(|(r, w)| (r * w) * (r * w))
        .sum();
    Ok(LsFit {
        x,
        cov_unscaled,
        weighted_rss,
        residuals,
        condition,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_line_matches_the_textbook_formulas() {
        // y = 2 + 3 t at t = 0..4 with one perturbed point: compare with the normal
        // equations solved by hand.
        let t = [0.0, 1.0, 2.0, 3.0, 4.0];
        let y = [2.0, 5.0, 8.5, 11.0, 14.0];
        let a = DMatrix::from_fn(5, 2, |i, j| if j == 0 { 1.0 } else { t[i] });
        let fit = solve_wls(&a, &y, None, &["b", "m"], 1e-10, |_| String::new()).unwrap();
        let (n, st, stt) = (5.0, 10.0, 30.0);
        let sy: f64 = y.iter().sum();
        let sty: f64 = t.iter().zip(&y).map(|(t, y)| t * y).sum();
        let det = n * stt - st * st;
        let m = (n * sty - st * sy) / det;
        let b = (sy - m * st) / n;
        assert!((fit.x[0] - b).abs() < 1e-13 && (fit.x[1] - m).abs() < 1e-13);
        assert!((fit.cov_unscaled[(1, 1)] - n / det).abs() < 1e-13);
        assert!((fit.cov_unscaled[(0, 0)] - stt / det).abs() < 1e-13);
    }

    #[test]
    fn collinear_columns_are_named() {
        let a = DMatrix::from_fn(4, 3, |i, j| match j {
            0 => 1.0,
            1 => 2.0,
            _ => i as f64,
        });
        let e = solve_wls(&a, &[1.0; 4], None, &["p", "q", "r"], 1e-10, |u| {
            format!("{} confounded", u.len())
        })
        .err()
        .unwrap();
        match e {
            Error::Unidentifiable { unknowns, hint, .. } => {
                assert_eq!(unknowns, vec!["p", "q"]);
                assert_eq!(hint, "2 confounded");
            }
            other => panic!("{other}"),
        }
    }
}
