//! # vibro-effects
//!
//! The physical effects beyond MODEL.md's model (MODEL.md section 11): mount
//! resonance, the unit's own frequency response, vibropendulous and anisoelastic
//! terms, saturation, heating, sensor errors and the rest. Each effect is one module
//! with one physics (time-domain hooks on sample blocks, the [`Effect`] contract) and
//! one mean formula ([`Effect::mean_shift_g`]: the change of the unit's mean output
//! when the effect is switched on, from a closed form or a deterministic quadrature,
//! never from a simulation). The same code serves
//!
//! - the rig simulator (`vibro-sim`), which runs the hooks sample by sample and checks
//!   its averaged output against the mean formulas;
//! - the model lab (`vibro-lab`), which fits effects to a campaign and explains its
//!   measured vibration error with the mean formulas;
//! - the real-time compensator, which removes the extended model's vibration error
//!   with the same mean formulas.
//!
//! Modules:
//!
//! - [`effect`]: the [`Effect`] trait, [`BlockCtx`] and [`MeanContext`];
//! - [`effects`]: the effects library, its registry ([`catalogue`]) and the builders
//!   of `[[effect]]` tables ([`EffectSpec`], [`build`], [`build_for_rig`]);
//! - [`model`]: the extended model file (`MODEL.toml`, docs/lab.md): a base mode and
//!   the `[[effect]]` tables added to it ([`LabModel`]);
//! - [`predict`]: the extended model's vibration error for one condition
//!   ([`predict_ve`]);
//! - [`mapping`]: from one vibration estimate (the estimator's wire `VibEstimate`, in
//!   the sensors' axes) to the vibration each unit sees in its own axes;
//! - [`interval`]: the part of that vibration *within* one output interval (what a
//!   reading that is a mean over the interval rectifies unseen). The compensator and
//!   the lab share these two, so that both read an estimate the same way.
//!
//! ```
//! use vibro_effects::model::{build_effects, BaseMode};
//! use vibro_effects::predict::{flat_passport, predict_ve};
//! use vibro_physics::vibration::Vibration;
//!
//! // One `[[effect]]` table, as a scenario or a MODEL.toml writes it.
//! let table: toml::Table = toml::from_str("kind = \"anisoelastic\"\nk_ae_per_g = 2.0e-5")?;
//! let passport = flat_passport(&vibro_config::resolve_passport("AL-15")?)?;
//! let effects = build_effects(&[table], &passport)?;
//! // A 30 Hz tone of 1.2 g on OA and 0.8 g on PA, in phase; gravity on IA.
//! let vib = Vibration::single_tone(30.0, [1.2, 0.8, 0.0]);
//! let a_l_unit_g = [0.0, 0.0, 1.0];
//! let p = predict_ve(BaseMode::Exact, &effects, &passport, a_l_unit_g, &vib, &[], f64::INFINITY)?;
//! // The anisoelastic VE change is k_ae E[v1 v2] = k_ae 0.5 aB1 aB2 (docs/effects.md).
//! assert_eq!(p.effects[0].0, "anisoelastic");
//! assert!((p.effects[0].1 - 2.0e-5 * 0.5 * 1.2 * 0.8).abs() < 1e-15);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The crate does no I/O beyond reading and writing a model file; a model file's
//! `passport` (an id or a file) is resolved by `vibro_config::resolve_passport`.
//!
//! References: docs/effects.md (every effect: physics, parameters, mean formula, how
//! to add one); MODEL.md section 11 (the effects the model leaves out), sections 2
//! (the conversion function and frames) and 5-6 (the base VE the effects add to);
//! docs/lab.md (the extended model file and its prediction).

// Index loops mirror the formulas' subscripts (axis i, K_ij) and index several arrays
// at once; iterator chains would hide the indices (as in vibro-physics).
#![allow(clippy::needless_range_loop)]

pub mod effect;
pub mod effects;
pub mod empirical;
mod error;
pub mod interval;
pub mod mapping;
pub mod model;
pub mod predict;
pub mod report;
pub mod spectrum;

pub use effect::{BlockCtx, Effect, MeanContext};
pub use effects::{
    build, build_for_rig, campaign_axes, catalogue, listing, EffectInfo, EffectListing, EffectSpec,
    ParamInfo, Rig, Scope, MAX_EFFECT_PARAMS,
};
pub use error::{Error, Result};
pub use model::{BaseMode, FitRecord, LabModel};
pub use predict::{predict_ve, Prediction};
