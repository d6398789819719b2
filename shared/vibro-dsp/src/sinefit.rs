//! Least-squares fit of up to [`MAX_TONES`] sinusoids common to the three axes: the
//! IEEE 1057 four-parameter sine fit [IEEE Std 1057-2017 §4.1.4.3; Händel 2000],
//! generalised to K tones sharing one frequency each over three axes.
//!
//! Model of axis `a` at centred sample index `n = k - (N-1)/2`:
//!
//! ```text
//! x_a[n] = c_a + sum_i ( A_ai cos(w_i n) + B_ai sin(w_i n) )      w_i in rad/sample
//! ```
//!
//! Parameters: `K` frequencies, and per axis `L = 1 + 2K` linear ones. The fit is
//! variable projection: at given frequencies the linear parameters are the exact least
//! squares solution; the frequencies move by Gauss-Newton steps of the joint problem
//! (Jacobian column `d_ai = n (-A_ai sin(w_i n) + B_ai cos(w_i n))`), and a step is kept
//! only if it lowers the residual sum of squares.
//!
//! Departure from the standard: IEEE 1057 accumulates the normal equations sample by
//! sample. Centring `n` makes every deterministic Gram entry a closed form in the
//! Dirichlet kernel `D(t) = sum_n cos(t n) = sin(N t/2) / sin(t/2)` and its first two
//! derivatives (the odd sums vanish), so one pass over the data per iteration only
//! accumulates `sum x cos`, `sum x sin`, `sum n x cos`, `sum n x sin`. Invalid samples
//! are zero in `x` and their rows are subtracted from the closed forms.

use crate::MAX_TONES;

/// Linear parameters per axis: the offset, then `(A_i, B_i)` for each tone.
pub(crate) const L_MAX: usize = 1 + 2 * MAX_TONES;
const P_MAX: usize = MAX_TONES + 3 * L_MAX;
const MAX_ITERATIONS: usize = 8;
/// Converged when no frequency step exceeds this (in bins); that last step is taken
/// without a further pass (see `fit`).
const FINAL_STEP_BINS: f64 = 1e-5;
/// Largest frequency step of one iteration, in bins: the interpolated start is within
/// a small fraction of a bin, so a larger step means the linearisation is off.
const MAX_STEP_BINS: f64 = 0.25;
/// Phasors are advanced by complex rotation and re-seeded exactly this often, so the
/// rounding drift stays below ~1e-13 whatever the window length.
const RESEED_SAMPLES: usize = 256;

/// Sums over the centred indices `n = k - (N-1)/2`, `k = 0..N`:
/// `D(t) = sum cos(t n)`, `D'(t) = -sum n sin(t n)`, `D''(t) = -sum n^2 cos(t n)`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Dirichlet {
    n: f64,
    s2: f64,
    s4: f64,
    s6: f64,
}

impl Dirichlet {
    pub(crate) fn new(samples: usize) -> Self {
        let n = samples as f64;
        let n2 = n * n;
        // Power sums of the centred indices (Faulhaber, symmetric form).
        Self {
            n,
            s2: n * (n2 - 1.0) / 12.0,
            s4: n * (n2 - 1.0) * (3.0 * n2 - 7.0) / 240.0,
            s6: n * (n2 - 1.0) * (3.0 * n2 * n2 - 18.0 * n2 + 31.0) / 1344.0,
        }
    }

    /// `D` alone at `t` (rad/sample), for `|t| < 2 pi`.
    pub(crate) fn value(&self, t: f64) -> f64 {
        if (t * self.n).abs() < 0.05 {
            let t2 = t * t;
            return self.n - t2 * self.s2 / 2.0 + t2 * t2 * self.s4 / 24.0
                - t2 * t2 * t2 * self.s6 / 720.0;
        }
        (self.n * t / 2.0).sin() / (t / 2.0).sin()
    }

    /// `(D, D', D'')` at `t` (rad/sample), for `|t| < 2 pi`.
    pub(crate) fn eval(&self, t: f64) -> (f64, f64, f64) {
        if (t * self.n).abs() < 0.05 {
            // Taylor series: the closed form below divides by sin(t/2) -> 0. With
            // N|t| < 0.05 the first omitted term is below 1e-18 relative.
            let t2 = t * t;
            let d = self.n - t2 * self.s2 / 2.0 + t2 * t2 * self.s4 / 24.0
                - t2 * t2 * t2 * self.s6 / 720.0;
            let d1 = -t * self.s2 + t * t2 * self.s4 / 6.0 - t * t2 * t2 * self.s6 / 120.0;
            let d2 = -self.s2 + t2 * self.s4 / 2.0 - t2 * t2 * self.s6 / 24.0;
            return (d, d1, d2);
        }
        // D = f/g with f = sin(N t/2), g = sin(t/2); differentiate f = D g twice.
        let (f, fp) = {
            let (s, c) = (self.n * t / 2.0).sin_cos();
            (s, self.n / 2.0 * c)
        };
        let fpp = -self.n * self.n / 4.0 * f;
        let (sg, cg) = (t / 2.0).sin_cos();
        let (g, gp, gpp) = (sg, cg / 2.0, -sg / 4.0);
        let d = f / g;
        let d1 = (fp - d * gp) / g;
        let d2 = (fpp - 2.0 * d1 * gp - d * gpp) / g;
        (d, d1, d2)
    }
}

/// Frequencies and linear parameters of a fit.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FitState {
    pub(crate) tones: usize,
    /// rad/sample.
    pub(crate) omega: [f64; MAX_TONES],
    /// Per axis: `[c, A_1, B_1, A_2, B_2, ...]`.
    pub(crate) lin: [[f64; L_MAX]; 3],
}

impl FitState {
    /// Tone `i`'s `(A, B)` per axis (`A cos + B sin`).
    #[inline]
    pub(crate) fn amplitudes(&self, i: usize) -> [(f64, f64); 3] {
        std::array::from_fn(|a| (self.lin[a][1 + 2 * i], self.lin[a][2 + 2 * i]))
    }
}

impl Default for FitState {
    fn default() -> Self {
        Self {
            tones: 0,
            omega: [0.0; MAX_TONES],
            lin: [[0.0; L_MAX]; 3],
        }
    }
}

/// Workspace of the fit; built once per estimator.
pub(crate) struct SineFit {
    samples: usize,
    dirichlet: Dirichlet,
    /// Gram matrix of the linear columns (the same for every axis).
    gram: [[f64; L_MAX]; L_MAX],
    /// `<d_ai, phi_l>` per axis.
    coupling: [[[f64; L_MAX]; MAX_TONES]; 3],
    /// `sum_a <d_ai, d_aj>`.
    w: [[f64; MAX_TONES]; MAX_TONES],
    /// Data sums: `sum x phi_l` and `[sum n x cos, sum n x sin]` per axis and tone.
    b: [[f64; L_MAX]; 3],
    bn: [[[f64; 2]; MAX_TONES]; 3],
    /// `sum x` and `sum x^2` per axis: the same in every pass of one fit.
    sx: [f64; 3],
    sxx: [f64; 3],
    normal: Vec<f64>,
    rhs: Vec<f64>,
    lin_matrix: Vec<f64>,
}

impl SineFit {
    pub(crate) fn new(samples: usize) -> Self {
        Self {
            samples,
            dirichlet: Dirichlet::new(samples),
            gram: [[0.0; L_MAX]; L_MAX],
            coupling: [[[0.0; L_MAX]; MAX_TONES]; 3],
            w: [[0.0; MAX_TONES]; MAX_TONES],
            b: [[0.0; L_MAX]; 3],
            bn: [[[0.0; 2]; MAX_TONES]; 3],
            sx: [0.0; 3],
            sxx: [0.0; 3],
            normal: vec![0.0; P_MAX * P_MAX],
            rhs: vec![0.0; P_MAX],
            lin_matrix: vec![0.0; L_MAX * L_MAX],
        }
    }

    fn centre(&self) -> f64 {
        (self.samples as f64 - 1.0) / 2.0
    }

    /// Fits `omega0.len()` tones to `x` (invalid samples zeroed, their indices in
    /// `invalid`), starting from the frequencies `omega0` (rad/sample). Returns `false`
    /// when not even the linear problem at `omega0` is solvable (tones too close).
    pub(crate) fn fit(
        &mut self,
        x: [&[f64]; 3],
        invalid: &[u32],
        omega0: &[f64],
        out: &mut FitState,
    ) -> bool {
        let k = omega0.len().min(MAX_TONES);
        let bin_rad = std::f64::consts::TAU / self.samples as f64;
        let mut best = FitState {
            tones: k,
            ..FitState::default()
        };
        best.omega[..k].copy_from_slice(&omega0[..k]);
        // The data's own sums, once per fit (each pass needs them).
        for a in 0..3 {
            let xa = &x[a][..self.samples];
            self.sx[a] = crate::sums::sum(xa);
            self.sxx[a] = crate::sums::sum_sq(xa);
        }
        self.pass(x, &best.omega[..k]);
        self.build_gram(&best.omega[..k], invalid);
        if !self.solve_linear(k, &mut best.lin) {
            return false;
        }
        let mut rss_best = self.rss(k, &best.lin);
        for _ in 0..MAX_ITERATIONS {
            if k == 0 {
                break;
            }
            // Gauss-Newton step of the joint problem from (omega, lin*(omega)); the data
            // sums and the Gram matrix in `self` are those at `best`.
            self.build_coupling(&best, invalid);
            let Some(step_scale) = self.gauss_newton_step(&best, bin_rad) else {
                break;
            };
            let mut cand = best;
            let mut largest_bins: f64 = 0.0;
            for i in 0..k {
                let d = self.rhs[i] * step_scale;
                cand.omega[i] += d;
                largest_bins = largest_bins.max(d.abs() / bin_rad);
            }
            if !frequencies_are_valid(&cand.omega[..k], bin_rad) {
                break;
            }
            if largest_bins < FINAL_STEP_BINS {
                // Gauss-Newton converges quadratically: after a step this small the
                // remaining error is of the order of its square, far below any
                // Cramér-Rao bound, and the joint step's linear part is exact to the
                // same order (~1e-9 relative amplitude). Another pass would only
                // confirm it, at a third of the estimator's time.
                let l = 1 + 2 * k;
                for a in 0..3 {
                    for m in 0..l {
                        cand.lin[a][m] += self.rhs[k + a * l + m] * step_scale;
                    }
                }
                best = cand;
                break;
            }
            self.pass(x, &cand.omega[..k]);
            self.build_gram(&cand.omega[..k], invalid);
            if !self.solve_linear(k, &mut cand.lin) {
                break;
            }
            let rss = self.rss(k, &cand.lin);
            // Accept ties within rounding: near convergence the RSS difference is below
            // the precision of sum(x^2) - b.theta.
            let tolerance = 1e-12 * (self.sxx.iter().sum::<f64>()) + f64::MIN_POSITIVE;
            if rss > rss_best + tolerance {
                break;
            }
            best = cand;
            rss_best = rss.min(rss_best);
        }
        *out = best;
        true
    }

    /// One pass over the data at frequencies `omega`: fills `b` and `bn` (`sx` and
    /// `sxx`, which `fit` took first, do not depend on them).
    fn pass(&mut self, x: [&[f64]; 3], omega: &[f64]) {
        let n_samples = self.samples;
        for a in 0..3 {
            self.b[a] = [0.0; L_MAX];
            self.b[a][0] = self.sx[a];
        }
        for (i, &w) in omega.iter().enumerate() {
            let acc = tone_sums(x, n_samples, self.centre(), w);
            for a in 0..3 {
                self.b[a][1 + 2 * i] = acc[a][0];
                self.b[a][2 + 2 * i] = acc[a][1];
                self.bn[a][i] = [acc[a][2], acc[a][3]];
            }
        }
    }

    /// Gram matrix of `phi = [1, cos w_1 n, sin w_1 n, ...]` over the valid samples.
    fn build_gram(&mut self, omega: &[f64], invalid: &[u32]) {
        let k = omega.len();
        let l = 1 + 2 * k;
        let d = self.dirichlet;
        self.gram[0][0] = self.samples as f64;
        for j in 0..k {
            self.gram[0][1 + 2 * j] = d.eval(omega[j]).0;
            self.gram[0][2 + 2 * j] = 0.0;
        }
        for i in 0..k {
            for j in i..k {
                let (dd, _, _) = d.eval(omega[i] - omega[j]);
                let (ds, _, _) = d.eval(omega[i] + omega[j]);
                self.gram[1 + 2 * i][1 + 2 * j] = 0.5 * (dd + ds);
                self.gram[2 + 2 * i][2 + 2 * j] = 0.5 * (dd - ds);
                self.gram[1 + 2 * i][2 + 2 * j] = 0.0;
                self.gram[2 + 2 * i][1 + 2 * j] = 0.0;
            }
        }
        let centre = self.centre();
        let mut phi = [0.0; L_MAX];
        for &idx in invalid {
            let n = idx as f64 - centre;
            fill_phi(&mut phi, omega, n);
            for r in 0..l {
                for c in r..l {
                    self.gram[r][c] -= phi[r] * phi[c];
                }
            }
        }
        for r in 0..l {
            for c in 0..r {
                self.gram[r][c] = self.gram[c][r];
            }
        }
    }

    /// The frequency columns' products with the linear columns and with each other.
    fn build_coupling(&mut self, state: &FitState, invalid: &[u32]) {
        let k = state.tones;
        let l = 1 + 2 * k;
        let d = self.dirichlet;
        self.w = [[0.0; MAX_TONES]; MAX_TONES];
        for i in 0..k {
            let wi = state.omega[i];
            let d1_i = d.eval(wi).1;
            for a in 0..3 {
                self.coupling[a][i][0] = state.lin[a][1 + 2 * i] * d1_i;
            }
            for j in 0..k {
                let wj = state.omega[j];
                let (_, d1_diff, d2_diff) = d.eval(wi - wj);
                let (_, d1_sum, d2_sum) = d.eval(wi + wj);
                let (c2_diff, c2_sum) = (-d2_diff, -d2_sum);
                for a in 0..3 {
                    let (ai, bi) = (state.lin[a][1 + 2 * i], state.lin[a][2 + 2 * i]);
                    let (aj, bj) = (state.lin[a][1 + 2 * j], state.lin[a][2 + 2 * j]);
                    self.coupling[a][i][1 + 2 * j] = 0.5 * ai * (d1_sum + d1_diff);
                    self.coupling[a][i][2 + 2 * j] = -0.5 * bi * (d1_sum - d1_diff);
                    self.w[i][j] +=
                        0.5 * ai * aj * (c2_diff - c2_sum) + 0.5 * bi * bj * (c2_diff + c2_sum);
                }
            }
        }
        let centre = self.centre();
        let mut phi = [0.0; L_MAX];
        let mut dcol = [[0.0; MAX_TONES]; 3];
        for &idx in invalid {
            let n = idx as f64 - centre;
            fill_phi(&mut phi, &state.omega[..k], n);
            for a in 0..3 {
                for i in 0..k {
                    let (c, s) = (phi[1 + 2 * i], phi[2 + 2 * i]);
                    dcol[a][i] = n * (-state.lin[a][1 + 2 * i] * s + state.lin[a][2 + 2 * i] * c);
                }
            }
            for a in 0..3 {
                for i in 0..k {
                    for m in 0..l {
                        self.coupling[a][i][m] -= dcol[a][i] * phi[m];
                    }
                }
            }
            for i in 0..k {
                for j in 0..k {
                    self.w[i][j] -= (0..3).map(|a| dcol[a][i] * dcol[a][j]).sum::<f64>();
                }
            }
        }
    }

    /// Solves the joint normal equations; the frequency steps end up in
    /// `rhs[..k]`. Returns the factor that limits the largest step to
    /// `MAX_STEP_BINS`, or `None` if the system is singular.
    fn gauss_newton_step(&mut self, state: &FitState, bin_rad: f64) -> Option<f64> {
        let k = state.tones;
        let l = 1 + 2 * k;
        let p = k + 3 * l;
        let g = &mut self.normal[..p * p];
        g.fill(0.0);
        let rhs = &mut self.rhs[..p];
        for i in 0..k {
            for j in 0..k {
                g[i * p + j] = self.w[i][j];
            }
            let mut r = 0.0;
            for a in 0..3 {
                let (ai, bi) = (state.lin[a][1 + 2 * i], state.lin[a][2 + 2 * i]);
                r += -ai * self.bn[a][i][1] + bi * self.bn[a][i][0];
                for m in 0..l {
                    let col = k + a * l + m;
                    g[i * p + col] = self.coupling[a][i][m];
                    g[col * p + i] = self.coupling[a][i][m];
                    r -= self.coupling[a][i][m] * state.lin[a][m];
                }
            }
            rhs[i] = r;
        }
        for a in 0..3 {
            for r in 0..l {
                let row = k + a * l + r;
                let mut v = self.b[a][r];
                for c in 0..l {
                    g[row * p + k + a * l + c] = self.gram[r][c];
                    v -= self.gram[r][c] * state.lin[a][c];
                }
                rhs[row] = v;
            }
        }
        if !solve_spd(g, p, rhs) {
            return None;
        }
        let largest = rhs[..k].iter().fold(0.0f64, |m, d| m.max(d.abs())) / bin_rad;
        Some(if largest > MAX_STEP_BINS {
            MAX_STEP_BINS / largest
        } else {
            1.0
        })
    }

    /// Linear least squares at the current Gram matrix and data sums.
    fn solve_linear(&mut self, k: usize, lin: &mut [[f64; L_MAX]; 3]) -> bool {
        let l = 1 + 2 * k;
        for (a, lin_a) in lin.iter_mut().enumerate() {
            let m = &mut self.lin_matrix[..l * l];
            for r in 0..l {
                for c in 0..l {
                    m[r * l + c] = self.gram[r][c];
                }
            }
            *lin_a = [0.0; L_MAX];
            lin_a[..l].copy_from_slice(&self.b[a][..l]);
            if !solve_spd(m, l, &mut lin_a[..l]) {
                return false;
            }
        }
        true
    }

    /// Residual sum of squares at a linear least-squares solution: `sum x^2 - b.theta`.
    fn rss(&self, k: usize, lin: &[[f64; L_MAX]; 3]) -> f64 {
        let l = 1 + 2 * k;
        (0..3)
            .map(|a| self.sxx[a] - (0..l).map(|m| self.b[a][m] * lin[a][m]).sum::<f64>())
            .sum()
    }

    /// `out_a = x_a - model_a` for the tones whose `keep` is true (the offset is always
    /// removed); invalid samples are set to 0.
    pub(crate) fn residual(
        &self,
        x: [&[f64]; 3],
        state: &FitState,
        keep: &[bool],
        invalid: &[u32],
        out: &mut [Vec<f64>; 3],
    ) {
        let n_samples = self.samples;
        let centre = self.centre();
        for a in 0..3 {
            let c0 = state.lin[a][0];
            for (o, v) in out[a][..n_samples].iter_mut().zip(&x[a][..n_samples]) {
                *o = v - c0;
            }
        }
        for i in 0..state.tones {
            if !keep.get(i).copied().unwrap_or(false) {
                continue;
            }
            let amp = state.amplitudes(i);
            let [o0, o1, o2] = out;
            let outs = [
                &mut o0[..n_samples],
                &mut o1[..n_samples],
                &mut o2[..n_samples],
            ];
            subtract_tone(outs, centre, state.omega[i], amp);
        }
        for &idx in invalid {
            for o in out.iter_mut() {
                if let Some(v) = o.get_mut(idx as usize) {
                    *v = 0.0;
                }
            }
        }
    }
}

/// Lanes of the phasor recurrence: four interleaved phasors stepping by `4 w` break the
/// serial dependency of one recurrence and let the compiler use SIMD.
const LANES: usize = 4;

/// Phasors `(cos, sin)(w n)` for the `LANES` samples from `first` (centred index).
#[inline(always)]
fn seed_lanes(w: f64, first: f64) -> ([f64; LANES], [f64; LANES]) {
    let mut c = [0.0; LANES];
    let mut s = [0.0; LANES];
    for l in 0..LANES {
        let (sl, cl) = (w * (first + l as f64)).sin_cos();
        c[l] = cl;
        s[l] = sl;
    }
    (c, s)
}

/// Advances every lane's phasor by the rotation `(cq, sq)`.
#[inline(always)]
fn rotate(c: &mut [f64; LANES], s: &mut [f64; LANES], cq: f64, sq: f64) {
    for l in 0..LANES {
        let c_next = c[l] * cq - s[l] * sq;
        s[l] = s[l] * cq + c[l] * sq;
        c[l] = c_next;
    }
}

/// Per axis: `[sum x cos, sum x sin, sum n x cos, sum n x sin]` at `w` (rad/sample),
/// with `n = k - centre`. The hot loop of the estimator: on x86-64 CPUs with AVX2 a
/// copy compiled for it runs the four lanes in one register.
fn tone_sums(x: [&[f64]; 3], samples: usize, centre: f64, w: f64) -> [[f64; 4]; 3] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, the only feature this copy is compiled for.
        return unsafe { tone_sums_avx2(x, samples, centre, w) };
    }
    tone_sums_portable(x, samples, centre, w)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn tone_sums_avx2(x: [&[f64]; 3], samples: usize, centre: f64, w: f64) -> [[f64; 4]; 3] {
    tone_sums_portable(x, samples, centre, w)
}

#[inline(always)]
fn tone_sums_portable(x: [&[f64]; 3], samples: usize, centre: f64, w: f64) -> [[f64; 4]; 3] {
    let (sq, cq) = (w * LANES as f64).sin_cos();
    // acc[a] = [x cos, x sin, n x cos, n x sin], each a vector of lanes.
    let mut acc = [[[0.0f64; LANES]; 4]; 3];
    let mut out = [[0.0f64; 4]; 3];
    let mut start = 0;
    while start < samples {
        let end = (start + RESEED_SAMPLES).min(samples);
        let full = start + (end - start) / LANES * LANES;
        let (mut c, mut s) = seed_lanes(w, start as f64 - centre);
        let mut n: [f64; LANES] = std::array::from_fn(|l| (start + l) as f64 - centre);
        for k in (start..full).step_by(LANES) {
            for (acc_a, xa) in acc.iter_mut().zip(x) {
                let v: [f64; LANES] = std::array::from_fn(|l| xa[k + l]);
                let nv: [f64; LANES] = std::array::from_fn(|l| n[l] * v[l]);
                let [xc, xs, nxc, nxs] = acc_a;
                for l in 0..LANES {
                    xc[l] += v[l] * c[l];
                    xs[l] += v[l] * s[l];
                    nxc[l] += nv[l] * c[l];
                    nxs[l] += nv[l] * s[l];
                }
            }
            rotate(&mut c, &mut s, cq, sq);
            for nl in n.iter_mut() {
                *nl += LANES as f64;
            }
        }
        // The last few samples of the window, if N is not a multiple of LANES.
        for k in full..end {
            let nk = k as f64 - centre;
            let (sk, ck) = (w * nk).sin_cos();
            for a in 0..3 {
                let v = x[a][k];
                out[a][0] += v * ck;
                out[a][1] += v * sk;
                out[a][2] += nk * v * ck;
                out[a][3] += nk * v * sk;
            }
        }
        start = end;
    }
    for a in 0..3 {
        for q in 0..4 {
            out[a][q] += acc[a][q].iter().sum::<f64>();
        }
    }
    out
}

/// `out_a -= A_a cos(w n) + B_a sin(w n)` with `n = k - centre`.
fn subtract_tone(out: [&mut [f64]; 3], centre: f64, w: f64, amp: [(f64, f64); 3]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, the only feature this copy is compiled for.
        return unsafe { subtract_tone_avx2(out, centre, w, amp) };
    }
    subtract_tone_portable(out, centre, w, amp)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn subtract_tone_avx2(out: [&mut [f64]; 3], centre: f64, w: f64, amp: [(f64, f64); 3]) {
    subtract_tone_portable(out, centre, w, amp)
}

#[inline(always)]
fn subtract_tone_portable(out: [&mut [f64]; 3], centre: f64, w: f64, amp: [(f64, f64); 3]) {
    let samples = out[0].len();
    let (sq, cq) = (w * LANES as f64).sin_cos();
    let [o0, o1, o2] = out;
    let mut start = 0;
    while start < samples {
        let end = (start + RESEED_SAMPLES).min(samples);
        let full = start + (end - start) / LANES * LANES;
        let (mut c, mut s) = seed_lanes(w, start as f64 - centre);
        let mut k = start;
        while k < full {
            for (o, &(ca, cb)) in [
                &mut o0[k..k + LANES],
                &mut o1[k..k + LANES],
                &mut o2[k..k + LANES],
            ]
            .into_iter()
            .zip(&amp)
            {
                for l in 0..LANES {
                    o[l] -= ca * c[l] + cb * s[l];
                }
            }
            rotate(&mut c, &mut s, cq, sq);
            k += LANES;
        }
        for k in full..end {
            let (sk, ck) = (w * (k as f64 - centre)).sin_cos();
            o0[k] -= amp[0].0 * ck + amp[0].1 * sk;
            o1[k] -= amp[1].0 * ck + amp[1].1 * sk;
            o2[k] -= amp[2].0 * ck + amp[2].1 * sk;
        }
        start = end;
    }
}

fn fill_phi(phi: &mut [f64; L_MAX], omega: &[f64], n: f64) {
    phi[0] = 1.0;
    for (i, w) in omega.iter().enumerate() {
        let (s, c) = (w * n).sin_cos();
        phi[1 + 2 * i] = c;
        phi[2 + 2 * i] = s;
    }
}

/// Frequencies stay inside (0, pi) and at least one bin apart: otherwise two columns
/// become (nearly) collinear and the fit is meaningless.
fn frequencies_are_valid(omega: &[f64], bin_rad: f64) -> bool {
    let inside = omega
        .iter()
        .all(|w| *w > bin_rad && *w < std::f64::consts::PI - bin_rad);
    let apart = omega
        .iter()
        .enumerate()
        .all(|(i, a)| omega[i + 1..].iter().all(|b| (a - b).abs() >= bin_rad));
    inside && apart
}

/// Solves `m x = rhs` in place (`rhs` becomes `x`) for a symmetric positive definite
/// `m` (row-major, `p x p`) by Cholesky after symmetric diagonal scaling: the frequency
/// columns are ~N^3 A^2 and the linear ones ~N, so unscaled pivots would span 1e10.
/// Returns `false` if `m` is not numerically positive definite.
pub(crate) fn solve_spd(m: &mut [f64], p: usize, rhs: &mut [f64]) -> bool {
    let mut scale = [0.0; P_MAX];
    for i in 0..p {
        let d = m[i * p + i];
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        scale[i] = 1.0 / d.sqrt();
    }
    for i in 0..p {
        for j in 0..p {
            m[i * p + j] *= scale[i] * scale[j];
        }
        rhs[i] *= scale[i];
    }
    // Cholesky: m = L L^T, L stored in the lower triangle.
    for j in 0..p {
        let mut d = m[j * p + j];
        for k in 0..j {
            d -= m[j * p + k] * m[j * p + k];
        }
        // Scaled diagonal is 1: a pivot below 1e-12 means the columns are dependent.
        if d.is_nan() || d <= 1e-12 {
            return false;
        }
        let d = d.sqrt();
        m[j * p + j] = d;
        for i in j + 1..p {
            let mut v = m[i * p + j];
            for k in 0..j {
                v -= m[i * p + k] * m[j * p + k];
            }
            m[i * p + j] = v / d;
        }
    }
    for i in 0..p {
        let mut v = rhs[i];
        for k in 0..i {
            v -= m[i * p + k] * rhs[k];
        }
        rhs[i] = v / m[i * p + i];
    }
    for i in (0..p).rev() {
        let mut v = rhs[i];
        for k in i + 1..p {
            v -= m[k * p + i] * rhs[k];
        }
        rhs[i] = v / m[i * p + i];
    }
    for i in 0..p {
        rhs[i] *= scale[i];
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(samples: usize, t: f64) -> (f64, f64, f64) {
        let c = (samples as f64 - 1.0) / 2.0;
        let mut s = (0.0, 0.0, 0.0);
        for k in 0..samples {
            let n = k as f64 - c;
            s.0 += (t * n).cos();
            s.1 -= n * (t * n).sin();
            s.2 -= n * n * (t * n).cos();
        }
        s
    }

    #[test]
    fn dirichlet_closed_forms_match_direct_sums() {
        for &samples in &[255usize, 256, 1000, 4097] {
            let d = Dirichlet::new(samples);
            let bin = std::f64::consts::TAU / samples as f64;
            for &t in &[
                0.0,
                1e-7,
                0.01 * bin,
                0.3 * bin,
                1.0,
                2.5 * bin,
                17.3 * bin,
                3.0,
                6.0,
            ] {
                let (a, b, c) = d.eval(t);
                let (ea, eb, ec) = brute(samples, t);
                let n = samples as f64;
                assert!((a - ea).abs() < 1e-9 * n, "D({t}) N={samples}: {a} vs {ea}");
                assert!(
                    (b - eb).abs() < 1e-9 * n * n,
                    "D'({t}) N={samples}: {b} vs {eb}"
                );
                assert!(
                    (c - ec).abs() < 1e-9 * n * n * n,
                    "D''({t}) N={samples}: {c} vs {ec}"
                );
            }
        }
    }

    #[test]
    fn noise_free_tones_are_recovered_exactly_with_gaps() {
        let samples = 2000;
        let centre = (samples as f64 - 1.0) / 2.0;
        let truth = [
            (0.0311, [1.0, -0.5, 0.25], [0.3, 0.0, -0.7]),
            (0.4, [0.0, 2.0, 1.0], [0.1, 0.2, 0.3]),
        ];
        let offset = [0.1, -0.2, 0.0];
        let mut x: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; samples]);
        for a in 0..3 {
            for k in 0..samples {
                let n = k as f64 - centre;
                x[a][k] = offset[a]
                    + truth
                        .iter()
                        .map(|(w, amp, ph)| amp[a] * (w * n + ph[a]).sin())
                        .sum::<f64>();
            }
        }
        let invalid: Vec<u32> = (500..530).chain([7, 1999]).collect();
        for &i in &invalid {
            for xa in x.iter_mut() {
                xa[i as usize] = 0.0;
            }
        }
        let mut fit = SineFit::new(samples);
        let mut out = FitState::default();
        let start = [
            0.0311 + 0.1 * std::f64::consts::TAU / 2000.0,
            0.4 - 0.05 * std::f64::consts::TAU / 2000.0,
        ];
        assert!(fit.fit([&x[0], &x[1], &x[2]], &invalid, &start, &mut out));
        for (i, (w, amp, ph)) in truth.iter().enumerate() {
            assert!((out.omega[i] - w).abs() < 1e-12, "{} vs {w}", out.omega[i]);
            for a in 0..3 {
                // A cos + B sin = R sin(wn + ph) with A = R sin ph, B = R cos ph.
                let (ea, eb) = (amp[a] * ph[a].sin(), amp[a] * ph[a].cos());
                // The last Gauss-Newton step is taken without a confirming pass, which
                // leaves ~1e-9 in the linear parameters: 60x below the amplitude CRB at
                // a per-sample SNR of 100 dB with this N.
                assert!((out.lin[a][1 + 2 * i] - ea).abs() < 1e-8);
                assert!((out.lin[a][2 + 2 * i] - eb).abs() < 1e-8);
            }
        }
        for a in 0..3 {
            assert!((out.lin[a][0] - offset[a]).abs() < 1e-10);
        }
        let mut res: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; samples]);
        fit.residual(
            [&x[0], &x[1], &x[2]],
            &out,
            &[true, true],
            &invalid,
            &mut res,
        );
        let worst = res.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(worst < 1e-9, "{worst}");
    }

    #[test]
    fn spd_solver_matches_a_known_solution_and_refuses_singular_matrices() {
        let mut m = vec![4.0, 2.0, 2.0, 3.0];
        let mut r = vec![2.0, 1.0];
        assert!(solve_spd(&mut m, 2, &mut r));
        // [4 2; 2 3] x = [2; 1] -> x = [0.5, 0]
        assert!((r[0] - 0.5).abs() < 1e-15 && r[1].abs() < 1e-15);
        let mut m = vec![1.0, 1.0, 1.0, 1.0];
        let mut r = vec![1.0, 1.0];
        assert!(!solve_spd(&mut m, 2, &mut r));
    }
}
