//! The exact vibration error: the true mean of (FP) over the vibration, term by term
//! (MODEL.md section 6).
//!
//! With `a3 = aL3 + v3`, `v3` the zero-mean vibration along IA,
//! `E[a3^n] = sum_j C(n, j) aL3^(n-j) E[v3^j]`. The raw moments of `v3` combine over
//! its independent parts (each tone, the random part) by the binomial rule; a tone of
//! amplitude `A` has `E[s^2] = A^2/2`, `E[s^4] = 3A^4/8`, the random part
//! `E[x^2] = sigma^2`, `E[x^4] = kurtosis * sigma^4` (3 for Gaussian); odd moments are 0.
//! Cross terms use `E[v3 v1] = sum_tones 0.5 aB3 aB1 cos(phi3 - phi1) + K_31(0)`.
//! The asymmetry term is `0.5 k1 d1A E|a3|` with `E|.|` from [`crate::abs_mean`];
//! `lambda(w)` scales each tone inside it (the pendulum's asymmetric response acts on
//! the acceleration it sees through its own frequency response), and the random part
//! with `lambda = 1`.

use crate::abs_mean::AbsMean;
use crate::passport::Passport;
use crate::ve::VeComponents;
use crate::vibration::{Vibration, MAX_TONES};
use crate::Result;

/// Binomial coefficients `C(n, j)` for n, j <= 5.
const BINOMIAL: [[f64; 6]; 6] = [
    [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1.0, 1.0, 0.0, 0.0, 0.0, 0.0],
    [1.0, 2.0, 1.0, 0.0, 0.0, 0.0],
    [1.0, 3.0, 3.0, 1.0, 0.0, 0.0],
    [1.0, 4.0, 6.0, 4.0, 1.0, 0.0],
    [1.0, 5.0, 10.0, 10.0, 5.0, 1.0],
];

/// Raw moments `E[(X + Y)^n]`, n = 0..5, of a sum of independent variables.
fn combine(a: &[f64; 6], b: &[f64; 6]) -> [f64; 6] {
    let mut out = [0.0; 6];
    for (n, o) in out.iter_mut().enumerate() {
        for j in 0..=n {
            *o += BINOMIAL[n][j] * a[j] * b[n - j];
        }
    }
    out
}

/// Raw moments `E[v3^j]`, j = 0..5, of the vibration along IA (axis 3).
pub fn ia_moments(vib: &Vibration) -> [f64; 6] {
    let mut m = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for t in vib.tones() {
        let a2 = t.amplitude_g[2] * t.amplitude_g[2];
        m = combine(&m, &[1.0, 0.0, 0.5 * a2, 0.0, 0.375 * a2 * a2, 0.0]);
    }
    let s2 = vib.covariance_g2[2][2].max(0.0);
    combine(&m, &[1.0, 0.0, s2, 0.0, vib.kurtosis[2] * s2 * s2, 0.0])
}

/// `[E[v3 v1], E[v3 v2]]`: the mean cross products with phase (MODEL.md section 6).
pub fn cross_moments_g2(vib: &Vibration) -> [f64; 2] {
    let mut c = [vib.covariance_g2[2][0], vib.covariance_g2[2][1]];
    for t in vib.tones() {
        for (i, ci) in c.iter_mut().enumerate() {
            *ci +=
                0.5 * t.amplitude_g[2] * t.amplitude_g[i] * (t.phase_rad[2] - t.phase_rad[i]).cos();
        }
    }
    c
}

/// The exact mean output `E[aF]` of one unit under one vibration state, as a function
/// of the flight acceleration. Building it (`set_vibration`) does the per-estimate
/// work; evaluating it is a few multiplications and one O(1) table read, with no
/// allocation, so the compensation kernel calls it per sample.
#[derive(Debug, Clone)]
pub struct MeanModel {
    passport: Passport,
    /// `poly[p]`: coefficient of `aL3^p` in `sum_n kn E[(aL3 + v3)^n]`.
    poly: [f64; 6],
    /// Moments of `v3`, kept for the VE components.
    moments: [f64; 6],
    cross_g2: [f64; 2],
    abs: AbsMean,
    /// Constants of [`Self::mean_output_with_derivatives_g`], kept by
    /// [`Self::update_poly`] so that the kernel does not recompute them per sample.
    hot: HotTerms,
}

/// [`MeanModel::mean_output_with_derivatives_g`]'s result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanOutputDerivatives {
    /// `E[aF]`, g.
    pub value_g: f64,
    /// `[d/daL1, d/daL2, d/daL3]` of `E[aF]`.
    pub gradient: [f64; 3],
    /// A bound on the second derivatives, 1/g.
    pub curvature_bound_per_g: f64,
    /// The slope of the asymmetry term's `E|aL3 + v3|` at this `aL3`, the input of
    /// [`MeanModel::asymmetry_step_error_bound_g`].
    pub abs_slope: f64,
}

/// The parts of `E[aF]` that do not depend on the flight acceleration.
#[derive(Debug, Clone, Copy, Default)]
struct HotTerms {
    /// `a0 + poly[0] + m31 E[v1 v3] + m32 E[v2 v3]`.
    offset_g: f64,
    /// `k1 + poly[1]`: the slope of the linear terms in `aL3`.
    linear: f64,
    /// `poly[2..=5]` and the coefficients of their first and second derivatives.
    poly: [f64; 4],
    slope: [f64; 4],
    curvature: [f64; 4],
    /// `0.5 k1 d1A` and its magnitude.
    half_asym: f64,
    half_asym_abs: f64,
    /// `|m31| + |m32|`: the mixed terms' part of the second-derivative bound.
    mixed_curvature: f64,
}

impl MeanModel {
    /// A model of the given unit with no vibration (allocates its table once).
    pub fn new(passport: Passport) -> Self {
        let mut m = Self {
            passport,
            poly: [0.0; 6],
            moments: [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            cross_g2: [0.0; 2],
            abs: AbsMean::new(),
            hot: HotTerms::default(),
        };
        m.update_poly();
        m
    }

    /// The unit's passport.
    pub fn passport(&self) -> &Passport {
        &self.passport
    }

    /// Replaces the passport (same vibration state).
    pub fn set_passport(&mut self, passport: Passport) {
        self.passport = passport;
        self.update_poly();
    }

    /// Sets the vibration state. Does not allocate.
    pub fn set_vibration(&mut self, vib: &Vibration) -> Result<()> {
        self.set_vibration_with(vib, false)
    }

    /// As [`Self::set_vibration`] for few evaluations of this state: one tone with
    /// random vibration is averaged over the tone's phase instead of tabulated
    /// ([`AbsMean::set_direct`]); each evaluation then costs more.
    pub fn set_vibration_direct(&mut self, vib: &Vibration) -> Result<()> {
        self.set_vibration_with(vib, true)
    }

    fn set_vibration_with(&mut self, vib: &Vibration, direct: bool) -> Result<()> {
        vib.validate()?;
        self.moments = ia_moments(vib);
        self.cross_g2 = cross_moments_g2(vib);
        let mut amplitudes = [0.0; MAX_TONES];
        for (a, t) in amplitudes.iter_mut().zip(vib.tones()) {
            *a = self.passport.lambda_at(t.freq_hz) * t.amplitude_g[2];
        }
        let set = if direct {
            AbsMean::set_direct
        } else {
            AbsMean::set
        };
        set(
            &mut self.abs,
            &amplitudes[..vib.tones().len()],
            vib.sigma_g(2),
            vib.kurtosis[2],
        )?;
        self.update_poly();
        Ok(())
    }

    fn update_poly(&mut self) {
        let k = &self.passport.k;
        self.poly = [0.0; 6];
        for n in 2..=5 {
            for p in 0..=n {
                self.poly[p] += k[n] * BINOMIAL[n][n - p] * self.moments[n - p];
            }
        }
        let (p, c) = (&self.passport, &self.poly);
        self.hot = HotTerms {
            offset_g: p.a0_g
                + c[0]
                + p.m31_per_g * self.cross_g2[0]
                + p.m32_per_g * self.cross_g2[1],
            linear: p.k1 + c[1],
            poly: [c[2], c[3], c[4], c[5]],
            slope: [2.0 * c[2], 3.0 * c[3], 4.0 * c[4], 5.0 * c[5]],
            curvature: [2.0 * c[2], 6.0 * c[3], 12.0 * c[4], 20.0 * c[5]],
            half_asym: 0.5 * p.k1 * p.d1a,
            half_asym_abs: (0.5 * p.k1 * p.d1a).abs(),
            mixed_curvature: p.m31_per_g.abs() + p.m32_per_g.abs(),
        };
    }

    /// `E[aF]` at the flight acceleration `a_l_g = [aL1, aL2, aL3]`, and its slope
    /// `dE[aF]/daL3`, both exact (MODEL.md section 6).
    #[inline]
    pub fn mean_output_g(&self, a_l_g: [f64; 3]) -> (f64, f64) {
        let (value, gradient) = self.mean_output_with_gradient_g(a_l_g);
        (value, gradient[2])
    }

    /// `E[aF]` at `a_l_g` and its gradient `[d/daL1, d/daL2, d/daL3]`.
    #[inline]
    pub fn mean_output_with_gradient_g(&self, a_l_g: [f64; 3]) -> (f64, [f64; 3]) {
        let d = self.mean_output_with_derivatives_g(a_l_g);
        (d.value_g, d.gradient)
    }

    /// `E[aF]`, its gradient, and a bound on its second derivatives: `|d2/daL3^2|` of
    /// the polynomial part plus `|m31| + |m32|` (the mixed terms). The piecewise-linear
    /// asymmetry table adds slope jumps of at most `d1A` per bin, which the compensation
    /// tolerates (see [`crate::compensation`]).
    #[inline(always)]
    pub fn mean_output_with_derivatives_g(&self, a_l_g: [f64; 3]) -> MeanOutputDerivatives {
        let p = &self.passport;
        let h = &self.hot;
        let [a1, a2, a] = a_l_g;
        // poly[0] and poly[1] aL3 are in `offset_g` and `linear`; Horner on the rest.
        let (c, d, e) = (&h.poly, &h.slope, &h.curvature);
        let poly_high = a * a * (c[0] + a * (c[1] + a * (c[2] + a * c[3])));
        let poly_slope = a * (d[0] + a * (d[1] + a * (d[2] + a * d[3])));
        let poly_curv = e[0] + a * (e[1] + a * (e[2] + a * e[3]));
        let (abs, abs_slope) = self.abs.eval(a);
        let cross_slope = p.m31_per_g * a1 + p.m32_per_g * a2;
        let value = h.offset_g
            + h.linear * a
            + h.half_asym * abs
            + poly_high
            + p.m1 * a1
            + p.m2 * a2
            + a * cross_slope;
        let gradient = [
            p.m1 + p.m31_per_g * a,
            p.m2 + p.m32_per_g * a,
            h.linear + h.half_asym * abs_slope + poly_slope + cross_slope,
        ];
        MeanOutputDerivatives {
            value_g: value,
            gradient,
            curvature_bound_per_g: poly_curv.abs() + h.mixed_curvature,
            abs_slope,
        }
    }

    /// A bound on the change of the asymmetry term's linearisation after a Newton
    /// step `step_g` taken from `a3_g`: `0.5 |k1 d1A| |s| max|slope change|`, exact
    /// for the convex `E|aL3 + v3|` (see [`AbsMean::slope_change_bound`]).
    /// `abs_slope` is [`MeanOutputDerivatives::abs_slope`] at `a3_g`, so that the
    /// table's bound reads one bin, not two.
    #[inline(always)]
    pub fn asymmetry_step_error_bound_g(&self, a3_g: f64, abs_slope: f64, step_g: f64) -> f64 {
        self.hot.half_asym_abs
            * step_g.abs()
            * self.abs.slope_change_bound_from(a3_g, abs_slope, step_g)
    }

    /// The exact VE components at `a_l_g`. The additive part `d0(1)` holds the
    /// asymmetry term evaluated at this `aL3` (it is not a polynomial in `aL3`).
    pub fn ve(&self, a_l_g: [f64; 3]) -> VeComponents {
        let p = &self.passport;
        let k = &p.k;
        let m = &self.moments;
        let a = a_l_g[2];
        // Coefficient of aL3^q of sum_n kn (E[(aL3+v)^n] - aL3^n): terms with j >= 1.
        let mut c = [0.0; 6];
        for n in 2..=5 {
            for j in 1..=n {
                c[n - j] += k[n] * BINOMIAL[n][j] * m[j];
            }
        }
        let asym = 0.5 * p.k1 * p.d1a * (self.abs.eval(a).0 - a.abs());
        VeComponents::new(
            [
                asym + c[0],
                p.m31_per_g * self.cross_g2[0],
                p.m32_per_g * self.cross_g2[1],
            ],
            // c[4] = 5 k5 E[v3] is zero for zero-mean vibration.
            [c[1], c[2], c[3]],
            a,
        )
    }
}

/// Exact VE of unit `p` at flight acceleration `a_l_g` under `vib` (MODEL.md section 6).
///
/// For one-shot evaluations (the lab's fits call it thousands of times): one tone with
/// random vibration is averaged directly over the tone's phase
/// ([`MeanModel::set_vibration_direct`]), and the model, whose table buffers and FFT
/// plans cost more to build than the evaluation, is kept per thread.
pub fn exact_ve(p: &Passport, a_l_g: [f64; 3], vib: &Vibration) -> Result<VeComponents> {
    thread_local! {
        static MODEL: std::cell::RefCell<Option<MeanModel>> = const { std::cell::RefCell::new(None) };
    }
    MODEL.with(|cell| {
        let mut slot = cell.borrow_mut();
        let model = match slot.as_mut() {
            Some(m) => {
                m.set_passport(*p);
                m
            }
            None => slot.insert(MeanModel::new(*p)),
        };
        model.set_vibration_direct(vib)?;
        Ok(model.ve(a_l_g))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fp::output_g;
    use crate::testutil::al15;
    use crate::ve::{published, Constants};
    use crate::vibration::Tone;

    /// Where the papers' model is exact (polynomial terms under one sinusoid), the
    /// two must agree: compare with the asymmetry and its constant switched off.
    #[test]
    fn equals_published_for_polynomial_terms_under_one_sinusoid() {
        let mut p = al15();
        p.d1a = 0.0;
        for (ab, al) in [
            ([0.8, 0.8, 0.42], 10.0),
            ([1.2, 1.2, 0.5], 2.0),
            ([2.0, 2.0, 2.0], -3.0),
        ] {
            let vib = Vibration::single_tone(20.0, ab);
            let a_l = [0.3, -0.7, al];
            let e = exact_ve(&p, a_l, &vib).unwrap();
            let q = published(&p, a_l, &vib, Constants::PAPER);
            for (x, y) in [
                (e.d01_g, q.d01_g),
                (e.d02_g, q.d02_g),
                (e.d03_g, q.d03_g),
                (e.delta1, q.delta1),
                (e.delta2_per_g, q.delta2_per_g),
                (e.delta3_per_g2, q.delta3_per_g2),
                (e.total_g, q.total_g),
            ] {
                assert!((x - y).abs() <= 1e-15 * y.abs().max(1e-12), "{x} vs {y}");
            }
        }
    }

    /// MODEL.md section 6: sigma3^2 = 38.4 g^2, aL3 = 10 g: exact about 924 mg, with
    /// 3 k4 sigma^4 and 15 k5 sigma^4 where the papers have k4 sigma^4 and 5 k5 sigma^4.
    #[test]
    fn random_band_gives_about_924_mg() {
        let mut v = Vibration::none();
        v.covariance_g2[2][2] = 38.4;
        let e = exact_ve(&al15(), [0.0, 0.0, 10.0], &v).unwrap();
        assert_eq!((e.total_g * 1e3).round(), 924.0);
        let s4 = 38.4f64 * 38.4;
        assert!((e.delta1 - (3.0 * 87e-6 * 38.4 + 15.0 * 0.9e-6 * s4)).abs() < 1e-15);
    }

    /// The mean output with no vibration is (FP) itself, and the model's slope is its
    /// derivative.
    #[test]
    fn mean_output_without_vibration_is_fp_and_slope_is_derivative() {
        let p = al15();
        let m = MeanModel::new(p);
        for a_l in [[0.2, 0.1, 1.0], [0.0, -1.0, -4.0]] {
            let (v, s) = m.mean_output_g(a_l);
            assert!((v - output_g(&p, a_l[0], a_l[1], a_l[2])).abs() < 1e-15);
            let d = 1e-5;
            let numeric = (output_g(&p, a_l[0], a_l[1], a_l[2] + d)
                - output_g(&p, a_l[0], a_l[1], a_l[2] - d))
                / (2.0 * d);
            assert!((s - numeric).abs() < 1e-9);
        }
    }

    #[test]
    fn moments_of_a_sine_and_noise_combine() {
        let mut v = Vibration::single_tone(10.0, [0.0, 0.0, 2.0]);
        v.covariance_g2[2][2] = 0.25;
        let m = ia_moments(&v);
        // E[(s+x)^4] = E[s^4] + 6 E[s^2] E[x^2] + E[x^4] = 6 + 6*2*0.25 + 3*0.0625.
        assert!((m[4] - (6.0 + 3.0 + 0.1875)).abs() < 1e-14);
        assert!((m[2] - 2.25).abs() < 1e-15);
    }

    #[test]
    fn cross_moment_follows_the_phase() {
        let mut v = Vibration::none();
        v.push_tone(Tone {
            freq_hz: 30.0,
            amplitude_g: [1.0, 2.0, 3.0],
            phase_rad: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
        })
        .unwrap();
        let c = cross_moments_g2(&v);
        assert!(
            c[0].abs() < 1e-15 && c[1].abs() < 1e-15,
            "quadrature: no rectification"
        );
    }
}
