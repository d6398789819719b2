//! `vibrocomp lab` on the waveform (issue 44): MCAP logs whose vibration samples
//! predict every reading (`vibro_lab::wave_diagnose`, docs/lab.md "The lab on the
//! waveform").

use super::lab::{fit_progress, write_report, AddArgs, EvaluationPath, Input};
use crate::output::{print_json, print_text};
use anyhow::{bail, Context};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use vibro_lab::wave_diagnose::{diagnose_logs, WaveOptions};
use vibro_lab::{wave_text, BaseMode, LabModel};

fn is_log(p: &Path) -> bool {
    p.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}

/// Whether `inputs` take the waveform path: `--path waveform`, or by default when
/// every input is an MCAP log.
pub fn takes_waveform(inputs: &[PathBuf], path: Option<EvaluationPath>) -> anyhow::Result<bool> {
    match path {
        Some(EvaluationPath::Waveform) => {
            if let Some(p) = inputs.iter().find(|p| !is_log(p)) {
                bail!(
                    "--path waveform: {} is not an MCAP log: the waveform path predicts each \
                     reading from a log's vibration samples (tables and manifests take \
                     --path statistics)",
                    p.display()
                );
            }
            Ok(true)
        }
        Some(_) => Ok(false),
        None => Ok(!inputs.is_empty() && inputs.iter().all(|p| is_log(p))),
    }
}

fn model_of(path: Option<&Path>, mode: BaseMode) -> anyhow::Result<LabModel> {
    Ok(match path {
        Some(p) => LabModel::load(p)?,
        None => LabModel::base(mode),
    })
}

/// Runs the waveform diagnosis of `inputs` with `options` (a progress bar on a terminal).
fn run(
    inputs: &[PathBuf],
    model: &LabModel,
    log: &super::lab_log::LogArgs,
    options: WaveOptions,
) -> anyhow::Result<vibro_lab::wave_diagnose::WaveDiagnosis> {
    let (bar, progress) = fit_progress();
    let d = diagnose_logs(
        inputs,
        model,
        &log.options()?,
        &WaveOptions {
            progress,
            ..options
        },
    );
    bar.finish_and_clear();
    Ok(d?)
}

/// `lab compare` on the waveform: the model as is (its delay fitted when no log states
/// it), every reading's residual against the quiet readings' noise.
pub fn compare(i: &Input) -> anyhow::Result<()> {
    let model = model_of(i.model.as_deref(), super::lab::base_mode(i.mode))?;
    let options = WaveOptions {
        max_effects: 0,
        ..WaveOptions::default()
    };
    let d = run(&i.input, &model, &i.log, options)?;
    if i.json {
        return print_json(&d);
    }
    let mut o = String::new();
    wave_text::write_wave_comparison(&mut o, &d);
    print_text(&o)
}

/// `lab diagnose` on the waveform.
pub fn diagnose(i: &Input, effects: &[String], max_effects: usize) -> anyhow::Result<()> {
    let model = model_of(i.model.as_deref(), super::lab::base_mode(i.mode))?;
    let options = WaveOptions {
        candidates: effects.to_vec(),
        max_effects,
        ..WaveOptions::default()
    };
    let d = run(&i.input, &model, &i.log, options)?;
    if i.json {
        return print_json(&d);
    }
    let mut o = String::new();
    wave_text::write_wave_diagnosis(&mut o, &d);
    print_text(&o)
}

#[derive(serde::Serialize)]
struct Added<'a> {
    out: String,
    effects: Vec<String>,
    diagnosis: &'a vibro_lab::wave_diagnose::WaveDiagnosis,
}

/// `lab add` on the waveform: the effects named (each added whatever its support), or
/// those the diagnosis finds (`--diagnosed`), fitted to every reading.
pub fn add(a: &AddArgs) -> anyhow::Result<()> {
    let mut inputs: Vec<&Path> = a.from.iter().map(PathBuf::as_path).collect();
    inputs.extend(a.model.as_deref());
    crate::files::check(&a.out, &inputs, a.force)?;
    let model = model_of(a.model.as_deref(), BaseMode::Exact)?;
    let options = if a.diagnosed {
        WaveOptions::default()
    } else {
        WaveOptions {
            candidates: a.effects.clone(),
            max_effects: a.effects.len(),
            z_noise: f64::NEG_INFINITY,
            bic_support: f64::INFINITY,
            bic_tie: f64::NEG_INFINITY,
            ..WaveOptions::default()
        }
    };
    let d = run(&a.from, &model, &a.log, options)?;
    if !a.diagnosed {
        let missing: Vec<&String> = a.effects.iter().filter(|k| !d.found.contains(k)).collect();
        if !missing.is_empty() {
            bail!("could not fit {missing:?} to the readings (see `lab diagnose --path waveform`)");
        }
    }
    d.model
        .save(&a.out, a.force)
        .context("writing the extended model")?;
    let report = Added {
        out: a.out.display().to_string(),
        effects: d.model.effect_kinds(),
        diagnosis: &d,
    };
    if a.json {
        return print_json(&report);
    }
    let mut o = String::new();
    wave_text::write_wave_diagnosis(&mut o, &d);
    let delay = d.params.iter().find(|p| p.kind == "sensor_chain");
    if let Some(p) = delay {
        let _ = writeln!(
            o,
            "the sensors' delay is the rig's, not the model's: state it in the rig file \
             ([sensors] delay_s = {:.6e}, +- {:.1e} s)",
            p.value, p.sigma
        );
    }
    let _ = writeln!(
        o,
        "wrote {} (effects: {})",
        report.out,
        report.effects.join(", ")
    );
    print_text(&o)
}

/// `lab report` on the waveform: the diagnosis as a page, with every reading's
/// residual along each run.
pub fn report(a: &super::lab::ReportArgs) -> anyhow::Result<()> {
    crate::files::check_dir(&a.out, vibro_lab::report::REPORT_FILES, a.force)?;
    let i = &a.input;
    let model = model_of(i.model.as_deref(), super::lab::base_mode(i.mode))?;
    let options = WaveOptions {
        max_effects: a.max_effects,
        ..WaveOptions::default()
    };
    let d = run(&i.input, &model, &i.log, options)?;
    let page = vibro_lab::wave_report::render_waveform(&d, &model)?;
    let written = write_report(&a.out, a.force, page)?;
    if i.json {
        return print_json(&written);
    }
    print_text(&format!(
        "wrote {} ({} plots): {} ({})\n",
        written.html,
        written.summary.plots,
        d.verdict,
        if d.found.is_empty() {
            "no effect added".to_string()
        } else {
            d.found.join(" + ")
        }
    ))
}
