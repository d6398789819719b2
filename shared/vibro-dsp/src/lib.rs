//! # vibro-dsp
//!
//! Vibration estimation from the vibration sensors next to each accelerometer
//! (RIG.md): per window of 3-axis samples, the tones (deterministic vibration `aB_i`,
//! `f`, `phi_i`), the broadband RMS per axis (`sigma_i`), the PSD per band, the 3x3
//! covariance (`K_ij(0)`) and the kurtosis of the broadband part: the inputs of the
//! in-flight compensation (MODEL.md section 7) and of the exact VE (section 6).
//!
//! Per window (length and overlap configurable, default 1 s and 50%):
//!
//! 1. **Detection** (module `detect`): Hann-windowed FFT (realfft) of the
//!    whole window, a median-based local floor, peaks above a configured SNR, each
//!    located by Grandke's two-bin interpolation for the Hann window.
//! 2. **Refinement** (module `sinefit`): a joint least-squares fit of all
//!    detected tones over the three axes (IEEE 1057 four-parameter fit, generalised),
//!    which reaches the Cramér-Rao bound and removes the interpolator's bias and the
//!    tones' mutual leakage. Tone amplitudes and phases are then corrected by the known
//!    response (first-order AC coupling, optional table).
//! 3. **Broadband** (module `welch`): the fitted tones are subtracted; the
//!    residual's auto- and cross-spectra are Welch-averaged (Hann, 50%, the conventions
//!    of `scipy.signal.welch`) and integrated over each band.
//! 4. **Kurtosis** (module `kurtosis`) of the band-limited residual.
//!
//! Every value carries a standard uncertainty, and every estimate [`Flags`] for gaps,
//! non-finite samples, out-of-order blocks, saturation and insufficient data. Bad
//! samples are kept out of the estimate; they never panic or poison a window. All
//! buffers are allocated by [`Estimator::new`]: taking a block never allocates.
//!
//! ```
//! use vibro_dsp::{Estimator, EstimatorConfig, EstimatorConfigRaw, SampleBlock};
//! let fs_hz = 4096.0;
//! let mut raw = EstimatorConfigRaw::new(fs_hz, [1.0; 3]); // samples already in g
//! raw.broadband_band_hz = [20.0, 1000.0];
//! let mut estimator = Estimator::new(EstimatorConfig::try_from(raw)?);
//! // 2 s of a 0.5 g, 30 Hz tone on the z axis, in blocks of 256 samples.
//! let samples: Vec<[f64; 3]> = (0..8192)
//!     .map(|k| [0.0, 0.0, 0.5 * (std::f64::consts::TAU * 30.0 * k as f64 / fs_hz).sin()])
//!     .collect();
//! let mut estimates = Vec::new();
//! for (seq, chunk) in samples.chunks(256).enumerate() {
//!     let t0_ns = (seq as f64 * 256.0 / fs_hz * 1e9) as u64;
//!     let block = SampleBlock { seq: seq as u64, t0_ns, samples_raw: chunk };
//!     estimator.push_block(&block, |e| estimates.push(*e))?;
//! }
//! assert_eq!(estimates.len(), 3); // windows at 0, 0.5 and 1 s
//! let tone = estimates[0].tones[0];
//! assert!((tone.frequency_hz - 30.0).abs() < 1e-6);
//! assert!((tone.amplitude_g[2] - 0.5).abs() < 1e-6);
//! # Ok::<(), vibro_dsp::Error>(())
//! ```
//!
//! References:
//! - P. D. Welch, "The use of fast Fourier transform for the estimation of power
//!   spectra", IEEE Trans. Audio Electroacoust. AU-15(2), 1967, 70-73.
//! - F. J. Harris, "On the use of windows for harmonic analysis with the discrete
//!   Fourier transform", Proc. IEEE 66(1), 1978, 51-83.
//! - T. Grandke, "Interpolation algorithms for discrete Fourier transforms of weighted
//!   signals", IEEE Trans. Instrum. Meas. IM-32(2), 1983, 350-355.
//! - IEEE Std 1057-2017, sine-wave fitting (four-parameter); P. Händel, "Properties of
//!   the IEEE-STD-1057 four-parameter sine wave fit algorithm", IEEE Trans. Instrum.
//!   Meas. 49(6), 2000, 1189-1193.
//! - S. M. Kay, *Fundamentals of Statistical Signal Processing: Estimation Theory*,
//!   1993, example 3.14 (Cramér-Rao bounds of a sinusoid's parameters).
//! - J. S. Bendat, A. G. Piersol, *Random Data*, 4th ed., 2010, ch. 8-9 (random errors
//!   of spectral estimates).

// Per-axis and per-parameter index loops mirror the formulas they implement (and
// index several arrays at once); iterator chains would hide the indices.
#![allow(clippy::needless_range_loop)]

mod config;
mod detect;
mod estimator;
mod kurtosis;
mod leakage;
mod output;
mod response;
mod sinefit;
mod sums;
pub mod text;
mod welch;

/// The unit tests' deterministic random numbers (xorshift64).
#[cfg(test)]
pub(crate) mod test_rng {
    /// The next state of `state` (Marsaglia's xorshift64: 13, 7, 17).
    pub(crate) fn next(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    /// Uniform in `[0, 1)` from the next state's top 53 bits.
    pub(crate) fn uniform(state: &mut u64) -> f64 {
        (next(state) >> 11) as f64 / (1u64 << 53) as f64
    }
}

pub use config::parse_band_hz;
pub use config::{
    EstimatorConfig, EstimatorConfigRaw, ResponsePoint, DEFAULT_BROADBAND_BAND_HZ,
    DEFAULT_MAX_INVALID_FRACTION, DEFAULT_MAX_TONES, DEFAULT_OVERLAP_FRACTION,
    DEFAULT_TONE_SNR_THRESHOLD_DB, DEFAULT_WELCH_SEGMENT_S, DEFAULT_WINDOW_S, MAX_DELAY_S,
    MAX_RESPONSE_POINTS, MAX_WINDOW_SAMPLES, MIN_SEGMENT_SAMPLES, MIN_WINDOW_SAMPLES,
    RIG_PSD_BANDS_HZ, TONE_EDGE_BINS,
};
pub use estimator::{
    BlockStatus, Counters, Estimator, SampleBlock, MAX_ABS_SAMPLE_G, RESYNC_AFTER_DROPS,
};
pub use leakage::BandLeakage;
pub use output::{BandEstimate, Broadband, Estimate, FixedList, Flags, ToneEstimate};

/// Most tones an estimate can hold.
pub const MAX_TONES: usize = 16;
/// Most PSD bands an estimate can hold.
pub const MAX_BANDS: usize = 16;

/// Errors of vibration estimation. Messages carry the offending values.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("invalid estimator configuration: {}", problems.join("; "))]
    InvalidConfig { problems: Vec<String> },
    /// Buffer sizes are fixed when the estimator is built, so this is a bug.
    #[error("FFT failed (buffer sizes are fixed at build time, so this is a bug): {0}")]
    Fft(#[from] realfft::FftError),
}

/// Result of vibration estimation.
pub type Result<T> = std::result::Result<T, Error>;
