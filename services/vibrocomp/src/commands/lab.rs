//! `vibrocomp lab`: compare the VE model with a campaign, find the missing physical
//! effect, fit it and add it to the model (`vibro_lab`, docs/lab.md).

use crate::output::{print_json, print_text};
use std::fmt::Write as _;

/// Appends a line to the output text (printed at once at the end, so that a closed
/// pipe ends it quietly).
macro_rules! p {
    ($o:expr) => {{
        let _ = writeln!($o);
    }};
    ($o:expr, $($arg:tt)*) => {{
        let _ = writeln!($o, $($arg)*);
    }};
}
use super::lab_log::{table_from_log, LogArgs, LogTableSummary};
use anyhow::Context;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use vibro_lab::diagnose::Progress;
use vibro_lab::diagnose::{Diagnosis, Verdict};
use vibro_lab::{BaseMode, CampaignTable, Comparison, DiagnoseOptions, LabModel};

#[derive(Debug, Subcommand)]
pub enum LabCommand {
    /// Measured against predicted VE per condition, the residual, chi-square, and the
    /// residual grouped by each condition variable.
    Compare(CompareArgs),
    /// Where the model fails, and which effect of the library is missing.
    Diagnose(DiagnoseArgs),
    /// Fit an effect to the campaign and write the extended model.
    Add(AddArgs),
    /// A self-contained HTML report with plots: the residuals before and after the
    /// effects the lab adds, the candidates' ranking, the error falling.
    Report(ReportArgs),
}

#[derive(Debug, Args)]
pub struct ReportArgs {
    #[command(flatten)]
    pub input: Input,
    /// The folder to write `index.html` (and the plots as SVG files) into.
    #[arg(long)]
    pub out: PathBuf,
    /// At most this many effects added, one at a time while one is supported.
    #[arg(long, default_value_t = 3)]
    pub max_effects: usize,
}

/// The input and the model, shared by the lab's commands.
#[derive(Debug, Args)]
pub struct Input {
    /// The campaign table (CSV, docs/lab.md), e.g. from `vibrocomp sim CAMPAIGN
    /// --lab-csv`, or an MCAP log with a reference (`.mcap`: a flight cut into the
    /// estimator's windows, docs/lab.md "Logs as input").
    pub input: PathBuf,
    /// The model to compare: an extended model file (`lab add --out`); default the
    /// model of MODEL.md, exact mode.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Without `--model`: the base model's mode (MODEL.md 6 exact, 5 paper or
    /// as-published). A model file sets its own.
    #[arg(long, value_enum, default_value = "exact", conflicts_with = "model")]
    pub mode: super::model::ModeArg,
    #[command(flatten)]
    pub log: LogArgs,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CompareArgs {
    #[command(flatten)]
    pub input: Input,
    /// Print every condition (default: the 10 largest residuals).
    #[arg(long)]
    pub all: bool,
}

#[derive(Debug, Args)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    pub input: Input,
    /// Only these candidates (comma-separated kinds; default the whole library).
    #[arg(long, value_delimiter = ',')]
    pub effects: Vec<String>,
}

#[derive(Debug, Args)]
pub struct AddArgs {
    /// The effect to fit and add (a kind of the lab's library, see `lab diagnose`).
    pub effect: String,
    /// The campaign table (or MCAP log with a reference) to fit it to.
    #[arg(long)]
    pub from: PathBuf,
    #[command(flatten)]
    pub log: LogArgs,
    /// The model to extend (default the model of MODEL.md, exact mode).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Where to write the extended model.
    #[arg(long)]
    pub out: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

fn base_mode(m: super::model::ModeArg) -> BaseMode {
    use super::model::ModeArg;
    match m {
        ModeArg::Exact => BaseMode::Exact,
        ModeArg::Paper => BaseMode::Paper,
        ModeArg::AsPublished => BaseMode::AsPublished,
    }
}

pub fn run(cmd: &LabCommand) -> anyhow::Result<()> {
    let (name, result) = match cmd {
        LabCommand::Compare(a) => ("compare", compare(a)),
        LabCommand::Diagnose(a) => ("diagnose", diagnose(a)),
        LabCommand::Add(a) => ("add", add(a)),
        LabCommand::Report(a) => ("report", report(a)),
    };
    // Errors open with the command the user typed (`lab diagnose: campaign.csv: ...`),
    // not with what the library was doing. A closed stdout stays a quiet exit.
    result.map_err(|e| {
        if crate::output::is_stdout_closed(&e) {
            e
        } else {
            e.context(format!("lab {name}"))
        }
    })
}

/// What the lab read: the model, the table, and for an MCAP log what became of its
/// windows.
struct Loaded {
    model: LabModel,
    table: CampaignTable,
    log: Option<LogTableSummary>,
}

fn load(
    input: &Path,
    model: Option<&Path>,
    mode: BaseMode,
    log_args: &LogArgs,
) -> anyhow::Result<Loaded> {
    let model = match model {
        Some(p) => LabModel::load(p)?,
        None => LabModel::base(mode),
    };
    let is_mcap = input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    if is_mcap {
        let (table, summary) = table_from_log(input, &model, log_args)?;
        return Ok(Loaded {
            model,
            table,
            log: Some(summary),
        });
    }
    let table = CampaignTable::load(input, &model)?;
    Ok(Loaded {
        model,
        table,
        log: None,
    })
}

/// A progress bar over the candidates' fits (a long log's diagnosis takes minutes),
/// on a terminal only: redirected stderr (scripts, tests) stays clean.
fn fit_progress() -> (ProgressBar, Progress) {
    if !std::io::stderr().is_terminal() {
        return (ProgressBar::hidden(), Progress::default());
    }
    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template("fitting candidates {bar:30} {pos}/{len} {msg}")
    {
        bar.set_style(style);
    }
    bar.set_message("(the library's effects to the residual)");
    let shown = bar.clone();
    let progress = Progress(Some(std::sync::Arc::new(
        move |done: usize, of: usize, kind: &str| {
            shown.set_length(of as u64);
            shown.set_position(done as u64);
            shown.set_message(format!("({kind} done)"));
        },
    )));
    (bar, progress)
}

/// One line on what became of a log's windows.
fn print_log_summary(o: &mut String, s: &LogTableSummary) {
    p!(
        o,
        "{}: {} conditions from {} of {} estimator windows ({} s, units {}, passports from {}); \
         left out: {} flagged, {} incomplete, {} with aL changing",
        s.log,
        s.conditions,
        s.windows_used,
        s.windows,
        s.estimator_window_s,
        s.units.join(", "),
        s.passports_from,
        s.left_out_flagged,
        s.left_out_incomplete,
        s.left_out_al_span
    );
}

/// A command's JSON with the log's summary beside it when the input was a log.
#[derive(serde::Serialize)]
struct WithLog<'a, T: serde::Serialize> {
    #[serde(flatten)]
    inner: &'a T,
    #[serde(skip_serializing_if = "Option::is_none")]
    log: Option<&'a LogTableSummary>,
}

fn print_json_with_log<T: serde::Serialize>(
    inner: &T,
    log: Option<&LogTableSummary>,
) -> anyhow::Result<()> {
    print_json(&WithLog { inner, log })
}

fn g(x: f64) -> String {
    format!("{x:>11.3e}")
}

fn print_comparison(o: &mut String, c: &Comparison, all: bool) {
    let s = &c.summary;
    let effects = if c.effects.is_empty() {
        "none".to_string()
    } else {
        c.effects.join(", ")
    };
    p!(
        o,
        "{}: {} conditions; model {} mode, effects: {}",
        c.table,
        s.n,
        c.mode,
        effects
    );
    p!(
        o,
        "residual RMS {:.3e} g (max {:.3e} g), measured VE RMS {:.3e} g, noise floor {:.3e} g",
        s.rms_residual_g,
        s.max_abs_residual_g,
        s.rms_measured_g,
        s.noise_floor_g
    );
    p!(
        o,
        "chi2 {:.4} for {} dof: {:.4} per dof, p = {:.3e}",
        s.chi2,
        s.dof,
        s.chi2_per_dof,
        s.p_value
    );
    let mut rows: Vec<_> = c.rows.iter().collect();
    if !all {
        rows.sort_by(|a, b| b.z.abs().total_cmp(&a.z.abs()));
        rows.truncate(10);
        p!(o, "\nlargest residuals (--all for every condition):");
    } else {
        p!(o);
    }
    p!(
        o,
        "{:<10} {:>5} {:>11} {:>11} {:>11} {:>11} {:>10}",
        "run_id",
        "line",
        "measured_g",
        "u_g",
        "predicted_g",
        "residual_g",
        "z"
    );
    for r in rows {
        p!(
            o,
            "{:<10} {:>5} {} {} {} {} {:>10.2}",
            r.run_id,
            r.line,
            g(r.measured_g),
            g(r.uncertainty_g),
            g(r.predicted_g),
            g(r.residual_g),
            r.z
        );
    }
    p!(
        o,
        "\nresidual by condition variable (RMS residual per group, g):"
    );
    for v in &c.by_variable {
        let groups: Vec<String> = v
            .groups
            .iter()
            .map(|gr| format!("{} ({}): {:.2e}", gr.label, gr.n, gr.rms_residual_g))
            .collect();
        p!(o, "  {:<12} {}", v.variable, groups.join("; "));
    }
}

fn compare(a: &CompareArgs) -> anyhow::Result<()> {
    let Loaded { model, table, log } = load(
        &a.input.input,
        a.input.model.as_deref(),
        base_mode(a.input.mode),
        &a.input.log,
    )?;
    let c = vibro_lab::compare(&model, &table)?;
    if a.input.json {
        return print_json_with_log(&c, log.as_ref());
    }
    let mut o = String::new();
    if let Some(s) = &log {
        print_log_summary(&mut o, s);
    }
    print_comparison(&mut o, &c, a.all);
    print_text(&o)
}

fn params_text(params: &[vibro_lab::fit::FittedParam]) -> String {
    params
        .iter()
        .map(|p| {
            if p.sigma.is_finite() {
                format!("{} = {:.6e} +- {:.2e}", p.name, p.value, p.sigma)
            } else {
                format!(
                    "{} = {:.6e} (not determined by this table)",
                    p.name, p.value
                )
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn print_diagnosis(o: &mut String, d: &Diagnosis) {
    let s = &d.comparison.summary;
    p!(
            o,
        "{}: {} conditions; residual RMS {:.3e} g against a noise floor of {:.3e} g; chi2 per dof {:.4}, p = {:.3e}",
        d.comparison.table, s.n, s.rms_residual_g, s.noise_floor_g, s.chi2_per_dof, s.p_value
    );
    p!(
        o,
        "\nwhere the residual goes (weighted quadratic in each variable, F-test):"
    );
    for t in d.trends.iter().take(8) {
        p!(
            o,
            "  {:<12} explains {:>6.1} % of the residual, p = {:.2e} ({} values)",
            t.variable,
            100.0 * t.explained_fraction,
            t.p_value,
            t.distinct_values
        );
    }
    if let Some(l) = &d.lack_of_fit {
        p!(
            o,
            "lack of fit over {} repeated conditions: F = {:.3}, p = {:.3e}; pure error chi2 per dof {:.3}",
            l.repeated_groups, l.f, l.p_value, l.pure_error_chi2_per_dof
        );
    }
    p!(o, "\ncandidates, best first (delta BIC < -10: supported):");
    p!(
        o,
        "  {:<24} {:>14} {:>12} {:>12}  parameters",
        "effect",
        "delta_bic",
        "rms_after_g",
        "chi2/dof"
    );
    for c in &d.candidates {
        match &c.fit {
            Some(f) => p!(
                o,
                "  {:<24} {:>14.1} {} {:>12.3}  {}",
                c.kind,
                f.delta_bic,
                g(f.rms_residual_after_g),
                f.chi2_per_dof_after,
                params_text(&f.params)
            ),
            None => p!(
                o,
                "  {:<24} not applicable: {}",
                c.kind,
                c.not_applicable.as_deref().unwrap_or("")
            ),
        }
    }
    p!(o);
    match &d.verdict {
        Verdict::Noise {
            p_value,
            chi2_per_dof,
        } => p!(
            o,
            "Verdict: the model agrees with the measurements within their uncertainty \
             (chi2 per dof {chi2_per_dof:.3}, p = {p_value:.3}): no effect is missing that this \
             campaign can see."
        ),
        Verdict::Effect {
            kind,
            params,
            delta_bic,
            rms_residual_before_g,
            rms_residual_after_g,
            physics,
        } => {
            p!(
                o,
                "Verdict: missing effect `{kind}` (delta BIC {delta_bic:.1})."
            );
            p!(o, "  fitted: {}", params_text(params));
            p!(
            o,
                "  residual RMS {rms_residual_before_g:.3e} g -> {rms_residual_after_g:.3e} g with it"
            );
            p!(o, "  physics: {physics}");
            p!(
                o,
                "  add it: vibrocomp lab add {kind} --from {} --out model.toml",
                d.comparison.table
            );
        }
        Verdict::Confounded {
            kinds,
            correlation,
            suggestions,
        } => {
            p!(
                o,
                "Verdict: confounded. {} explain the residual equally well (their fitted VE \
                 changes correlate at {correlation:.4} over this campaign): this campaign \
                 cannot tell them apart.",
                kinds.join(" and ")
            );
            p!(o, "  add conditions where they differ most:");
            for s in suggestions {
                let preds: Vec<String> = s
                    .predictions_g
                    .iter()
                    .map(|(k, v)| format!("{k} {v:.3e} g"))
                    .collect();
                p!(
                    o,
                    "  - {}: {} ({:.0} sigma apart)",
                    s.description,
                    preds.join(", "),
                    s.separation_sigma
                );
            }
        }
        Verdict::Unexplained {
            chi2_per_dof,
            variables,
            best,
            best_explained_fraction,
        } => {
            p!(
                o,
                "Verdict: unexplained structure (chi2 per dof {chi2_per_dof:.3}): no effect of \
                 the library explains it."
            );
            if !variables.is_empty() {
                p!(o, "  the residual follows: {}", variables.join(", "));
            }
            if let Some(b) = best {
                p!(
                    o,
                    "  the best candidate, {b}, would explain only {:.1} % of the chi-square: \
                     not attributed",
                    100.0 * best_explained_fraction
                );
            }
        }
    }
}

fn diagnose(a: &DiagnoseArgs) -> anyhow::Result<()> {
    let Loaded { model, table, log } = load(
        &a.input.input,
        a.input.model.as_deref(),
        base_mode(a.input.mode),
        &a.input.log,
    )?;
    let (bar, progress) = fit_progress();
    let opts = DiagnoseOptions {
        candidates: a.effects.clone(),
        progress,
        ..DiagnoseOptions::default()
    };
    let d = vibro_lab::diagnose(&model, &table, &opts);
    bar.finish_and_clear();
    let d = d?;
    if a.input.json {
        return print_json_with_log(&d, log.as_ref());
    }
    let mut o = String::new();
    if let Some(s) = &log {
        print_log_summary(&mut o, s);
    }
    print_diagnosis(&mut o, &d);
    print_text(&o)
}

#[derive(serde::Serialize)]
struct AddReport<'a> {
    out: String,
    effects: Vec<String>,
    fit: &'a vibro_lab::EffectFit,
}

fn add(a: &AddArgs) -> anyhow::Result<()> {
    let Loaded { model, table, log } = load(&a.from, a.model.as_deref(), BaseMode::Exact, &a.log)?;
    let (extended, fit) = vibro_lab::add_effect(&model, &table, &a.effect)?;
    extended
        .save(&a.out)
        .with_context(|| format!("{}: cannot write the extended model", a.out.display()))?;
    if a.json {
        return print_json_with_log(
            &AddReport {
                out: a.out.display().to_string(),
                effects: extended.effect_kinds(),
                fit: &fit,
            },
            log.as_ref(),
        );
    }
    let mut o = String::new();
    if let Some(s) = &log {
        print_log_summary(&mut o, s);
    }
    p!(
        o,
        "{} fitted to {} ({} conditions): {}",
        fit.kind,
        table.path.display(),
        fit.n,
        params_text(&fit.params)
    );
    p!(
        o,
        "residual RMS {:.3e} g -> {:.3e} g, chi2 per dof {:.4} -> {:.4}, delta BIC {:.1}",
        fit.rms_residual_before_g,
        fit.rms_residual_after_g,
        fit.chi2_before / fit.n as f64,
        fit.chi2_per_dof_after,
        fit.delta_bic
    );
    p!(
        o,
        "wrote {} (effects: {})",
        a.out.display(),
        extended.effect_kinds().join(", ")
    );
    print_text(&o)
}

fn report(a: &ReportArgs) -> anyhow::Result<()> {
    let Loaded { model, table, log } = load(
        &a.input.input,
        a.input.model.as_deref(),
        base_mode(a.input.mode),
        &a.input.log,
    )?;
    let (bar, progress) = fit_progress();
    let opts = DiagnoseOptions {
        progress,
        ..DiagnoseOptions::default()
    };
    let diagnosis = vibro_lab::diagnose(&model, &table, &opts)?;
    let mut text = String::new();
    print_diagnosis(&mut text, &diagnosis);
    let (ladder, extended) =
        vibro_lab::diagnose::ladder_from(&model, &table, &opts, a.max_effects, Some(&diagnosis))?;
    bar.finish_and_clear();
    let after = vibro_lab::compare(&extended, &table)?;
    let summary = super::lab_report::write(
        &a.out,
        &super::lab_report::ReportInput {
            table: &table,
            model: &model,
            diagnosis: &diagnosis,
            diagnosis_text: &text,
            ladder: &ladder,
            final_model: &extended,
            after: &after,
        },
    )?;
    if a.input.json {
        return print_json_with_log(&summary, log.as_ref());
    }
    let mut o = String::new();
    if let Some(s) = &log {
        print_log_summary(&mut o, s);
    }
    p!(
        o,
        "wrote {} ({} plots); residual RMS {:.3e} g -> {:.3e} g with {}",
        summary.html,
        summary.plots,
        summary.rms_before_g,
        summary.rms_after_g,
        if summary.effects_added.is_empty() {
            "no effect added".to_string()
        } else {
            summary.effects_added.join(" + ")
        }
    );
    print_text(&o)
}
