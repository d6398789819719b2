//! `vibrocomp model`: the vibration-error model of one accelerometer
//! (MODEL.md sections 4 to 7).

use crate::flags::FlagProblems;
use crate::output::{fmt_g, fmt_num, print_json};
use anyhow::Context;
use clap::{Args, Subcommand, ValueEnum};
use serde::Serialize;
use std::path::PathBuf;
use vibro_physics::compensation::{Mode, Stages, UnitCompensator};
use vibro_physics::exact::exact_ve;
use vibro_physics::montecarlo::{monte_carlo_ve, MonteCarloVe};
use vibro_physics::passport::Passport;
use vibro_physics::ve::{published, VeComponents};
use vibro_physics::vibration::rules;
use vibro_physics::vibration::{Tone, Vibration};

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

/// The unit and the vibration it sees, in its own axes (1 = OA, 2 = PA, 3 = IA).
#[derive(Debug, Args)]
pub struct VibrationArgs {
    /// Passport: a TOML file or a shipped id (AL-15, AL-1M, AKS-05).
    #[arg(long)]
    pub passport: String,
    /// Deterministic vibration amplitude along IA, g.
    #[arg(
        long = "aB3-g",
        alias = "ab3-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub ab3_g: f64,
    /// Deterministic vibration amplitude along OA, g.
    #[arg(
        long = "aB1-g",
        alias = "ab1-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub ab1_g: f64,
    /// Deterministic vibration amplitude along PA, g.
    #[arg(
        long = "aB2-g",
        alias = "ab2-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub ab2_g: f64,
    /// Vibration frequency, Hz (selects lambda(f) from the passport; 0 means lambda = 1).
    #[arg(long = "freq-hz", default_value_t = 0.0, allow_negative_numbers = true)]
    pub freq_hz: f64,
    /// Phase of the IA vibration relative to OA, phi3 - phi1, deg (the papers take 0).
    #[arg(
        long = "phase31-deg",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub phase31_deg: f64,
    /// Phase of the IA vibration relative to PA, phi3 - phi2, deg.
    #[arg(
        long = "phase32-deg",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub phase32_deg: f64,
    /// RMS of broadband random vibration along IA, g.
    #[arg(
        long = "sigma3-g",
        conflicts_with = "psd",
        allow_negative_numbers = true
    )]
    pub sigma3_g: Option<f64>,
    /// RMS of broadband random vibration along OA, g.
    #[arg(
        long = "sigma1-g",
        conflicts_with = "psd",
        allow_negative_numbers = true
    )]
    pub sigma1_g: Option<f64>,
    /// RMS of broadband random vibration along PA, g.
    #[arg(
        long = "sigma2-g",
        conflicts_with = "psd",
        allow_negative_numbers = true
    )]
    pub sigma2_g: Option<f64>,
    /// Covariance K_31(0) of the random vibration along IA and OA, g^2.
    #[arg(
        long = "cov31-g2",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub cov31_g2: f64,
    /// Covariance K_32(0) of the random vibration along IA and PA, g^2.
    #[arg(
        long = "cov32-g2",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub cov32_g2: f64,
    /// Band PSD table (CSV: f_lo_hz, f_hi_hz, psd3_g2_per_hz [, psd1.., psd2..]) instead of
    /// the sigmas, e.g. config/vibration/p1-table3.csv.
    #[arg(long)]
    pub psd: Option<PathBuf>,
    /// Kurtosis of the random vibration along IA (3 = Gaussian).
    #[arg(
        long = "kurtosis3",
        default_value_t = 3.0,
        allow_negative_numbers = true
    )]
    pub kurtosis3: f64,
}

impl VibrationArgs {
    /// The rules of a vibration file on each flag, every problem at once; the rules
    /// across flags (a covariance within the sigmas) are `Vibration::validate`'s.
    fn check_flags(&self) -> anyhow::Result<()> {
        let mut p = FlagProblems::new();
        self.check_into(&mut p);
        p.finish()
    }

    fn check_into(&self, p: &mut FlagProblems) {
        p.amplitude_g("--aB1-g", self.ab1_g);
        p.amplitude_g("--aB2-g", self.ab2_g);
        p.amplitude_g("--aB3-g", self.ab3_g);
        p.rule("--freq-hz", self.freq_hz, rules::freq_hz(self.freq_hz));
        p.rule(
            "--phase31-deg",
            self.phase31_deg,
            rules::phase(self.phase31_deg),
        );
        p.rule(
            "--phase32-deg",
            self.phase32_deg,
            rules::phase(self.phase32_deg),
        );
        for (flag, sigma) in [
            ("--sigma1-g", self.sigma1_g),
            ("--sigma2-g", self.sigma2_g),
            ("--sigma3-g", self.sigma3_g),
        ] {
            if let Some(s) = sigma {
                p.sigma_g(flag, s);
            }
        }
        p.rule(
            "--cov31-g2",
            self.cov31_g2,
            rules::covariance_g2(self.cov31_g2),
        );
        p.rule(
            "--cov32-g2",
            self.cov32_g2,
            rules::covariance_g2(self.cov32_g2),
        );
        p.rule(
            "--kurtosis3",
            self.kurtosis3,
            rules::kurtosis(self.kurtosis3),
        );
    }

    /// Validates the flags into a passport and a vibration description.
    fn resolve(&self) -> anyhow::Result<(Passport, Vibration)> {
        self.check_flags()?;
        let passport = vibro_config::resolve_passport(&self.passport)?;
        let mut vib = Vibration::none();
        if self.ab1_g != 0.0 || self.ab2_g != 0.0 || self.ab3_g != 0.0 {
            vib.push_tone(Tone {
                freq_hz: self.freq_hz,
                amplitude_g: [self.ab1_g, self.ab2_g, self.ab3_g],
                // Only the differences phi3 - phi1 and phi3 - phi2 matter: set phi3 = 0.
                phase_rad: [
                    -self.phase31_deg.to_radians(),
                    -self.phase32_deg.to_radians(),
                    0.0,
                ],
            })?;
        }
        if let Some(path) = &self.psd {
            let bands = vibro_config::load_psd_table(path)?;
            vib.set_random_from_psd(&bands);
        } else {
            for (i, s) in [self.sigma1_g, self.sigma2_g, self.sigma3_g]
                .iter()
                .enumerate()
            {
                let s = s.unwrap_or(0.0);
                anyhow::ensure!(
                    s.is_finite() && s >= 0.0,
                    "--sigma{}-g = {s}: must be finite and >= 0",
                    i + 1
                );
                vib.covariance_g2[i][i] = s * s;
            }
        }
        vib.covariance_g2[2][0] = self.cov31_g2;
        vib.covariance_g2[0][2] = self.cov31_g2;
        vib.covariance_g2[2][1] = self.cov32_g2;
        vib.covariance_g2[1][2] = self.cov32_g2;
        vib.kurtosis[2] = self.kurtosis3;
        vib.validate().context("the vibration flags")?;
        Ok((passport, vib))
    }
}

/// Flight acceleration along the unit's axes.
#[derive(Debug, Args)]
pub struct FlightArgs {
    /// Flight acceleration along IA, g.
    #[arg(long = "aL3-g", alias = "al3-g", allow_negative_numbers = true)]
    pub al3_g: f64,
    /// Flight acceleration along OA, g.
    #[arg(
        long = "aL1-g",
        alias = "al1-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub al1_g: f64,
    /// Flight acceleration along PA, g.
    #[arg(
        long = "aL2-g",
        alias = "al2-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub al2_g: f64,
}

/// Rejects every flight acceleration outside the rule, naming the flag, its value and
/// the rule.
fn check_accels(flags: &[(&str, f64)]) -> anyhow::Result<()> {
    let mut p = FlagProblems::new();
    for (name, v) in flags {
        p.accel_g(name, *v);
    }
    p.finish()
}

impl FlightArgs {
    /// The flight and the vibration flags' problems, all at once.
    fn check_with(&self, vibration: &VibrationArgs) -> anyhow::Result<()> {
        self.problems_with(vibration).finish()
    }

    /// The flight and the vibration flags' problems, for more to be added.
    fn problems_with(&self, vibration: &VibrationArgs) -> FlagProblems {
        let mut p = FlagProblems::new();
        for (name, v) in [
            ("--aL1-g", self.al1_g),
            ("--aL2-g", self.al2_g),
            ("--aL3-g", self.al3_g),
        ] {
            p.accel_g(name, v);
        }
        vibration.check_into(&mut p);
        p
    }

    fn a_l_g(&self) -> anyhow::Result<[f64; 3]> {
        check_accels(&[
            ("--aL1-g", self.al1_g),
            ("--aL2-g", self.al2_g),
            ("--aL3-g", self.al3_g),
        ])?;
        Ok([self.al1_g, self.al2_g, self.al3_g])
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
    #[arg(
        long = "reading1-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub reading1_g: f64,
    /// Flight acceleration along PA, from the triad's unit along PA, g.
    #[arg(
        long = "reading2-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
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

#[derive(Serialize)]
struct VeReport<'a> {
    passport: &'a str,
    mode: &'static str,
    a_l_g: [f64; 3],
    #[serde(flatten)]
    ve: VeComponents,
}

fn ve_components(
    p: &Passport,
    a_l: [f64; 3],
    vib: &Vibration,
    mode: Mode,
) -> anyhow::Result<VeComponents> {
    Ok(match mode {
        Mode::Exact => exact_ve(p, a_l, vib)?,
        // The VE model of [P1 (13)-(16)] has no misprint: both published modes use it.
        Mode::AsPublished | Mode::Paper => {
            published(p, a_l, vib, vibro_physics::ve::Constants::PAPER)
        }
    })
}

#[derive(Serialize)]
struct ExtendedVeReport<'a> {
    passport: &'a str,
    model: String,
    mode: &'static str,
    a_l_g: [f64; 3],
    base_ve_g: f64,
    sensor_rms_factor: f64,
    effects: Vec<EffectVe>,
    ve_g: f64,
}

#[derive(Serialize)]
struct EffectVe {
    kind: String,
    ve_g: f64,
}

/// `model ve --model`: the extended model's VE (vibro_effects::predict, steady state).
fn extended_ve(
    path: &std::path::Path,
    p: &Passport,
    a_l: [f64; 3],
    vib: &Vibration,
    json: bool,
) -> anyhow::Result<()> {
    let model = vibro_effects::LabModel::load(path)?;
    let flat = vibro_effects::predict::flat_passport(p)?;
    let effects = model.build_effects(&flat)?;
    let pred =
        vibro_effects::predict_ve(model.mode, &effects, &flat, a_l, vib, &[], f64::INFINITY)?;
    let report = ExtendedVeReport {
        passport: p.id(),
        model: path.display().to_string(),
        mode: model.mode.name(),
        a_l_g: a_l,
        base_ve_g: pred.base_ve_g,
        sensor_rms_factor: pred.sensor_rms_factor,
        effects: pred
            .effects
            .iter()
            .map(|(kind, ve_g)| EffectVe {
                kind: kind.clone(),
                ve_g: *ve_g,
            })
            .collect(),
        ve_g: pred.ve_g,
    };
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

fn ve(args: VeArgs) -> anyhow::Result<()> {
    args.flight.check_with(&args.vibration)?;
    let (p, vib) = args.vibration.resolve()?;
    let a_l = args.flight.a_l_g()?;
    if let Some(path) = &args.model {
        return extended_ve(path, &p, a_l, &vib, args.json);
    }
    let mode = Mode::from(args.mode);
    let ve = ve_components(&p, a_l, &vib, mode)?;
    if args.json {
        return print_json(&VeReport {
            passport: p.id(),
            mode: mode.name(),
            a_l_g: a_l,
            ve,
        });
    }
    outln!(
        "Vibration error of {} at aL3 = {} g ({} model)",
        p.id(),
        fmt_num(a_l[2]),
        mode.name()
    )?;
    print_components(&[("", ve)], a_l[2])?;
    Ok(())
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

#[derive(Serialize)]
struct CompensateReport<'a> {
    passport: &'a str,
    mode: &'static str,
    reading_g: f64,
    #[serde(flatten)]
    stages: Stages,
}

#[derive(Serialize)]
struct ExtendedCompensateReport<'a> {
    passport: &'a str,
    model: String,
    mode: &'static str,
    reading_g: f64,
    #[serde(flatten)]
    stages: Stages,
    sensor_rms_factor: f64,
    effects: Vec<EffectVe>,
    /// a(4) with the extended model's effects removed too.
    a4_extended_g: f64,
}

fn compensate_extended(args: &CompensateArgs, path: &std::path::Path) -> anyhow::Result<()> {
    let (p, vib) = args.vibration.resolve()?;
    let lab = vibro_effects::LabModel::load(path)?;
    let mode = match lab.mode {
        vibro_effects::BaseMode::Exact => Mode::Exact,
        vibro_effects::BaseMode::Paper => Mode::Paper,
        vibro_effects::BaseMode::AsPublished => Mode::AsPublished,
    };
    let flat = vibro_effects::predict::flat_passport(&p)?;
    let effects = lab.build_effects(&flat)?;
    let cross = [args.reading1_g, args.reading2_g];
    let truth = vibro_effects::predict::true_vibration(
        &effects,
        &flat,
        [cross[0], cross[1], args.reading_g],
        &vib,
        &[],
    )?;
    let (factor, vib_true) = (truth.sensor_rms_factor, truth.vibration);
    let mut unit = UnitCompensator::new(p, mode);
    unit.set_vibration(&vib_true)?;
    let stages = unit.compensate(args.reading_g, cross);
    let parts = vibro_effects::predict::effect_shifts_g(
        &effects,
        &flat,
        [cross[0], cross[1], stages.a1_g],
        &vib_true,
        &[],
        f64::INFINITY,
    )?;
    let total: f64 = parts.iter().map(|(_, v)| v).sum();
    let report = ExtendedCompensateReport {
        passport: p.id(),
        model: path.display().to_string(),
        mode: mode.name(),
        reading_g: args.reading_g,
        stages,
        sensor_rms_factor: factor,
        effects: parts
            .into_iter()
            .map(|(kind, ve_g)| EffectVe { kind, ve_g })
            .collect(),
        a4_extended_g: stages.a4_g - total,
    };
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
    let mode = Mode::from(args.mode);
    let mut unit = UnitCompensator::new(p, mode);
    unit.set_vibration(&vib)?;
    let stages = unit.compensate(args.reading_g, [args.reading1_g, args.reading2_g]);
    if args.json {
        return print_json(&CompensateReport {
            passport: p.id(),
            mode: mode.name(),
            reading_g: args.reading_g,
            stages,
        });
    }
    outln!(
        "Compensation of {} ({} mode), reading U/K1 = {} g",
        p.id(),
        mode.name(),
        fmt_num(args.reading_g)
    )?;
    let s = &stages;
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

#[derive(Serialize)]
struct CheckReport<'a> {
    passport: &'a str,
    a_l_g: [f64; 3],
    exact: VeComponents,
    as_published: VeComponents,
    monte_carlo: MonteCarloVe,
    /// (exact - Monte Carlo) / standard error.
    exact_z: f64,
    /// (as published - Monte Carlo) / standard error.
    as_published_z: f64,
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
    let exact = ve_components(&p, a_l, &vib, Mode::Exact)?;
    let as_published = ve_components(&p, a_l, &vib, Mode::AsPublished)?;
    let mc = monte_carlo_ve(&p, a_l, &vib, args.samples, args.seed)?;
    let z = |v: f64| {
        if mc.std_error_g > 0.0 {
            (v - mc.ve_g) / mc.std_error_g
        } else {
            f64::NAN
        }
    };
    let report = CheckReport {
        passport: p.id(),
        a_l_g: a_l,
        exact,
        as_published,
        monte_carlo: mc,
        exact_z: z(exact.total_g),
        as_published_z: z(as_published.total_g),
    };
    if args.json {
        return print_json(&report);
    }
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
