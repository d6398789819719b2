//! The checks that validation and the grid expansion share: the problem list, and the
//! rules on tone frequencies, PSD shapes, kurtosis and the random-vibration numerics.

use super::types::Rates;
use super::{DEFAULT_FILTER_RESOLUTION_HZ, DEFAULT_KURTOSIS_SEGMENT_S};
use crate::random::MAX_FILTER_LEN;
use std::fmt::Display;
use vibro_physics::vibration::PsdBand;

/// Collects every problem of a file.
#[derive(Debug, Default)]
pub(super) struct Problems(pub(super) Vec<String>);

impl Problems {
    pub(super) fn push(&mut self, key: impl Display, value: impl Display, rule: impl Display) {
        self.0.push(format!("{key} = {value}: {rule}"));
    }

    pub(super) fn note(&mut self, text: String) {
        self.0.push(text);
    }
}

pub(super) fn check_tone_freq(key: &str, f: f64, rates: &Rates, p: &mut Problems) {
    let limit = 0.5 * rates.sensor_hz.min(rates.internal_hz);
    if !(f.is_finite() && f > 0.0 && f < limit) {
        p.push(
            key,
            f,
            format!("must be finite, > 0 and below the sensor's Nyquist frequency {limit} Hz"),
        );
    }
}

/// Checks the table's psd1/psd2 columns are empty (the psd3 column is the PSD along
/// the axis or direction) and returns the psd3 shape.
pub(super) fn psd3_shape(
    key: &str,
    arg: &str,
    bands: &[PsdBand],
    p: &mut Problems,
) -> Vec<(f64, f64, f64)> {
    if bands
        .iter()
        .any(|b| b.psd_g2_per_hz[0] != 0.0 || b.psd_g2_per_hz[1] != 0.0)
    {
        p.push(
            key,
            format!("{arg:?}"),
            "its psd1_g2_per_hz/psd2_g2_per_hz columns are not used here: the psd3_g2_per_hz \
             column is the PSD along the axis (or direction); give one table per axis instead",
        );
    }
    bands
        .iter()
        .map(|b| (b.f_lo_hz, b.f_hi_hz, b.psd_g2_per_hz[2]))
        .collect()
}

/// Merges per-axis shapes (each a list of `(f_lo, f_hi, S)`) into bands holding all
/// three axes, on the union of their edges.
pub(super) fn merge_axes(shapes: &[Vec<(f64, f64, f64)>; 3]) -> Vec<PsdBand> {
    let mut edges: Vec<f64> = shapes.iter().flatten().flat_map(|b| [b.0, b.1]).collect();
    edges.sort_by(f64::total_cmp);
    edges.dedup();
    let mut out = Vec::new();
    for w in edges.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        let mid = 0.5 * (lo + hi);
        let mut psd = [0.0; 3];
        for (axis, shape) in shapes.iter().enumerate() {
            psd[axis] = shape
                .iter()
                .filter(|b| b.0 <= mid && mid < b.1)
                .map(|b| b.2)
                .sum();
        }
        if psd.iter().any(|s| *s > 0.0) {
            out.push(PsdBand {
                f_lo_hz: lo,
                f_hi_hz: hi,
                psd_g2_per_hz: psd,
            });
        }
    }
    out
}

pub(super) fn check_kurtosis(key: &str, k: f64, p: &mut Problems) {
    if !(k.is_finite() && (3.0..=30.0).contains(&k)) {
        p.push(
            key,
            k,
            "must be within 3..=30 (Gaussian to the scale mixture's limit; the generator has \
             no sub-Gaussian family)",
        );
    }
}

/// The settings shared by flight and campaign random vibration.
pub(super) fn random_numerics(
    key: &str,
    segment: Option<f64>,
    resolution: Option<f64>,
    bands: &[PsdBand],
    rates: &Rates,
    p: &mut Problems,
) -> (f64, f64) {
    let segment_s = segment.unwrap_or(DEFAULT_KURTOSIS_SEGMENT_S);
    let lowest_hz = bands
        .iter()
        .map(|b| b.f_lo_hz)
        .filter(|f| *f > 0.0)
        .fold(f64::INFINITY, f64::min);
    let min_segment_s = if lowest_hz.is_finite() {
        1.0 / lowest_hz
    } else {
        0.0
    };
    if !(segment_s.is_finite() && segment_s > 0.0 && segment_s >= min_segment_s && segment_s <= 1e3)
    {
        p.push(
            format!("{key}.kurtosis_segment_s"),
            segment_s,
            format!(
                "must be finite, at most 1000 s and at least one period of the lowest band \
                 edge ({min_segment_s} s), so that a segment is long against the correlation time"
            ),
        );
    }
    let resolution_hz = resolution.unwrap_or(DEFAULT_FILTER_RESOLUTION_HZ);
    let finest_hz = rates.internal_hz / MAX_FILTER_LEN as f64;
    if !(resolution_hz.is_finite() && resolution_hz >= finest_hz && resolution_hz <= 100.0) {
        p.push(
            format!("{key}.filter_resolution_hz"),
            resolution_hz,
            format!("must be finite within {finest_hz}..=100 Hz"),
        );
    }
    let nyquist = 0.5 * rates.sensor_hz.min(rates.internal_hz);
    for b in bands {
        if b.f_hi_hz > nyquist {
            p.push(
                format!("{key} band {}..{} Hz", b.f_lo_hz, b.f_hi_hz),
                b.f_hi_hz,
                format!("must end below the sensor's Nyquist frequency {nyquist} Hz"),
            );
            break;
        }
    }
    (segment_s, resolution_hz)
}
