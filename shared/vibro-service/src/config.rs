//! Loading a service's configuration: from a file, from the default path, from the
//! copy compiled into the binary, and the `--prefix` override. Each service says how
//! its text parses and validates; where the text comes from is the same for all.

use crate::{check_prefix, read_config_file, ConfigError, ConfigSource, ServiceSettings};
use std::path::Path;
use vibro_msgs::ServiceNames;

/// A service's validated configuration, and the ways to load it.
///
/// A service implements [`parse`](Self::parse) (TOML text → raw struct → validated
/// type) and names its default path and shipped text; `load`, `load_default`,
/// `shipped`, `shipped_text` and `with_prefix` come with the trait (bring it into scope
/// to call them: `use vibro_service::ServiceConfig;`).
pub trait ServiceConfig: Sized {
    /// Where `main` looks for the configuration when `--config` is not given
    /// (relative to the working directory), e.g. `config/services/estimator.toml`.
    const DEFAULT_CONFIG_PATH: &'static str;
    /// The shipped configuration's text, compiled in so the binary runs from any
    /// directory (`include_str!` of the file at [`Self::DEFAULT_CONFIG_PATH`]).
    const EMBEDDED: &'static str;

    /// Parses and validates TOML text; `source` names it in errors.
    fn parse(text: &str, source: ConfigSource) -> Result<Self, ConfigError>;

    /// Replaces the service names (the prefix), already validated.
    fn set_names(&mut self, names: ServiceNames);

    /// The `[service]` settings, for the command line's overrides (`--mode`).
    fn service_mut(&mut self) -> &mut ServiceSettings;

    /// The system and the service whose log lines [`crate::main_with`] publishes on
    /// `{prefix}log/{service}` ([`crate::logstream`]); `None`: stderr only.
    fn log_stream(&self) -> Option<(vibro_msgs::ServiceNames, vibro_msgs::ServiceId)> {
        None
    }

    /// Loads a configuration file.
    fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::parse(
            &read_config_file(path)?,
            ConfigSource::File(path.to_path_buf()),
        )
    }

    /// [`Self::DEFAULT_CONFIG_PATH`] if it exists (run from the repository), else the
    /// shipped copy compiled into the binary.
    fn load_default() -> Result<Self, ConfigError> {
        let path = Path::new(Self::DEFAULT_CONFIG_PATH);
        if path.is_file() {
            Self::load(path)
        } else {
            Self::shipped()
        }
    }

    /// The text of the shipped configuration (what a recording attaches when the
    /// service runs on it).
    fn shipped_text() -> &'static str {
        Self::EMBEDDED
    }

    /// The shipped configuration (compiled in).
    fn shipped() -> Result<Self, ConfigError> {
        Self::parse(
            Self::EMBEDDED,
            ConfigSource::Embedded(Self::DEFAULT_CONFIG_PATH),
        )
    }

    /// Replaces the service-name prefix (the `--prefix` option).
    fn with_prefix(mut self, prefix: &str) -> Result<Self, ConfigError> {
        let mut problems = Vec::new();
        match check_prefix("--prefix", prefix, &mut problems) {
            Some(names) => {
                self.set_names(names);
                Ok(self)
            }
            None => Err(ConfigError::new("command line", problems)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{parse_toml, ServiceSettingsRaw};

    /// A configuration with nothing but the shared keys.
    #[derive(Debug)]
    struct Minimal {
        names: ServiceNames,
        service: ServiceSettings,
        source: ConfigSource,
    }

    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct MinimalRaw {
        #[serde(default = "crate::default_prefix")]
        prefix: String,
        #[serde(default)]
        service: ServiceSettingsRaw,
    }

    impl ServiceConfig for Minimal {
        const DEFAULT_CONFIG_PATH: &'static str = "config/services/does-not-exist.toml";
        const EMBEDDED: &'static str = "prefix = \"shipped/\"\n";

        fn parse(text: &str, source: ConfigSource) -> Result<Self, ConfigError> {
            let file = source.to_string();
            let raw: MinimalRaw = parse_toml(text, &file)?;
            let mut problems = Vec::new();
            let names = check_prefix("prefix", &raw.prefix, &mut problems);
            let service = raw.service.validate("service", &mut problems);
            match (names, service) {
                (Some(names), Some(service)) if problems.is_empty() => Ok(Self {
                    names,
                    service,
                    source,
                }),
                _ => Err(ConfigError::new(file, problems)),
            }
        }

        fn set_names(&mut self, names: ServiceNames) {
            self.names = names;
        }

        fn service_mut(&mut self) -> &mut ServiceSettings {
            &mut self.service
        }
    }

    #[test]
    fn the_provided_loaders_use_the_service_parser() {
        let c = Minimal::load_default().unwrap();
        assert_eq!(c.names.prefix(), "shipped/");
        assert_eq!(
            c.source,
            ConfigSource::Embedded("config/services/does-not-exist.toml")
        );
        assert_eq!(Minimal::shipped_text(), Minimal::EMBEDDED);
        let c = c.with_prefix("rig-b/").unwrap();
        assert_eq!(c.names.prefix(), "rig-b/");
        let e = Minimal::shipped()
            .unwrap()
            .with_prefix("rig b/")
            .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("command line: --prefix = \"rig b/\""),
            "{e}"
        );
        let e = Minimal::load(Path::new("/nonexistent/vibro-service.toml")).unwrap_err();
        assert_eq!(e.file, "/nonexistent/vibro-service.toml");
        assert!(e.problems[0].starts_with("cannot read: "), "{e}");
    }
}
