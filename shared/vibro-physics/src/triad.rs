//! Geometry of the accelerometer triad (RIG.md, [P2 Fig. 6]): which body axis is each
//! unit's input axis IA (its `a3`), output axis OA (`a1`) and pendulum axis PA (`a2`).

use crate::{Error, Result};

/// A body axis with a sign, e.g. `-y`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SignedAxis {
    /// 0 = x, 1 = y, 2 = z.
    pub body_index: usize,
    /// +1 or -1.
    pub sign: i8,
}

impl SignedAxis {
    /// Parses `+x`, `-y`, `z` (sign optional, `+` assumed).
    pub fn parse(text: &str) -> Option<Self> {
        let t = text.trim();
        let (sign, rest) = match t.as_bytes().first()? {
            b'+' => (1, &t[1..]),
            b'-' => (-1, &t[1..]),
            _ => (1, t),
        };
        let body_index = match rest {
            "x" | "X" => 0,
            "y" | "Y" => 1,
            "z" | "Z" => 2,
            _ => return None,
        };
        Some(Self { body_index, sign })
    }

    /// The component of a body-frame vector along this signed axis.
    #[inline]
    pub fn project(&self, body: &[f64; 3]) -> f64 {
        f64::from(self.sign) * body[self.body_index]
    }
}

impl std::fmt::Display for SignedAxis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = if self.sign < 0 { '-' } else { '+' };
        write!(f, "{s}{}", ['x', 'y', 'z'][self.body_index])
    }
}

/// One unit's axes in the body frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnitAxes {
    pub ia: SignedAxis,
    pub oa: SignedAxis,
    pub pa: SignedAxis,
}

impl UnitAxes {
    /// Validates that IA, OA and PA are three different body axes.
    pub fn new(ia: SignedAxis, oa: SignedAxis, pa: SignedAxis) -> Result<Self> {
        let (a, b, c) = (ia.body_index, oa.body_index, pa.body_index);
        if a == b || b == c || a == c {
            return Err(Error::InvalidTriad(format!(
                "ia = {ia}, oa = {oa}, pa = {pa}: IA, OA and PA must be three different body axes"
            )));
        }
        Ok(Self { ia, oa, pa })
    }

    /// A body-frame vector in the unit's axes, ordered as MODEL.md's indices
    /// `[a1 (OA), a2 (PA), a3 (IA)]`.
    #[inline]
    pub fn to_unit(&self, body: &[f64; 3]) -> [f64; 3] {
        [
            self.oa.project(body),
            self.pa.project(body),
            self.ia.project(body),
        ]
    }
}

/// The three units of a triad.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TriadAxes {
    pub units: [UnitAxes; 3],
}

impl TriadAxes {
    /// Validates that the three input axes cover x, y and z.
    pub fn new(units: [UnitAxes; 3]) -> Result<Self> {
        let mut seen = [false; 3];
        for u in &units {
            seen[u.ia.body_index] = true;
        }
        if seen != [true; 3] {
            let ias: Vec<String> = units.iter().map(|u| u.ia.to_string()).collect();
            return Err(Error::InvalidTriad(format!(
                "input axes {}: the three units' IAs must cover x, y and z",
                ias.join(", ")
            )));
        }
        Ok(Self { units })
    }

    /// The standard triad: unit i has its IA along body axis i, OA and PA along the next
    /// two (cyclic), all positive.
    pub fn standard() -> Self {
        let ax = |i: usize| SignedAxis {
            body_index: i % 3,
            sign: 1,
        };
        let unit = |i: usize| UnitAxes {
            ia: ax(i),
            oa: ax(i + 1),
            pa: ax(i + 2),
        };
        Self {
            units: [unit(0), unit(1), unit(2)],
        }
    }

    /// The body-frame acceleration seen by the triad, from the three units' input-axis
    /// accelerations `ia_g[i]` (each unit measures its IA).
    #[inline]
    pub fn body_from_ia(&self, ia_g: &[f64; 3]) -> [f64; 3] {
        let mut body = [0.0; 3];
        for (u, a) in self.units.iter().zip(ia_g) {
            body[u.ia.body_index] = f64::from(u.ia.sign) * a;
        }
        body
    }
}

/// A body direction stated as a unit vector within this: `|v| = 1 +- tolerance` (rig
/// files, campaign manifests, `identify measure --ia`).
pub const UNIT_VECTOR_TOLERANCE: f64 = 1e-3;

/// `v` normalised when it has three components and its norm is 1 within
/// [`UNIT_VECTOR_TOLERANCE`]; otherwise the rule broken, for the caller to prefix with
/// the key or flag and the value.
pub fn unit_vector(v: &[f64]) -> std::result::Result<[f64; 3], String> {
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if v.len() != 3 || (norm - 1.0).abs() > UNIT_VECTOR_TOLERANCE {
        return Err(format!(
            "must be a unit vector (its norm is {norm:.6}, allowed 1 +- {UNIT_VECTOR_TOLERANCE})"
        ));
    }
    Ok([v[0] / norm, v[1] / norm, v[2] / norm])
}

/// A body direction: a signed body axis (`x`, `+y`, `-z`) or three components `x,y,z`
/// of a unit vector ([`unit_vector`]; returned normalised). The error is the rule
/// broken.
pub fn parse_body_direction(text: &str) -> std::result::Result<[f64; 3], String> {
    if let Some(axis) = SignedAxis::parse(text) {
        let mut v = [0.0; 3];
        v[axis.body_index] = f64::from(axis.sign);
        return Ok(v);
    }
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let numbers: Vec<f64> = parts.iter().filter_map(|p| p.parse().ok()).collect();
    if parts.len() != 3 || numbers.len() != 3 || numbers.iter().any(|x| !x.is_finite()) {
        return Err(
            "must be a signed body axis (x, +y, -z) or a unit vector of three finite \
             numbers x,y,z"
                .into(),
        );
    }
    unit_vector(&numbers)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_projects_signed_axes() {
        let a = SignedAxis::parse("-y").unwrap();
        assert_eq!(a.project(&[1.0, 2.0, 3.0]), -2.0);
        assert_eq!(SignedAxis::parse("z").unwrap().to_string(), "+z");
        assert!(SignedAxis::parse("+w").is_none());
    }

    #[test]
    fn round_trips_body_and_unit_frames() {
        let t = TriadAxes::standard();
        let body = [1.0, -2.0, 5.0];
        let ia = [body[0], body[1], body[2]];
        assert_eq!(t.body_from_ia(&ia), body);
        // Unit 0 (IA = x): OA = y, PA = z.
        assert_eq!(t.units[0].to_unit(&body), [-2.0, 5.0, 1.0]);
    }

    #[test]
    fn rejects_repeated_axes() {
        let x = SignedAxis::parse("x").unwrap();
        let y = SignedAxis::parse("-x").unwrap();
        assert!(UnitAxes::new(x, y, SignedAxis::parse("z").unwrap()).is_err());
    }
}
