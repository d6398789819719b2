//! The extended model file (`MODEL.toml`, docs/lab.md): the base VE model (mode) and
//! the effects added to it, each an `[[effect]]` table exactly as in a simulator
//! scenario (docs/effects.md), plus the provenance of each fit (`[[fit]]`, never used
//! by a prediction).
//!
//! ```toml
//! format = "vibrocomp-model/1"
//! mode = "exact"
//! passport = "AL-15"      # optional: for campaign rows with an empty passport cell
//!
//! [[effect]]
//! kind = "mount_resonance"
//! freq_hz = 47.93
//! q = 1.571
//! ```

use crate::effects::{build_for_rig, campaign_axes, EffectSpec, Rig};
use crate::{Effect, Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use vibro_config::resolve_passport;
use vibro_physics::passport::Passport;

/// The value of `format`.
pub const FORMAT: &str = "vibrocomp-model/1";

/// The base VE model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BaseMode {
    /// The exact means, MODEL.md section 6.
    Exact,
    /// The papers' formulas, MODEL.md section 5 (0.637, misprint of [P2 (19)] fixed).
    Paper,
    /// As published: for the VE the same as `paper` (the misprint of [P2 (19)] lives
    /// in the compensation algorithm only).
    AsPublished,
}

impl BaseMode {
    pub fn name(self) -> &'static str {
        match self {
            BaseMode::Exact => "exact",
            BaseMode::Paper => "paper",
            BaseMode::AsPublished => "as-published",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "exact" => Some(BaseMode::Exact),
            "paper" => Some(BaseMode::Paper),
            "as-published" => Some(BaseMode::AsPublished),
            _ => None,
        }
    }
}

/// Where a fitted effect came from (written by `lab add`, read back for reports).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitRecord {
    pub kind: String,
    /// The campaign table it was fitted to.
    pub table: String,
    /// Fitted parameters, in the effect's units (`freq_hz`, ...).
    pub params: BTreeMap<String, f64>,
    /// Their standard uncertainties (linearised, from `J^T J`).
    pub sigma: BTreeMap<String, f64>,
    /// The 68 % profile-likelihood interval `[low, high]` of each parameter whose
    /// interval is not `value +- sigma` (a nonlinear parameter along a curved valley).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub interval: BTreeMap<String, [f64; 2]>,
    pub rms_residual_before_g: f64,
    pub rms_residual_after_g: f64,
    /// BIC with the effect minus BIC without (negative: the effect is supported).
    pub delta_bic: f64,
}

/// An extended model: base mode, default passport, effects.
#[derive(Debug, Clone, PartialEq)]
pub struct LabModel {
    pub mode: BaseMode,
    /// Passport for campaign rows whose `passport` cell is empty.
    pub passport: Option<String>,
    /// The `[[effect]]` tables, `kind` included, in order.
    pub effects: Vec<toml::Table>,
    pub fits: Vec<FitRecord>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModel {
    format: Option<String>,
    mode: Option<String>,
    passport: Option<String>,
    #[serde(default)]
    effect: Vec<toml::Table>,
    #[serde(default)]
    fit: Vec<FitRecord>,
}

#[derive(Serialize)]
struct OutModel<'a> {
    format: &'a str,
    mode: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    passport: Option<&'a str>,
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    effect: &'a [toml::Table],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    fit: &'a [FitRecord],
}

impl LabModel {
    /// The model of MODEL.md alone.
    pub fn base(mode: BaseMode) -> Self {
        Self {
            mode,
            passport: None,
            effects: Vec::new(),
            fits: Vec::new(),
        }
    }

    /// Loads and validates a model file (see [`LabModel::parse`]).
    pub fn load(path: &Path) -> Result<Self> {
        let text = vibro_toml::bounds::read_file(path).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and validates model text; `file` names it in errors. Every problem is
    /// reported at once. The model's `passport` (a shipped id or a file) is resolved
    /// as every passport reference is, by `vibro_config::resolve_passport`.
    pub fn parse(text: &str, file: &str) -> Result<Self> {
        // The first problem whose key is known locates the error (line and key).
        let mut first_key: Option<String> = None;
        let bad = |problems: Vec<String>, key: Option<String>| Error::Model {
            path: file.to_string(),
            problems,
            line: key
                .as_deref()
                .and_then(|k| vibro_toml::key_position(text, k))
                .map(|(line, _)| line),
            key,
        };
        let raw: RawModel = vibro_toml::from_str(text, file)?;
        let mut problems = Vec::new();
        // Sizes first: a value over its bound is not looked at further.
        if !check_sizes(&raw, &mut problems) {
            return Err(bad(problems, None));
        }
        if let Some(f) = &raw.format {
            if f != FORMAT {
                first_key.get_or_insert_with(|| "format".into());
                problems.push(format!("format = {f:?}: must be {FORMAT:?}"));
            }
        }
        let mode = match raw.mode.as_deref() {
            None => BaseMode::Exact,
            Some(m) => BaseMode::parse(m).unwrap_or_else(|| {
                first_key.get_or_insert_with(|| "mode".into());
                problems.push(format!(
                    "mode = {m:?}: must be one of \"exact\", \"paper\", \"as-published\""
                ));
                BaseMode::Exact
            }),
        };
        if let Some(p) = &raw.passport {
            if let Err(e) = resolve_passport(p) {
                first_key.get_or_insert_with(|| "passport".into());
                problems.push(format!("passport = {p:?}: {e}"));
            }
        }
        let rig = validation_rig();
        for (i, t) in raw.effect.iter().enumerate() {
            if let Err(e) = build_one(t, &rig) {
                first_key.get_or_insert_with(|| match &e.param {
                    Some(param) => format!("effect[{i}].{param}"),
                    None => format!("effect[{i}]"),
                });
                problems.push(format!("effect[{i}]: {}", e.message));
            }
        }
        if !problems.is_empty() {
            return Err(bad(problems, first_key));
        }
        Ok(Self {
            mode,
            passport: raw.passport,
            effects: raw.effect,
            fits: raw.fit,
        })
    }

    /// The model as TOML text (what [`LabModel::parse_with`] reads back).
    pub fn to_toml(&self) -> String {
        let out = OutModel {
            format: FORMAT,
            mode: self.mode.name(),
            passport: self.passport.as_deref(),
            effect: &self.effects,
            fit: &self.fits,
        };
        let body = toml::to_string(&out).unwrap_or_default();
        format!(
            "# vibrocomp extended model (docs/lab.md): the VE model of MODEL.md plus the effects\n\
             # added by `vibrocomp lab add`. Read by `lab compare|diagnose|add|report`.\n{body}"
        )
    }

    /// Writes the model by the file rule (README, "Files"; `vibro_files::write_bytes`):
    /// complete or not at all (an unpredictable temporary file beside it, then a
    /// rename), an existing file only with `force`, never a link, a FIFO or a device.
    pub fn save(&self, path: &Path, force: bool) -> Result<()> {
        Ok(vibro_files::write_bytes(
            path,
            force,
            self.to_toml().as_bytes(),
        )?)
    }

    /// The kinds of the effects, in order.
    pub fn effect_kinds(&self) -> Vec<String> {
        self.effects
            .iter()
            .map(|t| {
                t.get("kind")
                    .and_then(|k| k.as_str())
                    .unwrap_or("?")
                    .to_string()
            })
            .collect()
    }

    /// The model with one more effect (and its provenance).
    pub fn with_effect(&self, effect: toml::Table, fit: Option<FitRecord>) -> Self {
        let mut m = self.clone();
        m.effects.push(effect);
        m.fits.extend(fit);
        m
    }

    /// The effects built for a unit with `passport`, in the campaign frame of the
    /// simulator (the unit's OA, PA, IA along body x, y, z).
    pub fn build_effects(&self, passport: &Passport) -> Result<Vec<Box<dyn Effect>>> {
        build_effects(&self.effects, passport)
    }
}

/// Builds `[[effect]]` tables for one unit with `passport`.
pub fn build_effects(tables: &[toml::Table], passport: &Passport) -> Result<Vec<Box<dyn Effect>>> {
    let rig = Rig {
        triad: campaign_axes(),
        passports: Some([*passport; 3]),
    };
    tables
        .iter()
        .enumerate()
        .map(|(i, t)| {
            build_one(t, &rig).map_err(|e| Error::Predict {
                what: format!("effect[{i}]"),
                reason: e.message,
            })
        })
        .collect()
}

/// One `[[effect]]` table of a model: an effect of the library, or an empirical
/// correction (`kind = "empirical"`, [`crate::empirical`]: a model file may carry one,
/// a simulator scenario may not).
fn build_one(t: &toml::Table, rig: &Rig) -> std::result::Result<Box<dyn Effect>, BuildProblem> {
    let problem = |e: Error| BuildProblem {
        param: problem_param(&e),
        message: e.to_string(),
    };
    if t.get("kind").and_then(|k| k.as_str()) == Some(crate::empirical::KIND) {
        return crate::empirical::Empirical::from_table(t)
            .map(|e| Box::new(e) as Box<dyn Effect>)
            .map_err(problem);
    }
    let spec = effect_spec(t).map_err(|message| BuildProblem {
        message,
        param: None,
    })?;
    build_for_rig(&spec, rig).map_err(problem)
}

/// Why an `[[effect]]` table could not be built: the message, and the parameter it
/// names when it names one (to locate it in the file).
struct BuildProblem {
    message: String,
    param: Option<String>,
}

/// The parameter an effect's problem names: `freq` of
/// `effect[mount_resonance].freq`, `kind` of `effect.kind`; the first of several.
fn problem_param(e: &Error) -> Option<String> {
    match e {
        Error::Invalid { key, .. } => key
            .split_once('.')
            .map(|(_, param)| param)
            .filter(|param| !param.is_empty())
            .map(str::to_string),
        Error::Several(all) => all.iter().find_map(problem_param),
        _ => None,
    }
}

/// Most `[[effect]]` tables of a model, and `[[fit]]` records: the catalogue has
/// eleven kinds, each may be given per unit, and `lab add` writes one record per
/// effect it adds.
pub const MAX_MODEL_EFFECTS: usize = 64;

/// Every string and list of a model file against its bound: whether all are within,
/// each one over added to `p`.
fn check_sizes(raw: &RawModel, p: &mut Vec<String>) -> bool {
    use vibro_toml::bounds::{list, text, MAX_PATH_BYTES};
    // A format, a mode, a kind or a parameter's name: one word.
    const MAX_WORD_BYTES: usize = 64;
    // An effect's table: its parameters, and `kind`, `enabled`, `units`.
    const MAX_TABLE_ENTRIES: usize = crate::MAX_EFFECT_PARAMS + 3;
    let mut ok = true;
    for (key, v) in [("format", &raw.format), ("mode", &raw.mode)] {
        if let Some(v) = v {
            ok &= text(key, v, MAX_WORD_BYTES, p);
        }
    }
    if let Some(v) = &raw.passport {
        ok &= text("passport", v, MAX_PATH_BYTES, p);
    }
    if list("effect", raw.effect.len(), MAX_MODEL_EFFECTS, p) {
        for (i, t) in raw.effect.iter().enumerate() {
            ok &= list(&format!("effect[{i}]"), t.len(), MAX_TABLE_ENTRIES, p);
        }
    } else {
        ok = false;
    }
    if list("fit", raw.fit.len(), MAX_MODEL_EFFECTS, p) {
        for (i, f) in raw.fit.iter().enumerate() {
            let key = format!("fit[{i}]");
            ok &= text(&format!("{key}.kind"), &f.kind, MAX_WORD_BYTES, p);
            ok &= text(&format!("{key}.table"), &f.table, MAX_PATH_BYTES, p);
            let names = |map: &str, keys: Vec<&String>, p: &mut Vec<String>| {
                let key = format!("{key}.{map}");
                if !list(&key, keys.len(), crate::MAX_EFFECT_PARAMS, p) {
                    return false;
                }
                // The name itself is what is too long: quoted as the value.
                let name_key = format!("{key} (a parameter's name)");
                // Every name over its bound, not the first alone.
                let mut all = true;
                for k in keys {
                    all &= text(&name_key, k, MAX_WORD_BYTES, p);
                }
                all
            };
            ok &= names("params", f.params.keys().collect(), p);
            ok &= names("sigma", f.sigma.keys().collect(), p);
            ok &= names("interval", f.interval.keys().collect(), p);
        }
    } else {
        ok = false;
    }
    ok
}

/// An `[[effect]]` table as the simulator's [`EffectSpec`].
pub fn effect_spec(t: &toml::Table) -> std::result::Result<EffectSpec, String> {
    EffectSpec::deserialize(toml::Value::Table(t.clone())).map_err(|e| e.to_string())
}

/// A rig to validate effects with when no passport is known yet (the
/// `scale_factor_frequency` effect needs one: AL-15's).
fn validation_rig() -> Rig {
    let passport = resolve_passport("AL-15").ok();
    Rig {
        triad: campaign_axes(),
        passports: passport.map(|p| [p; 3]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_round_trips_through_its_text() {
        let text = r#"
            mode = "paper"
            passport = "AL-15"
            [[effect]]
            kind = "anisoelastic"
            k_ae_per_g = 2.0e-5
            [[fit]]
            kind = "anisoelastic"
            table = "t.csv"
            params = { k_ae_per_g = 2.0e-5 }
            sigma = { k_ae_per_g = 1.0e-7 }
            rms_residual_before_g = 1e-4
            rms_residual_after_g = 1e-6
            delta_bic = -300.0
        "#;
        let m = LabModel::parse(text, "m.toml").unwrap();
        assert_eq!(m.mode, BaseMode::Paper);
        assert_eq!(m.effect_kinds(), ["anisoelastic"]);
        let back = LabModel::parse(&m.to_toml(), "back.toml").unwrap();
        assert_eq!(back, m);
    }

    /// Issue 46, item 7: every string and list of a model file is bounded, checked
    /// first, each one over its bound reported at once.
    #[test]
    fn strings_and_lists_over_their_bounds_are_refused_first() {
        let fit = |name: &str| {
            format!(
                "[[fit]]\nkind = \"anisoelastic\"\ntable = \"t.csv\"\nparams = {{ {name} = 1.0 }}\n\
                 sigma = {{}}\nrms_residual_before_g = 1e-4\nrms_residual_after_g = 1e-6\n\
                 delta_bic = -3.0\n"
            )
        };
        let text = format!(
            "mode = \"{}\"\n[[effect]]\nkind = \"anisoelastic\"\n{}\n{}",
            "m".repeat(100_000),
            (0..40).map(|i| format!("p{i} = 1.0\n")).collect::<String>(),
            fit(&"n".repeat(5000))
        );
        let e = LabModel::parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.len() < 1024, "{} bytes: {e}", e.len());
        for needle in [
            "m.toml: mode = \"mmmm",
            "(100000 bytes): at most 64 bytes",
            "effect[0]: 41 entries: at most 35",
            "fit[0].params (a parameter's name) = \"nnnn",
            "(5000 bytes): at most 64 bytes",
        ] {
            assert!(e.contains(needle), "{needle:?} missing from {e}");
        }
        let e = LabModel::parse(&fit("k").repeat(65), "m.toml").unwrap_err();
        assert_eq!(e.to_string(), "m.toml: fit: 65 entries: at most 64");
        // An effect's unknown parameter with a huge value is quoted by its excerpt.
        let text = format!(
            "[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 1e-5\nwarp = \"{}\"\n",
            "w".repeat(100_000)
        );
        let e = LabModel::parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.len() < 1024 && e.contains("more bytes cut"),
            "{} bytes: {e}",
            e.len()
        );
    }

    #[test]
    fn every_problem_is_named_with_file_key_and_rule() {
        let text = r#"
            format = "other/2"
            mode = "fast"
            passport = "XX-99"
            [[effect]]
            kind = "mount_resonance"
            freq_hz = -3.0
            q = 1.0
            [[effect]]
            kind = "warp_drive"
        "#;
        let e = LabModel::parse(text, "m.toml").unwrap_err().to_string();
        for needle in [
            "m.toml: ",
            "format = \"other/2\": must be \"vibrocomp-model/1\"",
            "mode = \"fast\": must be one of",
            "passport = \"XX-99\"",
            "effect[0]: ",
            "freq_hz",
            "effect[1]: ",
            "unknown effect",
        ] {
            assert!(e.contains(needle), "{needle:?} missing from {e}");
        }
        let e = LabModel::parse("speed = 3\n", "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1, column 1: speed: unknown key"), "{e}");
    }

    /// Issue 47, item 5: a problem found after parsing (an effect's parameter against
    /// its rule) is located: the first such problem's key and the line it is on.
    #[test]
    fn a_problem_is_located_at_its_key_and_line() {
        let locate = |text: &str| {
            let e = LabModel::parse(text, "m.toml").unwrap_err();
            let at = e.location().unwrap();
            assert_eq!(at.file, "m.toml");
            (at.line, at.key)
        };
        let unknown = "mode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 100.0\n\
                       q = 5.0\nfoo = 1\n";
        assert_eq!(locate(unknown), (Some(6), Some("effect[0].foo".into())));
        // The second effect's bad value, after a good first effect.
        let second = "[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 1e-5\n\n[[effect]]\n\
                      kind = \"mount_resonance\"\nq = 1.0\nfreq_hz = -3.0\n";
        assert_eq!(locate(second), (Some(8), Some("effect[1].freq_hz".into())));
        // An unknown kind; the first problem in the file's order of checks wins.
        assert_eq!(
            locate("[[effect]]\nkind = \"warp_drive\"\n"),
            (Some(2), Some("effect[0].kind".into()))
        );
        assert_eq!(
            locate("mode = \"fast\"\n[[effect]]\nkind = \"warp_drive\"\n"),
            (Some(1), Some("mode".into()))
        );
    }

    /// An empirical correction is a model's effect like any other (and its bad keys
    /// are named like theirs); the simulator's registry does not know it.
    #[test]
    fn a_model_carries_an_empirical_correction() {
        let text = "[[effect]]\nkind = \"empirical\"\nc_p3_per_g = 2.0e-6\n";
        let m = LabModel::parse(text, "m.toml").unwrap();
        assert_eq!(m.effect_kinds(), ["empirical"]);
        let p = resolve_passport("AL-15").unwrap();
        let e = m.build_effects(&p).unwrap();
        let vib = vibro_physics::vibration::Vibration::single_tone(40.0, [0.0, 0.0, 2.0]);
        let got = crate::predict::effect_shifts_g(&e, &p, [0.0, 0.0, 1.0], &vib, &[], 1.0).unwrap();
        assert_eq!(got, vec![("empirical".to_string(), 2.0e-6 * 2.0)]);
        let e = LabModel::parse(&text.replace("c_p3", "c_q3"), "m.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("m.toml: effect[0]: effect[empirical].c_q3_per_g = 0.000002: unknown term"),
            "{e}"
        );
        assert!(crate::build(&effect_spec(&m.effects[0]).unwrap()).is_err());
    }

    /// A passport the model names but nobody can resolve is reported like any other
    /// problem, with its key and value.
    #[test]
    fn an_unknown_model_passport_is_reported() {
        let text =
            "passport = \"NO-SUCH\"\n[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 2.0e-5\n";
        let e = LabModel::parse(text, "m.toml").unwrap_err().to_string();
        assert!(e.starts_with("m.toml: passport = \"NO-SUCH\": "), "{e}");
        let text = text.replace("NO-SUCH", "AL-15");
        let m = LabModel::parse(&text, "m.toml").unwrap();
        assert_eq!(m.passport.as_deref(), Some("AL-15"));
        assert_eq!(m.effect_kinds(), ["anisoelastic"]);
    }
}
