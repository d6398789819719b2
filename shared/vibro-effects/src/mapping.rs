//! From one [`VibEstimate`] (sensor frame) to the vibration each unit sees in its own
//! axes `[OA, PA, IA]` (MODEL.md section 3 descriptions, [`Vibration`]).
//!
//! Geometry (RIG.md, [P2 Fig. 6]): vibration sensor `j` sits next to unit `j` and
//! measures along that unit's input axis, a signed body axis `s_j e_{b_j}`. The three
//! IAs cover x, y and z, so the sensors give the body-frame vibration
//! `v_body[b_j] = s_j v_sensor[j]`. Unit `u` sees along its axis `a` (a signed body axis
//! `s_a e_{b_a}`) the component `s_a v_body[b_a]`. So each unit axis reads one sensor
//! `j(b_a)` with the sign `s_a s_j`, and:
//!
//! - tone amplitudes carry over, a negative sign adds `pi` to the phase
//!   (`-A sin(wt + phi) = A sin(wt + phi + pi)`), wrapped to `(-pi, pi]`;
//! - covariances `K_ab = s_a s_b K_sensor[j(a)][j(b)]`, variances unchanged;
//! - kurtosis carries over (even moments do not see the sign).
//!
//! The physics keeps at most [`vibro_physics::vibration::MAX_TONES`] tones; when the
//! estimate holds more, the strongest (largest `sum_j aB_j^2`) are kept and the rest
//! counted. Nothing here allocates on success.

use std::f64::consts::PI;
use vibro_msgs::VibEstimate;
use vibro_physics::triad::TriadAxes;
use vibro_physics::vibration::{Tone, Vibration, MAX_TONES as PHYSICS_MAX_TONES};

/// What the estimate's kurtosis becomes in the vibration model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KurtosisUse {
    /// The estimated kurtosis per axis; a value that is not finite or outside the
    /// model's `1..=30` falls back to 3 (Gaussian) and the output is flagged.
    Estimated,
    /// Always 3: the random vibration taken as Gaussian.
    Gaussian,
}

/// How an estimate is turned into the model's vibration description (`[estimate]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EstimateMapping {
    /// Use the tones (deterministic vibration, stage (19)).
    pub use_tones: bool,
    /// Use the broadband part (random vibration, stage (20)).
    pub use_random: bool,
    /// Keep the cross-axis covariances (`K_31`, `K_32`); otherwise only the variances.
    pub use_cross_covariance: bool,
    pub kurtosis: KurtosisUse,
    /// Most tones handed to the model, `1..=vibro_physics::vibration::MAX_TONES`.
    pub max_tones: usize,
    /// Use only the vibration inside one output interval (`crate::interval`): the
    /// samples resolve the rest, and stage (18) at each sample removes what it
    /// rectifies. `false`: the whole vibration, for readings that are means over
    /// intervals long against the vibration periods (the papers' setting).
    pub within_output_interval: bool,
}

impl Default for EstimateMapping {
    fn default() -> Self {
        Self {
            use_tones: true,
            use_random: true,
            use_cross_covariance: true,
            kurtosis: KurtosisUse::Estimated,
            max_tones: PHYSICS_MAX_TONES,
            within_output_interval: true,
        }
    }
}

/// The vibration of each unit of the triad, in its own axes, from one estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitVibrations {
    pub units: [Vibration; 3],
    /// Tones of the estimate left out (beyond `max_tones`).
    pub tones_dropped: u32,
    /// A kurtosis was replaced by 3 (not finite or outside `1..=30`).
    pub kurtosis_defaulted: bool,
}

/// Why an estimate cannot be used. Messages carry the offending values.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum MappingError {
    #[error("estimate {seq}: {source}")]
    Counts { seq: u64, source: vibro_msgs::Error },
    #[error("estimate {seq}: {field}[{index}] = {value}: must be finite")]
    NonFinite {
        seq: u64,
        field: &'static str,
        index: usize,
        value: f64,
    },
    #[error("estimate {seq}: unit {unit}: {source}")]
    Invalid {
        seq: u64,
        unit: usize,
        source: vibro_physics::Error,
    },
}

/// Which sensor each unit axis reads, and with which sign: `[unit][axis OA, PA, IA]`.
pub fn sensor_map(axes: &TriadAxes) -> [[(usize, f64); 3]; 3] {
    // The sensor on each body axis (TriadAxes::new guarantees the IAs cover x, y, z).
    let mut sensor_of_body = [(0usize, 1.0f64); 3];
    for (j, u) in axes.units.iter().enumerate() {
        sensor_of_body[u.ia.body_index] = (j, f64::from(u.ia.sign));
    }
    axes.units.map(|u| {
        [u.oa, u.pa, u.ia].map(|a| {
            let (j, s_j) = sensor_of_body[a.body_index];
            (j, f64::from(a.sign) * s_j)
        })
    })
}

/// `phase + pi` for a negative sign, wrapped to `(-pi, pi]`.
fn signed_phase(phase_rad: f64, sign: f64) -> f64 {
    let p = if sign < 0.0 {
        phase_rad + PI
    } else {
        phase_rad
    };
    let wrapped = p - 2.0 * PI * ((p + PI) / (2.0 * PI)).floor();
    // `floor` maps exactly -pi to -pi; the interval is half-open the other way.
    if wrapped <= -PI {
        wrapped + 2.0 * PI
    } else {
        wrapped
    }
}

fn finite(seq: u64, field: &'static str, index: usize, value: f64) -> Result<f64, MappingError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(MappingError::NonFinite {
            seq,
            field,
            index,
            value,
        })
    }
}

/// Maps an estimate to each unit's vibration (see the module's documentation).
pub fn unit_vibrations(
    est: &VibEstimate,
    axes: &TriadAxes,
    mapping: &EstimateMapping,
) -> Result<UnitVibrations, MappingError> {
    use vibro_msgs::WireMessage;
    let seq = est.seq;
    est.validate()
        .map_err(|source| MappingError::Counts { seq, source })?;
    let map = sensor_map(axes);
    let mut out = UnitVibrations {
        units: [Vibration::none(); 3],
        tones_dropped: 0,
        kurtosis_defaulted: false,
    };

    if mapping.use_tones {
        let count = est.tone_count as usize;
        // Strongest tones first, the estimate's order among equals (an unstable sort
        // with the index as tie-break: it never allocates).
        let mut order = [0usize; vibro_msgs::MAX_TONES];
        let mut power = [0.0f64; vibro_msgs::MAX_TONES];
        for k in 0..count {
            order[k] = k;
            finite(seq, "tone_frequency_hz", k, est.tone_frequency_hz[k])?;
            for j in 0..3 {
                let a = finite(
                    seq,
                    "tone_amplitude_g",
                    3 * k + j,
                    est.tone_amplitude_g[k][j],
                )?;
                finite(seq, "tone_phase_rad", 3 * k + j, est.tone_phase_rad[k][j])?;
                power[k] += a * a;
            }
        }
        order[..count].sort_unstable_by(|&a, &b| power[b].total_cmp(&power[a]).then(a.cmp(&b)));
        let keep = count.min(mapping.max_tones.min(PHYSICS_MAX_TONES));
        out.tones_dropped = (count - keep) as u32;
        for &k in &order[..keep] {
            for (u, vib) in out.units.iter_mut().enumerate() {
                let mut tone = Tone {
                    freq_hz: est.tone_frequency_hz[k],
                    amplitude_g: [0.0; 3],
                    phase_rad: [0.0; 3],
                };
                for (axis, &(j, sign)) in map[u].iter().enumerate() {
                    tone.amplitude_g[axis] = est.tone_amplitude_g[k][j];
                    tone.phase_rad[axis] = signed_phase(est.tone_phase_rad[k][j], sign);
                }
                vib.push_tone(tone)
                    .map_err(|source| MappingError::Invalid {
                        seq,
                        unit: u,
                        source,
                    })?;
            }
        }
    }

    if mapping.use_random {
        let c = &est.broadband_covariance_g2;
        let mut cov = [[0.0f64; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                finite(seq, "broadband_covariance_g2", 3 * i + j, c[i][j])?;
            }
        }
        // The estimator's matrix is symmetric up to rounding and positive
        // semi-definite up to its uncertainty; the model wants both exactly.
        for i in 0..3 {
            cov[i][i] = c[i][i].max(0.0);
        }
        for i in 0..3 {
            for j in (i + 1)..3 {
                let limit = (cov[i][i] * cov[j][j]).sqrt();
                let v = if mapping.use_cross_covariance {
                    (0.5 * (c[i][j] + c[j][i])).clamp(-limit, limit)
                } else {
                    0.0
                };
                cov[i][j] = v;
                cov[j][i] = v;
            }
        }
        let mut kurtosis = [3.0f64; 3];
        if mapping.kurtosis == KurtosisUse::Estimated {
            for (j, k) in kurtosis.iter_mut().enumerate() {
                let e = est.broadband_kurtosis[j];
                if e.is_finite() && (1.0..=30.0).contains(&e) {
                    *k = e;
                } else if cov[j][j] > 0.0 {
                    // Without random vibration on the axis its kurtosis is irrelevant.
                    out.kurtosis_defaulted = true;
                }
            }
        }
        for (u, vib) in out.units.iter_mut().enumerate() {
            for (a, &(ja, sa)) in map[u].iter().enumerate() {
                vib.kurtosis[a] = kurtosis[ja];
                for (b, &(jb, sb)) in map[u].iter().enumerate() {
                    vib.covariance_g2[a][b] = sa * sb * cov[ja][jb];
                }
            }
        }
    }

    for (u, vib) in out.units.iter().enumerate() {
        vib.validate().map_err(|source| MappingError::Invalid {
            seq,
            unit: u,
            source,
        })?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_physics::triad::{SignedAxis, UnitAxes};

    fn ax(s: &str) -> SignedAxis {
        SignedAxis::parse(s).unwrap()
    }

    /// A triad with sign flips: unit 0 IA = -y, unit 1 IA = +z, unit 2 IA = -x.
    fn flipped() -> TriadAxes {
        TriadAxes::new([
            UnitAxes::new(ax("-y"), ax("+z"), ax("-x")).unwrap(),
            UnitAxes::new(ax("+z"), ax("-x"), ax("+y")).unwrap(),
            UnitAxes::new(ax("-x"), ax("-y"), ax("z")).unwrap(),
        ])
        .unwrap()
    }

    fn estimate() -> VibEstimate {
        let mut e = VibEstimate::ZEROED;
        e.seq = 4;
        e.tone_count = 1;
        e.tone_frequency_hz[0] = 12.0;
        e.tone_amplitude_g[0] = [0.5, 1.2, 0.8];
        e.tone_phase_rad[0] = [0.1, -0.2, 3.0];
        e.broadband_covariance_g2 = [[1.0, 0.2, -0.1], [0.2, 4.0, 0.3], [-0.1, 0.3, 2.25]];
        e.broadband_kurtosis = [3.0, 3.5, 2.5];
        e
    }

    #[test]
    fn the_standard_triad_reads_each_unit_axis_from_its_sensor() {
        let v = unit_vibrations(
            &estimate(),
            &TriadAxes::standard(),
            &EstimateMapping::default(),
        )
        .unwrap();
        // Unit 0: IA = x (sensor 0), OA = y (sensor 1), PA = z (sensor 2).
        let t = v.units[0].tones()[0];
        assert_eq!(t.amplitude_g, [1.2, 0.8, 0.5]);
        assert_eq!(t.phase_rad, [-0.2, 3.0, 0.1]);
        assert_eq!(v.units[0].covariance_g2[2][0], 0.2); // K_31 = cov(x, y)
        assert_eq!(v.units[0].covariance_g2[2][1], -0.1); // K_32 = cov(x, z)
        assert_eq!(v.units[0].kurtosis, [3.5, 2.5, 3.0]);
        assert_eq!(v.units[2].covariance_g2[2][2], 2.25);
        assert_eq!(v.tones_dropped, 0);
    }

    /// Checked against the phasor rotation: a tone is a complex vector per body axis,
    /// the unit sees its real and imaginary parts projected by `UnitAxes::to_unit`.
    #[test]
    fn sign_flips_turn_phases_by_pi_and_covariances_by_sign() {
        let axes = flipped();
        let e = estimate();
        let v = unit_vibrations(&e, &axes, &EstimateMapping::default()).unwrap();
        // Body-frame phasors from the sensors: sensor j reads s_j * body[b_j].
        let mut re = [0.0; 3];
        let mut im = [0.0; 3];
        let mut body_cov = [[0.0; 3]; 3];
        for (j, u) in axes.units.iter().enumerate() {
            let s = f64::from(u.ia.sign);
            let (a, p) = (e.tone_amplitude_g[0][j], e.tone_phase_rad[0][j]);
            re[u.ia.body_index] = s * a * p.cos();
            im[u.ia.body_index] = s * a * p.sin();
            for (k, w) in axes.units.iter().enumerate() {
                body_cov[u.ia.body_index][w.ia.body_index] =
                    s * f64::from(w.ia.sign) * e.broadband_covariance_g2[j][k];
            }
        }
        for (u, unit) in axes.units.iter().enumerate() {
            let (r, i) = (unit.to_unit(&re), unit.to_unit(&im));
            let t = v.units[u].tones()[0];
            for a in 0..3 {
                let amp = r[a].hypot(i[a]);
                assert!((t.amplitude_g[a] - amp).abs() < 1e-15, "unit {u} axis {a}");
                let got = (t.phase_rad[a].cos(), t.phase_rad[a].sin());
                assert!((got.0 * amp - r[a]).abs() < 1e-14 && (got.1 * amp - i[a]).abs() < 1e-14);
                assert!(t.phase_rad[a] > -PI && t.phase_rad[a] <= PI);
            }
            // Covariance: P C P^T with P's rows the unit axes in the body frame.
            let rows = [unit.oa, unit.pa, unit.ia];
            for a in 0..3 {
                for b in 0..3 {
                    let want = f64::from(rows[a].sign)
                        * f64::from(rows[b].sign)
                        * body_cov[rows[a].body_index][rows[b].body_index];
                    assert_eq!(v.units[u].covariance_g2[a][b], want, "unit {u} [{a}][{b}]");
                }
            }
        }
    }

    #[test]
    fn options_and_bad_values() {
        let mut e = estimate();
        let only_tones = EstimateMapping {
            use_random: false,
            ..EstimateMapping::default()
        };
        let v = unit_vibrations(&e, &TriadAxes::standard(), &only_tones).unwrap();
        assert_eq!(v.units[1].covariance_g2, [[0.0; 3]; 3]);
        assert_eq!(v.units[1].tones().len(), 1);
        let diagonal = EstimateMapping {
            use_tones: false,
            use_cross_covariance: false,
            kurtosis: KurtosisUse::Gaussian,
            ..EstimateMapping::default()
        };
        let v = unit_vibrations(&e, &TriadAxes::standard(), &diagonal).unwrap();
        assert!(v.units[0].tones().is_empty());
        assert_eq!(v.units[0].covariance_g2[2][0], 0.0);
        assert_eq!(v.units[0].kurtosis, [3.0; 3]);

        e.broadband_kurtosis[1] = f64::NAN;
        let v = unit_vibrations(&e, &TriadAxes::standard(), &EstimateMapping::default()).unwrap();
        assert!(v.kurtosis_defaulted);
        assert_eq!(v.units[1].kurtosis[2], 3.0);

        e.broadband_covariance_g2[2][2] = f64::NAN;
        let err =
            unit_vibrations(&e, &TriadAxes::standard(), &EstimateMapping::default()).unwrap_err();
        assert_eq!(
            err.to_string(),
            "estimate 4: broadband_covariance_g2[8] = NaN: must be finite"
        );
        e.tone_count = 17;
        assert!(matches!(
            unit_vibrations(&e, &TriadAxes::standard(), &EstimateMapping::default()),
            Err(MappingError::Counts { .. })
        ));
    }

    #[test]
    fn the_strongest_tones_are_kept() {
        let mut e = estimate();
        e.tone_count = 12;
        for k in 0..12 {
            e.tone_frequency_hz[k] = 10.0 + k as f64;
            e.tone_amplitude_g[k] = [0.1 * (k as f64 + 1.0); 3];
            e.tone_phase_rad[k] = [0.0; 3];
        }
        let m = EstimateMapping {
            max_tones: 3,
            ..EstimateMapping::default()
        };
        let v = unit_vibrations(&e, &TriadAxes::standard(), &m).unwrap();
        let f: Vec<f64> = v.units[0].tones().iter().map(|t| t.freq_hz).collect();
        assert_eq!(f, [21.0, 20.0, 19.0]);
        assert_eq!(v.tones_dropped, 9);
    }

    #[test]
    fn phases_wrap_into_the_half_open_interval() {
        assert_eq!(signed_phase(0.5, 1.0), 0.5);
        assert!((signed_phase(0.5, -1.0) - (0.5 - PI)).abs() < 1e-15);
        assert!((signed_phase(-0.5, -1.0) - (PI - 0.5)).abs() < 1e-15);
        assert_eq!(signed_phase(0.0, -1.0), PI);
        assert_eq!(signed_phase(-PI, 1.0), PI);
    }
}
