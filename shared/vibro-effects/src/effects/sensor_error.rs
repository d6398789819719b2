//! `sensor_error`: gain error and misalignment of a unit's vibration sensor (MODEL.md
//! section 11, last item; RIG.md: each sensor VD measures along its unit's IA).
//!
//! Physics: the compensation (MODEL.md section 7) trusts the vibration sensors; a
//! sensor whose sensitivity is off by `gain_error` and whose axis leans by
//! `misalignment_oa_rad` towards the unit's OA and `misalignment_pa_rad` towards its
//! PA reads (small angles)
//! `sensor = (1 + gain_error) v_IA + misalignment_oa_rad v_OA + misalignment_pa_rad v_PA`,
//! with `v_OA`, `v_PA` the body vibration projected on the unit's signed OA and PA
//! axes (from the rig's triad). Hook: [`Effect::at_sensor`].
//!
//! Mean contribution to the accelerometer: 0 (the unit itself is untouched; the error
//! appears only once the compensation uses the sensor). [`Effect::sensor_rms_factor`]:
//! the ratio of the sensor's RMS with the error to without,
//! `sqrt(P_err / P_IA)` over tones and random part together, where for a tone
//! `P = |(1+g) aB3 e^{j phi3} + m_oa aB1 e^{j phi1} + m_pa aB2 e^{j phi2}|^2 / 2` and
//! for the random part `P = u^T C u` with `u = (m_oa, m_pa, 1+g)` and `C` the
//! covariance in unit axes; for uncorrelated axes this is
//! `sqrt((1+g)^2 + m_oa^2 sigma_OA^2/sigma_IA^2 + m_pa^2 sigma_PA^2/sigma_IA^2)`.
//! Per tone and per band the factor is the same only when the axes' spectra are
//! proportional; the trait asks for one number, so this is the total. With no IA
//! vibration at all the factor is `|1 + g|`.

use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext};
use crate::Result;
use realfft::num_complex::Complex;
use vibro_physics::triad::TriadAxes;

const KIND: &str = "sensor_error";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "vibration-sensor gain error and misalignment towards the unit's OA and PA",
    params: &[
        ParamInfo {
            name: "gain_error",
            unit: "1",
            meaning: "relative sensitivity error of the sensor; default 0, |g| <= 0.5",
        },
        ParamInfo {
            name: "misalignment_oa_rad",
            unit: "rad",
            meaning: "tilt of the sensor axis towards the unit's OA; default 0, |m| <= 0.2",
        },
        ParamInfo {
            name: "misalignment_pa_rad",
            unit: "rad",
            meaning: "tilt towards the unit's PA; default 0, |m| <= 0.2; at least one of the \
                      three is required",
        },
    ],
    hooks: "at_sensor",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "sensor_error"
gain_error = 0.02
misalignment_oa_rad = 0.005
misalignment_pa_rad = -0.003
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    p.require_any(&["gain_error", "misalignment_oa_rad", "misalignment_pa_rad"]);
    let gain_error = p.with_default(
        "gain_error",
        0.0,
        "must be finite and |gain_error| <= 0.5",
        |g| g.abs() <= 0.5,
    );
    let rule = "must be finite and |misalignment| <= 0.2 rad";
    let m_oa = p.with_default("misalignment_oa_rad", 0.0, rule, |m| m.abs() <= 0.2);
    let m_pa = p.with_default("misalignment_pa_rad", 0.0, rule, |m| m.abs() <= 0.2);
    Ok(Box::new(SensorError {
        gain: 1.0 + gain_error,
        misalignment_rad: [m_oa, m_pa],
        triad: p.rig().triad,
    }))
}

#[derive(Debug, Clone)]
struct SensorError {
    /// `1 + gain_error`.
    gain: f64,
    /// Towards OA, PA.
    misalignment_rad: [f64; 2],
    triad: TriadAxes,
}

impl Effect for SensorError {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn at_sensor(&mut self, ctx: &BlockCtx, body_vib_g: &[[f64; 3]], sensor_g: &mut [f64]) {
        let Some(axes) = self.triad.units.get(ctx.unit) else {
            return;
        };
        let [m_oa, m_pa] = self.misalignment_rad;
        for (s, b) in sensor_g.iter_mut().zip(body_vib_g) {
            *s = self.gain * *s + m_oa * axes.oa.project(b) + m_pa * axes.pa.project(b);
        }
    }

    fn mean_shift_g(&self, _ctx: &MeanContext<'_>) -> Result<f64> {
        Ok(0.0)
    }

    fn sensor_response(&self, _unit: usize) -> Option<[f64; 3]> {
        Some([
            self.misalignment_rad[0],
            self.misalignment_rad[1],
            self.gain,
        ])
    }

    fn sensor_rms_factor(&self, ctx: &MeanContext<'_>) -> Option<f64> {
        let vib = ctx.vibration_unit;
        let u = [
            self.misalignment_rad[0],
            self.misalignment_rad[1],
            self.gain,
        ];
        let (mut p_ia, mut p_err) = (0.0, 0.0);
        for t in vib.tones() {
            let phasor = |i: usize| Complex::from_polar(t.amplitude_g[i], t.phase_rad[i]);
            p_ia += 0.5 * t.amplitude_g[2] * t.amplitude_g[2];
            p_err += 0.5 * (u[0] * phasor(0) + u[1] * phasor(1) + u[2] * phasor(2)).norm_sqr();
        }
        let c = &vib.covariance_g2;
        p_ia += c[2][2];
        for i in 0..3 {
            for j in 0..3 {
                p_err += u[i] * c[i][j] * u[j];
            }
        }
        Some(if p_ia > 0.0 {
            (p_err.max(0.0) / p_ia).sqrt()
        } else {
            self.gain.abs()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{
        al15, band, bands_to_unit, body_to_unit, build_toml, estimate, tone, unit_shift, Scene,
    };
    use crate::effect::BlockCtx;
    use vibro_physics::triad::TriadAxes;

    /// The RMS of the sensor with the error over the RMS of the ideal sensor, measured
    /// on body-frame records (tones with phases, correlated noise), against the factor.
    #[test]
    fn rms_factor_matches_time_domain_and_unit_output_is_untouched() {
        let p = al15();
        let mut s = Scene::new(1024.0, 1 << 13);
        s.tones = vec![tone(19.3, [1.0, 1.5, 0.8], [0.0, 120.0, 30.0])];
        s.bands = vec![band(10.0, 200.0, [0.01, 0.006, 0.003])];
        s.coherence = [[1.0, 0.3, -0.4], [0.3, 1.0, 0.2], [-0.4, 0.2, 1.0]];
        let mut e = build_toml(
            "kind = \"sensor_error\"\ngain_error = 0.03\nmisalignment_oa_rad = 0.1\nmisalignment_pa_rad = -0.08",
            &p,
        );
        let triad = TriadAxes::standard();
        let unit = 1;
        let axes = triad.units[unit];
        let vib_unit = body_to_unit(&s.vibration(), &axes);
        let bands = bands_to_unit(&s.bands, &axes);
        let mut ctx = s.ctx(unit, &p, &vib_unit);
        ctx.psd_unit = &bands;
        let factor = e.sensor_rms_factor(&ctx).unwrap();
        let desc = s.vibration();
        let est = estimate(s.reps, 1300, |seed| {
            let body = s.synth(&desc, seed);
            let ideal: Vec<f64> = body.iter().map(|b| axes.ia.project(b)).collect();
            let mut sensor = ideal.clone();
            e.reset(s.rate_hz);
            for (k, (chunk, out)) in body.chunks(700).zip(sensor.chunks_mut(700)).enumerate() {
                let ctx = BlockCtx {
                    unit,
                    t0_s: (k * 700) as f64 / s.rate_hz,
                    dt_s: 1.0 / s.rate_hz,
                };
                e.at_sensor(&ctx, chunk, out);
            }
            let power = |x: &[f64]| x.iter().map(|v| v * v).sum::<f64>();
            (power(&sensor) / power(&ideal)).sqrt()
        });
        let z = (est.mean_g - factor) / est.se_g;
        eprintln!(
            "sensor_error: factor {factor:.6}, time domain {:.6} +- {:.1e}, z = {z:.2}",
            est.mean_g, est.se_g
        );
        assert!(z.abs() < 4.0, "z = {z:.2}");
        assert!((factor - 1.0).abs() > 10.0 * est.se_g);
        // The accelerometer output does not change at all.
        assert_eq!(e.mean_shift_g(&ctx).unwrap(), 0.0);
        let shift = unit_shift(&s, &p, unit, e.as_mut(), 1400);
        assert_eq!(shift.mean_g, 0.0);
    }
}
