//! Faulty streams: gaps, out-of-order and duplicate blocks, NaN/Inf samples,
//! saturation, odd block sizes. They are flagged, kept out of the estimate, and never
//! panic or poison a window.
// Per-axis index loops mirror the formulas and index several arrays at once.
#![allow(clippy::needless_range_loop)]

mod common;

use common::*;
use vibro_dsp::{Estimate, EstimatorConfigRaw, SampleBlock};

const FS_HZ: f64 = 8192.0;
const BLOCK: usize = 512;

fn cfg() -> EstimatorConfigRaw {
    let mut c = EstimatorConfigRaw::new(FS_HZ, [1.0; 3]);
    c.full_scale_g = Some([5.0, 5.0, 5.0]);
    c
}

/// 4 s of a 1 g, 123.4 Hz tone on every axis in 0.05 g of white noise.
fn signal(seed: u64) -> (Vec<[f64; 3]>, Tone) {
    let tone = Tone {
        frequency_hz: 123.4,
        amplitude_g: [1.0, 1.0, 1.0],
        phase_rad: [0.0, 0.5, 1.0],
    };
    let mut x = white_noise(&mut rng(seed), 4 * FS_HZ as usize, [0.05; 3]);
    add_tone(&mut x, &tone, FS_HZ);
    (x, tone)
}

fn block_t0_ns(seq: usize) -> u64 {
    (seq as f64 * BLOCK as f64 * 1e9 / FS_HZ).round() as u64
}

/// Pushes the blocks of `x` in the order given by `order` (indices of blocks).
fn feed_order(
    est: &mut vibro_dsp::Estimator,
    x: &[[f64; 3]],
    order: &[usize],
) -> (Vec<Estimate>, Vec<vibro_dsp::BlockStatus>) {
    let blocks: Vec<&[[f64; 3]]> = x.chunks(BLOCK).collect();
    let mut out = Vec::new();
    let mut statuses = Vec::new();
    for &i in order {
        let b = SampleBlock {
            seq: i as u64,
            t0_ns: block_t0_ns(i),
            samples_raw: blocks[i],
        };
        statuses.push(est.push_block(&b, |e| out.push(*e)).unwrap());
    }
    (out, statuses)
}

fn assert_tone_close(e: &Estimate, tone: &Tone, amp_tol: f64) {
    assert_eq!(e.tones.len(), 1, "{:?}", e.tones);
    let t = e.tones[0];
    assert!(
        (t.frequency_hz - tone.frequency_hz).abs() < 0.01,
        "{}",
        t.frequency_hz
    );
    for a in 0..3 {
        assert!(
            (t.amplitude_g[a] - tone.amplitude_g[a]).abs() < amp_tol,
            "{:?}",
            t.amplitude_g
        );
    }
}

#[test]
fn nan_and_infinite_samples_are_flagged_and_kept_out() {
    let (mut x, tone) = signal(1);
    for k in (1000..1010).chain([5000, 9000]) {
        x[k][1] = f64::NAN;
    }
    x[12000][0] = f64::INFINITY;
    x[12001][2] = f64::NEG_INFINITY;
    let mut est = estimator(cfg());
    let out = feed(&mut est, &x, BLOCK);
    assert_eq!(out.len(), 7);
    // Windows of 8192 samples every 4096: 0..8191 holds 11 bad samples, 4096..12287
    // holds 4 (5000, 9000, 12000, 12001), 8192..16383 holds 3.
    assert!(out[0].flags.non_finite && out[0].valid_samples == 8192 - 11);
    assert!(out[1].flags.non_finite && out[1].valid_samples == 8192 - 4);
    assert!(out[2].valid_samples == 8192 - 3);
    assert!(out[2].flags.non_finite && !out[3].flags.non_finite);
    for e in &out {
        assert!(!e.flags.insufficient_data && !e.flags.gap);
        assert_tone_close(e, &tone, 5e-3);
        assert!(e.broadband.rms_g.iter().all(|v| v.is_finite()));
        assert!(e.broadband.kurtosis.iter().all(|v| v.is_finite()));
        // 0.05 g white at 8192 Hz over 20..2000 Hz.
        let expected = (2.0 * 0.05f64.powi(2) / FS_HZ * 1980.0).sqrt();
        for a in 0..3 {
            assert!((e.broadband.rms_g[a] / expected - 1.0).abs() < 0.1);
        }
    }
    // The Welch segments holding a bad sample were skipped.
    assert!(out[0].broadband.welch_segments < 7 && out[3].broadband.welch_segments == 7);
    // 7 half-overlapping segments fill the 8192-sample window: 2048 samples each, what a
    // consumer needs to undo the leakage between bands.
    assert!(out
        .iter()
        .all(|e| e.broadband.welch_segment_samples == 2048));
    assert_eq!(est.counters().non_finite_samples, 14);
}

#[test]
fn out_of_order_and_duplicate_blocks_are_dropped_and_flagged_without_changing_the_estimates() {
    let (x, _) = signal(2);
    let n_blocks = x.len() / BLOCK;
    let in_order: Vec<usize> = (0..n_blocks).collect();
    // Block 5 again after 6 (a late duplicate), block 3 again right after itself.
    let mut disordered = vec![0, 1, 2, 3, 3, 4, 5, 6, 5];
    disordered.extend(7..n_blocks);
    let (clean, _) = feed_order(&mut estimator(cfg()), &x, &in_order);
    let mut est = estimator(cfg());
    let (got, statuses) = feed_order(&mut est, &x, &disordered);
    assert!(statuses[4].out_of_order && !statuses[4].accepted);
    assert!(statuses[8].out_of_order && !statuses[8].accepted);
    assert_eq!(est.counters().blocks_dropped, 2);
    assert_eq!(clean.len(), got.len());
    assert!(got[0].flags.out_of_order && !got[1].flags.out_of_order);
    for (c, g) in clean.iter().zip(&got) {
        assert_eq!(c.tones, g.tones);
        assert_eq!(c.broadband, g.broadband);
        assert_eq!(c.start_ns, g.start_ns);
    }
}

#[test]
fn a_short_gap_is_filled_and_flagged_and_a_long_gap_restarts_the_window() {
    let (x, tone) = signal(3);
    let n_blocks = x.len() / BLOCK;
    // Lose block 4 (0.0625 s): filled with invalid samples.
    let order: Vec<usize> = (0..n_blocks).filter(|&i| i != 4).collect();
    let mut est = estimator(cfg());
    let (out, statuses) = feed_order(&mut est, &x, &order);
    assert!(statuses[4].sequence_gap && statuses[4].gap_samples == BLOCK as u64);
    assert!(!statuses[4].restarted);
    assert!(out[0].flags.gap && out[0].valid_samples == 8192 - BLOCK);
    // The window still spans 1 s of time and its tone is intact.
    assert_eq!(out[0].start_ns, 0);
    assert_eq!(out[0].end_ns, 1_000_000_000);
    assert_tone_close(&out[0], &tone, 5e-3);
    assert!(!out[2].flags.gap);

    // Lose 20 blocks (1.25 s, more than a window): restart after the gap.
    let order: Vec<usize> = (0..n_blocks).filter(|&i| !(10..30).contains(&i)).collect();
    let mut est = estimator(cfg());
    let (out, statuses) = feed_order(&mut est, &x, &order);
    assert!(statuses[10].restarted);
    assert_eq!(est.counters().restarts, 1);
    let after: Vec<&Estimate> = out
        .iter()
        .filter(|e| e.start_ns >= block_t0_ns(30))
        .collect();
    assert!(after[0].flags.gap && !after[0].flags.non_finite);
    assert_eq!(after[0].start_ns, block_t0_ns(30));
    assert_eq!(after[0].valid_samples, 8192);
    assert!(out
        .iter()
        .all(|e| e.start_ns >= block_t0_ns(30) || e.end_ns <= block_t0_ns(10)));
}

#[test]
fn a_sequence_reset_is_a_gap_and_a_clock_stepping_back_restarts() {
    let (x, tone) = signal(8);
    let blocks: Vec<&[[f64; 3]]> = x.chunks(BLOCK).collect();
    let mut est = estimator(cfg());
    let mut out = Vec::new();
    // Blocks 0..20 in order, then the publisher restarts its sequence at 0 while time
    // goes on (blocks 20..40), then its clock steps back by 2 s (blocks 40..64).
    let mut statuses = Vec::new();
    for (i, block) in blocks.iter().enumerate() {
        let seq = if i < 20 {
            i as u64
        } else {
            i as u64 - 20 + if i >= 40 { 100 } else { 0 }
        };
        let t0_ns = if i < 40 {
            block_t0_ns(i)
        } else {
            block_t0_ns(i) - 2_000_000_000
        };
        let b = SampleBlock {
            seq,
            t0_ns,
            samples_raw: block,
        };
        statuses.push(est.push_block(&b, |e| out.push(*e)).unwrap());
    }
    assert!(statuses[20].accepted && statuses[20].sequence_gap && !statuses[20].restarted);
    assert!(statuses[40].accepted && statuses[40].restarted);
    assert!(statuses.iter().all(|s| s.accepted));
    for e in &out {
        assert_tone_close(e, &tone, 5e-3);
    }
    // The window holding the sequence reset is flagged; after the clock step the
    // first window starts at the stepped-back time and is flagged too.
    let step = out
        .windows(2)
        .position(|w| w[1].start_ns < w[0].start_ns)
        .expect("a window after the clock step");
    assert!(out[step + 1].flags.gap);
    assert_eq!(out[step + 1].start_ns, block_t0_ns(40) - 2_000_000_000);
    let reset = out
        .iter()
        .position(|e| e.end_ns > block_t0_ns(20))
        .expect("a window over the sequence reset");
    assert!(out[reset].flags.gap && !out[reset].flags.non_finite);
    assert!(!out[step].flags.gap);
}

#[test]
fn a_window_with_too_many_invalid_samples_is_declared_insufficient() {
    let nan = vec![[f64::NAN; 3]; 3 * FS_HZ as usize];
    let mut est = estimator(cfg());
    let out = feed(&mut est, &nan, 1000);
    assert_eq!(out.len(), 5);
    for e in &out {
        assert!(e.flags.insufficient_data && e.flags.non_finite && e.flags.tone_free);
        assert!(e.broadband.rms_g.iter().all(|v| v.is_nan()));
        assert!(e
            .bands
            .iter()
            .all(|b| b.psd_g2_per_hz.iter().all(|v| v.is_nan())));
        assert_eq!(e.valid_samples, 0);
    }
}

#[test]
fn saturation_is_flagged_per_axis() {
    let (mut x, _) = signal(4);
    x[100][2] = 5.0;
    x[200][2] = -7.0;
    let out = feed(&mut estimator(cfg()), &x, BLOCK);
    assert_eq!(out[0].flags.saturated, [false, false, true]);
    assert_eq!(out[0].saturated_samples, [0, 0, 2]);
    assert_eq!(out[2].flags.saturated, [false; 3]);
}

#[test]
fn block_size_does_not_change_the_estimates() {
    let (x, _) = signal(5);
    let a = feed(&mut estimator(cfg()), &x, BLOCK);
    let b = feed(&mut estimator(cfg()), &x, 7);
    let c = feed(&mut estimator(cfg()), &x, x.len());
    assert_eq!(a.len(), 7);
    for (e1, e2) in a.iter().zip(&b) {
        assert_eq!(e1.tones, e2.tones);
        assert_eq!(e1.broadband, e2.broadband);
    }
    for (e1, e3) in a.iter().zip(&c) {
        assert_eq!(e1.tones, e3.tones);
        assert_eq!(e1.bands, e3.bands);
    }
    // Empty blocks are accepted and change nothing.
    let mut est = estimator(cfg());
    let empty = SampleBlock {
        seq: 0,
        t0_ns: 0,
        samples_raw: &[],
    };
    let status = est.push_block(&empty, |_| panic!("no window")).unwrap();
    assert!(status.accepted);

    // Between regular blocks too, whatever their timestamp says (none of their samples
    // sits anywhere): an empty block after every regular one, dated 0, now or never.
    let mut est = estimator(cfg());
    let mut d = Vec::new();
    for (k, chunk) in x.chunks(BLOCK).enumerate() {
        let seq = 2 * k as u64;
        let block = SampleBlock {
            seq,
            t0_ns: block_t0_ns(k),
            samples_raw: chunk,
        };
        let status = est.push_block(&block, |e| d.push(*e)).unwrap();
        assert!(status.accepted && !status.sequence_gap && !status.restarted);
        let empty = SampleBlock {
            seq: seq + 1,
            t0_ns: [0, block_t0_ns(k + 1), u64::MAX][k % 3],
            samples_raw: &[],
        };
        let status = est.push_block(&empty, |_| panic!("no window")).unwrap();
        assert_eq!(
            status,
            vibro_dsp::BlockStatus {
                accepted: true,
                ..Default::default()
            }
        );
    }
    assert_eq!(d, a, "estimates, flags and times all equal");
    let c = est.counters();
    assert_eq!((c.sequence_gaps, c.restarts, c.blocks_dropped), (0, 0, 0));
    // An empty block that skips a seq flags the gap; an older one is dropped.
    let skip = SampleBlock { seq: 1000, ..empty };
    assert!(est.push_block(&skip, |_| {}).unwrap().sequence_gap);
    let old = SampleBlock { seq: 3, ..empty };
    let status = est.push_block(&old, |_| {}).unwrap();
    assert!(!status.accepted && status.out_of_order);
}

#[test]
fn estimate_time_span_and_sensitivity_are_honoured() {
    // Volts at 0.1 V/g on x, -0.2 V/g on y (axis reversed), 1 counts/g on z.
    let (x, tone) = signal(6);
    let volts: Vec<[f64; 3]> = x.iter().map(|s| [0.1 * s[0], -0.2 * s[1], s[2]]).collect();
    let mut c = cfg();
    c.sensitivity_raw_per_g = [0.1, -0.2, 1.0];
    let out = feed(&mut estimator(c), &volts, BLOCK);
    assert_eq!(out.len(), 7);
    for (i, e) in out.iter().enumerate() {
        assert_eq!(e.start_ns, i as u64 * 500_000_000);
        assert_eq!(e.end_ns, e.start_ns + 1_000_000_000);
        // Centre of samples 0..8191 is sample 4095.5.
        assert_eq!(e.center_ns, e.start_ns + (4095.5e9 / FS_HZ).round() as u64);
        assert_tone_close(e, &tone, 5e-3);
        // The reversed y axis keeps its phase relative to x (sign handled by the
        // sensitivity, not by a 180 degree phase jump).
        let d = wrap_pi(e.tones[0].phase_rad[1] - e.tones[0].phase_rad[0] - 0.5);
        assert!(d.abs() < 0.01, "{d}");
    }
}

/// Issue 31: one block numbered and dated ahead of the stream (block 500,000, 1 h on)
/// had every later block dropped as out of order until the stream caught up with it.
/// Now the fourth dropped block in a row is taken (the window restarts there), and so
/// are the blocks after it.
#[test]
fn one_block_ahead_of_the_stream_does_not_silence_the_estimator() {
    let (x, _) = signal(4);
    let blocks: Vec<&[[f64; 3]]> = x.chunks(BLOCK).collect();
    let mut est = estimator(cfg());
    let push = |seq: usize, est: &mut vibro_dsp::Estimator| {
        let b = SampleBlock {
            seq: seq as u64,
            t0_ns: block_t0_ns(seq),
            samples_raw: blocks[seq % blocks.len()],
        };
        est.push_block(&b, |_| {}).unwrap()
    };
    for seq in 0..=10 {
        assert!(push(seq, &mut est).accepted);
    }
    assert!(push(500_000, &mut est).accepted);
    let after: Vec<_> = (11..=40).map(|seq| push(seq, &mut est)).collect();
    let dropped = after.iter().take_while(|s| !s.accepted).count();
    assert_eq!(dropped, vibro_dsp::RESYNC_AFTER_DROPS as usize - 1);
    assert!(after[dropped].restarted, "{:?}", after[dropped]);
    assert!(after[dropped..].iter().all(|s| s.accepted), "{after:?}");
    // A window (1 s at 8192 Hz, 16 blocks) of the stream again gives estimates.
    let mut estimates = 0;
    for seq in 41..=120 {
        let b = SampleBlock {
            seq,
            t0_ns: block_t0_ns(seq as usize),
            samples_raw: blocks[seq as usize % blocks.len()],
        };
        est.push_block(&b, |_| estimates += 1).unwrap();
    }
    assert!(estimates > 0);
}

/// A caller that resynchronised upstream says so: the next block is newer whatever its
/// sequence number, and the window goes on when its time does.
#[test]
fn a_resync_from_upstream_takes_the_next_block() {
    let (x, _) = signal(5);
    let blocks: Vec<&[[f64; 3]]> = x.chunks(BLOCK).collect();
    let mut est = estimator(cfg());
    for seq in 0..10 {
        let b = SampleBlock {
            seq: 1_000 + seq as u64,
            t0_ns: block_t0_ns(seq),
            samples_raw: blocks[seq],
        };
        est.push_block(&b, |_| {}).unwrap();
    }
    est.resync();
    let b = SampleBlock {
        seq: 10,
        t0_ns: block_t0_ns(10),
        samples_raw: blocks[10],
    };
    let s = est.push_block(&b, |_| {}).unwrap();
    assert!(s.accepted && s.sequence_gap && !s.restarted, "{s:?}");
    assert_eq!(
        est.samples_to_next_estimate(),
        (x.len() / 4 - 11 * BLOCK) as u64
    );
}

#[test]
fn garbage_streams_never_panic() {
    let mut r = rng(7);
    let mut est = estimator(cfg());
    let mut seq = 0u64;
    let mut t_ns = 0u64;
    let mut estimates = 0;
    for _ in 0..400 {
        let len = (uniform(&mut r) * 3000.0) as usize;
        let block: Vec<[f64; 3]> = (0..len)
            .map(|_| {
                std::array::from_fn(|_| match (uniform(&mut r) * 20.0) as u32 {
                    0 => f64::NAN,
                    1 => f64::INFINITY,
                    2 => 1e300,
                    3 => 0.0,
                    _ => gauss(&mut r),
                })
            })
            .collect();
        // Sequence and time jump around: forwards, backwards, far ahead.
        match (uniform(&mut r) * 10.0) as u32 {
            0 => seq = seq.saturating_sub(3),
            1 => t_ns = t_ns.saturating_sub(1_000_000_000),
            2 => t_ns = t_ns.saturating_add(3_000_000_000),
            3 => seq = u64::MAX - 1,
            4 if uniform(&mut r) < 0.05 => t_ns = u64::MAX - 1_000_000,
            _ => {}
        }
        let b = SampleBlock {
            seq,
            t0_ns: t_ns,
            samples_raw: &block,
        };
        est.push_block(&b, |e| {
            estimates += 1;
            assert!(e.valid_samples <= e.samples);
        })
        .unwrap();
        seq = seq.saturating_add(1);
        t_ns = t_ns.saturating_add((len as f64 * 1e9 / FS_HZ) as u64);
    }
    assert!(estimates > 0);
}
