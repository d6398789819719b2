//! The vibration-error model over arrays of conditions (MODEL.md sections 4 to 7, 10):
//! what `vibrocomp model ve`, `model compensate` and `require` compute for one
//! condition, here for each element of equally long columns. Every value is checked
//! against the rule a file's value obeys (`vibro_physics::vibration::rules`), all
//! problems at once, each as `column[index] = value: rule`.

use std::collections::HashMap;
use std::path::Path;

use anyhow::Context;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use vibro_effects::report::{extended_compensate_of, extended_ve_of};
use vibro_lab::LabModel;
use vibro_physics::compensation::{Mode, UnitCompensator};
use vibro_physics::passport::Passport;
use vibro_physics::report::ve_components;
use vibro_physics::requirements::{self, Environment};
use vibro_physics::vibration::{rules, PsdBand, UnitVibration, Vibration};

use crate::errors::IntoPy;

/// Problems listed before the rest are only counted.
const MAX_LISTED_PROBLEMS: usize = 20;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(passport, m)?)?;
    m.add_function(wrap_pyfunction!(triad, m)?)?;
    m.add_function(wrap_pyfunction!(ve, m)?)?;
    m.add_function(wrap_pyfunction!(compensate, m)?)?;
    m.add_function(wrap_pyfunction!(require, m)?)?;
    Ok(())
}

/// A passport (a TOML file or a shipped id) as its file's fields.
#[pyfunction]
fn passport(spec: &str) -> PyResult<String> {
    let p = vibro_config::resolve_passport(spec)
        .map_err(anyhow::Error::from)
        .py_err()?;
    serde_json::to_string(&p.to_spec())
        .map_err(anyhow::Error::from)
        .py_err()
}

/// A triad (a TOML file, `default` or a shipped id): its units' names, axes and
/// passports, as JSON.
#[pyfunction]
fn triad(spec: &str) -> PyResult<String> {
    let t = vibro_config::resolve_triad(spec)
        .map_err(anyhow::Error::from)
        .py_err()?;
    let units: Vec<serde_json::Value> = (0..3)
        .map(|i| {
            let axes = t.axes.units[i];
            serde_json::json!({
                "name": t.names[i],
                "ia": axes.ia.to_string(),
                "oa": axes.oa.to_string(),
                "pa": axes.pa.to_string(),
                "passport": t.passports[i].to_spec(),
            })
        })
        .collect();
    Ok(serde_json::json!({ "id": t.id, "units": units }).to_string())
}

/// The model's mode by its command-line name.
pub fn parse_mode(name: &str) -> anyhow::Result<Mode> {
    match name {
        "exact" => Ok(Mode::Exact),
        "paper" => Ok(Mode::Paper),
        "as-published" => Ok(Mode::AsPublished),
        other => {
            anyhow::bail!("mode = {other:?}: must be \"exact\", \"paper\" or \"as-published\"")
        }
    }
}

/// The columns of one call, all of length `n`, by name.
struct Columns {
    n: usize,
    cols: HashMap<String, Vec<f64>>,
}

/// The rule each known column obeys.
fn rule_of(name: &str) -> Option<fn(f64) -> Option<&'static str>> {
    Some(match name {
        "al1_g" | "al2_g" | "al3_g" | "reading_g" | "reading1_g" | "reading2_g" => {
            rules::flight_accel_g
        }
        "ab1_g" | "ab2_g" | "ab3_g" => rules::amplitude_g,
        "freq_hz" => rules::freq_hz,
        "phase31_deg" | "phase32_deg" => rules::phase,
        "sigma1_g" | "sigma2_g" | "sigma3_g" => rules::sigma_g,
        "cov31_g2" | "cov32_g2" => rules::covariance_g2,
        "kurtosis3" => rules::kurtosis,
        _ => return None,
    })
}

impl Columns {
    fn new(arrays: &HashMap<String, Bound<'_, PyBytes>>) -> anyhow::Result<Self> {
        let mut cols = HashMap::new();
        let mut n = None;
        for (name, array) in arrays {
            anyhow::ensure!(rule_of(name).is_some(), "unknown column {name:?}");
            let slice = crate::arrays::f64s(array).with_context(|| format!("column {name}"))?;
            match n {
                None => n = Some(slice.len()),
                Some(len) => anyhow::ensure!(
                    len == slice.len(),
                    "{name}: {} values, the other columns {len}",
                    slice.len()
                ),
            }
            cols.insert(name.clone(), slice);
        }
        let columns = Columns {
            n: n.unwrap_or(0),
            cols,
        };
        columns.check()?;
        Ok(columns)
    }

    /// Every value against its rule, all problems at once.
    fn check(&self) -> anyhow::Result<()> {
        let mut names: Vec<&String> = self.cols.keys().collect();
        names.sort();
        let mut problems = Vec::new();
        let mut more = 0usize;
        for name in names {
            let rule = rule_of(name).unwrap_or(|_| None);
            for (i, &v) in self.cols[name].iter().enumerate() {
                if let Some(problem) = rule(v) {
                    if problems.len() < MAX_LISTED_PROBLEMS {
                        problems.push(format!("{name}[{i}] = {v}: {problem}"));
                    } else {
                        more += 1;
                    }
                }
            }
        }
        if more > 0 {
            problems.push(format!("and {more} more"));
        }
        anyhow::ensure!(problems.is_empty(), "{}", problems.join("\n  "));
        Ok(())
    }

    fn get(&self, name: &str, i: usize) -> Option<f64> {
        self.cols.get(name).map(|c| c[i])
    }

    fn value(&self, name: &str, i: usize, default: f64) -> f64 {
        self.get(name, i).unwrap_or(default)
    }

    /// The vibration of condition `i` (as `model ve`'s flags give it).
    fn vibration(&self, i: usize, psd: Option<&[PsdBand]>) -> anyhow::Result<Vibration> {
        let unit = UnitVibration {
            amplitude_g: [
                self.value("ab1_g", i, 0.0),
                self.value("ab2_g", i, 0.0),
                self.value("ab3_g", i, 0.0),
            ],
            freq_hz: self.value("freq_hz", i, 0.0),
            phase31_deg: self.value("phase31_deg", i, 0.0),
            phase32_deg: self.value("phase32_deg", i, 0.0),
            sigma_g: [
                self.get("sigma1_g", i),
                self.get("sigma2_g", i),
                self.get("sigma3_g", i),
            ],
            cov31_g2: self.value("cov31_g2", i, 0.0),
            cov32_g2: self.value("cov32_g2", i, 0.0),
            kurtosis3: self.value("kurtosis3", i, 3.0),
        };
        let vib = unit.to_vibration(psd)?;
        vib.validate()?;
        Ok(vib)
    }

    fn a_l_g(&self, i: usize) -> [f64; 3] {
        [
            self.value("al1_g", i, 0.0),
            self.value("al2_g", i, 0.0),
            self.value("al3_g", i, 0.0),
        ]
    }
}

/// Output columns by name, each with one value per condition; an extended model's
/// effects by kind.
#[derive(Default)]
struct Out {
    columns: Vec<(&'static str, Vec<f64>)>,
    effects: Vec<(String, Vec<f64>)>,
}

impl Out {
    fn push(&mut self, name: &'static str, v: f64) {
        match self.columns.iter_mut().find(|(n, _)| *n == name) {
            Some((_, c)) => c.push(v),
            None => self.columns.push((name, vec![v])),
        }
    }

    fn push_effect(&mut self, kind: &str, v: f64) {
        match self.effects.iter_mut().find(|(k, _)| k == kind) {
            Some((_, c)) => c.push(v),
            None => self.effects.push((kind.to_string(), vec![v])),
        }
    }

    fn into_dict(self, py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
        let d = PyDict::new(py);
        for (name, values) in self.columns {
            let n = values.len();
            d.set_item(name, crate::arrays::out(py, &values, vec![n])?)?;
        }
        let effects = PyDict::new(py);
        for (kind, values) in self.effects {
            let n = values.len();
            effects.set_item(kind, crate::arrays::out(py, &values, vec![n])?)?;
        }
        d.set_item("effects", effects)?;
        Ok(d)
    }
}

/// What a call evaluates: the passport, the base mode or an extended model (its TOML
/// text and the name it is known by), and a band PSD file for the random part.
struct Setup {
    passport: Passport,
    mode: Mode,
    model: Option<(LabModel, String)>,
    psd: Option<Vec<PsdBand>>,
}

fn setup(
    passport: &str,
    mode: &str,
    model: Option<(String, String)>,
    psd: Option<&str>,
) -> anyhow::Result<Setup> {
    let passport = vibro_config::resolve_passport(passport)?;
    let psd = psd
        .map(|p| vibro_config::load_psd_table(Path::new(p)))
        .transpose()?;
    let model = model
        .map(|(text, name)| LabModel::parse(&text, &name).map(|m| (m, name)))
        .transpose()?;
    let mode = match &model {
        Some((m, _)) => vibro_effects::report::compensation_mode(m.mode),
        None => parse_mode(mode)?,
    };
    Ok(Setup {
        passport,
        mode,
        model,
        psd,
    })
}

/// The extended model under random vibration given as RMS: an effect that filters the
/// vibration needs its spectrum (the command line's hint, `model ve --model`).
fn spectrum_hint(vib: &Vibration, psd: Option<&[PsdBand]>) -> &'static str {
    let random = (0..3).any(|i| vib.covariance_g2[i][i] > 0.0);
    if random && psd.is_none() {
        "the extended model under random vibration given as RMS (sigma*_g): an effect \
         that filters the vibration needs its spectrum; give it as a band PSD file (psd=)"
    } else {
        "the extended model"
    }
}

fn ve_rows(s: &Setup, c: &Columns) -> anyhow::Result<Out> {
    let mut out = Out::default();
    let psd = s.psd.as_deref();
    for i in 0..c.n {
        let vib = c
            .vibration(i, psd)
            .with_context(|| format!("condition {i}: the vibration"))?;
        let a_l = c.a_l_g(i);
        if let Some((model, name)) = &s.model {
            let r = extended_ve_of(model, name, &s.passport, a_l, (&vib, psd.unwrap_or(&[])))
                .with_context(|| format!("condition {i}: {}", spectrum_hint(&vib, psd)))?;
            out.push("base_ve_g", r.base_ve_g);
            out.push("sensor_rms_factor", r.sensor_rms_factor);
            out.push("ve_g", r.ve_g);
            for e in &r.effects {
                out.push_effect(&e.kind, e.ve_g);
            }
        } else {
            let v = ve_components(&s.passport, a_l, &vib, s.mode)
                .with_context(|| format!("condition {i}"))?;
            for (name, x) in [
                ("d01_g", v.d01_g),
                ("d02_g", v.d02_g),
                ("d03_g", v.d03_g),
                ("delta1", v.delta1),
                ("delta2_per_g", v.delta2_per_g),
                ("delta3_per_g2", v.delta3_per_g2),
                ("additive_g", v.additive_g),
                ("multiplicative_g", v.multiplicative_g),
                ("total_g", v.total_g),
            ] {
                out.push(name, x);
            }
        }
    }
    Ok(out)
}

fn compensate_rows(s: &Setup, c: &Columns) -> anyhow::Result<Out> {
    let mut out = Out::default();
    let psd = s.psd.as_deref();
    for i in 0..c.n {
        let vib = c
            .vibration(i, psd)
            .with_context(|| format!("condition {i}: the vibration"))?;
        let reading_g = c.value("reading_g", i, 0.0);
        let cross = [c.value("reading1_g", i, 0.0), c.value("reading2_g", i, 0.0)];
        let stages = if let Some((model, name)) = &s.model {
            let r = extended_compensate_of(
                model,
                name,
                s.passport,
                (&vib, psd.unwrap_or(&[])),
                (reading_g, cross),
            )
            .with_context(|| format!("condition {i}: {}", spectrum_hint(&vib, psd)))?;
            out.push("sensor_rms_factor", r.sensor_rms_factor);
            out.push("a4_extended_g", r.a4_extended_g);
            for e in &r.effects {
                out.push_effect(&e.kind, e.ve_g);
            }
            r.stages
        } else {
            let mut unit = UnitCompensator::new(s.passport, s.mode);
            unit.set_vibration(&vib)
                .with_context(|| format!("condition {i}"))?;
            unit.compensate(reading_g, cross)
        };
        for (name, x) in [
            ("a1_g", stages.a1_g),
            ("a2_g", stages.a2_g),
            ("a3_g", stages.a3_g),
            ("a4_g", stages.a4_g),
            ("main_g", stages.main_g),
            ("det_g", stages.det_g),
            ("rand_g", stages.rand_g),
        ] {
            out.push(name, x);
        }
    }
    Ok(out)
}

/// Resolves the setup and the columns, then computes `rows` with the GIL released.
fn per_condition<'py>(
    py: Python<'py>,
    (passport, mode, model, psd): (&str, &str, Option<(String, String)>, Option<&str>),
    columns: &HashMap<String, Bound<'py, PyBytes>>,
    rows: fn(&Setup, &Columns) -> anyhow::Result<Out>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = setup(passport, mode, model, psd).py_err()?;
    let c = Columns::new(columns).py_err()?;
    let out = py.detach(|| rows(&s, &c)).py_err()?;
    out.into_dict(py)
}

/// The VE components of `model ve` (or an extended model's VE) for each condition.
#[pyfunction]
#[pyo3(signature = (passport, columns, mode, model=None, psd=None))]
fn ve<'py>(
    py: Python<'py>,
    passport: &str,
    columns: HashMap<String, Bound<'py, PyBytes>>,
    mode: &str,
    model: Option<(String, String)>,
    psd: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    per_condition(py, (passport, mode, model, psd), &columns, ve_rows)
}

/// The stages of [P2 (17)-(20)] of `model compensate` for each reading.
#[pyfunction]
#[pyo3(signature = (passport, columns, mode, model=None, psd=None))]
fn compensate<'py>(
    py: Python<'py>,
    passport: &str,
    columns: HashMap<String, Bound<'py, PyBytes>>,
    mode: &str,
    model: Option<(String, String)>,
    psd: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    per_condition(py, (passport, mode, model, psd), &columns, compensate_rows)
}

/// `vibrocomp require --json`: the allowed moduli of the passport coefficients for a
/// VE budget (MODEL.md section 10).
#[pyfunction]
fn require(
    dstar_g: f64,
    al3_g: f64,
    ab_g: [f64; 3],
    sigma3_g: f64,
    mode: &str,
) -> PyResult<String> {
    let run = || -> anyhow::Result<String> {
        let mut problems = Vec::new();
        let named = [
            ("al3_g", al3_g, rules::flight_accel_g(al3_g)),
            ("ab1_g", ab_g[0], rules::amplitude_g(ab_g[0])),
            ("ab2_g", ab_g[1], rules::amplitude_g(ab_g[1])),
            ("ab3_g", ab_g[2], rules::amplitude_g(ab_g[2])),
            ("sigma3_g", sigma3_g, rules::sigma_g(sigma3_g)),
        ];
        for (name, v, problem) in named {
            if let Some(rule) = problem {
                problems.push(format!("{name} = {v}: {rule}"));
            }
        }
        anyhow::ensure!(problems.is_empty(), "{}", problems.join("\n  "));
        let env = Environment {
            d_star_g: dstar_g,
            a_l3_g: al3_g,
            ab_g,
            sigma3_g,
        };
        let (mode, reqs) = match mode {
            "paper" => ("paper", requirements::paper(&env)?),
            "exact" => ("exact", requirements::exact(&env)?),
            other => anyhow::bail!("mode = {other:?}: must be \"paper\" or \"exact\""),
        };
        Ok(
            serde_json::json!({ "mode": mode, "dstar_g": dstar_g, "requirements": reqs })
                .to_string(),
        )
    };
    run().py_err()
}
