//! Deterministic quadrature for the mean formulas (never called from a hook):
//! composite Gauss–Legendre rules, kink location by bracketing, and the midpoint rule
//! over tone phases.
//!
//! Accuracy, for the integrands of this library:
//! - composite 8-point Gauss–Legendre on panels where the integrand is smooth
//!   (polynomial times a Gaussian, or analytic in a phase): relative error below 1e-12
//!   with panels no wider than one standard deviation (or pi/8 rad);
//! - kinks (clipping thresholds) are located by bisection to 1e-14 of the interval and
//!   become panel edges, so they cost no accuracy;
//! - the midpoint rule over a tone's phase is exact for trigonometric polynomials of
//!   degree below the number of points and converges exponentially for smooth periodic
//!   integrands (Trefethen & Weideman, "The exponentially convergent trapezoidal rule",
//!   SIAM Review 56 (2014)); where the inner average has a square-root singularity
//!   (a tone alone reaching a threshold), the error falls as `n^-1.5`.

use std::f64::consts::TAU;

/// Nodes of the 8-point Gauss–Legendre rule on `[-1, 1]` (positive half).
const GL8_NODES: [f64; 4] = [
    0.183_434_642_495_649_8,
    0.525_532_409_916_329,
    0.796_666_477_413_626_7,
    0.960_289_856_497_536_3,
];
/// Weights of the 8-point Gauss–Legendre rule, matching [`GL8_NODES`].
const GL8_WEIGHTS: [f64; 4] = [
    0.362_683_783_378_362,
    0.313_706_645_877_887_3,
    0.222_381_034_453_374_5,
    0.101_228_536_290_376_3,
];

/// `int_lo^hi f(x) dx` by 8-point Gauss–Legendre on `panels` equal panels.
pub(crate) fn gauss_legendre(
    f: &mut impl FnMut(f64) -> f64,
    lo: f64,
    hi: f64,
    panels: usize,
) -> f64 {
    let panels = panels.max(1);
    let h = (hi - lo) / panels as f64;
    let mut sum = 0.0;
    for p in 0..panels {
        let mid = lo + (p as f64 + 0.5) * h;
        let half = 0.5 * h;
        for (x, w) in GL8_NODES.iter().zip(GL8_WEIGHTS) {
            sum += w * (f(mid - half * x) + f(mid + half * x)) * half;
        }
    }
    sum
}

/// `int_lo^hi f` with panels no wider than `max_panel`, splitting at every point of
/// `breaks` inside `(lo, hi)` (sorted ascending).
pub(crate) fn integrate_between_breaks(
    f: &mut impl FnMut(f64) -> f64,
    lo: f64,
    hi: f64,
    breaks: &[f64],
    max_panel: f64,
) -> f64 {
    let mut sum = 0.0;
    let mut left = lo;
    for &b in breaks
        .iter()
        .filter(|b| **b > lo && **b < hi)
        .chain([hi].iter())
    {
        if b > left {
            let panels = ((b - left) / max_panel).ceil().max(1.0) as usize;
            sum += gauss_legendre(f, left, b, panels);
            left = b;
        }
    }
    sum
}

/// Appends to `out` every point in `[lo, hi]` where the continuous `g` changes sign
/// between two of `cells + 1` equally spaced samples, refined by bisection. A sign
/// change confined within one
/// cell (two crossings closer than `(hi - lo)/cells`) is missed, which callers make
/// harmless by choosing cells far finer than the features of `g`.
pub(crate) fn crossings(
    g: &mut impl FnMut(f64) -> f64,
    lo: f64,
    hi: f64,
    cells: usize,
    out: &mut Vec<f64>,
) {
    let cells = cells.max(1);
    let h = (hi - lo) / cells as f64;
    let mut x0 = lo;
    let mut g0 = g(x0);
    for c in 1..=cells {
        let x1 = if c == cells { hi } else { lo + c as f64 * h };
        let g1 = g(x1);
        if (g0 < 0.0) != (g1 < 0.0) {
            let (mut a, mut b, mut ga) = (x0, x1, g0);
            // 60 halvings take any cell to below 1e-17 of its width.
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                let gm = g(m);
                if (gm < 0.0) == (ga < 0.0) {
                    a = m;
                    ga = gm;
                } else {
                    b = m;
                }
                if b - a <= 1e-14 * h {
                    break;
                }
            }
            out.push(0.5 * (a + b));
        }
        x0 = x1;
        g0 = g1;
    }
}

/// Points per tone of a tensor midpoint grid over `levels` tone phases, keeping the
/// grid within `budget` points (at least 4 per tone, at most `max_per_tone`).
pub(crate) fn points_per_tone(levels: usize, budget: usize, max_per_tone: usize) -> usize {
    if levels == 0 {
        return 1;
    }
    let n = (budget as f64).powf(1.0 / levels as f64).floor() as usize;
    n.clamp(4, max_per_tone.max(4))
}

/// Calls `f(sines, cosines, weight)` at every node of the tensor midpoint grid over
/// `levels` independent uniform phases with `n` points each (`weight = n^-levels`).
/// `sines`/`cosines` hold `sin(theta_k)`, `cos(theta_k)` per level.
pub(crate) fn for_each_phase(levels: usize, n: usize, mut f: impl FnMut(&[f64], &[f64], f64)) {
    let n = n.max(1);
    let weight = (n as f64).powi(-(levels as i32));
    let table: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let th = TAU * (i as f64 + 0.5) / n as f64;
            (th.sin(), th.cos())
        })
        .collect();
    let mut index = vec![0usize; levels];
    let mut sines = vec![0.0; levels];
    let mut cosines = vec![0.0; levels];
    loop {
        for (k, &i) in index.iter().enumerate() {
            sines[k] = table[i].0;
            cosines[k] = table[i].1;
        }
        f(&sines, &cosines, weight);
        // Odometer increment.
        let mut k = 0;
        loop {
            if k == levels {
                return;
            }
            index[k] += 1;
            if index[k] < n {
                break;
            }
            index[k] = 0;
            k += 1;
        }
    }
}

/// The mean of a smooth `2 pi`-periodic `f(sin theta, cos theta)` (`N` components)
/// over one period by the trapezoid rule, from `start` nodes, doubled (each doubling
/// adds the previous rule's midpoints) until two successive estimates agree within
/// `tol` in every component or the rule has `max_nodes` nodes. For an integrand
/// analytic in a strip, the error falls exponentially in the nodes (Trefethen &
/// Weideman 2014, section 3), so the agreement of two estimates bounds the error of
/// the first and the second is far better.
pub(crate) fn periodic_mean<const N: usize>(
    f: &mut impl FnMut(f64, f64) -> [f64; N],
    start: usize,
    max_nodes: usize,
    tol: f64,
) -> [f64; N] {
    let sum_at = |f: &mut dyn FnMut(f64, f64) -> [f64; N], n: usize, offset: f64| {
        let mut sum = [0.0; N];
        for k in 0..n {
            let (s, c) = (TAU * (k as f64 + offset) / n as f64).sin_cos();
            for (acc, v) in sum.iter_mut().zip(f(s, c)) {
                *acc += v;
            }
        }
        sum
    };
    let mut n = start.max(1);
    let mut sum = sum_at(f, n, 0.0);
    let mut mean = sum.map(|x| x / n as f64);
    while n < max_nodes {
        for (acc, v) in sum.iter_mut().zip(sum_at(f, n, 0.5)) {
            *acc += v;
        }
        n *= 2;
        let next = sum.map(|x| x / n as f64);
        let converged = next.iter().zip(&mean).all(|(a, b)| (a - b).abs() <= tol);
        mean = next;
        if converged {
            break;
        }
    }
    mean
}

/// The number of trapezoid nodes over a tone's phase that resolves a Gaussian
/// smoothing of width `narrowest_g` under the tone's swing `amplitude_g` (about one
/// width between nodes), as a power of two within `min_nodes..=max_nodes`.
pub(crate) fn periodic_start(
    amplitude_g: f64,
    narrowest_g: f64,
    min_nodes: usize,
    max_nodes: usize,
) -> usize {
    let nodes = (TAU * amplitude_g.abs() / narrowest_g).ceil();
    if !(nodes.is_finite() && nodes >= 1.0) {
        return if nodes.is_finite() {
            min_nodes
        } else {
            max_nodes
        };
    }
    (nodes.min(max_nodes as f64) as usize)
        .next_power_of_two()
        .clamp(min_nodes, max_nodes)
}

/// Standard normal density.
#[inline]
pub(crate) fn normal_pdf(z: f64) -> f64 {
    const INV_SQRT_TAU: f64 = 0.398_942_280_401_432_7;
    INV_SQRT_TAU * (-0.5 * z * z).exp()
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_physics::abs_mean::normal_cdf;

    #[test]
    fn gauss_legendre_integrates_a_gaussian_tail() {
        // int_1^9 phi = Phi(9) - Phi(1).
        let got = gauss_legendre(&mut normal_pdf, 1.0, 9.0, 8);
        let want = normal_cdf(9.0) - normal_cdf(1.0);
        assert!((got - want).abs() < 1e-13, "{got} vs {want}");
    }

    #[test]
    fn kinks_become_panel_edges() {
        let mut g = |x: f64| x * x - 2.0;
        let mut roots = Vec::new();
        crossings(&mut g, -3.0, 3.0, 10, &mut roots);
        assert_eq!(roots.len(), 2);
        assert!((roots[1] - 2f64.sqrt()).abs() < 1e-13);
        // int_{-3}^{3} |x^2 - 2| dx, exact: 2 * (int_0^r (2 - x^2) + int_r^3 (x^2 - 2)).
        let r = 2f64.sqrt();
        let want = 2.0 * ((2.0 * r - r.powi(3) / 3.0) + (9.0 - 6.0 - (r.powi(3) / 3.0 - 2.0 * r)));
        let got =
            integrate_between_breaks(&mut |x: f64| (x * x - 2.0).abs(), -3.0, 3.0, &roots, 1.0);
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }

    /// The doubled trapezoid rule against closed forms: `E[exp(k cos t)] = I0(k)`
    /// (the modified Bessel function, by its series) for a sharp `k`, reached by
    /// doubling from 4 nodes, and a trigonometric polynomial, exact at once.
    #[test]
    fn periodic_mean_meets_closed_forms() {
        let k: f64 = 30.0;
        let mut i0 = 0.0;
        let mut term = 1.0;
        for m in 1..200 {
            i0 += term;
            term *= (k / 2.0).powi(2) / (m as f64 * m as f64);
        }
        let mut calls = 0;
        let [got] = periodic_mean(
            &mut |_, c| {
                calls += 1;
                [(k * c).exp()]
            },
            4,
            1024,
            1e-13 * i0,
        );
        assert!((got - i0).abs() < 1e-12 * i0, "{got} vs {i0}");
        assert!(calls < 1024, "{calls} evaluations");
        let [got] = periodic_mean(&mut |s, c| [s * s * c * c + 0.25], 16, 1024, 1e-15);
        assert!((got - 0.375).abs() < 1e-15, "{got}");
    }

    #[test]
    fn phase_grid_averages_trigonometric_polynomials_exactly() {
        let mut sum = 0.0;
        let mut weights = 0.0;
        for_each_phase(2, 8, |s, c, w| {
            // E[sin^2 t1 cos^2 t2 + sin^4 t1] = 1/4 + 3/8.
            sum += w * (s[0] * s[0] * c[1] * c[1] + s[0].powi(4));
            weights += w;
        });
        assert!((weights - 1.0).abs() < 1e-14);
        assert!((sum - 0.625).abs() < 1e-14);
        assert_eq!(points_per_tone(1, 1024, 1024), 1024);
        assert_eq!(points_per_tone(2, 1 << 14, 1024), 128);
        assert_eq!(points_per_tone(8, 1 << 14, 1024), 4);
    }
}
