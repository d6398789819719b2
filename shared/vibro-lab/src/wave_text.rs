//! The lab's waveform results as text ([`crate::wave_diagnose`], issue 44), the way
//! `vibrocomp lab diagnose` and `lab compare` print them for logs with samples and the
//! waveform report quotes them: the runs, the model as is (chi2 per reading, vibrating
//! against quiet, and the lack of fit's z), each round's candidates by delta BIC, the
//! verdict with the effects found and their parameters, the noise per unit and the
//! residual of 1 s windows against the noise's own level. Each `write_*` appends lines
//! to a `String`, like [`crate::text`].
//!
//! Residuals and noise are printed in ug (micro-g) and the sensors' delay in us: a
//! reading's noise is tens of ug and a delay hundreds of us, where `1.234e-5 g` would
//! make the reader count digits.
//!
//! ```
//! use vibro_lab::wave_text::pm;
//! assert_eq!(pm("freq_hz", 48.0, 0.5), "freq_hz = 4.800000e1 +- 5.00e-1");
//! ```

use crate::wave_diagnose::{CandidateOut, ParamOut, RunOut, StepOut, WaveDiagnosis};
use std::fmt::Write as _;
use vibro_wavefit::LackOfFit;

/// Appends a line to the text.
macro_rules! p {
    ($o:expr) => {{
        let _ = writeln!($o);
    }};
    ($o:expr, $($arg:tt)*) => {{
        let _ = writeln!($o, $($arg)*);
    }};
}

/// The kind of the sensors' delay among the parameters ([`WaveDiagnosis::params`]).
pub const DELAY_KIND: &str = "sensor_chain";

/// g to ug, for residuals and noise.
const UG_PER_G: f64 = 1e6;
/// s to us, for the delay.
const US_PER_S: f64 = 1e6;

/// A residual or noise level in ug: `12.345 ug`.
fn ug(x_g: f64) -> String {
    if x_g.is_finite() {
        format!("{:.3} ug", x_g * UG_PER_G)
    } else {
        "n/a".into()
    }
}

/// A parameter with its uncertainty, as [`crate::text::params_text`] writes one:
/// `freq_hz = 4.800000e1 +- 5.00e-1`.
pub fn pm(name: &str, value: f64, sigma: f64) -> String {
    if sigma.is_finite() && sigma > 0.0 {
        format!("{name} = {value:.6e} +- {sigma:.2e}")
    } else {
        format!("{name} = {value:.6e} (not determined by these readings)")
    }
}

/// The delay in us with its uncertainty, to the uncertainty's second digit:
/// `1250.3 +- 2.1 us`.
pub fn delay_us(value_s: f64, sigma_s: f64) -> String {
    delay_in_us(value_s, sigma_s, "+-", "us")
}

/// [`delay_us`] with its plus-minus sign and unit given (`±`, `µs` in the report).
pub(crate) fn delay_in_us(value_s: f64, sigma_s: f64, plus_minus: &str, us: &str) -> String {
    let (v, s) = (value_s * US_PER_S, sigma_s * US_PER_S);
    if !(s.is_finite() && s > 0.0) {
        return format!("{v:.3} {us} (not determined by these readings)");
    }
    let decimals = (1.0 - s.log10().floor()).clamp(0.0, 6.0) as usize;
    format!("{v:.decimals$} {plus_minus} {s:.decimals$} {us}")
}

/// `unit 2`, or `-` for an effect on every unit.
fn unit_label(unit: Option<usize>) -> String {
    unit.map_or_else(|| "-".into(), |u| format!("unit {u}"))
}

/// Each parameter of `params` as `name = value +- sigma`, joined.
fn params_line(params: &[ParamOut]) -> String {
    params
        .iter()
        .map(|p| {
            if p.kind == DELAY_KIND && p.name == "delay_s" {
                format!("delay = {}", delay_us(p.value, p.sigma))
            } else {
                pm(&p.name, p.value, p.sigma)
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The fitted delay (kind `sensor_chain`), when no log states it.
pub fn fitted_delay(d: &WaveDiagnosis) -> Option<&ParamOut> {
    d.params
        .iter()
        .find(|p| p.kind == DELAY_KIND && p.name == "delay_s")
}

/// The effects' parameters (the delay left out), grouped by effect and unit in the
/// order fitted.
pub fn effect_groups(params: &[ParamOut]) -> Vec<(String, Option<usize>, Vec<ParamOut>)> {
    let mut out: Vec<(String, Option<usize>, Vec<ParamOut>)> = Vec::new();
    for p in params.iter().filter(|p| p.kind != DELAY_KIND) {
        match out.last_mut() {
            // A new group when the effect changes (the same kind twice on two units
            // stays two groups).
            Some((k, u, ps))
                if *k == p.kind && *u == p.unit && !ps.iter().any(|q| q.name == p.name) =>
            {
                ps.push(p.clone())
            }
            _ => out.push((p.kind.clone(), p.unit, vec![p.clone()])),
        }
    }
    out
}

/// The header: the path, the logs, the model.
fn write_header(o: &mut String, d: &WaveDiagnosis) {
    p!(
        o,
        "path: waveform (every accelerometer reading predicted from the vibration sensors' \
         samples); {} log{}, {:.1} s",
        d.runs.len(),
        if d.runs.len() == 1 { "" } else { "s" },
        d.elapsed_s
    );
}

/// The runs: readings used, quiet, uncovered, and the delay stated or fitted.
pub fn write_runs(o: &mut String, runs: &[RunOut]) {
    let width = runs
        .iter()
        .map(|r| r.log.chars().count())
        .max()
        .unwrap_or(3)
        .max(3);
    p!(
        o,
        "{:<width$} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  {:<20} {}",
        "log",
        "readings",
        "used",
        "quiet",
        "uncovered",
        "missing",
        "no_ref",
        "delay",
        "band"
    );
    for r in runs {
        let delay = format!(
            "{} {:.1} us",
            if r.delay_stated { "stated" } else { "fitted" },
            r.delay_s * US_PER_S
        );
        p!(
            o,
            "{:<width$} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  {:<20} {:.1}-{:.1} Hz",
            r.log,
            r.counts.readings,
            r.counts.used,
            r.counts.quiet,
            r.counts.uncovered,
            r.counts.missing,
            r.counts.no_reference,
            delay,
            r.band_hz.0,
            r.band_hz.1
        );
    }
}

/// Chi2 per reading vibrating against quiet, and the lack of fit's z.
fn lof_line(l: &LackOfFit) -> String {
    format!(
        "chi2 per reading {:.4} vibrating ({} readings) vs {:.4} quiet ({} readings); \
         lack of fit z = {:.2} (correlation inflation {:.2})",
        l.chi2_per_reading_vibrating,
        l.vibrating,
        l.chi2_per_reading_quiet,
        l.quiet,
        l.z,
        l.inflation
    )
}

/// The model as given: its mode and effects.
fn model_line(d: &WaveDiagnosis) -> String {
    let kinds = d.model.effect_kinds();
    let given = kinds.len().saturating_sub(d.found.len());
    let effects = kinds.get(..given).unwrap_or_default();
    format!(
        "{} mode, effects: {}",
        d.model.mode.name(),
        if effects.is_empty() {
            "none".into()
        } else {
            effects.join(", ")
        }
    )
}

/// The candidates of a round, best (lowest delta BIC) first.
fn write_round(o: &mut String, round: usize, base: &[String], step: &StepOut, support: f64) {
    let against = if base.is_empty() {
        "the model as is".to_string()
    } else {
        format!("the model + {}", base.join(" + "))
    };
    p!(
        o,
        "\nround {round}: candidates against {against}, best first (delta BIC <= {support}: \
         supported):"
    );
    p!(
        o,
        "  {:<20} {:<7} {:>12} {:>9}  parameters",
        "effect",
        "unit",
        "delta_bic",
        "supported"
    );
    let mut cands: Vec<&CandidateOut> = step.candidates.iter().collect();
    cands.sort_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic));
    for c in cands {
        match &c.error {
            Some(e) => p!(
                o,
                "  {:<20} {:<7} {:>12} {:>9}  not fitted: {e}",
                c.kind,
                unit_label(c.unit),
                "-",
                "no"
            ),
            None => p!(
                o,
                "{}",
                format!(
                    "  {:<20} {:<7} {:>12.1} {:>9}  {}",
                    c.kind,
                    unit_label(c.unit),
                    c.delta_bic,
                    if c.supported { "yes" } else { "no" },
                    params_line(&c.params)
                )
                .trim_end()
            ),
        }
    }
    p!(
        o,
        "  after the round ({}): residual RMS {} vibrating; {}",
        step.added
            .as_deref()
            .map_or("nothing added".to_string(), |a| format!("+ {a}")),
        ug(step.rms_vibrating_g),
        lof_line(&step.lack_of_fit)
    );
}

/// The verdict in words, with the effects found and their parameters.
fn write_verdict(o: &mut String, d: &WaveDiagnosis) {
    let (before, after) = (&d.lack_of_fit_before, &d.lack_of_fit);
    let z_noise = d.options.z_noise;
    match d.verdict.as_str() {
        "noise" => p!(
            o,
            "Verdict: noise. The model as is predicts the readings within their noise \
             (lack of fit z {:.2} < {z_noise}): no effect is missing that these logs can see.",
            after.z
        ),
        "effect" => p!(
            o,
            "Verdict: missing effect{} `{}`: with {} the lack of fit z falls from {:.2} to \
             {:.2} (< {z_noise}), chi2 per reading vibrating {:.4}.",
            if d.found.len() > 1 { "s" } else { "" },
            d.found.join("` + `"),
            if d.found.len() > 1 { "them" } else { "it" },
            before.z,
            after.z,
            d.chi2_per_dof
        ),
        "confounded" => {
            if !d.found.is_empty() {
                p!(o, "Found first: {}.", d.found.join(", "));
            }
            p!(
                o,
                "Verdict: confounded. {} explain the residual equally well (delta BIC within \
                 {}): these logs cannot tell them apart.",
                d.confounded.join(" and "),
                d.options.bic_tie
            );
        }
        _ if d.found.is_empty() => p!(
            o,
            "Verdict: unexplained. The lack of fit z {:.2} (>= {z_noise}) remains and no \
             candidate of the library is supported.",
            after.z
        ),
        _ => p!(
            o,
            "Verdict: found {}, but structure remains unexplained: the lack of fit z falls \
             from {:.2} to {:.2} (>= {z_noise}), chi2 per reading vibrating {:.4}.",
            d.found.join(" + "),
            before.z,
            after.z,
            d.chi2_per_dof
        ),
    }
    for (kind, unit, ps) in effect_groups(&d.params) {
        let on = unit.map_or(String::new(), |u| format!(" (unit {u})"));
        p!(o, "  {kind}{on}: {}", params_line(&ps));
    }
    if let Some(delay) = fitted_delay(d) {
        p!(
            o,
            "  sensors' delay (fitted): {}",
            delay_us(delay.value, delay.sigma)
        );
    }
}

/// The noise per unit and the 1 s windows' residual against it.
fn write_noise(o: &mut String, d: &WaveDiagnosis) {
    let units: Vec<String> = d
        .noise
        .sigma_g
        .iter()
        .enumerate()
        .map(|(u, s)| format!("unit {u} {}", ug(*s)))
        .collect();
    p!(
        o,
        "noise per reading ({}): {}",
        if d.noise.from_quiet {
            "from the quiet readings"
        } else {
            "from the fit's own residual: too few quiet readings"
        },
        units.join(", ")
    );
    let (vib, quiet) = d.windows.iter().fold(
        (0, 0),
        |(v, q), w| {
            if w.quiet {
                (v, q + 1)
            } else {
                (v + 1, q)
            }
        },
    );
    let ratio = d.window_residual_rms_g / d.window_noise_rms_g;
    p!(
        o,
        "{} s windows: residual RMS {} ({vib} vibrating) vs noise RMS {} ({quiet} quiet): \
         ratio {}",
        d.options.window_s,
        ug(d.window_residual_rms_g),
        ug(d.window_noise_rms_g),
        if ratio.is_finite() {
            format!("{ratio:.2}")
        } else {
            "n/a".into()
        }
    );
}

/// What `vibrocomp lab diagnose` prints for logs diagnosed on the waveform: the runs,
/// the model as is, the candidates of each round, the verdict, the noise and the
/// windows.
pub fn write_wave_diagnosis(o: &mut String, d: &WaveDiagnosis) {
    write_header(o, d);
    write_runs(o, &d.runs);
    p!(
        o,
        "\nmodel as is ({}{}): {}{}",
        model_line(d),
        if fitted_delay(d).is_some() {
            "; the sensors' delay fitted"
        } else {
            ""
        },
        d.steps.first().map_or(String::new(), |s| format!(
            "residual RMS {} vibrating; ",
            ug(s.rms_vibrating_g)
        )),
        lof_line(&d.lack_of_fit_before)
    );
    for (i, step) in d.steps.iter().enumerate().skip(1) {
        let base = d.found.get(..i - 1).unwrap_or(&d.found);
        write_round(o, i, base, step, d.options.bic_support);
    }
    if d.steps.len() <= 1 {
        p!(
            o,
            "\ncandidates: not fitted (the model as is leaves the noise: lack of fit z {:.2} < {})",
            d.lack_of_fit_before.z,
            d.options.z_noise
        );
    }
    p!(o);
    write_verdict(o, d);
    write_noise(o, d);
}

/// What `vibrocomp lab compare` prints for logs on the waveform: the runs, the model's
/// chi2 per reading and z, its fitted parameters (the delay when no log states it),
/// the noise and the windows.
pub fn write_wave_comparison(o: &mut String, d: &WaveDiagnosis) {
    write_header(o, d);
    write_runs(o, &d.runs);
    p!(
        o,
        "\nmodel ({}): {}",
        model_line(d),
        lof_line(&d.lack_of_fit)
    );
    if let Some(delay) = fitted_delay(d) {
        p!(
            o,
            "  sensors' delay (fitted): {}",
            delay_us(delay.value, delay.sigma)
        );
    }
    for (kind, unit, ps) in effect_groups(&d.params) {
        let on = unit.map_or(String::new(), |u| format!(" (unit {u})"));
        p!(o, "  {kind}{on}: {}", params_line(&ps));
    }
    p!(
        o,
        "  {}",
        if d.lack_of_fit.z < d.options.z_noise {
            format!(
                "the model predicts the readings within their noise (z < {})",
                d.options.z_noise
            )
        } else {
            format!(
                "the model misses something under vibration (z >= {}): `lab diagnose` looks for it",
                d.options.z_noise
            )
        }
    );
    write_noise(o, d);
}

/// A hand-made diagnosis for the tests of this module and [`crate::wave_report`].
/// What `lab add` prints on the waveform path after the diagnosis: the fitted delay (the
/// rig file's to state, not the model's) and the file written.
pub fn write_wave_added(o: &mut String, d: &WaveDiagnosis, out: &str) {
    write_wave_diagnosis(o, d);
    if let Some(p) = d.params.iter().find(|p| p.kind == "sensor_chain") {
        let _ = writeln!(
            o,
            "the sensors' delay is the rig's, not the model's: state it in the rig file \
             ([sensors] delay_s = {:.6e}, +- {:.1e} s)",
            p.value, p.sigma
        );
    }
    let _ = writeln!(
        o,
        "wrote {out} (effects: {})",
        d.model.effect_kinds().join(", ")
    );
}

#[cfg(test)]
pub(crate) mod fixture {
    use crate::wave_diagnose::*;
    use crate::{BaseMode, LabModel};
    use vibro_wavefit::{LackOfFit, Noise, PrepareCounts};

    pub fn lof(chi2_vib: f64, z: f64) -> LackOfFit {
        LackOfFit {
            chi2_per_reading_vibrating: chi2_vib,
            chi2_per_reading_quiet: 1.0,
            z,
            inflation: 1.1,
            vibrating: 1500,
            quiet: 500,
        }
    }

    pub fn param(kind: &str, name: &str, unit: Option<usize>, value: f64, sigma: f64) -> ParamOut {
        ParamOut {
            kind: kind.into(),
            name: name.into(),
            unit,
            value,
            sigma,
            sigma_white: sigma * 0.8,
        }
    }

    fn candidate(
        kind: &str,
        unit: Option<usize>,
        delta_bic: f64,
        params: Vec<ParamOut>,
    ) -> CandidateOut {
        CandidateOut {
            kind: kind.into(),
            unit,
            delta_bic,
            chi2: 1000.0,
            params,
            supported: delta_bic <= -10.0,
            error: None,
            starts: 4,
            evaluations: 20,
            elapsed_s: 0.5,
        }
    }

    /// Residuals along a run: `n` readings at 400 Hz, the first and last quarter quiet
    /// (noise), the middle vibrating with `extra_g` of a 3 Hz sine; reading 5 not used.
    pub fn residual(log: &str, n: usize, extra_g: f64) -> RunResidual {
        let t_s: Vec<f64> = (0..n).map(|k| k as f64 / 400.0).collect();
        let quiet: Vec<bool> = (0..n).map(|k| k < n / 4 || k >= 3 * n / 4).collect();
        let residual_g = (0..n)
            .map(|k| {
                if k == 5 {
                    return [f64::NAN; 3];
                }
                // A deterministic stand-in for noise of about 10 ug.
                let noise = 10e-6 * ((k as f64 * 12.9898).sin() * 43758.5453).fract();
                let sig = if quiet[k] {
                    0.0
                } else {
                    extra_g * (2.0 * std::f64::consts::PI * 3.0 * t_s[k]).sin()
                };
                [noise + sig, noise - sig, 0.5 * noise]
            })
            .collect();
        RunResidual {
            log: log.into(),
            t_s,
            quiet,
            residual_g,
        }
    }

    /// Two runs (one with a stated delay), one round that found `mount_resonance` on
    /// every unit, a second where nothing was supported (and `heating` failed).
    pub fn diagnosis(runs: usize, readings: usize) -> WaveDiagnosis {
        let mut model = LabModel::base(BaseMode::Exact);
        let mut t = toml::Table::new();
        t.insert("kind".into(), "mount_resonance".into());
        model.effects.push(t);
        let mr = vec![
            param("mount_resonance", "freq_hz", None, 48.0123, 0.0021),
            param("mount_resonance", "q", None, 12.5, 0.4),
        ];
        let delay = param("sensor_chain", "delay_s", None, 1.2503e-3, 2.1e-6);
        let mut params = mr.clone();
        params.push(delay.clone());
        let mut heating = candidate("heating", None, f64::INFINITY, Vec::new());
        heating.error = Some("heating: no start".into());
        let names: Vec<String> = (0..runs).map(|i| format!("flight{i}.mcap")).collect();
        let windows = (0..runs)
            .flat_map(|r| {
                (0..(readings / 400)).map(move |w| WindowOut {
                    run: r,
                    t_s: w as f64 + 0.5,
                    quiet: w == 0,
                    readings: 400,
                    residual_g: [2e-6, -1e-6, 0.5e-6],
                })
            })
            .collect();
        WaveDiagnosis {
            path: "waveform",
            verdict: "effect".into(),
            found: vec!["mount_resonance".into()],
            params,
            correlation: vec![
                vec![1.0, 0.3, 0.0],
                vec![0.3, 1.0, 0.1],
                vec![0.0, 0.1, 1.0],
            ],
            confounded: Vec::new(),
            chi2_per_dof: 1.0312,
            lack_of_fit_before: lof(4.25, 35.2),
            lack_of_fit: lof(1.0312, 0.8),
            noise: Noise {
                sigma_g: [12.3e-6, 11.0e-6, 9.5e-6],
                from_quiet: true,
            },
            steps: vec![
                StepOut {
                    added: None,
                    chi2: 8000.0,
                    rms_vibrating_g: 115e-6,
                    lack_of_fit: lof(4.25, 35.2),
                    candidates: Vec::new(),
                },
                StepOut {
                    added: Some("mount_resonance".into()),
                    chi2: 2000.0,
                    rms_vibrating_g: 6e-6,
                    lack_of_fit: lof(1.0312, 0.8),
                    candidates: vec![
                        candidate(
                            "sensor_error",
                            Some(2),
                            -15.0,
                            vec![param("sensor_error", "k2_ppm_per_g", Some(2), 3.0, 1.0)],
                        ),
                        candidate("mount_resonance", None, -1234.5, mr.clone()),
                        candidate("vibropendulous", None, 4.2, Vec::new()),
                    ],
                },
                StepOut {
                    added: None,
                    chi2: 2000.0,
                    rms_vibrating_g: 6e-6,
                    lack_of_fit: lof(1.0312, 0.8),
                    candidates: vec![candidate("vibropendulous", None, 3.0, Vec::new()), heating],
                },
            ],
            runs: names
                .iter()
                .enumerate()
                .map(|(i, l)| RunOut {
                    log: l.clone(),
                    counts: PrepareCounts {
                        readings,
                        used: readings - 1,
                        missing: 0,
                        no_reference: 0,
                        uncovered: 1,
                        quiet: readings / 2,
                        transition: 0,
                    },
                    delay_stated: i == 0,
                    delay_s: if i == 0 { 1.0e-3 } else { 1.2503e-3 },
                    band_hz: (20.0, 640.0),
                    grid_points_per_reading: 64,
                    passports_from: "log".into(),
                    vib_blocks_refused: 0,
                    vib_breaks: 0,
                })
                .collect(),
            windows,
            window_residual_rms_g: 1.5e-6,
            window_noise_rms_g: 1.2e-6,
            options: WaveOptions::default(),
            elapsed_s: 12.34,
            timings: Default::default(),
            model,
            residuals: names.iter().map(|l| residual(l, readings, 0.0)).collect(),
            residuals_before: names
                .iter()
                .map(|l| residual(l, readings, 200e-6))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::fixture::diagnosis;
    use super::*;

    #[test]
    fn the_diagnosis_names_runs_rounds_verdict_noise_and_windows() {
        let d = diagnosis(2, 2000);
        let mut o = String::new();
        write_wave_diagnosis(&mut o, &d);
        assert!(o.starts_with("path: waveform"), "{o}");
        // The runs, the delay stated for one and fitted for the other.
        assert!(o.contains("flight0.mcap"), "{o}");
        assert!(o.contains("stated 1000.0 us"), "{o}");
        assert!(o.contains("fitted 1250.3 us"), "{o}");
        // The model as is: its chi2 per reading and z.
        assert!(
            o.contains("model as is (exact mode, effects: none; the sensors' delay fitted): residual RMS 115.000 ug vibrating; chi2 per reading 4.2500 vibrating (1500 readings) vs 1.0000 quiet (500 readings); lack of fit z = 35.20"),
            "{o}"
        );
        // Round 1 sorted by delta BIC: mount_resonance before sensor_error before
        // vibropendulous.
        let (a, b, c) = (
            o.find("  mount_resonance").unwrap(),
            o.find("  sensor_error").unwrap(),
            o.find("  vibropendulous").unwrap(),
        );
        assert!(a < b && b < c, "{o}");
        assert!(o.contains("-1234.5"), "{o}");
        assert!(o.contains("unit 2"), "{o}");
        assert!(
            o.contains("round 2: candidates against the model + mount_resonance"),
            "{o}"
        );
        assert!(o.contains("not fitted: heating: no start"), "{o}");
        // The verdict, the parameters +- sigma, the delay in us.
        assert!(
            o.contains("Verdict: missing effect `mount_resonance`"),
            "{o}"
        );
        assert!(o.contains("z falls from 35.20 to 0.80"), "{o}");
        assert!(o.contains("freq_hz = 4.801230e1 +- 2.10e-3"), "{o}");
        assert!(
            o.contains("sensors' delay (fitted): 1250.3 +- 2.1 us"),
            "{o}"
        );
        assert!(
            o.contains("unit 0 12.300 ug, unit 1 11.000 ug, unit 2 9.500 ug"),
            "{o}"
        );
        assert!(o.contains("from the quiet readings"), "{o}");
        assert!(
            o.contains(
                "residual RMS 1.500 ug (8 vibrating) vs noise RMS 1.200 ug (2 quiet): ratio 1.25"
            ),
            "{o}"
        );
    }

    #[test]
    fn the_comparison_leaves_out_the_candidates() {
        let d = diagnosis(1, 2000);
        let mut o = String::new();
        write_wave_comparison(&mut o, &d);
        assert!(!o.contains("round"), "{o}");
        assert!(!o.contains("delta_bic"), "{o}");
        assert!(o.contains("chi2 per reading 1.0312 vibrating"), "{o}");
        assert!(o.contains("lack of fit z = 0.80"), "{o}");
        assert!(o.contains("within their noise"), "{o}");
        assert!(o.contains("noise per reading"), "{o}");
        assert!(o.contains("ratio 1.25"), "{o}");
    }

    #[test]
    fn a_noise_verdict_says_no_candidate_was_fitted() {
        let mut d = diagnosis(1, 800);
        d.verdict = "noise".into();
        d.found.clear();
        d.params.retain(|p| p.kind == DELAY_KIND);
        d.steps.truncate(1);
        d.lack_of_fit_before.z = 1.2;
        d.lack_of_fit.z = 1.2;
        let mut o = String::new();
        write_wave_diagnosis(&mut o, &d);
        assert!(o.contains("candidates: not fitted"), "{o}");
        assert!(o.contains("Verdict: noise"), "{o}");
        assert!(!o.contains("freq_hz"), "{o}");
    }

    #[test]
    fn uncertainties_read_as_text_does() {
        assert_eq!(
            pm("q", 12.5, f64::NAN),
            "q = 1.250000e1 (not determined by these readings)"
        );
        assert_eq!(delay_us(1.2503e-3, 2.1e-6), "1250.3 +- 2.1 us");
        assert_eq!(delay_us(1.2503e-3, 21e-6), "1250 +- 21 us");
        let groups = effect_groups(&diagnosis(1, 800).params);
        assert_eq!(groups.len(), 1);
        assert_eq!(groups[0].2.len(), 2);
    }
}
