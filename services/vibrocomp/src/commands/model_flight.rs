//! `vibrocomp model flight`: the physics core alone on the Cyclone-4 flight (RIG.md),
//! every mode side by side (the streaming `vibrocomp demo` runs the simulator's flight
//! through the services).
//!
//! The AL-15 triad flies the Cyclone-4 profile: longitudinal apparent acceleration
//! rising from 1 g to 5 g over 600 s (mean about 2-3 g), deterministic vibration
//! aB3 = 0.5 g along the longitudinal axis and 1.2 g transverse at 8..16 Hz, and the
//! broadband random vibration of [P1 Table 3] seen by the unit as sigma = 1.4 g ([P2]).
//! Every 10 s the mean readings of the three units are the exact mean of (FP) over
//! that vibration (MODEL.md section 6); the compensation algorithm runs in each mode,
//! and the demo reports the error against the true flight acceleration before and
//! after compensation. The readings come from the model itself, so the exact mode
//! recovering them is a check of the solver, and the published modes show what the
//! papers' approximations leave.

use crate::output::{fmt_g, fmt_ratio, print_json};
use clap::Args;
use serde::Serialize;
use vibro_physics::compensation::{Mode, TriadCompensator};
use vibro_physics::exact::MeanModel;
use vibro_physics::vibration::Vibration;

#[derive(Debug, Args)]
pub struct FlightArgs {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// RMS errors of one mode over the flight, g.
#[derive(Debug, Serialize)]
struct ModeErrors {
    mode: &'static str,
    uncompensated_rms_g: f64,
    main_removed_rms_g: f64,
    vibration_removed_rms_g: f64,
    reduction: f64,
}

#[derive(Debug, Serialize)]
struct DemoReport {
    scenario: &'static str,
    triad: String,
    samples: usize,
    modes: Vec<ModeErrors>,
}

/// Longitudinal apparent acceleration of the Cyclone-4 profile at time `t_s`: three
/// stages rising from about 1 g to about 5 g over 600 s (RIG.md, [P2 Fig. 3a]).
fn cyclone4_longitudinal_g(t_s: f64) -> f64 {
    let stage_s = 200.0;
    let within = (t_s % stage_s) / stage_s;
    let stage = (t_s / stage_s).floor().min(2.0);
    // Each stage climbs as propellant burns; the next stage restarts a little higher.
    1.0 + 0.6 * stage + (1.6 + 0.4 * stage) * within * within
}

pub fn run(args: FlightArgs) -> anyhow::Result<()> {
    let triad = vibro_config::default_triad()?;
    // Vibration in each unit's own axes [OA, PA, IA]: the longitudinal unit (IA = x)
    // sees 0.5 g along its IA and 1.2 g across; the transverse units see 1.2 g along
    // their IA. All see sigma = 1.4 g random vibration along IA ([P2]).
    let mut vibs = [Vibration::none(); 3];
    for (i, v) in vibs.iter_mut().enumerate() {
        let ab_ia = if triad.axes.units[i].ia.body_index == 0 {
            0.5
        } else {
            1.2
        };
        let ab_oa = if triad.axes.units[i].oa.body_index == 0 {
            0.5
        } else {
            1.2
        };
        let ab_pa = if triad.axes.units[i].pa.body_index == 0 {
            0.5
        } else {
            1.2
        };
        *v = Vibration::single_tone(12.0, [ab_oa, ab_pa, ab_ia]);
        v.covariance_g2[2][2] = 1.4 * 1.4;
        v.covariance_g2[0][0] = 1.0;
        v.covariance_g2[1][1] = 1.0;
    }
    let mut truth_models = Vec::new();
    for (p, v) in triad.passports.iter().zip(&vibs) {
        let mut m = MeanModel::new(*p);
        m.set_vibration(v)?;
        truth_models.push(m);
    }
    let times_s: Vec<f64> = (0..60).map(|k| 5.0 + 10.0 * k as f64).collect();
    let mut modes = Vec::new();
    for mode in [Mode::AsPublished, Mode::Paper, Mode::Exact] {
        let mut comp = TriadCompensator::new(triad.axes, triad.passports, mode);
        for (i, v) in vibs.iter().enumerate() {
            comp.set_vibration(i, v)?;
        }
        let (mut e1, mut e2, mut e4) = (0.0, 0.0, 0.0);
        for &t in &times_s {
            // Body frame: x longitudinal, small lateral accelerations from manoeuvres.
            let body = [
                cyclone4_longitudinal_g(t),
                0.05 * (t / 90.0).sin(),
                -0.03 * (t / 70.0).cos(),
            ];
            let mut readings = [0.0; 3];
            for i in 0..3 {
                readings[i] = truth_models[i]
                    .mean_output_g(triad.axes.units[i].to_unit(&body))
                    .0;
            }
            let out = comp.compensate(readings);
            for i in 0..3 {
                let truth = triad.axes.units[i].ia.project(&body);
                let s = &out.units[i];
                e1 += (s.a1_g - truth).powi(2);
                e2 += (s.a2_g - truth).powi(2);
                e4 += (s.a4_g - truth).powi(2);
            }
        }
        let n = (3 * times_s.len()) as f64;
        let (u, m, v) = ((e1 / n).sqrt(), (e2 / n).sqrt(), (e4 / n).sqrt());
        modes.push(ModeErrors {
            mode: mode.name(),
            uncompensated_rms_g: u,
            main_removed_rms_g: m,
            vibration_removed_rms_g: v,
            reduction: if v > 0.0 { u / v } else { f64::INFINITY },
        });
    }
    let report = DemoReport {
        scenario: "Cyclone-4 flight (RIG.md): 600 s, aL 1..5 g, aB3 = 0.5 g, aB1 = aB2 = 1.2 g at 12 Hz, sigma = 1.4 g",
        triad: format!("{} ({}, {}, {})", triad.id, triad.passports[0].id(), triad.passports[1].id(), triad.passports[2].id()),
        samples: times_s.len(),
        modes,
    };
    if args.json {
        return print_json(&report);
    }
    outln!("{}", report.scenario)?;
    outln!("Triad {}; {} mean readings per unit, errors against the true acceleration (RMS over the flight):", report.triad, report.samples)?;
    outln!(
        "  {:<14}{:>16}{:>18}{:>20}{:>12}",
        "mode",
        "uncompensated",
        "main removed",
        "vibration removed",
        "reduction"
    )?;
    for m in &report.modes {
        outln!(
            "  {:<14}{:>16}{:>18}{:>20}{:>12}",
            m.mode,
            fmt_g(m.uncompensated_rms_g),
            fmt_g(m.main_removed_rms_g),
            fmt_g(m.vibration_removed_rms_g),
            fmt_ratio(m.reduction)
        )?;
    }
    Ok(())
}
