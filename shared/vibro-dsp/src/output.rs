//! What one window's estimate holds: plain, fixed-size structs (no heap), per-axis
//! arrays `[f64; 3]` in the order of the sensor axes, serialisable with serde.
//!
//! A value that could not be estimated is `NaN` (serialised as JSON `null`) and the
//! estimate's [`Flags`] say why.

use crate::{MAX_BANDS, MAX_TONES};
use serde::ser::{Serialize, SerializeSeq, Serializer};
use std::ops::Deref;

/// A list of at most `C` items stored inline, so that an estimate never allocates.
/// It dereferences to the slice of its items and serialises as a sequence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedList<T: Copy + Default, const C: usize> {
    len: usize,
    items: [T; C],
}

impl<T: Copy + Default, const C: usize> FixedList<T, C> {
    pub fn new() -> Self {
        Self {
            len: 0,
            items: [T::default(); C],
        }
    }
    /// Appends `item`; returns `false` (and drops it) when the list is full.
    pub fn push(&mut self, item: T) -> bool {
        match self.items.get_mut(self.len) {
            Some(slot) => {
                *slot = item;
                self.len += 1;
                true
            }
            None => false,
        }
    }
    pub fn clear(&mut self) {
        self.len = 0;
    }
    pub fn capacity(&self) -> usize {
        C
    }
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.items[..self.len]
    }
}

impl<T: Copy + Default, const C: usize> Default for FixedList<T, C> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Copy + Default, const C: usize> Deref for FixedList<T, C> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        &self.items[..self.len]
    }
}

impl<T: Copy + Default + Serialize, const C: usize> Serialize for FixedList<T, C> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut seq = serializer.serialize_seq(Some(self.len))?;
        for item in self.iter() {
            seq.serialize_element(item)?;
        }
        seq.end()
    }
}

/// One tone (deterministic vibration) common to the three axes:
/// `x_axis(t) = amplitude_g[axis] * sin(2 pi frequency_hz (t - center) + phase_rad[axis])`
/// where `center` is the estimate's `center_ns`. Amplitudes and phases are corrected
/// for the AC coupling and the response table, so they describe the true vibration.
/// `*_u_*` fields are standard uncertainties (the Cramér-Rao bounds for the local noise
/// floor, which the least-squares fit attains).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ToneEstimate {
    pub frequency_hz: f64,
    pub frequency_u_hz: f64,
    pub amplitude_g: [f64; 3],
    pub amplitude_u_g: [f64; 3],
    pub phase_rad: [f64; 3],
    pub phase_u_rad: [f64; 3],
    /// Tone power over the local floor's power in the window's resolution bandwidth
    /// `1/window_s`, per axis, in dB.
    pub snr_db: [f64; 3],
}

/// The broadband (tones removed) vibration in one PSD band.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct BandEstimate {
    pub f_lo_hz: f64,
    pub f_hi_hz: f64,
    /// Mean one-sided PSD over the band (band power / band width).
    pub psd_g2_per_hz: [f64; 3],
    pub psd_u_g2_per_hz: [f64; 3],
    /// RMS in the band, `sqrt(psd * width)`.
    pub rms_g: [f64; 3],
}

/// The broadband (tones removed) vibration over the configured broadband band.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Broadband {
    pub f_lo_hz: f64,
    pub f_hi_hz: f64,
    /// RMS per axis (`sigma_i` of MODEL.md).
    pub rms_g: [f64; 3],
    pub rms_u_g: [f64; 3],
    /// Covariance `K_ij(0)`: the real part of the cross-spectrum integrated over the band.
    pub covariance_g2: [[f64; 3]; 3],
    pub covariance_u_g2: [[f64; 3]; 3],
    /// Kurtosis `E[x^4] / E[x^2]^2` of the band-limited broadband part (3 for Gaussian).
    pub kurtosis: [f64; 3],
    /// Its standard uncertainty under the Gaussian hypothesis.
    pub kurtosis_u: [f64; 3],
    /// Welch segments averaged.
    pub welch_segments: usize,
    /// Samples per Welch segment (the bins are the sample rate over it wide): with the
    /// rate, what the window's leakage between bands follows from
    /// (`crate::BandLeakage::with_segment`).
    pub welch_segment_samples: usize,
}

/// Why an estimate may be incomplete or should be used with care.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Flags {
    /// No tone passed the detection threshold.
    pub tone_free: bool,
    /// Per axis: at least one sample at or over the configured full scale.
    pub saturated: [bool; 3],
    /// Samples were missing (a timestamp or sequence gap) in or just before this window;
    /// gap-filled samples were kept out of the estimate.
    pub gap: bool,
    /// NaN, infinite or absurd (beyond [`crate::MAX_ABS_SAMPLE_G`]) samples were found
    /// in the window and kept out of the estimate.
    pub non_finite: bool,
    /// Out-of-order or overlapping blocks were dropped since the previous estimate.
    pub out_of_order: bool,
    /// Too few valid samples or Welch segments: some values are NaN.
    pub insufficient_data: bool,
}

impl Flags {
    /// The flags raised that make an estimate incomplete, by their short names
    /// (`insufficient`, `gap`, `bad-samples`, `out-of-order`, `saturated`), in that
    /// order; `tone_free` is not one of them.
    pub fn labels(&self) -> Vec<&'static str> {
        let mut out = Vec::new();
        if self.insufficient_data {
            out.push("insufficient");
        }
        if self.gap {
            out.push("gap");
        }
        if self.non_finite {
            out.push("bad-samples");
        }
        if self.out_of_order {
            out.push("out-of-order");
        }
        if self.saturated.iter().any(|s| *s) {
            out.push("saturated");
        }
        out
    }
}

/// The estimate of one window.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Estimate {
    /// Counts the estimates emitted since the estimator was built.
    pub index: u64,
    /// Timestamp of the window's first sample.
    pub start_ns: u64,
    /// Timestamp one sample period after the window's last sample (exclusive end).
    pub end_ns: u64,
    /// Mid-point of the window's samples: the reference time of the tone phases.
    pub center_ns: u64,
    /// Samples in the window, valid or not.
    pub samples: usize,
    /// Samples that entered the estimate (finite, not gap-filled).
    pub valid_samples: usize,
    /// Samples at or over full scale, per axis.
    pub saturated_samples: [usize; 3],
    pub tones: FixedList<ToneEstimate, MAX_TONES>,
    pub broadband: Broadband,
    pub bands: FixedList<BandEstimate, MAX_BANDS>,
    pub flags: Flags,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flag_labels_name_what_is_raised_in_order() {
        assert!(Flags::default().labels().is_empty());
        let f = Flags {
            tone_free: true,
            saturated: [false, true, false],
            gap: true,
            insufficient_data: true,
            ..Flags::default()
        };
        assert_eq!(f.labels(), ["insufficient", "gap", "saturated"]);
    }

    #[test]
    fn fixed_list_keeps_at_most_its_capacity_and_serialises_its_items() {
        let mut l: FixedList<u8, 2> = FixedList::new();
        assert!(l.push(1) && l.push(2));
        assert!(!l.push(3));
        assert_eq!(&*l, &[1, 2]);
        assert_eq!(serde_json::to_string(&l).unwrap(), "[1,2]");
        l.clear();
        assert_eq!(serde_json::to_string(&l).unwrap(), "[]");
    }

    #[test]
    fn not_estimated_values_serialise_as_null() {
        let b = BandEstimate {
            rms_g: [f64::NAN, 1.0, 2.0],
            ..Default::default()
        };
        let text = serde_json::to_string(&b).unwrap();
        assert!(text.contains("\"rms_g\":[null,1.0,2.0]"), "{text}");
    }
}
