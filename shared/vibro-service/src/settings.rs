//! Configuration pieces every service shares: the error type (file, key, value, rule,
//! all problems at once), the `[service]` table, the loop mode, the service-name
//! prefix and the quality of service of each stream.

use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;
use vibro_ipc::StreamConfig;
use vibro_msgs::ServiceNames;
use vibro_toml::bounds::quote;

/// An invalid configuration: the file (or other origin) and every problem found, each
/// naming its key path, the value and the rule.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {}", problems.join("; "))]
pub struct ConfigError {
    pub file: String,
    pub problems: Vec<String>,
    /// The line and key of a TOML error (`vibro_toml`), for `--json` errors (boxed:
    /// the error stays small on the `Ok` path).
    pub location: Option<Box<vibro_toml::Location>>,
}

impl ConfigError {
    pub fn new(file: impl Into<String>, problems: Vec<String>) -> Self {
        Self {
            file: file.into(),
            problems,
            location: None,
        }
    }

    /// The same problems, attributed to `file`.
    pub fn in_file(self, file: &str) -> Self {
        Self {
            file: file.to_string(),
            location: self.location.map(|l| {
                Box::new(vibro_toml::Location {
                    file: file.to_string(),
                    ..*l
                })
            }),
            ..self
        }
    }

    /// The file, and the line and key where known.
    pub fn location(&self) -> vibro_toml::Location {
        self.location
            .as_deref()
            .cloned()
            .unwrap_or_else(|| vibro_toml::Location {
                file: self.file.clone(),
                ..Default::default()
            })
    }
}

/// Where a configuration came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConfigSource {
    /// A file on disk (watched for changes where the service supports hot reload).
    File(PathBuf),
    /// The copy compiled into the binary, named by its path in the repository.
    Embedded(&'static str),
    /// Built in code (tests, other programs).
    Inline,
}

impl std::fmt::Display for ConfigSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConfigSource::File(p) => write!(f, "{}", p.display()),
            ConfigSource::Embedded(name) => write!(f, "{name} (embedded)"),
            ConfigSource::Inline => f.write_str("inline configuration"),
        }
    }
}

/// Reads a configuration file: at most [`vibro_toml::bounds::MAX_FILE_BYTES`], a
/// bigger one refused before it is read ([`vibro_toml::bounds::read_file`]).
pub fn read_config_file(path: &Path) -> Result<String, ConfigError> {
    vibro_toml::bounds::read_file(path).map_err(|e| {
        ConfigError::new(
            path.display().to_string(),
            vec![format!("cannot read: {e}")],
        )
    })
}

/// Parses TOML into a raw configuration (`vibro_toml`): a syntax error keeps its line
/// and caret, and every unknown key is reported at once with its line.
pub fn parse_toml<T: serde::de::DeserializeOwned>(
    text: &str,
    file: &str,
) -> Result<T, ConfigError> {
    vibro_toml::from_str(text, file).map_err(|e| ConfigError {
        file: file.to_string(),
        problems: vec![e.detail()],
        location: Some(Box::new(e.location())),
    })
}

/// The prefix every service name starts with, unless the configuration names one.
pub fn default_prefix() -> String {
    vibro_msgs::DEFAULT_PREFIX.to_string()
}

/// Validates a service-name prefix found at `key` (its length is bounded by
/// iceoryx2's service names; a long one is quoted by its excerpt).
pub fn check_prefix(key: &str, prefix: &str, problems: &mut Vec<String>) -> Option<ServiceNames> {
    match ServiceNames::new(prefix) {
        Ok(names) => Some(names),
        Err(vibro_msgs::Error::InvalidPrefix { rule, .. }) => {
            problems.push(format!("{key} = {}: {rule}", quote(prefix)));
            None
        }
        Err(e) => {
            problems.push(format!("{key} = {}: {e}", quote(prefix)));
            None
        }
    }
}

/// How the hot loop waits for input.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LoopMode {
    /// Sleep in an iceoryx2 `WaitSet` until a publisher notifies (the default: no CPU
    /// used while idle, a few microseconds of wake-up latency).
    #[default]
    Event,
    /// Busy-poll the subscribers without ever sleeping: lowest latency, one core at 100 %.
    Spin,
}

impl LoopMode {
    pub fn as_str(self) -> &'static str {
        match self {
            LoopMode::Event => "event",
            LoopMode::Spin => "spin",
        }
    }
}

impl std::fmt::Display for LoopMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for LoopMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "event" => Ok(LoopMode::Event),
            "spin" => Ok(LoopMode::Spin),
            other => Err(format!("loop mode {other:?}: must be event or spin")),
        }
    }
}

/// The `[service]` table as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServiceSettingsRaw {
    /// `event` (default) or `spin`; `--mode` overrides it.
    #[serde(default)]
    pub loop_mode: LoopMode,
    /// Period of the heartbeat.
    #[serde(default = "default_heartbeat_period_s")]
    pub heartbeat_period_s: f64,
    /// Period of the one-line tracing summary and of the dead-node cleanup.
    #[serde(default = "default_summary_period_s")]
    pub summary_period_s: f64,
    /// Longest the event loop sleeps before it looks at the shutdown flag again.
    #[serde(default = "default_shutdown_poll_s")]
    pub shutdown_poll_s: f64,
    /// `SCHED_FIFO` priority of the hot-loop thread (1..=99); absent: normal
    /// scheduling. `--realtime-priority` overrides it ([`crate::realtime`]).
    #[serde(default)]
    pub realtime_priority: Option<i64>,
}

fn default_heartbeat_period_s() -> f64 {
    1.0
}
fn default_summary_period_s() -> f64 {
    10.0
}
fn default_shutdown_poll_s() -> f64 {
    0.1
}

impl Default for ServiceSettingsRaw {
    fn default() -> Self {
        Self {
            loop_mode: LoopMode::Event,
            heartbeat_period_s: default_heartbeat_period_s(),
            summary_period_s: default_summary_period_s(),
            shutdown_poll_s: default_shutdown_poll_s(),
            realtime_priority: None,
        }
    }
}

/// The validated `[service]` table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServiceSettings {
    pub loop_mode: LoopMode,
    pub heartbeat_period: Duration,
    pub summary_period: Duration,
    pub shutdown_poll: Duration,
    /// `SCHED_FIFO` priority of the hot-loop thread, if asked for.
    pub realtime_priority: Option<u8>,
}

impl Default for ServiceSettings {
    fn default() -> Self {
        let mut problems = Vec::new();
        ServiceSettingsRaw::default()
            .validate("service", &mut problems)
            .unwrap_or(Self {
                loop_mode: LoopMode::Event,
                heartbeat_period: Duration::from_secs(1),
                summary_period: Duration::from_secs(10),
                shutdown_poll: Duration::from_millis(100),
                realtime_priority: None,
            })
    }
}

/// Checks that `value` (seconds) at `key` is finite and within `[lo, hi]`.
pub fn check_seconds(
    key: &str,
    value: f64,
    lo: f64,
    hi: f64,
    problems: &mut Vec<String>,
) -> Option<Duration> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Some(Duration::from_secs_f64(value))
    } else {
        problems.push(format!(
            "{key} = {value}: must be finite and {lo} <= s <= {hi}"
        ));
        None
    }
}

impl ServiceSettingsRaw {
    /// Validates the table found at `table` (its key path), adding problems to `problems`.
    pub fn validate(&self, table: &str, problems: &mut Vec<String>) -> Option<ServiceSettings> {
        let hb = check_seconds(
            &format!("{table}.heartbeat_period_s"),
            self.heartbeat_period_s,
            0.01,
            60.0,
            problems,
        );
        let summary = check_seconds(
            &format!("{table}.summary_period_s"),
            self.summary_period_s,
            0.1,
            3600.0,
            problems,
        );
        let poll = check_seconds(
            &format!("{table}.shutdown_poll_s"),
            self.shutdown_poll_s,
            0.001,
            1.0,
            problems,
        );
        let realtime = match self.realtime_priority {
            None => Some(None),
            Some(p) => match u8::try_from(p) {
                Ok(p) if crate::realtime::PRIORITY_RANGE.contains(&p) => Some(Some(p)),
                _ => {
                    problems.push(format!(
                        "{table}.realtime_priority = {p}: must be 1..=99 (a SCHED_FIFO priority)"
                    ));
                    None
                }
            },
        };
        Some(ServiceSettings {
            loop_mode: self.loop_mode,
            heartbeat_period: hb?,
            summary_period: summary?,
            shutdown_poll: poll?,
            realtime_priority: realtime?,
        })
    }
}

/// Quality of service of the data streams (`accel`, `vib`, `compensated`, heartbeats):
/// vibro-ipc's defaults. Every participant of a stream must ask for no more than the
/// stream was created with, so all services use these.
pub fn data_stream_config() -> StreamConfig {
    vibro_ipc::stream_config(vibro_msgs::Stream::Accel)
}

/// Quality of service of `{prefix}estimate`: history 1, so a compensator that connects
/// late receives the latest estimate with the estimator's next publish.
pub fn estimate_stream_config() -> StreamConfig {
    vibro_ipc::stream_config(vibro_msgs::Stream::Estimate)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn service_table_defaults_and_rules() {
        let s = ServiceSettings::default();
        assert_eq!(s.heartbeat_period, Duration::from_secs(1));
        assert_eq!(s.shutdown_poll, Duration::from_millis(100));
        let raw: ServiceSettingsRaw = parse_toml(
            "loop_mode = \"spin\"\nheartbeat_period_s = -1.0\nsummary_period_s = nan",
            "x.toml",
        )
        .unwrap();
        let mut problems = Vec::new();
        assert!(raw.validate("service", &mut problems).is_none());
        assert_eq!(
            problems,
            [
                "service.heartbeat_period_s = -1: must be finite and 0.01 <= s <= 60",
                "service.summary_period_s = NaN: must be finite and 0.1 <= s <= 3600",
            ]
        );
        let e = parse_toml::<ServiceSettingsRaw>("loop_mode = \"fast\"", "x.toml").unwrap_err();
        assert_eq!(e.file, "x.toml");
        assert!(e.problems[0].contains("unknown variant `fast`"), "{e}");
        let e = parse_toml::<ServiceSettingsRaw>("period = 1.0", "x.toml").unwrap_err();
        assert!(
            e.to_string()
                .contains("line 1, column 1: period: unknown key"),
            "{e}"
        );
        assert_eq!(s.realtime_priority, None);
        for (p, ok) in [(0, false), (1, true), (99, true), (100, false), (-5, false)] {
            let raw: ServiceSettingsRaw =
                parse_toml(&format!("realtime_priority = {p}"), "x.toml").unwrap();
            let mut problems = Vec::new();
            let got = raw.validate("service", &mut problems);
            if ok {
                assert_eq!(got.unwrap().realtime_priority, Some(p as u8));
            } else {
                assert!(got.is_none());
                assert_eq!(
                    problems,
                    [format!(
                        "service.realtime_priority = {p}: must be 1..=99 (a SCHED_FIFO priority)"
                    )]
                );
            }
        }
    }

    #[test]
    fn prefixes_are_checked_with_their_key() {
        let mut problems = Vec::new();
        assert!(check_prefix("prefix", "vibrocomp/", &mut problems).is_some());
        assert!(check_prefix("prefix", "no slash", &mut problems).is_none());
        assert_eq!(problems.len(), 1);
        assert!(
            problems[0].starts_with("prefix = \"no slash\": character ' '"),
            "{problems:?}"
        );
    }
}
