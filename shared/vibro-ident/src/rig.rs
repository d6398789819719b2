//! One unit's VE from a rig's own time-stamped records, MODEL.md section 8 [P2 (16)]:
//! the unit's readings (`time_s` and its output, V, each reading the mean over its
//! interval, latched at its end) and, optionally, a DC-coupled reference accelerometer
//! on the table (`time_s` and body x, y, z, g), with the still / vibrating / still
//! windows on the files' time ([`Segments`]).
//!
//! With the reference, the unit's linear response to the table's motion is fitted over
//! the vibrating window through the reference's exact interval means and removed before
//! the batch means ([`crate::reference`]): the stated uncertainty is then the VE's own.
//! Without it the raw records are measured, and the vibrating record's batch means carry
//! that response: they state many times the VE's scatter over repeats (19 times on the
//! independent rig generator's runs, docs/identification.md).
//!
//! [`RunReference`] prepares a run's reference once for every unit of the run (a
//! campaign's triad, `vibro_lab::campaign`); [`measure_timed_file`] measures one unit
//! from its files (`vibrocomp identify measure --still-before-s ...`).
//!
//! ```
//! use vibro_ident::rig::{parse_body_direction, BodyAxes};
//! // The input axis along -x, OA along +y, PA along -z (a right-handed IA, OA, PA).
//! let axes = BodyAxes {
//!     ia: parse_body_direction("-x").unwrap(),
//!     oa: Some(parse_body_direction("0,1,0").unwrap()),
//!     pa: Some(parse_body_direction("-z").unwrap()),
//! };
//! assert!(axes.problems().is_empty());
//! assert_eq!(axes.ia, [-1.0, 0.0, 0.0]);
//! // Not a unit vector: refused with its norm.
//! assert!(parse_body_direction("0,0,0.9").unwrap_err().contains("norm is 0.900000"));
//! ```

use std::cell::OnceCell;
use std::path::{Path, PathBuf};

use realfft::num_complex::Complex;
use serde::Serialize;
use vibro_physics::passport::Passport;

use crate::chain::{reference_in_g, ReferenceChainRequest};
use crate::reference::{response_knots_hz, IntervalMeans, LinearFit, ResponseBasis};
use crate::table::{read_timed, Timed};
use crate::{
    measure_ve_timed, Error, MeasureOptions, Result, Segments, TimedMeasurement, VeMeasurement,
};

/// The body directions' rules live with the triad's axes (`vibro_physics::triad`), one
/// home for rig files, manifests and these flags.
pub use vibro_physics::triad::{parse_body_direction, unit_vector, UNIT_VECTOR_TOLERANCE};

/// Axes stated as perpendicular within this: `|a . b| <= tolerance`.
pub const PERPENDICULAR_TOLERANCE: f64 = 1e-3;

/// The unit's still reading may differ from what the passport makes of the reference's
/// still reading along the stated axes by this much, g, before the run is refused (a
/// wrong axis or sign is about 1 g off or more; a passport's offset and a reference's
/// bias are far less). As `vibro_lab::campaign::ORIENTATION_CHECK_G`.
pub const STILL_CHECK_G: f64 = 0.05;

/// The fitted response stops at this fraction of the reference's rate at most (as the
/// campaign's: the estimator's broadband band must stay below Nyquist).
pub const RESPONSE_TOP_FRACTION_OF_RATE: f64 = 0.45;

/// A unit's axes in the body frame, unit vectors: the input axis, and the output and
/// pendulum axes when known (both or neither).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BodyAxes {
    pub ia: [f64; 3],
    pub oa: Option<[f64; 3]>,
    pub pa: Option<[f64; 3]>,
}

impl From<&vibro_physics::triad::UnitAxes> for BodyAxes {
    fn from(axes: &vibro_physics::triad::UnitAxes) -> Self {
        let vector = |a: vibro_physics::triad::SignedAxis| {
            let mut v = [0.0; 3];
            v[a.body_index] = f64::from(a.sign);
            v
        };
        Self {
            ia: vector(axes.ia),
            oa: Some(vector(axes.oa)),
            pa: Some(vector(axes.pa)),
        }
    }
}

impl BodyAxes {
    /// Every broken rule as `name = value: rule` (`ia`, `oa`, `pa`): unit vectors, OA
    /// and PA both or neither, the three perpendicular.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        let named = [("ia", Some(self.ia)), ("oa", self.oa), ("pa", self.pa)];
        for (name, v) in named {
            if let Some(v) = v {
                if let Err(rule) = unit_vector(&v) {
                    out.push(format!("{name} = {v:?}: {rule}"));
                }
            }
        }
        let missing = match (self.oa, self.pa) {
            (Some(_), None) => Some("pa"),
            (None, Some(_)) => Some("oa"),
            _ => None,
        };
        if let Some(key) = missing {
            out.push(format!(
                "{key}: missing: give OA and PA both or neither (they carry the passport's \
                 cross-axis terms m1, m2)"
            ));
        }
        let present: Vec<(&str, [f64; 3])> = named
            .iter()
            .filter_map(|(n, v)| Some((*n, (*v)?)))
            .collect();
        for (i, (n1, a)) in present.iter().enumerate() {
            for (n2, b) in &present[i + 1..] {
                let dot: f64 = (0..3).map(|k| a[k] * b[k]).sum();
                if dot.abs() > PERPENDICULAR_TOLERANCE {
                    out.push(format!(
                        "{n1} = {a:?}, {n2} = {b:?}: must be perpendicular (their dot \
                         product is {dot:.6}, allowed +- {PERPENDICULAR_TOLERANCE})"
                    ));
                }
            }
        }
        out
    }

    /// The passport's linear response [P1 (1)] per body axis, V/g:
    /// `K1 (k1 e_IA + m1 e_OA + m2 e_PA)`; without OA and PA the cross-axis terms are
    /// left out (they are about 1e-3 of the IA term on an AL-15).
    pub fn weights_v_per_g(&self, passport: &Passport) -> [f64; 3] {
        let k1v = passport.k1_v_per_g;
        let mut weights = [0.0; 3];
        for (axis, w) in [
            (Some(self.ia), passport.k1),
            (self.oa, passport.m1),
            (self.pa, passport.m2),
        ] {
            let Some(axis) = axis else { continue };
            for (slot, component) in weights.iter_mut().zip(axis) {
                // On a signed body axis, one component is +-1 and the others 0: the
                // weight is `K1 w sign`, as a triad's axes give it.
                if component != 0.0 {
                    *slot += k1v * w * component;
                }
            }
        }
        weights
    }

    /// `[a1, a2, a3]` (OA, PA, IA) of a body-frame acceleration; OA and PA 0 when not
    /// known.
    pub fn to_unit(&self, body_g: &[f64; 3]) -> [f64; 3] {
        let dot = |v: Option<[f64; 3]>| v.map_or(0.0, |v| (0..3).map(|k| v[k] * body_g[k]).sum());
        [dot(self.oa), dot(self.pa), dot(Some(self.ia))]
    }
}

/// Checks that the segments lie within the readings (their first interval's start to
/// their last latch time, within one reading period before and half a period after).
pub fn check_segments(readings: &Timed, file: &Path, segments: &Segments) -> Result<()> {
    if let Some(problem) = segments.problems().into_iter().next() {
        return Err(Error::Segments { problem });
    }
    let interval_s = readings.step_s;
    let (t0, t1) = span(readings);
    let (lo, hi) = (segments.still_before_s[0], segments.still_after_s[1]);
    if lo < t0 - interval_s || hi > t1 + interval_s * 0.5 {
        return Err(Error::Coverage {
            file: file.display().to_string(),
            problem: format!(
                "the segments span {lo}..{hi} s, the readings {t0}..{t1} s: the segments \
                 must lie within the record"
            ),
        });
    }
    Ok(())
}

fn span(t: &Timed) -> (f64, f64) {
    match (t.time_s.first(), t.time_s.last()) {
        (Some(&a), Some(&b)) => (a, b),
        _ => (f64::NAN, f64::NAN),
    }
}

/// A run's reference prepared for its readings: each body axis's exact interval means
/// at the readings' times, and the fit's basis over the vibrating window, computed once
/// for every unit of the run.
pub struct RunReference<'a> {
    times_s: &'a [f64],
    interval_s: f64,
    segments: Segments,
    inputs: [IntervalMeans; 3],
    basis: Option<ResponseBasis>,
    /// The reference's own interval means, for a unit whose fit fails (computed once).
    means: OnceCell<Vec<Vec<Option<f64>>>>,
}

impl<'a> RunReference<'a> {
    /// Checks that the reference (its first three columns: body x, y, z, g) covers
    /// every segment, and prepares it for the readings. `response_top_hz`: the top
    /// of the fitted response (its knots: [`response_knots_hz`]). The segments are
    /// checked against the readings by [`check_segments`].
    pub fn new(
        readings: &'a Timed,
        reference: &Timed,
        reference_file: &Path,
        segments: &Segments,
        response_top_hz: f64,
    ) -> Result<Self> {
        let interval_s = readings.step_s;
        let (t0_ref, t1_ref) = span(reference);
        let (lo, hi) = (segments.still_before_s[0], segments.still_after_s[1]);
        let name = || reference_file.display().to_string();
        if lo < t0_ref - interval_s || hi > t1_ref + interval_s * 0.5 {
            return Err(Error::Coverage {
                file: name(),
                problem: format!(
                    "the segments span {lo}..{hi} s, the reference {t0_ref}..{t1_ref} s: the \
                     reference must cover every segment"
                ),
            });
        }
        let prepared: Vec<IntervalMeans> = reference
            .columns
            .iter()
            .take(3)
            .filter_map(|x| {
                IntervalMeans::new(x, t0_ref, reference.rate_hz(), interval_s, &readings.time_s)
            })
            .collect();
        let Ok(inputs) = <[IntervalMeans; 3]>::try_from(prepared) else {
            return Err(Error::Coverage {
                file: name(),
                problem: format!(
                    "{} samples of three body axes: the reference needs at least 4 of each",
                    reference.time_s.len()
                ),
            });
        };
        let basis = ResponseBasis::new(
            &inputs,
            &readings.time_s,
            segments.vibrating_s,
            &response_knots_hz(response_top_hz),
        );
        Ok(Self {
            times_s: &readings.time_s,
            interval_s,
            segments: *segments,
            inputs,
            basis,
            means: OnceCell::new(),
        })
    }

    /// The unit's linear response at each reading, V, and its fit: fitted through the
    /// reference over the vibrating window ([`ResponseBasis::fit`]; 0 elsewhere: the
    /// table is still, the still records are the unit's own), or, when the window is
    /// too short for the fit (`None`), the passport's `weights_v_per_g` applied to the
    /// reference's interval means everywhere (NaN where a reading has none).
    pub fn linear_response(
        &self,
        weights_v_per_g: [f64; 3],
        u_v: &[f64],
    ) -> (Vec<f64>, Option<LinearFit>) {
        let fitted = self
            .basis
            .as_ref()
            .and_then(|b| b.fit(weights_v_per_g, u_v));
        match fitted {
            Some((v, fit)) => (
                v.into_iter()
                    .map(|x| if x.is_nan() { 0.0 } else { x })
                    .collect(),
                Some(fit),
            ),
            None => {
                let means = self.means.get_or_init(|| {
                    self.inputs
                        .iter()
                        .map(|m| m.filtered(|_| Complex::new(1.0, 0.0), true, self.times_s))
                        .collect()
                });
                let w = weights_v_per_g;
                (
                    (0..self.times_s.len())
                        .map(|i| match (means[0][i], means[1][i], means[2][i]) {
                            (Some(x), Some(y), Some(z)) => w[0] * x + w[1] * y + w[2] * z,
                            _ => f64::NAN,
                        })
                        .collect(),
                    None,
                )
            }
        }
    }

    /// One unit's VE [P2 (16)] with its linear response removed
    /// ([`RunReference::linear_response`], then [`measure_ve_timed`]); the raw
    /// records' measurement beside it.
    pub fn measure_unit(
        &self,
        u_v: &[f64],
        weights_v_per_g: [f64; 3],
        k1_v_per_g: f64,
        options: &MeasureOptions,
    ) -> Result<UnitVe> {
        let (linear_v, fit) = self.linear_response(weights_v_per_g, u_v);
        let measurement = measure_ve_timed(
            self.times_s,
            self.interval_s,
            u_v,
            Some(&linear_v),
            &self.segments,
            k1_v_per_g,
            options,
        )?;
        Ok(UnitVe {
            measurement,
            linear_response: fit,
        })
    }
}

/// One unit's VE with its linear response removed through the reference.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UnitVe {
    /// The response-removed measurement and the raw records'.
    pub measurement: TimedMeasurement,
    /// The fitted linear response; `None`: the passport's was removed (a vibrating
    /// window too short for the fit).
    pub linear_response: Option<LinearFit>,
}

/// The reference of a [`TimedRequest`].
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceRequest {
    pub file: PathBuf,
    /// Body x, y, z, g.
    pub columns: [String; 3],
    /// The unit's axes in the body frame.
    pub axes: BodyAxes,
    /// The top of the fitted response, Hz; at most
    /// [`RESPONSE_TOP_FRACTION_OF_RATE`] of the reference's rate is used.
    pub response_top_hz: f64,
    /// An AC-coupled reference in V: its chain and orientation ([`crate::chain`]);
    /// `None`: DC-coupled, in g.
    pub chain: Option<ReferenceChainRequest>,
}

/// What to measure from a rig's files (validated by the caller: [`TimedRequest::problems`]).
#[derive(Debug, Clone, PartialEq)]
pub struct TimedRequest {
    /// The readings: `time_s` first, then `column` among others.
    pub file: PathBuf,
    pub column: String,
    pub segments: Segments,
    pub reference: Option<ReferenceRequest>,
    pub options: MeasureOptions,
}

impl TimedRequest {
    /// Every broken rule as `key = value: rule`, with the keys
    /// `column`, `reference_columns`, `ia`/`oa`/`pa`, `response_top_hz`, `batches`,
    /// `tilt_limit_rad` and the segments' (for the caller to name as its flags).
    pub fn problems(&self) -> Vec<String> {
        let mut out = self.segments.problems();
        let column_ok = |c: &str| !c.trim().is_empty() && c != "time_s";
        if !column_ok(&self.column) {
            out.push(format!(
                "column = {:?}: must name the unit's output column (V), not time_s",
                self.column
            ));
        }
        out.extend(self.options.problems());
        if let Some(r) = &self.reference {
            let c = &r.columns;
            if !c.iter().all(|s| column_ok(s)) || c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
                out.push(format!(
                    "reference_columns = {c:?}: must name three different columns other than \
                     time_s: body x, y, z in g"
                ));
            }
            out.extend(r.axes.problems());
            if !(r.response_top_hz.is_finite() && r.response_top_hz > 0.0) {
                out.push(format!(
                    "response_top_hz = {}: must be a finite frequency > 0 Hz",
                    r.response_top_hz
                ));
            }
        }
        out
    }
}

/// A [`TimedRequest`] as a command line states it: each part given or not, as typed.
/// [`TimedRequestRaw::validate`] checks it, every problem at once, each as
/// `key: rule` or `key = value: rule` with the keys of [`TimedRequest::problems`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TimedRequestRaw {
    pub file: PathBuf,
    pub column: Option<String>,
    /// Each window `[from, to]`, s.
    pub still_before_s: Option<Vec<f64>>,
    pub vibrating_s: Option<Vec<f64>>,
    pub still_after_s: Option<Vec<f64>>,
    pub reference: Option<PathBuf>,
    /// Default `ax_g, ay_g, az_g`.
    pub reference_columns: Option<Vec<String>>,
    /// Body directions ([`parse_body_direction`]).
    pub ia: Option<String>,
    pub oa: Option<String>,
    pub pa: Option<String>,
    pub response_top_hz: Option<f64>,
    /// An AC-coupled reference in V (a rig file's `[reference.chain]`): its columns
    /// then default to [`DEFAULT_REFERENCE_VOLT_COLUMNS`].
    pub reference_chain: Option<ReferenceChainRequest>,
    pub options: MeasureOptions,
}

/// The reference's columns when none are named: body x, y, z in g.
pub const DEFAULT_REFERENCE_COLUMNS: [&str; 3] = ["ax_g", "ay_g", "az_g"];

/// An AC-coupled reference's columns when none are named: body x, y, z in V.
pub const DEFAULT_REFERENCE_VOLT_COLUMNS: [&str; 3] = ["ax_v", "ay_v", "az_v"];

impl TimedRequestRaw {
    /// The request, or [`Error::Request`] with every problem: a missing part, a value
    /// that does not parse, then [`TimedRequest::problems`] for what did.
    /// `default_response_top_hz`: the fitted response's top when none is given.
    pub fn validate(self, default_response_top_hz: f64) -> Result<TimedRequest> {
        let mut problems = Vec::new();
        // The keys whose problem is said here: the request's own rules are not applied
        // to their placeholders.
        let mut said: Vec<&str> = Vec::new();
        if self.column.is_none() {
            problems.push("column: missing: the unit's output column of the readings, V".into());
            said.push("column");
        }
        let mut windows = [[f64::NAN; 2]; 3];
        for ((key, given), slot) in [
            ("still_before_s", &self.still_before_s),
            ("vibrating_s", &self.vibrating_s),
            ("still_after_s", &self.still_after_s),
        ]
        .into_iter()
        .zip(&mut windows)
        {
            match given.as_deref() {
                Some(&[from, to]) => *slot = [from, to],
                Some(v) => {
                    let text: Vec<String> = v.iter().map(f64::to_string).collect();
                    problems.push(format!(
                        "{key} = {}: must be two times FROM,TO in s",
                        text.join(",")
                    ));
                    said.push(key);
                }
                None => {
                    problems.push(format!(
                        "{key}: missing: the readings need all three windows, still before, \
                         vibrating and still after (FROM,TO in s)"
                    ));
                    said.push(key);
                }
            }
        }
        let reference = match self.reference {
            None => {
                let with_reference = [
                    ("reference_columns", self.reference_columns.is_some()),
                    ("ia", self.ia.is_some()),
                    ("oa", self.oa.is_some()),
                    ("pa", self.pa.is_some()),
                    ("response_top_hz", self.response_top_hz.is_some()),
                    ("rig", self.reference_chain.is_some()),
                ];
                for (key, given) in with_reference {
                    if given {
                        problems.push(format!(
                            "{key}: applies with a reference (the reference accelerometer's \
                             record)"
                        ));
                    }
                }
                None
            }
            Some(file) => {
                let mut direction = |key: &'static str, text: &Option<String>| {
                    let text = text.as_deref()?;
                    Some(parse_body_direction(text).unwrap_or_else(|rule| {
                        problems.push(format!("{key} = {text:?}: {rule}"));
                        said.push(key);
                        [f64::NAN; 3]
                    }))
                };
                let (ia, oa, pa) = (
                    direction("ia", &self.ia),
                    direction("oa", &self.oa),
                    direction("pa", &self.pa),
                );
                if ia.is_none() {
                    problems.push(
                        "ia: missing: with a reference, the unit's input axis in the body frame \
                         (x, +y, -z or X,Y,Z)"
                            .into(),
                    );
                    said.push("ia");
                }
                let default_columns = match self.reference_chain {
                    None => DEFAULT_REFERENCE_COLUMNS,
                    Some(_) => DEFAULT_REFERENCE_VOLT_COLUMNS,
                }
                .map(String::from);
                let columns = match self.reference_columns {
                    None => default_columns,
                    Some(names) => <[String; 3]>::try_from(names.clone()).unwrap_or_else(|_| {
                        problems.push(format!(
                            "reference_columns = {}: must name three columns: body x, y, z in g",
                            names.join(",")
                        ));
                        said.push("reference_columns");
                        default_columns
                    }),
                };
                Some(ReferenceRequest {
                    file,
                    columns,
                    axes: BodyAxes {
                        ia: ia.unwrap_or([f64::NAN; 3]),
                        oa,
                        pa,
                    },
                    response_top_hz: self.response_top_hz.unwrap_or(default_response_top_hz),
                    chain: self.reference_chain,
                })
            }
        };
        let request = TimedRequest {
            file: self.file,
            column: self.column.unwrap_or_default(),
            segments: Segments {
                still_before_s: windows[0],
                vibrating_s: windows[1],
                still_after_s: windows[2],
            },
            reference,
            options: self.options,
        };
        for p in request.problems() {
            let placeholder = said
                .iter()
                .any(|k| p.starts_with(&format!("{k} = ")) || p.starts_with(&format!("{k}: ")));
            if !placeholder {
                problems.push(p);
            }
        }
        if problems.is_empty() {
            Ok(request)
        } else {
            Err(Error::Request { problems })
        }
    }
}

/// The reference's part of a [`TimedReport`].
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceReport {
    pub file: String,
    pub columns: [String; 3],
    pub rate_hz: f64,
    pub axes: BodyAxes,
    /// Whether the passport's cross-axis terms m1, m2 are in the weights (OA and PA
    /// given).
    pub cross_axis_terms: bool,
    /// The passport's linear response per body axis, V/g ([`BodyAxes::weights_v_per_g`]).
    pub weights_v_per_g: [f64; 3],
    /// The fitted response's top, Hz (the request's, at most
    /// [`RESPONSE_TOP_FRACTION_OF_RATE`] of the rate).
    pub response_top_hz: f64,
    /// The reference's still mean along the unit's axes `[a1, a2, a3]`, g.
    pub still_unit_g: [f64; 3],
    /// The chain undone when the reference is AC-coupled in V; `None`: DC-coupled in g.
    pub chain: Option<ChainReport>,
}

/// The chain of an AC-coupled reference, as undone ([`crate::chain`]).
#[derive(Debug, Clone, Serialize)]
pub struct ChainReport {
    /// Where it is stated (the rig file).
    pub source: String,
    pub sensitivity_v_per_g: [f64; 3],
    /// 0: DC-coupled.
    pub ac_corner_hz: f64,
    pub delay_s: f64,
}

/// The VE measured from a rig's files ([`measure_timed_file`]).
#[derive(Debug, Clone, Serialize)]
pub struct TimedReport {
    pub file: String,
    pub column: String,
    pub passport: String,
    pub readings: usize,
    pub reading_rate_hz: f64,
    pub segments: Segments,
    /// With the linear response removed when a reference was given, else the raw
    /// records' (the same keys as [`crate::MeasureReport`]'s).
    #[serde(flatten)]
    pub measurement: VeMeasurement,
    pub linear_response_removed: bool,
    /// The raw records' measurement (the linear response left in) beside it; `None`
    /// without a reference (it is `measurement`).
    pub raw: Option<VeMeasurement>,
    /// `fitted`: through the reference; `passport`: the passport's response through the
    /// reference (a vibrating window too short for the fit); `none`: no reference.
    pub linear_response_source: &'static str,
    /// The fitted linear response: knots, gain and phase relative to the passport's.
    pub linear_response: Option<LinearFit>,
    pub reference: Option<ReferenceReport>,
}

/// Measures one unit's VE from a rig's files (module docs): the readings' `column`
/// over the request's segments, with the linear response removed through the reference
/// when one is given. The request's rules are checked first ([`TimedRequest::problems`],
/// all at once), then the files are read ([`read_timed`]: every row one period apart,
/// every cell a finite number), the segments checked against them, and, with a
/// reference, the unit's still reading against what the passport makes of the
/// reference's along the stated axes ([`STILL_CHECK_G`]).
pub fn measure_timed_file(request: &TimedRequest, passport: &Passport) -> Result<TimedReport> {
    let problems = request.problems();
    if !problems.is_empty() {
        return Err(Error::Request { problems });
    }
    let name = request.file.display().to_string();
    let readings = read_timed(&request.file, &[request.column.as_str()])?;
    let u_v = readings.columns.first().map_or(&[][..], Vec::as_slice);
    check_segments(&readings, &request.file, &request.segments)?;
    let in_file = |e: Error| Error::Measurement {
        file: name.clone(),
        source: Box::new(e),
    };
    let k1_v_per_g = passport.k1_v_per_g;
    let (timed, fit, reference_report) = match &request.reference {
        None => {
            let timed = measure_ve_timed(
                &readings.time_s,
                readings.step_s,
                u_v,
                None,
                &request.segments,
                k1_v_per_g,
                &request.options,
            )
            .map_err(in_file)?;
            (timed, None, None)
        }
        Some(r) => {
            let columns = [
                r.columns[0].as_str(),
                r.columns[1].as_str(),
                r.columns[2].as_str(),
            ];
            let reference = read_timed(&r.file, &columns)?;
            // An AC-coupled reference in V: into the DC-coupled one in g (crate::chain).
            let reference = match &r.chain {
                None => reference,
                Some(c) => reference_in_g(
                    &reference,
                    &c.chain,
                    &[
                        request.segments.still_before_s,
                        request.segments.still_after_s,
                    ],
                    |t| c.gravity_body_g(t),
                    &r.file,
                )?,
            };
            let response_top_hz = r
                .response_top_hz
                .min(RESPONSE_TOP_FRACTION_OF_RATE * reference.rate_hz());
            let prepared = RunReference::new(
                &readings,
                &reference,
                &r.file,
                &request.segments,
                response_top_hz,
            )?;
            let still_unit_g = check_still(&readings, u_v, &reference, request, r, passport)?;
            let weights_v_per_g = r.axes.weights_v_per_g(passport);
            let unit = prepared
                .measure_unit(u_v, weights_v_per_g, k1_v_per_g, &request.options)
                .map_err(in_file)?;
            let report = ReferenceReport {
                file: r.file.display().to_string(),
                columns: r.columns.clone(),
                rate_hz: reference.rate_hz(),
                axes: r.axes,
                cross_axis_terms: r.axes.oa.is_some(),
                weights_v_per_g,
                response_top_hz,
                still_unit_g,
                chain: r.chain.as_ref().map(|c| ChainReport {
                    source: c.source.clone(),
                    sensitivity_v_per_g: c.chain.sensitivity_v_per_g,
                    ac_corner_hz: c.chain.ac_corner_hz,
                    delay_s: c.chain.delay_s,
                }),
            };
            (unit.measurement, unit.linear_response, Some(report))
        }
    };
    let linear_response_source = match (&reference_report, &fit) {
        (None, _) => "none",
        (Some(_), Some(_)) => "fitted",
        (Some(_), None) => "passport",
    };
    Ok(TimedReport {
        file: name,
        column: request.column.clone(),
        passport: passport.id().to_string(),
        readings: readings.time_s.len(),
        reading_rate_hz: readings.rate_hz(),
        segments: request.segments,
        measurement: timed.measurement,
        linear_response_removed: timed.linear_response_removed,
        raw: timed.raw,
        linear_response_source,
        linear_response: fit,
        reference: reference_report,
    })
}

/// The unit's still reading against (FP) [P1 (1)] of the reference's still mean along
/// the stated axes: refused when more than [`STILL_CHECK_G`] apart. Returns the
/// reference's still mean along the unit's axes `[a1, a2, a3]`, g.
fn check_still(
    readings: &Timed,
    u_v: &[f64],
    reference: &Timed,
    request: &TimedRequest,
    r: &ReferenceRequest,
    passport: &Passport,
) -> Result<[f64; 3]> {
    let seg = &request.segments;
    let still = |t: f64, interval_s: f64| {
        let inside = |w: [f64; 2]| t - interval_s >= w[0] - 1e-9 && t <= w[1] + 1e-9;
        inside(seg.still_before_s) || inside(seg.still_after_s)
    };
    let mean = |times: &[f64], x: &[f64], interval_s: f64| {
        let (mut sum, mut n) = (0.0, 0usize);
        for (t, v) in times.iter().zip(x) {
            if still(*t, interval_s) {
                sum += v;
                n += 1;
            }
        }
        (n > 0).then(|| sum / n as f64)
    };
    let body: Vec<Option<f64>> = reference
        .columns
        .iter()
        .map(|c| mean(&reference.time_s, c, 0.0))
        .collect();
    let u_still_v = mean(&readings.time_s, u_v, readings.step_s);
    let [x, y, z] = [0, 1, 2].map(|i| body.get(i).copied().flatten());
    let (Some(x), Some(y), Some(z), Some(u_still_v)) = (x, y, z, u_still_v) else {
        // The segments' checks left no still reading: measure_ve_timed says so.
        return Ok([f64::NAN; 3]);
    };
    let a = r.axes.to_unit(&[x, y, z]);
    let expected_v = vibro_physics::fp::output_v(passport, a[0], a[1], a[2]);
    let off_g = ((u_still_v - expected_v) / passport.k1_v_per_g).abs();
    if off_g > STILL_CHECK_G {
        return Err(Error::Coverage {
            file: request.file.display().to_string(),
            problem: format!(
                "column {}: the still readings average {u_still_v:.6} V = {:.4} g; the \
                 reference ({}) reads [{x:.4}, {y:.4}, {z:.4}] g while still, which along \
                 ia = {:?} makes aL3 = {:.4} g and the passport {} expects {expected_v:.6} V: \
                 {off_g:.4} g apart, more than {STILL_CHECK_G} g (a wrong axis or sign, \
                 reference columns in the wrong order, or another unit's column)",
                request.column,
                u_still_v / passport.k1_v_per_g,
                r.file.display(),
                r.axes.ia,
                a[2],
                passport.id()
            ),
        });
    }
    Ok(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_parse_as_axes_or_unit_vectors() {
        assert_eq!(parse_body_direction("z"), Ok([0.0, 0.0, 1.0]));
        assert_eq!(parse_body_direction("-x"), Ok([-1.0, 0.0, 0.0]));
        assert_eq!(parse_body_direction(" 0, 1 ,0 "), Ok([0.0, 1.0, 0.0]));
        let v = parse_body_direction("0.6,0,0.8").unwrap();
        assert!((v[0] - 0.6).abs() < 1e-15 && (v[2] - 0.8).abs() < 1e-15);
        assert!(parse_body_direction("w")
            .unwrap_err()
            .contains("signed body axis"));
        assert!(parse_body_direction("1,0")
            .unwrap_err()
            .contains("three finite"));
        assert!(parse_body_direction("nan,0,1")
            .unwrap_err()
            .contains("three finite"));
        assert_eq!(
            parse_body_direction("0,0,2").unwrap_err(),
            "must be a unit vector (its norm is 2.000000, allowed 1 +- 0.001)"
        );
    }

    #[test]
    fn axes_name_every_broken_rule() {
        let axes = BodyAxes {
            ia: [0.0, 0.0, 1.0],
            oa: Some([0.0, 0.6, 0.8]),
            pa: None,
        };
        let p = axes.problems();
        assert_eq!(p.len(), 2, "{p:?}");
        assert!(
            p[0].starts_with("pa: missing: give OA and PA both or neither"),
            "{p:?}"
        );
        assert!(p[1].starts_with("ia = [0.0, 0.0, 1.0], oa = [0.0, 0.6, 0.8]: must be perpendicular (their dot product is 0.800000"), "{p:?}");
    }

    #[test]
    fn weights_are_the_passports_linear_response_per_body_axis() {
        let mut p = vibro_config::resolve_passport("AL-15").unwrap();
        (p.k1_v_per_g, p.k1, p.m1, p.m2) = (-2.0, 0.5, 1e-3, 2e-3);
        // IA -y, OA +z, PA +x: K1 (k1 e_IA + m1 e_OA + m2 e_PA).
        let axes = BodyAxes {
            ia: [0.0, -1.0, 0.0],
            oa: Some([0.0, 0.0, 1.0]),
            pa: Some([1.0, 0.0, 0.0]),
        };
        assert_eq!(axes.weights_v_per_g(&p), [-2.0 * 2e-3, 1.0, -2.0 * 1e-3]);
        let ia_only = BodyAxes {
            oa: None,
            pa: None,
            ..axes
        };
        assert_eq!(ia_only.weights_v_per_g(&p), [0.0, 1.0, 0.0]);
        assert_eq!(axes.to_unit(&[1.0, 2.0, 3.0]), [3.0, 1.0, -2.0]);
    }

    #[test]
    fn a_raw_request_reports_every_problem_once() {
        let raw = TimedRequestRaw {
            file: "readings.csv".into(),
            vibrating_s: Some(vec![1.0, 2.0, 3.0]),
            still_after_s: Some(vec![0.5, 4.0]),
            still_before_s: Some(vec![0.0, 1.0]),
            reference: Some("reference.csv".into()),
            ia: Some("0,0,0.9".into()),
            oa: Some("x".into()),
            ..Default::default()
        };
        let Err(Error::Request { problems }) = raw.validate(2000.0) else {
            panic!("accepted")
        };
        assert_eq!(
            problems,
            [
                "column: missing: the unit's output column of the readings, V",
                "vibrating_s = 1,2,3: must be two times FROM,TO in s",
                "ia = \"0,0,0.9\": must be a unit vector (its norm is 0.900000, allowed 1 +- 0.001)",
                "pa: missing: give OA and PA both or neither (they carry the passport's \
                 cross-axis terms m1, m2)",
            ]
        );
        let good = TimedRequestRaw {
            file: "readings.csv".into(),
            column: Some("u3_v".into()),
            still_before_s: Some(vec![0.0, 1.0]),
            vibrating_s: Some(vec![1.2, 1.9]),
            still_after_s: Some(vec![2.1, 3.0]),
            ia: Some("z".into()),
            ..Default::default()
        };
        let Err(Error::Request { problems }) = good.clone().validate(2000.0) else {
            panic!("accepted")
        };
        assert_eq!(
            problems,
            ["ia: applies with a reference (the reference accelerometer's record)"]
        );
        let request = TimedRequestRaw { ia: None, ..good }
            .validate(2000.0)
            .unwrap();
        assert_eq!(request.segments.vibrating_s, [1.2, 1.9]);
        assert!(request.reference.is_none());
    }
}
