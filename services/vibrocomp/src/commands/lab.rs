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
use indicatif::{ProgressBar, ProgressStyle};
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
    /// Fit effects to the campaign (jointly with the model's own) and write the
    /// extended model.
    Add(AddArgs),
    /// A self-contained HTML report with plots: the residuals before and after the
    /// effects the lab adds, the candidates' ranking, the error falling.
    Report(ReportArgs),
}

#[derive(Debug, Args)]
pub struct ReportArgs {
    #[command(flatten)]
    pub input: Input,
    /// The folder to write `index.html` (and the plots as SVG files) into (created if
    /// missing; one holding a previous report is refused unless --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the files of a previous report in --out.
    #[arg(long)]
    pub force: bool,
    /// At most this many effects added by the stepwise search.
    #[arg(long, default_value_t = 4)]
    pub max_effects: usize,
}

/// The input and the model, shared by the lab's commands.
#[derive(Debug, Args)]
pub struct Input {
    /// Campaign tables (CSV, docs/lab.md), e.g. from `vibrocomp sim CAMPAIGN
    /// --lab-csv`, and MCAP logs with a reference (`.mcap`: a flight cut into the
    /// estimator's windows, docs/lab.md "Logs as input"); several are fitted jointly.
    #[arg(required = true, num_args = 1..)]
    pub input: Vec<PathBuf>,
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
    /// Most effects the stepwise search adds.
    #[arg(long, default_value_t = 4)]
    pub max_effects: usize,
}

#[derive(Debug, Args)]
pub struct AddArgs {
    /// The effects to fit and add (kinds of the lab's library, comma-separated, see
    /// `lab diagnose`); or `--diagnosed`; or `empirical` alone: the cross-validated
    /// correction (not physical) that `lab diagnose` offers when the verdict is
    /// "unexplained", the model's effects refitted beside it.
    #[arg(value_delimiter = ',', required_unless_present = "diagnosed")]
    pub effects: Vec<String>,
    /// Add the effects `lab diagnose` finds on the same inputs (its stepwise search),
    /// in one command.
    #[arg(long, conflicts_with = "effects")]
    pub diagnosed: bool,
    /// Keep the model's own effects as they are (default: refit them jointly with the
    /// new ones, all parameters free).
    #[arg(long)]
    pub freeze: bool,
    /// The campaign tables and MCAP logs with a reference to fit to (jointly).
    #[arg(long, required = true, num_args = 1..)]
    pub from: Vec<PathBuf>,
    #[command(flatten)]
    pub log: LogArgs,
    /// The model to extend (default the model of MODEL.md, exact mode).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Where to write the extended model (an existing file only with --force; never
    /// an input).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, help = crate::files::FORCE_HELP)]
    pub force: bool,
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

/// What the lab read: the model, the inputs as one table, and for each MCAP log what
/// became of its windows.
struct Loaded {
    model: LabModel,
    table: CampaignTable,
    log: Vec<LogTableSummary>,
}

fn load(
    inputs: &[PathBuf],
    model: Option<&Path>,
    mode: BaseMode,
    log_args: &LogArgs,
) -> anyhow::Result<Loaded> {
    let model = match model {
        Some(p) => LabModel::load(p)?,
        None => LabModel::base(mode),
    };
    let mut tables = Vec::with_capacity(inputs.len());
    let mut logs = Vec::new();
    for input in inputs {
        let is_mcap = input
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
        if is_mcap {
            let (table, summary) = table_from_log(input, &model, log_args)?;
            tables.push(table);
            logs.push(summary);
        } else {
            tables.push(CampaignTable::load(input, &model)?);
        }
    }
    let table = CampaignTable::joined(tables)?;
    Ok(Loaded {
        model,
        table,
        log: logs,
    })
}

/// A progress bar over the candidates' fits (a long log's diagnosis takes minutes),
/// on a terminal only: redirected stderr (scripts, tests) stays clean.
fn fit_progress() -> (ProgressBar, Progress) {
    if !std::io::stderr().is_terminal() {
        return (ProgressBar::hidden(), Progress::default());
    }
    let bar = ProgressBar::with_draw_target(None, crate::output::progress_target());
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

/// A command's JSON with the logs' summaries beside it when inputs were logs (`log`:
/// the one log's, `logs`: every log's when there are several).
#[derive(serde::Serialize)]
struct WithLog<'a, T: serde::Serialize> {
    #[serde(flatten)]
    inner: &'a T,
    #[serde(skip_serializing_if = "Option::is_none")]
    log: Option<&'a LogTableSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    logs: Option<&'a [LogTableSummary]>,
}

fn print_json_with_log<T: serde::Serialize>(
    inner: &T,
    logs: &[LogTableSummary],
) -> anyhow::Result<()> {
    print_json(&WithLog {
        inner,
        log: (logs.len() == 1).then(|| &logs[0]),
        logs: (logs.len() > 1).then_some(logs),
    })
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
        return print_json_with_log(&c, &log);
    }
    let mut o = String::new();
    for s in &log {
        print_log_summary(&mut o, s);
    }
    print_comparison(&mut o, &c, a.all);
    print_text(&o)
}

fn params_text(params: &[vibro_lab::fit::FittedParam]) -> String {
    params
        .iter()
        .map(|p| {
            if !p.sigma.is_finite() {
                format!(
                    "{} = {:.6e} (not determined by this table)",
                    p.name, p.value
                )
            } else if vibro_lab::fit::asymmetric(p) {
                format!(
                    "{} = {:.6e} -{:.2e} +{:.2e} (profile likelihood; 3 sigma: {:.3e} .. {:.3e})",
                    p.name,
                    p.value,
                    p.sigma_minus,
                    p.sigma_plus,
                    p.value - p.three_sigma_minus,
                    p.value + p.three_sigma_plus
                )
            } else if p.sigma.is_finite() {
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
    if d.candidates.is_empty() {
        p!(
            o,
            "\ncandidates: not fitted (the model as is passes the chi-square test: nothing to \
             attribute; `lab add EFFECT` fits one on request)"
        );
    } else {
        p!(
            o,
            "\ncandidates, each alone against the model as is, best first (delta BIC < -10: \
             supported):"
        );
    }
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
                params_text(&f.params_of(&c.kind))
            ),
            None => p!(
                o,
                "  {:<24} not applicable: {}",
                c.kind,
                c.not_applicable.as_deref().unwrap_or("")
            ),
        }
    }
    for n in &d.not_applicable {
        p!(o, "{}", not_applicable_line(n));
    }
    if let Some(c) = d.candidates.iter().find_map(|c| c.fit.as_ref()) {
        for n in &c.not_applicable {
            p!(o, "{}", not_applicable_line(n));
        }
    }
    if d.steps.len() > 1 {
        p!(
            o,
            "\nstepwise search (each step refits all chosen effects jointly; an addition \
             needs delta BIC < {}):",
            d.options.bic_support
        );
        p!(
            o,
            "  {:<28} {:>14} {:>12} {:>10} {:>10}  next best",
            "step",
            "delta_bic",
            "rms_g",
            "chi2/dof",
            "p"
        );
        for st in &d.steps {
            let next: Vec<String> = st
                .runners_up
                .iter()
                .take(2)
                .map(|(k, b)| format!("{k} {b:.1}"))
                .collect();
            p!(
                o,
                "  {:<28} {:>14.1} {} {:>10.3} {:>10.2e}  {}",
                st.action,
                st.delta_bic,
                g(st.rms_residual_g),
                st.chi2_per_dof,
                st.p_value,
                next.join(", ")
            );
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
            kinds,
            delta_bic,
            rms_residual_before_g,
            rms_residual_after_g,
            chi2_per_dof_after,
            physics,
            ..
        } => {
            let what = if kinds.len() > 1 {
                format!("missing effects `{}`", kinds.join("` + `"))
            } else {
                format!("missing effect `{}`", kinds.join(""))
            };
            p!(o, "Verdict: {what} (delta BIC {delta_bic:.1}).");
            if let Some(f) = &d.selected {
                print_fit_params(o, f);
            }
            p!(
                o,
                "  residual RMS {rms_residual_before_g:.3e} g -> {rms_residual_after_g:.3e} g \
                 (chi2 per dof {chi2_per_dof_after:.3}) with {}",
                if kinds.len() > 1 { "them" } else { "it" }
            );
            for ph in physics {
                p!(o, "  physics: {ph}");
            }
            p!(
                o,
                "  add {}: vibrocomp lab add {} --from {} --out model.toml",
                if kinds.len() > 1 { "them" } else { "it" },
                kinds.join(","),
                d.comparison.table
            );
        }
        Verdict::Confounded {
            kinds,
            correlation,
            suggestions,
            found,
        } => {
            if !found.is_empty() {
                p!(o, "Found first: {}.", found.join(", "));
            }
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
            found,
            found_explained_fraction,
        } => {
            if found.is_empty() {
                p!(
                    o,
                    "Verdict: unexplained structure (chi2 per dof {chi2_per_dof:.3}): no effect \
                     of the library explains it."
                );
            } else {
                p!(
                    o,
                    "Verdict: found {} (removing {:.1} % of the chi-square), but structure \
                     remains unexplained (chi2 per dof {chi2_per_dof:.3} with {}).",
                    found.join(" + "),
                    100.0 * found_explained_fraction,
                    if found.len() > 1 { "them" } else { "it" }
                );
                if let Some(f) = &d.selected {
                    print_fit_params(o, f);
                }
            }
            if !variables.is_empty() {
                p!(o, "  the residual left follows: {}", variables.join(", "));
            }
            if let Some(b) = best {
                p!(
                    o,
                    "  the best candidate left, {b}, would explain only {:.1} % of it: \
                     not attributed",
                    100.0 * best_explained_fraction
                );
            }
            print_empirical(o, d);
        }
    }
}

/// An empirical correction's terms, the effects refitted beside it or dropped, and
/// what it does to the residual.
fn print_correction(o: &mut String, e: &vibro_lab::EmpiricalFit) {
    for t in &e.terms {
        p!(
            o,
            "  {:<20} {:>13.6e} +- {:.2e}   ({})",
            t.key,
            t.value,
            t.sigma,
            t.meaning
        );
    }
    if !e.found.is_empty() {
        p!(o, "  beside it, refitted: {}", params_text(&e.found));
    }
    for dropped in &e.dropped {
        p!(o, "  not needed beside it: {dropped}");
    }
    p!(
        o,
        "  cross-validated chi2 {:.1} -> {:.1}; residual RMS {:.3e} g -> {:.3e} g (chi2 per \
         dof {:.3}, p = {:.3})",
        e.cv_chi2_before,
        e.cv_chi2_after,
        e.rms_residual_before_g,
        e.rms_residual_after_g,
        e.chi2_per_dof_after,
        e.p_value_after
    );
}

/// Beyond the library: the empirical correction offered (or why none is).
fn print_empirical(o: &mut String, d: &Diagnosis) {
    if let Some(why) = &d.empirical_none {
        p!(o, "Beyond the library: {why}.");
    }
    let Some(e) = &d.empirical else {
        return;
    };
    p!(
        o,
        "Beyond the library: an empirical correction, NOT PHYSICAL (a smooth function of {}, \
         chosen by leave-one-out cross-validation; an extrapolation outside the conditions \
         measured):",
        e.variables.join(", ")
    );
    print_correction(o, e);
    p!(
        o,
        "  add it: vibrocomp lab add empirical --from {} --out model.toml",
        d.comparison.table
    );
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
        max_effects: a.max_effects,
        progress,
        ..DiagnoseOptions::default()
    };
    let d = vibro_lab::diagnose(&model, &table, &opts);
    bar.finish_and_clear();
    let d = d?;
    if a.input.json {
        return print_json_with_log(&d, &log);
    }
    let mut o = String::new();
    for s in &log {
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
    // README, "Files": checked before the fit runs; the inputs are never replaced.
    let mut inputs: Vec<&Path> = a.from.iter().map(PathBuf::as_path).collect();
    inputs.extend(a.model.as_deref());
    crate::files::check(&a.out, &inputs, a.force)?;
    let Loaded { model, table, log } = load(&a.from, a.model.as_deref(), BaseMode::Exact, &a.log)?;
    let kinds: Vec<String> = if a.diagnosed {
        let (bar, progress) = fit_progress();
        let opts = DiagnoseOptions {
            progress,
            ..DiagnoseOptions::default()
        };
        let d = vibro_lab::diagnose(&model, &table, &opts);
        bar.finish_and_clear();
        let d = d?;
        let kinds = vibro_lab::diagnose::next_effects(&d);
        anyhow::ensure!(
            !kinds.is_empty(),
            "--diagnosed: the diagnosis of {} found no effect to add ({})",
            table.path.display(),
            verdict_line(&d.verdict)
        );
        kinds
    } else {
        a.effects.clone()
    };
    if kinds.iter().any(|k| k == vibro_effects::empirical::KIND) {
        anyhow::ensure!(
            kinds.len() == 1 && !a.freeze,
            "`empirical` is added alone and refits the model's effects beside it (no \
             --freeze): first add the physical effects, then `lab add empirical`"
        );
        return add_empirical(a, &model, &table, &log);
    }
    let refs: Vec<&str> = kinds.iter().map(String::as_str).collect();
    let (extended, fit) = vibro_lab::add_effects(&model, &table, &refs, a.freeze)?;
    crate::files::write_with(&a.out, a.force, |tmp| {
        extended
            .save(tmp)
            .with_context(|| format!("{}: cannot write the extended model", a.out.display()))
    })?;
    if a.json {
        return print_json_with_log(
            &AddReport {
                out: a.out.display().to_string(),
                effects: extended.effect_kinds(),
                fit: &fit,
            },
            &log,
        );
    }
    let mut o = String::new();
    for s in &log {
        print_log_summary(&mut o, s);
    }
    let before_g = extended
        .fits
        .last()
        .map_or(fit.rms_residual_before_g, |r| r.rms_residual_before_g);
    p!(
        o,
        "{} fitted {}to {} ({} conditions):",
        fit.kinds.join(" + "),
        if fit.kinds.len() > 1 { "jointly " } else { "" },
        table.path.display(),
        fit.n
    );
    print_fit_params(&mut o, &fit);
    p!(
        o,
        "residual RMS {:.3e} g -> {:.3e} g, chi2 per dof {:.4}, delta BIC {:.1}",
        before_g,
        fit.rms_residual_after_g,
        fit.chi2_per_dof_after,
        fit.delta_bic
    );
    for n in &fit.not_applicable {
        p!(o, "{}", not_applicable_line(n));
    }
    p!(
        o,
        "wrote {} (effects: {})",
        a.out.display(),
        extended.effect_kinds().join(", ")
    );
    print_text(&o)
}

#[derive(serde::Serialize)]
struct AddEmpiricalReport<'a> {
    out: String,
    effects: Vec<String>,
    empirical: &'a vibro_lab::EmpiricalFit,
}

/// `lab add empirical`: the cross-validated correction (not physical) beside the
/// model's effects, refitted jointly.
fn add_empirical(
    a: &AddArgs,
    model: &vibro_lab::LabModel,
    table: &vibro_lab::CampaignTable,
    log: &[LogTableSummary],
) -> anyhow::Result<()> {
    let Some((extended, e)) = vibro_lab::add_empirical(model, table)? else {
        anyhow::bail!(
            "{}: no empirical correction: no smooth function of the vibration and the flight \
             acceleration predicts the residual out of sample (no set of terms, each \
             lowering the leave-one-out chi-square by {}, brings it below {} of its value); \
             nothing written",
            table.path.display(),
            vibro_lab::empirical::CV_SUPPORT,
            vibro_lab::empirical::OFFER_FRACTION
        );
    };
    crate::files::write_with(&a.out, a.force, |tmp| {
        extended
            .save(tmp)
            .with_context(|| format!("{}: cannot write the extended model", a.out.display()))
    })?;
    if a.json {
        return print_json_with_log(
            &AddEmpiricalReport {
                out: a.out.display().to_string(),
                effects: extended.effect_kinds(),
                empirical: &e,
            },
            log,
        );
    }
    let mut o = String::new();
    for s in log {
        print_log_summary(&mut o, s);
    }
    p!(
        o,
        "empirical correction (NOT PHYSICAL) fitted to {} ({} conditions):",
        table.path.display(),
        e.n
    );
    print_correction(&mut o, &e);
    p!(
        o,
        "wrote {} (effects: {})",
        a.out.display(),
        extended.effect_kinds().join(", ")
    );
    print_text(&o)
}

/// Each effect's parameters on a line, then the correlations beyond 0.5 in size.
fn print_fit_params(o: &mut String, f: &vibro_lab::EffectFit) {
    for k in &f.kinds {
        p!(o, "  {k}: {}", params_text(&f.params_of(k)));
    }
    let mut strong = Vec::new();
    for i in 0..f.params.len() {
        for j in 0..i {
            let r = f.correlation[i][j];
            if r.abs() > 0.5 {
                strong.push(format!(
                    "{}.{} ~ {}.{} {r:+.3}",
                    f.params[i].effect, f.params[i].name, f.params[j].effect, f.params[j].name
                ));
            }
        }
    }
    if !strong.is_empty() {
        p!(o, "  correlations beyond 0.5: {}", strong.join("; "));
    }
}

/// The rows an effect could not act on, in a line (the first ten named).
fn not_applicable_line(n: &vibro_lab::fit::NotApplicable) -> String {
    let mut rows: Vec<String> = n
        .rows
        .iter()
        .take(10)
        .map(|(l, r)| format!("line {l} ({r})"))
        .collect();
    if n.rows.len() > 10 {
        rows.push(format!("and {} more", n.rows.len() - 10));
    }
    format!(
        "  {} not evaluated on {} rows: {}: {}",
        n.effect,
        n.rows.len(),
        rows.join(", "),
        n.reason
    )
}

/// The verdict in a few words.
fn verdict_line(v: &Verdict) -> String {
    match v {
        Verdict::Noise { chi2_per_dof, .. } => format!("noise, chi2 per dof {chi2_per_dof:.3}"),
        Verdict::Effect { kinds, .. } => format!("effects {}", kinds.join(", ")),
        Verdict::Confounded { kinds, .. } => format!("confounded: {}", kinds.join(", ")),
        Verdict::Unexplained { chi2_per_dof, .. } => {
            format!("unexplained, chi2 per dof {chi2_per_dof:.3}")
        }
    }
}

fn report(a: &ReportArgs) -> anyhow::Result<()> {
    crate::files::check_dir(&a.out, super::lab_report::REPORT_FILES, a.force)?;
    let Loaded { model, table, log } = load(
        &a.input.input,
        a.input.model.as_deref(),
        base_mode(a.input.mode),
        &a.input.log,
    )?;
    let (bar, progress) = fit_progress();
    let opts = DiagnoseOptions {
        progress,
        max_effects: a.max_effects,
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
        a.force,
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
        return print_json_with_log(&summary, &log);
    }
    let mut o = String::new();
    for s in &log {
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
