//! The known response of the measuring chain, divided out of every estimate: the AC
//! coupling (first-order high-pass) times the optional correction table.

use crate::config::ResponsePoint;
use realfft::num_complex::Complex64;

/// Below this gain a bin is treated as carrying no information (e.g. DC behind an AC
/// coupling) and is left out rather than divided by a near-zero number.
pub(crate) const MIN_GAIN: f64 = 1e-9;

#[derive(Debug, Clone)]
pub(crate) struct Response {
    ac_corner_hz: Option<f64>,
    table: Vec<ResponsePoint>,
}

impl Response {
    pub(crate) fn new(ac_corner_hz: Option<f64>, table: &[ResponsePoint]) -> Self {
        Self {
            ac_corner_hz,
            table: table.to_vec(),
        }
    }

    /// `H(f)` of `axis` (measured = H * true).
    pub(crate) fn gain(&self, axis: usize, f_hz: f64) -> Complex64 {
        let mut h = Complex64::new(1.0, 0.0);
        if let Some(fc) = self.ac_corner_hz {
            // First-order high-pass (an RC AC coupling): H = j(f/fc) / (1 + j(f/fc)).
            let u = Complex64::new(0.0, f_hz / fc);
            h = u / (1.0 + u);
        }
        if !self.table.is_empty() {
            let (g, ph) = self.interpolate(axis, f_hz);
            h *= Complex64::from_polar(g, ph);
        }
        h
    }

    /// `1/H(f)`, or 0 where the chain passes nothing (`|H| < MIN_GAIN`).
    pub(crate) fn inverse_gain(&self, axis: usize, f_hz: f64) -> Complex64 {
        let h = self.gain(axis, f_hz);
        if h.norm() < MIN_GAIN {
            Complex64::new(0.0, 0.0)
        } else {
            1.0 / h
        }
    }

    /// Gain and phase linearly interpolated in frequency, held at the end points.
    fn interpolate(&self, axis: usize, f_hz: f64) -> (f64, f64) {
        let t = &self.table;
        let i = t.partition_point(|p| p.frequency_hz <= f_hz);
        match (i.checked_sub(1).and_then(|j| t.get(j)), t.get(i)) {
            (Some(a), Some(b)) => {
                let w = (f_hz - a.frequency_hz) / (b.frequency_hz - a.frequency_hz);
                (
                    a.gain[axis] + w * (b.gain[axis] - a.gain[axis]),
                    a.phase_rad[axis] + w * (b.phase_rad[axis] - a.phase_rad[axis]),
                )
            }
            (Some(p), None) | (None, Some(p)) => (p.gain[axis], p.phase_rad[axis]),
            (None, None) => (1.0, 0.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_4;

    #[test]
    fn first_order_high_pass_is_3_db_down_and_45_degrees_ahead_at_its_corner() {
        let r = Response::new(Some(10.0), &[]);
        let h = r.gain(0, 10.0);
        assert!((h.norm() - 0.5f64.sqrt()).abs() < 1e-15);
        assert!((h.arg() - FRAC_PI_4).abs() < 1e-15);
        assert!(r.inverse_gain(0, 0.0) == Complex64::new(0.0, 0.0));
    }

    #[test]
    fn table_is_interpolated_linearly_and_held_outside() {
        let p = |f: f64, g: f64, ph: f64| ResponsePoint {
            frequency_hz: f,
            gain: [g, 1.0, 1.0],
            phase_rad: [ph, 0.0, 0.0],
        };
        let r = Response::new(None, &[p(100.0, 1.0, 0.0), p(200.0, 2.0, -0.2)]);
        let h = r.gain(0, 150.0);
        assert!((h.norm() - 1.5).abs() < 1e-12 && (h.arg() + 0.1).abs() < 1e-12);
        assert!((r.gain(0, 10.0).norm() - 1.0).abs() < 1e-12);
        assert!((r.gain(0, 1e4).norm() - 2.0).abs() < 1e-12);
        assert!((r.gain(1, 150.0).norm() - 1.0).abs() < 1e-12);
    }
}
