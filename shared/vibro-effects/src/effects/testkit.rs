//! Test support: synthetic vibration records and the time-domain average of the hooks,
//! the independent check of every effect's mean formula.
//!
//! A record is tones with uniform random phases plus Gaussian random vibration
//! synthesised in the frequency domain (independent complex Gaussian amplitudes on
//! every FFT bin inside the PSD bands, correlated across axes by a constant coherence,
//! then an inverse FFT: exactly Gaussian, periodic over the record, with the band PSD
//! in expectation). Non-Gaussian vibration multiplies the record by `sqrt(w)` per
//! segment, with the high scale of [`ScaleMixture`] on exactly its share of segments
//! (stratified, so every record has the mixture's exact moments of `w`).
//!
//! The shift of an effect is `mean(FP + effect) - mean(FP)` over the same record
//! (common random numbers), averaged with the negated record (antithetic pair: odd
//! terms, whose mean is zero but whose noise is large, cancel). Independent records
//! give the spread, hence the standard error of the mean shift.

// Index loops mirror the formulas' subscripts (C_ij, L_ik) and read better here.
#![allow(clippy::needless_range_loop)]

use crate::effect::{BlockCtx, Effect, MeanContext};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use realfft::num_complex::Complex;
use realfft::RealFftPlanner;
use std::f64::consts::{PI, TAU};
use vibro_physics::abs_mean::ScaleMixture;
use vibro_physics::fp::output_g;
use vibro_physics::passport::{Passport, PassportSpec};
use vibro_physics::triad::UnitAxes;
use vibro_physics::vibration::{PsdBand, Tone, Vibration, MAX_TONES};

/// The AL-15 passport of MODEL.md section 5, written out here (not read from config).
pub(crate) fn al15_spec() -> PassportSpec {
    PassportSpec {
        id: "AL-15".into(),
        a0_g: 3.324e-3,
        k1: 1.0,
        k1_v_per_g: -1.6698,
        d1a_ppm: 15.0,
        k2_ppm_per_g: 105.0,
        k3_ppm_per_g2: 87.0,
        k4_ppm_per_g3: 10.0,
        k5_ppm_per_g4: 0.9,
        m1_ppm: 1150.0,
        m2_ppm: 1150.0,
        m31_ppm_per_g: 11.6,
        m32_ppm_per_g: 11.6,
        lambda: vec![],
    }
}

pub(crate) fn passport(spec: &PassportSpec) -> Passport {
    Passport::try_from_spec(spec).expect("test passport is valid")
}

pub(crate) fn al15() -> Passport {
    passport(&al15_spec())
}

/// A tone with phases in degrees.
pub(crate) fn tone(freq_hz: f64, amplitude_g: [f64; 3], phase_deg: [f64; 3]) -> Tone {
    Tone {
        freq_hz,
        amplitude_g,
        phase_rad: phase_deg.map(f64::to_radians),
    }
}

/// A band with the same PSD shape on all axes, scaled per axis.
pub(crate) fn band(f_lo_hz: f64, f_hi_hz: f64, psd_g2_per_hz: [f64; 3]) -> PsdBand {
    PsdBand {
        f_lo_hz,
        f_hi_hz,
        psd_g2_per_hz,
    }
}

/// A synthetic test scene in one frame (unit axes, or body axes for body-frame effects).
#[derive(Debug, Clone)]
pub(crate) struct Scene {
    pub rate_hz: f64,
    /// Samples averaged per record (a power of two: the random part's FFT length).
    pub n: usize,
    /// Samples run through the hooks before averaging (filter warm-up).
    pub pre_roll: usize,
    /// Samples per hook call (not a divisor of `n`, to exercise block continuity).
    pub block: usize,
    /// Independent records.
    pub reps: usize,
    pub a_l_g: [f64; 3],
    pub tones: Vec<Tone>,
    pub bands: Vec<PsdBand>,
    /// Coherence between axes (symmetric, unit diagonal, positive definite).
    pub coherence: [[f64; 3]; 3],
    pub kurtosis: f64,
}

/// A mean shift measured in the time domain.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Estimate {
    pub mean_g: f64,
    pub se_g: f64,
}

impl Scene {
    pub fn new(rate_hz: f64, n: usize) -> Self {
        Self {
            rate_hz,
            n,
            pre_roll: 0,
            block: 1000,
            reps: 24,
            a_l_g: [0.0; 3],
            tones: Vec::new(),
            bands: Vec::new(),
            coherence: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            kurtosis: 3.0,
        }
    }

    pub fn duration_s(&self) -> f64 {
        self.n as f64 / self.rate_hz
    }

    /// `C_ij = rho_ij int sqrt(S_i S_j) df`.
    pub fn covariance(&self) -> [[f64; 3]; 3] {
        let mut c = [[0.0; 3]; 3];
        for b in &self.bands {
            let df = b.f_hi_hz - b.f_lo_hz;
            for i in 0..3 {
                for j in 0..3 {
                    c[i][j] += self.coherence[i][j]
                        * (b.psd_g2_per_hz[i] * b.psd_g2_per_hz[j]).sqrt()
                        * df;
                }
            }
        }
        c
    }

    /// The scene as a vibration description.
    pub fn vibration(&self) -> Vibration {
        let mut v = Vibration::none();
        for t in &self.tones {
            v.push_tone(*t).expect("at most MAX_TONES tones");
        }
        v.covariance_g2 = self.covariance();
        v.kurtosis = [self.kurtosis; 3];
        v
    }

    pub fn ctx<'a>(&'a self, unit: usize, p: &'a Passport, vib: &'a Vibration) -> MeanContext<'a> {
        MeanContext {
            unit,
            passport: p,
            a_l_unit_g: self.a_l_g,
            vibration_unit: vib,
            psd_unit: &self.bands,
            internal_rate_hz: self.rate_hz,
            duration_s: self.duration_s(),
        }
    }

    /// `pre_roll + n` samples of the tones and kurtosis (IA's) of `desc` plus the
    /// scene's random part. `seed` fixes the tone phases, the noise and the burst
    /// segments, so two descriptions with one seed give common random numbers.
    pub fn synth(&self, desc: &Vibration, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let thetas: Vec<f64> = (0..MAX_TONES).map(|_| rng.random::<f64>() * TAU).collect();
        let n = self.n;
        let random = self.random_record(&mut rng);
        // Burst segments: the mixture's high scale on exactly its share of segments.
        let n_seg = 20;
        let mut order: Vec<usize> = (0..n_seg).collect();
        for i in (1..n_seg).rev() {
            let j = rng.random_range(0..=i);
            order.swap(i, j);
        }
        let mixture = ScaleMixture::for_kurtosis(desc.kurtosis[2]);
        let n_high = (mixture.prob[1] * n_seg as f64).round() as usize;
        let mut scale = vec![mixture.scale[0].sqrt(); n_seg];
        for &s in &order[..n_high] {
            scale[s] = mixture.scale[1].sqrt();
        }
        if mixture.is_gaussian() {
            scale.fill(1.0);
        }
        let total = self.pre_roll + n;
        let mut out = vec![[0.0; 3]; total];
        for (k, o) in out.iter_mut().enumerate() {
            let t_index = k as isize - self.pre_roll as isize;
            let t = t_index as f64 / self.rate_hz;
            let idx = t_index.rem_euclid(n as isize) as usize;
            let w = scale[idx * n_seg / n];
            for i in 0..3 {
                let mut v = w * random[i][idx];
                for (tn, th) in desc.tones().iter().zip(&thetas) {
                    v += tn.amplitude_g[i] * (TAU * tn.freq_hz * t + th + tn.phase_rad[i]).sin();
                }
                o[i] = v;
            }
        }
        out
    }

    /// The Gaussian random part, one periodic record per axis.
    fn random_record(&self, rng: &mut ChaCha8Rng) -> [Vec<f64>; 3] {
        let n = self.n;
        let mut out = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        if self.bands.is_empty() {
            return out;
        }
        let l = cholesky3(&self.coherence);
        let df = self.rate_hz / n as f64;
        let mut planner = RealFftPlanner::<f64>::new();
        let inverse = planner.plan_fft_inverse(n);
        let mut spectra: Vec<Vec<Complex<f64>>> =
            (0..3).map(|_| inverse.make_input_vec()).collect();
        for k in 1..n / 2 {
            let f = k as f64 * df;
            let Some(b) = self.bands.iter().find(|b| f >= b.f_lo_hz && f < b.f_hi_hz) else {
                continue;
            };
            let z: [Complex<f64>; 3] = std::array::from_fn(|_| {
                Complex::new(rng.sample(StandardNormal), rng.sample(StandardNormal))
            });
            for i in 0..3 {
                let y = l[i][0] * z[0] + l[i][1] * z[1] + l[i][2] * z[2];
                // x[t] = sum_k 2 Re(X_k e^{i 2 pi k t/n}); X_k = sqrt(S df)/2 (a - i b)
                // gives a_k cos + b_k sin with a, b ~ N(0, S df): variance S df per bin.
                spectra[i][k] = 0.5 * (b.psd_g2_per_hz[i] * df).sqrt() * y.conj();
            }
        }
        for (spectrum, o) in spectra.iter_mut().zip(out.iter_mut()) {
            inverse
                .process(spectrum, o)
                .expect("FFT lengths match the plan");
        }
        out
    }
}

fn cholesky3(c: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut l = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let mut s = c[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                l[i][i] = s.max(0.0).sqrt();
            } else if l[j][j] > 0.0 {
                l[i][j] = s / l[j][j];
            }
        }
    }
    l
}

/// The negated record (antithetic partner).
pub(crate) fn negated(v: &[[f64; 3]]) -> Vec<[f64; 3]> {
    v.iter().map(|s| s.map(|x| -x)).collect()
}

/// Mean output of `unit` over the last `scene.n` samples of `vib` (vibration in unit
/// axes): FP of `aL + vib`, through `effect`'s unit hooks when given (reset first).
pub(crate) fn mean_output(
    scene: &Scene,
    p: &Passport,
    unit: usize,
    vib: &[[f64; 3]],
    mut effect: Option<&mut dyn Effect>,
) -> f64 {
    if let Some(e) = effect.as_deref_mut() {
        e.reset(scene.rate_hz);
    }
    let a_l = scene.a_l_g;
    let mut sum = 0.0;
    let mut buf = Vec::with_capacity(scene.block);
    let mut total = Vec::with_capacity(scene.block);
    let mut out = Vec::with_capacity(scene.block);
    for (b, chunk) in vib.chunks(scene.block).enumerate() {
        let start = b * scene.block;
        let ctx = BlockCtx {
            unit,
            t0_s: (start as f64 - scene.pre_roll as f64) / scene.rate_hz,
            dt_s: 1.0 / scene.rate_hz,
        };
        buf.clear();
        buf.extend_from_slice(chunk);
        if let Some(e) = effect.as_deref_mut() {
            e.at_unit_input(&ctx, &mut buf);
        }
        total.clear();
        total.extend(
            buf.iter()
                .map(|v| [a_l[0] + v[0], a_l[1] + v[1], a_l[2] + v[2]]),
        );
        out.clear();
        out.extend(total.iter().map(|a| output_g(p, a[0], a[1], a[2])));
        if let Some(e) = effect.as_deref_mut() {
            e.at_unit_output(&ctx, &total, &mut out);
        }
        for (k, o) in out.iter().enumerate() {
            if start + k >= scene.pre_roll {
                sum += o;
            }
        }
    }
    sum / scene.n as f64
}

/// Mean and standard error of `one(seed)` over `reps` independent seeds.
pub(crate) fn estimate(reps: usize, seed0: u64, mut one: impl FnMut(u64) -> f64) -> Estimate {
    let values: Vec<f64> = (0..reps as u64).map(|r| one(seed0 + r)).collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    Estimate {
        mean_g: mean,
        se_g: (var / n).sqrt(),
    }
}

/// The time-domain mean shift of a unit-frame effect on `unit`: common random numbers
/// (same record with the effect on and off) and antithetic pairs.
pub(crate) fn unit_shift(
    scene: &Scene,
    p: &Passport,
    unit: usize,
    effect: &mut dyn Effect,
    seed0: u64,
) -> Estimate {
    let desc = scene.vibration();
    estimate(scene.reps, seed0, |seed| {
        let v = scene.synth(&desc, seed);
        let w = negated(&v);
        let off = mean_output(scene, p, unit, &v, None) + mean_output(scene, p, unit, &w, None);
        let on = mean_output(scene, p, unit, &v, Some(&mut *effect))
            + mean_output(scene, p, unit, &w, Some(&mut *effect));
        0.5 * (on - off)
    })
}

/// A body-frame description in one unit's axes `[OA, PA, IA]`: a negative axis adds
/// pi to the tone phases and flips the covariances' signs.
pub(crate) fn body_to_unit(body: &Vibration, axes: &UnitAxes) -> Vibration {
    let map = [axes.oa, axes.pa, axes.ia];
    let mut v = Vibration::none();
    for t in body.tones() {
        let mut u = *t;
        for (j, ax) in map.iter().enumerate() {
            u.amplitude_g[j] = t.amplitude_g[ax.body_index];
            u.phase_rad[j] = t.phase_rad[ax.body_index] + if ax.sign < 0 { PI } else { 0.0 };
        }
        v.push_tone(u).expect("same number of tones");
    }
    for (j, a) in map.iter().enumerate() {
        for (l, b) in map.iter().enumerate() {
            v.covariance_g2[j][l] =
                f64::from(a.sign * b.sign) * body.covariance_g2[a.body_index][b.body_index];
        }
        v.kurtosis[j] = body.kurtosis[a.body_index];
    }
    v
}

/// Body-frame PSD bands in one unit's axes.
pub(crate) fn bands_to_unit(bands: &[PsdBand], axes: &UnitAxes) -> Vec<PsdBand> {
    let map = [axes.oa, axes.pa, axes.ia];
    bands
        .iter()
        .map(|b| PsdBand {
            psd_g2_per_hz: std::array::from_fn(|j| b.psd_g2_per_hz[map[j].body_index]),
            ..*b
        })
        .collect()
}

/// The time-domain mean shift of a body-frame effect on `unit`: records drawn from
/// the body description with and without `adjust_body_vibration` (one seed each, so
/// common random numbers), projected on the unit's axes.
pub(crate) fn body_shift(
    scene: &Scene,
    p: &Passport,
    axes: &UnitAxes,
    unit: usize,
    effect: &dyn Effect,
    seed0: u64,
) -> Estimate {
    let desc = scene.vibration();
    let mut adjusted = desc;
    effect.adjust_body_vibration(&mut adjusted);
    let to_unit =
        |v: Vec<[f64; 3]>| -> Vec<[f64; 3]> { v.iter().map(|s| axes.to_unit(s)).collect() };
    estimate(scene.reps, seed0, |seed| {
        let off = to_unit(scene.synth(&desc, seed));
        let on = to_unit(scene.synth(&adjusted, seed));
        let mean = |v: &[[f64; 3]]| {
            mean_output(scene, p, unit, v, None) + mean_output(scene, p, unit, &negated(v), None)
        };
        0.5 * (mean(&on) - mean(&off))
    })
}

/// Asserts that the time-domain estimate agrees with the formula (`|z| < 4`) and that
/// the effect is at least `power` standard errors large (the test could fail).
pub(crate) fn assert_agrees(name: &str, est: Estimate, formula_g: f64, power: f64) -> f64 {
    let z = (est.mean_g - formula_g) / est.se_g;
    eprintln!(
        "{name}: formula {formula_g:.6e} g, time domain {:.6e} +- {:.2e} g, z = {z:.2}",
        est.mean_g, est.se_g
    );
    assert!(
        z.abs() < 4.0,
        "{name}: formula {formula_g:.6e} g vs time domain {:.6e} +- {:.2e} g (z = {z:.2})",
        est.mean_g,
        est.se_g
    );
    assert!(
        formula_g.abs() > power * est.se_g,
        "{name}: effect {formula_g:.3e} g is not {power} standard errors ({:.2e} g) large",
        est.se_g
    );
    z
}

/// The standard triad with `p` on every unit.
pub(crate) fn rig_with(p: &Passport) -> super::Rig {
    super::Rig {
        triad: vibro_physics::triad::TriadAxes::standard(),
        passports: Some([*p; 3]),
    }
}

/// Builds an effect from the body of an `[[effect]]` table, for a rig of `p` units.
pub(crate) fn build_toml(text: &str, p: &Passport) -> Box<dyn Effect> {
    let spec: super::EffectSpec = toml::from_str(text).expect("valid TOML");
    super::build_for_rig(&spec, &rig_with(p)).expect("valid effect")
}

/// The error message of building `text`.
pub(crate) fn build_error(text: &str) -> String {
    let spec: super::EffectSpec = toml::from_str(text).expect("valid TOML");
    match super::build_for_rig(&spec, &rig_with(&al15())) {
        Ok(e) => panic!("{} built from invalid parameters", e.kind()),
        Err(e) => e.to_string(),
    }
}
