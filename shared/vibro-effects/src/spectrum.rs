//! The spectrum behind an estimate's band powers: the random part of one vibration
//! estimate (the estimator's wire `VibEstimate`, sensor axes) as a piecewise-flat PSD
//! per sensor axis, solved through the Welch window's leakage
//! (`vibro_dsp::BandLeakage`), with its levels' standard uncertainties, and mapped to a
//! unit's axes. The lab reads a log's windows through it (`vibro_lab::log_table`) and
//! the compensator its live estimates (the effects' mean formulas under random
//! vibration need the spectrum, and both must see the same one): the
//! reported band PSDs lend 3 % to 6 % of a band across its edges at the 4 Hz bins of
//! 1 s estimates, which made a fitted mount resonance's effect 7 % short (docs/lab.md,
//! "Logs as input").
//!
//! ```
//! use vibro_dsp::{BandLeakage, EstimatorConfig, EstimatorConfigRaw};
//! use vibro_effects::spectrum::{sensor_spectrum, SpectrumSolver};
//! use vibro_msgs::VibEstimate;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let config = EstimatorConfig::try_from(EstimatorConfigRaw::new(25600.0, [0.1; 3]))?;
//! let mut solver = SpectrumSolver::new(BandLeakage::new(&config));
//! // An estimate without bands has no spectrum to solve.
//! assert!(sensor_spectrum(&VibEstimate::ZEROED, &mut solver).is_empty());
//! # Ok(())
//! # }
//! ```

use vibro_dsp::BandLeakage;
use vibro_msgs::{VibEstimate, MAX_BANDS};
use vibro_physics::vibration::PsdBand;

/// The random part's spectrum per sensor axis (`psd_g2_per_hz[j]` is sensor axis `j`)
/// behind the estimate's band powers: piecewise flat over the estimate's bands and over
/// the broadband band's uncovered ends (one level for both, which hold the broadband
/// power outside the bands), solved from the band powers through the Welch window's
/// leakage (`vibro_dsp::BandLeakage`: a band's reported power is its own minus what
/// its steps lend to the neighbours, 3 % to 6 % of a band at the 4 Hz bins of 1 s
/// estimates of RIG.md's flight spectrum), levels below 0 (scatter) set to 0, and
/// scaled to the broadband variance. Empty when the estimate has no bands; the
/// reported PSDs as they are when the leakage cannot be solved.
pub fn sensor_spectrum(est: &VibEstimate, solver: &mut SpectrumSolver) -> Vec<PsdBand> {
    let n = (est.band_count as usize).min(MAX_BANDS);
    if n == 0 {
        return Vec::new();
    }
    solver.adapt(est);
    let mut bands: Vec<PsdBand> = (0..n)
        .map(|b| PsdBand {
            f_lo_hz: est.band_f_lo_hz[b],
            f_hi_hz: est.band_f_hi_hz[b],
            psd_g2_per_hz: est.band_psd_g2_per_hz[b].map(|x| x.max(0.0)),
        })
        .collect();
    if bands.iter().any(|b| {
        b.f_hi_hz.partial_cmp(&b.f_lo_hz) != Some(std::cmp::Ordering::Greater)
            || b.psd_g2_per_hz.iter().any(|x| !x.is_finite())
    }) {
        return Vec::new();
    }
    let (lo, hi) = (est.broadband_f_lo_hz, est.broadband_f_hi_hz);
    let covered_lo = bands
        .iter()
        .map(|b| b.f_lo_hz)
        .fold(f64::INFINITY, f64::min);
    let covered_hi = bands.iter().map(|b| b.f_hi_hz).fold(0.0, f64::max);
    let gaps: Vec<[f64; 2]> = [[lo, covered_lo], [covered_hi, hi]]
        .into_iter()
        .filter(|[a, b]| b > a)
        .collect();
    let gap_width: f64 = gaps.iter().map(|[a, b]| b - a).sum();
    // Unknown levels: one per band, then one for the gaps.
    let mut pieces: Vec<Vec<[f64; 2]>> =
        bands.iter().map(|b| vec![[b.f_lo_hz, b.f_hi_hz]]).collect();
    if gap_width > 0.0 {
        pieces.push(gaps.clone());
    }
    let lu = solver.factor(&pieces);
    let mut gap_psd = [0.0; 3];
    for j in 0..3 {
        let total = est.broadband_rms_g[j].powi(2);
        let mut reported: Vec<f64> = bands
            .iter()
            .map(|b| b.psd_g2_per_hz[j] * (b.f_hi_hz - b.f_lo_hz))
            .collect();
        let in_bands: f64 = reported.iter().sum();
        if gap_width > 0.0 {
            reported.push(total - in_bands);
        }
        let solved = lu
            .and_then(|lu| lu.solve(&nalgebra::DVector::from_vec(reported)))
            .filter(|x| x.iter().all(|v| v.is_finite()))
            .map(|x| x.as_slice().to_vec());
        let mut level = solved.unwrap_or_else(|| {
            // Unsolvable: the reported levels, the gaps holding the remainder.
            let mut r: Vec<f64> = bands.iter().map(|b| b.psd_g2_per_hz[j]).collect();
            if gap_width > 0.0 {
                r.push((total - in_bands) / gap_width);
            }
            r
        });
        for x in &mut level {
            *x = if x.is_finite() { x.max(0.0) } else { 0.0 };
        }
        let widths = pieces
            .iter()
            .map(|p| p.iter().map(|[a, b]| b - a).sum::<f64>());
        let power: f64 = level.iter().zip(widths).map(|(s, w)| s * w).sum();
        let f = if power > 0.0 && total.is_finite() {
            total / power
        } else {
            0.0
        };
        for (b, s) in bands.iter_mut().zip(&level) {
            b.psd_g2_per_hz[j] = s * f;
        }
        if gap_width > 0.0 {
            gap_psd[j] = level[n] * f;
        }
    }
    for [a, b] in gaps {
        bands.push(PsdBand {
            f_lo_hz: a,
            f_hi_hz: b,
            psd_g2_per_hz: gap_psd,
        });
    }
    bands.sort_by(|x, y| x.f_lo_hz.total_cmp(&y.f_lo_hz));
    bands
}

/// The standard uncertainties of [`sensor_spectrum`]'s levels (same pieces), per sensor
/// axis: an estimate band's relative uncertainty as the estimate states it
/// (`band_psd_u_g2_per_hz`) kept through the leakage solution and the scaling; a piece
/// outside the bands (no stated uncertainty) takes the relative uncertainty a flat
/// spectrum's Welch estimate has over its width, `rel^2 ∝ 1 / width` (the degrees of
/// freedom grow with the bins), from the bands' own `rel_b^2 width_b`, averaged.
pub fn sensor_spectrum_u(est: &VibEstimate, spectrum: &[PsdBand]) -> Vec<PsdBand> {
    let n = (est.band_count as usize).min(MAX_BANDS);
    let rel_of_band = |b: usize, j: usize| {
        let (s, u) = (est.band_psd_g2_per_hz[b][j], est.band_psd_u_g2_per_hz[b][j]);
        (s > 0.0 && u.is_finite() && u >= 0.0).then(|| u / s)
    };
    let mut per_width = [0.0; 3];
    for j in 0..3 {
        let known: Vec<f64> = (0..n)
            .filter_map(|b| {
                rel_of_band(b, j).map(|r| r * r * (est.band_f_hi_hz[b] - est.band_f_lo_hz[b]))
            })
            .collect();
        if !known.is_empty() {
            per_width[j] = known.iter().sum::<f64>() / known.len() as f64;
        }
    }
    spectrum
        .iter()
        .map(|piece| {
            let band = (0..n).find(|&b| {
                est.band_f_lo_hz[b] == piece.f_lo_hz && est.band_f_hi_hz[b] == piece.f_hi_hz
            });
            let width = piece.f_hi_hz - piece.f_lo_hz;
            PsdBand {
                psd_g2_per_hz: std::array::from_fn(|j| {
                    let rel = match band {
                        Some(b) => rel_of_band(b, j).unwrap_or(0.0),
                        None if width > 0.0 => (per_width[j] / width).sqrt(),
                        None => 0.0,
                    };
                    rel * piece.psd_g2_per_hz[j]
                }),
                ..*piece
            }
        })
        .collect()
}

/// An LU factorization of a square matrix.
type Lu = nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>;

/// [`sensor_spectrum`]'s linear system: the leakage matrix of a set of pieces (each
/// piece's reported power from each piece's flat level, `vibro_dsp::BandLeakage`),
/// factored once and kept while the windows' bands stay the same (they do through a
/// log: the estimator's configured bands).
pub struct SpectrumSolver {
    /// `None`: the leakage is not known (the reported levels are used as they are).
    leakage: Option<BandLeakage>,
    /// Take the leakage from each estimate ([`SpectrumSolver::from_estimates`]): the
    /// sample rate and Welch segment it was made with, and the key they give.
    from_estimates: bool,
    key: Option<(u64, u32)>,
    /// The pieces the factorization is for (`None`: none made yet).
    pieces: Option<Vec<Vec<[f64; 2]>>>,
    /// Their leakage matrix's factorization (`None`: singular or not finite).
    lu: Option<Lu>,
}

/// Most samples per Welch segment an estimate may state for [`SpectrumSolver::from_estimates`]
/// to build its leakage (a table the segment long): 2^18, 10 s at 25.6 kHz. A larger
/// (forged or corrupted) value leaves the leakage unknown rather than allocating what
/// the value asks.
pub const MAX_WELCH_SEGMENT_SAMPLES: u32 = 1 << 18;

/// The sample rate (the window's samples over its span, Hz) and Welch segment an
/// estimate states, when both are usable: the segment at least 2 samples, at most the
/// window and [`MAX_WELCH_SEGMENT_SAMPLES`].
pub fn estimate_welch(est: &VibEstimate) -> Option<(f64, usize)> {
    let seg = est.welch_segment_samples;
    let span_s = est.end_ns.checked_sub(est.start_ns)? as f64 * 1e-9;
    let rate_hz = f64::from(est.samples) / span_s;
    (seg >= 2
        && seg <= est.samples
        && seg <= MAX_WELCH_SEGMENT_SAMPLES
        && rate_hz.is_finite()
        && rate_hz > 0.0)
        .then_some((rate_hz, seg as usize))
}

impl SpectrumSolver {
    /// A solver over `leakage` (the estimator configuration's Welch window and bins).
    pub fn new(leakage: BandLeakage) -> Self {
        Self {
            leakage: Some(leakage),
            from_estimates: false,
            key: None,
            pieces: None,
            lu: None,
        }
    }

    /// A solver that takes the leakage from the estimates themselves
    /// ([`estimate_welch`]: the rate and Welch segment each states), for a consumer that
    /// does not hold the estimator's configuration (the compensator). An estimate that
    /// states none (an older estimator) is read with its reported levels as they are.
    pub fn from_estimates() -> Self {
        Self {
            leakage: None,
            from_estimates: true,
            key: None,
            pieces: None,
            lu: None,
        }
    }

    /// With [`Self::from_estimates`]: the leakage of `est`'s estimator, rebuilt when it
    /// changes (rate to 1 ppm).
    fn adapt(&mut self, est: &VibEstimate) {
        if !self.from_estimates {
            return;
        }
        let welch = estimate_welch(est);
        let key = welch.map(|(rate, seg)| ((rate * 1e6).round() as u64, seg as u32));
        if key != self.key {
            self.key = key;
            self.leakage = welch.map(|(rate, seg)| BandLeakage::with_segment(rate, seg));
            self.pieces = None;
            self.lu = None;
        }
    }

    /// The LU factorization of the leakage matrix of `pieces`; `None` when it is
    /// singular or not finite, or the leakage is not known.
    fn factor(&mut self, pieces: &[Vec<[f64; 2]>]) -> Option<&Lu> {
        let leakage = self.leakage.as_ref()?;
        if self.pieces.as_deref() != Some(pieces) {
            let n = pieces.len();
            let m = nalgebra::DMatrix::from_fn(n, n, |r, c| {
                let mut sum = 0.0;
                for reported in &pieces[r] {
                    for source in &pieces[c] {
                        sum += leakage.band_power_g2(*reported, *source);
                    }
                }
                sum
            });
            let lu = m
                .iter()
                .all(|x| x.is_finite())
                .then(|| m.lu())
                .filter(|lu| lu.is_invertible());
            self.pieces = Some(pieces.to_vec());
            self.lu = lu;
        }
        self.lu.as_ref()
    }
}

/// The spectrum of unit `u` from the sensors' ([`sensor_spectrum`]): each axis reads its
/// sensor's.
pub fn unit_bands(spectrum: &[PsdBand], sensor_of_axis: &[(usize, f64); 3]) -> Vec<PsdBand> {
    spectrum
        .iter()
        .map(|b| PsdBand {
            psd_g2_per_hz: sensor_of_axis.map(|(j, _)| b.psd_g2_per_hz[j]),
            ..*b
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `[estimator]` of the shipped service configuration
    /// (`config/services/estimator.toml`).
    fn shipped_estimator() -> vibro_dsp::EstimatorConfig {
        #[derive(serde::Deserialize)]
        struct File {
            estimator: vibro_dsp::EstimatorConfigRaw,
        }
        let text = include_str!("../../../config/services/estimator.toml");
        let file: File = toml::from_str(text).unwrap();
        vibro_dsp::EstimatorConfig::try_from(file.estimator).unwrap()
    }

    /// RIG.md's flight spectrum (P1 Table 3 times the amplification squared, 1.96 g^2)
    /// on the sensor axes at 1, 0.5 and 2 times, as 1 s estimates of the shipped
    /// estimator report it in expectation (the band powers through the Welch window's
    /// leakage, `vibro_dsp::BandLeakage`, itself checked against the time-domain
    /// expectation): the spectrum behind them is recovered, where the reported PSDs are
    /// 3 % low in 40-80 Hz and 6 % high in 80-160 Hz. Those shifts made the lab's
    /// mount resonance (48 Hz, Q 1.56) under-predict its effect on `cyclone-4-short` by
    /// 7.1 +- 0.9 % over 30 seeds (docs/lab.md, "Logs as input").
    #[test]
    fn the_spectrum_behind_the_band_powers_is_recovered() {
        let leakage = BandLeakage::new(&shipped_estimator());
        let edges = [20.0, 40.0, 80.0, 160.0, 320.0, 640.0];
        let shape = [
            0.017 * 2.56,
            0.020 * 3.24,
            0.07 * 0.16,
            0.12 * 0.01,
            0.12 * 0.0025,
        ];
        let power: f64 = (0..5).map(|b| shape[b] * (edges[b + 1] - edges[b])).sum();
        let level = [1.0, 0.5, 2.0];
        let truth = |b: usize, j: usize| shape[b] * 1.96 / power * level[j];
        let mut est = VibEstimate::ZEROED;
        est.broadband_f_lo_hz = 20.0;
        est.broadband_f_hi_hz = 2000.0;
        est.band_count = 5;
        // (A spectrum solved once: the cases below change only what the estimate
        // states about its Welch segment.)
        let reported = |band: [f64; 2], j: usize| -> f64 {
            (0..5)
                .map(|c| truth(c, j) * leakage.band_power_g2(band, [edges[c], edges[c + 1]]))
                .sum()
        };
        for b in 0..5 {
            let band = [edges[b], edges[b + 1]];
            est.band_f_lo_hz[b] = band[0];
            est.band_f_hi_hz[b] = band[1];
            est.band_psd_g2_per_hz[b] = [0, 1, 2].map(|j| reported(band, j) / (band[1] - band[0]));
        }
        est.broadband_rms_g = [0, 1, 2].map(|j| reported([20.0, 2000.0], j).sqrt());
        let lent = est.band_psd_g2_per_hz[2][0] / truth(2, 0) - 1.0;
        assert!(
            (0.05..0.07).contains(&lent),
            "80-160 Hz reported {lent:+.4} off"
        );

        let mut solver = SpectrumSolver::new(leakage);
        let spectrum = sensor_spectrum(&est, &mut solver);
        // The next window's bands are the same: the factorization is reused.
        assert_eq!(sensor_spectrum(&est, &mut solver), spectrum);
        // A consumer without the estimator's configuration (the compensator) reads the
        // same spectrum from what the estimate states: its window (1 s of 25 600
        // samples) and Welch segment.
        let config = shipped_estimator();
        est.samples = 25_600;
        est.start_ns = 7_000_000_000;
        est.end_ns = 8_000_000_000;
        est.welch_segment_samples = config.segment_samples() as u32;
        let stated = sensor_spectrum(&est, &mut SpectrumSolver::from_estimates());
        for (a, b) in stated.iter().zip(&spectrum) {
            for j in 0..3 {
                let d = (a.psd_g2_per_hz[j] - b.psd_g2_per_hz[j]).abs();
                assert!(
                    d <= 1e-12 * b.psd_g2_per_hz[j].abs().max(1e-12),
                    "{a:?} {b:?}"
                );
            }
        }
        // An estimate that states no segment (an older estimator) is read with its
        // reported levels, scaled to the broadband variance.
        est.welch_segment_samples = 0;
        let unsolved = sensor_spectrum(&est, &mut SpectrumSolver::from_estimates());
        let ratio = unsolved[2].psd_g2_per_hz[0] / est.band_psd_g2_per_hz[2][0];
        assert!(
            (ratio / unsolved[0].psd_g2_per_hz[0] * est.band_psd_g2_per_hz[0][0] - 1.0).abs()
                < 1e-12
        );
        assert_eq!(spectrum.len(), 6, "{spectrum:?}");
        // Scaled to the reported broadband variance, which lost the power lent below
        // 20 Hz (0.8 %): the shape is the truth's.
        for j in 0..3 {
            let total = est.broadband_rms_g[j].powi(2);
            let scale = total / (1.96 * level[j]);
            assert!((0.985..0.995).contains(&scale), "{scale}");
            for b in 0..5 {
                let got = spectrum[b].psd_g2_per_hz[j] / scale;
                assert!(
                    (got / truth(b, j) - 1.0).abs() < 1e-4,
                    "axis {j}, {}-{} Hz: {got} against {}",
                    edges[b],
                    edges[b + 1],
                    truth(b, j)
                );
            }
            let held: f64 = spectrum
                .iter()
                .map(|b| b.psd_g2_per_hz[j] * (b.f_hi_hz - b.f_lo_hz))
                .sum();
            assert!((held / total - 1.0).abs() < 1e-12, "{held} vs {total}");
            // Nothing above 640 Hz but the leakage from below.
            assert!(spectrum[5].psd_g2_per_hz[j] < 1e-4 * truth(4, j));
        }
        // Unit axes read their sensors.
        let unit = unit_bands(&spectrum, &[(2, 1.0), (0, -1.0), (1, 1.0)]);
        assert_eq!(unit[1].psd_g2_per_hz[0], spectrum[1].psd_g2_per_hz[2]);
        assert_eq!(unit[1].psd_g2_per_hz[1], spectrum[1].psd_g2_per_hz[0]);

        // The levels' uncertainties: a band's relative one as stated; the piece above
        // the bands (1360 Hz wide) that of a flat spectrum's Welch estimate over its
        // width, rel^2 = mean(rel_b^2 width_b) / width (here rel_b^2 width_b = 4 Hz for
        // every band: rel = sqrt(4 / 1360)).
        for b in 0..5 {
            let width = edges[b + 1] - edges[b];
            est.band_psd_u_g2_per_hz[b] =
                est.band_psd_g2_per_hz[b].map(|s| s * (4.0 / width).sqrt());
        }
        let u = sensor_spectrum_u(&est, &spectrum);
        assert_eq!(u.len(), spectrum.len());
        for j in 0..3 {
            for b in 0..5 {
                let rel = u[b].psd_g2_per_hz[j] / spectrum[b].psd_g2_per_hz[j];
                let want = (4.0 / (edges[b + 1] - edges[b])).sqrt();
                assert!(
                    (rel / want - 1.0).abs() < 1e-12,
                    "band {b}: {rel} vs {want}"
                );
            }
            let rel = u[5].psd_g2_per_hz[j] / spectrum[5].psd_g2_per_hz[j];
            assert!(
                (rel / (4.0f64 / 1360.0).sqrt() - 1.0).abs() < 1e-12,
                "{rel}"
            );
        }
    }

    /// A forged or corrupted segment length never makes the consumer build a table of
    /// its size: beyond the window or [`MAX_WELCH_SEGMENT_SAMPLES`], or over a window
    /// of no span, the leakage is left unknown.
    #[test]
    fn a_stated_segment_is_used_only_within_bounds() {
        let mut est = VibEstimate::ZEROED;
        est.samples = 25_600;
        est.start_ns = 1_000_000_000;
        est.end_ns = 2_000_000_000;
        est.welch_segment_samples = 6_400;
        let (rate, seg) = estimate_welch(&est).unwrap();
        assert_eq!(seg, 6_400);
        assert!((rate - 25_600.0).abs() < 1e-9);
        for bad in [0, 1, 25_601, u32::MAX] {
            est.welch_segment_samples = bad;
            assert_eq!(estimate_welch(&est), None, "{bad}");
        }
        est.samples = u32::MAX;
        est.welch_segment_samples = MAX_WELCH_SEGMENT_SAMPLES + 1;
        assert_eq!(estimate_welch(&est), None);
        est.welch_segment_samples = 6_400;
        est.end_ns = est.start_ns;
        assert_eq!(estimate_welch(&est), None);
        est.end_ns = 0;
        assert_eq!(estimate_welch(&est), None);
    }
}
