//! Bad input at the estimator service (docs/reliability.md, "Bad input"): a block at
//! another sample rate than the configured one, empty blocks (with any timestamp) and
//! blocks of odd sizes. Each run goes through the service over shared memory and is
//! compared with a reference run of the same samples: the excluded block must leave
//! exactly the estimates of a stream that lost it, and odd or empty blocks exactly the
//! estimates of regular blocks. The truth (a 97.3 Hz tone in white noise) is checked
//! too, within 5 of the estimates' own standard uncertainties.

use crate::in_process::{
    config, within, BAND_HZ, BLOCK, FS_HZ, NOISE_G, SENSITIVITY_V_PER_G, TONE_G, TONE_HZ,
    TONE_PHASE_RAD,
};
use crate::support::{prefix, wait_until, Gaussian, Running};
use std::f64::consts::TAU;
use std::time::Duration;
use vibro_estimator::Summary;
use vibro_ipc::{create_node, StreamPublisher, StreamSubscriber};
use vibro_msgs::{
    estimate_flags, Heartbeat, ServiceId, ServiceNames, Stream, VibBlock, VibEstimate,
};
use vibro_service::{data_stream_config, estimate_stream_config, now_ns};

/// 6 s of signal.
const SAMPLES: usize = 6 * FS_HZ as usize;

/// Sample period in ns, exact (4096 Hz: 244140.625 ns).
const PERIOD_NS: f64 = 1e9 / FS_HZ;

/// The tone in white noise, in volts, `[sample][axis]`.
fn signal_v() -> Vec<[f64; 3]> {
    let mut noise = Gaussian::new(11);
    (0..SAMPLES)
        .map(|i| {
            let t_s = i as f64 / FS_HZ;
            std::array::from_fn(|a| {
                let g = TONE_G[a] * (TAU * TONE_HZ * t_s + TONE_PHASE_RAD[a]).sin()
                    + NOISE_G * noise.next();
                g * SENSITIVITY_V_PER_G
            })
        })
        .collect()
}

/// A block of `samples` from sample `first` on, dated by its index.
fn block(seq: u64, first: usize, samples: &[[f64; 3]]) -> VibBlock {
    let mut b = VibBlock::ZEROED;
    b.seq = seq;
    b.first_sample_index = first as u64;
    b.t0_ns = (first as f64 * PERIOD_NS).round() as u64;
    b.sample_period_ns = PERIOD_NS.round() as u64;
    b.count = samples.len() as u32;
    b.sample_v[..samples.len()].copy_from_slice(samples);
    b
}

/// The signal in regular blocks of [`BLOCK`] samples.
fn regular_blocks(x: &[[f64; 3]]) -> Vec<VibBlock> {
    x.chunks(BLOCK)
        .enumerate()
        .map(|(k, c)| block(k as u64, k * BLOCK, c))
        .collect()
}

/// Runs the service on its own prefix, sends `blocks`, waits until it has taken every
/// one, and returns the estimates and the summary.
fn run(blocks: &[VibBlock]) -> (Vec<VibEstimate>, Summary) {
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
    let progress = Stream::Progress(ServiceId::Estimator);
    let progress = StreamSubscriber::<Heartbeat>::create(
        &node,
        &names.stream(progress),
        &names.event(progress),
        &data_stream_config(),
    )
    .unwrap();
    let service = Running::start(vibro_estimator::run, config(&prefix));
    assert!(wait_until(Duration::from_secs(5), || vib
        .subscriber_count()
        == 1));
    let mut got = Vec::new();
    let mut taken = 0;
    for b in blocks {
        let mut b = *b;
        b.publish_ns = now_ns();
        vib.publish(&b).unwrap();
        while let Some(e) = estimates.receive().unwrap() {
            got.push(*e);
        }
    }
    // A progress message follows every wake-up that took input, after its estimates.
    assert!(
        wait_until(Duration::from_secs(10), || {
            while let Some(p) = progress.receive().unwrap() {
                taken = p.received;
            }
            while let Some(e) = estimates.receive().unwrap() {
                got.push(*e);
            }
            taken == blocks.len() as u64
        }),
        "the service took {taken} of {} blocks",
        blocks.len()
    );
    while let Some(e) = estimates.receive().unwrap() {
        got.push(*e);
    }
    (got, service.stop())
}

/// Everything an estimate says about the vibration (values bit for bit, counts, flags
/// but `RATE_MISMATCH`), not its bookkeeping (`seq`, `source_seq`, `publish_ns`) or
/// window times.
fn values(e: &VibEstimate) -> Vec<u64> {
    let mut v: Vec<u64> = Vec::new();
    let mut put = |xs: &[f64]| v.extend(xs.iter().map(|x| x.to_bits()));
    put(&[e.broadband_f_lo_hz, e.broadband_f_hi_hz]);
    put(&e.broadband_rms_g);
    put(&e.broadband_rms_u_g);
    put(e.broadband_covariance_g2.as_flattened());
    put(e.broadband_covariance_u_g2.as_flattened());
    put(&e.broadband_kurtosis);
    put(&e.broadband_kurtosis_u);
    put(&e.tone_frequency_hz);
    put(&e.tone_frequency_u_hz);
    put(e.tone_amplitude_g.as_flattened());
    put(e.tone_amplitude_u_g.as_flattened());
    put(e.tone_phase_rad.as_flattened());
    put(e.tone_phase_u_rad.as_flattened());
    put(e.tone_snr_db.as_flattened());
    put(&e.band_f_lo_hz);
    put(&e.band_f_hi_hz);
    put(e.band_psd_g2_per_hz.as_flattened());
    put(e.band_psd_u_g2_per_hz.as_flattened());
    put(e.band_rms_g.as_flattened());
    v.extend(
        [
            e.samples,
            e.valid_samples,
            e.broadband_welch_segments,
            e.tone_count,
            e.band_count,
            e.flags & !estimate_flags::RATE_MISMATCH,
        ]
        .iter()
        .chain(&e.saturated_samples)
        .map(|&c| u64::from(c)),
    );
    v
}

/// The tone and the broadband RMS of estimate `n` are the truth within 5 standard
/// uncertainties, and there is no other tone.
fn assert_truth(n: usize, e: &VibEstimate) {
    let truth_rms_g = NOISE_G * ((BAND_HZ[1] - BAND_HZ[0]) / (FS_HZ / 2.0)).sqrt();
    assert_eq!(
        e.tone_count, 1,
        "estimate {n}: one tone, {:?}",
        e.tone_frequency_hz
    );
    within(
        "frequency",
        e.tone_frequency_hz[0],
        TONE_HZ,
        e.tone_frequency_u_hz[0],
        5.0,
    );
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
    }
}

/// Block 60 (3.75 s) says it was sampled at 2048 Hz and carries a 2 g, 300 Hz tone
/// instead of the signal. It is counted, kept out (its 256 samples a gap) and the two
/// windows over it, [3, 4) s and [3.5, 4.5) s, say `RATE_MISMATCH` and `GAP`: every
/// estimate equals, bit for bit, that of the stream with block 60 lost, and the truth.
/// Sent at the configured rate, the same block is taken: its 2 g burst more than doubles
/// the broadband RMS of those two windows.
#[test]
fn a_block_at_another_rate_is_kept_out_and_the_estimates_over_it_are_flagged() {
    let x = signal_v();
    let clean = regular_blocks(&x);
    assert_eq!(clean.len(), 96);
    let bad_seq = 60usize;
    let mut wrong_rate = clean.clone();
    let b = &mut wrong_rate[bad_seq];
    b.sample_period_ns *= 2;
    for i in 0..BLOCK {
        let t_s = i as f64 * 2.0 / FS_HZ;
        b.sample_v[i] = [(TAU * 300.0 * t_s).sin() * 2.0 * SENSITIVITY_V_PER_G; 3];
    }
    let (got, summary) = run(&wrong_rate);
    let lost: Vec<VibBlock> = clean
        .iter()
        .filter(|b| b.seq != bad_seq as u64)
        .copied()
        .collect();
    let (reference, reference_summary) = run(&lost);

    // Windows of 4096 samples every 2048: 11 in 6 s, window n over [n/2, n/2 + 1) s.
    assert_eq!((got.len(), reference.len()), (11, 11));
    let span_ns = [3_750_000_000u64, 3_750_000_000 + 256 * 2 * 244_141];
    let both = estimate_flags::GAP | estimate_flags::RATE_MISMATCH;
    for (n, (e, r)) in got.iter().zip(&reference).enumerate() {
        assert_eq!((e.start_ns, e.end_ns), (r.start_ns, r.end_ns));
        assert_eq!(e.start_ns, n as u64 * 500_000_000);
        let over = e.start_ns < span_ns[1] && e.end_ns > span_ns[0];
        assert_eq!(over, n == 6 || n == 7, "estimate {n}");
        assert_eq!(
            e.flags & both,
            if over { both } else { 0 },
            "estimate {n}: flags {:#x}",
            e.flags
        );
        assert_eq!(r.flags & estimate_flags::RATE_MISMATCH, 0);
        assert_eq!(values(e), values(r), "estimate {n}");
        if over {
            assert_eq!(e.valid_samples, 4096 - 256, "estimate {n}");
        }
        assert_truth(n, e);
    }
    assert_eq!(summary.rate_mismatches, 1);
    assert_eq!(summary.estimates_flagged, 2);
    assert_eq!(
        (summary.vib.lost_messages, summary.dsp.sequence_gaps),
        (0, 0),
        "a dropped block is no lost message"
    );
    assert_eq!(summary.dsp.gap_samples, BLOCK as u64);
    assert_eq!(
        (
            reference_summary.vib.lost_messages,
            reference_summary.dsp.gap_samples
        ),
        (1, BLOCK as u64)
    );
    assert!(summary.to_json().contains("\"rate_mismatches\":1"));

    // The same block at the configured rate is taken, and would spoil the estimates.
    let mut taken = wrong_rate;
    taken[bad_seq].sample_period_ns = clean[bad_seq].sample_period_ns;
    let (with_it, summary) = run(&taken);
    assert_eq!(summary.rate_mismatches, 0);
    let truth_rms_g = NOISE_G * ((BAND_HZ[1] - BAND_HZ[0]) / (FS_HZ / 2.0)).sqrt();
    for (n, e) in with_it.iter().enumerate() {
        let spoilt = e.broadband_rms_g.iter().all(|&r| r > 2.0 * truth_rms_g);
        assert_eq!(
            spoilt,
            n == 6 || n == 7,
            "estimate {n}: {:?}",
            e.broadband_rms_g
        );
        assert_eq!(e.flags & both, 0);
    }
}

/// The same samples as regular 256-sample blocks, and as blocks of 1, 0, 255, 37, 0,
/// 511, 300, 129, 0, 7 samples over and over (none a multiple of the 1024-sample Welch
/// segment or of the 2048-sample hop), the empty ones dated 0, right or `u64::MAX`:
/// never a panic, and the same estimates bit for bit, window times within the 1 ns of
/// rounding each block's `t0_ns` to whole ns.
#[test]
fn empty_and_odd_sized_blocks_give_the_estimates_of_regular_blocks() {
    let x = signal_v();
    let c = config("unused/");
    assert_eq!(
        (c.estimator.segment_samples(), c.estimator.hop_samples()),
        (1024, 2048)
    );
    let sizes = [1usize, 0, 255, 37, 0, 511, 300, 129, 0, 7];
    let mut odd = Vec::new();
    let (mut first, mut empties) = (0usize, 0usize);
    for &n in sizes.iter().cycle() {
        if first == x.len() {
            break;
        }
        let n = n.min(x.len() - first);
        let mut b = block(odd.len() as u64, first, &x[first..first + n]);
        if n == 0 {
            b.t0_ns = [0, b.t0_ns, u64::MAX][empties % 3];
            empties += 1;
        }
        odd.push(b);
        first += n;
    }
    assert!(odd.len() > 190 && empties > 50, "{} blocks", odd.len());
    let (got, summary) = run(&odd);
    let (reference, reference_summary) = run(&regular_blocks(&x));

    assert_eq!((got.len(), reference.len()), (11, 11));
    for (n, (e, r)) in got.iter().zip(&reference).enumerate() {
        for (what, a, b) in [
            ("start", e.start_ns, r.start_ns),
            ("end", e.end_ns, r.end_ns),
            ("center", e.center_ns, r.center_ns),
        ] {
            assert!(a.abs_diff(b) <= 1, "estimate {n}: {what} {a} vs {b}");
        }
        assert_eq!(values(e), values(r), "estimate {n}");
        assert_eq!(e.flags & !estimate_flags::TONE_FREE, 0, "estimate {n}");
        assert_truth(n, e);
    }
    assert_eq!(summary.vib.received, odd.len() as u64);
    assert_eq!(
        (summary.vib.lost_messages, summary.vib.lost_samples),
        (0, 0)
    );
    let d = summary.dsp;
    assert_eq!(
        (d.sequence_gaps, d.gap_samples, d.restarts, d.blocks_dropped),
        (0, 0, 0, 0)
    );
    assert_eq!(d.blocks_accepted, odd.len() as u64);
    assert_eq!(reference_summary.dsp.estimates, d.estimates);
}
