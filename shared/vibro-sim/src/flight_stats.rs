//! Each unit's mean error over a simulated flight, against the acceleration it sensed
//! and against the exact model (MODEL.md sections 4 and 6), with the standard error of
//! what the model does not explain from batch means.
//!
//! Per output sample of unit `u` (axes `[OA, PA, IA]`), with `U` its output and `a` the
//! mean acceleration it sensed over the output interval ([`crate::Truth`]):
//!
//! ```text
//! error     = U/K1 - a3                         (offset, main error, VE, effects)
//! model     = E[aF](aL) - aL3                   (exact model, no effect)
//! cross     = m1 (a1 - aL1) + m2 (a2 - aL2)     (the OA/PA vibration passed linearly)
//! residual  = error - model - cross
//! ```
//!
//! The cross-axis sensitivities `m1, m2` ([P1 (1)], MODEL.md section 2) pass the
//! OA/PA vibration through linearly: zero-mean, but not averaged away within an output
//! interval; taking it out of the residual leaves its noise to the rectified terms.
//! The residual's standard error is that of [`BATCHES`] batch means (the last batch
//! takes the remainder).

use serde::Serialize;

use crate::{Scenario, Truth};

/// Batches of the residual's batch-means standard error.
pub const BATCHES: usize = 10;

/// Per-unit statistics of a flight.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UnitReport {
    pub name: String,
    /// Mean of `U/K1 - a` over the flight, `a` the mean acceleration the unit sensed
    /// over each output interval: the simulated total error (offset, main error, VE
    /// and every effect), g.
    pub mean_error_g: f64,
    /// Mean of `E[aF] - aL3` from the exact model, no effect, g.
    pub exact_mean_error_g: f64,
    /// Mean exact VE, g.
    pub exact_ve_g: f64,
    /// `mean_error_g - exact_mean_error_g`: what the model does not explain (effects,
    /// plus the run's statistical error), g.
    pub unexplained_g: f64,
    /// Standard error of `unexplained_g` from 10 batch means, g.
    pub unexplained_sigma_g: f64,
}

/// Running sums of a flight's errors, one output sample at a time (no allocation per
/// sample).
#[derive(Debug, Clone)]
pub struct FlightStats {
    k1_v_per_g: [f64; 3],
    /// `[m1, m2]` of each unit, per g.
    m: [[f64; 2]; 3],
    batch_len: u64,
    sum_err: [f64; 3],
    sum_resid: [[f64; 3]; BATCHES],
    sum_exact: [f64; 3],
    sum_ve: [f64; 3],
    n: u64,
}

impl FlightStats {
    /// Sums for a flight of `total_output` output samples of units with scale factors
    /// `k1_v_per_g` and cross-axis sensitivities `m = [m1, m2]`.
    pub fn new(total_output: u64, k1_v_per_g: [f64; 3], m: [[f64; 2]; 3]) -> Self {
        Self {
            k1_v_per_g,
            m,
            batch_len: (total_output / BATCHES as u64).max(1),
            sum_err: [0.0; 3],
            sum_resid: [[0.0; 3]; BATCHES],
            sum_exact: [0.0; 3],
            sum_ve: [0.0; 3],
            n: 0,
        }
    }

    /// Sums for `scenario`'s flight (its triad's K1, m1, m2); a campaign has no triad
    /// and gets zeros.
    pub fn for_scenario(scenario: &Scenario, total_output: u64) -> Self {
        let (mut k1, mut m) = ([0.0; 3], [[0.0; 2]; 3]);
        if let Some(f) = scenario.flight() {
            for (u, p) in f.triad.passports.iter().enumerate() {
                k1[u] = p.k1_v_per_g;
                m[u] = [p.m1, p.m2];
            }
        }
        Self::new(total_output, k1, m)
    }

    /// Adds one output sample: the three units' outputs `accel_v`, V, and its truth.
    pub fn push(&mut self, accel_v: &[f64; 3], truth: &Truth) {
        let batch = ((self.n / self.batch_len) as usize).min(BATCHES - 1);
        for u in 0..3 {
            let [a_l1, a_l2, a_l3] = truth.a_l_unit_g[u];
            let [a1, a2, a3] = truth.a_mean_unit_g[u];
            // Against the acceleration the unit sensed: the vibration's own motion
            // along IA is measured, not an error.
            let error_g = accel_v[u] / self.k1_v_per_g[u] - a3;
            let model_error_g = truth.exact_mean_output_g[u] - a_l3;
            self.sum_err[u] += error_g;
            let cross_g = self.m[u][0] * (a1 - a_l1) + self.m[u][1] * (a2 - a_l2);
            self.sum_resid[batch][u] += error_g - model_error_g - cross_g;
            self.sum_exact[u] += model_error_g;
            self.sum_ve[u] += truth.exact_ve_g[u];
        }
        self.n += 1;
    }

    /// Output samples added so far.
    pub fn samples(&self) -> u64 {
        self.n
    }

    /// Each unit's means and the residual's batch-means standard error; `names` of
    /// the units (missing ones are empty).
    pub fn units(&self, names: &[String]) -> Vec<UnitReport> {
        let n = self.n;
        let nf = n.max(1) as f64;
        (0..3)
            .map(|u| {
                let mean = self.sum_err[u] / nf;
                let resid: f64 = self.sum_resid.iter().map(|b| b[u]).sum::<f64>() / nf;
                let means: Vec<f64> = (0..BATCHES)
                    .map(|b| {
                        let len = if b == BATCHES - 1 {
                            n.saturating_sub(self.batch_len * (BATCHES as u64 - 1))
                        } else {
                            self.batch_len
                        };
                        self.sum_resid[b][u] / len.max(1) as f64
                    })
                    .collect();
                let var =
                    means.iter().map(|m| (m - resid).powi(2)).sum::<f64>() / (BATCHES as f64 - 1.0);
                UnitReport {
                    name: names.get(u).cloned().unwrap_or_default(),
                    mean_error_g: mean,
                    exact_mean_error_g: self.sum_exact[u] / nf,
                    exact_ve_g: self.sum_ve[u] / nf,
                    unexplained_g: resid,
                    unexplained_sigma_g: (var / BATCHES as f64).sqrt(),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(a_l3: f64, a3: f64, exact: f64, ve: f64) -> Truth {
        Truth {
            a_l_unit_g: [[0.0, 0.0, a_l3]; 3],
            a_mean_unit_g: [[0.5, -0.25, a3]; 3],
            exact_mean_output_g: [exact; 3],
            exact_ve_g: [ve; 3],
        }
    }

    #[test]
    fn constant_errors_give_their_means_and_no_scatter() {
        // K1 = 2 V/g, output 2.2 V: U/K1 = 1.1 g against a sensed 1 g, error 0.1 g;
        // the model's error E[aF] - aL3 = 1.03 - 1 = 0.03 g; no cross-axis terms.
        let mut s = FlightStats::new(20, [2.0; 3], [[0.0; 2]; 3]);
        for _ in 0..20 {
            s.push(&[2.2; 3], &truth(1.0, 1.0, 1.03, 0.02));
        }
        let names = vec!["AK1".to_string(), "AK2".to_string()];
        let units = s.units(&names);
        assert_eq!(s.samples(), 20);
        assert_eq!(units[0].name, "AK1");
        assert_eq!(units[2].name, "");
        for u in &units {
            assert!((u.mean_error_g - 0.1).abs() < 1e-12);
            assert!((u.exact_mean_error_g - 0.03).abs() < 1e-12);
            assert!((u.exact_ve_g - 0.02).abs() < 1e-12);
            assert!((u.unexplained_g - 0.07).abs() < 1e-12);
            assert!(u.unexplained_sigma_g < 1e-12);
        }
    }

    #[test]
    fn the_cross_axis_vibration_is_taken_out_of_the_residual() {
        // m1 = 0.01, m2 = 0.02 per g; a1 - aL1 = 0.5 g, a2 - aL2 = -0.25 g:
        // cross = 0.005 - 0.005 = 0; with m2 = 0 it is 0.005 g.
        let mut s = FlightStats::new(10, [1.0; 3], [[0.01, 0.0]; 3]);
        for _ in 0..10 {
            s.push(&[1.0; 3], &truth(1.0, 1.0, 1.0, 0.0));
        }
        assert!((s.units(&[])[0].unexplained_g + 0.005).abs() < 1e-15);
    }

    #[test]
    fn the_standard_error_is_that_of_ten_batch_means() {
        // Residuals 0 in batches 0..5 and 1 in batches 5..10 (10 samples each): batch
        // means 0 and 1, overall 0.5; variance of the means 10 * 0.25 / 9, standard
        // error sqrt(variance / 10) = sqrt(0.25 / 9) = 1/6.
        let mut s = FlightStats::new(100, [1.0; 3], [[0.0; 2]; 3]);
        for k in 0..100 {
            let error = if k < 50 { 0.0 } else { 1.0 };
            s.push(&[1.0 + error; 3], &truth(1.0, 1.0, 1.0, 0.0));
        }
        let u = &s.units(&[])[1];
        assert!((u.unexplained_g - 0.5).abs() < 1e-12);
        assert!((u.unexplained_sigma_g - 1.0 / 6.0).abs() < 1e-12);
    }
}
