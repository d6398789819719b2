//! One unit's vibration error, compensation and model check as `vibrocomp model`
//! reports them (MODEL.md sections 4 to 7), and the Cyclone-4 flight of the physics
//! core alone (`vibrocomp model flight`, RIG.md).

use serde::Serialize;

use crate::compensation::{Mode, Stages, TriadCompensator, UnitCompensator};
use crate::exact::{exact_ve, MeanModel};
use crate::montecarlo::{monte_carlo_ve, MonteCarloVe};
use crate::passport::Passport;
use crate::triad::TriadAxes;
use crate::ve::{published, Constants, VeComponents};
use crate::vibration::Vibration;
use crate::Result;

/// The VE components of a unit with passport `p` at the flight acceleration `a_l`
/// (`[aL1, aL2, aL3]`, g) under `vib`: exact means (MODEL.md section 6) or the papers'
/// formulas [P1 (13)-(16)], which have no misprint (both published modes use them).
pub fn ve_components(
    p: &Passport,
    a_l: [f64; 3],
    vib: &Vibration,
    mode: Mode,
) -> Result<VeComponents> {
    Ok(match mode {
        Mode::Exact => exact_ve(p, a_l, vib)?,
        Mode::AsPublished | Mode::Paper => published(p, a_l, vib, Constants::PAPER),
    })
}

/// `model ve`: the VE of one unit in one mode.
#[derive(Debug, Clone, Serialize)]
pub struct VeReport {
    pub passport: String,
    pub mode: &'static str,
    pub a_l_g: [f64; 3],
    #[serde(flatten)]
    pub ve: VeComponents,
}

/// The [`VeReport`] of [`ve_components`].
pub fn ve_report(p: &Passport, a_l: [f64; 3], vib: &Vibration, mode: Mode) -> Result<VeReport> {
    Ok(VeReport {
        passport: p.id().to_string(),
        mode: mode.name(),
        a_l_g: a_l,
        ve: ve_components(p, a_l, vib, mode)?,
    })
}

/// `model compensate`: the stages of [P2 (17)-(20)] on one mean reading.
#[derive(Debug, Clone, Serialize)]
pub struct CompensateReport {
    pub passport: String,
    pub mode: &'static str,
    pub reading_g: f64,
    #[serde(flatten)]
    pub stages: Stages,
}

/// Compensates the mean reading `reading_g` (U/K1, g) of a unit under `vib`, with the
/// flight accelerations along OA and PA `cross_g` from the triad's other units.
pub fn compensate_report(
    p: Passport,
    vib: &Vibration,
    mode: Mode,
    reading_g: f64,
    cross_g: [f64; 2],
) -> Result<CompensateReport> {
    let mut unit = UnitCompensator::new(p, mode);
    unit.set_vibration(vib)?;
    Ok(CompensateReport {
        passport: p.id().to_string(),
        mode: mode.name(),
        reading_g,
        stages: unit.compensate(reading_g, cross_g),
    })
}

/// `model check`: exact and as-published VE against a Monte Carlo of (FP).
#[derive(Debug, Clone, Serialize)]
pub struct CheckReport {
    pub passport: String,
    pub a_l_g: [f64; 3],
    pub exact: VeComponents,
    pub as_published: VeComponents,
    pub monte_carlo: MonteCarloVe,
    /// (exact - Monte Carlo) / standard error.
    pub exact_z: f64,
    /// (as published - Monte Carlo) / standard error.
    pub as_published_z: f64,
}

/// The exact (section 6) and as-published (section 5) VE beside a Monte Carlo of
/// (FP) with `samples` evaluations from `seed`, each as a z-score against it (NaN for
/// a zero standard error).
pub fn check_report(
    p: &Passport,
    a_l: [f64; 3],
    vib: &Vibration,
    samples: u64,
    seed: u64,
) -> Result<CheckReport> {
    let exact = ve_components(p, a_l, vib, Mode::Exact)?;
    let as_published = ve_components(p, a_l, vib, Mode::AsPublished)?;
    let mc = monte_carlo_ve(p, a_l, vib, samples, seed)?;
    let z = |v: f64| {
        if mc.std_error_g > 0.0 {
            (v - mc.ve_g) / mc.std_error_g
        } else {
            f64::NAN
        }
    };
    Ok(CheckReport {
        passport: p.id().to_string(),
        a_l_g: a_l,
        exact,
        as_published,
        monte_carlo: mc,
        exact_z: z(exact.total_g),
        as_published_z: z(as_published.total_g),
    })
}

/// RMS errors of one mode over the flight, g.
#[derive(Debug, Clone, Serialize)]
pub struct ModeErrors {
    pub mode: &'static str,
    pub uncompensated_rms_g: f64,
    pub main_removed_rms_g: f64,
    pub vibration_removed_rms_g: f64,
    /// Uncompensated over vibration-removed RMS (infinite when the latter is 0).
    pub reduction: f64,
}

/// `model flight`: the Cyclone-4 flight's errors in every mode.
#[derive(Debug, Clone, Serialize)]
pub struct FlightModelReport {
    pub scenario: &'static str,
    pub triad: String,
    pub samples: usize,
    pub modes: Vec<ModeErrors>,
}

/// Longitudinal apparent acceleration of the Cyclone-4 profile at time `t_s`: three
/// stages rising from about 1 g to about 5 g over 600 s (RIG.md, [P2 Fig. 3a]).
pub fn cyclone4_longitudinal_g(t_s: f64) -> f64 {
    let stage_s = 200.0;
    let within = (t_s % stage_s) / stage_s;
    let stage = (t_s / stage_s).floor().min(2.0);
    // Each stage climbs as propellant burns; the next stage restarts a little higher.
    1.0 + 0.6 * stage + (1.6 + 0.4 * stage) * within * within
}

/// The Cyclone-4 flight (RIG.md) of a triad through the physics core alone: every
/// 10 s the three units' mean readings are the exact mean of (FP) over the flight's
/// vibration (MODEL.md section 6), compensated in each mode; the RMS error against the
/// true flight acceleration before and after. `triad` names the triad in the report.
///
/// The vibration, in each unit's axes `[OA, PA, IA]`: 0.5 g at 12 Hz along the
/// longitudinal body axis and 1.2 g across, and random vibration of sigma = 1.4 g along
/// IA ([P2]) and 1 g along OA and PA.
pub fn cyclone4_flight(
    axes: TriadAxes,
    passports: [Passport; 3],
    triad: String,
) -> Result<FlightModelReport> {
    let mut vibs = [Vibration::none(); 3];
    for (i, v) in vibs.iter_mut().enumerate() {
        let amplitude = |body_index: usize| if body_index == 0 { 0.5 } else { 1.2 };
        let unit = &axes.units[i];
        *v = Vibration::single_tone(
            12.0,
            [
                amplitude(unit.oa.body_index),
                amplitude(unit.pa.body_index),
                amplitude(unit.ia.body_index),
            ],
        );
        v.covariance_g2[2][2] = 1.4 * 1.4;
        v.covariance_g2[0][0] = 1.0;
        v.covariance_g2[1][1] = 1.0;
    }
    let mut truth_models = Vec::new();
    for (p, v) in passports.iter().zip(&vibs) {
        let mut m = MeanModel::new(*p);
        m.set_vibration(v)?;
        truth_models.push(m);
    }
    let times_s: Vec<f64> = (0..60).map(|k| 5.0 + 10.0 * k as f64).collect();
    let mut modes = Vec::new();
    for mode in [Mode::AsPublished, Mode::Paper, Mode::Exact] {
        let mut comp = TriadCompensator::new(axes, passports, mode);
        for (i, v) in vibs.iter().enumerate() {
            comp.set_vibration(i, v)?;
        }
        let (mut e1, mut e2, mut e4) = (0.0, 0.0, 0.0);
        for &t in &times_s {
            // Body frame: x longitudinal, small lateral accelerations from manoeuvres.
            let body = [
                cyclone4_longitudinal_g(t),
                0.05 * (t / 90.0).sin(),
                -0.03 * (t / 70.0).cos(),
            ];
            let mut readings = [0.0; 3];
            for i in 0..3 {
                readings[i] = truth_models[i]
                    .mean_output_g(axes.units[i].to_unit(&body))
                    .0;
            }
            let out = comp.compensate(readings);
            for i in 0..3 {
                let truth = axes.units[i].ia.project(&body);
                let s = &out.units[i];
                e1 += (s.a1_g - truth).powi(2);
                e2 += (s.a2_g - truth).powi(2);
                e4 += (s.a4_g - truth).powi(2);
            }
        }
        let n = (3 * times_s.len()) as f64;
        let (u, m, v) = ((e1 / n).sqrt(), (e2 / n).sqrt(), (e4 / n).sqrt());
        modes.push(ModeErrors {
            mode: mode.name(),
            uncompensated_rms_g: u,
            main_removed_rms_g: m,
            vibration_removed_rms_g: v,
            reduction: if v > 0.0 { u / v } else { f64::INFINITY },
        });
    }
    Ok(FlightModelReport {
        scenario: "Cyclone-4 flight (RIG.md): 600 s, aL 1..5 g, aB3 = 0.5 g, aB1 = aB2 = 1.2 g at 12 Hz, sigma = 1.4 g",
        triad,
        samples: times_s.len(),
        modes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cyclone4_profile_climbs_in_three_stages() {
        // Stage starts: 1 g, 1.6 g, 2.2 g; a stage ends 1.6 + 0.4 * stage above its start.
        assert_eq!(cyclone4_longitudinal_g(0.0), 1.0);
        assert!((cyclone4_longitudinal_g(100.0) - (1.0 + 1.6 * 0.25)).abs() < 1e-12);
        assert!((cyclone4_longitudinal_g(200.0) - 1.6).abs() < 1e-12);
        assert!((cyclone4_longitudinal_g(400.0) - 2.2).abs() < 1e-12);
        // The last stage stays the third: at 600 s within wraps to 0 again.
        assert!((cyclone4_longitudinal_g(599.999) - (2.2 + 2.4)).abs() < 1e-4);
    }
}
