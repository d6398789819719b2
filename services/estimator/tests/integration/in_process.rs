//! The estimator run in-process: a synthetic 3-axis signal with a known tone and known
//! broadband noise goes in as VibBlocks; the estimates must find the truth within their
//! own reported uncertainties, and every lost block must be counted.

use crate::support::{prefix, wait_until, Gaussian, Running};
use std::f64::consts::TAU;
use std::time::Duration;
use vibro_dsp::EstimatorConfigRaw;
use vibro_estimator::{Config, RawConfig};
use vibro_ipc::{create_node, StreamPublisher, StreamSubscriber};
use vibro_msgs::{
    estimate_flags, Heartbeat, ServiceId, ServiceNames, Stream, VibBlock, VibEstimate,
};
use vibro_service::{data_stream_config, estimate_stream_config, now_ns, ServiceSettingsRaw};

pub const FS_HZ: f64 = 4096.0;
pub const BLOCK: usize = 256;
pub const SENSITIVITY_V_PER_G: f64 = 0.1;
pub const TONE_HZ: f64 = 97.3;
pub const TONE_G: [f64; 3] = [0.8, 0.5, 1.2];
pub const TONE_PHASE_RAD: [f64; 3] = [0.3, 1.0, -0.5];
/// White noise over 0..fs/2, per axis.
pub const NOISE_G: f64 = 0.2;
pub const BAND_HZ: [f64; 2] = [20.0, 1000.0];

pub fn config(prefix: &str) -> Config {
    let mut estimator = EstimatorConfigRaw::new(FS_HZ, [SENSITIVITY_V_PER_G; 3]);
    estimator.broadband_band_hz = BAND_HZ;
    Config::try_from(RawConfig {
        prefix: prefix.to_string(),
        service: ServiceSettingsRaw {
            heartbeat_period_s: 0.1,
            ..ServiceSettingsRaw::default()
        },
        estimator,
    })
    .expect("valid configuration")
}

/// Block `k` of the synthetic signal, in volts.
fn block(k: u64, noise: &mut Gaussian) -> VibBlock {
    let mut b = VibBlock::ZEROED;
    b.seq = k;
    b.first_sample_index = k * BLOCK as u64;
    // 256 samples at 4096 Hz: exactly 62.5 ms per block.
    b.t0_ns = k * 62_500_000;
    b.sample_period_ns = (1e9 / FS_HZ).round() as u64;
    b.count = BLOCK as u32;
    for i in 0..BLOCK {
        let t_s = (b.first_sample_index + i as u64) as f64 / FS_HZ;
        for a in 0..3 {
            let g = TONE_G[a] * (TAU * TONE_HZ * t_s + TONE_PHASE_RAD[a]).sin()
                + NOISE_G * noise.next();
            b.sample_v[i][a] = g * SENSITIVITY_V_PER_G;
        }
    }
    b
}

pub fn within(what: &str, got: f64, want: f64, u: f64, k: f64) {
    assert!(
        u.is_finite() && u > 0.0 && (got - want).abs() <= k * u,
        "{what}: {got} vs truth {want}, |error| = {:.3e} > {k} u = {:.3e}",
        (got - want).abs(),
        k * u
    );
}

#[test]
fn estimates_a_tone_in_noise_and_counts_a_lost_block() {
    let prefix = prefix();
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vct-est-test").unwrap();
    let mut vib = StreamPublisher::<VibBlock>::create(
        &node,
        &names.vib(),
        &names.event(Stream::Vib),
        &data_stream_config(),
    )
    .unwrap();
    let estimates = StreamSubscriber::<VibEstimate>::create(
        &node,
        &names.estimate(),
        &names.event(Stream::Estimate),
        &estimate_stream_config(),
    )
    .unwrap();
    let hb = Stream::Heartbeat(ServiceId::Estimator);
    let heartbeats = StreamSubscriber::<Heartbeat>::create(
        &node,
        &names.stream(hb),
        &names.event(hb),
        &data_stream_config(),
    )
    .unwrap();

    let service = Running::start(vibro_estimator::run, config(&prefix));
    assert!(wait_until(Duration::from_secs(5), || vib
        .subscriber_count()
        == 1));

    // 6 s of signal; block 60 is lost on the way.
    let mut noise = Gaussian::new(7);
    let lost = 60;
    for k in 0..96u64 {
        let mut b = block(k, &mut noise);
        if k == lost {
            continue;
        }
        b.publish_ns = now_ns();
        vib.publish(&b).unwrap();
    }
    // Windows of 4096 samples every 2048: (6 s * 4096 - 4096) / 2048 + 1 = 11.
    let mut got = Vec::new();
    assert!(wait_until(Duration::from_secs(10), || {
        while let Some(e) = estimates.receive().unwrap() {
            got.push(*e);
        }
        got.len() == 11
    }));
    // The heartbeat catches up within a period. (Read it before stopping: a message
    // lives in its publisher's shared memory, which goes when the service stops.)
    let mut beat = None;
    assert!(wait_until(Duration::from_secs(5), || {
        while let Some(h) = heartbeats.receive().unwrap() {
            beat = Some(*h);
        }
        beat.is_some_and(|h| h.published == 11)
    }));
    let summary = service.stop();

    let truth_rms_g = NOISE_G * ((BAND_HZ[1] - BAND_HZ[0]) / (FS_HZ / 2.0)).sqrt();
    let lost_start_ns = lost * 62_500_000;
    let lost_end_ns = lost_start_ns + 62_500_000;
    let mut worst = [0.0f64; 3]; // |error| / u: frequency, amplitude, rms
    for (n, e) in got.iter().enumerate() {
        assert_eq!(e.seq, n as u64);
        assert_eq!(e.index, n as u64);
        assert_eq!(e.start_ns, n as u64 * 500_000_000);
        assert_eq!(e.end_ns, e.start_ns + 1_000_000_000);
        // The last block in the window: the window ends at sample 4096 + 2048 n.
        assert_eq!(e.source_seq, (4096 + 2048 * n as u64) / BLOCK as u64 - 1);
        assert!(e.publish_ns > 0);
        let covers_gap = e.start_ns < lost_end_ns && e.end_ns > lost_start_ns;
        assert_eq!(
            e.flags & estimate_flags::GAP != 0,
            covers_gap,
            "estimate {n}"
        );
        if covers_gap {
            continue;
        }
        assert_eq!(e.tone_count, 1, "estimate {n}: one tone");
        within(
            "frequency",
            e.tone_frequency_hz[0],
            TONE_HZ,
            e.tone_frequency_u_hz[0],
            5.0,
        );
        worst[0] =
            worst[0].max((e.tone_frequency_hz[0] - TONE_HZ).abs() / e.tone_frequency_u_hz[0]);
        for a in 0..3 {
            within(
                "amplitude",
                e.tone_amplitude_g[0][a],
                TONE_G[a],
                e.tone_amplitude_u_g[0][a],
                5.0,
            );
            within(
                "rms",
                e.broadband_rms_g[a],
                truth_rms_g,
                e.broadband_rms_u_g[a],
                5.0,
            );
            worst[1] = worst[1]
                .max((e.tone_amplitude_g[0][a] - TONE_G[a]).abs() / e.tone_amplitude_u_g[0][a]);
            worst[2] =
                worst[2].max((e.broadband_rms_g[a] - truth_rms_g).abs() / e.broadband_rms_u_g[a]);
        }
    }
    println!(
        "worst |error|/u over {} clean estimates: frequency {:.2}, amplitude {:.2}, rms {:.2}; latency p50 {} ns p99 {} ns",
        got.iter().filter(|e| e.flags & estimate_flags::GAP == 0).count(),
        worst[0],
        worst[1],
        worst[2],
        summary.latency.p50_ns,
        summary.latency.p99_ns
    );

    assert_eq!(summary.vib.received, 95);
    assert_eq!(summary.vib.lost_messages, 1);
    assert_eq!(summary.vib.lost_samples, BLOCK as u64);
    assert_eq!(summary.dsp.gap_samples, BLOCK as u64);
    assert_eq!(summary.dsp.sequence_gaps, 1);
    assert_eq!(summary.estimates_published, 11);
    assert_eq!(summary.latency.count, 11);
    assert!(summary.estimates_flagged >= 1);
    assert_eq!((summary.undelivered, summary.publish_errors), (0, 0));

    let beat = beat.unwrap();
    assert_eq!(beat.service, ServiceId::Estimator.code());
    assert_eq!((beat.received, beat.published, beat.lost), (95, 11, 1));
    assert!(
        beat.stale >= 1,
        "estimates with a gap count as produced from missing input"
    );
    assert!(summary.to_json().contains("\"lost_messages\":1"));
}

#[test]
fn bad_input_is_counted_never_fatal() {
    let prefix = prefix();
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vct-est-test").unwrap();
    let mut vib = StreamPublisher::<VibBlock>::create(
        &node,
        &names.vib(),
        &names.event(Stream::Vib),
        &data_stream_config(),
    )
    .unwrap();
    let hb = Stream::Heartbeat(ServiceId::Estimator);
    let heartbeats = StreamSubscriber::<Heartbeat>::create(
        &node,
        &names.stream(hb),
        &names.event(hb),
        &data_stream_config(),
    )
    .unwrap();
    let service = Running::start(vibro_estimator::run, config(&prefix));
    assert!(wait_until(Duration::from_secs(5), || vib
        .subscriber_count()
        == 1));
    let mut noise = Gaussian::new(3);
    let mut sent = 0;
    for k in 0..20u64 {
        let mut b = block(k, &mut noise);
        match k {
            5 => b.count = 9999,                // malformed: dropped, counted
            7 => b.sample_v[3] = [f64::NAN; 3], // non-finite: kept out of the estimate
            9 => b.sample_v[4][1] = f64::INFINITY,
            _ => {}
        }
        vib.publish(&b).unwrap();
        sent += 1;
        if k == 12 {
            // Block 12 again: a duplicate, out of order.
            vib.publish(&b).unwrap();
            sent += 1;
        }
        if k == 15 {
            // Block 15 again, its counter glitched to 500,000 (issue 31): blocks 16..=18
            // are out of order behind it, and block 19 resyncs the stream.
            b.seq = 500_000;
            vib.publish(&b).unwrap();
            sent += 1;
        }
    }
    // The heartbeat tells when the service has taken every block, and what was out of
    // order (the duplicate and 16..=18) and resynced (schema v5).
    let mut last = None;
    assert!(wait_until(Duration::from_secs(5), || {
        while let Some(h) = heartbeats.receive().unwrap() {
            last = Some(*h);
        }
        last.is_some_and(|h| h.received == sent)
    }));
    let beat = last.unwrap();
    assert_eq!((beat.out_of_order, beat.resyncs), (4, 1), "{beat:?}");
    let summary = service.stop();
    assert_eq!(summary.vib.received, sent);
    assert_eq!(summary.vib.malformed, 1);
    assert_eq!((summary.vib.out_of_order, summary.vib.resyncs), (4, 1));
    assert_eq!(
        summary.vib.lost_messages, 1,
        "the malformed block's seq is missing"
    );
    assert_eq!(summary.dsp.non_finite_samples, 2);
    assert_eq!(summary.dsp.blocks_dropped, 1);
    assert!(summary.estimates_published >= 1);
}
