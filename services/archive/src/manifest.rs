//! The batch's manifest (docs/archive.md): a TOML file `format = "vibrocomp-archive/1"`
//! listing the models, the logs with their units and the campaign tables. Read into a
//! raw type (`deny_unknown_fields`: every unknown key reported by `vibro_toml`, with a
//! "did you mean"), then validated into [`Manifest`], every problem at once with its
//! line and key. Paths are relative to the manifest's folder and resolved to absolute
//! ones, so that a job carries everything it needs.

use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::fmt;
use std::path::{Path, PathBuf};
use toml::Spanned;

use crate::{Error, Result};

/// The manifest's `format`.
pub const FORMAT: &str = "vibrocomp-archive/1";
/// Most models, logs, tables: a manifest is a person's list, not a data dump.
pub const MAX_ENTRIES: usize = 100_000;
/// Units of a log: the triad's positions AK1..AK3.
pub const MAX_UNITS_PER_LOG: usize = 3;
/// Longest model name or unit id, in bytes.
pub const MAX_NAME_BYTES: usize = 128;
/// Most effects the lab's stepwise search may add (`[lab] max_effects`).
pub const MAX_EFFECTS: usize = 8;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    format: Spanned<String>,
    window_s: Option<Spanned<f64>>,
    triad: Option<Spanned<String>>,
    keep_sessions: Option<bool>,
    lab: Option<RawLab>,
    #[serde(default)]
    model: Vec<RawModel>,
    #[serde(default)]
    log: Vec<RawLog>,
    #[serde(default)]
    table: Vec<RawTable>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLab {
    enabled: Option<bool>,
    max_effects: Option<Spanned<i64>>,
    effects: Option<Vec<Spanned<String>>>,
    model: Option<Spanned<String>>,
    estimator_config: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModel {
    name: Spanned<String>,
    estimator_config: Option<Spanned<String>>,
    compensator_config: Option<Spanned<String>>,
    model: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLog {
    path: Spanned<String>,
    units: Spanned<Vec<Spanned<String>>>,
    rig: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTable {
    path: Spanned<String>,
    unit: Spanned<String>,
}

/// One problem of a manifest: its line (1-based, where known), the key's dotted path,
/// and what is wrong with the value.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Problem {
    pub line: Option<usize>,
    pub key: String,
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "line {line}: {}: {}", self.key, self.message),
            None => write!(f, "{}: {}", self.key, self.message),
        }
    }
}

/// The lab's part of the batch (`[lab]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LabSettings {
    pub enabled: bool,
    pub max_effects: usize,
    /// Candidate kinds; empty: the library's.
    pub effects: Vec<String>,
    /// The model the units are diagnosed against (an extended model, `lab add --out`);
    /// none: the model of MODEL.md, exact mode.
    pub model: Option<PathBuf>,
    /// The estimator's configuration for the logs' windows; none: the shipped one.
    pub estimator_config: Option<PathBuf>,
}

/// A model every log is compensated with (`[[model]]`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModelSpec {
    pub name: String,
    pub estimator_config: Option<PathBuf>,
    pub compensator_config: Option<PathBuf>,
    /// An extended model (`lab add --out`).
    pub model: Option<PathBuf>,
}

/// A log of the archive (`[[log]]`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogEntry {
    /// Absolute.
    pub path: PathBuf,
    /// As the manifest writes it (the table's `log` column).
    pub label: String,
    /// The unit at each triad position, AK1 first.
    pub units: Vec<String>,
    /// The rig's sensor chain (as `up --rig`), absolute.
    pub rig: Option<PathBuf>,
}

/// A campaign table of one unit (`[[table]]`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TableEntry {
    pub path: PathBuf,
    pub label: String,
    pub unit: String,
}

/// A validated manifest: paths absolute, defaults filled in.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Manifest {
    /// The manifest file (absolute).
    #[serde(skip)]
    pub path: PathBuf,
    pub window_s: f64,
    /// `default`, or the absolute path of a triad file.
    pub triad: String,
    pub keep_sessions: bool,
    pub lab: LabSettings,
    pub models: Vec<ModelSpec>,
    pub logs: Vec<LogEntry>,
    pub tables: Vec<TableEntry>,
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|b| **b == b'\n')
        .count()
        + 1
}

struct Checker<'a> {
    text: &'a str,
    dir: &'a Path,
    problems: Vec<Problem>,
}

impl Checker<'_> {
    fn problem<T>(&mut self, at: &Spanned<T>, key: String, message: String) {
        self.problems.push(Problem {
            line: Some(line_of(self.text, at.span().start)),
            key,
            message,
        });
    }

    /// The absolute path of an existing regular file the manifest names.
    fn file(&mut self, value: &Spanned<String>, key: String) -> Option<PathBuf> {
        let written = value.get_ref();
        if written.is_empty() {
            self.problem(value, key, "\"\": must name a file".into());
            return None;
        }
        let joined = self.dir.join(written);
        let path = std::path::absolute(&joined).unwrap_or(joined);
        let quoted = vibro_toml::bounds::quote(written);
        match std::fs::metadata(&path) {
            Ok(m) if m.is_file() => Some(path),
            Ok(_) => {
                self.problem(
                    value,
                    key,
                    format!("{quoted}: {} is not a file", path.display()),
                );
                None
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                self.problem(
                    value,
                    key,
                    format!("{quoted}: no such file ({})", path.display()),
                );
                None
            }
            Err(e) => {
                self.problem(
                    value,
                    key,
                    format!("{quoted}: cannot read {}: {e}", path.display()),
                );
                None
            }
        }
    }

    fn optional_file(&mut self, value: &Option<Spanned<String>>, key: String) -> Option<PathBuf> {
        value.as_ref().and_then(|v| self.file(v, key))
    }

    /// A model name or a unit id: printable, without `/` (job ids are `kind/...`).
    fn name(&mut self, value: &Spanned<String>, key: String) -> bool {
        let s = value.get_ref();
        let rule = if s.is_empty() {
            Some("must not be empty".to_string())
        } else if s.len() > MAX_NAME_BYTES {
            Some(format!("{} bytes: at most {MAX_NAME_BYTES}", s.len()))
        } else if s.chars().any(|c| c.is_control() || c == '/') {
            Some("must not hold control characters or '/'".to_string())
        } else {
            None
        };
        match rule {
            Some(rule) => {
                let quoted = vibro_toml::bounds::quote(s);
                self.problem(value, key, format!("{quoted}: {rule}"));
                false
            }
            None => true,
        }
    }
}

impl Manifest {
    /// Reads and validates the manifest `path`: every problem at once
    /// ([`Error::Invalid`]), or the TOML's own ([`Error::Toml`]).
    pub fn load(path: &Path) -> Result<Manifest> {
        let text = vibro_toml::bounds::read_file(path).map_err(|source| Error::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Manifest::parse(&text, path)
    }

    /// Validates the manifest text `text` of the file `path` (whose folder resolves
    /// the paths it names).
    pub fn parse(text: &str, path: &Path) -> Result<Manifest> {
        let raw: RawManifest =
            vibro_toml::from_str(text, &path.display().to_string()).map_err(|source| {
                Error::Toml {
                    file: path.to_path_buf(),
                    source: Box::new(source),
                }
            })?;
        let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
        let dir = abs.parent().map(Path::to_path_buf).unwrap_or_default();
        let mut c = Checker {
            text,
            dir: &dir,
            problems: Vec::new(),
        };
        if raw.format.get_ref() != FORMAT {
            let quoted = vibro_toml::bounds::quote(raw.format.get_ref());
            c.problem(
                &raw.format,
                "format".into(),
                format!("{quoted}: must be \"{FORMAT}\""),
            );
        }
        let window_s = match &raw.window_s {
            Some(w) => {
                if let Some(rule) = vibro_log::session::window_problem(*w.get_ref()) {
                    c.problem(w, "window_s".into(), format!("{}: {rule}", w.get_ref()));
                }
                *w.get_ref()
            }
            None => vibro_log::session::DEFAULT_WINDOW_S,
        };
        let triad = match &raw.triad {
            Some(t) if t.get_ref().eq_ignore_ascii_case("default") => "default".to_string(),
            Some(t) => c
                .file(t, "triad".into())
                .map_or_else(String::new, |p| p.display().to_string()),
            None => "default".to_string(),
        };
        let lab = check_lab(&mut c, raw.lab.as_ref());
        for (key, n) in [
            ("model", raw.model.len()),
            ("log", raw.log.len()),
            ("table", raw.table.len()),
        ] {
            if n > MAX_ENTRIES {
                c.problems.push(Problem {
                    line: None,
                    key: key.into(),
                    message: format!("{n} entries: at most {MAX_ENTRIES}"),
                });
            }
        }
        let models = check_models(&mut c, &raw.model);
        let mut logs = Vec::new();
        for (i, l) in raw.log.iter().enumerate() {
            let path = c.file(&l.path, format!("log[{i}].path"));
            let rig = c.optional_file(&l.rig, format!("log[{i}].rig"));
            let units = l.units.get_ref();
            if units.is_empty() || units.len() > MAX_UNITS_PER_LOG {
                c.problem(
                    &l.units,
                    format!("log[{i}].units"),
                    format!(
                        "{} units: a log holds 1 to {MAX_UNITS_PER_LOG} (AK1..AK3)",
                        units.len()
                    ),
                );
            }
            let mut seen = BTreeSet::new();
            for (j, u) in units.iter().enumerate() {
                let key = format!("log[{i}].units[{j}]");
                if c.name(u, key.clone()) && !seen.insert(u.get_ref().clone()) {
                    let quoted = vibro_toml::bounds::quote(u.get_ref());
                    c.problem(u, key, format!("{quoted}: named twice in this log"));
                }
            }
            if let Some(path) = path {
                logs.push(LogEntry {
                    path,
                    label: l.path.get_ref().clone(),
                    units: units.iter().map(|u| u.get_ref().clone()).collect(),
                    rig,
                });
            }
        }
        let mut tables = Vec::new();
        for (i, t) in raw.table.iter().enumerate() {
            let path = c.file(&t.path, format!("table[{i}].path"));
            let named = c.name(&t.unit, format!("table[{i}].unit"));
            if let (Some(path), true) = (path, named) {
                tables.push(TableEntry {
                    path,
                    label: t.path.get_ref().clone(),
                    unit: t.unit.get_ref().clone(),
                });
            }
        }
        if raw.log.is_empty() && raw.table.is_empty() {
            c.problems.push(Problem {
                line: None,
                key: "log".into(),
                message: "no [[log]] and no [[table]]: nothing to run".into(),
            });
        }
        if !c.problems.is_empty() {
            return Err(Error::Invalid {
                file: path.to_path_buf(),
                problems: c.problems,
            });
        }
        Ok(Manifest {
            path: abs,
            window_s,
            triad,
            keep_sessions: raw.keep_sessions.unwrap_or(false),
            lab,
            models,
            logs,
            tables,
        })
    }

    /// A hash of the resolved content (FNV-1a, 64 bits, of its JSON): what the journal's
    /// header holds, so that a journal is only continued by the manifest it was begun
    /// with.
    pub fn hash(&self) -> String {
        let json = serde_json::to_string(self).unwrap_or_default();
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in json.bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        format!("{h:016x}")
    }

    /// The units in order of first appearance (logs first, then tables).
    pub fn units(&self) -> Vec<String> {
        let mut seen = BTreeSet::new();
        let mut out = Vec::new();
        let all = self
            .logs
            .iter()
            .flat_map(|l| l.units.iter())
            .chain(self.tables.iter().map(|t| &t.unit));
        for u in all {
            if seen.insert(u.clone()) {
                out.push(u.clone());
            }
        }
        out
    }
}

fn check_lab(c: &mut Checker<'_>, raw: Option<&RawLab>) -> LabSettings {
    let default_max = 2;
    let Some(raw) = raw else {
        return LabSettings {
            enabled: true,
            max_effects: default_max,
            effects: Vec::new(),
            model: None,
            estimator_config: None,
        };
    };
    let max_effects = match &raw.max_effects {
        Some(m) if (1..=MAX_EFFECTS as i64).contains(m.get_ref()) => *m.get_ref() as usize,
        Some(m) => {
            c.problem(
                m,
                "lab.max_effects".into(),
                format!("{}: must be 1 to {MAX_EFFECTS}", m.get_ref()),
            );
            default_max
        }
        None => default_max,
    };
    let known = vibro_lab::library::kinds();
    let mut effects = Vec::new();
    for (i, e) in raw.effects.iter().flatten().enumerate() {
        if known.contains(&e.get_ref().as_str()) {
            effects.push(e.get_ref().clone());
        } else {
            let quoted = vibro_toml::bounds::quote(e.get_ref());
            c.problem(
                e,
                format!("lab.effects[{i}]"),
                format!(
                    "{quoted}: not an effect of the library (known: {})",
                    known.join(", ")
                ),
            );
        }
    }
    LabSettings {
        enabled: raw.enabled.unwrap_or(true),
        max_effects,
        effects,
        model: c.optional_file(&raw.model, "lab.model".into()),
        estimator_config: c.optional_file(&raw.estimator_config, "lab.estimator_config".into()),
    }
}

/// A model that names no configuration gets the services' own rule (as `vibrocomp up`):
/// `config/services/*.toml` in the working directory if present, else the shipped copy.
/// Resolved here, to an absolute path, so that a job run elsewhere (another working
/// directory, another machine) uses the same file, and the journal's hash sees it.
fn services_default(relative: &str) -> Option<PathBuf> {
    let p = Path::new(relative);
    p.is_file()
        .then(|| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()))
}

fn check_models(c: &mut Checker<'_>, raw: &[RawModel]) -> Vec<ModelSpec> {
    if raw.is_empty() {
        c.problems.push(Problem {
            line: None,
            key: "model".into(),
            message:
                "no [[model]]: name at least one (name = \"shipped\" for the shipped configuration)"
                    .into(),
        });
    }
    let mut names = BTreeSet::new();
    let mut models = Vec::new();
    for (i, m) in raw.iter().enumerate() {
        let key = format!("model[{i}].name");
        let name = m.name.get_ref();
        let ok = c.name(&m.name, key.clone());
        if ok && !names.insert(name.clone()) {
            let quoted = vibro_toml::bounds::quote(name);
            c.problem(
                &m.name,
                key,
                format!("{quoted}: a second model of this name (names are unique)"),
            );
        }
        let estimator_config = c
            .optional_file(&m.estimator_config, format!("model[{i}].estimator_config"))
            .or_else(|| services_default(vibro_estimator::DEFAULT_CONFIG_PATH));
        let compensator_config = c
            .optional_file(
                &m.compensator_config,
                format!("model[{i}].compensator_config"),
            )
            .or_else(|| services_default(vibro_compensator::DEFAULT_CONFIG_PATH));
        models.push(ModelSpec {
            name: name.clone(),
            estimator_config,
            compensator_config,
            model: c.optional_file(&m.model, format!("model[{i}].model")),
        });
    }
    models
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir_with(files: &[&str]) -> tempfile::TempDir {
        let dir = tempfile::TempDir::new().unwrap();
        for f in files {
            let p = dir.path().join(f);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, "x").unwrap();
        }
        dir
    }

    #[test]
    fn a_good_manifest_resolves_its_paths_and_defaults() {
        let dir = dir_with(&["logs/a.mcap", "t.csv"]);
        let text = "format = \"vibrocomp-archive/1\"\n[[model]]\nname = \"shipped\"\n\
                    [[log]]\npath = \"logs/a.mcap\"\nunits = [\"SN-1\", \"SN-2\"]\n\
                    [[table]]\npath = \"t.csv\"\nunit = \"SN-3\"\n";
        let m = Manifest::parse(text, &dir.path().join("m.toml")).unwrap();
        assert_eq!(m.window_s, vibro_log::session::DEFAULT_WINDOW_S);
        assert_eq!(m.logs[0].path, dir.path().join("logs/a.mcap"));
        assert_eq!(m.logs[0].label, "logs/a.mcap");
        assert_eq!(m.units(), ["SN-1", "SN-2", "SN-3"]);
        assert!(m.lab.enabled);
        assert_eq!(
            m.hash(),
            Manifest::parse(text, &dir.path().join("m.toml"))
                .unwrap()
                .hash()
        );
        let other = text.replace("SN-2", "SN-9");
        assert_ne!(
            m.hash(),
            Manifest::parse(&other, &dir.path().join("m.toml"))
                .unwrap()
                .hash()
        );
    }

    #[test]
    fn every_problem_is_reported_at_once_with_its_line_and_key() {
        let dir = dir_with(&["a.mcap"]);
        let text = "format = \"vibrocomp-archive/1\"\nwindow_s = -1.0\n\
                    [[model]]\nname = \"m\"\n[[model]]\nname = \"m\"\n\
                    [[log]]\npath = \"missing.mcap\"\nunits = [\"A\", \"A\"]\n\
                    [[table]]\npath = \"a.mcap\"\nunit = \"\"\n";
        let e = Manifest::parse(text, &dir.path().join("m.toml")).unwrap_err();
        let Error::Invalid { problems, .. } = &e else {
            panic!("{e}")
        };
        let keys: Vec<(Option<usize>, &str)> =
            problems.iter().map(|p| (p.line, p.key.as_str())).collect();
        assert_eq!(
            keys,
            [
                (Some(2), "window_s"),
                (Some(6), "model[1].name"),
                (Some(8), "log[0].path"),
                (Some(9), "log[0].units[1]"),
                (Some(12), "table[0].unit"),
            ],
            "{e}"
        );
        assert!(e.to_string().contains("no such file"), "{e}");
        let loc = e.location().unwrap();
        assert_eq!((loc.line, loc.key.as_deref()), (Some(2), Some("window_s")));
    }

    #[test]
    fn unknown_keys_are_refused_with_a_suggestion() {
        let dir = dir_with(&["a.mcap"]);
        let text = "format = \"vibrocomp-archive/1\"\nwindw_s = 1.0\n[[model]]\nname = \"m\"\n\
                    [[log]]\npath = \"a.mcap\"\nunits = [\"A\"]\nrigg = \"x\"\n";
        let e = Manifest::parse(text, &dir.path().join("m.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 2, column 1: windw_s: unknown key (did you mean window_s?)"),
            "{e}"
        );
        assert!(
            e.contains("line 8, column 1: log[0].rigg: unknown key (did you mean rig?)"),
            "{e}"
        );
    }
}
