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
//! papers' approximations leave. The computation is `vibro_physics::report::cyclone4_flight`.

use crate::output::{fmt_g, fmt_ratio, print_json};
use clap::Args;

#[derive(Debug, Args)]
pub struct FlightArgs {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: FlightArgs) -> anyhow::Result<()> {
    let triad = vibro_config::default_triad()?;
    let [p0, p1, p2] = &triad.passports;
    let label = format!("{} ({}, {}, {})", triad.id, p0.id(), p1.id(), p2.id());
    let report = vibro_physics::report::cyclone4_flight(triad.axes, triad.passports, label)?;
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
