//! Tone detection: a Hann-windowed FFT of the whole window, a local broadband floor,
//! peaks over that floor, and Grandke's interpolation of each peak's frequency.
//!
//! The window is applied in the frequency domain: the FFT takes the plain samples (less
//! their mean, invalid ones zeroed), and the periodic Hann `0.5 - 0.5 cos(2 pi n / N)`
//! is its three-tap kernel there, `X_w[k] = 0.5 X[k] - 0.25 (X[k-1] + X[k+1])`
//! (exact). The plain DFT is kept: it is the kurtosis' forward transform too
//! ([`crate::kurtosis`]).
//!
//! Why Hann: its sidelobes fall 18 dB/octave, so a strong tone does not raise the
//! floor far from it, while its main lobe (+-2 bins) keeps tones 2.5 bins apart
//! resolvable. Amplitude accuracy does not come from the window: the least-squares fit
//! ([`crate::sinefit`]) refines every detected tone, so a flat-top window's amplitude
//! flatness is not needed and its 3.8-bin-wide main lobe would only cost resolution.
//!
//! Interpolation [Grandke 1983, IEEE Trans. IM-32(2) 350-355]: for a Hann window the
//! ratio of the two largest bins, `alpha = |X[k+1]| / |X[k]|`, gives the offset of the
//! tone from bin `k` as `delta = (2 alpha - 1) / (alpha + 1)` (exact for one tone in
//! the limit of large N), and the amplitude follows from the window's kernel
//! `|W(delta)| = |sinc(delta) / (1 - delta^2)|`.
//!
//! The floor is a running median of the periodogram: the median of the 32 bins around
//! every 16th bin, linearly interpolated between, divided by ln 2 (a noise bin's power
//! is exponentially distributed, and its median is ln 2 times its mean): tones take up
//! a few bins and barely move a median. It must be local: a tone beside a band of
//! random vibration is measured against the floor under it, not the band's. With the
//! fixed 64-bin blocks used before, the first block of a 1 s window (0-63 Hz) took the
//! Cyclone-4's random band (from 20 Hz) as the floor of its 8-16 Hz tones, and their
//! 1.2 g went undetected in most windows (`tone_below_a_random_band_is_detected`).
//!
//! False alarms: a noise-only bin's "tone SNR" (see [`crate::ToneEstimate::snr_db`])
//! is 1.5 x Exp(1) at a bin centre and at most 2.1 x Exp(1) with scalloping, so a 20 dB
//! threshold is crossed with probability exp(-100/2.1) ~ 2e-21 per bin.

use crate::output::FixedList;
use crate::{Result, MAX_TONES};
use realfft::num_complex::Complex64;
use realfft::{RealFftPlanner, RealToComplex};
use std::f64::consts::PI;
use std::sync::Arc;

/// Bins in each median of the floor.
const FLOOR_SPAN_BINS: usize = 32;
/// Bins between the medians (the floor is interpolated between them): half a span, so
/// every bin lies within a quarter span of a median's centre.
const FLOOR_HOP_BINS: usize = 16;
const MAX_CANDIDATES: usize = 4 * MAX_TONES;
/// Tone SNR of a peak bin relative to its power-to-floor ratio, at worst scalloping
/// (Hann: 1.5 at a bin centre, / 0.72 at half a bin).
const SCALLOPED_SNR_PER_RATIO: f64 = 2.1;
/// Peaks closer than this to a stronger tone (in bins) are in its main lobe.
const MIN_SEPARATION_BINS: f64 = 2.5;
/// A peak further away must stand this far (power ratio) above the stronger tone's
/// Hann sidelobe envelope to count as a tone of its own.
const LEAKAGE_MARGIN: f64 = 10.0;

/// A detected tone before refinement.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Detected {
    /// Interpolated position, in bins of the window's DFT.
    pub(crate) bin: f64,
    /// Interpolated amplitude per axis (measured units, g).
    pub(crate) amplitude_g: [f64; 3],
}

pub(crate) struct Detector {
    samples: usize,
    sample_rate_hz: f64,
    fft: Arc<dyn RealToComplex<f64>>,
    input: Vec<f64>,
    scratch: Vec<Complex64>,
    window: Vec<f64>,
    window_sum_all: f64,
    window_sq_sum_all: f64,
    /// Over the valid samples of the current window.
    window_sum: f64,
    window_sq_sum: f64,
    /// The DFT of the plain samples, less their mean, invalid ones zeroed.
    plain: [Vec<Complex64>; 3],
    /// The Hann-windowed DFT.
    spectrum: [Vec<Complex64>; 3],
    power: [Vec<f64>; 3],
    /// Mean periodogram power of the broadband floor, per bin.
    floor: [Vec<f64>; 3],
    /// The bits of the powers under one median: positive floats order as their bits.
    median_scratch: Vec<u64>,
    /// Every whole hop block of one axis' powers, sorted (as bits).
    sorted_blocks: Vec<[u64; FLOOR_HOP_BINS]>,
    node_floor: Vec<f64>,
    /// Per bin: sum over the axes of power / floor, and its largest term.
    ratio_sum: Vec<f64>,
    ratio_max: Vec<f64>,
    candidates: [(f64, usize); MAX_CANDIDATES],
}

impl Detector {
    pub(crate) fn new(
        samples: usize,
        sample_rate_hz: f64,
        planner: &mut RealFftPlanner<f64>,
    ) -> Self {
        let fft = planner.plan_fft_forward(samples);
        let bins = samples / 2 + 1;
        // Periodic Hann (the DFT-even form), as Grandke's formula assumes.
        let window = crate::welch::periodic_hann(samples);
        let window_sum_all = window.iter().sum();
        let window_sq_sum_all = window.iter().map(|w| w * w).sum();
        Self {
            samples,
            sample_rate_hz,
            input: fft.make_input_vec(),
            scratch: fft.make_scratch_vec(),
            plain: std::array::from_fn(|_| fft.make_output_vec()),
            spectrum: std::array::from_fn(|_| fft.make_output_vec()),
            fft,
            window,
            window_sum_all,
            window_sq_sum_all,
            window_sum: window_sum_all,
            window_sq_sum: window_sq_sum_all,
            power: std::array::from_fn(|_| vec![0.0; bins]),
            floor: std::array::from_fn(|_| vec![0.0; bins]),
            median_scratch: vec![0; FLOOR_SPAN_BINS],
            sorted_blocks: vec![[0; FLOOR_HOP_BINS]; bins / FLOOR_HOP_BINS],
            node_floor: vec![0.0; floor_nodes(bins)],
            ratio_sum: vec![0.0; bins],
            ratio_max: vec![0.0; bins],
            candidates: [(0.0, 0); MAX_CANDIDATES],
        }
    }

    /// Finds up to `max_tones` tones in bins `tone_bins[0]..=tone_bins[1]` whose SNR
    /// passes `threshold` (a power ratio) on at least one axis. `x` holds the window
    /// with invalid samples zeroed; `invalid` lists them.
    pub(crate) fn run(
        &mut self,
        x: [&[f64]; 3],
        invalid: &[u32],
        tone_bins: [usize; 2],
        max_tones: usize,
        threshold: f64,
        out: &mut FixedList<Detected, MAX_TONES>,
    ) -> Result<()> {
        out.clear();
        self.window_sum = self.window_sum_all;
        self.window_sq_sum = self.window_sq_sum_all;
        for &i in invalid {
            let w = self.window[i as usize];
            self.window_sum -= w;
            self.window_sq_sum -= w * w;
        }
        self.spectra(x, invalid)?;
        if max_tones == 0 || tone_bins[0] > tone_bins[1] || self.window_sum <= 0.0 {
            return Ok(());
        }
        let count = self.collect_candidates(tone_bins, threshold);
        for c in 0..count {
            if out.len() >= max_tones {
                break;
            }
            let k = self.candidates[c].1;
            let Some(tone) = self.interpolate(k) else {
                continue;
            };
            let snr = self.snr(&tone.amplitude_g, k);
            let passes: [bool; 3] = std::array::from_fn(|a| snr[a] >= threshold);
            if !passes.iter().any(|p| *p) {
                continue;
            }
            if self.is_leakage(k, &tone, &passes, out) {
                continue;
            }
            out.push(tone);
        }
        Ok(())
    }

    /// Per axis: the plain DFT, the Hann-windowed one, its powers and its floor. Its
    /// per-bin loops run in an AVX2 copy where the CPU has it (four wide instead of
    /// two): the same IEEE operations (no FMA), so the same numbers bit for bit.
    fn spectra(&mut self, x: [&[f64]; 3], invalid: &[u32]) -> Result<()> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, the only feature this copy is compiled for.
            return unsafe { self.spectra_avx2(x, invalid) };
        }
        self.spectra_portable(x, invalid)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn spectra_avx2(&mut self, x: [&[f64]; 3], invalid: &[u32]) -> Result<()> {
        self.spectra_portable(x, invalid)
    }

    #[inline(always)]
    fn spectra_portable(&mut self, x: [&[f64]; 3], invalid: &[u32]) -> Result<()> {
        let n = self.samples;
        let valid = (n - invalid.len()) as f64;
        for a in 0..3 {
            // Invalid samples are 0 in x: the mean over the valid ones is sum / valid.
            let mean = crate::sums::sum(&x[a][..n]) / valid;
            for (inp, v) in self.input.iter_mut().zip(&x[a][..n]) {
                *inp = v - mean;
            }
            for &i in invalid {
                self.input[i as usize] = 0.0;
            }
            self.fft.process_with_scratch(
                &mut self.input,
                &mut self.plain[a],
                &mut self.scratch,
            )?;
            hann_in_frequency(&self.plain[a], n, &mut self.spectrum[a], &mut self.power[a]);
            sort_blocks(&self.power[a], &mut self.sorted_blocks);
            estimate_floor(
                &self.power[a],
                &self.sorted_blocks,
                &mut self.floor[a],
                &mut self.median_scratch,
                &mut self.node_floor,
            );
        }
        Ok(())
    }

    /// Local maxima of the summed power-to-floor ratio that could pass the threshold,
    /// strongest first, in `self.candidates`; returns how many.
    fn collect_candidates(&mut self, tone_bins: [usize; 2], threshold: f64) -> usize {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, the only feature this copy is compiled for.
            return unsafe { self.collect_candidates_avx2(tone_bins, threshold) };
        }
        self.collect_candidates_portable(tone_bins, threshold)
    }

    /// [`Self::collect_candidates`] compiled for AVX2, as [`Self::spectra`].
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn collect_candidates_avx2(&mut self, tone_bins: [usize; 2], threshold: f64) -> usize {
        self.collect_candidates_portable(tone_bins, threshold)
    }

    #[inline(always)]
    fn collect_candidates_portable(&mut self, tone_bins: [usize; 2], threshold: f64) -> usize {
        let last_bin = self.samples / 2;
        let (lo, hi) = (tone_bins[0].max(1), tone_bins[1].min(last_bin - 1));
        if lo > hi {
            return 0;
        }
        // Axis by axis over the bins (the divisions vectorise); the same sums and
        // maxima as bin by bin, in the same order. Powers are >= 0: a NaN ratio
        // (a NaN power) is passed over, as `f64::max` would.
        let bins = lo - 1..=hi + 1;
        self.ratio_sum[bins.clone()].fill(0.0);
        self.ratio_max[bins.clone()].fill(0.0);
        for a in 0..3 {
            let terms = self.ratio_sum[bins.clone()]
                .iter_mut()
                .zip(&mut self.ratio_max[bins.clone()])
                .zip(
                    self.power[a][bins.clone()]
                        .iter()
                        .zip(&self.floor[a][bins.clone()]),
                );
            for ((sum, max), (&p, &f)) in terms {
                let r = if f > 0.0 { p / f } else { 0.0 };
                *sum += r;
                *max = if r > *max { r } else { *max };
            }
        }
        let mut count = 0;
        for k in lo..=hi {
            let here = self.ratio_sum[k];
            if self.ratio_max[k] * SCALLOPED_SNR_PER_RATIO < threshold
                || here < self.ratio_sum[k - 1]
                || here <= self.ratio_sum[k + 1]
            {
                continue;
            }
            // Insert into the descending list, dropping the weakest when full.
            let mut pos = count;
            while pos > 0 && self.candidates[pos - 1].0 < here {
                pos -= 1;
            }
            if pos >= MAX_CANDIDATES {
                continue;
            }
            let end = count.min(MAX_CANDIDATES - 1);
            self.candidates.copy_within(pos..end, pos + 1);
            self.candidates[pos] = (here, k);
            count = (count + 1).min(MAX_CANDIDATES);
        }
        count
    }

    /// Grandke's interpolation around peak bin `k`, the axes weighted by their excess
    /// power over the floor (a tone on one axis only is located by that axis).
    fn interpolate(&self, k: usize) -> Option<Detected> {
        let mut sum_w = 0.0;
        let mut sum_wd = 0.0;
        for a in 0..3 {
            let p0 = self.spectrum[a][k].norm();
            if p0 <= 0.0 || self.floor[a][k] <= 0.0 {
                continue;
            }
            let left = self.spectrum[a][k - 1].norm();
            let right = self.spectrum[a][k + 1].norm();
            let delta = if right >= left {
                let alpha = right / p0;
                (2.0 * alpha - 1.0) / (alpha + 1.0)
            } else {
                let alpha = left / p0;
                -(2.0 * alpha - 1.0) / (alpha + 1.0)
            };
            let w = (self.power[a][k] / self.floor[a][k] - 1.0).max(0.0);
            sum_w += w;
            sum_wd += w * delta;
        }
        if sum_w <= 0.0 {
            return None;
        }
        // k is a local maximum of the summed spectrum: the tone is within half a bin,
        // and noise may push the ratio estimate a little beyond.
        let delta = (sum_wd / sum_w).clamp(-0.6, 0.6);
        let kernel = hann_kernel(delta);
        let amplitude_g =
            std::array::from_fn(|a| 2.0 * self.spectrum[a][k].norm() / (self.window_sum * kernel));
        Some(Detected {
            bin: k as f64 + delta,
            amplitude_g,
        })
    }

    /// Tone SNR per axis of amplitudes `amplitude_g` against the floor at bin `k`.
    fn snr(&self, amplitude_g: &[f64; 3], k: usize) -> [f64; 3] {
        std::array::from_fn(|a| {
            let floor = self.floor_psd_at_bin(a, k as f64);
            0.5 * amplitude_g[a] * amplitude_g[a] / (floor * self.resolution_hz())
        })
    }

    /// Whether the peak at `k` is explained by the leakage of a stronger, already
    /// accepted tone on every axis where it passes the threshold.
    fn is_leakage(
        &self,
        k: usize,
        tone: &Detected,
        passes: &[bool; 3],
        accepted: &FixedList<Detected, MAX_TONES>,
    ) -> bool {
        let mut own_axis = [true; 3];
        for other in accepted.iter() {
            let d = (tone.bin - other.bin).abs();
            if d < MIN_SEPARATION_BINS {
                return true;
            }
            // Hann sidelobe envelope |W(d)| <= 1 / (pi d (d^2 - 1)), in power.
            let envelope = (1.0 / (PI * d * (d * d - 1.0))).powi(2);
            for a in 0..3 {
                let peak = (0.5 * other.amplitude_g[a] * self.window_sum).powi(2);
                if self.power[a][k] < LEAKAGE_MARGIN * envelope * peak {
                    own_axis[a] = false;
                }
            }
        }
        !(0..3).any(|a| passes[a] && own_axis[a])
    }

    /// The DFT of `axis`' plain samples (less their mean, invalid ones zeroed) in the
    /// last window: bins `0..=N/2`.
    pub(crate) fn plain_spectrum(&self, axis: usize) -> &[Complex64] {
        &self.plain[axis]
    }

    /// Bin width of the window's DFT.
    pub(crate) fn resolution_hz(&self) -> f64 {
        self.sample_rate_hz / self.samples as f64
    }

    /// One-sided PSD of the broadband floor of `axis` at fractional bin `bin`, in the
    /// measured units (g^2/Hz, before any response correction).
    pub(crate) fn floor_psd_at_bin(&self, axis: usize, bin: f64) -> f64 {
        let floor = &self.floor[axis];
        let last = floor.len() - 1;
        let b = bin.clamp(0.0, last as f64);
        let i = (b.floor() as usize).min(last);
        let j = (i + 1).min(last);
        let t = b - i as f64;
        let p = floor[i] * (1.0 - t) + floor[j] * t;
        2.0 * p / (self.sample_rate_hz * self.window_sq_sum)
    }
}

/// The periodic Hann window applied to the one-sided DFT `plain` of `n` real samples:
/// `0.5 X[k] - 0.25 (X[k-1] + X[k+1])`, the bins beyond the ends being the conjugates
/// of those inside (`X[-1] = X[1]*`, `X[N/2+1] = X[N/2-1]*`); and each bin's power.
#[inline(always)]
fn hann_in_frequency(plain: &[Complex64], n: usize, out: &mut [Complex64], power: &mut [f64]) {
    let last = plain.len() - 1;
    let at = |k: usize| plain[k];
    let below = |k: usize| {
        if k == 0 {
            plain[1.min(last)].conj()
        } else {
            plain[k - 1]
        }
    };
    let above = |k: usize| {
        if k < last {
            plain[k + 1]
        } else if n % 2 == 0 {
            // Even N: bin N/2 + 1 is the conjugate of N/2 - 1.
            plain[last.saturating_sub(1)].conj()
        } else {
            // Odd N: bin (N + 1) / 2 is the conjugate of (N - 1) / 2.
            plain[last].conj()
        }
    };
    let ends = [
        (0, 0.5 * at(0) - 0.25 * (below(0) + above(0))),
        (last, 0.5 * at(last) - 0.25 * (below(last) + above(last))),
    ];
    if last > 1 {
        let inner = out[1..last].iter_mut().zip(&mut power[1..last]);
        for ((o, p), x) in inner.zip(plain.windows(3)) {
            let c = 0.5 * x[1] - 0.25 * (x[0] + x[2]);
            *o = c;
            *p = c.norm_sqr();
        }
    }
    for (k, c) in ends {
        out[k] = c;
        power[k] = c.norm_sqr();
    }
}

/// Normalised Hann kernel `|W(delta)| / |W(0)| = |sinc(delta) / (1 - delta^2)|`.
fn hann_kernel(delta: f64) -> f64 {
    if delta.abs() < 1e-9 {
        return 1.0;
    }
    let x = PI * delta;
    (x.sin() / x / (1.0 - delta * delta)).abs()
}

/// Number of running-median nodes for `bins` bins: every `FLOOR_HOP_BINS`-th bin and
/// the last.
fn floor_nodes(bins: usize) -> usize {
    bins.saturating_sub(1).div_ceil(FLOOR_HOP_BINS) + 1
}

/// Running-median floor (see the module docs). `sorted` holds the whole hop blocks of
/// `power` sorted ([`sort_blocks`]), `node_floor` one value per node
/// ([`floor_nodes`]), `scratch` at least `FLOOR_SPAN_BINS` values.
#[inline(always)]
fn estimate_floor(
    power: &[f64],
    sorted: &[[u64; FLOOR_HOP_BINS]],
    floor: &mut [f64],
    scratch: &mut [u64],
    node_floor: &mut [f64],
) {
    let bins = power.len();
    if bins == 0 {
        return;
    }
    let span = FLOOR_SPAN_BINS.min(bins);
    let nodes = floor_nodes(bins).min(node_floor.len());
    for (n, nf) in node_floor[..nodes].iter_mut().enumerate() {
        let centre = (n * FLOOR_HOP_BINS).min(bins - 1);
        // A full span around the centre, shifted inwards at the ends.
        let lo = centre.saturating_sub(span / 2).min(bins - span);
        let mid = span / 2;
        // Powers are squared magnitudes, >= +0: their bits order as the values do, and
        // integer comparisons are about twice as fast as `total_cmp`.
        let block = lo / FLOOR_HOP_BINS;
        let median =
            if span == 2 * FLOOR_HOP_BINS && lo % FLOOR_HOP_BINS == 0 && block + 1 < sorted.len() {
                // The same element of rank `mid` as a selection over the span, read off
                // its two sorted halves (a span on the hop grid is two whole blocks).
                rank_of_two_sorted(&sorted[block], &sorted[block + 1], mid)
            } else {
                let s = &mut scratch[..span];
                for (b, p) in s.iter_mut().zip(&power[lo..lo + span]) {
                    *b = p.to_bits();
                }
                *s.select_nth_unstable(mid).1
            };
        *nf = f64::from_bits(median) / std::f64::consts::LN_2;
    }
    // Linear between the nodes, one hop at a time (one division per hop, not per bin);
    // beyond the last node, its value.
    for i in 0..nodes {
        let ci = i * FLOOR_HOP_BINS;
        if ci >= bins {
            break;
        }
        let end = if i + 1 < nodes {
            (ci + FLOOR_HOP_BINS).min(bins)
        } else {
            bins
        };
        let j = (i + 1).min(nodes - 1);
        let cj = (j * FLOOR_HOP_BINS).min(bins - 1);
        let (fi, fj) = (node_floor[i], node_floor[j]);
        let hop = &mut floor[ci..end];
        if cj > ci {
            // `d < end - ci <= cj - ci + 1`: `t` stays within [0, 1].
            let per_bin = 1.0 / (cj - ci) as f64;
            for (d, f) in hop.iter_mut().enumerate() {
                let t = d as f64 * per_bin;
                *f = fi * (1.0 - t) + fj * t;
            }
        } else {
            hop.fill(fi);
        }
    }
}

/// Batcher's odd-even merge sort of 16 elements: 63 compare-exchanges in a fixed
/// order (branch-free: a median's blocks are random, so an insertion sort's branches
/// mispredict). The pairs are handed to `$then!` after `$args`: the one list for the
/// table below and for the lanes of `sort_blocks_avx2`, which need it written out.
macro_rules! sort16_network {
    ($then:ident ! ($($args:tt)*)) => {
        $then!($($args)*
            (0, 1), (2, 3), (0, 2), (1, 3), (1, 2), (4, 5), (6, 7), (4, 6),
            (5, 7), (5, 6), (0, 4), (2, 6), (2, 4), (1, 5), (3, 7), (3, 5),
            (1, 2), (3, 4), (5, 6), (8, 9), (10, 11), (8, 10), (9, 11), (9, 10),
            (12, 13), (14, 15), (12, 14), (13, 15), (13, 14), (8, 12), (10, 14), (10, 12),
            (9, 13), (11, 15), (11, 13), (9, 10), (11, 12), (13, 14), (0, 8), (4, 12),
            (4, 8), (2, 10), (6, 14), (6, 10), (2, 4), (6, 8), (10, 12), (1, 9),
            (5, 13), (5, 9), (3, 11), (7, 15), (7, 11), (3, 5), (7, 9), (11, 13),
            (1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14)
        )
    };
}

macro_rules! pair_table {
    ($(($i:literal, $j:literal)),*) => {
        [$(($i, $j)),*]
    };
}

/// `sort16_network!` as a table.
const SORT16_NETWORK: [(usize, usize); 63] = sort16_network!(pair_table!());

/// Every whole hop block of `power` (>= +0, finite) sorted, as bits, into `sorted`
/// (as many as it holds). With AVX2 four blocks go through the network at once, one
/// in each lane; the sorted multiset is the same however it is sorted.
fn sort_blocks(power: &[f64], sorted: &mut [[u64; FLOOR_HOP_BINS]]) {
    let blocks = (power.len() / FLOOR_HOP_BINS).min(sorted.len());
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        done = blocks - blocks % 4;
        // SAFETY: AVX2 is present (checked above).
        unsafe { sort_blocks_avx2(&power[..done * FLOOR_HOP_BINS], &mut sorted[..done]) };
    }
    for (b, out) in sorted[..blocks].iter_mut().enumerate().skip(done) {
        *out = sorted_bits(&power[b * FLOOR_HOP_BINS..(b + 1) * FLOOR_HOP_BINS]);
    }
}

/// [`sort_blocks`] for a whole number of groups of four blocks: block `4g + j` in
/// lane `j`. `min_pd`/`max_pd` order non-negative finite doubles as their bits do
/// (the powers are squared magnitudes: never NaN, never -0).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn sort_blocks_avx2(power: &[f64], sorted: &mut [[u64; FLOOR_HOP_BINS]]) {
    use std::arch::x86_64::*;
    macro_rules! network {
        ($v:ident; $(($i:literal, $j:literal)),*) => {
            $(
                let (x, y) = ($v[$i], $v[$j]);
                $v[$i] = _mm256_min_pd(x, y);
                $v[$j] = _mm256_max_pd(x, y);
            )*
        };
    }
    for (g, out) in sorted.chunks_exact_mut(4).enumerate() {
        let p = &power[g * 4 * FLOOR_HOP_BINS..(g + 1) * 4 * FLOOR_HOP_BINS];
        let mut v: [__m256d; FLOOR_HOP_BINS] = std::array::from_fn(|i| {
            _mm256_set_pd(
                p[3 * FLOOR_HOP_BINS + i],
                p[2 * FLOOR_HOP_BINS + i],
                p[FLOOR_HOP_BINS + i],
                p[i],
            )
        });
        // The network written out, so that the lanes stay in registers.
        sort16_network!(network!(v;));
        let mut lanes = [0.0f64; 4];
        for (i, vi) in v.iter().enumerate() {
            _mm256_storeu_pd(lanes.as_mut_ptr(), *vi);
            for (block, lane) in out.iter_mut().zip(lanes) {
                block[i] = lane.to_bits();
            }
        }
    }
}

/// One hop block of powers (`FLOOR_HOP_BINS` of them, >= +0) as sorted bits.
#[inline]
fn sorted_bits(power: &[f64]) -> [u64; FLOOR_HOP_BINS] {
    let mut b = [0u64; FLOOR_HOP_BINS];
    for (b, p) in b.iter_mut().zip(power) {
        *b = p.to_bits();
    }
    for &(i, j) in SORT16_NETWORK.iter() {
        let (x, y) = (b[i], b[j]);
        b[i] = x.min(y);
        b[j] = x.max(y);
    }
    b
}

/// The element of rank `k` (from 0) of the multiset union of the sorted `a` and `b`,
/// `k < a.len() + b.len()`: the number `i` of the `k` smallest that come from `a` by
/// bisection (the smallest `i` with `a[i] >= b[k - i - 1]`), then the smaller of the
/// next ones.
fn rank_of_two_sorted(a: &[u64], b: &[u64], k: usize) -> u64 {
    let (mut lo, mut hi) = (k.saturating_sub(b.len()), k.min(a.len()));
    while lo < hi {
        let i = (lo + hi) / 2;
        if a[i] < b[k - i - 1] {
            lo = i + 1;
        } else {
            hi = i;
        }
    }
    match (a.get(lo), b.get(k - lo)) {
        (Some(&x), Some(&y)) => x.min(y),
        (Some(&x), None) => x,
        (None, Some(&y)) => y,
        (None, None) => u64::MAX,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::{next, uniform};

    /// The window applied in frequency against the Hann-windowed samples' FFT, for
    /// even and odd lengths, with a tone near DC and one at the Nyquist end.
    #[test]
    fn hann_in_frequency_is_the_windowed_fft() {
        for n in [2usize, 3, 16, 17, 1000, 1001, 25_600] {
            let mut planner = RealFftPlanner::<f64>::new();
            let fft = planner.plan_fft_forward(n);
            let window = crate::welch::periodic_hann(n);
            let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ n as u64;
            let x: Vec<f64> = (0..n)
                .map(|k| {
                    let t = k as f64;
                    uniform(&mut state) - 0.5 + 3.0 * (0.31 * t).cos() + 2.0 * (3.1 * t + 0.4).sin()
                })
                .collect();
            let mut plain_in = x.clone();
            let mut plain = fft.make_output_vec();
            fft.process(&mut plain_in, &mut plain).unwrap();
            let mut windowed_in: Vec<f64> = x.iter().zip(&window).map(|(v, w)| v * w).collect();
            let mut want = fft.make_output_vec();
            fft.process(&mut windowed_in, &mut want).unwrap();
            let mut got = fft.make_output_vec();
            let mut power = vec![0.0; got.len()];
            hann_in_frequency(&plain, n, &mut got, &mut power);
            let scale = want.iter().map(|c| c.norm()).fold(0.0, f64::max);
            for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!((g - w).norm() <= 1e-12 * scale, "n {n} bin {k}: {g} vs {w}");
                assert_eq!(power[k], g.norm_sqr());
            }
        }
    }

    /// The floor between the medians is the straight line through them, bin by bin
    /// (the interpolation written per bin, as it was), held beyond the last.
    #[test]
    fn floor_is_linear_between_its_medians() {
        for bins in [1usize, 2, 17, 33, 100, 12_801] {
            let mut state = 0x6a09_e667_f3bc_c908u64 ^ bins as u64;
            let power: Vec<f64> = (0..bins).map(|_| uniform(&mut state)).collect();
            let mut sorted = vec![[0u64; FLOOR_HOP_BINS]; bins / FLOOR_HOP_BINS];
            sort_blocks(&power, &mut sorted);
            let mut floor = vec![f64::NAN; bins];
            let mut scratch = vec![0u64; FLOOR_SPAN_BINS];
            let nodes = floor_nodes(bins);
            let mut node_floor = vec![0.0; nodes];
            estimate_floor(&power, &sorted, &mut floor, &mut scratch, &mut node_floor);
            for (k, f) in floor.iter().enumerate() {
                let i = (k / FLOOR_HOP_BINS).min(nodes - 1);
                let j = (i + 1).min(nodes - 1);
                let (ci, cj) = (i * FLOOR_HOP_BINS, (j * FLOOR_HOP_BINS).min(bins - 1));
                let t = if cj > ci {
                    ((k - ci) as f64 / (cj - ci) as f64).min(1.0)
                } else {
                    0.0
                };
                let want = node_floor[i] * (1.0 - t) + node_floor[j] * t;
                assert!(
                    (f - want).abs() <= 1e-15 * want.abs(),
                    "bins {bins} k {k}: {f} vs {want}"
                );
            }
        }
    }

    /// The sorting network against a sort, with ties and without.
    #[test]
    fn sort16_network_sorts() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for trial in 0..5000 {
            let distinct = if trial % 2 == 0 { 3 } else { u64::MAX };
            let powers: [f64; 16] =
                std::array::from_fn(|_| (next(&mut state) % distinct) as f64 * 0.37);
            let mut want: Vec<u64> = powers.iter().map(|p| p.to_bits()).collect();
            want.sort_unstable();
            assert_eq!(super::sorted_bits(&powers).to_vec(), want);
        }
    }

    /// The blocks sorted four at a time (AVX2 lanes, the network written out) and one
    /// at a time against a plain sort, with ties and zeros, for lengths with blocks
    /// and bins left over.
    #[test]
    fn blocks_sorted_in_lanes_are_sorted() {
        let mut state = 0x51_7cc1_b727_220au64;
        for (trial, bins) in [0usize, 15, 16, 63, 64, 65, 16 * 13 + 5, 12801]
            .into_iter()
            .enumerate()
        {
            let distinct = if trial % 2 == 0 { 4 } else { u64::MAX };
            let power: Vec<f64> = (0..bins)
                .map(|_| (next(&mut state) % distinct) as f64 * 0.37)
                .collect();
            let mut sorted = vec![[0u64; FLOOR_HOP_BINS]; bins / FLOOR_HOP_BINS];
            super::sort_blocks(&power, &mut sorted);
            for (b, got) in sorted.iter().enumerate() {
                let mut want: Vec<u64> = power[16 * b..16 * b + 16]
                    .iter()
                    .map(|p| p.to_bits())
                    .collect();
                want.sort_unstable();
                assert_eq!(got.to_vec(), want, "{bins} bins, block {b}");
            }
        }
    }

    /// The rank selection over two sorted halves against a plain sort of the whole,
    /// with ties (a few distinct values) and without.
    #[test]
    fn rank_of_two_sorted_matches_a_sort() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || next(&mut state);
        for trial in 0..2000 {
            let distinct = if trial % 2 == 0 { 4 } else { u64::MAX };
            let (na, nb) = (1 + (next() % 20) as usize, 1 + (next() % 20) as usize);
            let mut a: Vec<u64> = (0..na).map(|_| next() % distinct).collect();
            let mut b: Vec<u64> = (0..nb).map(|_| next() % distinct).collect();
            let mut all: Vec<u64> = a.iter().chain(&b).copied().collect();
            a.sort_unstable();
            b.sort_unstable();
            all.sort_unstable();
            for (k, want) in all.iter().enumerate() {
                assert_eq!(
                    super::rank_of_two_sorted(&a, &b, k),
                    *want,
                    "{a:?} {b:?} {k}"
                );
            }
        }
    }

    #[test]
    fn hann_kernel_has_the_known_scalloping_loss() {
        // Hann scalloping loss at half a bin: 1.42 dB (Harris 1978, Table 1).
        let loss_db = -20.0 * hann_kernel(0.5).log10();
        assert!((loss_db - 1.4243).abs() < 1e-3, "{loss_db}");
    }

    #[test]
    fn grandke_interpolation_is_exact_for_one_clean_tone() {
        let n = 4096;
        let mut planner = RealFftPlanner::new();
        let mut d = Detector::new(n, 4096.0, &mut planner);
        for &pos in &[100.0, 100.25, 100.5, 100.8, 333.37] {
            let x: Vec<f64> = (0..n)
                .map(|k| 0.7 * (2.0 * PI * pos * k as f64 / n as f64 + 0.3).sin())
                .collect();
            let zero = vec![0.0; n];
            let mut out = FixedList::new();
            d.run([&x, &zero, &zero], &[], [4, 2040], 4, 100.0, &mut out)
                .unwrap();
            assert_eq!(out.len(), 1, "pos {pos}");
            assert!((out[0].bin - pos).abs() < 2e-3, "{} vs {pos}", out[0].bin);
            assert!(
                (out[0].amplitude_g[0] - 0.7).abs() < 2e-3,
                "{:?}",
                out[0].amplitude_g
            );
        }
    }

    #[test]
    fn floor_of_a_flat_power_spectrum_is_that_power() {
        for bins in [1, 7, 32, 33, 1000, 1001] {
            let power = vec![2.0; bins];
            let mut floor = vec![0.0; bins];
            let mut scratch = vec![0u64; FLOOR_SPAN_BINS];
            let mut nodes = vec![0.0; floor_nodes(bins)];
            let mut sorted = vec![[0u64; FLOOR_HOP_BINS]; bins / FLOOR_HOP_BINS];
            sort_blocks(&power, &mut sorted);
            estimate_floor(&power, &sorted, &mut floor, &mut scratch, &mut nodes);
            assert!(floor
                .iter()
                .all(|f| (f - 2.0 / std::f64::consts::LN_2).abs() < 1e-12));
        }
    }

    /// A step in the spectrum (a random band starting at bin 20): the floor follows it
    /// within half a span, so bins 0..12 see the low side (the old 64-bin blocks gave
    /// the whole of 0..63 the high side's floor).
    #[test]
    fn floor_follows_a_step_in_the_spectrum() {
        let bins = 12_801;
        let power: Vec<f64> = (0..bins).map(|k| if k < 20 { 0.01 } else { 1.0 }).collect();
        let mut floor = vec![0.0; bins];
        let mut scratch = vec![0u64; FLOOR_SPAN_BINS];
        let mut nodes = vec![0.0; floor_nodes(bins)];
        let mut sorted = vec![[0u64; FLOOR_HOP_BINS]; bins / FLOOR_HOP_BINS];
        sort_blocks(&power, &mut sorted);
        estimate_floor(&power, &sorted, &mut floor, &mut scratch, &mut nodes);
        let ln2 = std::f64::consts::LN_2;
        for k in 0..=12 {
            assert!(
                (floor[k] - 0.01 / ln2).abs() < 1e-12,
                "bin {k}: {}",
                floor[k]
            );
        }
        for k in 40..bins {
            assert!(
                (floor[k] - 1.0 / ln2).abs() < 1e-12,
                "bin {k}: {}",
                floor[k]
            );
        }
    }
}
