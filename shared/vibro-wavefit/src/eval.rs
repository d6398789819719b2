//! Every reading of a prepared run predicted from its samples under a model (MODEL.md
//! section 12, the forward direction of the compensator's stage):
//!
//! ```text
//! R_j = mean over (t_j - P, t_j] of [ FP(aL + v_u(t)) + output effects ]
//!     = lin(aL_j)  +  lin_vib_j  +  rest_j
//! ```
//!
//! - `v_u(t)`, the vibration at unit `u` in its axes: the sensors' record (chain undone,
//!   [`crate::prepare`]), shifted by the delay's change `e^{j w dtau}`, mapped to the
//!   body frame through the sensors' response (each sensor along its unit's IA, or as a
//!   `sensor_error` effect says, `Effect::sensor_response`), to each unit's axes, and
//!   through the path effects' continuous-time transfers (`Effect::path_transfer`:
//!   a mount, the unit's own response), all per frequency bin;
//! - `lin(a) = a0 + k1 a3 + m1 a1 + m2 a2`, FP's linear part: at the reference, and its
//!   response to the vibration, `lin_vib_j`, taken exactly in the frequency domain (the
//!   continuous boxcar `(1 - e^{-j w P}) / (j w P)`, then the spectrum folded onto the
//!   readings' rate): no quadrature error in the term that is 1e4 times the vibration
//!   error. From the bins that carry vibration only (`PreparedRun::lin_bins`): above
//!   them the sensors record their own noise, which the unit never felt;
//! - `rest_j`, the mean of `FP(a) + output effects - lin(a)` (asymmetry, k2..k5, the
//!   cross-axis terms, vibropendulous, anisoelastic, k6/k7, heating, the clip) on the
//!   grid by Gregory's end-corrected rule, with the effects' own time-domain hooks
//!   (`Effect::at_unit_output`), run through every grid point in order from the
//!   record's start (their filters keep state).
//!
//! The parts are kept apart so that a fit differentiates each where it is cheap: a path
//! or chain parameter through `lin_vib` alone (a fold per parameter, no grid pass), an
//! output effect's parameter through `rest` alone (a grid pass, the signals reused).

use crate::prepare::PreparedRun;
use crate::{Error, Result};
use realfft::num_complex::Complex;
use realfft::RealFftPlanner;
use std::f64::consts::PI;
use vibro_effects::{BlockCtx, Effect};
use vibro_physics::fp;
use vibro_physics::passport::Passport;
use vibro_physics::triad::UnitAxes;

/// What a parameter acts through, so that its derivative is taken where it is cheap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Role {
    /// The sensors' delay, a sensor's response or a path filter: the vibration each
    /// unit sees (its derivative through `lin_vib`).
    Path,
    /// A term of the unit's output (its derivative through `rest`).
    Output,
}

/// The model at one parameter point, built for a run's three units.
pub struct Built {
    /// Per unit, the model's effects.
    effects: [Vec<Box<dyn Effect>>; 3],
    /// Per unit, per effect: acts through its path transfer (not its hook).
    is_path: [Vec<bool>; 3],
    /// The delay, s.
    pub delay_s: f64,
}

impl Built {
    /// The model `tables` (`[[effect]]` tables) for `passports`, and the sensors' delay.
    /// Effects the waveform cannot evaluate are refused: a path effect without a
    /// transfer (the phases of `axis_phase` are a description's, not a filter's), the
    /// kurtosis of `non_gaussian` (the samples carry their own), an empirical
    /// correction (a mean, not a waveform).
    pub fn new(tables: &[toml::Table], passports: &[Passport; 3], delay_s: f64) -> Result<Self> {
        let mut effects: [Vec<Box<dyn Effect>>; 3] = Default::default();
        let mut is_path: [Vec<bool>; 3] = Default::default();
        for u in 0..3 {
            let list = vibro_effects::model::build_effects(tables, &passports[u])?;
            for e in &list {
                let kind = e.kind();
                if matches!(kind, "non_gaussian" | "axis_phase" | "empirical") {
                    return Err(Error::NotOnWaveform(kind.to_string()));
                }
                let path = e.path_transfer(u, 1.0).is_some() || e.sensor_response(u).is_some();
                if e.on_vibration_path() && e.path_transfer(u, 1.0).is_none() {
                    return Err(Error::NotOnWaveform(kind.to_string()));
                }
                is_path[u].push(path);
            }
            effects[u] = list;
        }
        Ok(Self {
            effects,
            is_path,
            delay_s,
        })
    }

    #[allow(dead_code)]
    fn has_path(&self) -> bool {
        self.effects
            .iter()
            .flatten()
            .any(|e| (0..3).any(|u| e.path_transfer(u, 1.0).is_some()))
    }

    /// Per unit, what its sensor reads in the unit's axes `[OA, PA, IA]`.
    fn sensor_rows(&self) -> [[f64; 3]; 3] {
        std::array::from_fn(|u| {
            let mut c = [0.0, 0.0, 1.0];
            for e in &self.effects[u] {
                if let Some(r) = e.sensor_response(u) {
                    c[0] += r[0];
                    c[1] += r[1];
                    c[2] += r[2] - 1.0;
                }
            }
            c
        })
    }
}

/// `R_u`: a body vector in unit `u`'s axes `[OA, PA, IA]`, as a matrix.
fn unit_matrix(axes: &UnitAxes) -> [[f64; 3]; 3] {
    let mut r = [[0.0; 3]; 3];
    for (i, a) in [axes.oa, axes.pa, axes.ia].iter().enumerate() {
        r[i][a.body_index] = f64::from(a.sign);
    }
    r
}

fn inverse3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if !(det.is_finite() && det.abs() > 1e-9) {
        return None;
    }
    let c =
        |r0: usize, r1: usize, c0: usize, c1: usize| a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0];
    Some([
        [
            c(1, 2, 1, 2) / det,
            -c(0, 2, 1, 2) / det,
            c(0, 1, 1, 2) / det,
        ],
        [
            -c(1, 2, 0, 2) / det,
            c(0, 2, 0, 2) / det,
            -c(0, 1, 0, 2) / det,
        ],
        [
            c(1, 2, 0, 1) / det,
            -c(0, 2, 0, 1) / det,
            c(0, 1, 0, 1) / det,
        ],
    ])
}

/// Per unit: the matrix from the three sensors' spectra to the unit's axes, `R_u G^-1`.
fn sensor_to_unit(run: &PreparedRun, built: &Built) -> Result<[[[f64; 3]; 3]; 3]> {
    let rows = built.sensor_rows();
    let r: [[[f64; 3]; 3]; 3] = std::array::from_fn(|u| unit_matrix(&run.axes.units[u]));
    // G: sensor u reads c_u . (R_u v_body).
    let g: [[f64; 3]; 3] = std::array::from_fn(|u| {
        std::array::from_fn(|b| (0..3).map(|i| rows[u][i] * r[u][i][b]).sum())
    });
    let g_inv = inverse3(&g).ok_or_else(|| Error::Input {
        run: run.name.clone(),
        reason: format!("the sensors' responses {rows:?} do not span the body's axes"),
    })?;
    Ok(std::array::from_fn(|u| {
        std::array::from_fn(|i| {
            std::array::from_fn(|s| (0..3).map(|b| r[u][i][b] * g_inv[b][s]).sum())
        })
    }))
}

/// The linear part's coefficients `[m1, m2, k1]` of a passport.
fn lin_coefficients(p: &Passport) -> [f64; 3] {
    [p.m1, p.m2, p.k1]
}

/// `lin(a) = a0 + k1 a3 + m1 a1 + m2 a2`.
#[inline]
fn lin(p: &Passport, a: &[f64; 3]) -> f64 {
    p.a0_g + p.k1 * a[2] + p.m1 * a[0] + p.m2 * a[1]
}

/// Per reading, `lin(aL)` of each unit.
pub fn static_part(run: &PreparedRun) -> Vec<[f64; 3]> {
    run.a_l_unit_g
        .iter()
        .map(|a| std::array::from_fn(|u| lin(&run.passports[u], &a[u])))
        .collect()
}

/// Per unit and axis, the product of the path effects' transfers over the run's bins;
/// `None` where there is no path effect.
fn transfers(run: &PreparedRun, built: &Built, nb: usize) -> [Option<[Vec<Complex<f64>>; 3]>; 3] {
    let mut out: [Option<[Vec<Complex<f64>>; 3]>; 3] = [None, None, None];
    for u in 0..3 {
        // A unit whose transfers equal an earlier unit's at spread probe frequencies
        // (the same effects acting on both) shares its arrays.
        let probe = |v: usize| -> Vec<[Complex<f64>; 3]> {
            (1..9)
                .map(|q| {
                    let f = run.freq_hz(q * (nb.max(1) - 1) / 9);
                    let mut t = [Complex::new(1.0, 0.0); 3];
                    for (e, &p) in built.effects[v].iter().zip(&built.is_path[v]) {
                        if let (true, Some(h)) = (p, e.path_transfer(v, f)) {
                            for i in 0..3 {
                                t[i] *= h[i];
                            }
                        }
                    }
                    t
                })
                .collect()
        };
        let mine = probe(u);
        if let Some(v) = (0..u).find(|&v| out[v].is_some() && probe(v) == mine) {
            out[u] = out[v].clone();
            continue;
        }
        out[u] = unit_transfers(run, built, u, nb);
    }
    out
}

/// Unit `u`'s path transfers over the run's bins (`None`: no path effect).
fn unit_transfers(
    run: &PreparedRun,
    built: &Built,
    u: usize,
    nb: usize,
) -> Option<[Vec<Complex<f64>>; 3]> {
    {
        let list: Vec<&Box<dyn Effect>> = built.effects[u]
            .iter()
            .zip(&built.is_path[u])
            .filter(|(e, &p)| p && e.path_transfer(u, 1.0).is_some())
            .map(|(e, _)| e)
            .collect();
        if list.is_empty() {
            return None;
        }
        let mut t: [Vec<Complex<f64>>; 3] =
            std::array::from_fn(|_| vec![Complex::new(1.0, 0.0); nb]);
        for k in 0..nb {
            let f = run.freq_hz(k);
            for e in &list {
                if let Some(h) = e.path_transfer(u, f) {
                    for i in 0..3 {
                        t[i][k] *= h[i];
                    }
                }
            }
        }
        Some(t)
    }
}

/// `e^{j w dtau}` per bin.
fn delay_phase(run: &PreparedRun, delay_s: f64, nb: usize) -> Option<Vec<Complex<f64>>> {
    if run.delay_stated {
        return None;
    }
    let d = delay_s - run.delay0_s;
    if d == 0.0 {
        return None;
    }
    let step = 2.0 * PI * d / (run.n as f64 * run.dt_s);
    Some(
        (0..nb)
            .map(|k| Complex::from_polar(1.0, step * k as f64))
            .collect(),
    )
}

/// What every unit's axis sees, per bin: `X_ui[k]` for the bins `0..=n/2`.
struct UnitSpectra {
    map: [[[f64; 3]; 3]; 3],
    phase: Option<Vec<Complex<f64>>>,
    transfer: [Option<[Vec<Complex<f64>>; 3]>; 3],
}

impl UnitSpectra {
    /// For the bins `0..nb`.
    fn new(run: &PreparedRun, built: &Built, nb: usize) -> Result<Self> {
        let nb = nb.min(run.n / 2 + 1);
        Ok(Self {
            map: sensor_to_unit(run, built)?,
            phase: delay_phase(run, built.delay_s, nb),
            transfer: transfers(run, built, nb),
        })
    }

    #[inline]
    fn at(&self, run: &PreparedRun, u: usize, i: usize, k: usize) -> Complex<f64> {
        let m = &self.map[u][i];
        let mut x = run.sensors[0][k] * m[0] + run.sensors[1][k] * m[1] + run.sensors[2][k] * m[2];
        if let Some(p) = &self.phase {
            x *= p[k];
        }
        if let Some(t) = &self.transfer[u] {
            x *= t[i][k];
        }
        x
    }
}

/// Per reading, each unit's linear response to the vibration, `lin_vib`, g (exact:
/// module doc).
pub fn linear_part(run: &PreparedRun, built: &Built) -> Result<Vec<[f64; 3]>> {
    linear_part_in(run, built, None)
}

/// [`linear_part`] from the bins `band` alone (a multi-start's cheap objective: the
/// bins outside the vibration's band hold the sensors' noise, alike for every start).
pub fn linear_part_in(
    run: &PreparedRun,
    built: &Built,
    band: Option<(usize, usize)>,
) -> Result<Vec<[f64; 3]>> {
    let spectra = UnitSpectra::new(run, built, run.lin_bins)?;
    let (n, j) = (run.n, run.j);
    let nb = n / 2 + 1;
    let (k_lo, k_hi) = band.map_or((0, run.lin_bins), |(a, b)| (a, b.min(run.lin_bins)));
    let k_hi = k_hi.min(nb);
    // The boxcar depends on k mod J only: f P = k / J.
    let boxcar: Vec<Complex<f64>> = (0..j)
        .map(|r| {
            let x = 2.0 * PI * r as f64 / j as f64;
            if r == 0 {
                Complex::new(1.0, 0.0)
            } else {
                (Complex::new(1.0, 0.0) - Complex::from_polar(1.0, -x)) / Complex::new(0.0, x)
            }
        })
        .collect();
    let mut planner = RealFftPlanner::<f64>::new();
    let inv = planner.plan_fft_inverse(j);
    let mut out = vec![[0.0; 3]; j];
    for u in 0..3 {
        let c = lin_coefficients(&run.passports[u]);
        // Z_r = sum over all k = r (mod J) of Y_k, Y_k the boxcar-filtered spectrum
        // (Hermitian: Y_{N-k} = conj(Y_k)).
        let mut z = vec![Complex::new(0.0, 0.0); j / 2 + 1];
        for k in k_lo..k_hi {
            let mut y = Complex::new(0.0, 0.0);
            for i in 0..3 {
                if c[i] != 0.0 {
                    y += spectra.at(run, u, i, k) * c[i];
                }
            }
            let r = k % j;
            // The boxcar's value at the true frequency k (not at r): f P = k / J.
            let y = y * boxcar_at(k, j, &boxcar);
            if r <= j / 2 {
                z[r] += y;
            }
            // Its mirror -k = N - k (k not 0 nor N/2).
            if k != 0 && !(n % 2 == 0 && k == n / 2) {
                let rm = (n - k) % j;
                if rm <= j / 2 {
                    z[rm] += y.conj();
                }
            }
        }
        z[0].im = 0.0;
        if j % 2 == 0 {
            z[j / 2].im = 0.0;
        }
        let mut y = inv.make_output_vec();
        inv.process(&mut z, &mut y).map_err(|e| Error::Input {
            run: run.name.clone(),
            reason: format!("inverse FFT: {e}"),
        })?;
        // Reading r ends at grid point (r + 1) M: y[(r + 1) mod J].
        for r in 0..j {
            out[r][u] = y[(r + 1) % j] / n as f64;
        }
    }
    Ok(out)
}

/// The chi2 the sensors' own noise adds through the predicted linear response, expected
/// over the noise: `sum_u w_u n_u (2 / N^2) sum_k |B_k|^2 sum_s |a_us(k)|^2 p_s`, with
/// `a_us(k) = sum_i c_i T_ui(k) (R_u G^-1)_is` the path from sensor `s` to unit `u`'s
/// linear response, `p_s` the sensor's noise per bin, `n_u` the run's used readings and
/// `w_u` the weights. The regressors of the fit carry the sensors' noise (errors in
/// variables): least squares then prefers a path that passes less of it (a lower Q, a
/// shifted resonance), by about half a standard uncertainty on the generator's rigs.
/// [`crate::fit::fit`] removes that: its correction is the step that minimises
/// `chi2 - E(theta)` instead of `chi2`.
pub fn sensor_noise_chi2(run: &PreparedRun, built: &Built, w: [f64; 3]) -> Result<f64> {
    let p = run.noise_per_bin_g2;
    if p.iter().all(|&x| x <= 0.0) {
        return Ok(0.0);
    }
    let spectra = UnitSpectra::new(run, built, run.lin_bins)?;
    let (n, j) = (run.n, run.j);
    let kb = run.lin_bins.min(n / 2 + 1);
    let used = run.used.iter().filter(|&&u| u).count() as f64;
    let mut total = 0.0;
    for u in 0..3 {
        let c = lin_coefficients(&run.passports[u]);
        let mut sum = 0.0;
        for k in 1..kb {
            let x = 2.0 * PI * k as f64 / j as f64;
            let b2 = (2.0 - 2.0 * x.cos()) / (x * x);
            let mut pw = 0.0;
            for s in 0..3 {
                let mut a = Complex::new(0.0, 0.0);
                for i in 0..3 {
                    let mut t = Complex::new(spectra.map[u][i][s] * c[i], 0.0);
                    if let Some(tr) = &spectra.transfer[u] {
                        t *= tr[i][k];
                    }
                    a += t;
                }
                pw += a.norm_sqr() * p[s];
            }
            sum += b2 * pw;
        }
        total += w[u] * used * 2.0 / (n as f64 * n as f64) * sum;
    }
    Ok(total)
}

/// The bins of `lo_hz..hi_hz`.
pub fn bins(run: &PreparedRun, lo_hz: f64, hi_hz: f64) -> (usize, usize) {
    let df = 1.0 / (run.n as f64 * run.dt_s);
    let nb = run.n / 2 + 1;
    (
        ((lo_hz / df).floor().max(0.0) as usize).min(nb),
        ((hi_hz / df).ceil().max(0.0) as usize + 1).min(nb),
    )
}

/// The cross-correlation of `d` (per reading and unit, g: the readings less what the
/// model predicts besides its linear response, demeaned) with the linear response
/// predicted under `built`, for the sensors' delay changed by `q` grid spacings,
/// `q = 0..n` (negative changes wrap to the end), summed over units with weights `w`.
/// `chi2(delay) = const - 2 cc(q) + |prediction|^2`, the last nearly constant (it
/// changes only through the folding of the readings' rate): its peak is where the
/// delay's search starts.
pub fn delay_cross_correlation(
    run: &PreparedRun,
    built: &Built,
    d: &[[f64; 3]],
    w: [f64; 3],
) -> Result<(Vec<f64>, f64)> {
    let spectra = UnitSpectra::new(run, built, run.lin_bins)?;
    let (n, j) = (run.n, run.j);
    let nb = n / 2 + 1;
    let mut planner = RealFftPlanner::<f64>::new();
    let fwd_j = planner.plan_fft_forward(j);
    // The correlation is band-limited to the vibration's bins: evaluated on a grid of
    // `l` lags over the record (a spacing of the record over l), not of n.
    let kb = run.lin_bins.min(nb);
    let l = (2 * kb).next_power_of_two().clamp(64, n.max(64));
    let inv_l = planner.plan_fft_inverse(l);
    let fail = |e: realfft::FftError| Error::Input {
        run: run.name.clone(),
        reason: format!("FFT: {e}"),
    };
    let mut acc = vec![Complex::new(0.0, 0.0); l / 2 + 1];
    for u in 0..3 {
        let c = lin_coefficients(&run.passports[u]);
        let mut dj: Vec<f64> = d
            .iter()
            .map(|x| if x[u].is_finite() { x[u] } else { 0.0 })
            .collect();
        let mut dspec = fwd_j.make_output_vec();
        fwd_j.process(&mut dj, &mut dspec).map_err(fail)?;
        let d_at = |r: usize| -> Complex<f64> {
            // D_r for r in 0..J from the half spectrum.
            if r <= j / 2 {
                dspec[r]
            } else {
                dspec[j - r].conj()
            }
        };
        for k in 1..kb.min(l / 2) {
            let mut y = Complex::new(0.0, 0.0);
            for i in 0..3 {
                if c[i] != 0.0 {
                    y += spectra.at(run, u, i, k) * c[i];
                }
            }
            let x = 2.0 * PI * k as f64 / j as f64;
            let bx = (Complex::new(1.0, 0.0) - Complex::from_polar(1.0, -x)) / Complex::new(0.0, x);
            acc[k] += y * bx * Complex::from_polar(1.0, x) * d_at(k % j).conj() * w[u];
        }
    }
    acc[0] = Complex::new(0.0, 0.0);
    acc[l / 2] = Complex::new(0.0, 0.0);
    let mut out = inv_l.make_output_vec();
    inv_l.process(&mut acc, &mut out).map_err(fail)?;
    let lag_s = n as f64 * run.dt_s / l as f64;
    Ok((out.into_iter().map(|x| x / n as f64).collect(), lag_s))
}

/// The boxcar `(1 - e^{-j 2 pi k/J}) / (j 2 pi k / J)` at bin `k` (its numerator is
/// periodic in `k` with period `J`, its denominator is not).
#[inline]
fn boxcar_at(k: usize, j: usize, table: &[Complex<f64>]) -> Complex<f64> {
    if k == 0 {
        return Complex::new(1.0, 0.0);
    }
    let r = k % j;
    if r == 0 {
        return Complex::new(0.0, 0.0);
    }
    // table[r] = num / (j x_r), x_r = 2 pi r / J; at k: num / (j x_k).
    table[r] * (r as f64 / k as f64)
}

/// The vibration at each unit on the grid, per unit and axis.
pub struct Signals {
    v: [[Vec<f64>; 3]; 3],
}

/// A run's last grid signals and the key of the path they were made under (the path
/// effects' tables and the delay): a fit that moves output effects alone reuses them.
#[derive(Default)]
pub struct SignalsCache(std::sync::Mutex<Option<(String, std::sync::Arc<Signals>)>>);

impl Clone for SignalsCache {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl std::fmt::Debug for SignalsCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SignalsCache")
    }
}

/// The key of `built`'s path (its path effects' tables, the delay).
pub fn path_key(tables: &[toml::Table], built: &Built) -> String {
    let mut key = format!("{:e}", built.delay_s);
    for (t, &p) in tables.iter().zip(&built.is_path[0]) {
        if p {
            key.push('|');
            key.push_str(&t.to_string());
        }
    }
    key
}

/// The grid signals under `built`, from the run's cache when its path is the same.
pub fn signals_cached(
    run: &PreparedRun,
    tables: &[toml::Table],
    built: &Built,
) -> Result<std::sync::Arc<Signals>> {
    let key = path_key(tables, built);
    if let Ok(guard) = run.signals_cache.0.lock() {
        if let Some((k, s)) = guard.as_ref() {
            if *k == key {
                return Ok(s.clone());
            }
        }
    }
    let s = std::sync::Arc::new(signals(run, built)?);
    if let Ok(mut guard) = run.signals_cache.0.lock() {
        *guard = Some((key, s.clone()));
    }
    Ok(s)
}

/// The grid signals `v_u(t)` of every unit's axes.
pub fn signals(run: &PreparedRun, built: &Built) -> Result<Signals> {
    let spectra = UnitSpectra::new(run, built, run.n / 2 + 1)?;
    let n = run.n;
    let nb = n / 2 + 1;
    let mut planner = RealFftPlanner::<f64>::new();
    let inv = planner.plan_fft_inverse(n);
    let mut scratch = inv.make_scratch_vec();
    let fail = |e: realfft::FftError| Error::Input {
        run: run.name.clone(),
        reason: format!("inverse FFT: {e}"),
    };
    let mut v: [[Vec<f64>; 3]; 3] = Default::default();
    let mut spec = vec![Complex::new(0.0, 0.0); nb];
    // One transfer for every axis of every unit (none, or a mount on all axes): three
    // body-frame transforms, then each unit's axes by its rotation.
    let common = match &spectra.transfer[0] {
        None => spectra.transfer.iter().all(Option::is_none),
        Some(t0) => {
            t0[1] == t0[0]
                && t0[2] == t0[0]
                && spectra.transfer[1..].iter().all(|t| {
                    t.as_ref()
                        .is_some_and(|t| t[0] == t0[0] && t[1] == t0[0] && t[2] == t0[0])
                })
        }
    };
    if common {
        // Body axis b: sum over sensors of G^-1[b][s] S_s; R_u's rows are signed unit
        // vectors, so unit u's axis i is sign * body[index].
        let map0 = &spectra.map;
        let r: [[[f64; 3]; 3]; 3] = std::array::from_fn(|u| unit_matrix(&run.axes.units[u]));
        // G^-1 = R_0^T (R_0 G^-1) (R_0 orthogonal).
        let g_inv: [[f64; 3]; 3] = std::array::from_fn(|b| {
            std::array::from_fn(|s| (0..3).map(|i| r[0][i][b] * map0[0][i][s]).sum())
        });
        let mut body: [Vec<f64>; 3] = Default::default();
        for b in 0..3 {
            for (k, x) in spec.iter_mut().enumerate() {
                let mut y = run.sensors[0][k] * g_inv[b][0]
                    + run.sensors[1][k] * g_inv[b][1]
                    + run.sensors[2][k] * g_inv[b][2];
                if let Some(p) = &spectra.phase {
                    y *= p[k];
                }
                if let Some(t) = &spectra.transfer[0] {
                    y *= t[0][k];
                }
                *x = y / n as f64;
            }
            spec[0].im = 0.0;
            if n % 2 == 0 {
                spec[nb - 1].im = 0.0;
            }
            let mut out = inv.make_output_vec();
            inv.process_with_scratch(&mut spec, &mut out, &mut scratch)
                .map_err(fail)?;
            body[b] = out;
        }
        for u in 0..3 {
            for i in 0..3 {
                let (bi, sign) = r[u][i]
                    .iter()
                    .enumerate()
                    .find(|(_, x)| **x != 0.0)
                    .map_or((0, 0.0), |(b, x)| (b, *x));
                v[u][i] = body[bi].iter().map(|x| sign * x).collect();
            }
        }
        return Ok(Signals { v });
    }
    for u in 0..3 {
        for i in 0..3 {
            for (k, x) in spec.iter_mut().enumerate() {
                *x = spectra.at(run, u, i, k) / n as f64;
            }
            spec[0].im = 0.0;
            if n % 2 == 0 {
                spec[nb - 1].im = 0.0;
            }
            let mut out = inv.make_output_vec();
            inv.process_with_scratch(&mut spec, &mut out, &mut scratch)
                .map_err(fail)?;
            v[u][i] = out;
        }
    }
    Ok(Signals { v })
}

/// Per reading, each unit's `rest` (module doc), g: the grid pass of FP and the output
/// effects' hooks. `built`'s path effects are not run (the signals hold them).
pub fn rest_part(run: &PreparedRun, signals: &Signals, built: &mut Built) -> Vec<[f64; 3]> {
    let (m, j, n) = (run.m, run.j, run.n);
    let w = vibro_waveform::stage::gregory_weights(m);
    let rate_hz = 1.0 / run.dt_s;
    let mut out = vec![[f64::NAN; 3]; j];
    let mut input = vec![[0.0; 3]; m];
    let mut vib = vec![[0.0; 3]; m];
    let mut out_g = vec![0.0; m];
    let mut seen = vec![[0.0; 3]; m];
    let mut rest = vec![0.0; n];
    for u in 0..3 {
        let p = run.passports[u];
        for e in built.effects[u].iter_mut() {
            e.reset(rate_hz);
        }
        let v = &signals.v[u];
        for b in 0..j {
            let a_l = run.a_l_unit_g[b][u];
            let i0 = b * m;
            for k in 0..m {
                let s = [v[0][i0 + k], v[1][i0 + k], v[2][i0 + k]];
                vib[k] = s;
                input[k] = [a_l[0] + s[0], a_l[1] + s[1], a_l[2] + s[2]];
                out_g[k] = fp::output_g(&p, input[k][0], input[k][1], input[k][2]);
            }
            let ctx = BlockCtx {
                unit: u,
                t0_s: i0 as f64 * run.dt_s,
                dt_s: run.dt_s,
            };
            for (e, &path) in built.effects[u].iter_mut().zip(&built.is_path[u]) {
                if path {
                    continue;
                }
                // Observers of the input (heating's power) get a copy: a hook that is
                // not a path effect must not change the vibration.
                seen.copy_from_slice(&vib);
                e.at_unit_input(&ctx, &mut seen);
                e.at_unit_output(&ctx, &input, &mut out_g);
            }
            for k in 0..m {
                rest[i0 + k] = out_g[k] - lin(&p, &input[k]);
            }
        }
        for r in 0..j.saturating_sub(1) {
            let i0 = r * m;
            out[r][u] = (0..=m).map(|k| w[k] * rest[i0 + k]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_boxcar_at_its_bins() {
        let j = 8;
        let table: Vec<Complex<f64>> = (0..j)
            .map(|r| {
                let x = 2.0 * PI * r as f64 / j as f64;
                if r == 0 {
                    Complex::new(1.0, 0.0)
                } else {
                    (Complex::new(1.0, 0.0) - Complex::from_polar(1.0, -x)) / Complex::new(0.0, x)
                }
            })
            .collect();
        for k in 1..40usize {
            let x = 2.0 * PI * k as f64 / j as f64;
            let want =
                (Complex::new(1.0, 0.0) - Complex::from_polar(1.0, -x)) / Complex::new(0.0, x);
            assert!((boxcar_at(k, j, &table) - want).norm() < 1e-14, "{k}");
        }
    }

    #[test]
    fn the_inverse_of_a_rotation() {
        let a = [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];
        let b = inverse3(&a).unwrap();
        for i in 0..3 {
            for k in 0..3 {
                let x: f64 = (0..3).map(|l| a[i][l] * b[l][k]).sum();
                assert!((x - if i == k { 1.0 } else { 0.0 }).abs() < 1e-15);
            }
        }
    }
}
