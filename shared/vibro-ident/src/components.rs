//! Identified VE components with their uncertainties, and the VE prediction (23).

use crate::positions::Amplitudes;
use serde::Serialize;

/// Names of the six components, in the order of [`Components::to_array`] and of the
/// rows and columns of [`ComponentsEstimate::covariance`].
pub const COMPONENT_NAMES: [&str; 6] = [
    "d01_g",
    "d02_g",
    "d03_g",
    "delta1",
    "delta2_per_g",
    "delta3_per_g2",
];

/// The VE components of MODEL.md section 5 [P1 (13)]:
/// `dV = d0(1) + d0(2) + d0(3) + delta(1)*aL + delta(2)*aL^2 + delta(3)*aL^3`.
/// Also used for their standard uncertainties (same units).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Components {
    /// `d0(1)`: additive VE from vibration along IA, g.
    pub d01_g: f64,
    /// `d0(2)`: additive VE from IA x OA vibration, g.
    pub d02_g: f64,
    /// `d0(3)`: additive VE from IA x PA vibration, g.
    pub d03_g: f64,
    /// `delta(1)`, dimensionless (g per g of flight acceleration).
    pub delta1: f64,
    /// `delta(2)`, 1/g.
    pub delta2_per_g: f64,
    /// `delta(3)`, 1/g^2.
    pub delta3_per_g2: f64,
}

impl Components {
    /// The components in the order of [`COMPONENT_NAMES`].
    pub fn to_array(&self) -> [f64; 6] {
        [
            self.d01_g,
            self.d02_g,
            self.d03_g,
            self.delta1,
            self.delta2_per_g,
            self.delta3_per_g2,
        ]
    }

    /// The inverse of [`Components::to_array`].
    pub fn from_array(x: [f64; 6]) -> Self {
        Self {
            d01_g: x[0],
            d02_g: x[1],
            d03_g: x[2],
            delta1: x[3],
            delta2_per_g: x[4],
            delta3_per_g2: x[5],
        }
    }

    /// The VE at flight acceleration `a_l_g` along IA, g [P1 (23)].
    pub fn ve_g(&self, a_l_g: f64) -> f64 {
        dot(&self.to_array(), &prediction_gradient(a_l_g))
    }
}

/// `d dV / d components` of (23) at `a_l_g`.
fn prediction_gradient(a_l_g: f64) -> [f64; 6] {
    [1.0, 1.0, 1.0, a_l_g, a_l_g * a_l_g, a_l_g * a_l_g * a_l_g]
}

fn dot(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Which method produced an estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// The closed form (22) over the ten standard positions.
    ClosedForm,
    /// Weighted least squares with the six components as unknowns.
    Wls,
    /// Components evaluated from the passport terms of a coefficient-level WLS.
    CoefficientWls,
}

/// Where the standard uncertainties come from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum UncertaintyBasis {
    /// From the standard uncertainties of `dU` given with the positions (weights
    /// `1/sigma_k^2`). `chi2` is the weighted sum of squared residuals with `dof`
    /// degrees of freedom; `chi2/dof` far from 1 says the given uncertainties or the
    /// model are off (the covariance is NOT rescaled by it).
    Given { chi2: f64, dof: usize },
    /// No uncertainties were given: unit weights, and the residual scatter with `dof`
    /// degrees of freedom estimates one common `dU` uncertainty `du_sigma_v`. With few
    /// degrees of freedom this estimate is itself uncertain (relative standard
    /// deviation about `1/sqrt(2*dof)`).
    ResidualScatter { dof: usize, du_sigma_v: f64 },
    /// No uncertainties were given and there are no redundant positions: the
    /// uncertainty is unknown (not zero). `sigma` and `covariance` are `None`.
    Unknown { reason: String },
}

/// Identified components with their standard uncertainties and covariance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ComponentsEstimate {
    pub method: Method,
    /// The vibration amplitudes at which the components hold: along IA for every
    /// component, along OA for `d0(2)`, along PA for `d0(3)` (0 when no position had
    /// vibration on that axis).
    pub amplitudes: Amplitudes,
    pub components: Components,
    /// Standard uncertainties, same units; `None` when unknown (see `basis`).
    pub sigma: Option<Components>,
    /// Covariance in the order of [`COMPONENT_NAMES`] (units: products of theirs);
    /// `None` when unknown.
    pub covariance: Option<[[f64; 6]; 6]>,
    pub basis: UncertaintyBasis,
    /// Number of positions used.
    pub n_positions: usize,
    /// `dU_k - K1*(model)` for each position, in the order given, V.
    pub residuals_v: Vec<f64>,
    /// Condition number of the column-scaled weighted design (least squares only).
    pub condition_number: Option<f64>,
}

/// The VE predicted at one flight acceleration by (23), with its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct VePrediction {
    /// Flight acceleration along IA, g.
    pub a_l_g: f64,
    /// `dV = d0(1) + d0(2) + d0(3) + delta(1)*aL + delta(2)*aL^2 + delta(3)*aL^3`, g.
    pub ve_g: f64,
    /// Standard uncertainty of `ve_g` from the full covariance, g; `None` when the
    /// covariance is unknown.
    pub sigma_g: Option<f64>,
}

impl ComponentsEstimate {
    /// The VE at flight acceleration `a_l_g` [P1 (23)], with `sigma^2 = h^T C h`,
    /// `h = (1, 1, 1, aL, aL^2, aL^3)`: correlations between components matter (the
    /// three `d0` of the standard positions share TP3 and TP7).
    pub fn predict(&self, a_l_g: f64) -> VePrediction {
        let h = prediction_gradient(a_l_g);
        let sigma_g = self.covariance.map(|c| {
            let variance_g2: f64 = (0..6)
                .flat_map(|i| (0..6).map(move |j| (i, j)))
                .map(|(i, j)| h[i] * c[i][j] * h[j])
                .sum();
            // Rounding can leave a tiny negative for a perfectly determined VE.
            variance_g2.max(0.0).sqrt()
        });
        VePrediction {
            a_l_g,
            ve_g: self.components.ve_g(a_l_g),
            sigma_g,
        }
    }
}

/// Standard uncertainties from the diagonal of a covariance.
pub(crate) fn sigma_from_covariance(c: &[[f64; 6]; 6]) -> Components {
    Components::from_array(std::array::from_fn(|i| c[i][i].max(0.0).sqrt()))
}
