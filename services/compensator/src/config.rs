//! The compensator's configuration: `config/services/compensator.toml` → [`RawConfig`]
//! (unknown keys refused) → [`Config`] (validated; the only form `run` takes).
//!
//! Relative paths (`triad`, `passports`) are looked up next to the configuration file
//! first, then in the working directory; a value that is not a file is a shipped id
//! (`default` for the triad, `AL-15`, `AL-1M`, `AKS-05` for passports). Passports named
//! inside a triad file are resolved by vibro-config (working directory, then ids).

use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Duration;
use vibro_config::TriadConfig;
use vibro_msgs::{CompensationMode, ServiceNames};
use vibro_physics::compensation::{Mode, TriadCompensator};
use vibro_physics::vibration::MAX_TONES as PHYSICS_MAX_TONES;
use vibro_service::{
    check_prefix, check_seconds, default_prefix, parse_toml, ConfigError, ConfigSource,
    ServiceConfig, ServiceSettings, ServiceSettingsRaw,
};

use crate::mapping::{EstimateMapping, KurtosisUse};

/// Where `main` looks for its configuration when `--config` is not given.
pub const DEFAULT_CONFIG_PATH: &str = "config/services/compensator.toml";
/// The shipped configuration, compiled in so the binary runs from any directory.
const EMBEDDED_CONFIG: &str = include_str!("../../../config/services/compensator.toml");

/// The configuration as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    /// Service-name prefix, e.g. `vibrocomp/`.
    #[serde(default = "default_prefix")]
    pub prefix: String,
    /// `exact`, `paper` or `as-published` (MODEL.md section 7).
    pub mode: String,
    /// A triad file, or `default` for the shipped one.
    pub triad: String,
    /// Per-unit passports overriding the triad's: a file or a shipped id each.
    #[serde(default)]
    pub passports: Option<Vec<String>>,
    /// An estimate whose window ended more than this before a block's last sample is
    /// stale: the block is compensated for the main error only.
    #[serde(default = "default_max_estimate_age_s")]
    pub max_estimate_age_s: f64,
    /// An estimate whose window ends more than this after a block's last sample is
    /// dated ahead of the block (the streams' clocks disagree): it is not used for that
    /// block (main error only, `ESTIMATE_AHEAD`).
    #[serde(default = "default_max_estimate_lead_s")]
    pub max_estimate_lead_s: f64,
    /// How often the model files are checked for changes; 0 disables hot reload.
    #[serde(default = "default_reload_poll_s")]
    pub reload_poll_s: f64,
    /// An extended model (`vibrocomp lab add --out`, docs/lab.md): its effects' VE is
    /// removed after stage (20). Its `mode` must be this file's `mode`.
    #[serde(default)]
    pub model: Option<String>,
    #[serde(default)]
    pub estimate: EstimateMappingRaw,
    /// `waveform` (default: the model evaluated on every vibration sample, MODEL.md
    /// section 12, whenever samples reach the compensator; the estimate stage answers
    /// readings they do not cover) or `estimate` (the paper's stages (17)-(20) only).
    #[serde(default = "default_stage")]
    pub stage: String,
    /// How long a reading waits for the vibration samples that cover its interval, in
    /// the streams' time, ms; past it the estimate stage answers it (flagged). Absent:
    /// one vibration block of the stream.
    #[serde(default)]
    pub max_wait_ms: Option<f64>,
    #[serde(default)]
    pub sensors: SensorsRaw,
    #[serde(default)]
    pub service: ServiceSettingsRaw,
}

fn default_stage() -> String {
    "waveform".into()
}

/// The `[sensors]` table: the vibration sensors' chain the waveform stage undoes
/// (`vibro_waveform::SensorChain`), as the estimator's `[estimator]` and a rig file's
/// `[sensors]` state it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorsRaw {
    #[serde(default = "default_sensitivity")]
    pub sensitivity_v_per_g: Vec<f64>,
    #[serde(default = "default_ac_corner_hz")]
    pub ac_corner_hz: f64,
    #[serde(default)]
    pub delay_s: f64,
}

fn default_sensitivity() -> Vec<f64> {
    vibro_waveform::SensorChain::default()
        .sensitivity_v_per_g
        .to_vec()
}
fn default_ac_corner_hz() -> f64 {
    vibro_waveform::SensorChain::default().ac_corner_hz
}

impl Default for SensorsRaw {
    fn default() -> Self {
        Self {
            sensitivity_v_per_g: default_sensitivity(),
            ac_corner_hz: default_ac_corner_hz(),
            delay_s: 0.0,
        }
    }
}

/// Which stage compensates readings whose vibration samples arrive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// MODEL.md section 12, with the estimate stage as the fallback.
    Waveform,
    /// [P2 (17)-(20)] only (the samples are not used).
    Estimate,
}

impl Stage {
    /// The configuration's word for it.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Waveform => "waveform",
            Stage::Estimate => "estimate",
        }
    }

    /// `waveform` or `estimate`; otherwise the rule, with the value.
    pub fn parse(word: &str) -> Result<Self, String> {
        match word {
            "waveform" => Ok(Stage::Waveform),
            "estimate" => Ok(Stage::Estimate),
            other => Err(format!("{other:?}: must be \"waveform\" or \"estimate\"")),
        }
    }
}

/// The waveform stage's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WaveformSettings {
    pub stage: Stage,
    /// `max_wait_ms` in ns; `None`: one vibration block.
    pub max_wait_ns: Option<u64>,
    pub chain: vibro_waveform::SensorChain,
}

fn default_max_estimate_age_s() -> f64 {
    2.0
}
/// Well above what the two streams' block lengths and latencies put between them
/// (tens of ms), well below any clock offset worth flagging.
fn default_max_estimate_lead_s() -> f64 {
    0.5
}
fn default_reload_poll_s() -> f64 {
    0.5
}

/// The `[estimate]` table as written (see [`EstimateMapping`]).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EstimateMappingRaw {
    #[serde(default = "yes")]
    pub use_tones: bool,
    #[serde(default = "yes")]
    pub use_random: bool,
    #[serde(default = "yes")]
    pub use_cross_covariance: bool,
    /// `estimated` or `gaussian`.
    #[serde(default = "default_kurtosis")]
    pub kurtosis: String,
    #[serde(default = "default_max_tones")]
    pub max_tones: usize,
    #[serde(default = "yes")]
    pub within_output_interval: bool,
}

fn yes() -> bool {
    true
}
fn default_kurtosis() -> String {
    "estimated".into()
}
fn default_max_tones() -> usize {
    PHYSICS_MAX_TONES
}

impl Default for EstimateMappingRaw {
    fn default() -> Self {
        Self {
            use_tones: true,
            use_random: true,
            use_cross_covariance: true,
            kurtosis: default_kurtosis(),
            max_tones: default_max_tones(),
            within_output_interval: true,
        }
    }
}

/// The part of the configuration that hot reload replaces while the service runs.
#[derive(Debug, Clone)]
pub struct Model {
    pub mode: Mode,
    /// Geometry and passports (with the `passports` overrides applied).
    pub triad: TriadConfig,
    /// `max_estimate_age_s` in ns.
    pub max_estimate_age_ns: u64,
    /// `max_estimate_lead_s` in ns.
    pub max_estimate_lead_ns: u64,
    pub estimate: EstimateMapping,
    /// The extended model's effects (`model = ...`), with the file they came from.
    pub effects: Option<(PathBuf, vibro_effects::LabModel)>,
    /// `stage`, `max_wait_ms` and `[sensors]`.
    pub waveform: WaveformSettings,
}

impl Model {
    /// A compensator for this model, with no vibration known yet (allocates its tables).
    pub fn compensator(&self) -> TriadCompensator {
        TriadCompensator::new(self.triad.axes, self.triad.passports, self.mode)
    }

    /// The mode's code on the wire.
    pub fn wire_mode(&self) -> CompensationMode {
        wire_mode(self.mode)
    }

    /// `K1` of each unit, V/g: readings are `U / K1`.
    pub fn k1_v_per_g(&self) -> [f64; 3] {
        self.triad.passports.map(|p| p.k1_v_per_g)
    }
}

/// The wire code of a compensation mode.
pub fn wire_mode(mode: Mode) -> CompensationMode {
    match mode {
        Mode::AsPublished => CompensationMode::AsPublished,
        Mode::Paper => CompensationMode::Paper,
        Mode::Exact => CompensationMode::Exact,
    }
}

/// A validated configuration.
#[derive(Debug, Clone)]
pub struct Config {
    pub source: ConfigSource,
    pub names: ServiceNames,
    pub model: Model,
    pub service: ServiceSettings,
    /// `None`: hot reload disabled.
    pub reload_poll: Option<Duration>,
    /// The files whose changes trigger a reload: this configuration, the triad and the
    /// passports it reads from disk.
    pub watched_files: Vec<PathBuf>,
    /// Prefix and `[service]` as the file has them (before command-line overrides),
    /// to tell a reload that changes them (they need a restart).
    pub(crate) as_written: (String, ServiceSettings),
}

/// A value as written, and the file it names if it is one.
fn locate(value: &str, base: Option<&Path>) -> (String, Option<PathBuf>) {
    if let Some(base) = base {
        let p = base.join(value);
        if p.is_file() {
            return (p.display().to_string(), Some(p));
        }
    }
    let p = Path::new(value);
    if p.is_file() {
        (value.to_string(), Some(p.to_path_buf()))
    } else {
        (value.to_string(), None)
    }
}

/// Passport files a triad file names (resolved as vibro-config does: from the
/// working directory), so that hot reload watches them too.
fn passport_files_of_triad(triad_file: &Path) -> Vec<PathBuf> {
    let Ok(text) = vibro_toml::bounds::read_file(triad_file) else {
        return Vec::new();
    };
    let Ok(table) = toml::from_str::<toml::Table>(&text) else {
        return Vec::new();
    };
    let units = table.get("unit").and_then(|u| u.as_array());
    units
        .into_iter()
        .flatten()
        .filter_map(|u| u.get("passport").and_then(|p| p.as_str()))
        .map(PathBuf::from)
        .filter(|p| p.is_file())
        .collect()
}

/// Every string and list of the file against its bound: whether all are within, each
/// one over added to `p`. (`prefix` is bounded by [`check_prefix`]: iceoryx2's
/// service names.)
fn check_sizes(raw: &RawConfig, p: &mut Vec<String>) -> bool {
    use vibro_toml::bounds::{text, texts, MAX_PATH_BYTES};
    // A mode or a kurtosis use is one word of a few; a triad, passport or model is a
    // file (a path) or a shipped id.
    const MAX_WORD_BYTES: usize = 64;
    let mut ok = text("mode", &raw.mode, MAX_WORD_BYTES, p);
    ok &= text("triad", &raw.triad, MAX_PATH_BYTES, p);
    if let Some(list) = &raw.passports {
        // One per unit; the entries of a longer list are not looked at one by one.
        if list.len() == 3 {
            ok &= texts("passports", list, 3, MAX_PATH_BYTES, p);
        } else {
            p.push(format!(
                "passports: {} entries, a triad has exactly 3 units",
                list.len()
            ));
            ok = false;
        }
    }
    if let Some(model) = &raw.model {
        ok &= text("model", model, MAX_PATH_BYTES, p);
    }
    ok &= text(
        "estimate.kurtosis",
        &raw.estimate.kurtosis,
        MAX_WORD_BYTES,
        p,
    );
    ok &= text("stage", &raw.stage, MAX_WORD_BYTES, p);
    if raw.sensors.sensitivity_v_per_g.len() != 3 {
        p.push(format!(
            "sensors.sensitivity_v_per_g: {} entries, one per sensor (3)",
            raw.sensors.sensitivity_v_per_g.len()
        ));
        ok = false;
    }
    ok
}

impl TryFrom<RawConfig> for Config {
    type Error = ConfigError;

    /// Validates with relative paths taken from the working directory.
    fn try_from(raw: RawConfig) -> Result<Self, ConfigError> {
        Self::from_raw(raw, None)
    }
}

impl Config {
    /// Validates `raw`, looking up relative paths in `base_dir` first; reports every
    /// problem at once (the file is named by the caller).
    pub fn from_raw(raw: RawConfig, base_dir: Option<&Path>) -> Result<Self, ConfigError> {
        let mut problems = Vec::new();
        // Sizes first: a value over its bound is not looked at further (every such
        // value at once).
        if !check_sizes(&raw, &mut problems) {
            return Err(ConfigError::new("configuration", problems));
        }
        let mut watched = Vec::new();
        let names = check_prefix("prefix", &raw.prefix, &mut problems);
        let service = raw.service.validate("service", &mut problems);
        let mode = match Mode::from_str(&raw.mode) {
            Ok(m) => Some(m),
            Err(_) => {
                problems.push(format!(
                    "mode = {:?}: must be one of \"exact\", \"paper\", \"as-published\"",
                    raw.mode
                ));
                None
            }
        };

        let (triad_arg, triad_file) = locate(&raw.triad, base_dir);
        let mut triad = match vibro_config::resolve_triad(&triad_arg) {
            Ok(t) => Some(t),
            Err(e) => {
                problems.push(format!("triad = {:?}: {e}", raw.triad));
                None
            }
        };
        if let Some(file) = triad_file {
            watched.extend(passport_files_of_triad(&file));
            watched.insert(0, file);
        }
        // Exactly 3 (checked with the sizes).
        if let Some(list) = &raw.passports {
            for (i, value) in list.iter().enumerate() {
                let (arg, file) = locate(value, base_dir);
                watched.extend(file);
                match vibro_config::resolve_passport(&arg) {
                    Ok(p) => {
                        if let Some(t) = triad.as_mut() {
                            t.passports[i] = p;
                        }
                    }
                    Err(e) => problems.push(format!("passports[{i}] = {value:?}: {e}")),
                }
            }
        }
        if let Some(t) = &triad {
            for (i, p) in t.passports.iter().enumerate() {
                let k1 = p.k1_v_per_g;
                if !(k1.is_finite() && k1 != 0.0) {
                    problems.push(format!(
                        "unit {i} ({}) passport {}: K1_v_per_g = {k1}: must be finite and non-zero",
                        t.names[i],
                        p.id()
                    ));
                }
            }
        }

        let age_s = raw.max_estimate_age_s;
        let max_age = if age_s.is_finite() && age_s > 0.0 && age_s <= 3600.0 {
            Some((age_s * 1e9).round() as u64)
        } else {
            problems.push(format!(
                "max_estimate_age_s = {age_s}: must be finite and 0 < s <= 3600"
            ));
            None
        };
        let lead_s = raw.max_estimate_lead_s;
        let max_lead = if lead_s.is_finite() && (0.0..=3600.0).contains(&lead_s) {
            Some((lead_s * 1e9).round() as u64)
        } else {
            problems.push(format!(
                "max_estimate_lead_s = {lead_s}: must be finite and 0 <= s <= 3600"
            ));
            None
        };
        let reload_poll = if raw.reload_poll_s == 0.0 {
            Some(None)
        } else {
            check_seconds(
                "reload_poll_s",
                raw.reload_poll_s,
                0.01,
                60.0,
                &mut problems,
            )
            .map(Some)
        };

        let effects = match &raw.model {
            None => Some(None),
            Some(value) => {
                let (arg, file) = locate(value, base_dir);
                watched.extend(file);
                match vibro_effects::LabModel::load(Path::new(&arg)) {
                    Ok(m) => {
                        let agree = matches!(
                            (m.mode, mode),
                            (vibro_effects::BaseMode::Exact, Some(Mode::Exact))
                                | (vibro_effects::BaseMode::Paper, Some(Mode::Paper))
                                | (
                                    vibro_effects::BaseMode::AsPublished,
                                    Some(Mode::AsPublished)
                                )
                        );
                        if agree || mode.is_none() {
                            Some(Some((PathBuf::from(arg), m)))
                        } else {
                            problems.push(format!(
                                "model = {value:?}: its mode {:?} is not this file's mode = {:?} (the effects were fitted on top of that base model)",
                                m.mode.name(),
                                raw.mode
                            ));
                            None
                        }
                    }
                    Err(e) => {
                        problems.push(format!("model = {value:?}: {e}"));
                        None
                    }
                }
            }
        };

        let e = &raw.estimate;
        let kurtosis = match e.kurtosis.as_str() {
            "estimated" => Some(KurtosisUse::Estimated),
            "gaussian" => Some(KurtosisUse::Gaussian),
            other => {
                problems.push(format!(
                    "estimate.kurtosis = {other:?}: must be \"estimated\" or \"gaussian\""
                ));
                None
            }
        };
        if !(1..=PHYSICS_MAX_TONES).contains(&e.max_tones) {
            problems.push(format!(
                "estimate.max_tones = {}: must be 1..={PHYSICS_MAX_TONES} (the model's capacity)",
                e.max_tones
            ));
        }

        let stage = match Stage::parse(&raw.stage) {
            Ok(s) => Some(s),
            Err(rule) => {
                problems.push(format!("stage = {rule}"));
                None
            }
        };
        let max_wait_ns = match raw.max_wait_ms {
            None => Some(None),
            Some(ms) if ms.is_finite() && (0.0..=10_000.0).contains(&ms) => {
                Some(Some((ms * 1e6).round() as u64))
            }
            Some(ms) => {
                problems.push(format!(
                    "max_wait_ms = {ms}: must be finite and 0 <= ms <= 10000"
                ));
                None
            }
        };
        let sens = &raw.sensors.sensitivity_v_per_g;
        let chain = vibro_waveform::SensorChain {
            sensitivity_v_per_g: [sens[0], sens[1], sens[2]],
            ac_corner_hz: raw.sensors.ac_corner_hz,
            delay_s: raw.sensors.delay_s,
        };
        for c in chain.problems() {
            problems.push(format!("sensors.{c}"));
        }
        let waveform = match (stage, max_wait_ns) {
            (Some(stage), Some(max_wait_ns)) => Some(WaveformSettings {
                stage,
                max_wait_ns,
                chain,
            }),
            _ => None,
        };

        match (
            names,
            service,
            mode,
            triad,
            max_age,
            max_lead,
            reload_poll,
            kurtosis,
            effects,
            waveform,
        ) {
            (
                Some(names),
                Some(service),
                Some(mode),
                Some(triad),
                Some(max_age),
                Some(max_lead),
                Some(reload_poll),
                Some(kurtosis),
                Some(effects),
                Some(waveform),
            ) if problems.is_empty() => Ok(Self {
                source: ConfigSource::Inline,
                as_written: (names.prefix().to_string(), service),
                names,
                model: Model {
                    mode,
                    triad,
                    max_estimate_age_ns: max_age,
                    max_estimate_lead_ns: max_lead,
                    estimate: EstimateMapping {
                        use_tones: e.use_tones,
                        use_random: e.use_random,
                        use_cross_covariance: e.use_cross_covariance,
                        kurtosis,
                        max_tones: e.max_tones,
                        within_output_interval: e.within_output_interval,
                    },
                    effects,
                    waveform,
                },
                service,
                reload_poll,
                watched_files: watched,
            }),
            _ => Err(ConfigError::new("configuration", problems)),
        }
    }
}

/// Loading: `Config::load(path)`, `Config::load_default()`, `Config::shipped()`,
/// `Config::shipped_text()`, `config.with_prefix(..)` (with [`ServiceConfig`] in scope).
impl ServiceConfig for Config {
    const DEFAULT_CONFIG_PATH: &'static str = DEFAULT_CONFIG_PATH;
    const EMBEDDED: &'static str = EMBEDDED_CONFIG;

    /// Parses and validates TOML text; `source` names it in errors, and a file source's
    /// directory is where relative paths are looked up first.
    fn parse(text: &str, source: ConfigSource) -> Result<Self, ConfigError> {
        let file = source.to_string();
        let raw: RawConfig = parse_toml(text, &file)?;
        let base = match &source {
            ConfigSource::File(p) => p.parent(),
            _ => None,
        };
        let mut config = Self::from_raw(raw, base).map_err(|e| e.in_file(&file))?;
        if let ConfigSource::File(p) = &source {
            config.watched_files.insert(0, p.clone());
        }
        config.source = source;
        Ok(config)
    }

    /// Replaces the service names only: `as_written` keeps the file's prefix, so a
    /// reload that keeps it is not taken for a prefix change.
    fn set_names(&mut self, names: ServiceNames) {
        self.names = names;
    }

    fn service_mut(&mut self) -> &mut ServiceSettings {
        &mut self.service
    }

    fn log_stream(&self) -> Option<(ServiceNames, vibro_msgs::ServiceId)> {
        Some((self.names.clone(), vibro_msgs::ServiceId::Compensator))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("vct-cfg-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn the_shipped_configuration_is_valid() {
        let c = Config::shipped().unwrap();
        assert_eq!(c.names.prefix(), "vibrocomp/");
        assert_eq!(c.model.mode, Mode::Exact);
        assert_eq!(c.model.max_estimate_age_ns, 2_000_000_000);
        assert_eq!(c.model.max_estimate_lead_ns, 500_000_000);
        assert_eq!(c.model.triad.id, "default");
        assert_eq!(c.model.estimate, EstimateMapping::default());
        assert_eq!(c.reload_poll, Some(Duration::from_millis(500)));
        assert!(
            c.watched_files.is_empty(),
            "embedded: nothing on disk to watch"
        );
        let on_disk = Config::load(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/services/compensator.toml"
        )))
        .unwrap();
        assert_eq!(on_disk.model.mode, c.model.mode);
        assert_eq!(on_disk.watched_files.len(), 1);
    }

    #[test]
    fn strings_and_lists_over_their_bounds_are_refused_first() {
        let text = EMBEDDED_CONFIG
            .replace(
                "mode = \"exact\"",
                &format!("mode = \"{}\"", "e".repeat(100_000)),
            )
            .replace(
                "triad = \"default\"",
                &format!(
                    "triad = \"{}\"\npassports = [{}]",
                    "t".repeat(5000),
                    vec!["\"AL-15\""; 1000].join(", ")
                ),
            );
        let e = Config::parse(&text, ConfigSource::File("c.toml".into())).unwrap_err();
        let msg = e.to_string();
        assert!(msg.len() < 1024, "{} bytes: {msg}", msg.len());
        for needle in [
            "c.toml: mode = \"eeee",
            "more bytes cut)\" (100000 bytes): at most 64 bytes",
            "triad = \"tttt",
            "(5000 bytes): at most 4095 bytes",
            "passports: 1000 entries, a triad has exactly 3 units",
        ] {
            assert!(msg.contains(needle), "{needle:?} missing from {msg}");
        }
        assert_eq!(e.problems.len(), 3, "{msg}");
    }

    #[test]
    fn every_problem_is_reported_with_file_key_and_value() {
        let text = EMBEDDED_CONFIG
            .replace("mode = \"exact\"", "mode = \"fast\"")
            .replace("triad = \"default\"", "triad = \"nowhere.toml\"")
            .replace("max_estimate_age_s = 2.0", "max_estimate_age_s = -1.0")
            .replace("max_estimate_lead_s = 0.5", "max_estimate_lead_s = inf")
            .replace("kurtosis = \"estimated\"", "kurtosis = \"normal\"")
            .replace("max_tones = 8", "max_tones = 9");
        let e = Config::parse(&text, ConfigSource::File("c.toml".into())).unwrap_err();
        let msg = e.to_string();
        assert!(msg.starts_with("c.toml: "), "{msg}");
        for needle in [
            "mode = \"fast\": must be one of",
            "triad = \"nowhere.toml\": \"nowhere.toml\" is neither a readable file nor a known triad id",
            "max_estimate_age_s = -1: must be finite and 0 < s <= 3600",
            "max_estimate_lead_s = inf: must be finite and 0 <= s <= 3600",
            "estimate.kurtosis = \"normal\"",
            "estimate.max_tones = 9: must be 1..=8",
        ] {
            assert!(msg.contains(needle), "{needle:?} missing from {msg}");
        }
        assert_eq!(e.problems.len(), 6, "{msg}");
        let e = Config::parse(
            &format!("{EMBEDDED_CONFIG}\nspeed = 1\n"),
            ConfigSource::File("c.toml".into()),
        )
        .unwrap_err();
        assert!(e.to_string().contains("service.speed: unknown key"), "{e}");
    }

    #[test]
    fn the_waveform_stages_keys_are_checked_with_file_key_value_and_rule() {
        for (from, to, needle) in [
            ("delay_s = 0.0 ", "delay_s = -0.001 ", "sensors.delay_s = -0.001: must be from 0 to 1 s"),
            ("delay_s = 0.0 ", "delay_s = 2.0 ", "sensors.delay_s = 2: must be from 0 to 1 s"),
            ("ac_corner_hz = 0.5 ", "ac_corner_hz = -2.0 ", "sensors.ac_corner_hz = -2: must be a finite corner"),
            ("stage = \"waveform\" ", "stage = \"wave\" ", "stage = \"wave\": must be \"waveform\" or \"estimate\""),
            ("# max_wait_ms = 20.0 ", "max_wait_ms = -5.0 ", "max_wait_ms = -5: must be finite and 0 <= ms <= 10000"),
            (
                "sensitivity_v_per_g = [0.1, 0.1, 0.1]",
                "sensitivity_v_per_g = [0.1, 0.0, 0.1]",
                "sensors.sensitivity_v_per_g = [0.1, 0.0, 0.1]: each sensitivity must be finite, nonzero",
            ),
            (
                "sensitivity_v_per_g = [0.1, 0.1, 0.1]",
                "sensitivity_v_per_g = [0.1, 0.1]",
                "sensors.sensitivity_v_per_g: 2 entries, one per sensor (3)",
            ),
        ] {
            assert!(EMBEDDED_CONFIG.contains(from), "{from}");
            let text = EMBEDDED_CONFIG.replacen(from, to, 1);
            let e = Config::parse(&text, ConfigSource::File("c.toml".into())).unwrap_err();
            let msg = e.to_string();
            assert!(msg.starts_with("c.toml: ") && msg.contains(needle), "{needle:?} missing from {msg}");
        }
        let c = Config::shipped().unwrap();
        assert_eq!(c.model.waveform.stage, Stage::Waveform);
        assert_eq!(c.model.waveform.max_wait_ns, None);
        assert_eq!(
            c.model.waveform.chain,
            vibro_waveform::SensorChain::default()
        );
    }

    #[test]
    fn paths_are_found_next_to_the_file_and_watched() {
        let dir = temp_dir("paths");
        let passport = vibro_config::EMBEDDED_PASSPORTS[1].2; // AL-1M
        std::fs::write(dir.join("unit2.toml"), passport).unwrap();
        let triad = r#"
id = "flipped"
[[unit]]
name = "A"
passport = "AL-15"
ia = "-y"
oa = "+z"
pa = "-x"
[[unit]]
name = "B"
passport = "AL-15"
ia = "+z"
oa = "-x"
pa = "+y"
[[unit]]
name = "C"
passport = "AKS-05"
ia = "-x"
oa = "-y"
pa = "z"
"#;
        std::fs::write(dir.join("triad.toml"), triad).unwrap();
        let text = EMBEDDED_CONFIG
            .replace("triad = \"default\"", "triad = \"triad.toml\"")
            .replace(
                "# passports = [\"AL-15\", \"AL-15\", \"AL-15\"]",
                "passports = [\"AL-15\", \"unit2.toml\", \"aks-05\"]",
            );
        let path = dir.join("compensator.toml");
        std::fs::write(&path, text).unwrap();
        let c = Config::load(&path).unwrap();
        assert_eq!(c.model.triad.id, "flipped");
        assert_eq!(c.model.triad.passports[1].id(), "AL-1M");
        assert_eq!(c.model.triad.passports[2].id(), "AKS-05");
        assert_eq!(
            c.watched_files,
            [path.clone(), dir.join("triad.toml"), dir.join("unit2.toml")]
        );
        let bad = std::fs::read_to_string(&path)
            .unwrap()
            .replace("\"aks-05\"]", "\"aks-05\", \"AL-15\"]");
        std::fs::write(&path, bad).unwrap();
        let e = Config::load(&path).unwrap_err().to_string();
        assert!(e.contains("4 entries, a triad has exactly 3 units"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
