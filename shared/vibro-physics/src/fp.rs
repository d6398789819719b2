//! The instantaneous conversion function (FP), MODEL.md section 2, [P1 (1)-(2)],
//! [P2 (1)], in acceleration units `aF = U/K1`.
//!
//! Used by the simulator sample by sample, so it is `#[inline]`, branch-light and
//! allocation-free. `lambda(w)` is a frequency response, not an instantaneous factor:
//! here it is `lambda(0) = 1`; a simulator models it as a filter on the input.

use crate::passport::Passport;

/// `aF` for true accelerations `a1` (OA), `a2` (PA), `a3` (IA), all in g (FP).
#[inline]
pub fn output_g(p: &Passport, a1_g: f64, a2_g: f64, a3_g: f64) -> f64 {
    let a = a3_g;
    // (1 + 0.5*d1A*sign(a3))*a3 = a3 + 0.5*d1A*|a3|.
    let asym = 0.5 * p.d1a * a.abs();
    // Horner for k2 a^2 + k3 a^3 + k4 a^4 + k5 a^5.
    let poly = a * a * (p.k[2] + a * (p.k[3] + a * (p.k[4] + a * p.k[5])));
    p.a0_g
        + p.k1 * (a + asym)
        + poly
        + p.m1 * a1_g
        + p.m2 * a2_g
        + a * (p.m31_per_g * a1_g + p.m32_per_g * a2_g)
}

/// `sign(a3)` of the asymmetry term, 0 at `a3 = 0` (where `|a3|` has no slope).
#[inline]
pub fn asymmetry_sign(a3_g: f64) -> f64 {
    if a3_g > 0.0 {
        1.0
    } else if a3_g < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Gradient of (FP) at `[a1, a2, a3]`, `[d/da1, d/da2, d/da3]`, with the asymmetry's
/// slope `0.5 k1 d1A sign(a3)` taken as 0 at `a3 = 0` ([`asymmetry_sign`]).
#[inline]
pub fn gradient_g(p: &Passport, a1_g: f64, a2_g: f64, a3_g: f64) -> [f64; 3] {
    let a = a3_g;
    // d/da of k2 a^2 + ... + k5 a^5 by Horner.
    let poly = a * (2.0 * p.k[2] + a * (3.0 * p.k[3] + a * (4.0 * p.k[4] + a * 5.0 * p.k[5])));
    [
        p.m1 + p.m31_per_g * a,
        p.m2 + p.m32_per_g * a,
        p.k1 * (1.0 + 0.5 * p.d1a * asymmetry_sign(a))
            + poly
            + p.m31_per_g * a1_g
            + p.m32_per_g * a2_g,
    ]
}

/// Output `U` in volts (output units) for true accelerations: `K1 * aF`.
#[inline]
pub fn output_v(p: &Passport, a1_g: f64, a2_g: f64, a3_g: f64) -> f64 {
    p.k1_v_per_g * output_g(p, a1_g, a2_g, a3_g)
}

/// Applies (FP) to whole records: `out[i] = aF(a1[i], a2[i], a3[i])`.
/// Records shorter than `out` are an error of the caller; the common length is used.
pub fn apply_g(p: &Passport, a1_g: &[f64], a2_g: &[f64], a3_g: &[f64], out_g: &mut [f64]) {
    for (((o, &x1), &x2), &x3) in out_g.iter_mut().zip(a1_g).zip(a2_g).zip(a3_g) {
        *o = output_g(p, x1, x2, x3);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::al15;

    /// The gradient against central differences of (FP) away from `a3 = 0`, and the
    /// asymmetry's slope left out at `a3 = 0`.
    #[test]
    fn gradient_is_the_derivative_of_the_conversion() {
        let p = al15();
        for a in [[0.3, -0.7, 2.0], [1.0, 0.5, -3.0], [0.0, 0.0, 0.4]] {
            let g = gradient_g(&p, a[0], a[1], a[2]);
            for i in 0..3 {
                let h = 1e-5;
                let (mut up, mut down) = (a, a);
                up[i] += h;
                down[i] -= h;
                let d = (output_g(&p, up[0], up[1], up[2])
                    - output_g(&p, down[0], down[1], down[2]))
                    / (2.0 * h);
                assert!((g[i] - d).abs() < 1e-9, "{a:?} axis {i}: {} vs {d}", g[i]);
            }
        }
        let at0 = gradient_g(&p, 0.0, 0.0, 0.0);
        assert_eq!(at0[2], p.k1);
    }

    #[test]
    fn matches_the_written_out_polynomial() {
        let p = al15();
        for &(a1, a2, a3) in &[(0.0, 0.0, 1.0), (0.3, -0.2, -2.5), (1.0, 2.0, 10.0)] {
            let sign: f64 = if a3 >= 0.0 { 1.0 } else { -1.0 };
            let want = 3.324e-3
                + (1.0 + 0.5 * 15e-6 * sign) * a3
                + 105e-6 * a3 * a3
                + 87e-6 * a3 * a3 * a3
                + 10e-6 * a3.powi(4)
                + 0.9e-6 * a3.powi(5)
                + 1.15e-3 * (a1 + a2)
                + 11.6e-6 * a3 * (a1 + a2);
            assert!((output_g(&p, a1, a2, a3) - want).abs() < 1e-14 * want.abs().max(1.0));
        }
        assert_eq!(output_v(&p, 0.0, 0.0, 0.0), -1.6698 * 3.324e-3);
    }
}
