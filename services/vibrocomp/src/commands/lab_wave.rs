//! `vibrocomp lab` on the waveform (issue 44): MCAP logs whose vibration samples
//! predict every reading (`vibro_lab::wave_diagnose`, docs/lab.md "The lab on the
//! waveform").

use super::lab::{base_mode, fit_progress, write_report, AddArgs, EvaluationPath, Input};
use crate::output::{print_json, print_text};
use anyhow::{bail, Context};
use std::path::{Path, PathBuf};
use vibro_lab::wave_diagnose::{diagnose_logs, WaveDiagnosis, WaveOptions};
use vibro_lab::{wave_text, BaseMode, LabModel};

/// Whether `inputs` take the waveform path: `--path waveform`, or by default when
/// every input is an MCAP log.
pub fn takes_waveform(inputs: &[PathBuf], path: Option<EvaluationPath>) -> anyhow::Result<bool> {
    let is_log = |p: &&PathBuf| {
        p.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    };
    match path {
        Some(EvaluationPath::Waveform) => match inputs.iter().find(|p| !is_log(p)) {
            Some(p) => bail!(
                "--path waveform: {} is not an MCAP log: the waveform path predicts each \
                 reading from a log's vibration samples (tables and manifests take \
                 --path statistics)",
                p.display()
            ),
            None => Ok(true),
        },
        Some(_) => Ok(false),
        None => Ok(!inputs.is_empty() && inputs.iter().all(|p| is_log(&p))),
    }
}

/// The model `path` names, or the base model of `mode`; then the waveform diagnosis of
/// `inputs` with `options` (a progress bar on a terminal).
fn run(
    inputs: &[PathBuf],
    model: Option<&Path>,
    mode: BaseMode,
    log: &super::lab_log::LogArgs,
    options: WaveOptions,
) -> anyhow::Result<(LabModel, WaveDiagnosis)> {
    let model = match model {
        Some(p) => LabModel::load(p)?,
        None => LabModel::base(mode),
    };
    let (bar, progress) = fit_progress();
    let options = WaveOptions {
        progress,
        ..options
    };
    let d = diagnose_logs(inputs, &model, &log.options()?, &options);
    bar.finish_and_clear();
    Ok((model, d?))
}

fn run_input(i: &Input, options: WaveOptions) -> anyhow::Result<(LabModel, WaveDiagnosis)> {
    let (m, mode) = (i.model.as_deref(), base_mode(i.mode));
    run(&i.input, m, mode, &i.log, options)
}

/// `lab compare` (the model as is, its delay fitted when no log states it: `max_effects
/// = 0`) or `lab diagnose` on the waveform.
pub fn diagnose(i: &Input, effects: &[String], max_effects: usize) -> anyhow::Result<()> {
    let options = WaveOptions {
        candidates: effects.to_vec(),
        max_effects,
        ..WaveOptions::default()
    };
    let (_, d) = run_input(i, options)?;
    if i.json {
        return print_json(&d);
    }
    let mut o = String::new();
    match max_effects {
        0 => wave_text::write_wave_comparison(&mut o, &d),
        _ => wave_text::write_wave_diagnosis(&mut o, &d),
    }
    print_text(&o)
}

/// `lab add` on the waveform: the effects named (each added whatever its support), or
/// those the diagnosis finds (`--diagnosed`), fitted to every reading.
pub fn add(a: &AddArgs) -> anyhow::Result<()> {
    let mut inputs: Vec<&Path> = a.from.iter().map(PathBuf::as_path).collect();
    inputs.extend(a.model.as_deref());
    crate::files::check(&a.out, &inputs, a.force)?;
    let options = match a.diagnosed {
        true => WaveOptions::default(),
        false => WaveOptions::adding(&a.effects),
    };
    let (m, mode) = (a.model.as_deref(), BaseMode::Exact);
    let (_, d) = run(&a.from, m, mode, &a.log, options)?;
    let missing: Vec<&String> = a.effects.iter().filter(|k| !d.found.contains(k)).collect();
    if !missing.is_empty() {
        bail!("could not fit {missing:?} to the readings (see `lab diagnose --path waveform`)");
    }
    let saved = d.model.save(&a.out, a.force);
    saved.context("writing the extended model")?;
    let out = a.out.display().to_string();
    if a.json {
        let effects = d.model.effect_kinds();
        return print_json(&serde_json::json!({"out": out, "effects": effects, "diagnosis": d}));
    }
    let mut o = String::new();
    wave_text::write_wave_added(&mut o, &d, &out);
    print_text(&o)
}

/// `lab report` on the waveform: the diagnosis as a page, with every reading's
/// residual along each run.
pub fn report(a: &super::lab::ReportArgs) -> anyhow::Result<()> {
    crate::files::check_dir(&a.out, vibro_lab::report::REPORT_FILES, a.force)?;
    let i = &a.input;
    let options = WaveOptions {
        max_effects: a.max_effects,
        ..WaveOptions::default()
    };
    let (model, d) = run_input(i, options)?;
    let page = vibro_lab::wave_report::render_waveform(&d, &model)?;
    let written = write_report(&a.out, a.force, page)?;
    if i.json {
        return print_json(&written);
    }
    let (html, plots, found) = (&written.html, written.summary.plots, d.found.join(" + "));
    print_text(&format!(
        "wrote {html} ({plots} plots): {} ({found})\n",
        d.verdict
    ))
}
