//! The lab's `--json` output against its one schema, `docs/schema/lab-json.schema.json`
//! (issue: "the package drifts from the command line where no test looks").
//!
//! Every variant the JSON can take is serialized here: each verdict, every `Option`
//! present and absent, every list that is left out when empty filled, the empirical
//! correction and `empirical_none`, one log and several, manifests; plus real runs of `compare`,
//! `diagnose` and `add` on a small table, one of which ends "unexplained" with no
//! correction offered. The schema is held both ways:
//!
//! - every output validates (objects are closed, `additionalProperties: false`): a key
//!   added in Rust fails here until the schema has it;
//! - every property of the schema is emitted by some variant: a key the schema names
//!   that Rust never writes fails here too.
//!
//! The hand-made variants are also the Python package's fixtures
//! (`tests/python/package/fixtures/lab-json/`, read by `test_lab_schema.py`, which holds
//! the package's dataclasses against the same schema). They are compared with what
//! this test serializes; regenerate them with
//! `VIBROCOMP_BLESS=1 cargo test -p vibro-lab --test json_schema`.
//!
//! The validator is a small one for the subset of JSON Schema the file uses; it refuses
//! any keyword it does not implement, so it cannot pass a schema by ignoring part of it.

use serde::Serialize;
use serde_json::{json, Map, Value};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use vibro_lab::campaign::BandClip;
use vibro_lab::diagnose::{
    ByVariable, Comparison, Diagnosis, Group, LackOfFit, PathCounts, RankedCandidate,
    RowComparison, Step, Suggestion, Summary, Trend, Verdict,
};
use vibro_lab::empirical::EmpiricalTerm;
use vibro_lab::fit::{FittedParam, NotApplicable, StageUse};
use vibro_lab::flight::GroupScale;
use vibro_lab::inputs::ManifestSummary;
use vibro_lab::log_table::LogTableSummary;
use vibro_lab::waveform::{WaveformCounts, WindowSpan};
use vibro_lab::{
    BaseMode, Budget, BudgetUsed, CampaignTable, DiagnoseOptions, EffectFit, EmpiricalFit, LabModel,
};

fn repo() -> PathBuf {
    let up = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    up.canonicalize().unwrap_or(up)
}

fn schema() -> Value {
    let path = repo().join("docs/schema/lab-json.schema.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{path:?}: {e}"))
}

// ---------------------------------------------------------------------------------
// A validator for the subset of JSON Schema (2020-12) the schema uses.

/// Keywords the validator implements, and annotations it may skip.
const KEYWORDS: &[&str] = &[
    "$ref",
    "anyOf",
    "oneOf",
    "const",
    "enum",
    "type",
    "properties",
    "required",
    "additionalProperties",
    "items",
    "prefixItems",
    "minItems",
    "minimum",
];
const ANNOTATIONS: &[&str] = &["description", "title", "$schema", "$id", "$defs"];

/// Every keyword of `node` (and below) is one the validator implements.
fn check_keywords(node: &Value, at: &str, bad: &mut Vec<String>) {
    let Some(map) = node.as_object() else {
        return;
    };
    for (k, v) in map {
        if !KEYWORDS.contains(&k.as_str()) && !ANNOTATIONS.contains(&k.as_str()) {
            bad.push(format!("{at}: keyword {k:?}"));
        }
        match k.as_str() {
            "properties" | "$defs" => {
                for (name, sub) in v.as_object().into_iter().flatten() {
                    check_keywords(sub, &format!("{at}/{k}/{name}"), bad);
                }
            }
            "anyOf" | "oneOf" | "prefixItems" => {
                for (i, sub) in v.as_array().into_iter().flatten().enumerate() {
                    check_keywords(sub, &format!("{at}/{k}/{i}"), bad);
                }
            }
            "items" | "additionalProperties" => check_keywords(v, &format!("{at}/{k}"), bad),
            _ => {}
        }
    }
}

struct Validator {
    root: Value,
}

impl Validator {
    fn def(&self, name: &str) -> &Value {
        self.root["$defs"]
            .get(name)
            .unwrap_or_else(|| panic!("the schema has no $defs/{name}"))
    }

    /// Errors of `v` (at JSON path `at`) against `node`; `def` is the definition being
    /// checked, and `seen` collects `def.property` for each property present.
    fn validate(
        &self,
        node: &Value,
        v: &Value,
        at: &str,
        def: &str,
        seen: &mut BTreeSet<String>,
    ) -> Vec<String> {
        let mut errors = Vec::new();
        let map = match node {
            Value::Bool(true) => return errors,
            Value::Bool(false) => return vec![format!("{at}: not allowed here")],
            Value::Object(m) => m,
            _ => panic!("schema node at {at} is not an object"),
        };
        if let Some(r) = map.get("$ref").and_then(Value::as_str) {
            let name = r.strip_prefix("#/$defs/").unwrap_or(r);
            return self.validate(self.def(name), v, at, name, seen);
        }
        for (key, exactly_one) in [("anyOf", false), ("oneOf", true)] {
            if let Some(branches) = map.get(key).and_then(Value::as_array) {
                let mut passing = Vec::new();
                let mut why = Vec::new();
                for b in branches {
                    let mut s = BTreeSet::new();
                    let e = self.validate(b, v, at, def, &mut s);
                    if e.is_empty() {
                        passing.push(s);
                    } else {
                        why.push(e.join("; "));
                    }
                }
                match passing.len() {
                    0 => errors.push(format!(
                        "{at}: matches none of {key}: [{}]",
                        why.join(" | ")
                    )),
                    n if exactly_one && n > 1 => {
                        errors.push(format!("{at}: matches {n} branches of oneOf"))
                    }
                    _ => seen.extend(passing.swap_remove(0)),
                }
            }
        }
        if let Some(c) = map.get("const") {
            if c != v {
                errors.push(format!("{at}: {v} is not {c}"));
            }
        }
        if let Some(list) = map.get("enum").and_then(Value::as_array) {
            if !list.contains(v) {
                errors.push(format!("{at}: {v} not one of {list:?}"));
            }
        }
        if let Some(t) = map.get("type") {
            let types: Vec<&str> = match t {
                Value::String(s) => vec![s.as_str()],
                Value::Array(a) => a.iter().filter_map(Value::as_str).collect(),
                _ => panic!("{at}: type {t}"),
            };
            let ok = types.iter().any(|t| match *t {
                "object" => v.is_object(),
                "array" => v.is_array(),
                "string" => v.is_string(),
                "boolean" => v.is_boolean(),
                "null" => v.is_null(),
                "number" => v.is_number(),
                "integer" => v.is_u64() || v.is_i64(),
                other => panic!("{at}: type {other:?}"),
            });
            if !ok {
                errors.push(format!("{at}: {v} is not {types:?}"));
                return errors;
            }
        }
        if let Some(min) = map.get("minimum").and_then(Value::as_f64) {
            if v.as_f64().is_some_and(|x| x < min) {
                errors.push(format!("{at}: {v} below {min}"));
            }
        }
        if let Some(obj) = v.as_object() {
            let props = map.get("properties").and_then(Value::as_object);
            for (k, x) in obj {
                match props.and_then(|p| p.get(k)) {
                    Some(sub) => {
                        seen.insert(format!("{def}.{k}"));
                        errors.extend(self.validate(sub, x, &format!("{at}.{k}"), def, seen));
                    }
                    None => match map.get("additionalProperties") {
                        Some(Value::Bool(false)) => {
                            errors.push(format!("{at}: key {k:?} is not in the schema ({def})"))
                        }
                        Some(sub) => {
                            errors.extend(self.validate(sub, x, &format!("{at}.{k}"), def, seen))
                        }
                        None => {}
                    },
                }
            }
            for r in map
                .get("required")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                let r = r.as_str().unwrap_or_default();
                if !obj.contains_key(r) {
                    errors.push(format!("{at}: required key {r:?} missing ({def})"));
                }
            }
        }
        if let Some(items) = v.as_array() {
            let prefix = map.get("prefixItems").and_then(Value::as_array);
            let skip = prefix.map_or(0, Vec::len);
            for (i, (p, x)) in prefix.into_iter().flatten().zip(items).enumerate() {
                errors.extend(self.validate(p, x, &format!("{at}[{i}]"), def, seen));
            }
            if let Some(rest) = map.get("items") {
                for (i, x) in items.iter().enumerate().skip(skip) {
                    errors.extend(self.validate(rest, x, &format!("{at}[{i}]"), def, seen));
                }
            }
            if let Some(min) = map.get("minItems").and_then(Value::as_u64) {
                if (items.len() as u64) < min {
                    errors.push(format!("{at}: {} items, fewer than {min}", items.len()));
                }
            }
        }
        errors
    }
}

// ---------------------------------------------------------------------------------
// The variants.

/// What `lab add --json` prints (the command line's `AddReport`, with `out`; the
/// Python binding's has no `out`).
#[derive(Serialize)]
struct AddReport<'a> {
    #[serde(skip_serializing_if = "Option::is_none")]
    out: Option<String>,
    effects: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    fit: Option<&'a EffectFit>,
    #[serde(skip_serializing_if = "Option::is_none")]
    empirical: Option<&'a EmpiricalFit>,
}

/// `inner` with the logs' summaries beside it, as the command line and the binding
/// print it (`log`: the one log's, `logs`: every log's when several), and the
/// manifests' summaries (`manifests`, when inputs were manifests).
fn with_inputs<T: Serialize>(
    inner: &T,
    logs: &[LogTableSummary],
    manifests: &[ManifestSummary],
) -> Value {
    let mut v = serde_json::to_value(inner).expect("serializes");
    if let Some(map) = v.as_object_mut() {
        match logs {
            [] => {}
            [one] => {
                map.insert("log".into(), serde_json::to_value(one).expect("serializes"));
            }
            many => {
                map.insert(
                    "logs".into(),
                    serde_json::to_value(many).expect("serializes"),
                );
            }
        }
        if !manifests.is_empty() {
            let m = serde_json::to_value(manifests).expect("serializes");
            map.insert("manifests".into(), m);
        }
    }
    v
}

/// [`with_inputs`] without manifests.
fn with_logs<T: Serialize>(inner: &T, logs: &[LogTableSummary]) -> Value {
    with_inputs(inner, logs, &[])
}

/// Two manifests read: one with its bands clipped to its reference's rate.
fn manifests() -> Vec<ManifestSummary> {
    let clip = BandClip {
        reference_rate_hz: 6400.0,
        broadband_stated_hz: [10.0, 3000.0],
        broadband_used_hz: [10.0, 2560.0],
        psd_bands_cut: 1,
        psd_bands_left_out: 2,
    };
    vec![
        ManifestSummary {
            manifest: "campaign.toml".into(),
            runs: 2,
            band_clipped: Some(clip),
            runs_band_clipped: 2,
        },
        ManifestSummary {
            manifest: "other.toml".into(),
            runs: 3,
            band_clipped: None,
            runs_band_clipped: 0,
        },
    ]
}

fn param(effect: &str, name: &str, value: f64) -> FittedParam {
    FittedParam {
        effect: effect.into(),
        name: name.into(),
        value,
        sigma: 0.5,
        sigma_minus: 0.4,
        sigma_plus: 0.6,
        three_sigma_minus: 1.3,
        three_sigma_plus: 1.9,
    }
}

fn not_applicable() -> NotApplicable {
    NotApplicable {
        effect: "mount_resonance".into(),
        rows: vec![(3, "C003".into()), (7, "R2".into())],
        reason: "random vibration without a spectrum".into(),
    }
}

/// A joint fit; `undetermined`: a parameter the table does not determine (its sigma
/// infinite, its correlations NaN: null in the JSON); `skipped`: rows left out.
fn fit(kinds: &[&str], undetermined: bool, skipped: bool) -> EffectFit {
    let mut params: Vec<FittedParam> = kinds.iter().map(|k| param(k, "k_ppm", 2.0)).collect();
    if undetermined {
        params[0].sigma = f64::INFINITY;
    }
    let n = params.len();
    let correlation = (0..n)
        .map(|i| {
            (0..n)
                .map(|j| match (i == j, undetermined) {
                    (true, _) => 1.0,
                    (false, true) => f64::NAN,
                    (false, false) => 0.25,
                })
                .collect()
        })
        .collect();
    EffectFit {
        kind: kinds[kinds.len() - 1].into(),
        kinds: kinds.iter().map(|k| k.to_string()).collect(),
        params,
        correlation,
        tables: Vec::new(),
        n: 3,
        k: n,
        chi2_before: 900.0,
        chi2_after: 2.5,
        chi2_per_dof_after: 1.25,
        p_value_after: 0.29,
        bic_before: 905.0,
        bic_after: 10.0,
        delta_bic: -895.0,
        rms_residual_before_g: 3e-4,
        rms_residual_after_g: 1e-6,
        shift_g: vec![1e-4, 2e-4, 3e-4],
        effect_shift_g: Vec::new(),
        residual_after_g: vec![1e-6, -1e-6, 0.0],
        not_applicable: if skipped {
            vec![not_applicable()]
        } else {
            Vec::new()
        },
        evaluations: 120,
    }
}

fn empirical(dropped: bool) -> EmpiricalFit {
    EmpiricalFit {
        nature: "not physical",
        terms: vec![EmpiricalTerm {
            key: "p1_al3_g_per_g3".into(),
            meaning: "P1 aL3".into(),
            value: 3e-6,
            sigma: 1e-7,
            cv_chi2: 12.0,
        }],
        variables: vec!["aB1_g".into(), "aL3_g".into()],
        table: toml::Table::new(),
        n: 3,
        chi2_before: 900.0,
        chi2_after: 3.0,
        chi2_per_dof_after: 1.5,
        p_value_after: 0.2,
        cv_chi2_before: 950.0,
        cv_chi2_after: 12.0,
        rms_residual_before_g: 3e-4,
        rms_residual_after_g: 1e-6,
        shift_g: vec![1e-4, 2e-4, 3e-4],
        residual_after_g: vec![1e-6, -1e-6, 0.0],
        found: vec![param("mount_resonance", "q", 8.0)],
        found_tables: Vec::new(),
        dropped: if dropped {
            vec!["high_order_nonlinearity: the correction makes it unnecessary".into()]
        } else {
            Vec::new()
        },
    }
}

fn log_summary(name: &str) -> LogTableSummary {
    LogTableSummary {
        log: name.into(),
        passports_from: "log".into(),
        units: vec!["AL-15".into(); 3],
        estimator_window_s: 1.0,
        estimator_overlap_fraction: 0.5,
        sensor_from_log: [("vib_rate_hz".to_string(), 1600.0)].into_iter().collect(),
        accel_samples: 48_000,
        sensed_from_sensors: 0,
        linear_response_fits: 0,
        linear_response_readings: 0,
        estimates: 60,
        windows: 30,
        windows_used: 28,
        left_out_flagged: 1,
        left_out_incomplete: 1,
        left_out_al_span: 0,
        pool_windows: 0,
        lab_windows: 28,
        conditions: 84,
        ..LogTableSummary::default()
    }
}

fn row(run_id: &str, line: usize, window: bool) -> RowComparison {
    RowComparison {
        run_id: run_id.into(),
        line,
        measured_g: 3.2e-4,
        uncertainty_g: 1e-6,
        predicted_g: 3.1e-4,
        residual_g: 1e-5,
        z: 10.0,
        path: if window { "waveform" } else { "statistics" },
        window: window.then_some(WindowSpan {
            first_latch_ns: 1_000,
            last_latch_ns: 2_000_000,
            readings: 1600,
            taper_readings: 80,
            stage_ve_g: 3.0e-4,
            interval_means_ve_g: 1.0e-5,
        }),
    }
}

/// A comparison; `full`: a log's windows on both paths with their scales.
fn comparison(full: bool) -> Comparison {
    let scale = |path: Option<&'static str>| GroupScale {
        source: 0,
        unit: 1,
        scale: 1.4,
        differences: 40,
        clipped: 2,
        pooled: path.is_none(),
        path,
    };
    Comparison {
        table: "campaign.csv".into(),
        mode: "exact".into(),
        effects: if full {
            vec!["mount_resonance".into()]
        } else {
            Vec::new()
        },
        rows: vec![row("C001", 2, full), row("C002", 3, false)],
        summary: Summary {
            n: 2,
            distinct_conditions: 2,
            rms_residual_g: 1e-5,
            max_abs_residual_g: 1e-5,
            rms_measured_g: 3.2e-4,
            chi2: 200.0,
            dof: 2,
            chi2_per_dof: 100.0,
            p_value: 0.0,
            noise_floor_g: 1e-6,
        },
        by_variable: vec![ByVariable {
            variable: "freq_hz".into(),
            groups: vec![Group {
                label: "20".into(),
                n: 2,
                mean_residual_g: 1e-5,
                rms_residual_g: 1e-5,
                chi2_per_dof: 100.0,
            }],
        }],
        residual_scales: if full {
            vec![scale(Some("waveform")), scale(None)]
        } else {
            Vec::new()
        },
        paths: PathCounts {
            waveform: usize::from(full),
            statistics: 2 - usize::from(full),
        },
        waveform: if full {
            vec![WaveformCounts {
                readings_solved: 48_000,
                readings_uncovered: 10,
                windows_waveform: 1,
                windows_statistics: 1,
                vib_refused: 0,
                vib_breaks: 1,
            }]
        } else {
            Vec::new()
        },
    }
}

fn candidate_fitted() -> RankedCandidate {
    RankedCandidate {
        kind: "mount_resonance".into(),
        physics: "a resonance of the mount".into(),
        signature: "peaks near f0".into(),
        fit: Some(fit(&["mount_resonance"], false, true)),
        not_applicable: None,
        supported: true,
        explains: true,
    }
}

fn candidate_refused() -> RankedCandidate {
    RankedCandidate {
        kind: "cable_whip".into(),
        physics: "a cable's whip".into(),
        signature: "random only".into(),
        fit: None,
        not_applicable: Some("no random rows".into()),
        supported: false,
        explains: false,
    }
}

fn step(action: &str, runners_up: bool) -> Step {
    Step {
        action: action.into(),
        effects: vec!["mount_resonance".into()],
        delta_bic: -895.0,
        bic: 10.0,
        chi2: 2.5,
        chi2_per_dof: 1.25,
        p_value: 0.29,
        rms_residual_g: 1e-6,
        runners_up: if runners_up {
            vec![("high_order_nonlinearity".into(), -12.0)]
        } else {
            Vec::new()
        },
    }
}

fn trend() -> Trend {
    Trend {
        variable: "freq_hz".into(),
        distinct_values: 7,
        explained_fraction: 0.9,
        p_value: 1e-9,
    }
}

fn verdict(kind: &str) -> Verdict {
    match kind {
        "noise" => Verdict::Noise {
            p_value: 0.4,
            chi2_per_dof: 1.02,
        },
        "effect" => Verdict::Effect {
            kind: "mount_resonance".into(),
            kinds: vec!["mount_resonance".into(), "high_order_nonlinearity".into()],
            params: vec![param("mount_resonance", "q", 8.0)],
            correlation: vec![vec![1.0]],
            delta_bic: -895.0,
            rms_residual_before_g: 3e-4,
            rms_residual_after_g: 1e-6,
            chi2_per_dof_after: 1.25,
            physics: vec!["mount_resonance: a resonance of the mount".into()],
        },
        "confounded" => Verdict::Confounded {
            kinds: vec!["mount_resonance".into(), "cable_whip".into()],
            correlation: 0.995,
            suggestions: vec![Suggestion {
                description: "a tone at 300 Hz".into(),
                predictions_g: vec![
                    ("mount_resonance".into(), 1e-4),
                    ("cable_whip".into(), 2e-4),
                ],
                separation_sigma: 100.0,
            }],
            found: vec!["high_order_nonlinearity".into()],
        },
        "unexplained" => Verdict::Unexplained {
            chi2_per_dof: 40.0,
            variables: vec!["aB1_g".into()],
            best: Some("mount_resonance".into()),
            best_explained_fraction: 0.1,
            found: Vec::new(),
            found_explained_fraction: 0.0,
        },
        "unexplained-no-best" => Verdict::Unexplained {
            chi2_per_dof: 40.0,
            variables: Vec::new(),
            best: None,
            best_explained_fraction: 0.0,
            found: Vec::new(),
            found_explained_fraction: 0.0,
        },
        other => panic!("verdict {other}"),
    }
}

/// A diagnosis ending in `v`; `full`: every `Option` present and every list filled.
fn diagnosis(v: Verdict, full: bool) -> Diagnosis {
    let mut options = DiagnoseOptions {
        threads: 2,
        ..DiagnoseOptions::default()
    };
    if full {
        options.candidates = vec!["mount_resonance".into(), "cable_whip".into()];
    }
    Diagnosis {
        comparison: comparison(full),
        trends: vec![trend()],
        trends_after: if full { vec![trend()] } else { Vec::new() },
        lack_of_fit: full.then_some(LackOfFit {
            repeated_groups: 2,
            lack_of_fit_chi2: 30.0,
            lack_of_fit_dof: 5,
            pure_error_chi2: 4.0,
            pure_error_dof: 4,
            f: 6.0,
            p_value: 0.05,
            pure_error_chi2_per_dof: 1.0,
        }),
        candidates: if full {
            vec![candidate_fitted(), candidate_refused()]
        } else {
            Vec::new()
        },
        steps: vec![
            step("model as is", false),
            step("add mount_resonance", full),
        ],
        selected: full.then(|| fit(&["mount_resonance", "high_order_nonlinearity"], true, false)),
        not_applicable: if full {
            vec![not_applicable()]
        } else {
            Vec::new()
        },
        verdict: v,
        options,
        budget: BudgetUsed {
            budget: Budget::default(),
            evaluations: 3000,
            profile_evaluations: 200,
            elapsed_s: 1.5,
            exhausted: full,
            cut_short: if full {
                vec!["cable_whip".into()]
            } else {
                Vec::new()
            },
            stages: vec![StageUse {
                stage: "candidates".into(),
                evaluations: 3000,
                elapsed_s: 1.5,
            }],
        },
        empirical: None,
        empirical_none: None,
    }
}

/// The hand-made variants: `(name, definition, JSON)`.
fn made() -> Vec<(String, &'static str, Value)> {
    let one = [log_summary("flight.mcap")];
    let two = [log_summary("a.mcap"), log_summary("b.mcap")];
    let m = manifests();
    let mut with_correction = diagnosis(verdict("unexplained"), true);
    with_correction.empirical = Some(empirical(true));
    let mut without_correction = diagnosis(verdict("unexplained-no-best"), false);
    without_correction.empirical_none =
        Some("no smooth function of the vibration predicts the residual".into());
    let f = fit(&["mount_resonance"], false, true);
    let (e, e_plain) = (empirical(true), empirical(false));
    let added = |out: Option<&str>, fit, empirical| AddReport {
        out: out.map(str::to_string),
        effects: vec!["mount_resonance".into()],
        fit,
        empirical,
    };
    let d = |v: &str, full| diagnosis(verdict(v), full);
    let variants = [
        (
            "compare-table",
            "Comparison",
            with_logs(&comparison(false), &[]),
        ),
        (
            "compare-log-windows",
            "Comparison",
            with_logs(&comparison(true), &one),
        ),
        (
            "compare-logs",
            "Comparison",
            with_logs(&comparison(true), &two),
        ),
        (
            "compare-manifests",
            "Comparison",
            with_inputs(&comparison(false), &[], &m),
        ),
        (
            "diagnose-noise",
            "Diagnosis",
            with_logs(&d("noise", false), &[]),
        ),
        (
            "diagnose-manifests",
            "Diagnosis",
            with_inputs(&d("noise", false), &[], &m),
        ),
        (
            "diagnose-effect",
            "Diagnosis",
            with_logs(&d("effect", true), &one),
        ),
        (
            "diagnose-confounded",
            "Diagnosis",
            with_logs(&d("confounded", true), &two),
        ),
        (
            "diagnose-unexplained-empirical",
            "Diagnosis",
            with_logs(&with_correction, &[]),
        ),
        (
            "diagnose-unexplained-empirical-none",
            "Diagnosis",
            with_logs(&without_correction, &[]),
        ),
        (
            "add-fit-cli",
            "Added",
            with_logs(&added(Some("model.toml"), Some(&f), None), &[]),
        ),
        (
            "add-empirical",
            "Added",
            with_logs(&added(None, None, Some(&e)), &one),
        ),
        (
            "add-empirical-plain",
            "Added",
            with_logs(&added(None, None, Some(&e_plain)), &two),
        ),
        (
            "add-nothing",
            "Added",
            with_logs(&added(None, None, None), &[]),
        ),
        (
            "add-manifests",
            "Added",
            with_inputs(&added(None, Some(&f), None), &[], &m),
        ),
    ];
    variants
        .into_iter()
        .map(|(name, def, v)| (name.to_string(), def, v))
        .collect()
}

/// The walkthrough's table: an effect found; and the same with a sign pattern of
/// 3e-4 g added to its measured VE (300 uncertainties, no smooth function of the
/// conditions): "unexplained", no empirical correction offered (`empirical_none`).
fn real() -> Vec<(String, &'static str, Value)> {
    let model = LabModel::base(BaseMode::Exact);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/walkthrough-14-rows.csv");
    let table = CampaignTable::load(&path, &model).expect("the walkthrough's table");
    let mut scrambled = table.clone();
    for (i, c) in scrambled.conditions.iter_mut().enumerate() {
        c.ve_measured_g += if (i * 7 + 3) % 5 < 2 { 3e-4 } else { -3e-4 };
    }
    let opts = DiagnoseOptions::default();
    let mut out = Vec::new();
    for (name, t) in [("walkthrough", &table), ("scrambled", &scrambled)] {
        let c = vibro_lab::compare(&model, t).expect("compare");
        out.push((
            format!("real-compare-{name}"),
            "Comparison",
            with_logs(&c, &[]),
        ));
        let c = vibro_lab::compare_evaluated(&model, t, &[]).expect("compare_evaluated");
        out.push((
            format!("real-compare-windows-{name}"),
            "Comparison",
            with_logs(&c, &[]),
        ));
        let d = vibro_lab::diagnose(&model, t, &opts).expect("diagnose");
        if name == "scrambled" {
            assert!(
                matches!(d.verdict, Verdict::Unexplained { .. }) && d.empirical_none.is_some(),
                "the scrambled table is to end unexplained without a correction: {:?} {:?}",
                d.verdict,
                d.empirical_none
            );
        }
        out.push((
            format!("real-diagnose-{name}"),
            "Diagnosis",
            with_logs(&d, &[]),
        ));
    }
    let a = vibro_lab::add::add(
        &model,
        &table,
        &vibro_lab::add::Effects::Diagnosed,
        false,
        &opts,
    )
    .expect("add --diagnosed");
    let report = AddReport {
        out: None,
        effects: a.model.effect_kinds(),
        fit: a.fit.as_ref(),
        empirical: a.empirical.as_ref(),
    };
    out.push((
        "real-add-diagnosed".into(),
        "Added",
        with_logs(&report, &[]),
    ));
    out
}

// ---------------------------------------------------------------------------------
// The tests.

#[test]
fn the_schema_uses_only_keywords_the_validator_implements() {
    let mut bad = Vec::new();
    check_keywords(&schema(), "#", &mut bad);
    assert!(bad.is_empty(), "{bad:#?}");
}

#[test]
fn the_validator_refuses_an_unknown_key_and_a_missing_one() {
    let v = Validator { root: schema() };
    let mut d = with_logs(&diagnosis(verdict("noise"), false), &[]);
    let mut seen = BTreeSet::new();
    assert!(v
        .validate(v.def("Diagnosis"), &d, "$", "Diagnosis", &mut seen)
        .is_empty());
    d["verdict"]["surprise"] = json!(1);
    let e = v.validate(v.def("Diagnosis"), &d, "$", "Diagnosis", &mut seen);
    assert!(e.iter().any(|e| e.contains("surprise")), "{e:?}");
    let mut d = with_logs(&diagnosis(verdict("noise"), false), &[]);
    d.as_object_mut().map(|m| m.remove("budget"));
    let e = v.validate(v.def("Diagnosis"), &d, "$", "Diagnosis", &mut seen);
    assert!(e.iter().any(|e| e.contains("\"budget\"")), "{e:?}");
}

#[test]
fn every_variant_fits_the_schema_and_every_key_of_the_schema_is_emitted() {
    let v = Validator { root: schema() };
    let mut seen = BTreeSet::new();
    let mut errors = Vec::new();
    for (name, def, json) in made().into_iter().chain(real()) {
        let mine = v.validate(v.def(def), &json, &format!("{name}:$"), def, &mut seen);
        if mine.is_empty() {
            // The top level allows any of the results.
            let top = v.validate(
                &v.root,
                &json,
                &format!("{name}:$"),
                "",
                &mut BTreeSet::new(),
            );
            errors.extend(top);
        }
        errors.extend(mine);
    }
    let mut never = Vec::new();
    for (def, node) in v.root["$defs"].as_object().into_iter().flatten() {
        for prop in node["properties"]
            .as_object()
            .into_iter()
            .flatten()
            .map(|p| p.0)
        {
            if !seen.contains(&format!("{def}.{prop}")) {
                never.push(format!("{def}.{prop}"));
            }
        }
    }
    assert!(
        errors.is_empty() && never.is_empty(),
        "outputs the schema does not allow:\n{}\nkeys of the schema no variant emits: {never:?}",
        errors.join("\n")
    );
}

#[test]
fn the_python_packages_fixtures_are_these_variants() {
    let dir = repo().join("tests/python/package/fixtures/lab-json");
    let bless = std::env::var_os("VIBROCOMP_BLESS").is_some();
    let mut stale = Vec::new();
    let made = made();
    for (name, def, json) in &made {
        let path = dir.join(format!("{name}.json"));
        let mut wrapped = Map::new();
        wrapped.insert("definition".into(), json!(def));
        wrapped.insert("json".into(), json.clone());
        let text = serde_json::to_string_pretty(&Value::Object(wrapped)).expect("json") + "\n";
        if bless {
            std::fs::create_dir_all(&dir).expect("fixtures directory");
            std::fs::write(&path, &text).unwrap_or_else(|e| panic!("{path:?}: {e}"));
        } else if std::fs::read_to_string(&path).ok().as_deref() != Some(text.as_str()) {
            stale.push(path.display().to_string());
        }
    }
    let names: BTreeSet<String> = made.iter().map(|m| format!("{}.json", m.0)).collect();
    let extra: Vec<String> = std::fs::read_dir(&dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".json") && !names.contains(n))
                .collect()
        })
        .unwrap_or_default();
    assert!(
        stale.is_empty() && extra.is_empty(),
        "fixtures out of date: {stale:?}, not made here: {extra:?}; regenerate with \
         `VIBROCOMP_BLESS=1 cargo test -p vibro-lab --test json_schema`"
    );
}
