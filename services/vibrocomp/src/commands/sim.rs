//! `vibrocomp sim`: runs a scenario of the rig simulator (`shared/vibro-sim`).
//!
//! - A **flight** streams the vibration sensors, the accelerometers and the truth:
//!   into an MCAP log (`--out`), live over iceoryx2 at real-time rate (`--live`), or
//!   both; it always prints the mean error of each unit against the exact model.
//! - A **campaign** runs every shake-table condition (MODEL.md section 8) and prints
//!   the measured VE beside the exact and published models; `--summary-csv` writes the
//!   per-condition table the model lab reads, `--positions-csv` the test positions
//!   `vibrocomp identify positions` reads.
//!
//! Effects of the scenario can be switched off (`--no-effects`) or on and tuned
//! (`--effect kind:key=value,...`); `--list-effects` prints the library.
//!
//! A flight with `--out` stopped by SIGINT (Ctrl-C) or SIGTERM stops generating between
//! chunks, finishes the log (a valid MCAP holding every message written so far), says
//! on stderr the simulated time it reached and exits with status 1.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use indicatif::ProgressBar;
use vibro_log::flight::{FlightOutput, LivePublishers};
use vibro_service::StopSignal;
use vibro_sim::{CampaignReport, Scenario, ScenarioKind};

use crate::flags::FlagProblems;
use crate::output::{fmt_g, fmt_num, print_json};

/// What a flight made, and each unit's mean error against the exact model.
pub use vibro_log::flight::FlightReport;

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Scenario: a TOML file or a shipped id (cyclone-4, cyclone-4-short,
    /// tactical-100s, tactical-300s, section8-grid, random-runs, ten-positions,
    /// compensation-experiment-al1m, compensation-experiment-aks05, lab-walkthrough).
    #[arg(required_unless_present = "list_effects")]
    pub scenario: Option<String>,
    /// Replaces the scenario's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Replaces a flight's duration, s.
    #[arg(long = "duration-s")]
    pub duration_s: Option<f64>,
    /// Switches an effect on, with parameters: `kind` or `kind:key=value,key=value`
    /// (values in TOML syntax; `units=[0,2]` limits it to those units). Repeatable.
    #[arg(long = "effect", value_name = "KIND[:KEY=VALUE,...]")]
    pub effects: Vec<String>,
    /// Switches off every effect of the scenario (before `--effect`).
    #[arg(long)]
    pub no_effects: bool,
    /// Flight: writes the rig streams, the truth and the scenario to this MCAP log
    /// (an existing file only with --force; it appears when finished). Stopped by
    /// SIGINT/SIGTERM, the flight ends early with the log finished (valid, holding what
    /// was generated so far) and exit status 1.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Flight: publishes the rig streams over iceoryx2 at real-time rate.
    #[arg(long)]
    pub live: bool,
    /// Service-name prefix of the live streams.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Live speed as a multiple of real time.
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// Campaign: writes the per-condition summary table (CSV; an existing file only
    /// with --force).
    #[arg(long = "summary-csv")]
    pub summary_csv: Option<PathBuf>,
    /// Campaign: writes the campaign table of the model lab (docs/lab.md) for
    /// `vibrocomp lab` (an existing file only with --force).
    #[arg(long = "lab-csv")]
    pub lab_csv: Option<PathBuf>,
    /// Campaign: optional floor of the uncertainty written to `--lab-csv`, g. Each
    /// row already states its real standard uncertainty (the VE's batch means and the
    /// vibration sensor's, propagated); 0, the default, adds only
    /// `vibro_sim::campaign::Z_FLOOR_G` (1e-9 g, what a noise-free run is compared at).
    #[arg(long = "ve-resolution-g", default_value_t = 0.0)]
    pub ve_resolution_g: f64,
    /// Campaign: writes the conditions as test positions for `identify positions` (an
    /// existing file only with --force).
    #[arg(long = "positions-csv")]
    pub positions_csv: Option<PathBuf>,
    #[arg(long, help = crate::files::FORCE_HELP)]
    pub force: bool,
    /// Campaign: conditions simulated in parallel (results do not depend on it).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Prints the effects library and exits.
    #[arg(long)]
    pub list_effects: bool,
    /// Print the report (or the effects library) as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &SimArgs) -> anyhow::Result<()> {
    if args.list_effects {
        return list_effects(args.json);
    }
    let Some(arg) = args.scenario.as_deref() else {
        bail!("a scenario is required (a file or a shipped id)");
    };
    let mut scenario =
        vibro_sim::resolve_scenario(arg).with_context(|| format!("scenario {arg}"))?;
    apply_overrides(&mut scenario, args)?;
    // Every output, before anything runs (README, "Files"); the scenario file is an input.
    let inputs: Vec<&Path> = Some(Path::new(arg))
        .filter(|p| p.is_file())
        .into_iter()
        .collect();
    for out in [
        &args.out,
        &args.summary_csv,
        &args.lab_csv,
        &args.positions_csv,
    ]
    .into_iter()
    .flatten()
    {
        crate::files::check(out, &inputs, args.force)?;
    }
    match &scenario.kind {
        ScenarioKind::Flight(_) => run_flight(&scenario, args),
        ScenarioKind::Campaign(_) => run_campaign(&scenario, args),
    }
}

/// `--seed`, `--duration-s`, `--no-effects`, `--effect` (`vibro_sim::apply_overrides`);
/// the numeric flags are checked first, all at once, before anything runs.
fn apply_overrides(scenario: &mut Scenario, args: &SimArgs) -> anyhow::Result<()> {
    let mut problems = FlagProblems::new();
    // The scenario file's own rule on a flight's length.
    if let Some(d) = args.duration_s {
        problems.rule("--duration-s", d, scenario.rates.length_problem(d));
    }
    // A paced replay's rule: a 5e-324 rate would wait for ever before a message.
    problems.rate("--rate", args.rate);
    // Written to `--lab-csv` as the uncertainty's floor: the lab table's rule on an
    // uncertainty's size (0 is floored to `vibro_sim::campaign::Z_FLOOR_G`).
    let max_g = vibro_lab::table::MAX_VE_G;
    problems.check(
        "--ve-resolution-g",
        args.ve_resolution_g,
        args.ve_resolution_g.is_finite() && (0.0..=max_g).contains(&args.ve_resolution_g),
        format_args!(
            "must be finite and 0 <= resolution <= {} g (the lab table's largest uncertainty)",
            fmt_num(max_g)
        ),
    );
    problems.finish()?;
    if let (Some(d), ScenarioKind::Campaign(_)) = (args.duration_s, &scenario.kind) {
        bail!(
            "--duration-s = {}: applies to flights only; {} is a campaign",
            fmt_num(d),
            scenario.name
        );
    }
    let overrides = vibro_sim::Overrides {
        seed: args.seed,
        duration_s: args.duration_s,
        no_effects: args.no_effects,
        effects: args.effects.clone(),
    };
    vibro_sim::apply_overrides(scenario, &overrides)?;
    // Builds every enabled effect once: a bad parameter fails here, named.
    vibro_sim::scenario_effects(scenario).context("effects")?;
    Ok(())
}

fn list_effects(json: bool) -> anyhow::Result<()> {
    let list = vibro_effects::listing();
    if json {
        return print_json(&list);
    }
    for e in &list {
        outln!("{:<26} {}", e.kind, e.summary)?;
        for p in &e.params {
            outln!("    {:<24} [{}] {}", p["name"], p["unit"], p["meaning"])?;
        }
    }
    outln!("\nSwitch one on with --effect kind:key=value,...; docs/effects.md has the formulas.")?;
    Ok(())
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let template = format!("{what} {{bar:40}} {{pos}}/{{len}} ({{eta}} left)");
    crate::output::progress_bar(len, &template)
}

/// `vibro_log::flight::simulate_flight` with a progress bar, stopping between chunks
/// once `stop` has caught a signal.
fn simulate(
    scenario: &Scenario,
    out: Option<&Path>,
    live: Option<LivePublishers>,
    stop: Option<&StopSignal>,
    force: bool,
) -> anyhow::Result<FlightReport> {
    let mut bar: Option<ProgressBar> = None;
    let output = FlightOutput { out, live, force };
    let result = vibro_log::flight::simulate_flight(
        scenario,
        output,
        &|| stop.and_then(StopSignal::caught),
        &mut |done, total| {
            bar.get_or_insert_with(|| progress_bar(total, "simulating"))
                .set_position(done)
        },
    );
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    Ok(result?)
}

/// The effects of a report, or `none`.
fn effects_text(effects: &[String]) -> String {
    if effects.is_empty() {
        "none".to_string()
    } else {
        effects.join(", ")
    }
}

fn print_flight(report: &FlightReport) -> anyhow::Result<()> {
    outln!(
        "Flight {} ({}), seed {}, {:.1} s: {} sensor samples x3, {} accelerometer samples x3",
        report.scenario,
        report.file,
        report.seed,
        report.duration_s,
        report.sensor_samples,
        report.output_samples
    )?;
    outln!("  effects: {}", effects_text(&report.effects))?;
    outln!(
        "  mean error over the flight (U/K1 minus the sensed acceleration), simulated and by the exact model (no effect):"
    )?;
    outln!("  unit    simulated      exact model    of which VE     simulated - exact")?;
    for u in &report.units {
        outln!(
            "  {:<6} {:>12}  {:>12}  {:>12}  {:>12} +- {}",
            u.name,
            fmt_g(u.mean_error_g),
            fmt_g(u.exact_mean_error_g),
            fmt_g(u.exact_ve_g),
            fmt_g(u.unexplained_g),
            fmt_g(u.unexplained_sigma_g)
        )?;
    }
    outln!(
        "  generated in {:.2} s ({:.1}x real time){}",
        report.elapsed_s,
        report.real_time_factor,
        report
            .out
            .as_ref()
            .map(|p| format!("; log: {p}"))
            .unwrap_or_default()
    )?;
    Ok(())
}

fn run_flight(scenario: &Scenario, args: &SimArgs) -> anyhow::Result<()> {
    let live = match args.live {
        true => Some(LivePublishers::new(&args.prefix, args.rate)?),
        false => None,
    };
    // Only a flight into a file is worth finishing on a signal; a live-only flight
    // keeps the default action (its publishers are released when the process ends).
    let stop = args.out.as_ref().map(|_| StopSignal::install());
    let out = args.out.as_deref();
    let result = simulate(scenario, out, live, stop.as_ref(), args.force);
    drop(stop);
    let mut report = result?;
    report.live_prefix = args.live.then(|| args.prefix.clone());
    if args.json {
        return print_json(&report);
    }
    print_flight(&report)
}

/// Runs a flight scenario: into the MCAP log `out` (rig streams, truth, scenario,
/// effects, passports), live (already opened publishers), or both; returns each
/// unit's mean error against the exact model.
pub fn simulate_flight(
    scenario: &Scenario,
    out: Option<&Path>,
    live: Option<LivePublishers>,
    force: bool,
) -> anyhow::Result<FlightReport> {
    simulate(scenario, out, live, None, force)
}

fn run_campaign(scenario: &Scenario, args: &SimArgs) -> anyhow::Result<()> {
    if args.out.is_some() || args.live {
        bail!(
            "--out/--live stream a flight; {} is a campaign: use --summary-csv / --positions-csv",
            scenario.name
        );
    }
    let Some(campaign) = scenario.campaign() else {
        bail!("{} is not a campaign", scenario.name);
    };
    let bar = progress_bar(campaign.conditions.len() as u64, "conditions");
    let started = Instant::now();
    let options = vibro_sim::CampaignOptions {
        threads: args.threads.max(1),
    };
    let summaries = vibro_sim::run_campaign(scenario, &options, &mut |_| bar.inc(1))?;
    bar.finish_and_clear();
    if let Some(p) = &args.summary_csv {
        crate::files::write_file(p, args.force, |w| {
            Ok(vibro_sim::write_summary_csv(w, &summaries)?)
        })?;
    }
    if let Some(p) = &args.positions_csv {
        let comment = [format!(
            "simulated by vibrocomp sim {} (seed {})",
            scenario.name, scenario.seed
        )];
        crate::files::write_file(p, args.force, |w| {
            Ok(vibro_sim::write_positions_csv(w, &summaries, &comment)?)
        })?;
    }
    if let Some(p) = &args.lab_csv {
        // `--ve-resolution-g` was checked before the campaign ran (`apply_overrides`).
        let table =
            vibro_lab::CampaignTable::from_campaign(p, scenario, &summaries, args.ve_resolution_g)?;
        let effects: String = vibro_sim::effect_labels(scenario)
            .iter()
            .map(|e| format!(", effect {e}"))
            .collect();
        let (name, seed) = (&scenario.name, scenario.seed);
        crate::files::write_file(p, args.force, |w| {
            use std::io::Write as _;
            let what = "campaign table of the model lab (docs/lab.md)";
            writeln!(w, "# {what}: vibrocomp sim {name} (seed {seed}{effects})")?;
            Ok(table.write_csv(w)?)
        })?;
    }
    let elapsed_s = started.elapsed().as_secs_f64();
    let mut report = CampaignReport::new(scenario, &summaries, elapsed_s)
        .with_context(|| format!("{} is not a campaign", scenario.name))?;
    report.summary_csv = args.summary_csv.as_ref().map(|p| p.display().to_string());
    report.lab_csv = args.lab_csv.as_ref().map(|p| p.display().to_string());
    report.positions_csv = args.positions_csv.as_ref().map(|p| p.display().to_string());
    if args.json {
        return print_json(&report);
    }
    outln!(
        "Campaign {} ({}), passport {}, seed {}, {} conditions in {:.1} s",
        report.scenario,
        report.file,
        report.passport,
        report.seed,
        report.conditions.len(),
        report.elapsed_s
    )?;
    outln!("  effects: {}", effects_text(&report.effects))?;
    outln!("  id     angle  direction   tone            sigma3     measured VE           exact        published     z")?;
    for c in &report.conditions {
        let tone = match (c.tone_freq_hz, c.tone_amplitude_g) {
            (Some(f), Some(a)) => format!("{a:.2} g @ {f:.0} Hz"),
            _ => "-".to_string(),
        };
        outln!(
            "  {:<6} {:>5.0}  {:<10} {:<15} {:>7.3} g  {:>11} +- {:<10} {:>11}  {:>11}  {:>5.1}{}",
            c.id,
            c.angle_deg,
            c.direction,
            tone,
            c.sigma_unit_g[2],
            fmt_g(c.measured_ve_g),
            fmt_g(c.measured_ve_sigma_g),
            fmt_g(c.exact_ve_g),
            fmt_g(c.published_ve_g),
            c.z_exact,
            if c.drift_accepted {
                ""
            } else {
                "  (tilt check failed)"
            }
        )?;
    }
    Ok(())
}
