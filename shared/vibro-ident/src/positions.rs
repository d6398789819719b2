//! Test positions of the shake-table identification, MODEL.md section 9.

use crate::{Error, Result};
use serde::Serialize;

/// Vibration amplitudes along the unit's axes: IA (axis 3), OA (axis 1), PA (axis 2).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Amplitudes {
    /// Along the input axis IA, g.
    pub a_b3_g: f64,
    /// Along the output axis OA, g.
    pub a_b1_g: f64,
    /// Along the pendulum axis PA, g.
    pub a_b2_g: f64,
}

/// One test position (TP) of the shake-table identification, MODEL.md section 9.
///
/// The unit is turned in the vertical plane by `angle_deg`, so gravity projects on IA
/// as `g3 = g*cos(angle)` with `g = 1 g` ([`TestPosition::g3_g`]); sinusoidal vibration
/// of amplitude `a_b3_g` is applied along IA, and `a_b1_g`, `a_b2_g` along OA, PA (TP9:
/// IA and OA both get `aB`; TP10: IA and PA). `du_v = <U_vibrating> - U_still` [P1 (21)].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TestPosition {
    /// Label, the paper's TP number. Used in messages only: the methods recognise a
    /// position by its angle and vibration axes, not by its label.
    pub tp: u32,
    /// Angle of the position in the vertical plane, deg (IA up at 0 deg).
    pub angle_deg: f64,
    /// Vibration amplitudes along IA, OA, PA.
    pub amplitudes: Amplitudes,
    /// `dU_k = <U_vibrating> - U_still`, V.
    pub du_v: f64,
    /// Standard uncertainty of `du_v`, V; `None` when unknown (then the scatter of the
    /// residuals estimates it, if there are more positions than unknowns).
    pub du_sigma_v: Option<f64>,
}

impl TestPosition {
    /// Gravity along IA in this position, g: `cos(angle)` with `g = 1 g` [P1 (21)].
    pub fn g3_g(&self) -> f64 {
        cos_deg(self.angle_deg)
    }

    /// Checks every field; `index` is the position's index in its slice, for messages.
    pub(crate) fn validate(&self, index: usize) -> Result<()> {
        let bad = |field, value, rule| Error::InvalidPosition {
            index,
            tp: self.tp,
            field,
            value,
            rule,
        };
        if !self.angle_deg.is_finite() {
            return Err(bad("angle_deg", self.angle_deg, "must be finite"));
        }
        let a = self.amplitudes;
        for (field, value) in [
            ("aB3_g", a.a_b3_g),
            ("aB1_g", a.a_b1_g),
            ("aB2_g", a.a_b2_g),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(bad(field, value, "must be a finite amplitude >= 0 g"));
            }
        }
        if !self.du_v.is_finite() {
            return Err(bad("du_v", self.du_v, "must be finite"));
        }
        if let Some(s) = self.du_sigma_v {
            if !(s.is_finite() && s > 0.0) {
                return Err(bad(
                    "du_sigma_v",
                    s,
                    "must be a finite standard uncertainty > 0 V",
                ));
            }
        }
        Ok(())
    }
}

/// `cos(angle_deg)`, exact (0, +1, -1) at multiples of 90 deg so that TP3, TP7, TP9
/// and TP10 have no spurious `1e-17 g` of gravity on IA, and folded into the first
/// quadrant so that symmetric positions (45, 135, 225, 315 deg) get projections of
/// exactly equal magnitude.
pub fn cos_deg(angle_deg: f64) -> f64 {
    let reduced_deg = angle_deg.rem_euclid(360.0);
    // cos is even about 0 and 180 deg: fold into 0..=180, then into 0..=90.
    let half_deg = if reduced_deg > 180.0 {
        360.0 - reduced_deg
    } else {
        reduced_deg
    };
    let (quarter_deg, sign) = if half_deg > 90.0 {
        (180.0 - half_deg, -1.0)
    } else {
        (half_deg, 1.0)
    };
    if quarter_deg == 90.0 {
        0.0
    } else if quarter_deg == 0.0 {
        sign
    } else {
        sign * quarter_deg.to_radians().cos()
    }
}

/// The ten standard positions of MODEL.md section 9 at vibration amplitude
/// `a_b_g`: TP k = 1..8 at `(k-1)*45 deg` with vibration along IA; TP9 at 90 deg with
/// `aB` along IA and OA; TP10 at 90 deg with `aB` along IA and PA. `measure` gives
/// each position's `(du_v, du_sigma_v)` (it is called with `du_v = 0`).
pub fn standard_ten_positions<F>(a_b_g: f64, mut measure: F) -> Vec<TestPosition>
where
    F: FnMut(&TestPosition) -> (f64, Option<f64>),
{
    (1..=10u32)
        .map(|tp| {
            let (angle_deg, a_b1_g, a_b2_g) = match tp {
                9 => (90.0, a_b_g, 0.0),
                10 => (90.0, 0.0, a_b_g),
                k => (f64::from(k - 1) * 45.0, 0.0, 0.0),
            };
            let mut position = TestPosition {
                tp,
                angle_deg,
                amplitudes: Amplitudes {
                    a_b3_g: a_b_g,
                    a_b1_g,
                    a_b2_g,
                },
                du_v: 0.0,
                du_sigma_v: None,
            };
            let (du_v, du_sigma_v) = measure(&position);
            position.du_v = du_v;
            position.du_sigma_v = du_sigma_v;
            position
        })
        .collect()
}

/// Validates every position and returns the standard uncertainties, all or none.
pub(crate) fn validate_all(positions: &[TestPosition]) -> Result<Option<Vec<f64>>> {
    for (i, p) in positions.iter().enumerate() {
        p.validate(i)?;
    }
    let given = positions.iter().filter(|p| p.du_sigma_v.is_some()).count();
    if given == 0 {
        return Ok(None);
    }
    if given < positions.len() {
        let first_missing = positions
            .iter()
            .position(|p| p.du_sigma_v.is_none())
            .unwrap_or(0);
        return Err(Error::PartialUncertainties {
            given,
            n_positions: positions.len(),
            first_missing,
        });
    }
    Ok(Some(
        positions
            .iter()
            .map(|p| p.du_sigma_v.unwrap_or(f64::NAN))
            .collect(),
    ))
}

/// Validates the passport scale factor.
pub(crate) fn validate_k1(k1_v_per_g: f64) -> Result<()> {
    if k1_v_per_g.is_finite() && k1_v_per_g != 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidArgument {
            name: "k1_v_per_g",
            value: k1_v_per_g,
            rule: "the scale factor K1 must be finite and non-zero",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cos_deg_is_exact_at_right_angles_and_periodic() {
        assert_eq!(cos_deg(90.0), 0.0);
        assert_eq!(cos_deg(-90.0), 0.0);
        assert_eq!(cos_deg(450.0), 0.0);
        assert_eq!(cos_deg(180.0), -1.0);
        assert_eq!(cos_deg(-360.0), 1.0);
        assert!((cos_deg(45.0) - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-16);
        assert_eq!(cos_deg(135.0), -cos_deg(45.0));
        assert_eq!(cos_deg(225.0), -cos_deg(45.0));
        assert_eq!(cos_deg(315.0), cos_deg(45.0));
        assert_eq!(cos_deg(-45.0), cos_deg(45.0));
        assert!((cos_deg(30.0) - 0.75f64.sqrt()).abs() < 2.3e-16);
    }

    #[test]
    fn invalid_positions_name_the_field_and_value() {
        let mut p = standard_ten_positions(0.42, |_| (1e-5, None));
        p[3].amplitudes.a_b1_g = -0.1;
        let e = validate_all(&p).unwrap_err().to_string();
        assert!(e.contains("#3 (TP4)") && e.contains("aB1_g = -0.1"), "{e}");
        let mut p = standard_ten_positions(0.42, |_| (1e-5, Some(1e-6)));
        p[7].du_sigma_v = None;
        let e = validate_all(&p).unwrap_err();
        assert!(matches!(
            e,
            Error::PartialUncertainties {
                given: 9,
                first_missing: 7,
                ..
            }
        ));
    }
}
