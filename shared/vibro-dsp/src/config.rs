//! Estimator configuration: a raw form (what a TOML file or the command line gives)
//! and the validated [`EstimatorConfig`] that [`crate::Estimator::new`] takes.

use crate::{Error, Result, MAX_BANDS, MAX_TONES};
use serde::{Deserialize, Serialize};

/// The random-vibration bands of RIG.md's table ([P1 Table 3], [P2 Table 1]), in Hz.
pub const RIG_PSD_BANDS_HZ: [[f64; 2]; 5] = [
    [20.0, 40.0],
    [40.0, 80.0],
    [80.0, 160.0],
    [160.0, 320.0],
    [320.0, 640.0],
];

/// Default estimation window (issue 3).
pub const DEFAULT_WINDOW_S: f64 = 1.0;
/// Default overlap of consecutive windows, as a fraction of the window.
pub const DEFAULT_OVERLAP_FRACTION: f64 = 0.5;
/// Default number of tones looked for per window.
pub const DEFAULT_MAX_TONES: usize = 4;
/// Default detection threshold: tone power over the local floor's power in the window's
/// resolution bandwidth `1/window_s`. At 20 dB a noise-only window of 25 600 bins raises
/// a false tone with probability below 1e-15 (see `detect.rs`).
pub const DEFAULT_TONE_SNR_THRESHOLD_DB: f64 = 20.0;
/// Default broadband band (RIG.md: 20..2000 Hz is the band of interest).
pub const DEFAULT_BROADBAND_BAND_HZ: [f64; 2] = [20.0, 2000.0];
/// Default Welch segment: 0.25 s gives 4 Hz bins (five across the narrowest RIG band,
/// 20..40 Hz) and seven 50%-overlapped averages in a 1 s window.
pub const DEFAULT_WELCH_SEGMENT_S: f64 = 0.25;
/// Default largest fraction of invalid (non-finite or gap-filled) samples in a window
/// before its estimate is declared insufficient.
pub const DEFAULT_MAX_INVALID_FRACTION: f64 = 0.25;

/// Most points of the frequency-response table: a calibration sheet gives tens; 1024
/// holds a swept-sine measurement at 2 Hz steps across the 2 kHz band of interest.
/// The table is searched per band and per tone; its points' problems are listed
/// only when it is within this bound.
pub const MAX_RESPONSE_POINTS: usize = 1024;

/// The longest sensor-chain delay (`delay_s`), s: a DAQ's filter delays by
/// milliseconds; a second is a unit mix-up (ms for s). The rig file and the
/// compensator's `[sensors]` keep the same bound.
pub const MAX_DELAY_S: f64 = 1.0;

/// Smallest window, in samples: below this the spectra have too few bins to find a floor.
pub const MIN_WINDOW_SAMPLES: usize = 256;
/// Largest window, in samples (2^24): bounds the memory allocated at build time.
pub const MAX_WINDOW_SAMPLES: usize = 1 << 24;
/// Smallest Welch segment, in samples.
pub const MIN_SEGMENT_SAMPLES: usize = 16;
/// Tones are only looked for this many bins away from DC and from the Nyquist
/// frequency: closer, the Hann main lobe (+-2 bins) overlaps its own mirror image.
pub const TONE_EDGE_BINS: usize = 4;

/// One point of a sensor's frequency-response correction table: the complex response
/// `H(f) = gain * exp(i * phase)` of the measuring chain (measured / true) per axis.
/// The estimator divides by it (linearly interpolated in frequency, held constant
/// outside the table).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResponsePoint {
    pub frequency_hz: f64,
    pub gain: [f64; 3],
    pub phase_rad: [f64; 3],
}

/// Estimator settings as written by a user; validate with `EstimatorConfig::try_from`.
///
/// Only the sample rate and the sensitivities have no default: they are physical facts
/// of the rig. Every other default is the one named in issue 3.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EstimatorConfigRaw {
    /// Sample rate of the vibration sensors.
    pub sample_rate_hz: f64,
    /// Raw units (V or ADC counts) per g, per axis; 1.0 when the samples are already in g.
    /// A negative value flips the axis.
    pub sensitivity_raw_per_g: [f64; 3],
    /// Full scale per axis: a sample with `|x| >= full_scale_g` marks the axis saturated.
    #[serde(default)]
    pub full_scale_g: Option<[f64; 3]>,
    /// Corner of the sensors' AC coupling, modelled as a first-order high-pass
    /// `H(f) = j(f/fc) / (1 + j(f/fc))`. `None`: DC-coupled.
    #[serde(default)]
    pub ac_corner_hz: Option<f64>,
    /// Frequency-response correction table (empty: none). Frequencies strictly increase.
    #[serde(default)]
    pub response: Vec<ResponsePoint>,
    /// Window length.
    #[serde(default = "default_window_s")]
    pub window_s: f64,
    /// Overlap of consecutive windows, 0 <= overlap < 1.
    #[serde(default = "default_overlap_fraction")]
    pub overlap_fraction: f64,
    /// Largest number of tones reported per window (0 disables tone detection).
    #[serde(default = "default_max_tones")]
    pub max_tones: usize,
    /// Detection threshold, see [`DEFAULT_TONE_SNR_THRESHOLD_DB`].
    #[serde(default = "default_tone_snr_threshold_db")]
    pub tone_snr_threshold_db: f64,
    /// Band where tones are looked for; `None`: everything resolvable.
    #[serde(default)]
    pub tone_band_hz: Option<[f64; 2]>,
    /// Band of the broadband RMS, covariance and kurtosis.
    #[serde(default = "default_broadband_band_hz")]
    pub broadband_band_hz: [f64; 2],
    /// Bands of the reported PSD.
    #[serde(default = "default_psd_bands_hz")]
    pub psd_bands_hz: Vec<[f64; 2]>,
    /// Length of a Welch segment (Hann, 50% overlap).
    #[serde(default = "default_welch_segment_s")]
    pub welch_segment_s: f64,
    /// Largest fraction of invalid samples a window may hold and still be estimated.
    #[serde(default = "default_max_invalid_fraction")]
    pub max_invalid_fraction: f64,
    /// A block's timestamp within this of the expected one counts as contiguous;
    /// `None`: half a sample period (hardware timestamps). Software timestamps need
    /// their jitter here.
    #[serde(default)]
    pub timestamp_tolerance_s: Option<f64>,
    /// The sensor chain's delay, s: a sample stamped `s` saw the base at `s - delay_s`
    /// (a DAQ's anti-alias filter, a digital sensor's group delay). The estimates' times
    /// are taken back by it, so that their tone phases refer to when the base moved
    /// (MODEL.md section 12 states the same chain for the waveform stage).
    #[serde(default)]
    pub delay_s: f64,
}

fn default_window_s() -> f64 {
    DEFAULT_WINDOW_S
}
fn default_overlap_fraction() -> f64 {
    DEFAULT_OVERLAP_FRACTION
}
fn default_max_tones() -> usize {
    DEFAULT_MAX_TONES
}
fn default_tone_snr_threshold_db() -> f64 {
    DEFAULT_TONE_SNR_THRESHOLD_DB
}
fn default_broadband_band_hz() -> [f64; 2] {
    DEFAULT_BROADBAND_BAND_HZ
}
fn default_psd_bands_hz() -> Vec<[f64; 2]> {
    RIG_PSD_BANDS_HZ.to_vec()
}
fn default_welch_segment_s() -> f64 {
    DEFAULT_WELCH_SEGMENT_S
}
fn default_max_invalid_fraction() -> f64 {
    DEFAULT_MAX_INVALID_FRACTION
}

impl EstimatorConfigRaw {
    /// The physical facts of the rig, every processing setting at its default.
    pub fn new(sample_rate_hz: f64, sensitivity_raw_per_g: [f64; 3]) -> Self {
        Self {
            sample_rate_hz,
            sensitivity_raw_per_g,
            full_scale_g: None,
            ac_corner_hz: None,
            response: Vec::new(),
            window_s: DEFAULT_WINDOW_S,
            overlap_fraction: DEFAULT_OVERLAP_FRACTION,
            max_tones: DEFAULT_MAX_TONES,
            tone_snr_threshold_db: DEFAULT_TONE_SNR_THRESHOLD_DB,
            tone_band_hz: None,
            broadband_band_hz: DEFAULT_BROADBAND_BAND_HZ,
            psd_bands_hz: RIG_PSD_BANDS_HZ.to_vec(),
            welch_segment_s: DEFAULT_WELCH_SEGMENT_S,
            max_invalid_fraction: DEFAULT_MAX_INVALID_FRACTION,
            timestamp_tolerance_s: None,
            delay_s: 0.0,
        }
    }
}

/// A validated estimator configuration, with the sample counts derived from it.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorConfig {
    raw: EstimatorConfigRaw,
    window_samples: usize,
    hop_samples: usize,
    segment_samples: usize,
    tone_bins: [usize; 2],
}

impl EstimatorConfig {
    /// The settings as given.
    pub fn raw(&self) -> &EstimatorConfigRaw {
        &self.raw
    }
    pub fn sample_rate_hz(&self) -> f64 {
        self.raw.sample_rate_hz
    }
    /// Samples per window, `N = round(window_s * sample_rate_hz)`.
    pub fn window_samples(&self) -> usize {
        self.window_samples
    }
    /// Samples between the starts of consecutive windows.
    pub fn hop_samples(&self) -> usize {
        self.hop_samples
    }
    /// Samples per Welch segment.
    pub fn segment_samples(&self) -> usize {
        self.segment_samples
    }
    /// Sample period in ns (fractional: 39 062.5 ns at 25.6 kHz).
    pub fn sample_period_ns(&self) -> f64 {
        1e9 / self.raw.sample_rate_hz
    }
    /// The chain's delay in ns (`delay_s`, rounded to the ns): taken off the samples'
    /// time stamps when an estimate is dated.
    pub fn delay_ns(&self) -> u64 {
        (self.raw.delay_s * 1e9).round() as u64
    }
    /// First and last DFT bin (of the window) where tones are looked for.
    pub(crate) fn tone_bins(&self) -> [usize; 2] {
        self.tone_bins
    }
}

impl TryFrom<EstimatorConfigRaw> for EstimatorConfig {
    type Error = Error;

    /// Checks every setting and reports all problems at once.
    fn try_from(raw: EstimatorConfigRaw) -> Result<Self> {
        let mut problems = Vec::new();
        let mut check = |ok: bool, text: String| {
            if !ok {
                problems.push(text);
            }
        };
        let fs_hz = raw.sample_rate_hz;
        let fs_ok = fs_hz.is_finite() && fs_hz > 0.0;
        check(
            fs_ok,
            format!("sample_rate_hz = {fs_hz}: must be finite and > 0"),
        );
        let nyquist_hz = if fs_ok { fs_hz / 2.0 } else { f64::INFINITY };
        for (axis, s) in raw.sensitivity_raw_per_g.iter().enumerate() {
            check(
                s.is_finite() && *s != 0.0,
                format!("sensitivity_raw_per_g[{axis}] = {s}: must be finite and non-zero"),
            );
        }
        if let Some(full_scale_g) = raw.full_scale_g {
            for (axis, v) in full_scale_g.iter().enumerate() {
                check(
                    v.is_finite() && *v > 0.0,
                    format!("full_scale_g[{axis}] = {v}: must be finite and > 0"),
                );
            }
        }
        if let Some(fc) = raw.ac_corner_hz {
            check(
                fc.is_finite() && fc > 0.0 && fc < nyquist_hz,
                format!("ac_corner_hz = {fc}: must be finite, > 0 and below the Nyquist frequency {nyquist_hz} Hz"),
            );
        }
        check(
            raw.response.len() <= MAX_RESPONSE_POINTS,
            format!(
                "response: {} points, at most {MAX_RESPONSE_POINTS} are allowed",
                raw.response.len()
            ),
        );
        // A table over its bound: its count alone (its points may number 100 000).
        let response = if raw.response.len() <= MAX_RESPONSE_POINTS {
            &raw.response[..]
        } else {
            &[]
        };
        for (i, p) in response.iter().enumerate() {
            check(
                p.frequency_hz.is_finite() && p.frequency_hz >= 0.0,
                format!(
                    "response[{i}].frequency_hz = {}: must be finite and >= 0",
                    p.frequency_hz
                ),
            );
            if i > 0 {
                let prev = raw.response[i - 1].frequency_hz;
                check(
                    p.frequency_hz > prev,
                    format!(
                        "response[{i}].frequency_hz = {}: must be greater than the previous point's {prev}",
                        p.frequency_hz
                    ),
                );
            }
            for axis in 0..3 {
                let g = p.gain[axis];
                check(
                    g.is_finite() && g > 0.0,
                    format!("response[{i}].gain[{axis}] = {g}: must be finite and > 0"),
                );
                let ph = p.phase_rad[axis];
                check(
                    ph.is_finite(),
                    format!("response[{i}].phase_rad[{axis}] = {ph}: must be finite"),
                );
            }
        }

        let samples = |s: f64| if fs_ok { (s * fs_hz).round() } else { 0.0 };
        let w = raw.window_s;
        let window_samples_f = samples(w);
        let window_ok = w.is_finite()
            && w > 0.0
            && window_samples_f >= MIN_WINDOW_SAMPLES as f64
            && window_samples_f <= MAX_WINDOW_SAMPLES as f64;
        check(
            !fs_ok || window_ok,
            format!(
                "window_s = {w}: must be finite and hold {MIN_WINDOW_SAMPLES}..={MAX_WINDOW_SAMPLES} samples (it holds {window_samples_f})"
            ),
        );
        let window_samples = if window_ok {
            window_samples_f as usize
        } else {
            0
        };

        let ov = raw.overlap_fraction;
        let overlap_ok = ov.is_finite() && (0.0..1.0).contains(&ov);
        check(
            overlap_ok,
            format!("overlap_fraction = {ov}: must be finite and 0 <= overlap < 1"),
        );
        let hop_samples = if overlap_ok {
            ((window_samples as f64) * (1.0 - ov)).round().max(1.0) as usize
        } else {
            0
        };

        check(
            raw.max_tones <= MAX_TONES,
            format!("max_tones = {}: must be <= {MAX_TONES}", raw.max_tones),
        );
        let thr = raw.tone_snr_threshold_db;
        check(
            thr.is_finite(),
            format!("tone_snr_threshold_db = {thr}: must be finite"),
        );

        let mut tone_bins = [0, 0];
        if window_ok && fs_ok {
            let window_s = window_samples as f64 / fs_hz;
            let lo_bin = TONE_EDGE_BINS;
            let hi_bin = (window_samples / 2).saturating_sub(TONE_EDGE_BINS);
            tone_bins = [lo_bin, hi_bin];
            if let Some([lo, hi]) = raw.tone_band_hz {
                let band_ok = lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo;
                check(
                    band_ok,
                    format!("tone_band_hz = [{lo}, {hi}]: must be finite with 0 <= lo < hi"),
                );
                if band_ok {
                    tone_bins = [
                        lo_bin.max((lo * window_s).ceil() as usize),
                        hi_bin.min((hi * window_s).floor().min(usize::MAX as f64) as usize),
                    ];
                }
            }
            check(
                raw.max_tones == 0 || tone_bins[0] <= tone_bins[1],
                format!(
                    "tone_band_hz = {:?}: holds no resolvable frequency (tones need {:.3}..{:.3} Hz with window_s = {window_s})",
                    raw.tone_band_hz,
                    lo_bin as f64 / window_s,
                    hi_bin as f64 / window_s
                ),
            );
        }

        let mut check_band = |name: String, [lo, hi]: [f64; 2]| {
            check(
                lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo && hi <= nyquist_hz,
                format!(
                    "{name} = [{lo}, {hi}]: must satisfy 0 < lo < hi <= {nyquist_hz} Hz (Nyquist)"
                ),
            );
        };
        check_band("broadband_band_hz".into(), raw.broadband_band_hz);
        // A list over its bound: its count alone (below).
        if raw.psd_bands_hz.len() <= MAX_BANDS {
            for (i, band) in raw.psd_bands_hz.iter().enumerate() {
                check_band(format!("psd_bands_hz[{i}]"), *band);
            }
        }
        check(
            raw.psd_bands_hz.len() <= MAX_BANDS,
            format!(
                "psd_bands_hz: {} bands, at most {MAX_BANDS} are allowed",
                raw.psd_bands_hz.len()
            ),
        );

        let seg = raw.welch_segment_s;
        let segment_samples_f = samples(seg);
        let segment_ok = seg.is_finite()
            && seg > 0.0
            && segment_samples_f >= MIN_SEGMENT_SAMPLES as f64
            && segment_samples_f <= window_samples as f64;
        check(
            !(fs_ok && window_ok) || segment_ok,
            format!(
                "welch_segment_s = {seg}: must hold {MIN_SEGMENT_SAMPLES} samples up to the window's {window_samples} (it holds {segment_samples_f})"
            ),
        );
        let segment_samples = if segment_ok {
            segment_samples_f as usize
        } else {
            0
        };

        let inv = raw.max_invalid_fraction;
        check(
            inv.is_finite() && (0.0..1.0).contains(&inv),
            format!("max_invalid_fraction = {inv}: must be finite and 0 <= fraction < 1"),
        );

        if let Some(tol) = raw.timestamp_tolerance_s {
            check(
                tol.is_finite() && tol >= 0.0 && tol < w,
                format!(
                    "timestamp_tolerance_s = {tol}: must be finite and 0 <= tolerance < window_s"
                ),
            );
        }

        let delay = raw.delay_s;
        check(
            delay.is_finite() && (0.0..=MAX_DELAY_S).contains(&delay),
            format!("delay_s = {delay}: must be finite and 0 <= delay <= {MAX_DELAY_S} s"),
        );

        if !problems.is_empty() {
            return Err(Error::InvalidConfig { problems });
        }
        Ok(Self {
            raw,
            window_samples,
            hop_samples,
            segment_samples,
            tone_bins,
        })
    }
}

/// A band written `LO-HI` in Hz (`20-40`), as a command line gives the PSD bands;
/// `None` unless both ends are numbers.
pub fn parse_band_hz(text: &str) -> Option<[f64; 2]> {
    let (lo, hi) = text.trim().split_once('-')?;
    Some([lo.trim().parse().ok()?, hi.trim().parse().ok()?])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_parse_as_lo_hi() {
        assert_eq!(parse_band_hz(" 20 - 40 "), Some([20.0, 40.0]));
        assert_eq!(parse_band_hz("0.5-1e3"), Some([0.5, 1000.0]));
        assert_eq!(parse_band_hz("20..40"), None);
        assert_eq!(parse_band_hz("20-"), None);
    }

    #[test]
    fn defaults_follow_the_issue() {
        let c = EstimatorConfig::try_from(EstimatorConfigRaw::new(25_600.0, [1.0; 3])).unwrap();
        assert_eq!(c.window_samples(), 25_600);
        assert_eq!(c.hop_samples(), 12_800);
        assert_eq!(c.segment_samples(), 6_400);
        assert_eq!(c.raw().max_tones, 4);
        assert_eq!(c.raw().psd_bands_hz.len(), 5);
        assert_eq!(c.tone_bins(), [4, 12_796]);
    }

    #[test]
    fn reports_every_problem_with_its_value() {
        let mut raw = EstimatorConfigRaw::new(1000.0, [1.0, 0.0, f64::NAN]);
        raw.overlap_fraction = 1.5;
        raw.broadband_band_hz = [20.0, 900.0];
        raw.max_tones = 99;
        let Err(Error::InvalidConfig { problems }) = EstimatorConfig::try_from(raw) else {
            panic!("expected an invalid configuration");
        };
        let text = problems.join("\n");
        assert!(text.contains("sensitivity_raw_per_g[1] = 0"), "{text}");
        assert!(text.contains("sensitivity_raw_per_g[2] = NaN"), "{text}");
        assert!(text.contains("overlap_fraction = 1.5"), "{text}");
        assert!(text.contains("broadband_band_hz = [20, 900]"), "{text}");
        assert!(text.contains("max_tones = 99"), "{text}");
        assert!(text.contains("psd_bands_hz[4] = [320, 640]"), "{text}");
        assert_eq!(problems.len(), 6, "{text}");
    }

    #[test]
    fn a_tone_band_outside_the_resolvable_range_is_refused() {
        let mut raw = EstimatorConfigRaw::new(1000.0, [1.0; 3]);
        raw.broadband_band_hz = [20.0, 400.0];
        raw.tone_band_hz = Some([0.0, 2.0]);
        let e = EstimatorConfig::try_from(raw).unwrap_err().to_string();
        assert!(e.contains("holds no resolvable frequency"), "{e}");
    }

    /// Issue 46, item 7: the lists of the estimator's configuration are bounded, and a
    /// list over its bound is reported by its count alone, not point by point.
    #[test]
    fn a_list_over_its_bound_is_refused_by_its_count() {
        let mut raw = EstimatorConfigRaw::new(25_600.0, [1.0; 3]);
        raw.response = vec![
            ResponsePoint {
                frequency_hz: -1.0,
                gain: [1.0; 3],
                phase_rad: [0.0; 3],
            };
            100_000
        ];
        raw.psd_bands_hz = vec![[-1.0, 0.0]; 100_000];
        let Err(Error::InvalidConfig { problems }) = EstimatorConfig::try_from(raw) else {
            panic!("accepted")
        };
        assert_eq!(
            problems,
            [
                "response: 100000 points, at most 1024 are allowed",
                "psd_bands_hz: 100000 bands, at most 16 are allowed",
            ]
        );
        let mut raw = EstimatorConfigRaw::new(25_600.0, [1.0; 3]);
        raw.response = (0..MAX_RESPONSE_POINTS)
            .map(|i| ResponsePoint {
                frequency_hz: i as f64,
                gain: [1.0; 3],
                phase_rad: [0.0; 3],
            })
            .collect();
        EstimatorConfig::try_from(raw).unwrap();
    }

    #[test]
    fn raw_config_rejects_unknown_keys() {
        let json = r#"{"sample_rate_hz": 1000.0, "sensitivity_raw_per_g": [1,1,1], "window": 2}"#;
        let e = serde_json::from_str::<EstimatorConfigRaw>(json).unwrap_err();
        assert!(e.to_string().contains("unknown field `window`"), "{e}");
    }
}
