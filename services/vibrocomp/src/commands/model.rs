//! `vibrocomp model`: the vibration-error model of one accelerometer
//! (MODEL.md sections 4 to 7). The flags of a unit, its vibration and its flight
//! acceleration are [`flags`]'s; the computations are `vibro_physics::report`'s and,
//! for an extended model, `vibro_effects::report`'s.

mod flags;

use flags::check_accels;
pub use flags::{FlightArgs, VibrationArgs};

use crate::output::{fmt_g, fmt_num, print_json};
use anyhow::Context;
use clap::{Args, Subcommand, ValueEnum};
use vibro_physics::compensation::Mode;
use vibro_physics::passport::Passport;
use vibro_physics::report;
use vibro_physics::ve::VeComponents;
use vibro_physics::vibration::{PsdBand, Vibration};

#[derive(Debug, Subcommand)]
pub enum ModelCommand {
    /// VE components d0(1..3), delta(1..3), additive, multiplicative and total.
    Ve(VeArgs),
    /// The compensation algorithm [P2 (17)-(20)] on one mean reading.
    Compensate(CompensateArgs),
    /// Exact vs as-published vs Monte Carlo, side by side.
    Check(CheckArgs),
    /// The Cyclone-4 flight's mean readings from the model, compensated in every mode.
    Flight(super::model_flight::FlightArgs),
}

/// The model mode on the command line.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ModeArg {
    /// The papers' formulas as printed ([P2 (19)]'s 1.185 in compensation).
    AsPublished,
    /// The papers' formulas with the misprint fixed.
    Paper,
    /// Exact means (MODEL.md section 6).
    Exact,
}

impl From<ModeArg> for Mode {
    fn from(m: ModeArg) -> Self {
        match m {
            ModeArg::AsPublished => Mode::AsPublished,
            ModeArg::Paper => Mode::Paper,
            ModeArg::Exact => Mode::Exact,
        }
    }
}

#[derive(Debug, Args)]
pub struct VeArgs {
    #[command(flatten)]
    pub flight: FlightArgs,
    #[command(flatten)]
    pub vibration: VibrationArgs,
    /// Model mode. For the VE model as-published and paper coincide: the misprint of
    /// [P2 (19)] lives in the compensation algorithm only.
    #[arg(long, value_enum, default_value = "exact")]
    pub mode: ModeArg,
    /// An extended model (`vibrocomp lab add --out`): its base mode (which replaces
    /// `--mode`) plus its effects, each effect's VE change listed (docs/lab.md).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CompensateArgs {
    /// The unit's mean output converted with its nominal scale factor, U/K1, g.
    #[arg(long = "reading-g", allow_negative_numbers = true)]
    pub reading_g: f64,
    /// Flight acceleration along OA, from the triad's unit along OA, g.
    #[arg(long = "reading1-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub reading1_g: f64,
    /// Flight acceleration along PA, from the triad's unit along PA, g.
    #[arg(long = "reading2-g", default_value_t = 0.0)]
    #[arg(allow_negative_numbers = true)]
    pub reading2_g: f64,
    #[command(flatten)]
    pub vibration: VibrationArgs,
    /// Compensation mode.
    #[arg(long, value_enum, default_value = "exact")]
    pub mode: ModeArg,
    /// An extended model (`vibrocomp lab add --out`): its mode replaces `--mode`, the
    /// sensor effects scale the IA vibration, and the other effects' VE at a(1) is
    /// removed after (20), as the compensator service does (docs/services.md).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CheckArgs {
    #[command(flatten)]
    pub flight: FlightArgs,
    #[command(flatten)]
    pub vibration: VibrationArgs,
    /// Monte Carlo evaluations of (FP).
    #[arg(long, default_value_t = 2_000_000)]
    pub samples: u64,
    /// Monte Carlo seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(cmd: ModelCommand) -> anyhow::Result<()> {
    match cmd {
        ModelCommand::Ve(args) => ve(args),
        ModelCommand::Compensate(args) => compensate(args),
        ModelCommand::Check(args) => check(args),
        ModelCommand::Flight(args) => super::model_flight::run(args),
    }
}

/// `model ve --model`: the extended model's VE (`vibro_effects::report::extended_ve`).
fn extended_ve(
    path: &std::path::Path,
    p: &Passport,
    a_l: [f64; 3],
    (vib, psd): (&Vibration, &[PsdBand]),
    json: bool,
) -> anyhow::Result<()> {
    let report = vibro_effects::report::extended_ve(path, p, a_l, vib, psd)
        .with_context(|| spectrum_hint(vib, psd))?;
    if json {
        return print_json(&report);
    }
    outln!(
        "Vibration error of {} at aL3 = {} g, extended model {} ({} base)",
        report.passport,
        fmt_num(a_l[2]),
        report.model,
        report.mode
    )?;
    outln!("  base model             {}", fmt_g(report.base_ve_g))?;
    if report.sensor_rms_factor != 1.0 {
        outln!(
            "  (sensor RMS factor {:.6}: the IA vibration divided by it)",
            report.sensor_rms_factor
        )?;
    }
    for e in &report.effects {
        outln!("  + {:<20} {}", e.kind, fmt_g(e.ve_g))?;
    }
    outln!("  total                  {}", fmt_g(report.ve_g))?;
    Ok(())
}

/// What the extended model was evaluated with, for its errors: a random part given as
/// RMS only has no spectrum for the effects that filter the vibration to weigh.
fn spectrum_hint(vib: &Vibration, psd: &[PsdBand]) -> String {
    let random = (0..3).any(|i| vib.covariance_g2[i][i] > 0.0);
    if random && psd.is_empty() {
        "the extended model under random vibration given as RMS (--sigma*-g): an effect \
         that filters the vibration needs its spectrum; give it as a band PSD with --psd FILE"
            .into()
    } else {
        "the extended model".into()
    }
}

fn ve(args: VeArgs) -> anyhow::Result<()> {
    args.flight.check_with(&args.vibration)?;
    let (p, vib, psd) = args.vibration.resolve_with_psd()?;
    let a_l = args.flight.a_l_g()?;
    if let Some(path) = &args.model {
        return extended_ve(path, &p, a_l, (&vib, &psd), args.json);
    }
    let report = report::ve_report(&p, a_l, &vib, Mode::from(args.mode))?;
    if args.json {
        return print_json(&report);
    }
    outln!(
        "Vibration error of {} at aL3 = {} g ({} model)",
        p.id(),
        fmt_num(a_l[2]),
        report.mode
    )?;
    print_components(&[("", report.ve)], a_l[2])
}

/// A row of the component table: its label and how to read it at `aL3`.
type ComponentRow = (&'static str, fn(&VeComponents, f64) -> f64);

fn print_components(columns: &[(&str, VeComponents)], a_l3_g: f64) -> anyhow::Result<()> {
    let rows: [ComponentRow; 9] = [
        ("d0(1)", |v, _| v.d01_g),
        ("d0(2)", |v, _| v.d02_g),
        ("d0(3)", |v, _| v.d03_g),
        ("delta(1)*aL3", |v, a| v.delta1 * a),
        ("delta(2)*aL3^2", |v, a| v.delta2_per_g * a * a),
        ("delta(3)*aL3^3", |v, a| v.delta3_per_g2 * a * a * a),
        ("additive", |v, _| v.additive_g),
        ("multiplicative", |v, _| v.multiplicative_g),
        ("total VE", |v, _| v.total_g),
    ];
    if columns.len() > 1 {
        out!("  {:<16}", "")?;
        for (name, _) in columns {
            out!("{name:>16}")?;
        }
        outln!()?;
    }
    for (label, f) in rows {
        out!("  {label:<16}")?;
        for (_, v) in columns {
            out!("{:>16}", fmt_g(f(v, a_l3_g)))?;
        }
        outln!()?;
    }
    Ok(())
}

fn compensate_extended(args: &CompensateArgs, path: &std::path::Path) -> anyhow::Result<()> {
    let (p, vib, psd) = args.vibration.resolve_with_psd()?;
    let cross = [args.reading1_g, args.reading2_g];
    let report =
        vibro_effects::report::extended_compensate(path, p, (&vib, &psd), args.reading_g, cross)
            .with_context(|| spectrum_hint(&vib, &psd))?;
    if args.json {
        return print_json(&report);
    }
    outln!(
        "Compensation of {} (extended model {}, {} base), reading U/K1 = {} g",
        report.passport,
        report.model,
        report.mode,
        fmt_num(args.reading_g)
    )?;
    let s = &report.stages;
    outln!("  {:<36}{:>+.9} g", "a(1) first approximation (17)", s.a1_g)?;
    outln!("  {:<36}{:>+.9} g", "a(4) random VE removed (20)", s.a4_g)?;
    for e in &report.effects {
        outln!("    effect {:<27} {}", e.kind, fmt_g(e.ve_g))?;
    }
    outln!(
        "  {:<36}{:>+.9} g",
        "a(4) with the effects removed",
        report.a4_extended_g
    )?;
    Ok(())
}

fn compensate(args: CompensateArgs) -> anyhow::Result<()> {
    check_accels(&[
        ("--reading-g", args.reading_g),
        ("--reading1-g", args.reading1_g),
        ("--reading2-g", args.reading2_g),
    ])?;
    if let Some(path) = &args.model {
        return compensate_extended(&args, path);
    }
    let (p, vib) = args.vibration.resolve()?;
    let cross = [args.reading1_g, args.reading2_g];
    let report = report::compensate_report(p, &vib, args.mode.into(), args.reading_g, cross)?;
    if args.json {
        return print_json(&report);
    }
    outln!(
        "Compensation of {} ({} mode), reading U/K1 = {} g",
        report.passport,
        report.mode,
        fmt_num(args.reading_g)
    )?;
    let s = &report.stages;
    outln!("  {:<36}{:>+.9} g", "a(1) first approximation (17)", s.a1_g)?;
    for (label, a, correction) in [
        ("a(2) main error removed (18)", s.a2_g, s.main_g),
        ("a(3) deterministic VE removed (19)", s.a3_g, s.det_g),
        ("a(4) random VE removed (20)", s.a4_g, s.rand_g),
    ] {
        outln!(
            "  {label:<36}{a:>+.9} g   (correction {})",
            fmt_g(correction)
        )?;
    }
    Ok(())
}

fn check(args: CheckArgs) -> anyhow::Result<()> {
    let mut problems = args.flight.problems_with(&args.vibration);
    problems.count(
        "--samples",
        args.samples,
        vibro_physics::montecarlo::samples_problem(args.samples),
    );
    problems.finish()?;
    let (p, vib) = args.vibration.resolve()?;
    let a_l = args.flight.a_l_g()?;
    let report = report::check_report(&p, a_l, &vib, args.samples, args.seed)?;
    if args.json {
        return print_json(&report);
    }
    let (exact, as_published, mc) = (report.exact, report.as_published, &report.monte_carlo);
    outln!("Model check of {} at aL3 = {} g", p.id(), fmt_num(a_l[2]))?;
    print_components(&[("as published", as_published), ("exact", exact)], a_l[2])?;
    outln!(
        "  Monte Carlo of (FP): {} +- {} ({} samples, seed {})",
        fmt_g(mc.ve_g),
        fmt_g(mc.std_error_g),
        mc.samples,
        mc.seed
    )?;
    outln!(
        "  departure from Monte Carlo: as published {:+.1} standard errors, exact {:+.1}",
        report.as_published_z,
        report.exact_z
    )?;
    Ok(())
}
