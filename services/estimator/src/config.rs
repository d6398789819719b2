//! The estimator's configuration: `config/services/estimator.toml` → [`RawConfig`]
//! (unknown keys refused) → [`Config`] (validated; the only form `run` takes).

use serde::Deserialize;
use vibro_dsp::{EstimatorConfig, EstimatorConfigRaw};
use vibro_msgs::ServiceNames;
use vibro_service::{
    check_prefix, default_prefix, parse_toml, ConfigError, ConfigSource, ServiceConfig,
    ServiceSettings, ServiceSettingsRaw,
};

/// Where `main` looks for its configuration when `--config` is not given.
pub const DEFAULT_CONFIG_PATH: &str = "config/services/estimator.toml";
/// The shipped configuration, compiled in so the binary runs from any directory.
const EMBEDDED_CONFIG: &str = include_str!("../../../config/services/estimator.toml");

/// The configuration as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    /// Service-name prefix, e.g. `vibrocomp/`.
    #[serde(default = "default_prefix")]
    pub prefix: String,
    /// Loop, heartbeat and summary settings.
    #[serde(default)]
    pub service: ServiceSettingsRaw,
    /// The estimator itself: exactly `vibro_dsp::EstimatorConfigRaw`.
    pub estimator: EstimatorConfigRaw,
}

/// A validated configuration.
#[derive(Debug, Clone)]
pub struct Config {
    pub source: ConfigSource,
    pub names: ServiceNames,
    pub service: ServiceSettings,
    pub estimator: EstimatorConfig,
}

impl TryFrom<RawConfig> for Config {
    type Error = ConfigError;

    /// Checks every key and reports all problems at once (the file is named by the caller).
    fn try_from(raw: RawConfig) -> Result<Self, ConfigError> {
        let mut problems = Vec::new();
        let names = check_prefix("prefix", &raw.prefix, &mut problems);
        let service = raw.service.validate("service", &mut problems);
        let estimator = match EstimatorConfig::try_from(raw.estimator) {
            Ok(c) => Some(c),
            Err(vibro_dsp::Error::InvalidConfig { problems: p }) => {
                problems.extend(p.into_iter().map(|p| format!("estimator.{p}")));
                None
            }
            Err(e) => {
                problems.push(format!("estimator: {e}"));
                None
            }
        };
        match (names, service, estimator) {
            (Some(names), Some(service), Some(estimator)) if problems.is_empty() => Ok(Self {
                source: ConfigSource::Inline,
                names,
                service,
                estimator,
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

    /// Parses and validates TOML text; `source` names it in errors.
    fn parse(text: &str, source: ConfigSource) -> Result<Self, ConfigError> {
        let file = source.to_string();
        let raw: RawConfig = parse_toml(text, &file)?;
        let mut config = Config::try_from(raw).map_err(|e| e.in_file(&file))?;
        config.source = source;
        Ok(config)
    }

    fn set_names(&mut self, names: ServiceNames) {
        self.names = names;
    }

    fn service_mut(&mut self) -> &mut ServiceSettings {
        &mut self.service
    }

    fn log_stream(&self) -> Option<(ServiceNames, vibro_msgs::ServiceId)> {
        Some((self.names.clone(), vibro_msgs::ServiceId::Estimator))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn the_shipped_configuration_is_valid_and_matches_the_rig() {
        let c = Config::shipped().unwrap();
        assert_eq!(c.names.prefix(), "vibrocomp/");
        let raw = c.estimator.raw();
        assert_eq!(raw.sample_rate_hz, 25_600.0);
        assert_eq!(raw.sensitivity_raw_per_g, [0.1; 3]);
        assert_eq!(raw.ac_corner_hz, Some(0.5));
        assert_eq!(raw.full_scale_g, Some([100.0; 3]));
        assert_eq!(c.estimator.window_samples(), 25_600);
        // The file in the repository is the embedded one.
        let on_disk = Config::load(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/services/estimator.toml"
        )))
        .unwrap();
        assert_eq!(on_disk.estimator, c.estimator);
    }

    #[test]
    fn every_problem_is_reported_with_file_key_and_value() {
        let text = EMBEDDED_CONFIG
            .replace("prefix = \"vibrocomp/\"", "prefix = \"vibrocomp\"")
            .replace("window_s = 1.0", "window_s = -2.0")
            .replace("heartbeat_period_s = 1.0", "heartbeat_period_s = 0.0");
        let e = Config::parse(&text, ConfigSource::File("est.toml".into())).unwrap_err();
        let msg = e.to_string();
        assert!(msg.starts_with("est.toml: "), "{msg}");
        assert!(
            msg.contains("prefix = \"vibrocomp\": must end with '/'"),
            "{msg}"
        );
        assert!(msg.contains("estimator.window_s = -2"), "{msg}");
        assert!(msg.contains("service.heartbeat_period_s = 0"), "{msg}");
        assert_eq!(e.problems.len(), 3, "{msg}");
    }

    #[test]
    fn unknown_keys_are_refused() {
        let text = format!("{EMBEDDED_CONFIG}\n[extra]\nx = 1\n");
        let e = Config::parse(&text, ConfigSource::File("est.toml".into())).unwrap_err();
        assert!(e.to_string().contains("extra: unknown key"), "{e}");
        let text = EMBEDDED_CONFIG.replace("window_s = 1.0", "window_seconds = 1.0");
        let e = Config::parse(&text, ConfigSource::File("est.toml".into())).unwrap_err();
        assert!(e.to_string().contains("window_seconds: unknown key"), "{e}");
    }

    #[test]
    fn the_prefix_can_be_overridden_and_is_checked() {
        let c = Config::shipped().unwrap().with_prefix("rig-b/").unwrap();
        assert_eq!(c.names.vib(), "rig-b/vib");
        let e = Config::shipped()
            .unwrap()
            .with_prefix("rig b/")
            .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("command line: --prefix = \"rig b/\""),
            "{e}"
        );
    }
}
