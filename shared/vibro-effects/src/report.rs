//! One unit's VE and compensation under an extended model (`vibrocomp model ve
//! --model`, `model compensate --model`; docs/lab.md): the base model plus each
//! effect's VE change, as [`crate::predict`] gives them in steady state.

use std::path::Path;

use serde::Serialize;
use vibro_physics::compensation::{Mode, Stages, UnitCompensator};
use vibro_physics::passport::Passport;
use vibro_physics::vibration::{PsdBand, Vibration};

use crate::{predict, BaseMode, LabModel, Result};

/// One effect's VE change, g.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EffectVe {
    pub kind: String,
    pub ve_g: f64,
}

/// `model ve --model`: the extended model's VE and its parts.
#[derive(Debug, Clone, Serialize)]
pub struct ExtendedVeReport {
    pub passport: String,
    pub model: String,
    pub mode: &'static str,
    pub a_l_g: [f64; 3],
    pub base_ve_g: f64,
    /// What the sensor effects scale the IA vibration's RMS by.
    pub sensor_rms_factor: f64,
    pub effects: Vec<EffectVe>,
    pub ve_g: f64,
}

/// The VE of a unit with passport `p` at `a_l` (g) under `vib` by the extended model
/// in the file `path`: its base mode plus its effects ([`crate::predict_ve`], steady
/// state).
pub fn extended_ve(
    path: &Path,
    p: &Passport,
    a_l: [f64; 3],
    vib: &Vibration,
    psd: &[PsdBand],
) -> Result<ExtendedVeReport> {
    let model = LabModel::load(path)?;
    extended_ve_of(&model, &path.display().to_string(), p, a_l, (vib, psd))
}

/// [`extended_ve`] of a model already read; `name` names it in the report.
pub fn extended_ve_of(
    model: &LabModel,
    name: &str,
    p: &Passport,
    a_l: [f64; 3],
    (vib, psd): (&Vibration, &[PsdBand]),
) -> Result<ExtendedVeReport> {
    let flat = predict::flat_passport(p)?;
    let effects = model.build_effects(&flat)?;
    let pred = crate::predict_ve(model.mode, &effects, &flat, a_l, vib, psd, f64::INFINITY)?;
    Ok(ExtendedVeReport {
        passport: p.id().to_string(),
        model: name.to_string(),
        mode: model.mode.name(),
        a_l_g: a_l,
        base_ve_g: pred.base_ve_g,
        sensor_rms_factor: pred.sensor_rms_factor,
        effects: pred
            .effects
            .iter()
            .map(|(kind, ve_g)| EffectVe {
                kind: kind.clone(),
                ve_g: *ve_g,
            })
            .collect(),
        ve_g: pred.ve_g,
    })
}

/// `model compensate --model`: the stages of [P2 (17)-(20)] and the extended model's
/// effects removed after them.
#[derive(Debug, Clone, Serialize)]
pub struct ExtendedCompensateReport {
    pub passport: String,
    pub model: String,
    pub mode: &'static str,
    pub reading_g: f64,
    #[serde(flatten)]
    pub stages: Stages,
    pub sensor_rms_factor: f64,
    pub effects: Vec<EffectVe>,
    /// a(4) with the extended model's effects removed too.
    pub a4_extended_g: f64,
}

/// The physics core's compensation mode of a model's base mode.
pub fn compensation_mode(mode: BaseMode) -> Mode {
    match mode {
        BaseMode::Exact => Mode::Exact,
        BaseMode::Paper => Mode::Paper,
        BaseMode::AsPublished => Mode::AsPublished,
    }
}

/// Compensates the mean reading `reading_g` (U/K1, g) as the compensator service does
/// with the extended model in `path` (docs/services.md): its mode replaces the
/// caller's, the sensor effects scale the IA vibration, and the other effects' VE at
/// a(1) is removed after (20). `cross_g`: the flight accelerations along OA and PA.
pub fn extended_compensate(
    path: &Path,
    p: Passport,
    (vib, psd): (&Vibration, &[PsdBand]),
    reading_g: f64,
    cross_g: [f64; 2],
) -> Result<ExtendedCompensateReport> {
    let lab = LabModel::load(path)?;
    extended_compensate_of(
        &lab,
        &path.display().to_string(),
        p,
        (vib, psd),
        (reading_g, cross_g),
    )
}

/// [`extended_compensate`] of a model already read; `name` names it in the report.
pub fn extended_compensate_of(
    lab: &LabModel,
    name: &str,
    p: Passport,
    (vib, psd): (&Vibration, &[PsdBand]),
    (reading_g, cross_g): (f64, [f64; 2]),
) -> Result<ExtendedCompensateReport> {
    let mode = compensation_mode(lab.mode);
    let flat = predict::flat_passport(&p)?;
    let effects = lab.build_effects(&flat)?;
    let cross = cross_g;
    let truth =
        predict::true_vibration(&effects, &flat, [cross[0], cross[1], reading_g], vib, psd)?;
    let (factor, vib_true) = (truth.sensor_rms_factor, truth.vibration);
    let mut unit = UnitCompensator::new(p, mode);
    unit.set_vibration(&vib_true)?;
    let stages = unit.compensate(reading_g, cross);
    let parts = predict::effect_shifts_g(
        &effects,
        &flat,
        [cross[0], cross[1], stages.a1_g],
        &vib_true,
        &truth.psd,
        f64::INFINITY,
    )?;
    let total: f64 = parts.iter().map(|(_, v)| v).sum();
    Ok(ExtendedCompensateReport {
        passport: p.id().to_string(),
        model: name.to_string(),
        mode: mode.name(),
        reading_g,
        stages,
        sensor_rms_factor: factor,
        effects: parts
            .into_iter()
            .map(|(kind, ve_g)| EffectVe { kind, ve_g })
            .collect(),
        a4_extended_g: stages.a4_g - total,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base_modes_map_to_compensation_modes() {
        assert_eq!(compensation_mode(BaseMode::Exact), Mode::Exact);
        assert_eq!(compensation_mode(BaseMode::Paper), Mode::Paper);
        assert_eq!(compensation_mode(BaseMode::AsPublished), Mode::AsPublished);
    }
}
