//! Scenarios (`config/scenarios/*.toml`): what to simulate.
//!
//! A file is read into [`ScenarioRaw`] (every table `deny_unknown_fields`), then
//! validated into a [`Scenario`] by [`Scenario::try_from_raw`], which checks every rule
//! and reports all problems at once, each naming the file, the key path, the value and
//! the rule (`flight.profile[2].t_s = 3: must be greater than the previous t_s = 5`).
//! Only the validated type reaches the simulator. The format is documented in
//! `config/scenarios/README.md`.
//!
//! A scenario is either a **flight** (the triad of RIG.md along a flight profile, with
//! tones and random vibration in body axes) or a shake-table **campaign** (one unit,
//! conditions still / vibrating / still, MODEL.md sections 8-9).
//!
//! File references (triad, passports, PSD tables) are resolved relative to the
//! scenario's directory, then the working directory, then as a shipped id
//! (`default`, `AL-15`, `p1-table3`, ...), so the shipped scenarios, which only use
//! ids, run from anywhere.
//!
//! This module reads, parses and resolves; the pieces live in
//!
//! - `raw`: the file as written ([`ScenarioRaw`] and its tables);
//! - `types`: the validated types ([`Scenario`], [`Flight`], [`Campaign`],
//!   [`Condition`], ...);
//! - `validate`: the rules, raw into validated;
//! - `grid`: a campaign's `[[campaign.grid]]` tables expanded into conditions.

mod checks;
mod grid;
mod raw;
mod sizes;
mod types;
mod validate;

pub use raw::{
    BandRaw, CampaignRaw, FlightRaw, GridRaw, ProfilePointRaw, RandomRaw, RatesRaw, ScenarioRaw,
    SensorRaw, ToneRaw,
};
pub use sizes::{
    MAX_CONDITIONS, MAX_EFFECTS, MAX_GRIDS, MAX_GRID_TABLES, MAX_GRID_VALUES, MAX_INLINE_BANDS,
    MAX_PROFILE_POINTS,
};
pub use types::{
    random_filter_len, Campaign, Condition, Direction, Flight, FlightTone, Profile, RandomSpec,
    Rates, Scenario, ScenarioKind, SensorSpec, TiltAxis,
};
// The triad frame a campaign simulates in: the effects library's, so that the lab
// builds a model's effects in the frame the simulator ran them in.
pub use vibro_effects::campaign_axes;

use crate::{Error, Result};
use std::path::{Path, PathBuf};
use vibro_config::TriadConfig;
use vibro_physics::passport::Passport;
use vibro_physics::vibration::PsdBand;

/// Default vibration-sensor rate, Hz (RIG.md: "25.6 kHz is a common rig rate").
pub const DEFAULT_SENSOR_RATE_HZ: f64 = 25_600.0;
/// Default segment of the non-Gaussian scale mixture, s.
pub const DEFAULT_KURTOSIS_SEGMENT_S: f64 = 0.25;
/// Default resolution of the random-vibration FIR, Hz.
pub const DEFAULT_FILTER_RESOLUTION_HZ: f64 = 1.0;
/// Default number of batches of the batch-means uncertainty (as `vibro-ident`).
pub const DEFAULT_BATCHES: usize = 20;
/// Default tilt limit of the still-drift check, rad (\[P2\], MODEL.md section 8).
pub const DEFAULT_TILT_LIMIT_RAD: f64 = 1e-4;

/// The PSD tables shipped in `config/vibration/`: (id, file, text).
pub const EMBEDDED_PSD_TABLES: [(&str, &str, &str); 2] = [
    (
        "p1-table3",
        "config/vibration/p1-table3.csv",
        include_str!("../../../../config/vibration/p1-table3.csv"),
    ),
    (
        "band-320-640",
        "config/vibration/band-320-640.csv",
        include_str!("../../../../config/vibration/band-320-640.csv"),
    ),
];

/// The scenarios shipped in `config/scenarios/`: (id, file, text).
pub const EMBEDDED_SCENARIOS: [(&str, &str, &str); 10] = [
    (
        "cyclone-4",
        "config/scenarios/cyclone-4.toml",
        include_str!("../../../../config/scenarios/cyclone-4.toml"),
    ),
    (
        "cyclone-4-short",
        "config/scenarios/cyclone-4-short.toml",
        include_str!("../../../../config/scenarios/cyclone-4-short.toml"),
    ),
    (
        "tactical-100s",
        "config/scenarios/tactical-100s.toml",
        include_str!("../../../../config/scenarios/tactical-100s.toml"),
    ),
    (
        "tactical-300s",
        "config/scenarios/tactical-300s.toml",
        include_str!("../../../../config/scenarios/tactical-300s.toml"),
    ),
    (
        "section8-grid",
        "config/scenarios/section8-grid.toml",
        include_str!("../../../../config/scenarios/section8-grid.toml"),
    ),
    (
        "random-runs",
        "config/scenarios/random-runs.toml",
        include_str!("../../../../config/scenarios/random-runs.toml"),
    ),
    (
        "ten-positions",
        "config/scenarios/ten-positions.toml",
        include_str!("../../../../config/scenarios/ten-positions.toml"),
    ),
    (
        "compensation-experiment-al1m",
        "config/scenarios/compensation-experiment-al1m.toml",
        include_str!("../../../../config/scenarios/compensation-experiment-al1m.toml"),
    ),
    (
        "compensation-experiment-aks05",
        "config/scenarios/compensation-experiment-aks05.toml",
        include_str!("../../../../config/scenarios/compensation-experiment-aks05.toml"),
    ),
    (
        "lab-walkthrough",
        "config/scenarios/lab-walkthrough.toml",
        include_str!("../../../../config/scenarios/lab-walkthrough.toml"),
    ),
];

// ---------------------------------------------------------------------------------
// Loading

/// Resolves file references of a scenario.
struct Refs<'a> {
    base_dir: Option<&'a Path>,
}

impl Refs<'_> {
    fn locate(&self, arg: &str) -> Option<PathBuf> {
        let p = Path::new(arg);
        if p.is_absolute() {
            return p.is_file().then(|| p.to_path_buf());
        }
        if let Some(b) = self.base_dir {
            let q = b.join(p);
            if q.is_file() {
                return Some(q);
            }
        }
        p.is_file().then(|| p.to_path_buf())
    }

    fn passport(&self, arg: &str) -> Result<Passport> {
        Ok(match self.locate(arg) {
            Some(path) => vibro_config::load_passport(&path)?,
            None => vibro_config::resolve_passport(arg)?,
        })
    }

    fn triad(&self, arg: &str) -> Result<TriadConfig> {
        Ok(match self.locate(arg) {
            Some(path) => vibro_config::load_triad(&path)?,
            None => vibro_config::resolve_triad(arg)?,
        })
    }

    /// A PSD table, its name for reports, and whether its OA/PA columns hold anything.
    fn psd(&self, arg: &str) -> Result<(Vec<PsdBand>, String)> {
        if let Some(path) = self.locate(arg) {
            return Ok((vibro_config::load_psd_table(&path)?, arg.to_string()));
        }
        if let Some((id, file, text)) = EMBEDDED_PSD_TABLES
            .iter()
            .find(|(id, _, _)| id.eq_ignore_ascii_case(arg))
        {
            let bands = vibro_config::parse_psd_table(text, &format!("{file} (embedded)"))?;
            return Ok((bands, id.to_string()));
        }
        Err(Error::Config(vibro_config::ConfigError::Unknown {
            arg: arg.to_string(),
            kind: "PSD table",
            known: EMBEDDED_PSD_TABLES
                .iter()
                .map(|(id, _, _)| *id)
                .collect::<Vec<_>>()
                .join(", "),
        }))
    }
}

/// Parses and validates a scenario from TOML text; `file` names it in errors and
/// `base_dir` (the file's directory) anchors its relative references.
pub fn parse_scenario(text: &str, file: &str, base_dir: Option<&Path>) -> Result<Scenario> {
    let raw: ScenarioRaw = vibro_toml::from_str(text, file)?;
    Scenario::try_from_raw(raw, file, base_dir)
}

/// Loads a scenario file.
pub fn load_scenario(path: &Path) -> Result<Scenario> {
    let text = vibro_toml::bounds::read_file(path).map_err(|source| Error::Io {
        file: path.display().to_string(),
        source,
    })?;
    parse_scenario(&text, &path.display().to_string(), path.parent())
}

/// A scenario from a path, or the id of a shipped one (`cyclone-4`, ...). An existing
/// file wins over an id.
pub fn resolve_scenario(arg: &str) -> Result<Scenario> {
    let path = Path::new(arg);
    if path.is_file() {
        return load_scenario(path);
    }
    if let Some((_, file, text)) = EMBEDDED_SCENARIOS
        .iter()
        .find(|(id, _, _)| id.eq_ignore_ascii_case(arg))
    {
        return parse_scenario(text, &format!("{file} (embedded)"), None);
    }
    Err(Error::Config(vibro_config::ConfigError::Unknown {
        arg: arg.to_string(),
        kind: "scenario",
        known: EMBEDDED_SCENARIOS
            .iter()
            .map(|(id, _, _)| *id)
            .collect::<Vec<_>>()
            .join(", "),
    }))
}
