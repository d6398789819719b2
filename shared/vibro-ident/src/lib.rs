//! # vibro-ident
//!
//! Shake-table work on a navigation accelerometer: measuring its vibration error (VE)
//! from still / vibrating / still records (MODEL.md section 8, [P2 (16)]) and
//! identifying the VE components from test positions (section 9, [P1 (18)-(23)]).
//! No I/O: callers hand in numbers and get numbers back, each with its standard
//! uncertainty.
//!
//! - [`measure`]: `dV = (<U2> - 0.5*(<U1> + <U3>))/K1` [P2 (16)] with a batch-means
//!   standard uncertainty and the tilt check.
//! - [`TestPosition`]: one test position (angle, vibration amplitudes, `dU_k`).
//! - [`closed_form`]: the paper's closed form (22) for the ten standard positions.
//! - [`wls_components`]: weighted least squares for any set of positions at one
//!   vibration amplitude; unknowns are the six components of (21).
//! - [`wls_coefficients`]: weighted least squares for positions at any amplitudes;
//!   unknowns are the passport terms of section 5, from which
//!   [`CoefficientEstimate::components_at`] gives the components at any amplitude.
//! - [`ComponentsEstimate::predict`]: the VE at a flight acceleration (23).
//! - [`rig`]: the VE of one unit from a rig's own time-stamped records, with its linear
//!   response to the table's motion removed through a reference accelerometer
//!   ([`reference`]), so that the stated uncertainty is the VE's own.
//!
//! ```
//! use vibro_ident::{closed_form, standard_ten_positions, wls_components, Components};
//! // Components of the AL-15 at aB = 0.42 g (MODEL.md section 5), K1 = -1.6698 V/g.
//! let truth = Components {
//!     d01_g: 13.39e-6, d02_g: 1.023e-6, d03_g: 1.023e-6,
//!     delta1: 23.07e-6, delta2_per_g: 5.292e-6, delta3_per_g2: 0.7938e-6,
//! };
//! let k1_v_per_g = -1.6698;
//! // dU_k of (21) for TP1..TP10, each with a standard uncertainty of 2 uV.
//! let positions = standard_ten_positions(0.42, |p| {
//!     let g3 = p.g3_g();
//!     let mut dv_g = truth.d01_g + truth.delta1 * g3 + truth.delta2_per_g * g3 * g3
//!         + truth.delta3_per_g2 * g3 * g3 * g3;
//!     if p.amplitudes.a_b1_g > 0.0 { dv_g += truth.d02_g } // TP9
//!     if p.amplitudes.a_b2_g > 0.0 { dv_g += truth.d03_g } // TP10
//!     (k1_v_per_g * dv_g, Some(2e-6))
//! });
//! let cf = closed_form(&positions, k1_v_per_g)?;
//! let ls = wls_components(&positions, k1_v_per_g, &Default::default())?;
//! assert!((cf.components.d01_g - truth.d01_g).abs() < 1e-17);
//! assert!((ls.components.delta2_per_g - truth.delta2_per_g).abs() < 1e-17);
//! // Least squares uses all eight positions for d0(1); (22) only TP3 and TP7.
//! let (s_cf, s_ls) = (cf.sigma.unwrap().d01_g, ls.sigma.unwrap().d01_g);
//! assert!(s_ls < s_cf);
//! // The VE at aL = 10 g (23): 1.569 mg, [P1 Table 4]'s 1.571 mg with aB1 = aB2 = 0.42 g
//! // instead of 0.8 g.
//! let ve = ls.predict(10.0);
//! assert!((ve.ve_g - 1.5691e-3).abs() < 1e-7);
//! // Extrapolating the cubic to 10 g from gravity projections within +-1 g magnifies
//! // the noise (delta(3) is multiplied by 1000 g^3): 2 uV on each dU_k gives a standard
//! // uncertainty of 2.4 mg here, more than the VE itself.
//! let sigma_g = ve.sigma_g.unwrap();
//! assert!((sigma_g - 2.38e-3).abs() < 0.01e-3);
//! # Ok::<(), vibro_ident::Error>(())
//! ```
//!
//! References: MODEL.md sections 5, 8, 9; \[P1\] (model and identification, equations
//! (13)-(16), (18)-(23)); \[P2\] (shake-table measurement, equation (16)). Where the
//! code departs from the papers it says so (for instance, MODEL.md calls (22)
//! "equivalent to least squares"; it is unbiased but is not the least-squares
//! solution for `d0` and `delta(2)`, see [`closed_form`]).

pub mod chain;
mod closed_form;
mod components;
mod linalg;
pub mod measure;
mod positions;
pub mod reference;
pub mod report;
pub mod rig;
pub mod table;
mod wls;

#[cfg(test)]
mod tests;

pub use closed_form::{closed_form, CLOSED_FORM_COEFFICIENTS};
pub use components::{
    Components, ComponentsEstimate, Method, UncertaintyBasis, VePrediction, COMPONENT_NAMES,
};
pub use measure::{
    measure_ve, measure_ve_from_samples, measure_ve_timed, MeasureOptions, Phase, RecordMean,
    Segments, TimedMeasurement, VeMeasurement,
};
pub use positions::{cos_deg, standard_ten_positions, Amplitudes, TestPosition};
pub use report::{
    identify_positions, measure_file, passport_terms, CoefficientReport, MeasureReport,
    MethodChoice, MethodReport, PositionsReport, PositionsRequest, Skipped,
};
pub use table::{read_positions, read_records, read_timed, Timed, POSITION_COLUMNS};
pub use wls::{
    wls_coefficients, wls_components, CoefficientEstimate, PassportTerms, WlsOptions, TERM_NAMES,
};

/// Errors of measurement and identification. Messages carry the offending values and
/// the rule that was broken.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// A scalar argument is out of its domain.
    #[error("{name} = {value}: {rule}")]
    InvalidArgument {
        name: &'static str,
        value: f64,
        rule: &'static str,
    },
    /// A field of one test position is out of its domain.
    #[error("test position #{index} (TP{tp}): {field} = {value}: {rule}")]
    InvalidPosition {
        /// Index in the slice given, from 0.
        index: usize,
        tp: u32,
        field: &'static str,
        value: f64,
        rule: &'static str,
    },
    /// A sample of a record is not a finite number.
    #[error("{phase} record: sample #{index} = {value} is not finite")]
    NonFiniteSample {
        phase: Phase,
        index: usize,
        value: f64,
    },
    /// A record is too short for its batch means.
    #[error(
        "{phase} record: {n_samples} samples cannot form {n_batches} batches \
         (need at least n_batches >= 2 samples, one per batch)"
    )]
    TooFewSamples {
        phase: Phase,
        n_samples: usize,
        n_batches: usize,
    },
    /// The tilt check of MODEL.md section 8 failed.
    #[error(
        "input axis moved during the run: |<U1> - <U3>|/|K1| = {drift_g:.3e} g exceeds \
         {limit_g:e} g ({limit_rad:e} rad tilt); the measurement is rejected (MODEL.md section 8)"
    )]
    InputAxisMoved {
        drift_g: f64,
        limit_g: f64,
        limit_rad: f64,
    },
    /// The positions are not the ten standard positions the closed form (22) needs.
    #[error("the closed form (22) needs the ten standard test positions of MODEL.md section 9: {reason}")]
    NotStandardPositions { reason: String },
    /// The component-level WLS was given rows at different amplitudes.
    #[error(
        "{axis} amplitudes differ between positions ({first_g} g at #{first_index}, \
         {other_g} g at #{other_index}): the components scale with the amplitude, so they \
         are not common unknowns; use the coefficient-level WLS (wls_coefficients)"
    )]
    MixedAmplitudes {
        axis: &'static str,
        first_g: f64,
        first_index: usize,
        other_g: f64,
        other_index: usize,
    },
    /// Some positions carry a standard uncertainty and others do not.
    #[error(
        "standard uncertainties of dU given for {given} of {n_positions} positions \
         (first missing: #{first_missing}): give them for all positions or for none"
    )]
    PartialUncertainties {
        given: usize,
        n_positions: usize,
        first_missing: usize,
    },
    /// Fewer rows than unknowns.
    #[error("{n_positions} test positions cannot determine {n_unknowns} unknowns ({unknowns})")]
    TooFewPositions {
        n_positions: usize,
        n_unknowns: usize,
        unknowns: String,
    },
    /// The design is rank-deficient: some unknowns are not identifiable.
    #[error(
        "cannot identify {} from these positions: the column-scaled design has condition \
         number {condition:.3e} (limit {limit:.1e}); {hint}",
        unknowns.join(", ")
    )]
    Unidentifiable {
        unknowns: Vec<&'static str>,
        condition: f64,
        limit: f64,
        hint: String,
    },
    /// The singular value decomposition of a design failed (it cannot on finite
    /// input; kept so that no input path panics).
    #[error("the SVD of the {rows} x {cols} least-squares design did not converge")]
    SvdFailed { rows: usize, cols: usize },
    /// A CSV file that cannot be read.
    #[error("{file}: cannot read")]
    ReadFile {
        file: String,
        source: Cause<std::io::Error>,
    },
    /// A CSV file that is not CSV (`what`: its header or a record).
    #[error("{file}: {what}")]
    Csv {
        file: String,
        what: &'static str,
        source: Cause<csv::Error>,
    },
    /// A CSV file with no header row.
    #[error("{file}: empty file: a header row is required")]
    EmptyTable { file: String },
    /// Every problem of a CSV file, each naming its line, column, value and rule.
    #[error("{file}: {}", problems_text(problems))]
    Table { file: String, problems: Vec<String> },
    /// An identification method that failed on a file; `located` says where the
    /// library pointed (a position's line) and what to do about it. One message: the
    /// cause is part of it, not a cause of its own.
    #[error("{file}: {method}: {cause}{located}")]
    Method {
        file: String,
        method: &'static str,
        cause: Box<Error>,
        located: String,
    },
    /// No requested method applies to the positions: each one's reason.
    #[error("no method applies:\n  {}", reasons.join("\n  "))]
    NoMethod { reasons: Vec<String> },
    /// A run's segments break a rule (`key = value: rule`).
    #[error("segments: {problem}")]
    Segments { problem: String },
    /// The section-8 measurement of a file of records failed.
    #[error("{file}: VE measurement (MODEL.md section 8)")]
    Measurement { file: String, source: Box<Error> },
    /// A rig's records that do not fit their segments or each other (a reference that
    /// does not cover the readings, a still reading the stated axes do not explain).
    #[error("{file}: {problem}")]
    Coverage { file: String, problem: String },
    /// Every broken rule of a request (`key = value: rule`), before any file is read.
    #[error("{}", problems_text(problems))]
    Request { problems: Vec<String> },
}

impl Error {
    /// The file the error is about, when it is about one.
    pub fn file(&self) -> Option<&str> {
        match self {
            Error::ReadFile { file, .. }
            | Error::Csv { file, .. }
            | Error::EmptyTable { file }
            | Error::Table { file, .. }
            | Error::Method { file, .. }
            | Error::Measurement { file, .. }
            | Error::Coverage { file, .. } => Some(file),
            _ => None,
        }
    }
}

/// The cause of a file error (an I/O or CSV error), shared so that [`Error`] stays
/// `Clone` and `PartialEq` (two causes are equal when they say the same). It says
/// what its error says, and has its error's cause.
#[derive(Debug)]
pub struct Cause<E>(pub std::sync::Arc<E>);

impl<E> Clone for Cause<E> {
    fn clone(&self) -> Self {
        Cause(self.0.clone())
    }
}

impl<E> From<E> for Cause<E> {
    fn from(e: E) -> Self {
        Cause(std::sync::Arc::new(e))
    }
}

impl<E: std::fmt::Display> std::fmt::Display for Cause<E> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl<E: std::error::Error> std::error::Error for Cause<E> {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.0.source()
    }
}

impl<E: std::fmt::Display> PartialEq for Cause<E> {
    fn eq(&self, other: &Self) -> bool {
        self.0.to_string() == other.0.to_string()
    }
}

/// A file's problems: the one, or their count and each on its own line.
fn problems_text(problems: &[String]) -> String {
    match problems {
        [one] => one.clone(),
        _ => format!("{} problems:\n  {}", problems.len(), problems.join("\n  ")),
    }
}

/// Result of measurement and identification.
pub type Result<T> = std::result::Result<T, Error>;
