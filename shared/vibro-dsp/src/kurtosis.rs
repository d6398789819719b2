//! Kurtosis of the band-limited broadband part.
//!
//! The tone-free residual of the window is band-limited to the broadband band by an
//! FFT mask over the whole window (with the response correction applied on the way),
//! then `kurtosis = m4 / m2^2` is taken over its samples. MODEL.md section 6 needs
//! `E[x^4]` of the vibration in the band; out-of-band content (sensor noise, the AC
//! coupling's low-frequency tail) would pull the value towards that content's own.
//!
//! The mask is circular: the window's ends meet, and the step there rings into the
//! first and last few milliseconds. For stationary broadband vibration this moves the
//! kurtosis by far less than its sampling error. Around invalid (zeroed) samples the
//! ringing is worse, so samples within one period of the band's lower edge of an
//! invalid sample are left out of the moments.
//!
//! Uncertainty: for a Gaussian process, `kurtosis - 3 ~ mean(He4(x/sigma))` and
//! `cov(He4(X), He4(Y)) = 24 rho^4`, so `var = 24 sum_tau rho(tau)^4 / N` (Isserlis'
//! theorem); `rho` comes from the Welch PSD of the band ([`crate::welch`]).

use crate::response::Response;
use crate::Result;
use realfft::num_complex::Complex64;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use std::sync::Arc;

pub(crate) struct Kurtosis {
    samples: usize,
    fft: Arc<dyn RealToComplex<f64>>,
    ifft: Arc<dyn ComplexToReal<f64>>,
    input: Vec<f64>,
    spectrum: Vec<Complex64>,
    output: Vec<f64>,
    scratch: Vec<Complex64>,
    iscratch: Vec<Complex64>,
    /// First and last bin of the band.
    bins: [usize; 2],
    /// `1/H` per axis over `bins`.
    inverse_gain: [Vec<Complex64>; 3],
    guard: usize,
}

impl Kurtosis {
    pub(crate) fn new(
        samples: usize,
        sample_rate_hz: f64,
        band_hz: [f64; 2],
        response: &Response,
        planner: &mut RealFftPlanner<f64>,
    ) -> Self {
        let fft = planner.plan_fft_forward(samples);
        let ifft = planner.plan_fft_inverse(samples);
        let df = sample_rate_hz / samples as f64;
        let last = samples / 2;
        // Bins whose centre lies in the band; DC never (the mean is not vibration).
        let lo = ((band_hz[0] / df).ceil() as usize).clamp(1, last);
        let hi = ((band_hz[1] / df).floor() as usize).clamp(lo, last);
        let inverse_gain = std::array::from_fn(|a| {
            (lo..=hi)
                .map(|k| response.inverse_gain(a, k as f64 * df))
                .collect()
        });
        Self {
            samples,
            input: fft.make_input_vec(),
            spectrum: fft.make_output_vec(),
            output: ifft.make_output_vec(),
            scratch: fft.make_scratch_vec(),
            iscratch: ifft.make_scratch_vec(),
            fft,
            ifft,
            bins: [lo, hi],
            inverse_gain,
            guard: (sample_rate_hz / band_hz[0]).ceil() as usize,
        }
    }

    /// Kurtosis of `residual` (the tone-free window of `axis`, invalid samples zeroed)
    /// band-limited, and the number of samples it was taken over. `invalid_prefix[k]`
    /// counts the invalid samples before `k`. NaN if fewer than a quarter of the window
    /// is usable or the band holds no power.
    pub(crate) fn run(
        &mut self,
        axis: usize,
        residual: &[f64],
        invalid_prefix: &[u32],
    ) -> Result<(f64, usize)> {
        let n = self.samples;
        self.input.copy_from_slice(&residual[..n]);
        self.fft
            .process_with_scratch(&mut self.input, &mut self.spectrum, &mut self.scratch)?;
        let [lo, hi] = self.bins;
        for (k, c) in self.spectrum.iter_mut().enumerate() {
            if k < lo || k > hi {
                *c = Complex64::new(0.0, 0.0);
            } else {
                *c *= self.inverse_gain[axis][k - lo];
            }
        }
        // A real signal's DC and Nyquist bins are real; the mask keeps them so.
        let last = self.spectrum.len() - 1;
        self.spectrum[0].im = 0.0;
        if n % 2 == 0 {
            self.spectrum[last].im = 0.0;
        }
        self.ifft
            .process_with_scratch(&mut self.spectrum, &mut self.output, &mut self.iscratch)?;

        let any_invalid = invalid_prefix[n] > 0;
        let g = self.guard;
        let usable = |k: usize| {
            !any_invalid
                || invalid_prefix[(k + g + 1).min(n)] == invalid_prefix[k.saturating_sub(g)]
        };
        let (mut count, mut sum) = (0usize, 0.0);
        if any_invalid {
            for (k, y) in self.output.iter().enumerate() {
                if usable(k) {
                    count += 1;
                    sum += y;
                }
            }
        } else {
            (count, sum) = (n, crate::sums::sum(&self.output[..n]));
        }
        if count < n / 4 || count == 0 {
            return Ok((f64::NAN, count));
        }
        let mean = sum / count as f64;
        let (mut m2, mut m4) = (0.0, 0.0);
        if any_invalid {
            for (k, y) in self.output.iter().enumerate() {
                if usable(k) {
                    let d = y - mean;
                    let d2 = d * d;
                    m2 += d2;
                    m4 += d2 * d2;
                }
            }
        } else {
            (m2, m4) = crate::sums::central_2_4(&self.output[..n], mean);
        }
        m2 /= count as f64;
        m4 /= count as f64;
        if m2 <= 0.0 || !m2.is_finite() {
            return Ok((f64::NAN, count));
        }
        Ok((m4 / (m2 * m2), count))
    }
}
