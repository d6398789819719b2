//! Shake-table campaigns: every condition simulated still / vibrating / still and
//! measured as on the rig (MODEL.md section 8, [P2 (16)]), next to the exact and the
//! published prediction.
//!
//! Per condition:
//!
//! - the unit under test's output records `U1`, `U2`, `U3` (V, one sample per output
//!   interval) give `dV = (<U2> - 0.5 (<U1> + <U3>))/K1` with its batch-means standard
//!   uncertainty and the still-drift (tilt) check, by `vibro_ident::measure_ve_from_samples`;
//! - the simulated vibration sensor of the unit (along IA) gives the measured vibration
//!   during `U2`: the tone amplitude by least squares at the known frequency (divided
//!   by the AC coupling's gain there), the RMS, the broadband RMS with the tone removed
//!   (`sqrt(rms^2 - A^2/2)`) and, without a tone, the kurtosis; the amplitude and the
//!   broadband RMS carry their standard uncertainties by batch means (below);
//! - the exact VE (MODEL.md section 6, `vibro_physics::exact`) and the published one
//!   (section 5) of the condition's vibration at its gravity projection.
//!
//! The vibration is switched on and off abruptly at the record boundaries. The linear
//! term of (FP) then leaves, in each batch mean, the partial cycle of the tone (and the
//! band-limited random part's end effects): these telescope over the record, so the
//! batch-means uncertainty over-states the error of the record mean of such a term;
//! it is exact for the rectified part. A tone that completes a whole number of cycles
//! per batch leaves nothing (`f * vibrating_s / batches` whole).
//!
//! **The measured vibration's uncertainty.** A VE is compared with a model evaluated at
//! the vibration the sensor measured, so the sensor's error enters the comparison as
//! much as the output's. The sensor record is cut into [`sensor_batches`] contiguous
//! batches; in each, `x = d + e t + i cos(2 pi f t) + q sin(2 pi f t)` is fitted by
//! least squares. The line `d + e t` takes up the AC coupling's slow transient after
//! the switch-on (`fc/f` of the amplitude, decaying over `1/(2 pi fc)`), which a plain
//! lock-in over the record leaks into the amplitude (8e-6 of it at 20 Hz for
//! `fc = 0.1 Hz` over 5 s) and a fit with a constant alone still does through the
//! transient's slope (2e-6 at 40 Hz). The amplitude is
//! `|(<i>, <q>)|`, its standard uncertainty the batch-means standard error of the
//! batches' `(i, q)` projected on that direction; the broadband variance's is the
//! batch-means standard error of the batches' residual variances (halved over `sigma`
//! for `sigma`'s). With the white sensor noise `s_n` of N samples the amplitude's is
//! `s_n sqrt(2/N)` (4e-6 g for 1e-3 g over 5 s at 25.6 kHz).

use crate::engine::{scenario_effects, Simulator};
use crate::scenario::{Condition, Scenario};
use crate::sensor::ac_coupling_response;
use crate::{Error, Result};
use std::f64::consts::TAU;
use std::io::Write;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;
use vibro_effects::Effect;
use vibro_ident::{measure_ve_from_samples, MeasureOptions, VeMeasurement};
use vibro_physics::ve::{published, Constants};
use vibro_physics::vibration::Vibration;

/// The numerical resolution of a simulated mean VE, g: z-values use
/// `sqrt(sigma^2 + Z_FLOOR_G^2)`, so that a run without statistical noise (a pure tone
/// over whole cycles) is compared at the precision of double sums and the exact
/// model's tables rather than at zero.
pub const Z_FLOOR_G: f64 = 1e-9;

/// Smallest `u_sigma_v` written to a positions CSV, V (the reader needs > 0).
pub const U_SIGMA_FLOOR_V: f64 = 1e-12;

/// Options of [`run_campaign`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CampaignOptions {
    /// Conditions simulated in parallel (each on its own thread); results do not
    /// depend on it.
    pub threads: usize,
}

impl Default for CampaignOptions {
    fn default() -> Self {
        Self { threads: 1 }
    }
}

/// The vibration measured by the unit's simulated vibration sensor (along IA) during
/// the vibrating record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredVibration {
    /// Tone amplitude along IA by lock-in at the condition's frequency, corrected for
    /// the AC coupling, g; `None` without a tone.
    pub tone_amplitude3_g: Option<f64>,
    /// RMS of the sensor signal, g.
    pub rms3_g: f64,
    /// RMS with the tone removed, `sqrt(max(0, rms^2 - A^2/2))`, g.
    pub sigma3_g: f64,
    /// Kurtosis `m4/m2^2` of the sensor signal; `None` when a tone is present.
    pub kurtosis3: Option<f64>,
    /// Standard uncertainty of `tone_amplitude3_g` by batch means (module docs), g;
    /// `None` without a tone.
    pub tone_amplitude3_u_g: Option<f64>,
    /// Standard uncertainty of `sigma3_g` by batch means (module docs), g; 0 when
    /// `sigma3_g` is 0.
    pub sigma3_u_g: f64,
    /// Batches of the sensor record the two uncertainties come from.
    pub n_batches: usize,
    /// ADC samples clipped in the whole run.
    pub clipped_samples: u64,
    /// Sensor samples in the vibrating record.
    pub n_samples: u64,
}

/// One effect's predicted change of the measured VE (from its documented mean
/// contribution, not from the simulation).
#[derive(Debug, Clone, PartialEq)]
pub struct EffectShift {
    pub kind: String,
    /// `mean_shift_g` under the condition's vibration (over the vibrating record)
    /// minus `mean_shift_g` without vibration (the static part the still records
    /// remove), g; the effect's error message when it has no formula for this case.
    pub ve_shift_g: std::result::Result<f64, String>,
}

/// The result of one condition.
#[derive(Debug, Clone)]
pub struct ConditionSummary {
    /// The condition as expanded from the scenario.
    pub condition: Condition,
    /// Identifier of the passport of the unit under test.
    pub passport_id: String,
    pub k1_v_per_g: f64,
    /// The vibration at the unit in its axes `[OA, PA, IA]` (realised random
    /// covariance), which the predictions use.
    pub vibration_unit: Vibration,
    /// The section-8 measurement, with its tilt check evaluated separately.
    pub measurement: VeMeasurement,
    /// Whether `|<U1> - <U3>|/|K1| <= tilt_limit_rad` (MODEL.md section 8).
    pub drift_accepted: bool,
    pub tilt_limit_rad: f64,
    /// Exact VE (MODEL.md section 6) at the condition's gravity, g.
    pub exact_ve_g: f64,
    /// VE as published (section 5, misprint fixed), g.
    pub published_ve_g: f64,
    /// `(measured - exact)/sqrt(sigma^2 + Z_FLOOR_G^2)`.
    pub z_exact: f64,
    /// The effects of the run, each with its predicted VE change.
    pub effect_shifts: Vec<EffectShift>,
    /// `exact_ve_g` plus every effect's VE shift; `None` when an effect has none.
    pub predicted_ve_g: Option<f64>,
    /// `(measured - predicted)/sqrt(sigma^2 + Z_FLOOR_G^2)`.
    pub z_predicted: Option<f64>,
    pub sensor: MeasuredVibration,
}

impl ConditionSummary {
    /// `sigma_i` of the random part at the unit per axis `[OA, PA, IA]`, g.
    pub fn sigma_unit_g(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| self.vibration_unit.sigma_g(i))
    }
}

/// Moment sums of the sensor signal during the vibrating record.
#[derive(Debug, Default)]
struct SensorSums {
    n: u64,
    s1: f64,
    s2: f64,
    s3: f64,
    s4: f64,
}

/// Most batches of the sensor record: its noise is white or, for random vibration,
/// correlated over a few periods of the band's lowest frequency, so batches of a tenth
/// of a second are independent; 40 of them give the uncertainty to
/// `1/sqrt(2*39) = 11 %` (the unit output's few batches would give 25 % with 9, and a
/// chi-square over rows weighted by an uncertainty from `nu` degrees of freedom is
/// inflated by `nu/(nu - 2)`: 1.05 with 39, 1.29 with 8).
pub const MAX_SENSOR_BATCHES: usize = 40;

/// Batches of the sensor record ([`MAX_SENSOR_BATCHES`], at least the output record's
/// `batches`), fewer when a batch would hold less than two periods of the tone or
/// fewer than 64 samples: the fit of a tone over a shorter batch is ill-conditioned.
pub fn sensor_batches(
    output_batches: usize,
    tone_hz: Option<f64>,
    vibrating_s: f64,
    n_samples: u64,
) -> usize {
    let by_samples = (n_samples / 64) as usize;
    let by_cycles = tone_hz.map_or(usize::MAX, |f| (f * vibrating_s / 2.0).floor() as usize);
    MAX_SENSOR_BATCHES
        .min(by_cycles)
        .max(output_batches)
        .min(by_samples)
        .max(2)
}

/// Least-squares sums of one batch of the sensor record: `x` against the regressors
/// `[1, t, cos, sin]` (`t` the time within the batch, 0..1; without a tone `[1, t]`).
#[derive(Debug, Default, Clone, Copy)]
struct BatchSums {
    /// Normal matrix (upper triangle used).
    a: [[f64; 4]; 4],
    /// Right-hand side.
    b: [f64; 4],
    xx: f64,
    n: f64,
}

impl BatchSums {
    fn add(&mut self, x: f64, t: f64, cs: Option<(f64, f64)>) {
        let (c, s) = cs.unwrap_or((0.0, 0.0));
        let r = [1.0, t, c, s];
        for i in 0..4 {
            for j in i..4 {
                self.a[i][j] += r[i] * r[j];
            }
            self.b[i] += r[i] * x;
        }
        self.xx += x * x;
        self.n += 1.0;
    }

    /// `(i, q, residual variance)` of the fit `x = d + e t + i cos + q sin` (without a
    /// tone `x = d + e t`, `i = q = 0`); `None` for a singular batch.
    fn fit(&self, tone: bool) -> Option<(f64, f64, f64)> {
        let k = if tone { 4 } else { 2 };
        if self.n < 2.0 * k as f64 {
            return None;
        }
        // The k x k normal equations, solved by LU with partial pivoting; a batch
        // whose design is singular (a pivot below 1e-12 of the largest diagonal) is
        // left out.
        let a = nalgebra::DMatrix::from_fn(
            k,
            k,
            |i, j| {
                if j >= i {
                    self.a[i][j]
                } else {
                    self.a[j][i]
                }
            },
        );
        let scale = (0..k).map(|i| a[(i, i)]).fold(0.0, f64::max);
        let lu = a.lu();
        if (0..k).any(|i| lu.u()[(i, i)].abs() <= 1e-12 * scale || lu.u()[(i, i)].is_nan()) {
            return None;
        }
        let rhs = nalgebra::DVector::from_fn(k, |i, _| self.b[i]);
        let x = lu.solve(&rhs)?;
        let mut sol = [0.0; 4];
        for i in 0..k {
            sol[i] = x[i];
        }
        let explained: f64 = (0..k).map(|i| sol[i] * self.b[i]).sum();
        let variance = ((self.xx - explained) / self.n).max(0.0);
        Some((sol[2], sol[3], variance))
    }
}

/// Mean and batch-means standard error of `values` (sample std over `sqrt(n)`).
fn batch_mean_se(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    if values.len() < 2 {
        return (mean, 0.0);
    }
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Runs every condition of a campaign scenario, with the scenario's own effects, and
/// calls `on_condition` (on the calling thread) as each finishes, in any order; the
/// result is in condition order.
pub fn run_campaign(
    scenario: &Scenario,
    options: &CampaignOptions,
    on_condition: &mut dyn FnMut(&ConditionSummary),
) -> Result<Vec<ConditionSummary>> {
    let Some(campaign) = scenario.campaign() else {
        return Err(Error::Unsupported {
            what: format!("scenario {:?}", scenario.name),
            reason: "is a flight, not a campaign: run it with Simulator".into(),
        });
    };
    let n = campaign.conditions.len();
    let threads = options.threads.clamp(1, n.max(1));
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let (tx, rx) = mpsc::channel::<(usize, Result<ConditionSummary>)>();
    let mut results: Vec<Option<ConditionSummary>> = vec![None; n];
    let mut first_error = None;
    std::thread::scope(|s| {
        for _ in 0..threads {
            let tx = tx.clone();
            let (next, stop) = (&next, &stop);
            s.spawn(move || loop {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n {
                    break;
                }
                let r = scenario_effects(scenario).and_then(|e| run_condition(scenario, i, e));
                if tx.send((i, r)).is_err() {
                    break;
                }
            });
        }
        drop(tx);
        for (i, r) in rx {
            match r {
                Ok(summary) => {
                    on_condition(&summary);
                    results[i] = Some(summary);
                }
                Err(e) => {
                    stop.store(true, Ordering::Relaxed);
                    first_error.get_or_insert(e);
                }
            }
        }
    });
    if let Some(e) = first_error {
        return Err(e);
    }
    Ok(results.into_iter().flatten().collect())
}

/// A condition's summary with the unit's output records (V, one sample per output
/// interval), e.g. to difference an effect-on run against an effect-off run sample by
/// sample (common random numbers).
#[derive(Debug, Clone)]
pub struct ConditionRun {
    pub summary: ConditionSummary,
    pub still1_v: Vec<f64>,
    pub vib_v: Vec<f64>,
    pub still2_v: Vec<f64>,
}

/// Simulates and measures condition `index` of a campaign with the given effects.
pub fn run_condition(
    scenario: &Scenario,
    index: usize,
    effects: Vec<Box<dyn Effect>>,
) -> Result<ConditionSummary> {
    run_condition_records(scenario, index, effects).map(|r| r.summary)
}

/// [`run_condition`], keeping the output records.
pub fn run_condition_records(
    scenario: &Scenario,
    index: usize,
    effects: Vec<Box<dyn Effect>>,
) -> Result<ConditionRun> {
    let mut sim = Simulator::for_condition(scenario, index, effects)?;
    let campaign = scenario.campaign().ok_or_else(|| Error::Unsupported {
        what: format!("scenario {:?}", scenario.name),
        reason: "is not a campaign".into(),
    })?;
    let c = &campaign.conditions[index];
    let rates = scenario.rates;
    let still = (campaign.still_s * rates.output_hz).round() as u64;
    let vib = (campaign.vibrating_s * rates.output_hz).round() as u64;
    let settle = (campaign.settle_s * rates.output_hz).round() as u64;
    let mut records: [Vec<f64>; 3] = [
        Vec::with_capacity(still as usize),
        Vec::with_capacity(vib as usize),
        Vec::with_capacity(still as usize),
    ];
    let d = rates.output_decimation() as u64;
    let m = rates.sensor_decimation() as u64;
    let (vib_on, vib_off) = (still * d, (still + vib) * d);
    let tone_hz = c.tone.map(|t| t.freq_hz);
    let inv_sens = 1.0 / scenario.sensor.sensitivity_v_per_g;
    let mut sums = SensorSums::default();
    // Sensor samples `s` with `s * m` in `[vib_on, vib_off)`.
    let (sensor_first, sensor_end) = (vib_on.div_ceil(m), vib_off.div_ceil(m));
    let n_sensor = sensor_end.saturating_sub(sensor_first);
    let n_sensor_batches =
        sensor_batches(campaign.batches, tone_hz, campaign.vibrating_s, n_sensor);
    let mut batches = vec![BatchSums::default(); n_sensor_batches];
    sim.set_chunk_output_samples(((0.5 * rates.output_hz).round() as usize).max(1))?;
    sim.run(|chunk| {
        for (k, row) in chunk.accel_v().iter().enumerate() {
            let j = chunk.output_first_index() + k as u64;
            let r = if j < still {
                0
            } else if j < still + vib {
                1
            } else {
                2
            };
            // The settling time after each switch is left out (campaign.settle_s).
            let settling = (r == 1 && j < still + settle) || (r == 2 && j < still + vib + settle);
            if !settling {
                records[r].push(row[0]);
            }
        }
        for (k, row) in chunk.sensor_v().iter().enumerate() {
            let s = chunk.sensor_first_index() + k as u64;
            let internal = s * m;
            if internal < vib_on || internal >= vib_off {
                continue;
            }
            let x = row[0] * inv_sens;
            let x2 = x * x;
            sums.n += 1;
            sums.s1 += x;
            sums.s2 += x2;
            sums.s3 += x2 * x;
            sums.s4 += x2 * x2;
            let cs = tone_hz.map(|f| {
                let cycles = f * (s as f64 / rates.sensor_hz);
                let (sin, cos) = (TAU * cycles.fract()).sin_cos();
                (cos, sin)
            });
            let rel = (s - sensor_first) as usize;
            let b = ((rel * n_sensor_batches) / n_sensor.max(1) as usize).min(n_sensor_batches - 1);
            // Batch b holds samples [b n / nb, (b + 1) n / nb) of the record.
            let start = b * n_sensor as usize / n_sensor_batches;
            let end = (b + 1) * n_sensor as usize / n_sensor_batches;
            let t = (rel - start) as f64 / (end - start).max(1) as f64;
            batches[b].add(x, t, cs);
        }
        ControlFlow::Continue(())
    })?;
    let k1 = campaign.passport.k1_v_per_g;
    let measurement = measure_ve_from_samples(
        &records[0],
        &records[1],
        &records[2],
        k1,
        &MeasureOptions {
            n_batches: campaign.batches,
            // The tilt check is reported, not enforced, so a rejected run still has a row.
            tilt_limit_rad: f64::MAX,
        },
    )
    .map_err(|source| Error::Measurement {
        condition: c.id.clone(),
        source,
    })?;
    let (_, exact_ve_g) =
        sim.exact_mean_and_ve_g(0, c.a_l_unit_g)
            .ok_or_else(|| Error::Unsupported {
                what: c.id.clone(),
                reason: "the simulator has no unit under test".into(),
            })?;
    let vibration_unit = *sim.unit_vibration(0).ok_or_else(|| Error::Unsupported {
        what: c.id.clone(),
        reason: "the simulator has no unit under test".into(),
    })?;
    let flat = crate::engine::passport_without_lambda(&campaign.passport)?;
    let published_ve_g = published(&flat, c.a_l_unit_g, &vibration_unit, Constants::PAPER).total_g;
    let sigma = measurement.ve_sigma_g.hypot(Z_FLOOR_G);
    let z_exact = (measurement.ve_g - exact_ve_g) / sigma;
    let on = sim.effect_mean_shifts_g(0, c.a_l_unit_g, true, campaign.vibrating_s);
    let off = sim.effect_mean_shifts_g(0, c.a_l_unit_g, false, campaign.still_s);
    let effect_shifts: Vec<EffectShift> = on
        .into_iter()
        .zip(off)
        .map(|((kind, a), (_, b))| EffectShift {
            kind: kind.to_string(),
            ve_shift_g: match (a, b) {
                (Ok(a), Ok(b)) => Ok(a - b),
                (Err(e), _) | (_, Err(e)) => Err(e.to_string()),
            },
        })
        .collect();
    let predicted_ve_g = effect_shifts
        .iter()
        .map(|e| e.ve_shift_g.as_ref().ok().copied())
        .sum::<Option<f64>>()
        .map(|s| exact_ve_g + s);
    let z_predicted = predicted_ve_g.map(|p| (measurement.ve_g - p) / sigma);
    let nf = sums.n.max(1) as f64;
    let mean = sums.s1 / nf;
    let m2 = (sums.s2 / nf - mean * mean).max(0.0);
    let m4 = sums.s4 / nf - 4.0 * mean * sums.s3 / nf + 6.0 * mean * mean * sums.s2 / nf
        - 3.0 * mean.powi(4);
    let fits: Vec<(f64, f64, f64)> = batches
        .iter()
        .map(|b| b.fit(tone_hz.is_some()))
        .collect::<Option<_>>()
        .ok_or_else(|| Error::Unsupported {
            what: c.id.clone(),
            reason: format!(
                "the vibration sensor's record ({n_sensor} samples in {n_sensor_batches} \
                 batches) is too short to fit the tone in each batch"
            ),
        })?;
    let column = |k: usize| -> Vec<f64> {
        fits.iter()
            .map(|f| match k {
                0 => f.0,
                1 => f.1,
                _ => f.2,
            })
            .collect()
    };
    let (i_mean, _) = batch_mean_se(&column(0));
    let (q_mean, _) = batch_mean_se(&column(1));
    let tone = tone_hz.map(|f| {
        let (gain, _) = ac_coupling_response(f, scenario.sensor.ac_corner_hz, rates.sensor_hz);
        let a = i_mean.hypot(q_mean);
        // The batches' amplitudes along the mean phasor: linear in the samples, so
        // their batch-means standard error is the amplitude's (to first order in the
        // noise over the amplitude).
        let (ui, uq) = if a > 0.0 {
            (i_mean / a, q_mean / a)
        } else {
            (1.0, 0.0)
        };
        let along: Vec<f64> = fits.iter().map(|f| f.0 * ui + f.1 * uq).collect();
        (a / gain, batch_mean_se(&along).1 / gain)
    });
    let tone_amplitude3_g = tone.map(|t| t.0);
    let rms3_g = m2.sqrt();
    let tone_power = tone_amplitude3_g.map_or(0.0, |a| 0.5 * a * a);
    let sigma3_g = (m2 - tone_power).max(0.0).sqrt();
    let (_, variance_u_g2) = batch_mean_se(&column(2));
    let sensor = MeasuredVibration {
        tone_amplitude3_g,
        rms3_g,
        sigma3_g,
        kurtosis3: (tone_hz.is_none() && m2 > 0.0).then(|| m4 / (m2 * m2)),
        clipped_samples: sim.sensor_clipped()[0],
        n_samples: sums.n,
        tone_amplitude3_u_g: tone.map(|t| t.1),
        sigma3_u_g: if sigma3_g > 0.0 {
            variance_u_g2 / (2.0 * sigma3_g)
        } else {
            0.0
        },
        n_batches: n_sensor_batches,
    };
    let summary = ConditionSummary {
        condition: c.clone(),
        passport_id: campaign.passport.id().to_string(),
        k1_v_per_g: k1,
        vibration_unit,
        drift_accepted: measurement.drift_g <= campaign.tilt_limit_rad,
        tilt_limit_rad: campaign.tilt_limit_rad,
        measurement,
        exact_ve_g,
        published_ve_g,
        z_exact,
        effect_shifts,
        predicted_ve_g,
        z_predicted,
        sensor,
    };
    let [still1_v, vib_v, still2_v] = records;
    Ok(ConditionRun {
        summary,
        still1_v,
        vib_v,
        still2_v,
    })
}

/// Columns of [`write_summary_csv`], in order.
pub const SUMMARY_COLUMNS: [&str; 47] = [
    "condition_id",
    "tp",
    "angle_deg",
    "tilt_toward",
    "aL1_g",
    "aL2_g",
    "aL3_g",
    "direction",
    "scale_45_by_sqrt2",
    "tone_freq_hz",
    "tone_amplitude_g",
    "aB1_g",
    "aB2_g",
    "aB3_g",
    "random_source",
    "sigma1_g",
    "sigma2_g",
    "sigma3_g",
    "cov31_g2",
    "cov32_g2",
    "kurtosis",
    "passport",
    "k1_v_per_g",
    "u_still1_v",
    "u_vib_v",
    "u_still2_v",
    "measured_ve_g",
    "measured_ve_sigma_g",
    "exact_ve_g",
    "published_ve_g",
    "z_exact",
    "effects",
    "effect_ve_shift_g",
    "predicted_ve_g",
    "z_predicted",
    "drift_g",
    "drift_sigma_g",
    "tilt_limit_rad",
    "drift_check",
    "sensor_tone_amplitude3_g",
    "sensor_rms3_g",
    "sensor_sigma3_g",
    "sensor_kurtosis3",
    "sensor_clipped",
    "n_still1",
    "n_vib",
    "n_still2",
];

fn opt(x: Option<f64>) -> String {
    x.map(|v| v.to_string()).unwrap_or_default()
}

/// Writes one row per condition with [`SUMMARY_COLUMNS`] (values in the unit their
/// name says; empty where not applicable), for the model lab.
pub fn write_summary_csv<W: Write>(w: W, summaries: &[ConditionSummary]) -> Result<()> {
    let mut out = csv::Writer::from_writer(w);
    out.write_record(SUMMARY_COLUMNS)?;
    for s in summaries {
        let c = &s.condition;
        let v = &s.vibration_unit;
        let m = &s.measurement;
        let ab = c.tone.map(|t| t.amplitude_g).unwrap_or([0.0; 3]);
        let sigma = s.sigma_unit_g();
        let row: Vec<String> = vec![
            c.id.clone(),
            c.tp.to_string(),
            c.angle_deg.to_string(),
            c.tilt_toward.name().into(),
            c.a_l_unit_g[0].to_string(),
            c.a_l_unit_g[1].to_string(),
            c.a_l_unit_g[2].to_string(),
            c.direction.name().into(),
            c.scale_45_by_sqrt2.to_string(),
            opt(c.tone.map(|t| t.freq_hz)),
            opt(c.tone_amplitude_g),
            ab[0].to_string(),
            ab[1].to_string(),
            ab[2].to_string(),
            c.random
                .as_ref()
                .map(|r| r.source.clone())
                .unwrap_or_default(),
            sigma[0].to_string(),
            sigma[1].to_string(),
            sigma[2].to_string(),
            v.covariance_g2[2][0].to_string(),
            v.covariance_g2[2][1].to_string(),
            v.kurtosis[2].to_string(),
            s.passport_id.clone(),
            s.k1_v_per_g.to_string(),
            m.still1.mean_v.to_string(),
            m.vib.mean_v.to_string(),
            m.still2.mean_v.to_string(),
            m.ve_g.to_string(),
            m.ve_sigma_g.to_string(),
            s.exact_ve_g.to_string(),
            s.published_ve_g.to_string(),
            s.z_exact.to_string(),
            s.effect_shifts
                .iter()
                .map(|e| e.kind.as_str())
                .collect::<Vec<_>>()
                .join(";"),
            opt(s.predicted_ve_g.map(|p| p - s.exact_ve_g)),
            opt(s.predicted_ve_g),
            opt(s.z_predicted),
            m.drift_g.to_string(),
            m.drift_sigma_g.to_string(),
            s.tilt_limit_rad.to_string(),
            if s.drift_accepted {
                "accepted"
            } else {
                "rejected"
            }
            .into(),
            opt(s.sensor.tone_amplitude3_g),
            s.sensor.rms3_g.to_string(),
            s.sensor.sigma3_g.to_string(),
            opt(s.sensor.kurtosis3),
            s.sensor.clipped_samples.to_string(),
            m.still1.n_samples.to_string(),
            m.vib.n_samples.to_string(),
            m.still2.n_samples.to_string(),
        ];
        out.write_record(&row)?;
    }
    out.flush().map_err(|e| Error::Csv(e.into()))?;
    Ok(())
}

/// Columns of [`write_positions_csv`]: exactly those `vibrocomp identify positions`
/// reads (one list, the reader's).
pub use vibro_ident::table::POSITION_COLUMNS;

/// Writes the conditions as test positions for `vibrocomp identify positions`
/// (docs/identification.md): `u_still_v = 0.5 (<U1> + <U3>)`, `u_vib_v = <U2>`,
/// `u_sigma_v` the batch-means standard uncertainty of their difference (at least
/// [`U_SIGMA_FLOOR_V`]). `comment` lines are written first, each prefixed with `# `.
/// Every condition must be a single tone without random vibration (the positions
/// model (21) is for sinusoidal vibration).
pub fn write_positions_csv<W: Write>(
    mut w: W,
    summaries: &[ConditionSummary],
    comment: &[String],
) -> Result<()> {
    for s in summaries {
        if s.condition.tone.is_none() || s.condition.random.is_some() {
            return Err(Error::Unsupported {
                what: format!("condition {} in a positions CSV", s.condition.id),
                reason: "the test positions of MODEL.md section 9 take one tone and no random \
                         vibration"
                    .into(),
            });
        }
    }
    for line in comment {
        // One comment line per entry, whatever it holds.
        let line = line.replace(['\n', '\r'], " ");
        writeln!(w, "# {line}").map_err(|e| Error::Csv(e.into()))?;
    }
    let mut out = csv::Writer::from_writer(w);
    out.write_record(POSITION_COLUMNS)?;
    for s in summaries {
        let m = &s.measurement;
        let ab = s.condition.tone.map(|t| t.amplitude_g).unwrap_or([0.0; 3]);
        let u_still_v = 0.5 * (m.still1.mean_v + m.still2.mean_v);
        let u_sigma_v = (m.ve_sigma_g * s.k1_v_per_g.abs()).max(U_SIGMA_FLOOR_V);
        out.write_record([
            s.condition.tp.to_string(),
            s.condition.angle_deg.to_string(),
            ab[2].to_string(),
            ab[0].to_string(),
            ab[1].to_string(),
            u_still_v.to_string(),
            m.vib.mean_v.to_string(),
            u_sigma_v.to_string(),
        ])?;
    }
    out.flush().map_err(|e| Error::Csv(e.into()))?;
    Ok(())
}
