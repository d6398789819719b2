//! `VibEstimate` mirrors `vibro_dsp::Estimate`: every estimate fits (same tone and band
//! capacities) and every field has a place. The conversion below is what the estimator
//! service does; vibro-msgs itself does not depend on vibro-dsp.

use vibro_dsp::{BandEstimate, Estimate, ToneEstimate};
use vibro_msgs::{estimate_flags, VibEstimate, MAX_BANDS, MAX_TONES};

fn mirror(e: &Estimate, seq: u64) -> VibEstimate {
    let mut m = VibEstimate::ZEROED;
    m.seq = seq;
    m.index = e.index;
    m.start_ns = e.start_ns;
    m.end_ns = e.end_ns;
    m.center_ns = e.center_ns;
    m.samples = e.samples as u32;
    m.valid_samples = e.valid_samples as u32;
    m.saturated_samples = e.saturated_samples.map(|s| s as u32);
    let b = &e.broadband;
    m.broadband_f_lo_hz = b.f_lo_hz;
    m.broadband_f_hi_hz = b.f_hi_hz;
    m.broadband_rms_g = b.rms_g;
    m.broadband_rms_u_g = b.rms_u_g;
    m.broadband_covariance_g2 = b.covariance_g2;
    m.broadband_covariance_u_g2 = b.covariance_u_g2;
    m.broadband_kurtosis = b.kurtosis;
    m.broadband_kurtosis_u = b.kurtosis_u;
    m.broadband_welch_segments = b.welch_segments as u32;
    m.welch_segment_samples = b.welch_segment_samples as u32;
    for (k, t) in e.tones.iter().enumerate() {
        m.tone_frequency_hz[k] = t.frequency_hz;
        m.tone_frequency_u_hz[k] = t.frequency_u_hz;
        m.tone_amplitude_g[k] = t.amplitude_g;
        m.tone_amplitude_u_g[k] = t.amplitude_u_g;
        m.tone_phase_rad[k] = t.phase_rad;
        m.tone_phase_u_rad[k] = t.phase_u_rad;
        m.tone_snr_db[k] = t.snr_db;
    }
    m.tone_count = e.tones.len() as u32;
    for (i, band) in e.bands.iter().enumerate() {
        m.band_f_lo_hz[i] = band.f_lo_hz;
        m.band_f_hi_hz[i] = band.f_hi_hz;
        m.band_psd_g2_per_hz[i] = band.psd_g2_per_hz;
        m.band_psd_u_g2_per_hz[i] = band.psd_u_g2_per_hz;
        m.band_rms_g[i] = band.rms_g;
    }
    m.band_count = e.bands.len() as u32;
    let f = &e.flags;
    let mut flags = 0;
    for (set, bit) in [
        (f.tone_free, estimate_flags::TONE_FREE),
        (f.gap, estimate_flags::GAP),
        (f.non_finite, estimate_flags::NON_FINITE),
        (f.out_of_order, estimate_flags::OUT_OF_ORDER),
        (f.insufficient_data, estimate_flags::INSUFFICIENT_DATA),
    ] {
        if set {
            flags |= bit;
        }
    }
    for (axis, &sat) in f.saturated.iter().enumerate() {
        if sat {
            flags |= estimate_flags::SATURATED_AXIS0 << axis;
        }
    }
    m.flags = flags;
    m
}

#[test]
fn capacities_match_the_estimator() {
    assert_eq!(MAX_TONES, vibro_dsp::MAX_TONES);
    assert_eq!(MAX_BANDS, vibro_dsp::MAX_BANDS);
}

#[test]
fn a_full_estimate_fits_field_by_field() {
    let mut e = Estimate {
        index: 9,
        start_ns: 1_000,
        end_ns: 2_000,
        center_ns: 1_500,
        samples: 8192,
        valid_samples: 8000,
        saturated_samples: [1, 0, 3],
        ..Default::default()
    };
    for k in 0..vibro_dsp::MAX_TONES {
        assert!(e.tones.push(ToneEstimate {
            frequency_hz: 12.0 + k as f64,
            amplitude_g: [1.2, 1.2, 0.5],
            phase_rad: [0.1, 0.2, 0.3],
            snr_db: [40.0, 41.0, 42.0],
            ..Default::default()
        }));
    }
    for b in 0..vibro_dsp::MAX_BANDS {
        assert!(e.bands.push(BandEstimate {
            f_lo_hz: 20.0 * (b + 1) as f64,
            f_hi_hz: 40.0 * (b + 1) as f64,
            rms_g: [0.1, 0.2, f64::NAN],
            ..Default::default()
        }));
    }
    e.broadband.rms_g = [1.4, 1.3, 1.2];
    e.broadband.covariance_g2[2][0] = 0.25;
    e.broadband.welch_segments = 15;
    e.broadband.welch_segment_samples = 6_400;
    e.flags.gap = true;
    e.flags.saturated = [true, false, true];

    let m = mirror(&e, 77);
    assert_eq!(m.tone_count, 16);
    assert_eq!(m.band_count, 16);
    assert_eq!(m.tone_frequency_hz[15], 27.0);
    assert_eq!(m.tone_snr_db[3], [40.0, 41.0, 42.0]);
    assert_eq!(m.band_f_hi_hz[15], 640.0);
    assert!(m.band_rms_g[0][2].is_nan());
    assert_eq!(m.broadband_covariance_g2[2][0], 0.25);
    assert_eq!(m.broadband_welch_segments, 15);
    assert_eq!(m.welch_segment_samples, 6_400);
    assert_eq!(m.saturated_samples, [1, 0, 3]);
    assert_eq!(
        m.flags,
        estimate_flags::GAP
            | estimate_flags::SATURATED_AXIS0
            | (estimate_flags::SATURATED_AXIS0 << 2)
    );
    assert_eq!((m.seq, m.index, m.center_ns), (77, 9, 1_500));
    use vibro_msgs::WireMessage;
    assert_eq!(m.validate(), Ok(()));
}
