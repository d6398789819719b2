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
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and validates model text; `file` names it in errors. Every problem is
    /// reported at once. The model's `passport` (a shipped id or a file) is resolved
    /// as every passport reference is, by `vibro_config::resolve_passport`.
    pub fn parse(text: &str, file: &str) -> Result<Self> {
        let bad = |problems: Vec<String>| Error::Model {
            path: file.to_string(),
            problems,
        };
        let raw: RawModel = vibro_toml::from_str(text, file)?;
        let mut problems = Vec::new();
        if let Some(f) = &raw.format {
            if f != FORMAT {
                problems.push(format!("format = {f:?}: must be {FORMAT:?}"));
            }
        }
        let mode = match raw.mode.as_deref() {
            None => BaseMode::Exact,
            Some(m) => BaseMode::parse(m).unwrap_or_else(|| {
                problems.push(format!(
                    "mode = {m:?}: must be one of \"exact\", \"paper\", \"as-published\""
                ));
                BaseMode::Exact
            }),
        };
        if let Some(p) = &raw.passport {
            if let Err(e) = resolve_passport(p) {
                problems.push(format!("passport = {p:?}: {e}"));
            }
        }
        let rig = validation_rig();
        for (i, t) in raw.effect.iter().enumerate() {
            if let Err(e) = build_one(t, &rig) {
                problems.push(format!("effect[{i}]: {e}"));
            }
        }
        if !problems.is_empty() {
            return Err(bad(problems));
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

    /// Writes the model atomically (a temporary file beside it, then a rename).
    pub fn save(&self, path: &Path) -> Result<()> {
        let io = |source| Error::Io {
            path: path.display().to_string(),
            source,
        };
        let tmp = path.with_extension("toml.tmp");
        std::fs::write(&tmp, self.to_toml()).map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
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
            build_one(t, &rig).map_err(|reason| Error::Predict {
                what: format!("effect[{i}]"),
                reason,
            })
        })
        .collect()
}

/// One `[[effect]]` table of a model: an effect of the library, or an empirical
/// correction (`kind = "empirical"`, [`crate::empirical`]: a model file may carry one,
/// a simulator scenario may not).
fn build_one(t: &toml::Table, rig: &Rig) -> std::result::Result<Box<dyn Effect>, String> {
    if t.get("kind").and_then(|k| k.as_str()) == Some(crate::empirical::KIND) {
        return crate::empirical::Empirical::from_table(t)
            .map(|e| Box::new(e) as Box<dyn Effect>)
            .map_err(|e| e.to_string());
    }
    effect_spec(t).and_then(|s| build_for_rig(&s, rig).map_err(|e| e.to_string()))
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
