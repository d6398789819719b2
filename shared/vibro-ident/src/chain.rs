//! A reference accelerometer recorded as a rig records a piezoelectric one (RIG.md: a
//! B&K 8503 through a charge converter): AC-coupled, in V, through its chain, with
//! gravity gone. [`reference_in_g`] turns such a record into the DC-coupled reference
//! in g that the fit and the still checks take ([`crate::rig`], `vibro_lab::campaign`):
//!
//! 1. the chain undone sample by sample by the vibration sensors' own inverse,
//!    `vibro_waveform::chain::ChainInverse` (MODEL.md section 12: "undo the sensor chain
//!    (sensitivity, AC coupling, the chain's delay: a sample stamped `s` saw the base at
//!    `s - delay`)"): the sensitivity divided out, the first-order AC coupling inverted
//!    (one home for that physics; its accuracy against an analog corner is stated
//!    there), the delay taken off the time stamps;
//! 2. the inverse's leftover constant (an AC-coupled record has no DC) removed as the
//!    record's mean over the still windows, where the table does not move;
//! 3. gravity added from the stated orientation, `gravity_g * up` per sample at its
//!    corrected time (MODEL.md section 9: a unit whose IA is along `up` reads `+g`).
//!
//! The unit's linear response is fitted from 20 Hz up ([`crate::reference`]), far above
//! any stated corner, so what the inverse leaves below the corner does not reach it.
//!
//! ```
//! use vibro_ident::chain::reference_in_g;
//! use vibro_ident::Timed;
//! use vibro_waveform::chain::SensorChain;
//! // A still record at 0.01 V/g: gravity comes from the orientation alone.
//! let volts = Timed { time_s: (0..100).map(|i| i as f64 * 1e-3).collect(), step_s: 1e-3,
//!     columns: vec![vec![0.0; 100]; 3] };
//! let chain = SensorChain { sensitivity_v_per_g: [0.01; 3], ac_corner_hz: 0.5, delay_s: 0.0 };
//! let g = reference_in_g(&volts, &chain, &[[0.0, 0.1]], |_| Some([0.0, 0.0, 1.0]),
//!     std::path::Path::new("r.csv")).unwrap();
//! assert_eq!(g.columns[2][50], 1.0);
//! ```

use std::path::Path;

use vibro_waveform::chain::{ChainInverse, SensorChain};

use crate::{Error, Result, Timed};

/// An AC-coupled reference's chain and the orientation its gravity comes from, as a rig
/// file (`[reference.chain]`, `[reference]`) or a campaign manifest states them.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceChainRequest {
    /// The chain, body axes x, y, z (`ac_corner_hz` 0: DC-coupled).
    pub chain: SensorChain,
    /// Gravity along the body axes per stated time span `[from_s, to_s]`, g.
    pub orientation: Vec<([f64; 2], [f64; 3])>,
    /// Where the chain is stated (the rig file or the manifest), for the report.
    pub source: String,
}

/// The chain as the sensor-chain inverse takes it (absent corner: DC-coupled, 0).
pub fn sensor_chain(chain: &vibro_config::rig::ReferenceChain) -> SensorChain {
    SensorChain {
        sensitivity_v_per_g: chain.sensitivity_v_per_g,
        ac_corner_hz: chain.ac_corner_hz.unwrap_or(0.0),
        delay_s: chain.delay_s,
    }
}

impl ReferenceChainRequest {
    /// The chain and orientation of a rig file: its static segments' `gravity_g * up`,
    /// or a centrifuge's constant specific force. `Error::Request` when the file states
    /// no `[reference.chain]` (its reference is then DC-coupled in g).
    pub fn from_rig(rig: &vibro_config::RigConfig) -> Result<Self> {
        use vibro_config::rig::ReferenceSpec;
        let Some(chain) = &rig.reference_chain else {
            return Err(Error::Request {
                problems: vec![format!(
                    "rig = {:?}: states no [reference.chain]: its reference is DC-coupled in \
                     g (give --reference alone)",
                    rig.file
                )],
            });
        };
        let orientation = match &rig.reference {
            ReferenceSpec::Static {
                gravity_g,
                segments,
            } => segments
                .iter()
                .map(|s| ([s.from_s, s.to_s], s.up.map(|u| u * gravity_g)))
                .collect(),
            spec => spec
                .body_g_at(0.0)
                .map(|g| vec![([f64::NEG_INFINITY, f64::INFINITY], g)])
                .unwrap_or_default(),
        };
        Ok(Self {
            chain: sensor_chain(chain),
            orientation,
            source: rig.file.clone(),
        })
    }

    /// The stated gravity along the body axes at `t_s`, g; `None` outside every span.
    pub fn gravity_body_g(&self, t_s: f64) -> Option<[f64; 3]> {
        self.orientation
            .iter()
            .find(|(span, _)| t_s >= span[0] && t_s <= span[1])
            .map(|(_, g)| *g)
    }
}

/// The DC-coupled reference in g (body x, y, z) from `volts`, its first three columns
/// recorded through `chain` (module docs). `still_windows_s`: where the table is still
/// (on the corrected time); `gravity_body_g(t_s)`: the stated gravity along the body
/// axes at `t_s`, g (`None`: the time is outside every stated orientation). `file`
/// names the record in errors.
pub fn reference_in_g(
    volts: &Timed,
    chain: &SensorChain,
    still_windows_s: &[[f64; 2]],
    gravity_body_g: impl Fn(f64) -> Option<[f64; 3]>,
    file: &Path,
) -> Result<Timed> {
    let problem = |problem: String| Error::Coverage {
        file: file.display().to_string(),
        problem,
    };
    let rules: Vec<String> = chain.problems().iter().map(|p| p.to_string()).collect();
    if !rules.is_empty() {
        return Err(problem(format!(
            "the reference's chain: {}",
            rules.join("; ")
        )));
    }
    let rate_hz = volts.rate_hz();
    if !chain.usable_at(rate_hz) {
        return Err(problem(format!(
            "the reference's chain: ac_corner_hz = {}: must be below 0.05 times the \
             reference's rate ({rate_hz} Hz) to be undone",
            chain.ac_corner_hz
        )));
    }
    let [Some(x), Some(y), Some(z)] = [0, 1, 2].map(|i| volts.columns.get(i)) else {
        return Err(problem(
            "the reference needs three columns (body x, y, z)".into(),
        ));
    };
    let mut inverse = ChainInverse::new(chain, rate_hz);
    let time_s: Vec<f64> = volts.time_s.iter().map(|t| t - chain.delay_s).collect();
    let mut columns: Vec<Vec<f64>> = (0..3).map(|_| Vec::with_capacity(time_s.len())).collect();
    let (mut still_sum, mut still_n) = ([0.0; 3], 0usize);
    for (i, t) in time_s.iter().enumerate() {
        let g = inverse.undo([x[i], y[i], z[i]]);
        if still_windows_s.iter().any(|w| *t >= w[0] && *t <= w[1]) {
            for (sum, g_a) in still_sum.iter_mut().zip(g) {
                *sum += g_a;
            }
            still_n += 1;
        }
        for (column, g_a) in columns.iter_mut().zip(g) {
            column.push(g_a);
        }
    }
    if still_n == 0 {
        return Err(problem(format!(
            "no sample of the reference lies in a still window ({still_windows_s:?} s): an \
             AC-coupled reference's constant is taken where the table is still"
        )));
    }
    let still_mean = still_sum.map(|s| s / still_n as f64);
    for (i, &t) in time_s.iter().enumerate() {
        // Before the first stated time by at most the delay: the stamped time's.
        let Some(gravity) = gravity_body_g(t).or_else(|| gravity_body_g(t + chain.delay_s)) else {
            return Err(problem(format!(
                "the sample at {} s (stamped): outside every stated orientation",
                t + chain.delay_s
            )));
        };
        for ((column, gravity_g), mean_g) in columns.iter_mut().zip(gravity).zip(still_mean) {
            column[i] += gravity_g - mean_g;
        }
    }
    Ok(Timed {
        time_s,
        step_s: volts.step_s,
        columns,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A tone through an analog first-order high-pass in its steady state (closed form,
    /// independent of the inverse), delayed, at 0.01 V/g: back in g with gravity, within
    /// the bilinear inverse's stated error.
    #[test]
    fn an_ac_coupled_delayed_tone_comes_back_in_g_with_gravity() {
        let (fs, fc, f, amp_g, delay_s, s_v_per_g) = (5000.0, 0.5, 60.0, 2.0, 0.0013, 0.01);
        let n = 50_000;
        let h = {
            // H(j w) = j w / (j w + wc): gain and phase of the analog high-pass.
            let (w, wc) = (2.0 * PI * f, 2.0 * PI * fc);
            (w / (w * w + wc * wc).sqrt(), (wc / w).atan())
        };
        let on = |t: f64| (4.0..6.0).contains(&t);
        let table = |t: f64| {
            if on(t) {
                amp_g * (2.0 * PI * f * t).sin()
            } else {
                0.0
            }
        };
        // A switched tone is not in steady state at its edges: test inside, away from them.
        let volts_of = |t: f64| {
            let seen = t - delay_s;
            if on(seen) {
                s_v_per_g * h.0 * amp_g * (2.0 * PI * f * seen + h.1).sin()
            } else {
                0.0
            }
        };
        let time_s: Vec<f64> = (0..n).map(|i| i as f64 / fs).collect();
        let v: Vec<f64> = time_s.iter().map(|&t| volts_of(t)).collect();
        let volts = Timed {
            time_s: time_s.clone(),
            step_s: 1.0 / fs,
            columns: vec![vec![0.0; n], v.iter().map(|x| -x).collect(), v],
        };
        let chain = SensorChain {
            sensitivity_v_per_g: [s_v_per_g, -s_v_per_g, s_v_per_g],
            ac_corner_hz: fc,
            delay_s,
        };
        let g = reference_in_g(
            &volts,
            &chain,
            &[[0.0, 3.9]],
            |_| Some([0.0, 0.6, 0.8]),
            Path::new("r.csv"),
        )
        .unwrap();
        assert!((g.time_s[0] + delay_s).abs() < 1e-15);
        // Still, before the tone: gravity alone.
        for (a, gravity) in [(1, 0.6), (2, 0.8)] {
            assert!((g.columns[a][100] - gravity).abs() < 1e-12);
        }
        // The tone's switch-on through the analog corner steps the steady state's DC
        // by about `amp fc / f`: the tone itself is compared as deviations from its mean
        // over whole periods, where the inverse is exact up to the bilinear warping.
        let inside: Vec<usize> = (0..n)
            .filter(|&i| (4.5..5.5).contains(&g.time_s[i]))
            .collect();
        let mean = |x: &dyn Fn(usize) -> f64| {
            inside.iter().map(|&i| x(i)).sum::<f64>() / inside.len() as f64
        };
        let mut worst: f64 = 0.0;
        for a in [1, 2] {
            let m_got = mean(&|i| g.columns[a][i]);
            let m_want = mean(&|i| table(g.time_s[i]));
            for &i in &inside {
                let d = (g.columns[a][i] - m_got) - (table(g.time_s[i]) - m_want);
                worst = worst.max(d.abs());
            }
        }
        assert!(worst < 1e-4 * amp_g, "worst {worst:e} g");
        assert!(g.columns[0].iter().all(|x| x.abs() < 1e-12));
    }

    /// Bad chains and a record without still samples are refused with the value and rule.
    #[test]
    fn a_bad_chain_is_refused() {
        let volts = Timed {
            time_s: (0..100).map(|i| i as f64 * 1e-3).collect(),
            step_s: 1e-3,
            columns: vec![vec![0.0; 100]; 3],
        };
        let up = |_| Some([0.0, 0.0, 1.0]);
        let chain = SensorChain {
            sensitivity_v_per_g: [0.01; 3],
            ac_corner_hz: 100.0,
            delay_s: 0.0,
        };
        let e = reference_in_g(&volts, &chain, &[[0.0, 1.0]], up, Path::new("r.csv"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("r.csv: ") && e.contains("ac_corner_hz = 100"),
            "{e}"
        );
        let chain = SensorChain {
            ac_corner_hz: 0.5,
            ..chain
        };
        let e = reference_in_g(&volts, &chain, &[[5.0, 6.0]], up, Path::new("r.csv"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("no sample of the reference lies in a still window"),
            "{e}"
        );
        let e = reference_in_g(&volts, &chain, &[[0.0, 1.0]], |_| None, Path::new("r.csv"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("outside every stated orientation"), "{e}");
    }
}
