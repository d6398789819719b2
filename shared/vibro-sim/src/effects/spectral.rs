//! The vibration description seen through linear filters, for the mean formulas of
//! the filtering effects.
//!
//! Tones pass a filter `G` as `aB -> |G(f)| aB`, `phi -> phi + arg G(f)`. The random
//! part follows the simulator's spectral model: per-axis band PSDs `S_i(f)` (the
//! `psd_unit` of [`crate::MeanContext`]) and real cross-spectra of constant coherence,
//! `S_ij(f) = cov_ij * sqrt(S_i S_j) / int sqrt(S_i S_j) df`. After per-axis filters
//! `G_i` the covariance is `int Re(G_i conj(G_j)) S_ij df` (Bendat & Piersol, Random
//! Data, the input/output relations of linear systems), evaluated by composite
//! Gauss–Legendre quadrature over each band ([`super::quad`]). The kurtosis is kept:
//! the simulator's non-Gaussian vibration is a scale mixture whose scale changes far
//! more slowly than the filters respond, so a filtered mixture is the same mixture.

use super::quad::gauss_legendre;
use crate::{Error, Result};
use realfft::num_complex::Complex;
use vibro_physics::vibration::{PsdBand, Vibration};

/// Most Gauss–Legendre panels spent on one band.
const MAX_PANELS_PER_BAND: f64 = 200_000.0;

/// `(sum_b w_b int_b f df, sum_b w_b (f_hi - f_lo))`: a band-weighted integral of `f`
/// and the same weights' integral of 1, with panels no wider than `max_panel_hz`.
pub(crate) fn band_integral(
    psd: &[PsdBand],
    weight: impl Fn(&PsdBand) -> f64,
    mut f: impl FnMut(f64) -> f64,
    max_panel_hz: f64,
) -> (f64, f64) {
    let (mut num, mut den) = (0.0, 0.0);
    for b in psd {
        let w = weight(b);
        let df = b.f_hi_hz - b.f_lo_hz;
        if w == 0.0 || df.is_nan() || df <= 0.0 {
            continue;
        }
        let panels = (df / max_panel_hz).ceil().clamp(1.0, MAX_PANELS_PER_BAND) as usize;
        num += w * gauss_legendre(&mut f, b.f_lo_hz, b.f_hi_hz, panels);
        den += w * df;
    }
    (num, den)
}

/// `sqrt(S_i S_j)` of one band: the cross-spectral weight of the constant-coherence
/// model (`S_i` itself when `i == j`).
pub(crate) fn cross_weight(b: &PsdBand, i: usize, j: usize) -> f64 {
    (b.psd_g2_per_hz[i].max(0.0) * b.psd_g2_per_hz[j].max(0.0)).sqrt()
}

/// The error for a random part whose spectrum the formula needs but does not have.
pub(crate) fn no_spectrum(kind: &str, what: String) -> Error {
    Error::Invalid {
        key: format!("effect[{kind}]"),
        value: what,
        rule: "the mean of this effect under random vibration needs the vibration's band PSD \
               (MeanContext::psd_unit), which is empty or zero on that axis"
            .into(),
    }
}

/// The vibration after per-axis filters: `filtered[i]` says whether axis `i` (0 = OA,
/// 1 = PA, 2 = IA) passes `gain(i, f)`; the other axes are unchanged.
pub(crate) fn filtered_vibration(
    kind: &str,
    vib: &Vibration,
    psd: &[PsdBand],
    filtered: [bool; 3],
    gain: impl Fn(usize, f64) -> Complex<f64>,
    max_panel_hz: f64,
) -> Result<Vibration> {
    let gain = |i: usize, f: f64| {
        if filtered[i] {
            gain(i, f)
        } else {
            Complex::new(1.0, 0.0)
        }
    };
    let mut out = *vib;
    out.clear_tones();
    for t in vib.tones() {
        let mut t2 = *t;
        for i in 0..3 {
            let g = gain(i, t.freq_hz);
            t2.amplitude_g[i] *= g.norm();
            t2.phase_rad[i] += g.arg();
        }
        out.push_tone(t2)?;
    }
    let c = &vib.covariance_g2;
    for i in 0..3 {
        for j in i..3 {
            if !(filtered[i] || filtered[j]) || c[i][j] == 0.0 {
                continue;
            }
            let (num, den) = band_integral(
                psd,
                |b| cross_weight(b, i, j),
                |f| (gain(i, f) * gain(j, f).conj()).re,
                max_panel_hz,
            );
            if den.is_nan() || den <= 0.0 {
                let what = if i == j {
                    format!("sigma{}^2 = {} g^2", i + 1, c[i][i])
                } else {
                    format!("cov{}{} = {} g^2", j + 1, i + 1, c[i][j])
                };
                return Err(no_spectrum(kind, what));
            }
            out.covariance_g2[i][j] = c[i][j] * num / den;
            out.covariance_g2[j][i] = out.covariance_g2[i][j];
        }
    }
    Ok(out)
}

/// The change of the exact mean output (MODEL.md section 6, `vibro_physics::exact`)
/// when the vibration at the unit becomes `changed`: `E[FP | changed] - E[FP | as is]`.
pub(crate) fn exact_shift(ctx: &crate::MeanContext<'_>, changed: &Vibration) -> Result<f64> {
    let on = vibro_physics::exact::exact_ve(ctx.passport, ctx.a_l_unit_g, changed)?;
    let off = vibro_physics::exact::exact_ve(ctx.passport, ctx.a_l_unit_g, ctx.vibration_unit)?;
    Ok(on.total_g - off.total_g)
}

/// Checks the internal rate a discrete-time formula needs.
pub(crate) fn check_rate(kind: &str, rate_hz: f64) -> Result<()> {
    if rate_hz.is_finite() && rate_hz > 0.0 {
        Ok(())
    } else {
        Err(Error::Invalid {
            key: format!("effect[{kind}]"),
            value: format!("internal_rate_hz = {rate_hz}"),
            rule: "the discrete-time response needs a finite internal rate > 0 Hz".into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_physics::vibration::Tone;

    #[test]
    fn tones_and_bands_pass_the_gain() {
        let mut v = Vibration::none();
        v.push_tone(Tone {
            freq_hz: 10.0,
            amplitude_g: [1.0, 1.0, 2.0],
            phase_rad: [0.0; 3],
        })
        .unwrap();
        let psd = [PsdBand {
            f_lo_hz: 0.0,
            f_hi_hz: 1.0,
            psd_g2_per_hz: [1.0, 4.0, 9.0],
        }];
        v.set_random_from_psd(&psd);
        v.covariance_g2[2][1] = 3.0;
        v.covariance_g2[1][2] = 3.0;
        // Gain 1 + j f on IA: |G|^2 = 1 + f^2, averaging 4/3 over 0..1 Hz; Re G = 1.
        let out = filtered_vibration(
            "t",
            &v,
            &psd,
            [false, false, true],
            |_, f| Complex::new(1.0, f),
            0.1,
        )
        .unwrap();
        let t = out.tones()[0];
        assert!((t.amplitude_g[2] - 2.0 * 101f64.sqrt()).abs() < 1e-12);
        assert!((t.phase_rad[2] - 10f64.atan()).abs() < 1e-12);
        assert_eq!(t.amplitude_g[0], 1.0);
        assert!((out.covariance_g2[2][2] - 9.0 * 4.0 / 3.0).abs() < 1e-12);
        assert!((out.covariance_g2[2][1] - 3.0).abs() < 1e-12);
        assert_eq!(out.covariance_g2[0][0], 1.0);
        let err = filtered_vibration("t", &v, &[], [true; 3], |_, _| Complex::new(1.0, 0.0), 1.0)
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("effect[t] = sigma1^2 = 1 g^2"), "{err}");
    }
}
