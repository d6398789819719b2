//! The effects library: physical effects that the conversion function (FP) of MODEL.md
//! leaves out (MODEL.md section 11), each a small module implementing [`Effect`] with
//! its physics, parameters (units in every name) and documented mean contribution.
//!
//! A scenario lists effects as `[[effect]]` tables, read into [`EffectSpec`] and built
//! with [`build_for_rig`] (or [`build`] for the standard triad without passports):
//!
//! ```
//! use vibro_effects::effects::{build, EffectSpec};
//! let spec: EffectSpec = toml::from_str(r#"
//!     kind = "mount_resonance"
//!     freq_hz = 48.0
//!     q = 1.56
//! "#).unwrap();
//! let effect = build(&spec).unwrap();
//! assert_eq!(effect.kind(), "mount_resonance");
//! ```
//!
//! Every parameter is validated when the effect is built; all problems are reported at
//! once as `effect[kind].key = value: rule`. [`catalogue`] lists the kinds, their
//! parameters and hooks (`vibrocomp sim --list-effects`); docs/effects.md documents
//! each effect and how to add one (one module and one line in `EFFECTS`).
//!
//! References: MODEL.md (the FP and its exact mean, section numbers as `section n`),
//! RIG.md (the rig and flight figures the defaults come from).

use crate::effect::{BlockCtx, Effect, MeanContext};
use crate::{Error, Result};
use vibro_physics::passport::Passport;
use vibro_physics::triad::{SignedAxis, TriadAxes, UnitAxes};
use vibro_physics::vibration::Vibration;

pub mod anisoelastic;
pub mod axis_phase;
pub mod heating;
pub mod high_order_nonlinearity;
pub mod mount_resonance;
pub mod non_gaussian;
pub mod saturation;
pub mod scale_factor_frequency;
pub mod sensor_error;
pub mod unit_response;
pub mod vibropendulous;

mod filter;
mod params;
mod quad;
mod spectral;
#[cfg(test)]
mod testkit;

pub(crate) use params::Params;

/// The registry: every effect the library knows, one line each.
static EFFECTS: &[EffectInfo] = &[
    mount_resonance::INFO,
    unit_response::INFO,
    axis_phase::INFO,
    vibropendulous::INFO,
    anisoelastic::INFO,
    non_gaussian::INFO,
    saturation::INFO,
    high_order_nonlinearity::INFO,
    heating::INFO,
    sensor_error::INFO,
    scale_factor_frequency::INFO,
];

/// One `[[effect]]` table of a scenario: `kind`, optional `enabled` and `units`, and
/// the effect's own parameters (validated by [`build`], unknown keys are errors).
#[derive(Debug, Clone, serde::Deserialize)]
pub struct EffectSpec {
    pub kind: String,
    /// Whether the simulator applies the effect (default true). [`build`] validates a
    /// disabled effect all the same, so a typo in it still fails the scenario.
    #[serde(default = "enabled_by_default")]
    pub enabled: bool,
    /// The triad units (0..3) the effect applies to; all when absent. Effects on the
    /// body-frame vibration description act on every unit and refuse this key.
    #[serde(default)]
    pub units: Option<Vec<usize>>,
    #[serde(flatten)]
    pub params: toml::Table,
}

fn enabled_by_default() -> bool {
    true
}

/// One parameter of an effect, for the catalogue and docs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParamInfo {
    /// Key in the `[[effect]]` table, unit last (`freq_hz`); dimensionless ratios
    /// (`q`, `damping_ratio`, `kurtosis`, `gain_error`) carry no suffix, as the
    /// passport's `k1`.
    pub name: &'static str,
    /// Unit (`Hz`, `rad/g`, `1` for dimensionless, `-` for non-numbers).
    pub unit: &'static str,
    /// What it means, its range and default.
    pub meaning: &'static str,
}

/// Where an effect acts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// Per unit: its vibration sensor, its input or its output (honours `units`).
    Unit,
    /// On the body-frame vibration description, shared by all units (refuses `units`).
    Body,
}

/// Signature of an effect's constructor: reads and validates its parameters.
pub(crate) type Builder = fn(&mut Params<'_>) -> Result<Box<dyn Effect>>;

/// A catalogue entry: an effect's kind, summary, parameters and hooks.
#[derive(Clone, Copy)]
pub struct EffectInfo {
    /// The `kind` key of its `[[effect]]` table.
    pub kind: &'static str,
    /// One line: what it models.
    pub summary: &'static str,
    /// Its parameters (the only keys it accepts besides `kind`, `enabled`, `units`).
    pub params: &'static [ParamInfo],
    /// The [`Effect`] hooks it implements.
    pub hooks: &'static str,
    pub scope: Scope,
    /// A valid `[[effect]]` table (also in docs/effects.md; tests build it).
    pub example: &'static str,
    pub(crate) build: Builder,
}

impl std::fmt::Debug for EffectInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EffectInfo")
            .field("kind", &self.kind)
            .field("summary", &self.summary)
            .field("params", &self.params)
            .field("hooks", &self.hooks)
            .field("scope", &self.scope)
            .finish()
    }
}

/// What some effects need to know about the rig they are built for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rig {
    /// Which body axis is each unit's IA, OA and PA (`sensor_error` projects the body
    /// vibration on them; `axis_phase` and `non_gaussian` map body axes to unit axes in
    /// their mean formulas).
    pub triad: TriadAxes,
    /// The units' passports, when known (`scale_factor_frequency` needs `k1` and `d1A`
    /// in its time-domain hook, which sees no passport).
    pub passports: Option<[Passport; 3]>,
}

impl Rig {
    /// The standard triad (unit i has IA along body axis i) and no passports.
    pub fn standard() -> Self {
        Self {
            triad: TriadAxes::standard(),
            passports: None,
        }
    }
}

/// The triad frame a campaign simulates in: the unit under test is unit 0 with body
/// axes = its own axes (`x` = OA, `y` = PA, `z` = IA), so that body-frame and unit-frame
/// vibration coincide. Units 1 and 2 only complete the geometry (they are not run).
/// The lab builds a model's effects in this frame too, so that it explains a campaign
/// with the physics that simulated it.
pub fn campaign_axes() -> TriadAxes {
    let ax = |body_index| SignedAxis {
        body_index,
        sign: 1,
    };
    let unit = |ia, oa, pa| UnitAxes {
        ia: ax(ia),
        oa: ax(oa),
        pa: ax(pa),
    };
    TriadAxes {
        units: [unit(2, 0, 1), unit(0, 1, 2), unit(1, 2, 0)],
    }
}

/// Every effect the registry knows.
pub fn catalogue() -> &'static [EffectInfo] {
    EFFECTS
}

/// One effect of the catalogue as `vibrocomp sim --list-effects --json` prints it:
/// each parameter as `{name, unit, meaning}` (keys in sorted order).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct EffectListing {
    pub kind: &'static str,
    pub summary: &'static str,
    pub hooks: &'static str,
    pub params: Vec<std::collections::BTreeMap<&'static str, &'static str>>,
}

/// The catalogue as listings, in its order.
pub fn listing() -> Vec<EffectListing> {
    catalogue()
        .iter()
        .map(|e| EffectListing {
            kind: e.kind,
            summary: e.summary,
            hooks: e.hooks,
            params: e
                .params
                .iter()
                .map(|p| {
                    std::collections::BTreeMap::from([
                        ("name", p.name),
                        ("unit", p.unit),
                        ("meaning", p.meaning),
                    ])
                })
                .collect(),
        })
        .collect()
}

/// Most parameters an `[[effect]]` table may give besides `kind`, `enabled` and
/// `units`: an effect takes at most a handful; a table of more is refused by its count
/// before its keys are looked at one by one.
pub const MAX_EFFECT_PARAMS: usize = 32;

/// Builds an effect for the standard triad with no passports (see [`build_for_rig`]).
pub fn build(spec: &EffectSpec) -> Result<Box<dyn Effect>> {
    build_for_rig(spec, &Rig::standard())
}

/// Builds the effect `spec` describes for `rig`, validating every parameter and
/// reporting all problems at once (`effect[kind].key = value: rule`).
pub fn build_for_rig(spec: &EffectSpec, rig: &Rig) -> Result<Box<dyn Effect>> {
    let Some(info) = EFFECTS.iter().find(|e| e.kind == spec.kind) else {
        let kinds: Vec<&str> = EFFECTS.iter().map(|e| e.kind).collect();
        return Err(Error::Invalid {
            key: "effect.kind".into(),
            value: vibro_toml::bounds::quote(&spec.kind),
            rule: format!("unknown effect; expected one of {}", kinds.join(", ")),
        });
    };
    if spec.params.len() > MAX_EFFECT_PARAMS {
        return Err(Error::Invalid {
            key: format!("effect[{}]", info.kind),
            value: format!("{} parameters", spec.params.len()),
            rule: format!("at most {MAX_EFFECT_PARAMS}"),
        });
    }
    let mut params = Params::new(info, &spec.params, rig);
    let on = units_mask(&mut params, info.scope, spec.units.as_deref());
    let built = (info.build)(&mut params);
    params.finish()?;
    let effect = built?;
    Ok(if on == [true; 3] {
        effect
    } else {
        Box::new(OnUnits { inner: effect, on })
    })
}

/// Validates the `units` key into a mask over the three units.
fn units_mask(params: &mut Params<'_>, scope: Scope, units: Option<&[usize]>) -> [bool; 3] {
    let Some(units) = units else {
        return [true; 3];
    };
    let shown = format!("{units:?}");
    if scope == Scope::Body {
        params.problem(
            "units",
            shown,
            "this effect acts on the body-frame vibration shared by all units; remove `units`",
        );
        return [true; 3];
    }
    let mut on = [false; 3];
    let mut ok = !units.is_empty();
    for &u in units {
        match on.get_mut(u) {
            Some(slot) if !*slot => *slot = true,
            _ => ok = false,
        }
    }
    if !ok {
        params.problem(
            "units",
            shown,
            "must list distinct unit indices 0, 1 or 2 (at least one)",
        );
        return [true; 3];
    }
    on
}

/// An effect restricted to some units: the hooks of other units pass through and
/// their mean contribution is zero.
struct OnUnits {
    inner: Box<dyn Effect>,
    on: [bool; 3],
}

impl OnUnits {
    fn applies(&self, unit: usize) -> bool {
        self.on.get(unit).copied().unwrap_or(false)
    }
}

impl Effect for OnUnits {
    fn kind(&self) -> &'static str {
        self.inner.kind()
    }

    fn adjust_body_vibration(&self, vib_body: &mut Vibration) {
        // Only unit-scoped effects are wrapped; they do not use this hook, but pass
        // it on so that the wrapper never changes an effect's behaviour silently.
        self.inner.adjust_body_vibration(vib_body);
    }

    fn reset(&mut self, internal_rate_hz: f64) {
        self.inner.reset(internal_rate_hz);
    }

    fn at_sensor(&mut self, ctx: &BlockCtx, body_vib_g: &[[f64; 3]], sensor_g: &mut [f64]) {
        if self.applies(ctx.unit) {
            self.inner.at_sensor(ctx, body_vib_g, sensor_g);
        }
    }

    fn at_unit_input(&mut self, ctx: &BlockCtx, vib_unit_g: &mut [[f64; 3]]) {
        if self.applies(ctx.unit) {
            self.inner.at_unit_input(ctx, vib_unit_g);
        }
    }

    fn at_unit_output(&mut self, ctx: &BlockCtx, input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        if self.applies(ctx.unit) {
            self.inner.at_unit_output(ctx, input_unit_g, out_g);
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        if self.applies(ctx.unit) {
            self.inner.mean_shift_g(ctx)
        } else {
            Ok(0.0)
        }
    }

    fn clips_output(&self) -> bool {
        self.inner.clips_output()
    }

    fn output_terms(&self, ctx: &MeanContext<'_>) -> Option<crate::effect::OutputTerms> {
        let terms = self.inner.output_terms(ctx);
        if self.applies(ctx.unit) {
            terms
        } else {
            terms.map(|_| crate::effect::OutputTerms::default())
        }
    }

    fn mean_shift_over_g(
        &self,
        ctx: &MeanContext<'_>,
        others: &crate::effect::OutputTerms,
    ) -> Option<Result<f64>> {
        let shift = self.inner.mean_shift_over_g(ctx, others);
        if self.applies(ctx.unit) {
            shift
        } else {
            shift.map(|_| Ok(0.0))
        }
    }

    fn sensor_rms_factor(&self, ctx: &MeanContext<'_>) -> Option<f64> {
        let factor = self.inner.sensor_rms_factor(ctx);
        if self.applies(ctx.unit) {
            factor
        } else {
            factor.map(|_| 1.0)
        }
    }
    fn on_vibration_path(&self) -> bool {
        self.inner.on_vibration_path()
    }

    fn path_transfer(
        &self,
        unit: usize,
        f_hz: f64,
    ) -> Option<[realfft::num_complex::Complex<f64>; 3]> {
        let t = self.inner.path_transfer(unit, f_hz);
        if self.applies(unit) {
            t
        } else {
            t.map(|_| [realfft::num_complex::Complex::new(1.0, 0.0); 3])
        }
    }

    fn sensor_response(&self, unit: usize) -> Option<[f64; 3]> {
        let c = self.inner.sensor_response(unit);
        if self.applies(unit) {
            c
        } else {
            c.map(|_| [0.0, 0.0, 1.0])
        }
    }

    fn transmitted(
        &self,
        ctx: &MeanContext<'_>,
    ) -> Option<Result<(Vibration, Vec<vibro_physics::vibration::PsdBand>)>> {
        if self.applies(ctx.unit) {
            self.inner.transmitted(ctx)
        } else {
            self.inner
                .transmitted(ctx)
                .map(|_| Ok((*ctx.vibration_unit, ctx.psd_unit.to_vec())))
        }
    }
}

/// Unit-axis names accepted by the `axes` parameters, in MODEL.md's index order.
pub(crate) const UNIT_AXIS_NAMES: [&str; 3] = ["OA", "PA", "IA"];

/// Reads an optional `axes = ["OA", "PA", "IA"]` list (case-insensitive) into a mask;
/// all axes when absent.
pub(crate) fn unit_axes_param(params: &mut Params<'_>, name: &str) -> [bool; 3] {
    let Some(list) = params.strings(name) else {
        return [true; 3];
    };
    let mut on = [false; 3];
    let mut ok = !list.is_empty();
    for s in &list {
        match UNIT_AXIS_NAMES
            .iter()
            .position(|a| a.eq_ignore_ascii_case(s.trim()))
        {
            Some(i) if !on[i] => on[i] = true,
            _ => ok = false,
        }
    }
    if !ok {
        params.problem(
            name,
            format!("{list:?}"),
            "must list distinct unit axes \"OA\", \"PA\", \"IA\" (at least one)",
        );
    }
    on
}

#[cfg(test)]
mod tests;
