//! A recorded session measured against its reference: each compensation stage's error
//! (uncompensated `U/K1`, main error removed `a(2)`, vibration error removed `a(4)`,
//! MODEL.md section 7, [P2 (17)-(20)]) against the acceleration each unit really
//! sensed (`TruthBlock.a_sensed_ia_g`), averaged over windows.
//!
//! Averaging over a window keeps what a navigation system integrates: the slowly
//! varying error. Per sample, the OA/PA vibration passes through the cross-axis
//! sensitivities `m1`, `m2` at about 2 mg RMS; it is zero-mean and no compensator
//! removes it sample by sample.

use crate::{Error, Result};
use serde::Serialize;
use std::path::Path;
use vibro_mcap::{Message, Reader};
use vibro_msgs::compensation_flags as cf;

/// RMS over windows (and units) of one stage's windowed mean error, g.
#[derive(Debug, Clone, Serialize)]
pub struct StageErrors {
    pub uncompensated_rms_g: f64,
    pub main_removed_rms_g: f64,
    pub vibration_removed_rms_g: f64,
    /// `uncompensated / vibration removed`.
    pub reduction: f64,
}

/// One unit's errors.
#[derive(Debug, Clone, Serialize)]
pub struct UnitErrors {
    pub unit: usize,
    #[serde(flatten)]
    pub errors: StageErrors,
}

/// The errors of a recorded session against the simulator's truth.
#[derive(Debug, Clone, Serialize)]
pub struct SessionErrors {
    pub window_s: f64,
    /// Output samples with a reading, a compensated output and the truth.
    pub samples: u64,
    pub windows: u64,
    /// Windows in which every block was compensated with a vibration estimate (the
    /// first ones come before the first estimate: main error only, flagged).
    pub compensated_windows: u64,
    /// Blocks flagged main-only (no usable estimate yet, or stale).
    pub main_only_blocks: u64,
    pub blocks: u64,
    /// Over the compensated windows and the three units.
    pub all_units: StageErrors,
    pub units: Vec<UnitErrors>,
}

#[derive(Default, Clone, Copy)]
struct Row {
    raw_g: Option<[f64; 3]>,
    sensed_g: Option<[f64; 3]>,
    a2_g: Option<[f64; 3]>,
    a4_g: Option<[f64; 3]>,
    main_only: bool,
}

fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

fn stage(unc: &[f64], main: &[f64], vib: &[f64]) -> StageErrors {
    let (u, m, v) = (rms(unc), rms(main), rms(vib));
    StageErrors {
        uncompensated_rms_g: u,
        main_removed_rms_g: m,
        vibration_removed_rms_g: v,
        reduction: if v > 0.0 { u / v } else { f64::INFINITY },
    }
}

/// Reads a session recording (`/accel`, `/truth`, `/compensated`) and measures each
/// stage's error against the sensed acceleration, averaged over `window_s` windows.
/// `k1_v_per_g`: the units' scale factors (readings are `U/K1`).
pub fn session_errors(path: &Path, k1_v_per_g: [f64; 3], window_s: f64) -> Result<SessionErrors> {
    let bad = |problem: String| Error::BadLog {
        path: path.to_path_buf(),
        problem,
    };
    let mut rows: Vec<Row> = Vec::new();
    let mut period_ns = 0u64;
    let (mut blocks, mut main_only_blocks) = (0u64, 0u64);
    let row = |rows: &mut Vec<Row>, i: u64| -> Result<usize> {
        let i = usize::try_from(i)
            .ok()
            .filter(|&i| i < 100_000_000)
            .ok_or_else(|| bad(format!("sample index {i}: implausibly large")))?;
        if rows.len() <= i {
            rows.resize(i + 1, Row::default());
        }
        Ok(i)
    };
    for record in Reader::open(path)? {
        let record = record?;
        match (&*record.topic, &record.message) {
            ("/accel", Message::AccelBlock(b)) => {
                period_ns = b.sample_period_ns;
                for (k, u_v) in b.samples_v().iter().enumerate() {
                    let i = row(&mut rows, b.first_sample_index + k as u64)?;
                    rows[i].raw_g = Some([
                        u_v[0] / k1_v_per_g[0],
                        u_v[1] / k1_v_per_g[1],
                        u_v[2] / k1_v_per_g[2],
                    ]);
                }
            }
            ("/truth", Message::TruthBlock(b)) => {
                for k in 0..b.count as usize {
                    let i = row(&mut rows, b.first_sample_index + k as u64)?;
                    rows[i].sensed_g = Some(b.a_sensed_ia_g[k]);
                }
            }
            ("/compensated", Message::CompensatedBlock(b)) => {
                blocks += 1;
                let main_only = b.flags & cf::MAIN_ONLY != 0;
                main_only_blocks += u64::from(main_only);
                for k in 0..b.count as usize {
                    let i = row(&mut rows, b.first_sample_index + k as u64)?;
                    rows[i].a2_g = Some(b.a2_g[k]);
                    rows[i].a4_g = Some(b.a4_g[k]);
                    rows[i].main_only = main_only;
                }
            }
            _ => {}
        }
    }
    if period_ns == 0 || blocks == 0 {
        return Err(bad("no /accel and /compensated blocks to compare".into()));
    }
    let per_window = ((window_s * 1e9 / period_ns as f64).round() as usize).max(1);
    let mut unc = [Vec::new(), Vec::new(), Vec::new()];
    let mut main = [Vec::new(), Vec::new(), Vec::new()];
    let mut vib = [Vec::new(), Vec::new(), Vec::new()];
    let (mut windows, mut compensated_windows, mut samples) = (0u64, 0u64, 0u64);
    for w in rows.chunks(per_window) {
        let complete: Vec<&Row> = w
            .iter()
            .filter(|r| r.raw_g.is_some() && r.sensed_g.is_some() && r.a4_g.is_some())
            .collect();
        samples += complete.len() as u64;
        // Only whole windows: a partial one is noisier than the rest.
        if complete.len() < per_window {
            continue;
        }
        windows += 1;
        if complete.iter().any(|r| r.main_only) {
            continue;
        }
        compensated_windows += 1;
        let n = complete.len() as f64;
        for u in 0..3 {
            let mean = |f: &dyn Fn(&Row) -> f64| complete.iter().map(|r| f(r)).sum::<f64>() / n;
            let s = |r: &Row| r.sensed_g.map_or(f64::NAN, |s| s[u]);
            unc[u].push(mean(&|r| r.raw_g.map_or(f64::NAN, |a| a[u]) - s(r)));
            main[u].push(mean(&|r| r.a2_g.map_or(f64::NAN, |a| a[u]) - s(r)));
            vib[u].push(mean(&|r| r.a4_g.map_or(f64::NAN, |a| a[u]) - s(r)));
        }
    }
    if compensated_windows == 0 {
        return Err(bad(format!(
            "no window of {window_s} s was compensated with a vibration estimate ({blocks} blocks, {main_only_blocks} main-only)"
        )));
    }
    let all = |v: &[Vec<f64>; 3]| v.concat();
    Ok(SessionErrors {
        window_s,
        samples,
        windows,
        compensated_windows,
        main_only_blocks,
        blocks,
        all_units: stage(&all(&unc), &all(&main), &all(&vib)),
        units: (0..3)
            .map(|u| UnitErrors {
                unit: u + 1,
                errors: stage(&unc[u], &main[u], &vib[u]),
            })
            .collect(),
    })
}
