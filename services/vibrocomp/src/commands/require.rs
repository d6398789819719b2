//! `vibrocomp require`: allowed moduli of the passport coefficients for a VE budget
//! (MODEL.md section 10).

use crate::flags::FlagProblems;
use crate::output::{fmt_fixed, fmt_num, print_json};
use clap::{Args, ValueEnum};
use serde::Serialize;
use vibro_physics::requirements::{exact, paper, Environment, Requirement};

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum RequireMode {
    /// The paper's formulas [P2 (13), (15)].
    Paper,
    /// The same budget shares with the exact means (MODEL.md section 6).
    Exact,
}

#[derive(Debug, Args)]
pub struct RequireArgs {
    /// Allowed vibration error D*, g.
    #[arg(long = "dstar-g", allow_negative_numbers = true)]
    pub dstar_g: f64,
    /// Mean flight acceleration along IA, g.
    #[arg(long = "aL3-g", alias = "al3-g", allow_negative_numbers = true)]
    pub al3_g: f64,
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
    /// RMS random vibration along IA seen by the unit, g.
    #[arg(
        long = "sigma3-g",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub sigma3_g: f64,
    /// Which model derives the limits.
    #[arg(long, value_enum, default_value = "paper")]
    pub mode: RequireMode,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Report {
    mode: &'static str,
    dstar_g: f64,
    requirements: Vec<Requirement>,
}

pub fn run(args: RequireArgs) -> anyhow::Result<()> {
    // The flight and vibration rules of the files; `D*`'s own rule is the physics'
    // (`Environment::validate`), applied below.
    let mut problems = FlagProblems::new();
    problems.accel_g("--aL3-g", args.al3_g);
    problems.amplitude_g("--aB1-g", args.ab1_g);
    problems.amplitude_g("--aB2-g", args.ab2_g);
    problems.amplitude_g("--aB3-g", args.ab3_g);
    problems.sigma_g("--sigma3-g", args.sigma3_g);
    problems.finish()?;
    let env = Environment {
        d_star_g: args.dstar_g,
        a_l3_g: args.al3_g,
        ab_g: [args.ab1_g, args.ab2_g, args.ab3_g],
        sigma3_g: args.sigma3_g,
    };
    let (mode, requirements) = match args.mode {
        RequireMode::Paper => ("paper", paper(&env)?),
        RequireMode::Exact => ("exact", exact(&env)?),
    };
    if args.json {
        return print_json(&Report {
            mode,
            dstar_g: args.dstar_g,
            requirements,
        });
    }
    outln!(
        "Allowed coefficient moduli for D* = {} g ({mode} model)",
        fmt_num(args.dstar_g)
    )?;
    outln!(
        "  {:<16}{:>8}{:>14}  unit",
        "coefficient",
        "share",
        "allowed"
    )?;
    for r in &requirements {
        outln!(
            "  {:<16}{:>7.2}D*{:>12}  {}",
            r.coefficient,
            r.share,
            fmt_fixed(r.allowed, 4),
            r.unit
        )?;
    }
    Ok(())
}
