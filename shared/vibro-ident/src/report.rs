//! What `vibrocomp identify` reports: the VE components identified from a file of test
//! positions by the closed form [P1 (22)], the WLS of the components, or the WLS of
//! the passport terms (MODEL.md section 9), with the VE predicted by [P1 (23)]; and
//! the VE measured from still / vibrating / still records ([P2 (16)], section 8).

use std::path::Path;

use serde::Serialize;
use vibro_physics::passport::Passport;

use crate::table::{read_positions, read_records};
use crate::{
    Amplitudes, CoefficientEstimate, ComponentsEstimate, Error, MeasureOptions, PassportTerms,
    Result, VeMeasurement, VePrediction, WlsOptions,
};

/// The identification method(s) of a positions file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MethodChoice {
    /// The paper's closed form (22): the ten standard positions only.
    ClosedForm,
    /// Weighted least squares of the six components: any positions at one amplitude.
    Wls,
    /// Closed form and WLS side by side; a method that does not apply is skipped with
    /// its reason.
    Both,
    /// WLS of the passport terms: positions at two or more IA amplitudes, components
    /// evaluated at [`PositionsRequest::at_ab3_g`].
    Coefficients,
}

/// What to identify from a positions file.
#[derive(Debug, Clone, PartialEq)]
pub struct PositionsRequest {
    pub method: MethodChoice,
    /// Flight accelerations along IA at which to predict the VE by (23), g.
    pub at_g: Vec<f64>,
    /// Coefficients: IA amplitude of the components, g (default: the largest IA
    /// amplitude among the positions).
    pub at_ab3_g: Option<f64>,
    /// Coefficients: OA amplitude for d0(2), g (default: as IA, as in TP9).
    pub at_ab1_g: Option<f64>,
    /// Coefficients: PA amplitude for d0(3), g (default: as IA, as in TP10).
    pub at_ab2_g: Option<f64>,
}

/// One method's components and VE predictions.
#[derive(Debug, Clone, Serialize)]
pub struct MethodReport {
    pub estimate: ComponentsEstimate,
    pub predictions: Vec<VePrediction>,
}

impl MethodReport {
    /// The estimate with its VE predicted by (23) at each flight acceleration `at_g`.
    pub fn new(estimate: ComponentsEstimate, at_g: &[f64]) -> Self {
        let predictions = at_g.iter().map(|a| estimate.predict(*a)).collect();
        Self {
            estimate,
            predictions,
        }
    }
}

/// The coefficient-level WLS: the passport terms and the components from them.
#[derive(Debug, Clone, Serialize)]
pub struct CoefficientReport {
    pub terms: CoefficientEstimate,
    /// The components at the chosen amplitudes, and the VE predictions from them.
    pub components: MethodReport,
}

/// A method of [`MethodChoice::Both`] that does not apply, and why.
#[derive(Debug, Clone, Serialize)]
pub struct Skipped {
    pub method: &'static str,
    pub reason: String,
}

/// The identification of a positions file.
#[derive(Debug, Clone, Serialize)]
pub struct PositionsReport {
    pub file: String,
    pub passport: String,
    pub k1_v_per_g: f64,
    pub n_positions: usize,
    /// The passport's terms of section 5, `lambda = 1` (the test frequency is not in
    /// the CSV), for comparison.
    pub passport_terms: PassportTerms,
    pub closed_form: Option<MethodReport>,
    pub wls: Option<MethodReport>,
    pub coefficients: Option<CoefficientReport>,
    pub skipped: Vec<Skipped>,
}

/// A passport's section-5 terms with `lambda = 1`: `c_asym = 0.637 k1 d1A` [P1 (15)],
/// and `k2..k5`, `m31`, `m32` as they are.
pub fn passport_terms(p: &Passport) -> PassportTerms {
    PassportTerms {
        c_asym: 0.637 * p.k1 * p.d1a,
        k2_per_g: p.k[2],
        k3_per_g2: p.k[3],
        k4_per_g3: p.k[4],
        k5_per_g4: p.k[5],
        m31_per_g: p.m31_per_g,
        m32_per_g: p.m32_per_g,
    }
}

/// Where a library error points at a position by index, says which CSV line it is,
/// and translates the library's advice into command-line terms.
fn locate(e: &Error, lines: &[usize]) -> String {
    let index = match e {
        Error::InvalidPosition { index, .. } => Some(*index),
        Error::MixedAmplitudes { other_index, .. } => Some(*other_index),
        Error::PartialUncertainties { first_missing, .. } => Some(*first_missing),
        _ => None,
    };
    let mut text = match index.and_then(|i| lines.get(i).map(|l| (i, l))) {
        Some((i, line)) => format!(" (position #{i} is on line {line})"),
        None => String::new(),
    };
    if matches!(e, Error::MixedAmplitudes { .. }) {
        text += "; for positions at several amplitudes use --method coefficients";
    }
    text
}

/// Identifies the VE components from the test positions of `file` (read with
/// [`read_positions`]) for a unit with `passport` (its K1), by the methods of
/// `request`. A method's failure names the file, the method and, where the library
/// points at a position, its line.
pub fn identify_positions(
    file: &Path,
    passport: &Passport,
    request: &PositionsRequest,
) -> Result<PositionsReport> {
    let k1 = passport.k1_v_per_g;
    let name = file.display().to_string();
    let (positions, lines) = read_positions(file)?;
    let failed = |method: &'static str, e: Error| Error::Method {
        file: name.clone(),
        method,
        located: locate(&e, &lines),
        cause: Box::new(e),
    };
    let options = WlsOptions::default();
    let mut report = PositionsReport {
        file: name.clone(),
        passport: passport.id().to_string(),
        k1_v_per_g: k1,
        n_positions: positions.len(),
        passport_terms: passport_terms(passport),
        closed_form: None,
        wls: None,
        coefficients: None,
        skipped: Vec::new(),
    };
    let method = request.method;
    let want_cf = matches!(method, MethodChoice::ClosedForm | MethodChoice::Both);
    let want_wls = matches!(method, MethodChoice::Wls | MethodChoice::Both);
    let optional = method == MethodChoice::Both;
    if want_cf {
        match crate::closed_form(&positions, k1) {
            Ok(e) => report.closed_form = Some(MethodReport::new(e, &request.at_g)),
            Err(e) if optional => report.skipped.push(Skipped {
                method: "closed_form",
                reason: failed("closed form", e).to_string(),
            }),
            Err(e) => return Err(failed("closed form", e)),
        }
    }
    if want_wls {
        match crate::wls_components(&positions, k1, &options) {
            Ok(e) => report.wls = Some(MethodReport::new(e, &request.at_g)),
            Err(e) if optional => report.skipped.push(Skipped {
                method: "wls",
                reason: failed("WLS", e).to_string(),
            }),
            Err(e) => return Err(failed("WLS", e)),
        }
    }
    if method == MethodChoice::Coefficients {
        let terms = crate::wls_coefficients(&positions, k1, &options)
            .map_err(|e| failed("coefficient-level WLS", e))?;
        let a_b3_g = request
            .at_ab3_g
            .or_else(|| terms.a_b3_levels_g.last().copied())
            .unwrap_or(0.0);
        let amplitudes = Amplitudes {
            a_b3_g,
            a_b1_g: request.at_ab1_g.unwrap_or(a_b3_g),
            a_b2_g: request.at_ab2_g.unwrap_or(a_b3_g),
        };
        let components = MethodReport::new(terms.components_at(amplitudes), &request.at_g);
        report.coefficients = Some(CoefficientReport { terms, components });
    }
    if report.closed_form.is_none() && report.wls.is_none() && report.coefficients.is_none() {
        let reasons = report.skipped.iter().map(|s| s.reason.clone()).collect();
        return Err(Error::NoMethod { reasons });
    }
    Ok(report)
}

/// The VE measured from a file of records.
#[derive(Debug, Clone, Serialize)]
pub struct MeasureReport {
    pub file: String,
    pub passport: String,
    #[serde(flatten)]
    pub measurement: VeMeasurement,
}

/// Measures the VE from the still / vibrating / still records of `file` (read with
/// [`read_records`]) as MODEL.md section 8 does, [P2 (16)].
pub fn measure_file(
    file: &Path,
    passport: &Passport,
    options: &MeasureOptions,
) -> Result<MeasureReport> {
    let name = file.display().to_string();
    let [u1, u2, u3] = read_records(file)?;
    let measurement = crate::measure_ve_from_samples(&u1, &u2, &u3, passport.k1_v_per_g, options)
        .map_err(|e| Error::Measurement {
        file: name.clone(),
        source: Box::new(e),
    })?;
    Ok(MeasureReport {
        file: name,
        passport: passport.id().to_string(),
        measurement,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passport_terms_take_c_asym_from_k1_and_d1a() {
        let mut p = vibro_config::resolve_passport("AL-15").unwrap();
        p.k1 = 1.5;
        p.d1a = 2e-5;
        let t = passport_terms(&p);
        // c_asym = 0.637 * 1.5 * 2e-5 = 1.911e-5.
        assert!((t.c_asym - 1.911e-5).abs() < 1e-18);
        assert_eq!(t.k2_per_g, p.k[2]);
        assert_eq!(t.k5_per_g4, p.k[5]);
        assert_eq!(t.m32_per_g, p.m32_per_g);
    }

    #[test]
    fn a_failure_names_the_line_of_its_position() {
        let e = Error::PartialUncertainties {
            given: 1,
            n_positions: 3,
            first_missing: 2,
        };
        assert_eq!(locate(&e, &[4, 5, 9]), " (position #2 is on line 9)");
        assert_eq!(locate(&e, &[4]), "");
        let e = Error::MixedAmplitudes {
            axis: "IA",
            first_g: 1.0,
            first_index: 0,
            other_g: 2.0,
            other_index: 1,
        };
        assert_eq!(
            locate(&e, &[3, 7]),
            " (position #1 is on line 7); for positions at several amplitudes use --method coefficients"
        );
    }
}
