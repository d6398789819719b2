//! One evaluation everywhere (issue 43, MODEL.md section 12): a log's windows predicted
//! by the waveform stage the compensator runs (`vibro_waveform::WaveformStage`), fed the
//! log's own vibration samples and readings, instead of the statistics of the
//! estimator's window (`vibro_effects::predict`). Only `lab compare` of a fixed model
//! takes this path ([`crate::diagnose::compare_evaluated`]); the fits of `diagnose` and
//! `add` stay on the statistics (docs/lab.md, "Which evaluation").
//!
//! Per reading `n` and unit, the stage solves the interval-mean acceleration `m` of each
//! unit from its reading `R_n` and returns `ve_g = R_n - FP(m1, m2, m3)`: what the
//! vibration's deviation `d(t)` from its interval mean rectifies, plus the model's
//! output effects, through its path effects. The compensator removes exactly that
//! (`det_g` of its waveform blocks) and outputs `m`.
//!
//! The window's measured VE (`flight::sample_ve_g`) is another quantity:
//! `R - FP(aL) - lin`, `lin` the unit's *linear* response to the vibration over the
//! reading's interval (fitted through the sensors on a rig, `J(aL) (sensed - aL)` on a
//! simulated log). Write `m = aL + dbar + e` (`dbar` the vibration's interval mean at the
//! unit, `e` the reading's noise over the slope); then
//!
//! ```text
//! R - FP(aL) - lin = [R - FP(m)] + [FP(m) - FP(aL) - J(aL) (m - aL)] + [J(aL)(m - aL) - lin]
//!                  =    ve_g     +          nl_g                     +   J e + fit error
//! ```
//!
//! - `ve_g` holds the rectification of `d(t)` within the interval;
//! - `nl_g`, FP's nonlinear part at the interval means (`k2 dbar^2 + ...`), is the
//!   rectification of the interval means themselves. `ve_g` leaves it out because `m`
//!   holds `dbar`: the compensator's main-error step, evaluated per reading at its own
//!   `a(1)`, removes it. With random vibration up to 640 Hz and 800 Hz readings `dbar`
//!   keeps about half of the vibration's variance, so `nl_g` is as large as `ve_g`;
//! - the linear response is subtracted on both sides (in `m`, in `lin`): neither holds
//!   it; the reading's noise `e` moves `m` and cancels in `ve_g + nl_g` to second order,
//!   and stays in the measured VE, where the batch means state it.
//!
//! So a window's predicted VE is the mean of `ve_g + nl_g` over the window's readings,
//! with the weights of its measured VE (`flight::window_ve`'s taper, the same
//! readings), and the residual is the model's error, the readings' noise and the linear
//! fit's error. The two parts are reported apart ([`WindowSpan`]): `ve_g`'s mean is
//! what the compensator's corrections over the same readings add up to.
//!
//! A window falls back to the statistics path when any of its readings is not solved
//! (a sensor block lost or flagged, the stream not covering the interval with the
//! interpolation's half-width, a reading that is not finite); the row says which path
//! it took.

use std::collections::VecDeque;
use std::path::PathBuf;

use crate::{Error, LabModel, Result};
use serde::Serialize;
use vibro_log::topic;
use vibro_mcap::{Message, Reader};
use vibro_msgs::{vib_flags, Stream};
use vibro_physics::fp;
use vibro_physics::passport::Passport;
use vibro_physics::triad::TriadAxes;
use vibro_waveform::{Coverage, SensorChain, WaveformStage};

/// The row's prediction came from the waveform stage.
pub const PATH_WAVEFORM: &str = "waveform";
/// The row's prediction came from the statistics (`vibro_effects::predict`).
pub const PATH_STATISTICS: &str = "statistics";

/// What the waveform evaluation needs of a log: kept by [`crate::log_table`] beside the
/// log's summary.
#[derive(Debug, Clone)]
pub struct LogWaveform {
    pub path: PathBuf,
    pub axes: TriadAxes,
    /// Per unit, the passport the log's table uses (flat: `lambda(w)` dropped).
    pub passports: [Passport; 3],
    /// The sensors' chain: the log's metadata over the estimator's configuration.
    pub chain: SensorChain,
    /// The taper of each window's measured VE, readings (`flight::window_ve`).
    pub taper_samples: usize,
    /// The log's lab windows, in time order.
    pub windows: Vec<LabWindow>,
}

/// One lab window of a log: its conditions and its readings.
#[derive(Debug, Clone)]
pub struct LabWindow {
    /// Its first condition in the log's table; one per unit, in unit order.
    pub first_condition: usize,
    pub units: usize,
    /// The latch times of the readings its measured VE is the mean of, increasing.
    pub latch_ns: Vec<u64>,
    /// Their reference `aL` along the units' IAs, g (the measured VE's `FP(aL)`).
    pub a_l_ia_g: Vec<[f64; 3]>,
}

/// Where a row's readings lie, for a caller that checks the prediction against another
/// evaluation (the compensator's corrections over the same readings).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WindowSpan {
    pub first_latch_ns: u64,
    pub last_latch_ns: u64,
    pub readings: usize,
    /// The raised-cosine taper at each end, readings (`vibro_ident::measure::taper_weights`).
    pub taper_readings: usize,
    /// The weighted mean of the stage's `ve_g` (module doc): what the compensator
    /// removes over these readings, g.
    pub stage_ve_g: f64,
    /// The weighted mean of FP's nonlinear part at the solved interval means, `nl_g`
    /// (module doc), g. The prediction is `stage_ve_g + interval_means_ve_g`.
    pub interval_means_ve_g: f64,
}

/// The waveform stage's prediction of one condition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WaveformPrediction {
    pub ve_g: f64,
    pub span: WindowSpan,
}

/// What became of a log's readings on the waveform path.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct WaveformCounts {
    /// Readings the stage solved.
    pub readings_solved: u64,
    /// Readings the samples never covered (a break, a gap, the record's ends).
    pub readings_uncovered: u64,
    /// Lab windows predicted from the waveform, and left to the statistics.
    pub windows_waveform: usize,
    pub windows_statistics: usize,
    /// Sensor blocks the stage refused (flagged or not finite) and breaks in the stream.
    pub vib_refused: u64,
    pub vib_breaks: u64,
}

/// An accelerometer block waiting for the samples that cover it.
struct Held {
    t0_ns: u64,
    period_ns: u64,
    readings_g: Vec<[f64; 3]>,
}

/// A window's running sums, per unit.
struct Sums {
    weights: Vec<f64>,
    sum_w: f64,
    sum_wve: [f64; 3],
    sum_wnl: [f64; 3],
    solved: usize,
}

/// Per condition of the log's table (`conditions` of them), the waveform stage's
/// prediction under `model`, or `None` where the window falls back to the statistics.
pub fn predict_log(
    model: &LabModel,
    log: &LogWaveform,
    conditions: usize,
) -> Result<(Vec<Option<WaveformPrediction>>, WaveformCounts)> {
    let context = |what: &str| format!("{}: the waveform stage: {what}", log.path.display());
    let effects = [0, 1, 2]
        .map(|u| model.build_effects(&log.passports[u]))
        .into_iter()
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let effects: [Vec<_>; 3] = effects
        .try_into()
        .map_err(|_| Error::Invalid(context("three units")))?;
    let mut stage = WaveformStage::new(log.chain, log.axes, log.passports, effects)
        .map_err(|e| Error::Invalid(context(&e.to_string())))?;
    let k1 = log.passports.map(|p| p.k1_v_per_g);
    let mut sums: Vec<Option<Sums>> = (0..log.windows.len()).map(|_| None).collect();
    let mut cursor = 0usize;
    let mut counts = WaveformCounts::default();
    let mut held: VecDeque<Held> = VecDeque::new();
    let mut out_g: Vec<[f64; 3]> = Vec::new();
    let mut ve_g: Vec<[f64; 3]> = Vec::new();
    let (vib_topic, accel_topic) = (topic(Stream::Vib), topic(Stream::Accel));
    let reader = Reader::open(&log.path)?;
    let mut solve = |stage: &mut WaveformStage, h: &Held, counts: &mut WaveformCounts| {
        let n = h.readings_g.len();
        out_g.resize(n, [0.0; 3]);
        ve_g.resize(n, [0.0; 3]);
        stage.compensate_with_ve(
            h.t0_ns,
            h.period_ns,
            &h.readings_g,
            &mut out_g,
            Some(&mut ve_g),
        );
        counts.readings_solved += n as u64;
        for (k, (ve, m)) in ve_g.iter().zip(&out_g).enumerate() {
            let latch = h.t0_ns + k as u64 * h.period_ns;
            accumulate(log, &mut sums, &mut cursor, latch, *ve, *m);
        }
    };
    // Solves or drops the held blocks in order; `ended`: no more samples come.
    let mut drain = |stage: &mut WaveformStage,
                     held: &mut VecDeque<Held>,
                     counts: &mut WaveformCounts,
                     ended: bool| {
        while let Some(h) = held.front() {
            match stage.coverage(h.t0_ns, h.period_ns, h.readings_g.len()) {
                Coverage::Ready => solve(stage, h, counts),
                Coverage::NotYet if !ended => break,
                Coverage::NotYet | Coverage::Never => {
                    counts.readings_uncovered += h.readings_g.len() as u64
                }
            }
            held.pop_front();
        }
    };
    for record in reader {
        let record = record?;
        let t = &*record.topic;
        match &record.message {
            Message::VibBlock(b) if t == vib_topic => {
                stage.push_vib(
                    b.seq,
                    b.first_sample_index,
                    b.t0_ns,
                    b.sample_period_ns,
                    b.samples_v(),
                    b.flags & vib_flags::SATURATED != 0,
                    b.flags & vib_flags::GAP_BEFORE != 0,
                );
            }
            Message::AccelBlock(b) if t == accel_topic => {
                held.push_back(Held {
                    t0_ns: b.t0_ns,
                    period_ns: b.sample_period_ns,
                    readings_g: b
                        .samples_v()
                        .iter()
                        .map(|u| [0, 1, 2].map(|i| u[i] / k1[i]))
                        .collect(),
                });
            }
            _ => continue,
        }
        drain(&mut stage, &mut held, &mut counts, false);
    }
    drain(&mut stage, &mut held, &mut counts, true);
    let c = stage.counters();
    counts.vib_refused = c.refused;
    counts.vib_breaks = c.breaks;
    let mut out = vec![None; conditions];
    for (w, s) in log.windows.iter().zip(sums) {
        let n = w.latch_ns.len();
        let predicted = s.filter(|s| s.solved == n).and_then(|s| {
            let ve: Vec<(f64, f64)> = (0..w.units.min(3))
                .map(|u| (s.sum_wve[u] / s.sum_w, s.sum_wnl[u] / s.sum_w))
                .collect();
            ve.iter()
                .all(|(a, b)| a.is_finite() && b.is_finite())
                .then_some(ve)
        });
        let Some(ve) = predicted else {
            counts.windows_statistics += 1;
            continue;
        };
        counts.windows_waveform += 1;
        for (u, (stage_ve_g, interval_means_ve_g)) in ve.into_iter().enumerate() {
            let span = WindowSpan {
                first_latch_ns: w.latch_ns[0],
                last_latch_ns: w.latch_ns[n - 1],
                readings: n,
                taper_readings: log.taper_samples,
                stage_ve_g,
                interval_means_ve_g,
            };
            if let Some(slot) = out.get_mut(w.first_condition + u) {
                *slot = Some(WaveformPrediction {
                    ve_g: stage_ve_g + interval_means_ve_g,
                    span,
                });
            }
        }
    }
    Ok((out, counts))
}

/// Adds reading `latch`'s `ve` (the stage's `ve_g`) and FP's nonlinear part at its
/// solved means `m` (`nl_g`, module doc) to the window that holds it (windows and
/// readings both in time order: `cursor` only moves forward).
fn accumulate(
    log: &LogWaveform,
    sums: &mut [Option<Sums>],
    cursor: &mut usize,
    latch: u64,
    ve: [f64; 3],
    m: [f64; 3],
) {
    while *cursor < log.windows.len()
        && log.windows[*cursor]
            .latch_ns
            .last()
            .is_none_or(|&l| l < latch)
    {
        *cursor += 1;
    }
    let Some(w) = log.windows.get(*cursor) else {
        return;
    };
    let Ok(i) = w.latch_ns.binary_search(&latch) else {
        return;
    };
    let s = sums[*cursor].get_or_insert_with(|| Sums {
        weights: vibro_ident::measure::taper_weights(w.latch_ns.len(), log.taper_samples),
        sum_w: 0.0,
        sum_wve: [0.0; 3],
        sum_wnl: [0.0; 3],
        solved: 0,
    });
    let wt = s.weights[i];
    let axes = &log.axes;
    let (body_m, body_l) = (axes.body_from_ia(&m), axes.body_from_ia(&w.a_l_ia_g[i]));
    s.sum_w += wt;
    for u in 0..3 {
        let (a, l) = (
            axes.units[u].to_unit(&body_m),
            axes.units[u].to_unit(&body_l),
        );
        let p = &log.passports[u];
        let grad = fp::gradient_g(p, l[0], l[1], l[2]);
        let linear: f64 = (0..3).map(|i| grad[i] * (a[i] - l[i])).sum();
        let nl = fp::output_g(p, a[0], a[1], a[2]) - fp::output_g(p, l[0], l[1], l[2]) - linear;
        s.sum_wve[u] += wt * ve[u];
        s.sum_wnl[u] += wt * nl;
    }
    s.solved += 1;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log(windows: Vec<LabWindow>, taper_samples: usize) -> LogWaveform {
        let triad = vibro_config::resolve_triad("default").unwrap();
        LogWaveform {
            path: PathBuf::from("test.mcap"),
            axes: triad.axes,
            passports: triad
                .passports
                .map(|p| vibro_effects::predict::flat_passport(&p).unwrap()),
            chain: SensorChain::default(),
            taper_samples,
            windows,
        }
    }

    fn window(first_ns: u64, n: usize, a_l: [f64; 3]) -> LabWindow {
        LabWindow {
            first_condition: 0,
            units: 3,
            latch_ns: (0..n as u64).map(|k| first_ns + k * 1_250_000).collect(),
            a_l_ia_g: vec![a_l; n],
        }
    }

    /// `nl_g` is FP's nonlinear part at the interval mean: it scales as the square of
    /// the mean's excursion from `aL` (the conversion function's `k2` leads), and is 0
    /// with no excursion. (Away from `a3 = 0`, where the asymmetry `|a3|` makes it
    /// first order.)
    #[test]
    fn the_interval_means_part_is_second_order_in_the_excursion() {
        let a_l = [0.8, -0.6, 1.0];
        let nl = |delta: f64| {
            let log = log(vec![window(0, 1, a_l)], 0);
            let mut sums = vec![None];
            let m = [a_l[0] + delta, a_l[1] - 0.5 * delta, a_l[2] + 0.3 * delta];
            accumulate(&log, &mut sums, &mut 0, 0, [0.0; 3], m);
            let s = sums[0].take().unwrap();
            s.sum_wnl.map(|x| x / s.sum_w)
        };
        assert_eq!(nl(0.0), [0.0; 3]);
        let (a, b) = (nl(0.02), nl(0.04));
        for u in 0..3 {
            assert!(a[u] != 0.0, "unit {u}");
            let ratio = b[u] / a[u];
            assert!((ratio - 4.0).abs() < 0.1, "unit {u}: {ratio}");
        }
    }

    /// Readings are added to the window that holds them with the measured VE's taper
    /// weights; one outside every window is not; a window short of a reading falls back.
    #[test]
    fn readings_fall_into_their_windows_with_the_taper() {
        let log = log(
            vec![
                window(10_000_000, 8, [0.0; 3]),
                window(30_000_000, 8, [0.0; 3]),
            ],
            2,
        );
        let mut sums: Vec<Option<Sums>> = vec![None, None];
        let mut cursor = 0;
        // Before every window: dropped.
        accumulate(&log, &mut sums, &mut cursor, 1_000, [1.0; 3], [0.0; 3]);
        assert!(sums.iter().all(Option::is_none));
        for k in 0..8u64 {
            let ve = [k as f64; 3];
            accumulate(
                &log,
                &mut sums,
                &mut cursor,
                10_000_000 + k * 1_250_000,
                ve,
                [0.0; 3],
            );
        }
        let s = sums[0].as_ref().unwrap();
        assert_eq!(s.solved, 8);
        let w = vibro_ident::measure::taper_weights(8, 2);
        let want: f64 = (0..8).map(|k| k as f64 * w[k]).sum::<f64>() / w.iter().sum::<f64>();
        assert!((s.sum_wve[1] / s.sum_w - want).abs() < 1e-15);
        // Symmetric weights over 0..7: the mean is 3.5, the taper keeps it there.
        assert!((want - 3.5).abs() < 1e-12);
        // The second window sees one reading of eight.
        accumulate(&log, &mut sums, &mut cursor, 30_000_000, [1.0; 3], [0.0; 3]);
        assert_eq!(sums[1].as_ref().unwrap().solved, 1);
    }
}
