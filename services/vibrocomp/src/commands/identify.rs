//! `vibrocomp identify`: shake-table identification of the VE components from test
//! positions (MODEL.md section 9) and measurement of the VE from still / vibrating /
//! still records (section 8, `identify_measure`). The maths, and the reading and validation of the CSV
//! files (every problem at once, each with its line, column, value and rule), live in
//! `vibro-ident` (`table`, `report`); this module turns the flags into a request and
//! prints a table or `--json`. See docs/identification.md.

use anyhow::Context;
use clap::{Args, Subcommand, ValueEnum};
use std::path::PathBuf;
use vibro_ident::{
    MethodChoice, MethodReport, PositionsReport, PositionsRequest, UncertaintyBasis,
};
use vibro_physics::passport::Passport;

pub use super::identify_measure::MeasureArgs;
use crate::output::{fmt_g, print_json};

#[derive(Debug, Subcommand)]
pub enum IdentifyCommand {
    /// VE components from a CSV of test positions (MODEL.md section 9, [P1 (21)-(23)]).
    Positions(PositionsArgs),
    /// The VE measured from still / vibrating / still records (MODEL.md section 8, [P2 (16)]):
    /// records by phase, or a rig's time-stamped readings with the unit's linear response
    /// removed through a reference accelerometer (`--reference`).
    Measure(MeasureArgs),
    /// A shake-table campaign from a rig's raw runs (a manifest, docs/identification.md):
    /// each unit's VE by [P2 (16)] with its linear response removed through the reference
    /// accelerometer, the vibration each unit saw from the estimator on the reference,
    /// and the lab's table (`--table-out`).
    Campaign(CampaignArgs),
}

#[derive(Debug, Args)]
pub struct CampaignArgs {
    /// The campaign manifest: TOML, or a CSV of the runs whose first line is
    /// `# vibrocomp-campaign/1` (docs/identification.md "Campaigns from raw records").
    pub manifest: PathBuf,
    /// Write the lab's table (CSV, docs/lab.md) of the campaign here.
    #[arg(long)]
    pub table_out: Option<PathBuf>,
    #[arg(long, help = crate::files::FORCE_HELP)]
    pub force: bool,
    /// The estimator's configuration for the reference (default: the shipped
    /// `config/services/estimator.toml`; its rate, sensitivity and coupling are the
    /// reference file's: g, DC-coupled).
    #[arg(long)]
    pub estimator_config: Option<PathBuf>,
    /// Print the results as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Identification method(s).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// The paper's closed form (22): the ten standard positions only.
    ClosedForm,
    /// Weighted least squares of the six components: any positions at one amplitude.
    Wls,
    /// Closed form and WLS side by side; a method that does not apply is skipped
    /// with its reason.
    Both,
    /// WLS of the passport terms (c_asym, k2..k5, m31, m32): positions at any
    /// amplitudes (two or more IA amplitudes), components evaluated at `--at-ab3-g`.
    Coefficients,
}

#[derive(Debug, Args)]
pub struct PositionsArgs {
    /// CSV of test positions: tp, angle_deg, aB3_g, aB1_g, aB2_g, u_still_v, u_vib_v
    /// and optionally u_sigma_v (standard uncertainty of dU); `#` starts a comment line.
    pub file: PathBuf,
    /// Passport file, or the id of a shipped one (AL-15, AL-1M, AKS-05); gives K1.
    #[arg(long)]
    pub passport: String,
    /// Identification method(s).
    #[arg(long, value_enum, default_value_t = MethodArg::Both)]
    pub method: MethodArg,
    /// Flight accelerations along IA at which to predict the VE by (23), g.
    #[arg(long = "at-g", num_args = 1.., allow_negative_numbers = true, default_values_t = vec![1.0, 10.0])]
    pub at_g: Vec<f64>,
    /// `--method coefficients`: IA amplitude at which to give the components, g
    /// (default: the largest IA amplitude among the positions).
    #[arg(long)]
    pub at_ab3_g: Option<f64>,
    /// `--method coefficients`: OA amplitude for d0(2), g (default: as IA, as in TP9).
    #[arg(long)]
    pub at_ab1_g: Option<f64>,
    /// `--method coefficients`: PA amplitude for d0(3), g (default: as IA, as in TP10).
    #[arg(long)]
    pub at_ab2_g: Option<f64>,
    /// Print the full results as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(cmd: IdentifyCommand) -> anyhow::Result<()> {
    match cmd {
        IdentifyCommand::Positions(args) => run_positions(args),
        IdentifyCommand::Measure(args) => super::identify_measure::run(args),
        IdentifyCommand::Campaign(args) => run_campaign(args),
    }
}

pub(super) fn load_passport(arg: &str) -> anyhow::Result<Passport> {
    vibro_config::resolve_passport(arg).with_context(|| format!("loading passport {arg:?}"))
}

fn run_positions(args: PositionsArgs) -> anyhow::Result<()> {
    // A flight acceleration's and a tone amplitude's rules (a scenario's, the
    // physics'), every bad value at once.
    let mut problems = crate::flags::FlagProblems::new();
    for a in &args.at_g {
        problems.accel_g("--at-g", *a);
    }
    for (name, value) in [
        ("--at-ab3-g", args.at_ab3_g),
        ("--at-ab1-g", args.at_ab1_g),
        ("--at-ab2-g", args.at_ab2_g),
    ] {
        if let Some(v) = value {
            problems.amplitude_g(name, v);
        }
    }
    problems.finish()?;
    let passport = load_passport(&args.passport)?;
    let request = PositionsRequest {
        method: match args.method {
            MethodArg::ClosedForm => MethodChoice::ClosedForm,
            MethodArg::Wls => MethodChoice::Wls,
            MethodArg::Both => MethodChoice::Both,
            MethodArg::Coefficients => MethodChoice::Coefficients,
        },
        at_g: args.at_g,
        at_ab3_g: args.at_ab3_g,
        at_ab1_g: args.at_ab1_g,
        at_ab2_g: args.at_ab2_g,
    };
    let report = vibro_ident::identify_positions(&args.file, &passport, &request)?;
    if args.json {
        print_json(&report)
    } else {
        print_positions(&report)
    }
}

/// A component in readable units: d0 in g with a prefix, delta(n) in ug/g^n.
fn fmt_component(i: usize, value: f64) -> String {
    match i {
        0..=2 => fmt_g(value),
        _ => format!("{:.4} ug/g{}", value * 1e6, ["", "^2", "^3"][i - 3]),
    }
}

const COMPONENT_LABELS: [&str; 6] = [
    "d0(1)", "d0(2)", "d0(3)", "delta(1)", "delta(2)", "delta(3)",
];

pub(super) fn value_pm(value: String, sigma: Option<String>) -> String {
    match sigma {
        Some(s) => format!("{value} ± {s}"),
        None => format!("{value} ± unknown"),
    }
}

fn describe_basis(basis: &UncertaintyBasis) -> String {
    match basis {
        UncertaintyBasis::Given { chi2, dof } => {
            format!("from u_sigma_v (chi2 = {chi2:.3} for {dof} dof)")
        }
        UncertaintyBasis::ResidualScatter { dof, du_sigma_v } => format!(
            "from the residual scatter: sigma(dU) = {:.3} uV ({dof} dof)",
            du_sigma_v * 1e6
        ),
        UncertaintyBasis::Unknown { reason } => format!("unknown: {reason}"),
    }
}

fn print_positions(r: &PositionsReport) -> anyhow::Result<()> {
    outln!(
        "Identification from {} ({} positions), passport {} (K1 = {} V/g)",
        r.file,
        r.n_positions,
        r.passport,
        r.k1_v_per_g
    )?;
    let mut methods: Vec<(&str, &MethodReport)> = Vec::new();
    if let Some(m) = &r.closed_form {
        methods.push(("closed form (22)", m));
    }
    if let Some(m) = &r.wls {
        methods.push(("WLS", m));
    }
    if let Some(c) = &r.coefficients {
        methods.push(("from coefficient WLS", &c.components));
    }
    if let Some(first) = methods.first() {
        let a = first.1.estimate.amplitudes;
        outln!(
            "Components at aB3 = {} g (IA), aB1 = {} g (OA, for d0(2)), aB2 = {} g (PA, for d0(3))",
            a.a_b3_g,
            a.a_b1_g,
            a.a_b2_g
        )?;
        let passport = r.passport_terms.components_at(a).to_array();
        outln!()?;
        let mut header = format!("{:<10}", "component");
        for (name, _) in &methods {
            header += &format!("  {name:<30}");
        }
        outln!("{header}  passport (section 5, lambda = 1)")?;
        for (i, label) in COMPONENT_LABELS.iter().enumerate() {
            let mut row = format!("{label:<10}");
            for (_, m) in &methods {
                let e = &m.estimate;
                let value = fmt_component(i, e.components.to_array()[i]);
                let sigma = e.sigma.map(|s| fmt_component(i, s.to_array()[i]));
                row += &format!("  {:<30}", value_pm(value, sigma));
            }
            outln!("{row}  {}", fmt_component(i, passport[i]))?;
        }
        outln!()?;
        for (name, m) in &methods {
            outln!(
                "{name}: uncertainties {}",
                describe_basis(&m.estimate.basis)
            )?;
        }
        outln!()?;
        outln!("VE predicted by (23)")?;
        let mut header = format!("{:<10}", "aL");
        for (name, _) in &methods {
            header += &format!("  {name:<30}");
        }
        outln!("{}", header.trim_end())?;
        for (k, a_l_g) in first.1.predictions.iter().map(|p| p.a_l_g).enumerate() {
            let mut row = format!("{:<10}", format!("{a_l_g} g"));
            for (_, m) in &methods {
                let p = &m.predictions[k];
                row += &format!("  {:<30}", value_pm(fmt_g(p.ve_g), p.sigma_g.map(fmt_g)));
            }
            outln!("{}", row.trim_end())?;
        }
    }
    if let Some(c) = &r.coefficients {
        let t = &c.terms;
        outln!()?;
        outln!(
            "Passport terms (coefficient WLS over IA amplitudes {:?} g; {})",
            t.a_b3_levels_g,
            describe_basis(&t.basis)
        )?;
        let units = [
            "ppm", "ppm/g", "ppm/g^2", "ppm/g^3", "ppm/g^4", "ppm/g", "ppm/g",
        ];
        let labels = [
            "c_asym = 0.637*lambda*k1*d1A",
            "k2",
            "k3",
            "k4",
            "k5",
            "m31",
            "m32",
        ];
        let x = t.terms.to_array();
        let s = t.sigma.map(|s| s.to_array());
        let p = r.passport_terms.to_array();
        for i in 0..7 {
            let value = format!("{:.4} {}", x[i] * 1e6, units[i]);
            let sigma = s.map(|s| format!("{:.4} {}", s[i] * 1e6, units[i]));
            outln!(
                "  {:<30} {:<36} passport {:.4} {}",
                labels[i],
                value_pm(value, sigma),
                p[i] * 1e6,
                units[i]
            )?;
        }
    }
    for s in &r.skipped {
        outln!()?;
        outln!("{} skipped: {}", s.method, s.reason)?;
    }
    Ok(())
}

fn run_campaign(args: CampaignArgs) -> anyhow::Result<()> {
    if let Some(out) = &args.table_out {
        crate::files::check(out, &[&args.manifest], args.force)?;
    }
    let log_args = super::lab_log::LogArgs {
        triad: "default".into(),
        estimator_config: args.estimator_config.clone(),
        batches: 8,
        max_al_span_g: 1.0,
        pool_windows: 0,
        table_out: None,
    };
    let result = super::lab_log::table_from_manifest(&args.manifest, &log_args.estimator()?)?;
    if let Some(out) = &args.table_out {
        let mut bytes = Vec::new();
        result.table.write_csv(&mut bytes)?;
        crate::files::write_bytes(out, args.force, &bytes)?;
    }
    if args.json {
        return print_json(&serde_json::json!({
            "manifest": args.manifest.display().to_string(),
            "table_out": args.table_out.as_ref().map(|p| p.display().to_string()),
            "runs": result.runs,
            "units": result.units,
        }));
    }
    outln!(
        "Campaign {}: {} runs, {} unit-runs; VE by [P2 (16)] with the linear response \
         removed through the reference (raw records beside it)",
        args.manifest.display(),
        result.runs.len(),
        result.units.len()
    )?;
    let summary = vibro_lab::inputs::ManifestSummary::new(&args.manifest, &result);
    let mut clip = String::new();
    vibro_lab::text::write_manifest_summary(&mut clip, &summary);
    if !clip.is_empty() {
        out!("{clip}")?;
    }
    outln!()?;
    outln!(
        "{:<16} {:<5} {:>7} {:>24} {:>24} {:>8} {:>8} {:>8}",
        "run",
        "unit",
        "aL3 g",
        "VE (reference removed)",
        "VE (raw records)",
        "f Hz",
        "aB3 g",
        "sig3 g"
    )?;
    for u in &result.units {
        let m = &u.measurement.measurement;
        let raw = u
            .measurement
            .raw
            .map(|r| value_pm(fmt_g(r.ve_g), Some(fmt_g(r.ve_sigma_g))))
            .unwrap_or_default();
        let c = &u.condition;
        let (f, ab3) = c
            .tone
            .map(|t| (format!("{:.2}", t.freq_hz), format!("{:.4}", t.a_b_g[2])))
            .unwrap_or_default();
        let sig3 = c
            .random
            .map(|r| format!("{:.4}", r.sigma_g[2]))
            .unwrap_or_default();
        outln!(
            "{:<16} {:<5} {:>7.3} {:>24} {:>24} {:>8} {:>8} {:>8}",
            u.run_id,
            u.unit,
            u.a_l_g[2],
            value_pm(fmt_g(m.ve_g), Some(fmt_g(m.ve_sigma_g))),
            raw,
            f,
            ab3,
            sig3
        )?;
    }
    if let Some(out) = &args.table_out {
        outln!()?;
        outln!(
            "table written: {} (vibrocomp lab diagnose {})",
            out.display(),
            out.display()
        )?;
    }
    Ok(())
}
