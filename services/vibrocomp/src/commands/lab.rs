//! `vibrocomp lab`: compare the VE model with a campaign, find the missing physical
//! effect, fit it and add it to the model (`vibro_lab`, docs/lab.md).

use super::lab_log::LogArgs;
use crate::output::{print_json, print_text};
use anyhow::Context;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::fmt::Write as _;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use vibro_lab::diagnose::Progress;
use vibro_lab::log_table::LogTableSummary;
use vibro_lab::text;
use vibro_lab::{BaseMode, CampaignTable, DiagnoseOptions, LabModel};

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
    /// --lab-csv`, MCAP logs with a reference (`.mcap`: a flight cut into the
    /// estimator's windows, docs/lab.md "Logs as input"), and shake-table campaign
    /// manifests (`.toml`, or a CSV whose first line is `# vibrocomp-campaign/1`: a rig's
    /// raw runs, docs/identification.md "Campaigns from raw records"); several are
    /// fitted jointly.
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
    /// `waveform`: every reading from its samples (logs' default); `statistics`;
    /// `windows`: `compare` by the stage (docs/lab.md, "Which evaluation").
    #[arg(long, value_enum)]
    pub path: Option<EvaluationPath>,
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

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum EvaluationPath {
    Waveform,
    Statistics,
    Windows,
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
    /// How readings are predicted (`lab diagnose --path`).
    #[arg(long, value_enum)]
    pub path: Option<EvaluationPath>,
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

pub(super) fn base_mode(m: super::model::ModeArg) -> BaseMode {
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
    read: Read,
}

/// What became of each log's windows, and each manifest's summary (its estimator bands
/// clipped to its reference's rate).
struct Read {
    log: Vec<LogTableSummary>,
    manifests: Vec<vibro_lab::inputs::ManifestSummary>,
}

fn load(
    inputs: &[PathBuf],
    model: Option<&Path>,
    mode: BaseMode,
    log_args: &LogArgs,
) -> anyhow::Result<Loaded> {
    if let Some(out) = &log_args.table_out {
        let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
        crate::files::check(out, &inputs, false).context("--table-out")?;
    }
    let model = match model {
        Some(p) => LabModel::load(p)?,
        None => LabModel::base(mode),
    };
    let inputs: Vec<vibro_lab::inputs::Input> = inputs
        .iter()
        .cloned()
        .map(vibro_lab::inputs::Input::Path)
        .collect();
    let bar = crate::output::progress_bar(
        0,
        "measuring runs {bar:30} {pos}/{len} (reference, VE, estimator)",
    );
    let loaded = vibro_lab::inputs::load(
        &inputs,
        &model,
        &mut || log_args.options(),
        &mut |done, of| {
            bar.set_length(of as u64);
            bar.set_position(done as u64)
        },
    );
    bar.finish_and_clear();
    let vibro_lab::inputs::Loaded {
        table,
        logs,
        manifests,
    } = loaded?;
    if let Some(out) = &log_args.table_out {
        let mut bytes = Vec::new();
        table.write_csv(&mut bytes).context("--table-out")?;
        crate::files::write_bytes(out, false, &bytes)?;
    }
    let read = Read {
        log: logs,
        manifests,
    };
    Ok(Loaded { model, table, read })
}

/// A progress bar over the candidates' fits (a long log's diagnosis takes minutes),
/// on a terminal only: redirected stderr (scripts, tests) stays clean.
pub(super) fn fit_progress() -> (ProgressBar, Progress) {
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

/// Prints `inner` as JSON with the logs' summaries beside it, or the logs' summary
/// lines followed by the text `write` appends.
fn print_result<T: serde::Serialize>(
    json: bool,
    inner: &T,
    read: &Read,
    write: impl FnOnce(&mut String),
) -> anyhow::Result<()> {
    let with = vibro_lab::inputs::WithInputs::new(inner, &read.log, &read.manifests);
    if json {
        return print_json(&with);
    }
    let mut o = String::new();
    with.write_text(&mut o);
    write(&mut o);
    print_text(&o)
}

/// Loads the inputs and the model of the compare, diagnose and report commands.
fn load_input(i: &Input) -> anyhow::Result<Loaded> {
    load(&i.input, i.model.as_deref(), base_mode(i.mode), &i.log)
}

fn compare(a: &CompareArgs) -> anyhow::Result<()> {
    if super::lab_wave::takes_waveform(&a.input.input, a.input.path)? {
        return super::lab_wave::diagnose(&a.input, &[], 0);
    }
    let Loaded { model, table, read } = load_input(&a.input)?;
    // `windows` (and the default beside tables): a log's windows by the stage.
    let c = match a.input.path {
        Some(EvaluationPath::Statistics) => vibro_lab::compare(&model, &table)?,
        _ => vibro_lab::compare_evaluated(&model, &table, &read.log)?,
    };
    print_result(a.input.json, &c, &read, |o| {
        text::write_comparison(o, &c, a.all)
    })
}

fn diagnose(a: &DiagnoseArgs) -> anyhow::Result<()> {
    if super::lab_wave::takes_waveform(&a.input.input, a.input.path)? {
        return super::lab_wave::diagnose(&a.input, &a.effects, a.max_effects);
    }
    let Loaded { model, table, read } = load_input(&a.input)?;
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
    print_result(a.input.json, &d, &read, |o| text::write_diagnosis(o, &d))
}

#[derive(serde::Serialize)]
struct AddReport<'a> {
    out: String,
    effects: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    fit: Option<&'a vibro_lab::EffectFit>,
    #[serde(skip_serializing_if = "Option::is_none")]
    empirical: Option<&'a vibro_lab::EmpiricalFit>,
}

fn add(a: &AddArgs) -> anyhow::Result<()> {
    if super::lab_wave::takes_waveform(&a.from, a.path)? {
        return super::lab_wave::add(a);
    }
    // README, "Files": checked before the fit runs; the inputs are never replaced.
    let mut inputs: Vec<&Path> = a.from.iter().map(PathBuf::as_path).collect();
    inputs.extend(a.model.as_deref());
    crate::files::check(&a.out, &inputs, a.force)?;
    let Loaded { model, table, read } = load(&a.from, a.model.as_deref(), BaseMode::Exact, &a.log)?;
    let effects = if a.diagnosed {
        vibro_lab::add::Effects::Diagnosed
    } else {
        vibro_lab::add::Effects::Kinds(a.effects.clone())
    };
    let (bar, progress) = if a.diagnosed {
        fit_progress()
    } else {
        (ProgressBar::hidden(), Progress::default())
    };
    let opts = DiagnoseOptions {
        progress,
        ..DiagnoseOptions::default()
    };
    let added = vibro_lab::add::add(&model, &table, &effects, a.freeze, &opts);
    bar.finish_and_clear();
    let vibro_lab::add::Added {
        model: extended,
        fit,
        empirical: correction,
    } = added?;
    extended
        .save(&a.out, a.force)
        .context("writing the extended model")?;
    let report = AddReport {
        out: a.out.display().to_string(),
        effects: extended.effect_kinds(),
        fit: fit.as_ref(),
        empirical: correction.as_ref(),
    };
    print_result(a.json, &report, &read, |o| {
        text::write_added(o, &extended, &table.path, fit.as_ref(), correction.as_ref());
        let _ = writeln!(
            o,
            "wrote {} (effects: {})",
            report.out,
            report.effects.join(", ")
        );
    })
}

fn report(a: &ReportArgs) -> anyhow::Result<()> {
    if super::lab_wave::takes_waveform(&a.input.input, a.input.path)? {
        return super::lab_wave::report(a);
    }
    crate::files::check_dir(&a.out, vibro_lab::report::REPORT_FILES, a.force)?;
    let Loaded { model, table, read } = load_input(&a.input)?;
    let (bar, progress) = fit_progress();
    let opts = DiagnoseOptions {
        progress,
        max_effects: a.max_effects,
        ..DiagnoseOptions::default()
    };
    let diagnosis = vibro_lab::diagnose(&model, &table, &opts)?;
    let (ladder, extended) =
        vibro_lab::diagnose::ladder_from(&model, &table, &opts, a.max_effects, Some(&diagnosis))?;
    bar.finish_and_clear();
    let after = vibro_lab::compare(&extended, &table)?;
    let report = vibro_lab::report::render(&vibro_lab::report::ReportInput {
        table: &table,
        model: &model,
        diagnosis: &diagnosis,
        ladder: &ladder,
        final_model: &extended,
        after: &after,
    })?;
    let written = write_report(&a.out, a.force, report)?;
    let s = &written.summary;
    print_result(a.input.json, &written, &read, |o| {
        let added = if s.effects_added.is_empty() {
            "no effect added".to_string()
        } else {
            s.effects_added.join(" + ")
        };
        let _ = writeln!(
            o,
            "wrote {} ({} plots); residual RMS {:.3e} g -> {:.3e} g with {added}",
            written.html, s.plots, s.rms_before_g, s.rms_after_g
        );
    })
}

/// What `lab report --json` prints: where the page is, and what it holds.
#[derive(serde::Serialize)]
pub(super) struct WrittenReport {
    pub html: String,
    #[serde(flatten)]
    pub summary: vibro_lab::report::ReportSummary,
}

/// Writes the report into `dir` (checked by `files::check_dir`): each plot as an SVG
/// file, then `index.html` last, since its presence marks a complete report; each file
/// complete or not at all (`crate::files`).
pub(super) fn write_report(
    dir: &Path,
    force: bool,
    report: vibro_lab::report::Report,
) -> anyhow::Result<WrittenReport> {
    crate::files::create_dir(dir)?;
    for (name, text) in &report.plots {
        // The plots of a report without its index.html (a run that failed midway) are
        // this command's own: replaced without --force.
        crate::files::write_bytes(&dir.join(name), true, text.as_bytes())?;
    }
    let html = dir.join("index.html");
    crate::files::write_bytes(&html, force, report.index_html.as_bytes())?;
    Ok(WrittenReport {
        html: html.display().to_string(),
        summary: report.summary,
    })
}
