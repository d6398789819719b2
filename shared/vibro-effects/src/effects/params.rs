//! Reading and validating an effect's parameters: every problem is collected and
//! reported at once as `effect[kind].key = value: rule`.

use super::{EffectInfo, Rig};
use crate::Error;

/// The raw parameters of one effect being built, and the problems found so far.
pub(crate) struct Params<'a> {
    info: &'a EffectInfo,
    table: &'a toml::Table,
    rig: &'a Rig,
    problems: Vec<Error>,
}

impl<'a> Params<'a> {
    pub(crate) fn new(info: &'a EffectInfo, table: &'a toml::Table, rig: &'a Rig) -> Self {
        Self {
            info,
            table,
            rig,
            problems: Vec::new(),
        }
    }

    /// The rig the effect is built for.
    pub(crate) fn rig(&self) -> &'a Rig {
        self.rig
    }

    /// Records a problem with parameter `name` (or with the whole effect if empty).
    pub(crate) fn problem(&mut self, name: &str, value: String, rule: impl Into<String>) {
        let key = if name.is_empty() {
            format!("effect[{}]", self.info.kind)
        } else {
            format!("effect[{}].{name}", self.info.kind)
        };
        self.problems.push(Error::Invalid {
            key,
            value,
            rule: rule.into(),
        });
    }

    /// Whether the scenario gives `name`.
    pub(crate) fn has(&self, name: &str) -> bool {
        self.table.contains_key(name)
    }

    /// A number (integers accepted) that must satisfy `ok` (and be finite); `None`
    /// when absent. A broken rule is recorded and gives `Some(NaN)`.
    pub(crate) fn optional(
        &mut self,
        name: &str,
        rule: &str,
        ok: impl Fn(f64) -> bool,
    ) -> Option<f64> {
        let value = self.table.get(name)?;
        let x = match value {
            toml::Value::Float(x) => *x,
            toml::Value::Integer(i) => *i as f64,
            other => {
                self.problem(name, other.to_string(), format!("must be a number; {rule}"));
                return Some(f64::NAN);
            }
        };
        if x.is_finite() && ok(x) {
            Some(x)
        } else {
            self.problem(name, value.to_string(), rule);
            Some(f64::NAN)
        }
    }

    /// A number that must be given.
    pub(crate) fn required(&mut self, name: &str, rule: &str, ok: impl Fn(f64) -> bool) -> f64 {
        match self.optional(name, rule, ok) {
            Some(x) => x,
            None => {
                self.problem(name, "(missing)".into(), format!("is required; {rule}"));
                f64::NAN
            }
        }
    }

    /// A number with a documented default when absent.
    pub(crate) fn with_default(
        &mut self,
        name: &str,
        default: f64,
        rule: &str,
        ok: impl Fn(f64) -> bool,
    ) -> f64 {
        self.optional(name, rule, ok).unwrap_or(default)
    }

    /// Records a problem unless at least one of `names` is given.
    pub(crate) fn require_any(&mut self, names: &[&str]) {
        if !names.iter().any(|n| self.has(n)) {
            self.problem(
                "",
                "no parameter given".into(),
                format!("at least one of {} is required", names.join(", ")),
            );
        }
    }

    /// An array of strings; `None` when absent or of the wrong type (recorded).
    pub(crate) fn strings(&mut self, name: &str) -> Option<Vec<String>> {
        let value = self.table.get(name)?;
        let items = value.as_array().and_then(|a| {
            a.iter()
                .map(|v| v.as_str().map(str::to_string))
                .collect::<Option<Vec<_>>>()
        });
        if items.is_none() {
            self.problem(name, value.to_string(), "must be an array of strings");
        }
        items
    }

    /// Unknown keys become problems; all problems are returned at once.
    pub(crate) fn finish(mut self) -> crate::Result<()> {
        let known: Vec<&str> = self.info.params.iter().map(|p| p.name).collect();
        let table = self.table;
        for (key, value) in table {
            if !known.contains(&key.as_str()) {
                let rule = if known.is_empty() {
                    "unknown parameter; this effect takes none".to_string()
                } else {
                    format!("unknown parameter; expected one of {}", known.join(", "))
                };
                self.problem(key, value.to_string(), rule);
            }
        }
        match self.problems.len() {
            0 => Ok(()),
            1 => Err(self.problems.remove(0)),
            _ => Err(Error::Several(self.problems)),
        }
    }
}
