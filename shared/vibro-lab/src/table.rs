//! The campaign table: one row per test condition (docs/lab.md).
//!
//! Required columns ([`REQUIRED_COLUMNS`]), in the unit's axes (1 = OA, 2 = PA,
//! 3 = IA, MODEL.md section 1): `run_id`, `passport` (an id such as `AL-15`, or a
//! passport file relative to the table's folder; empty: the model's `passport`), the
//! flight (or gravity) acceleration `aL1_g..aL3_g`, the tone `freq_hz`, `aB1_g..aB3_g`,
//! `phase31_deg = phi3 - phi1`, `phase32_deg = phi3 - phi2` (all empty: no tone), the
//! random part `sigma1_g..sigma3_g`, `cov31_g2`, `cov32_g2`, `kurtosis3` (all empty:
//! no random part), the measured VE and its standard uncertainty. Any other column is
//! an extra numeric variable (empty cells are NaN); the lab understands
//! `vibrating_s` (length of the vibrating record, for heating; default 300 s) and
//! `band_lo_hz`, `band_hi_hz` (the random part as a flat band, which the filtering
//! effects need). Lines starting with `#` are comments.

use crate::table_input::{quote, Problems, TableReader, MAX_PASSPORT_BYTES, MAX_TEXT_CELL_BYTES};
use crate::{Error, Result};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vibro_effects::model::LabModel;
use vibro_effects::predict::flat_passport;
use vibro_physics::passport::Passport;
use vibro_physics::vibration::{PsdBand, Tone, Vibration};
use vibro_toml::echo::excerpt;

/// The columns every table must have, in the documented order.
pub const REQUIRED_COLUMNS: [&str; 19] = [
    "run_id",
    "passport",
    "aL1_g",
    "aL2_g",
    "aL3_g",
    "freq_hz",
    "aB1_g",
    "aB2_g",
    "aB3_g",
    "phase31_deg",
    "phase32_deg",
    "sigma1_g",
    "sigma2_g",
    "sigma3_g",
    "cov31_g2",
    "cov32_g2",
    "kurtosis3",
    "ve_measured_g",
    "ve_uncertainty_g",
];

/// The tone's group of [`REQUIRED_COLUMNS`]: `freq_hz` .. `phase32_deg`.
const TONE_COLUMNS: &[&str] = REQUIRED_COLUMNS.split_at(5).1.split_at(6).0;
/// The random part's group: `sigma1_g` .. `kurtosis3`.
const RANDOM_COLUMNS: &[&str] = REQUIRED_COLUMNS.split_at(11).1.split_at(6).0;

/// Largest acceleration a row may state (flight `aL`, tone amplitude `aB`, random
/// RMS `sigma`), g: shake tables and flights stay within a few hundred g, and the
/// vibration's own check stops at 1000 g.
pub const MAX_ACCEL_G: f64 = 500.0;
/// Highest tone or band frequency, Hz: shake tables work below about 10 kHz.
pub const MAX_FREQ_HZ: f64 = 1e4;
/// Largest phase difference, deg (one turn either way).
pub const MAX_PHASE_DEG: f64 = 360.0;
/// Largest kurtosis of the IA random part (Gaussian: 3; heavy shocks: tens).
pub const MAX_KURTOSIS: f64 = 1e3;
/// Largest measured VE and uncertainty, g: a rectification error beyond 10 g is a
/// broken reading, not a vibration error.
pub const MAX_VE_G: f64 = 10.0;
/// Smallest standard uncertainty, g: below 1e-15 g no rig measures (a noise-free
/// simulation's batch means scatter by 1e-16 g).
pub const MIN_UNCERTAINTY_G: f64 = 1e-15;
/// Smallest uncertainty relative to the measured VE: a VE known to 12 significant
/// digits is not a measurement (and weights `1/u^2` beyond it overflow the fits).
pub const MIN_RELATIVE_UNCERTAINTY: f64 = 1e-12;
/// Longest vibrating record (`vibrating_s`), s: 10 days.
pub const MAX_VIBRATING_S: f64 = 864_000.0;
/// Largest magnitude of any other extra column: whatever its unit, a condition
/// variable beyond 1e12 is not a test condition (and its square overflows the trend
/// fits' sums).
pub const MAX_EXTRA_ABS: f64 = 1e12;

/// Floor of a simulated campaign row's VE uncertainty, g: a noise-free simulation's
/// section-8 VE agrees with the exact model's mean at the true vibration to 5e-11 g
/// RMS over seeds (the lab walkthrough, seeds 1..8: double sums over 1e5 samples and
/// the exact model's quadrature), far above its batch means' 1e-15 g.
pub const SIMULATION_FLOOR_G: f64 = 5e-11;

/// Extra column: the standard uncertainty of the row's IA tone amplitude `aB3_g`, g
/// (the vibration sensor's measurement error); the lab propagates it through the
/// model under test.
pub const A_B3_U_COLUMN: &str = "aB3_u_g";
/// Extra column: the standard uncertainty of the row's IA RMS `sigma3_g`, g.
pub const SIGMA3_U_COLUMN: &str = "sigma3_u_g";

/// Default length of the vibrating record when the table has no `vibrating_s`: the
/// papers' 5 minutes (MODEL.md section 8), s.
pub const DEFAULT_VIBRATING_S: f64 = 300.0;

/// The variables of every row ([`Condition::variables`]), before its extra columns.
const BASE_VARIABLES: [&str; 13] = [
    "aL1_g",
    "aL2_g",
    "aL3_g",
    "freq_hz",
    "aB1_g",
    "aB2_g",
    "aB3_g",
    "phase31_deg",
    "phase32_deg",
    "sigma1_g",
    "sigma2_g",
    "sigma3_g",
    "kurtosis3",
];

/// Whether extra column `name` is a condition variable: the stated uncertainties are
/// not.
fn is_condition_variable(name: &str) -> bool {
    name != A_B3_U_COLUMN && name != SIGMA3_U_COLUMN
}

/// [`Condition::prediction_key`]: the text parts (passport cell, extra columns' names)
/// and the numbers' bits.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) struct PredictionKey {
    names: String,
    bits: Vec<u64>,
}

/// The deterministic part of a condition.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ToneCondition {
    pub freq_hz: f64,
    /// `[aB1, aB2, aB3]`, amplitude, g.
    pub a_b_g: [f64; 3],
    pub phase31_deg: f64,
    pub phase32_deg: f64,
}

/// The broadband random part of a condition.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RandomCondition {
    pub sigma_g: [f64; 3],
    pub cov31_g2: f64,
    pub cov32_g2: f64,
    /// `K_12(0)` between OA and PA: no table column (0 for table rows); a flight
    /// window's estimate has it (`crate::flight`).
    pub cov12_g2: f64,
    pub kurtosis3: f64,
}

/// Where a log's window belongs for the scale of its uncertainty
/// (`crate::flight::data_scales`): the log, the unit, and the run of consecutive
/// windows (none left out between them) it is part of. Rows of one group follow each
/// other in the table in time order. A campaign manifest's rows (`crate::campaign`)
/// are one run per unit, in the manifest's order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
pub struct ScaleGroup {
    /// Which input of a joint table (set by [`CampaignTable::joined`]).
    pub source: u32,
    /// The unit, 0-based, within the log.
    pub unit: u32,
    /// The run of consecutive windows, within the log.
    pub run: u32,
}

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct Condition {
    pub run_id: String,
    /// Line of the file (1-based), for messages.
    pub line: usize,
    /// The passport cell as written (the model's default when it was empty).
    pub passport_ref: String,
    /// The resolved passport, `lambda(w)` dropped (`predict::flat_passport`); shared
    /// by the rows that name it (a passport is 680 bytes, most of a row's memory).
    #[serde(skip)]
    pub passport: Arc<Passport>,
    /// `[aL1, aL2, aL3]`, g.
    pub a_l_g: [f64; 3],
    pub tone: Option<ToneCondition>,
    /// Further tones (a flight window can hold several; a table row holds one), weaker
    /// than `tone`. Empty for table rows.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub more_tones: Vec<ToneCondition>,
    pub random: Option<RandomCondition>,
    /// The random part's spectrum per axis as piecewise-flat bands (a flight window's
    /// estimated band PSDs, `crate::flight`); empty: `band_lo_hz`/`band_hi_hz` if given.
    #[serde(skip)]
    pub bands: Vec<PsdBand>,
    /// Standard uncertainties of `bands`' PSDs, per band and axis, on the same edges (a
    /// flight window's estimate states them); empty when none are stated.
    #[serde(skip)]
    pub bands_u: Vec<PsdBand>,
    /// A log's window or a manifest's run: its stated uncertainty is scaled by the
    /// scatter of its group's residuals against the model under test
    /// (`crate::flight::data_scales`). `None` for table rows, whose uncertainty is what
    /// they state.
    #[serde(skip)]
    pub scale_group: Option<ScaleGroup>,
    pub ve_measured_g: f64,
    pub ve_uncertainty_g: f64,
    /// Extra numeric columns by name (NaN where empty).
    pub extra: BTreeMap<String, f64>,
}

impl Condition {
    /// The vibration at the unit as measured, in its axes `[OA, PA, IA]`: the tone with
    /// `phi3 = 0`, `phi1 = -phase31`, `phi2 = -phase32`; the random part's covariance.
    pub fn vibration(&self) -> Vibration {
        let mut v = Vibration::none();
        for t in self.tone.iter().chain(&self.more_tones) {
            let _ = v.push_tone(Tone {
                freq_hz: t.freq_hz,
                amplitude_g: t.a_b_g,
                phase_rad: [
                    -t.phase31_deg.to_radians(),
                    -t.phase32_deg.to_radians(),
                    0.0,
                ],
            });
        }
        if let Some(r) = &self.random {
            for i in 0..3 {
                v.covariance_g2[i][i] = r.sigma_g[i] * r.sigma_g[i];
            }
            v.covariance_g2[2][0] = r.cov31_g2;
            v.covariance_g2[0][2] = r.cov31_g2;
            v.covariance_g2[2][1] = r.cov32_g2;
            v.covariance_g2[1][2] = r.cov32_g2;
            v.covariance_g2[0][1] = r.cov12_g2;
            v.covariance_g2[1][0] = r.cov12_g2;
            v.kurtosis[2] = r.kurtosis3;
        }
        v
    }

    /// The random part's spectrum: the condition's bands, or one flat band
    /// (`band_lo_hz`, `band_hi_hz`) when given.
    pub fn psd(&self) -> Vec<PsdBand> {
        if !self.bands.is_empty() {
            return self.bands.clone();
        }
        let (Some(r), Some(lo), Some(hi)) = (
            &self.random,
            self.extra
                .get("band_lo_hz")
                .copied()
                .filter(|x| x.is_finite()),
            self.extra
                .get("band_hi_hz")
                .copied()
                .filter(|x| x.is_finite()),
        ) else {
            return Vec::new();
        };
        if hi <= lo {
            return Vec::new();
        }
        vec![PsdBand {
            f_lo_hz: lo,
            f_hi_hz: hi,
            psd_g2_per_hz: r.sigma_g.map(|s| s * s / (hi - lo)),
        }]
    }

    /// Length of the vibrating record, s.
    pub fn vibrating_s(&self) -> f64 {
        self.extra
            .get("vibrating_s")
            .copied()
            .filter(|x| x.is_finite() && *x > 0.0)
            .unwrap_or(DEFAULT_VIBRATING_S)
    }

    /// The vibration direction in words, from which axes vibrate: `IA`, `IA+OA`, ...
    pub fn direction(&self) -> String {
        let mut on = [false; 3];
        for t in self.tone.iter().chain(&self.more_tones) {
            for i in 0..3 {
                on[i] |= t.a_b_g[i] != 0.0;
            }
        }
        if let Some(r) = &self.random {
            for i in 0..3 {
                on[i] |= r.sigma_g[i] != 0.0;
            }
        }
        let names = ["OA", "PA", "IA"];
        let mut parts: Vec<&str> = [2, 0, 1]
            .iter()
            .filter(|&&i| on[i])
            .map(|&i| names[i])
            .collect();
        if parts.is_empty() {
            parts.push("none");
        }
        parts.join("+")
    }

    /// The condition variables the lab looks at the residual against, by name (NaN
    /// where a variable does not apply).
    pub fn variables(&self) -> Vec<(String, f64)> {
        let names = self.variable_names();
        let mut values = Vec::with_capacity(names.len());
        self.variable_values(&mut values);
        names.into_iter().zip(values).collect()
    }

    /// The names of [`Self::variables`], in order.
    fn variable_names(&self) -> Vec<String> {
        let mut names: Vec<String> = BASE_VARIABLES.iter().map(|n| n.to_string()).collect();
        names.extend(
            self.extra
                .keys()
                .filter(|k| is_condition_variable(k))
                .cloned(),
        );
        names
    }

    /// The values of [`Self::variables`], in order, into `out` (cleared first): no
    /// allocation per row when `out` is reused.
    fn variable_values(&self, out: &mut Vec<f64>) {
        let nan = f64::NAN;
        let t = self.tone;
        let r = self.random;
        out.clear();
        out.extend([
            self.a_l_g[0],
            self.a_l_g[1],
            self.a_l_g[2],
            t.map_or(nan, |t| t.freq_hz),
            t.map_or(nan, |t| t.a_b_g[0]),
            t.map_or(nan, |t| t.a_b_g[1]),
            t.map_or(nan, |t| t.a_b_g[2]),
            t.map_or(nan, |t| t.phase31_deg),
            t.map_or(nan, |t| t.phase32_deg),
            r.map_or(nan, |r| r.sigma_g[0]),
            r.map_or(nan, |r| r.sigma_g[1]),
            r.map_or(nan, |r| r.sigma_g[2]),
            r.map_or(nan, |r| r.kurtosis3),
        ]);
        out.extend(
            self.extra
                .iter()
                .filter(|(k, _)| is_condition_variable(k))
                .map(|(_, x)| *x),
        );
    }

    /// The key of everything a prediction reads from the row (the passport named,
    /// acceleration, vibration, spectrum, extra columns; not its name, line, measured
    /// VE, uncertainty or scale group), numbers by their bits: rows with equal keys and
    /// equal passports are one condition, which the fits evaluate once
    /// (`crate::fit::Prepared`).
    pub(crate) fn prediction_key(&self) -> PredictionKey {
        let mut bits = Vec::with_capacity(32 + self.extra.len());
        bits.extend(self.a_l_g.map(f64::to_bits));
        for t in self.tone.iter().chain(&self.more_tones) {
            bits.push(u64::MAX);
            bits.push(t.freq_hz.to_bits());
            bits.extend(t.a_b_g.map(f64::to_bits));
            bits.push(t.phase31_deg.to_bits());
            bits.push(t.phase32_deg.to_bits());
        }
        // Marks between the groups: a tone's count, a random part's presence.
        bits.push(self.more_tones.len() as u64);
        if let Some(r) = &self.random {
            bits.push(1);
            bits.extend(r.sigma_g.map(f64::to_bits));
            bits.extend([r.cov31_g2, r.cov32_g2, r.cov12_g2, r.kurtosis3].map(f64::to_bits));
        } else {
            bits.push(0);
        }
        for bands in [&self.bands, &self.bands_u] {
            bits.push(bands.len() as u64);
            for b in bands {
                bits.push(b.f_lo_hz.to_bits());
                bits.push(b.f_hi_hz.to_bits());
                bits.extend(b.psd_g2_per_hz.map(f64::to_bits));
            }
        }
        let mut names = self.passport_ref.clone();
        for (k, x) in &self.extra {
            names.push('\0');
            names.push_str(k);
            bits.push(x.to_bits());
        }
        PredictionKey { names, bits }
    }

    /// The standard uncertainties of the stated IA tone amplitude and IA RMS, g (0
    /// where the table states none).
    pub fn ia_u_g(&self) -> (f64, f64) {
        let get = |k: &str| {
            self.extra
                .get(k)
                .copied()
                .filter(|x| x.is_finite() && *x > 0.0)
                .unwrap_or(0.0)
        };
        (get(A_B3_U_COLUMN), get(SIGMA3_U_COLUMN))
    }

    /// Whether the row states an uncertainty of its vibration that a model can
    /// propagate ([`Self::ia_u_g`], or [`Self::bands_u`]).
    pub fn states_vibration_u(&self) -> bool {
        self.ia_u_g() != (0.0, 0.0)
            || self
                .bands_u
                .iter()
                .any(|b| b.psd_g2_per_hz.iter().any(|u| *u > 0.0))
    }
}

/// A campaign table.
#[derive(Debug, Clone, Serialize)]
pub struct CampaignTable {
    pub path: PathBuf,
    pub conditions: Vec<Condition>,
    pub extra_columns: Vec<String>,
}

impl CampaignTable {
    /// Whether a row's uncertainty depends on the model under test: it states its
    /// vibration's uncertainty ([`Condition::states_vibration_u`]) or takes its scale
    /// from the residuals ([`Condition::scale_group`]).
    pub fn weights_follow_model(&self) -> bool {
        self.conditions
            .iter()
            .any(|c| c.states_vibration_u() || c.scale_group.is_some())
    }

    /// Every condition variable ([`Condition::variables`]) as a column over the
    /// conditions, in the variables' order (NaN where one does not apply).
    pub fn variable_columns(&self) -> Vec<(String, Vec<f64>)> {
        let Some(first) = self.conditions.first() else {
            return Vec::new();
        };
        let names = first.variable_names();
        let mut columns: Vec<Vec<f64>> = names
            .iter()
            .map(|_| Vec::with_capacity(self.conditions.len()))
            .collect();
        let mut values = Vec::with_capacity(names.len());
        for c in &self.conditions {
            c.variable_values(&mut values);
            for (j, column) in columns.iter_mut().enumerate() {
                column.push(values.get(j).copied().unwrap_or(f64::NAN));
            }
        }
        names.into_iter().zip(columns).collect()
    }

    /// The column of variable `name`, if the table has it.
    pub fn variable_column(&self, name: &str) -> Option<Vec<f64>> {
        let j = self
            .conditions
            .first()?
            .variable_names()
            .iter()
            .position(|n| n == name)?;
        let mut values = Vec::new();
        Some(
            self.conditions
                .iter()
                .map(|c| {
                    c.variable_values(&mut values);
                    values.get(j).copied().unwrap_or(f64::NAN)
                })
                .collect(),
        )
    }

    /// Reads and validates a table; rows with an empty passport take `model.passport`.
    /// The file is read through a fixed buffer within [`crate::table_input`]'s bounds:
    /// `/dev/zero` or a file without a line ending is refused at the cap on a line.
    pub fn load(path: &Path, model: &LabModel) -> Result<Self> {
        let file = std::fs::File::open(path).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        Self::read(file, path, dir, model)
    }

    /// Parses table text; `path` names it in errors, `dir` resolves passport files.
    pub fn parse(text: &str, path: &Path, dir: &Path, model: &LabModel) -> Result<Self> {
        Self::read(text.as_bytes(), path, dir, model)
    }

    /// Reads a table from `input` ([`Self::parse`]), within the bounds of
    /// [`crate::table_input`]: a line's length, the columns, the rows, UTF-8. Every
    /// problem of the rows is listed (the first
    /// [`crate::table_input::MAX_LISTED_PROBLEMS`], the others
    /// counted); a refusal of the reader (a line too long, too many rows) stops it.
    pub fn read<R: std::io::Read>(
        input: R,
        path: &Path,
        dir: &Path,
        model: &LabModel,
    ) -> Result<Self> {
        let name = path.display().to_string();
        let fail = |problems: Problems| Error::Table {
            path: name.clone(),
            problems: problems.into_lines(),
        };
        let one = |problem: String| {
            let mut p = Problems::new();
            p.push(problem);
            fail(p)
        };
        let mut reader = TableReader::new(input, &name)?;
        let header = reader.header()?;
        let missing: Vec<&str> = REQUIRED_COLUMNS
            .iter()
            .copied()
            .filter(|c| !header.iter().any(|h| h == c))
            .collect();
        if !missing.is_empty() {
            return Err(one(format!(
                "missing required column(s) {}; a table needs {}",
                missing.join(", "),
                REQUIRED_COLUMNS.join(", ")
            )));
        }
        let mut seen = HashMap::new();
        for h in &header {
            if seen.insert(h.as_str(), ()).is_some() {
                return Err(one(format!("column {} appears twice", quote(h))));
            }
        }
        let col = |n: &str| header.iter().position(|h| h == n).unwrap_or(usize::MAX);
        let extra_columns: Vec<String> = header
            .iter()
            .filter(|h| !REQUIRED_COLUMNS.contains(&h.as_str()))
            .cloned()
            .collect();
        let mut passports: HashMap<String, std::result::Result<Arc<Passport>, String>> =
            HashMap::new();
        let mut problems = Problems::new();
        let mut conditions = Vec::new();
        while let Some(row) = reader.next_row()? {
            let record = match row {
                Ok(r) => r,
                Err(e) => {
                    problems.push(e);
                    continue;
                }
            };
            let line = record.line;
            let cell = |n: &str| record.cells.get(col(n)).map_or("", String::as_str);
            let num = |n: &str, problems: &mut Problems| -> Option<f64> {
                let s = cell(n);
                if s.is_empty() {
                    return None;
                }
                match s.parse::<f64>() {
                    Ok(x) if x.is_finite() => Some(x),
                    _ => {
                        problems.push(format!(
                            "line {line}, column {n} = {}: must be a finite number",
                            quote(s)
                        ));
                        None
                    }
                }
            };
            let required = |n: &str, problems: &mut Problems| -> f64 {
                if cell(n).is_empty() {
                    problems.push(format!(
                        "line {line}, column {n}: empty; a value is required"
                    ));
                    return f64::NAN;
                }
                num(n, problems).unwrap_or(f64::NAN)
            };
            // Physical range of a parsed value: `ok` false names line, column, the
            // cell as written, and the rule.
            let range = |n: &str, x: f64, ok: bool, rule: &str, problems: &mut Problems| {
                if x.is_finite() && !ok {
                    problems.push(format!(
                        "line {line}, column {n} = {}: must be {rule}",
                        excerpt(cell(n))
                    ));
                }
            };
            let run_id = cell("run_id").to_string();
            if run_id.is_empty() {
                problems.push(format!(
                    "line {line}, column run_id: empty; a value is required"
                ));
            } else if run_id.len() > MAX_TEXT_CELL_BYTES {
                problems.push(format!(
                    "line {line}, column run_id = {} ({} bytes): at most \
                     {MAX_TEXT_CELL_BYTES} bytes (a condition's name)",
                    quote(&run_id),
                    run_id.len()
                ));
            }
            let a_l_g = [
                required("aL1_g", &mut problems),
                required("aL2_g", &mut problems),
                required("aL3_g", &mut problems),
            ];
            for (i, a) in a_l_g.iter().enumerate() {
                range(
                    ["aL1_g", "aL2_g", "aL3_g"][i],
                    *a,
                    a.abs() <= MAX_ACCEL_G,
                    &format!("within +-{MAX_ACCEL_G} g (a flight or gravity acceleration)"),
                    &mut problems,
                );
            }
            let ve_measured_g = required("ve_measured_g", &mut problems);
            let ve_uncertainty_g = required("ve_uncertainty_g", &mut problems);
            range(
                "ve_measured_g",
                ve_measured_g,
                ve_measured_g.abs() <= MAX_VE_G,
                &format!("within +-{MAX_VE_G} g (a vibration error; beyond it a broken reading)"),
                &mut problems,
            );
            if ve_uncertainty_g.is_finite() && ve_uncertainty_g <= 0.0 {
                problems.push(format!(
                    "line {line}, column ve_uncertainty_g = {ve_uncertainty_g}: must be > 0 (a standard uncertainty)"
                ));
            } else {
                range(
                    "ve_uncertainty_g",
                    ve_uncertainty_g,
                    (MIN_UNCERTAINTY_G..=MAX_VE_G).contains(&ve_uncertainty_g),
                    &format!(
                        "within {MIN_UNCERTAINTY_G:e} g ..= {MAX_VE_G} g (a standard uncertainty \
                         below 1e-15 g is not a measurement)"
                    ),
                    &mut problems,
                );
                if ve_measured_g.is_finite()
                    && ve_measured_g.abs() <= MAX_VE_G
                    && (MIN_UNCERTAINTY_G..=MAX_VE_G).contains(&ve_uncertainty_g)
                {
                    range(
                        "ve_uncertainty_g",
                        ve_uncertainty_g,
                        ve_uncertainty_g >= MIN_RELATIVE_UNCERTAINTY * ve_measured_g.abs(),
                        &format!(
                            ">= {MIN_RELATIVE_UNCERTAINTY:e} x |ve_measured_g| = {:e} g (a VE \
                             known to more than 12 digits is not a measurement)",
                            MIN_RELATIVE_UNCERTAINTY * ve_measured_g.abs()
                        ),
                        &mut problems,
                    );
                }
            }
            // A group is present when any of its cells is filled; its key cell must be.
            let tone = if TONE_COLUMNS.iter().any(|c| !cell(c).is_empty()) {
                let f = required("freq_hz", &mut problems);
                if f.is_finite() && f <= 0.0 {
                    problems.push(format!("line {line}, column freq_hz = {f}: must be > 0"));
                }
                range(
                    "freq_hz",
                    f,
                    f <= MAX_FREQ_HZ,
                    &format!("<= {MAX_FREQ_HZ} Hz (shake tables work below about 10 kHz)"),
                    &mut problems,
                );
                let mut g = |n: &str| num(n, &mut problems).unwrap_or(0.0);
                let t = ToneCondition {
                    freq_hz: f,
                    a_b_g: [g("aB1_g"), g("aB2_g"), g("aB3_g")],
                    phase31_deg: g("phase31_deg"),
                    phase32_deg: g("phase32_deg"),
                };
                for (i, a) in t.a_b_g.iter().enumerate() {
                    range(
                        ["aB1_g", "aB2_g", "aB3_g"][i],
                        *a,
                        (0.0..=MAX_ACCEL_G).contains(a),
                        &format!("within 0 ..= {MAX_ACCEL_G} g (a tone amplitude)"),
                        &mut problems,
                    );
                }
                for (n, x) in [
                    ("phase31_deg", t.phase31_deg),
                    ("phase32_deg", t.phase32_deg),
                ] {
                    range(
                        n,
                        x,
                        x.abs() <= MAX_PHASE_DEG,
                        &format!("within +-{MAX_PHASE_DEG} deg (a phase difference)"),
                        &mut problems,
                    );
                }
                Some(t)
            } else {
                None
            };
            let random = if RANDOM_COLUMNS.iter().any(|c| !cell(c).is_empty()) {
                let mut g = |n: &str, default: f64| num(n, &mut problems).unwrap_or(default);
                let r = RandomCondition {
                    sigma_g: [g("sigma1_g", 0.0), g("sigma2_g", 0.0), g("sigma3_g", 0.0)],
                    cov31_g2: g("cov31_g2", 0.0),
                    cov32_g2: g("cov32_g2", 0.0),
                    cov12_g2: 0.0,
                    kurtosis3: g("kurtosis3", 3.0),
                };
                for (i, s) in r.sigma_g.iter().enumerate() {
                    if *s < 0.0 {
                        problems.push(format!(
                            "line {line}, column sigma{}_g = {s}: must be >= 0 (an RMS)",
                            i + 1
                        ));
                    } else {
                        range(
                            ["sigma1_g", "sigma2_g", "sigma3_g"][i],
                            *s,
                            *s <= MAX_ACCEL_G,
                            &format!("<= {MAX_ACCEL_G} g (an RMS acceleration)"),
                            &mut problems,
                        );
                    }
                }
                for (n, x) in [("cov31_g2", r.cov31_g2), ("cov32_g2", r.cov32_g2)] {
                    range(
                        n,
                        x,
                        x.abs() <= MAX_ACCEL_G * MAX_ACCEL_G,
                        &format!(
                            "within +-{} g^2 (a covariance of RMS <= {MAX_ACCEL_G} g)",
                            MAX_ACCEL_G * MAX_ACCEL_G
                        ),
                        &mut problems,
                    );
                }
                if r.kurtosis3 < 1.0 {
                    problems.push(format!(
                        "line {line}, column kurtosis3 = {}: must be >= 1 (E[x^4]/sigma^4)",
                        r.kurtosis3
                    ));
                } else {
                    range(
                        "kurtosis3",
                        r.kurtosis3,
                        r.kurtosis3 <= MAX_KURTOSIS,
                        &format!("<= {MAX_KURTOSIS} (E[x^4]/sigma^4 of real vibration)"),
                        &mut problems,
                    );
                }
                Some(r)
            } else {
                None
            };
            let mut extra = BTreeMap::new();
            for c in &extra_columns {
                let x = num(c, &mut problems).unwrap_or(f64::NAN);
                let (ok, rule) = match c.as_str() {
                    "vibrating_s" => (
                        x > 0.0 && x <= MAX_VIBRATING_S,
                        format!(
                            "within 0 < vibrating_s <= {MAX_VIBRATING_S} s (a record's length)"
                        ),
                    ),
                    "band_lo_hz" | "band_hi_hz" => (
                        (0.0..=MAX_FREQ_HZ).contains(&x),
                        format!(
                            "within 0 ..= {MAX_FREQ_HZ} Hz (a band edge of shake-table vibration)"
                        ),
                    ),
                    _ => (
                        x.abs() <= MAX_EXTRA_ABS,
                        format!("within +-{MAX_EXTRA_ABS:e} (an extra condition variable)"),
                    ),
                };
                range(c, x, ok, &rule, &mut problems);
                extra.insert(c.clone(), x);
            }
            let passport_ref = match (cell("passport"), &model.passport) {
                ("", Some(p)) => p.clone(),
                ("", None) => {
                    problems.push(format!(
                        "line {line}, column passport: empty, and the model names no default passport"
                    ));
                    String::new()
                }
                (p, _) => p.to_string(),
            };
            let passport = if passport_ref.is_empty() {
                None
            } else if passport_ref.len() > MAX_PASSPORT_BYTES {
                problems.push(format!(
                    "line {line}, column passport = {} ({} bytes): at most \
                     {MAX_PASSPORT_BYTES} bytes (a passport id or a path)",
                    quote(&passport_ref),
                    passport_ref.len()
                ));
                None
            } else {
                let resolved = passports.entry(passport_ref.clone()).or_insert_with(|| {
                    let file = dir.join(&passport_ref);
                    let arg = if file.is_file() {
                        file.display().to_string()
                    } else {
                        passport_ref.clone()
                    };
                    vibro_config::resolve_passport(&arg)
                        .map_err(|e| e.to_string())
                        .and_then(|p| flat_passport(&p).map_err(|e| e.to_string()))
                        .map(Arc::new)
                });
                match resolved {
                    Ok(p) => Some(Arc::clone(p)),
                    Err(e) => {
                        problems.push(format!(
                            "line {line}, column passport = {}: {e}",
                            quote(&passport_ref)
                        ));
                        None
                    }
                }
            };
            // Once a row has a problem the table is refused: the rows after it are
            // checked (their problems listed or counted), not kept.
            if !problems.is_empty() {
                conditions = Vec::new();
                continue;
            }
            let Some(passport) = passport else { continue };
            let c = Condition {
                run_id,
                line,
                passport_ref,
                passport,
                a_l_g,
                tone,
                more_tones: Vec::new(),
                random,
                bands: Vec::new(),
                bands_u: Vec::new(),
                scale_group: None,
                ve_measured_g,
                ve_uncertainty_g,
                extra,
            };
            if let Err(e) = c.vibration().validate() {
                problems.push(format!("line {line}: the vibration is not valid: {e}"));
                continue;
            }
            conditions.push(c);
        }
        if !problems.is_empty() {
            return Err(fail(problems));
        }
        if conditions.is_empty() {
            return Err(one("no condition rows".into()));
        }
        Ok(Self {
            path: path.to_path_buf(),
            conditions,
            extra_columns,
        })
    }

    /// Writes the table as CSV (required columns, then the extra ones).
    pub fn write_csv<W: std::io::Write>(&self, w: W) -> Result<()> {
        let io = |e: csv::Error| Error::Io {
            path: self.path.display().to_string(),
            source: std::io::Error::other(e.to_string()),
        };
        // What a CSV row cannot hold (a flight window's condition, `crate::flight`).
        for c in &self.conditions {
            let mut lost = Vec::new();
            if !c.more_tones.is_empty() {
                lost.push(format!("{} tones", 1 + c.more_tones.len()));
            }
            if !c.bands.is_empty() {
                lost.push(format!("a spectrum of {} bands", c.bands.len()));
            }
            if c.random.is_some_and(|r| r.cov12_g2 != 0.0) {
                lost.push("an OA-PA covariance".to_string());
            }
            if !lost.is_empty() {
                return Err(Error::Invalid(format!(
                    "{}: condition {} has {}: a CSV row holds one tone, one flat band and no \
                     OA-PA covariance",
                    self.path.display(),
                    c.run_id,
                    lost.join(", ")
                )));
            }
        }
        let mut out = csv::Writer::from_writer(w);
        let mut header: Vec<&str> = REQUIRED_COLUMNS.to_vec();
        header.extend(self.extra_columns.iter().map(String::as_str));
        out.write_record(&header).map_err(io)?;
        let f = |x: f64| format!("{x:e}");
        for c in &self.conditions {
            let mut row = vec![c.run_id.clone(), c.passport_ref.clone()];
            row.extend(c.a_l_g.map(f));
            match &c.tone {
                Some(t) => {
                    row.push(f(t.freq_hz));
                    row.extend(t.a_b_g.map(f));
                    row.push(f(t.phase31_deg));
                    row.push(f(t.phase32_deg));
                }
                None => row.extend(std::iter::repeat_n(String::new(), 6)),
            }
            match &c.random {
                Some(r) => {
                    row.extend(r.sigma_g.map(f));
                    row.push(f(r.cov31_g2));
                    row.push(f(r.cov32_g2));
                    row.push(f(r.kurtosis3));
                }
                None => row.extend(std::iter::repeat_n(String::new(), 6)),
            }
            row.push(f(c.ve_measured_g));
            row.push(f(c.ve_uncertainty_g));
            for e in &self.extra_columns {
                let x = c.extra.get(e).copied().unwrap_or(f64::NAN);
                row.push(if x.is_finite() { f(x) } else { String::new() });
            }
            out.write_record(&row).map_err(io)?;
        }
        out.flush().map_err(|source| Error::Io {
            path: self.path.display().to_string(),
            source,
        })
    }

    /// The table of a simulated campaign (`vibro_sim::run_campaign`): per condition
    /// the shaker's controlled amplitudes on OA and PA, the unit's vibration sensor's
    /// measurement on IA (tone amplitude by least squares, RMS with the tone removed)
    /// with its batch-means standard uncertainty (`aB3_u_g`, `sigma3_u_g`), the
    /// realised random covariance, the section-8 measured VE and its batch-means
    /// uncertainty combined with `resolution_g` (at least [`SIMULATION_FLOOR_G`], how
    /// closely a run without any noise agrees with the model);
    /// extra columns `tp`, `angle_deg`, `vibrating_s`.
    ///
    /// The sensor's uncertainty is stated, not folded into `ve_uncertainty_g`: how much
    /// it moves the prediction depends on the model (near a mount resonance the VE
    /// rises faster with the amplitude than the base model says), so the lab
    /// propagates it through the model under test (docs/lab.md, "Uncertainty").
    pub fn from_campaign(
        path: &Path,
        scenario: &vibro_sim::Scenario,
        summaries: &[vibro_sim::ConditionSummary],
        resolution_g: f64,
    ) -> Result<Self> {
        let floor_g = resolution_g.max(SIMULATION_FLOOR_G);
        let vibrating_s = scenario
            .campaign()
            .map_or(DEFAULT_VIBRATING_S, |c| c.vibrating_s);
        let mut conditions = Vec::new();
        for (k, s) in summaries.iter().enumerate() {
            let c = &s.condition;
            let v = &s.vibration_unit;
            let tone = c.tone.map(|t| ToneCondition {
                freq_hz: t.freq_hz,
                a_b_g: [
                    t.amplitude_g[0],
                    t.amplitude_g[1],
                    s.sensor.tone_amplitude3_g.unwrap_or(t.amplitude_g[2]),
                ],
                phase31_deg: 0.0,
                phase32_deg: 0.0,
            });
            let sigma = s.sigma_unit_g();
            let ia_scale = |tone: bool, realised_g: f64| {
                if tone || realised_g <= 0.0 {
                    1.0
                } else {
                    s.sensor.sigma3_g / realised_g
                }
            };
            let random = (sigma.iter().any(|x| *x > 0.0)).then(|| RandomCondition {
                sigma_g: [
                    sigma[0],
                    sigma[1],
                    if tone.is_some() {
                        sigma[2]
                    } else {
                        s.sensor.sigma3_g
                    },
                ],
                // The IA covariances at the stated IA RMS (the realised correlation
                // kept): the sensor's RMS differs from the realised one by its error.
                cov31_g2: v.covariance_g2[2][0] * ia_scale(tone.is_some(), sigma[2]),
                cov32_g2: v.covariance_g2[2][1] * ia_scale(tone.is_some(), sigma[2]),
                cov12_g2: 0.0,
                kurtosis3: v.kurtosis[2],
            });
            let mut extra = BTreeMap::new();
            extra.insert(A_B3_U_COLUMN.to_string(), f64::NAN);
            extra.insert(SIGMA3_U_COLUMN.to_string(), f64::NAN);
            extra.insert("tp".to_string(), c.tp as f64);
            extra.insert("angle_deg".to_string(), c.angle_deg);
            extra.insert("vibrating_s".to_string(), vibrating_s);
            let passport = vibro_config::resolve_passport(&s.passport_id)
                .map_err(|e| e.to_string())
                .and_then(|p| flat_passport(&p).map_err(|e| e.to_string()))
                .map(Arc::new)
                .map_err(|e| Error::Invalid(format!("condition {}: passport: {e}", c.id)))?;
            let mut row = Condition {
                run_id: c.id.clone(),
                line: k + 2,
                passport_ref: s.passport_id.clone(),
                passport,
                a_l_g: c.a_l_unit_g,
                tone,
                more_tones: Vec::new(),
                random,
                bands: Vec::new(),
                bands_u: Vec::new(),
                scale_group: None,
                ve_measured_g: s.measurement.ve_g,
                ve_uncertainty_g: 0.0,
                extra,
            };
            row.ve_uncertainty_g = s.measurement.ve_sigma_g.hypot(floor_g);
            if let (Some(_), Some(u)) = (row.tone, s.sensor.tone_amplitude3_u_g) {
                row.extra.insert(A_B3_U_COLUMN.to_string(), u);
            }
            if row.tone.is_none() && row.random.is_some() {
                row.extra
                    .insert(SIGMA3_U_COLUMN.to_string(), s.sensor.sigma3_u_g);
            }
            conditions.push(row);
        }
        Ok(Self {
            path: path.to_path_buf(),
            conditions,
            extra_columns: [
                "tp",
                "angle_deg",
                "vibrating_s",
                A_B3_U_COLUMN,
                SIGMA3_U_COLUMN,
            ]
            .map(String::from)
            .to_vec(),
        })
    }
}

impl CampaignTable {
    /// Several tables as one (fitted jointly): the conditions in order, each input's
    /// run ids prefixed with its file name when there are several (`a.mcap:w3-u1`),
    /// the extra columns of all (NaN where an input lacks one). One table is returned
    /// as it is.
    pub fn joined(mut tables: Vec<CampaignTable>) -> Result<Self> {
        if tables.len() == 1 {
            if let Some(t) = tables.pop() {
                return Ok(t);
            }
        }
        if tables.is_empty() {
            return Err(Error::Invalid("no input table".into()));
        }
        let names: Vec<String> = tables
            .iter()
            .map(|t| t.path.display().to_string())
            .collect();
        let mut extra_columns: Vec<String> = Vec::new();
        for t in &tables {
            for c in &t.extra_columns {
                if !extra_columns.contains(c) {
                    extra_columns.push(c.clone());
                }
            }
        }
        let mut conditions = Vec::new();
        for (source, t) in (0u32..).zip(tables) {
            let file = t.path.file_name().map_or_else(
                || t.path.display().to_string(),
                |f| f.to_string_lossy().into(),
            );
            for mut c in t.conditions {
                c.run_id = format!("{file}:{}", c.run_id);
                if let Some(g) = c.scale_group.as_mut() {
                    g.source = source;
                }
                for e in &extra_columns {
                    c.extra.entry(e.clone()).or_insert(f64::NAN);
                }
                conditions.push(c);
            }
        }
        Ok(Self {
            path: PathBuf::from(names.join(" + ")),
            conditions,
            extra_columns,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_effects::model::BaseMode;

    const HEADER: &str = "run_id,passport,aL1_g,aL2_g,aL3_g,freq_hz,aB1_g,aB2_g,aB3_g,phase31_deg,phase32_deg,sigma1_g,sigma2_g,sigma3_g,cov31_g2,cov32_g2,kurtosis3,ve_measured_g,ve_uncertainty_g";

    fn parse(text: &str) -> Result<CampaignTable> {
        CampaignTable::parse(
            text,
            Path::new("c.csv"),
            Path::new("."),
            &LabModel::base(BaseMode::Exact),
        )
    }

    #[test]
    fn rows_parse_into_tones_random_parts_and_extras() {
        let t = parse(&format!(
            "# a comment\n{HEADER},temperature_c\n\
             R1,AL-15,0,0,1,30,0,0,0.42,,,,,,,,,1.3e-5,1e-7,21.5\n\
             R2,AL-15,0,0,-1,,,,,,,0.5,0.5,2,0.1,0,6,2e-4,3e-6,\n"
        ))
        .unwrap();
        assert_eq!(t.conditions.len(), 2);
        assert_eq!(t.extra_columns, ["temperature_c"]);
        let r1 = &t.conditions[0];
        assert_eq!(r1.tone.unwrap().a_b_g, [0.0, 0.0, 0.42]);
        assert!(r1.random.is_none());
        assert_eq!(r1.extra["temperature_c"], 21.5);
        assert_eq!(r1.line, 3);
        let r2 = &t.conditions[1];
        assert!(r2.tone.is_none());
        let v = r2.vibration();
        assert_eq!(v.covariance_g2[2][2], 4.0);
        assert_eq!(v.covariance_g2[0][2], 0.1);
        assert_eq!(v.kurtosis[2], 6.0);
        assert!(r2.extra["temperature_c"].is_nan());
        assert_eq!(r2.direction(), "IA+OA+PA");
        assert_eq!(r1.direction(), "IA");
    }

    #[test]
    fn bad_tables_name_line_column_value_and_rule_all_at_once() {
        let e = parse("run_id,passport,aL1_g\nR1,AL-15,0\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("c.csv: missing required column(s) aL2_g, aL3_g"),
            "{e}"
        );
        let e = parse(&format!(
            "{HEADER}\n\
             R1,AL-15,0,0,x,30,0,0,0.42,,,,,,,,,1e-5,1e-7\n\
             R2,XX-9,0,0,1,30,0,0,0.42,,,,,,,,,1e-5,0\n\
             R3,AL-15,0,0,1,,,,0.4,,,,,,,,,inf,1e-7\n\
             R4,AL-15,0,0,1,,,,,,,-1,,,,,0.5,1e-5,1e-7\n\
             ,,0,0,1,,,,,,,,,,,,,1e-5,1e-7\n"
        ))
        .unwrap_err()
        .to_string();
        for needle in [
            "line 2, column aL3_g = \"x\": must be a finite number",
            "line 3, column ve_uncertainty_g = 0: must be > 0",
            "line 3, column passport = \"XX-9\"",
            "line 4, column freq_hz: empty; a value is required",
            "line 4, column ve_measured_g = \"inf\": must be a finite number",
            "line 5, column sigma1_g = -1: must be >= 0",
            "line 5, column kurtosis3 = 0.5: must be >= 1",
            "line 6, column run_id: empty",
            "line 6, column passport: empty, and the model names no default passport",
        ] {
            assert!(e.contains(needle), "{needle:?} missing from {e}");
        }
    }

    #[test]
    fn a_table_survives_its_own_writer() {
        let t = parse(&format!(
            "{HEADER},vibrating_s\nR1,AL-15,0.5,0,0.8,30,1.2,0,0.42,10,,,,,,,,1.3e-5,1e-7,4\n"
        ))
        .unwrap();
        let mut out = Vec::new();
        t.write_csv(&mut out).unwrap();
        let back = parse(std::str::from_utf8(&out).unwrap()).unwrap();
        let (a, b) = (&t.conditions[0], &back.conditions[0]);
        assert_eq!(a.a_l_g, b.a_l_g);
        assert_eq!(a.tone, b.tone);
        assert_eq!(a.ve_measured_g, b.ve_measured_g);
        assert_eq!(b.vibrating_s(), 4.0);
    }
}
