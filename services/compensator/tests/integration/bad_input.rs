//! Bad input on the accelerometer stream and between the streams (docs/reliability.md,
//! "Bad input"): a rate change mid-run, timestamps that jump while `seq` and the sample
//! index go on, estimates dated far ahead of the blocks (two clocks), saturated blocks.
//! Each is flagged on exactly the blocks concerned, and the values are checked against
//! references built without the fault: the kernel in-process with a vibration computed
//! here in closed form, a compensator started afresh, or the same blocks with clean
//! timestamps.
//!
//! These run the service's own handler in-process ([`InProcess`], the hot loop's code
//! without the transport), so every figure is deterministic.

use crate::support::*;
use std::f64::consts::PI;
use vibro_compensator::interval::band_within_fraction;
use vibro_compensator::{Config, InProcess};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{accel_flags, AccelBlock, CompensatedBlock, VibEstimate};
use vibro_physics::compensation::{Mode, TriadCompensator};
use vibro_physics::triad::TriadAxes;
use vibro_physics::vibration::Vibration;
use vibro_service::ServiceConfig;

/// 800 Hz output.
const T_NS: u64 = 1_250_000;
const BLOCK: u64 = 32;
/// Where the test streams start on the data time base.
const START_NS: u64 = 10_000_000_000_000;
/// Tolerance between two exact-mode runs whose Newton iterations start from different
/// points: each stops within 1e-12 g of the same root.
const NEWTON_G: f64 = 1e-11;

/// The flight: body acceleration at sample `n` (1..5 g along z, a little on x and y).
fn body_g(n: u64) -> [f64; 3] {
    let t = n as f64 * 1e-3;
    [
        0.3 + 0.05 * (3.0 * t).sin(),
        -0.2 + 0.01 * t,
        1.0 + 4.0 * t / 0.64,
    ]
}

struct Stream {
    config: Config,
    axes: TriadAxes,
    k1_v_per_g: [f64; 3],
}

impl Stream {
    fn shipped() -> Self {
        let mut config = Config::shipped().unwrap();
        // The estimate stage's rules: no vibration samples in these streams.
        config.model.waveform.stage = vibro_compensator::Stage::Estimate;
        Self {
            axes: config.model.triad.axes,
            k1_v_per_g: config.model.k1_v_per_g(),
            config,
        }
    }

    /// Block `seq`: samples `32 seq ..` of the flight, plus a 3 mg bias, in volts; sample
    /// 0's interval ends at `t0_ns`.
    fn block(&self, seq: u64, t0_ns: u64, period_ns: u64) -> AccelBlock {
        let output_v: Vec<[f64; 3]> = (0..BLOCK)
            .map(|k| {
                let body = body_g(seq * BLOCK + k);
                [0, 1, 2]
                    .map(|u| (self.axes.units[u].ia.project(&body) + 3e-3) * self.k1_v_per_g[u])
            })
            .collect();
        let mut b = accel_block(seq, t0_ns, &output_v);
        b.sample_period_ns = period_ns;
        b
    }

    /// Block `seq` of a stream at 800 Hz from [`START_NS`].
    fn regular(&self, seq: u64) -> AccelBlock {
        self.block(seq, START_NS + (seq * BLOCK + 1) * T_NS, T_NS)
    }

    fn readings_g(&self, b: &AccelBlock, k: usize) -> [f64; 3] {
        [0, 1, 2].map(|u| b.output_v[k][u] / self.k1_v_per_g[u])
    }

    fn run(&self, steps: &[Step<'_>]) -> (Vec<CompensatedBlock>, vibro_compensator::Summary) {
        let mut c = InProcess::new(&self.config).unwrap();
        let mut out = Vec::new();
        for step in steps {
            match step {
                Step::Estimate(e) => c.on_estimate(e),
                Step::Block(b) => c.on_accel(b, 0, &mut out),
            }
        }
        (out, c.summary())
    }
}

/// An estimate or a block, in arrival order.
enum Step<'a> {
    Estimate(&'a VibEstimate),
    Block(&'a AccelBlock),
}

/// A vibration with a fast tone (200 Hz), which output intervals of a few ms cut into
/// very different parts, a slow one and broadband noise.
fn vibration() -> BodyVibration {
    BodyVibration {
        tones: vec![
            (200.0, [1.0, 0.8, 1.5], [0.4, -0.3, 0.1]),
            (31.0, [0.3, 0.2, 0.6], [2.0, -1.0, 0.7]),
        ],
        covariance_g2: [[1.0, 0.2, 0.3], [0.2, 1.44, -0.1], [0.3, -0.1, 1.96]],
        kurtosis: [3.0, 3.3, 2.8],
    }
}

/// The estimate of [`vibration`] whose window ends at `end_ns`, broadband over
/// 20..2000 Hz with no band PSDs (a flat spectrum).
fn estimate(axes: &TriadAxes, seq: u64, end_ns: u64) -> VibEstimate {
    let mut e = vibration().estimate(axes, seq, end_ns);
    e.broadband_f_lo_hz = 20.0;
    e.broadband_f_hi_hz = 2000.0;
    e
}

/// `1 - sinc^2(pi f T)`, written out again here.
fn r(f_hz: f64, t_s: f64) -> f64 {
    let x = PI * f_hz * t_s;
    1.0 - (x.sin() / x).powi(2)
}

/// [`vibration`] inside output intervals of `t_s`, in closed form: tone amplitudes times
/// `sqrt(r(f))`, the (flat, 20..2000 Hz) random part's covariance times the mean of `r`
/// over the band, by the midpoint rule on 200 000 points.
fn within_interval(t_s: f64) -> BodyVibration {
    let mut v = vibration();
    for tone in &mut v.tones {
        let s = r(tone.0, t_s).sqrt();
        tone.1 = tone.1.map(|a| a * s);
    }
    let n = 200_000;
    let mean_r = (0..n)
        .map(|i| r(20.0 + 1980.0 * (i as f64 + 0.5) / n as f64, t_s))
        .sum::<f64>()
        / n as f64;
    for row in &mut v.covariance_g2 {
        for c in row.iter_mut() {
            *c *= mean_r;
        }
    }
    v
}

fn kernel(stream: &Stream, vib: Option<&BodyVibration>) -> TriadCompensator {
    let mut k = TriadCompensator::new(
        stream.axes,
        stream.config.model.triad.passports,
        Mode::Exact,
    );
    for i in 0..3 {
        let v = vib.map_or(Vibration::none(), |v| v.at_unit(&stream.axes.units[i]));
        k.set_vibration(i, &v).unwrap();
    }
    k
}

fn arrays(b: &CompensatedBlock) -> [(&str, &[[f64; 3]; 32]); 7] {
    [
        ("a1", &b.a1_g),
        ("a2", &b.a2_g),
        ("a3", &b.a3_g),
        ("a4", &b.a4_g),
        ("main", &b.main_g),
        ("det", &b.det_g),
        ("rand", &b.rand_g),
    ]
}

/// Every stage of `got` equals `want`'s bit for bit.
fn assert_same_bits(got: &CompensatedBlock, want: &CompensatedBlock, what: &str) {
    assert_eq!(got.count, want.count, "{what}");
    for ((name, x), (_, y)) in arrays(got).into_iter().zip(arrays(want)) {
        for k in 0..got.count as usize {
            for u in 0..3 {
                assert_eq!(
                    x[k][u].to_bits(),
                    y[k][u].to_bits(),
                    "{what}: {name}[{k}][{u}] {:e} vs {:e}",
                    x[k][u],
                    y[k][u]
                );
            }
        }
    }
}

/// The largest difference over every stage between `got` and `want`, g.
fn max_difference_g(got: &CompensatedBlock, want: &CompensatedBlock) -> f64 {
    let mut worst = 0.0f64;
    for ((_, x), (_, y)) in arrays(got).into_iter().zip(arrays(want)) {
        for k in 0..got.count as usize {
            for u in 0..3 {
                worst = worst.max((x[k][u] - y[k][u]).abs());
            }
        }
    }
    worst
}

/// Main error only: `a3 = a4 = a2` exactly, no vibration corrections.
fn assert_main_only(out: &CompensatedBlock, what: &str) {
    for k in 0..out.count as usize {
        for u in 0..3 {
            assert_eq!(out.a3_g[k][u].to_bits(), out.a2_g[k][u].to_bits(), "{what}");
            assert_eq!(out.a4_g[k][u].to_bits(), out.a2_g[k][u].to_bits(), "{what}");
            assert_eq!((out.det_g[k][u], out.rand_g[k][u]), (0.0, 0.0), "{what}");
        }
    }
}

/// The main-error stages `a1`, `a2` of `got` are within `tol_g` of `want`'s.
fn assert_main_close(got: &CompensatedBlock, want: &CompensatedBlock, tol_g: f64, what: &str) {
    for k in 0..got.count as usize {
        for u in 0..3 {
            for (x, y) in [
                (got.a1_g[k][u], want.a1_g[k][u]),
                (got.a2_g[k][u], want.a2_g[k][u]),
            ] {
                assert!((x - y).abs() <= tol_g, "{what}: {x:e} vs {y:e}");
            }
        }
    }
}

/// The accelerometer stream goes from 800 Hz to 400 Hz mid-run, sample index and data
/// time continuing: the block at the change says `RATE_CHANGE` (and nothing else), and
/// from it on the outputs are bit for bit those of a compensator started on 400 Hz, and
/// within 1e-9 g of the kernel given the vibration inside a 2.5 ms interval computed
/// here in closed form (before the change: inside 1.25 ms). The 1e-9 g is the service's
/// quadrature of the band fraction (Simpson, 128 panels: 1.5e-8 relative at 2.5 ms)
/// on random corrections of a few mg.
#[test]
fn a_rate_change_is_flagged_and_compensated_as_by_a_compensator_started_on_the_new_rate() {
    let s = Stream::shipped();
    assert!(s.config.model.estimate.within_output_interval);
    let new_ns = 2 * T_NS;
    let est = estimate(&s.axes, 0, START_NS);
    // 10 blocks at 800 Hz, then 10 at 400 Hz: the first 400 Hz sample's interval starts
    // where the last 800 Hz one ended.
    let switch_ns = START_NS + 10 * BLOCK * T_NS;
    let blocks: Vec<AccelBlock> = (0..20)
        .map(|seq| {
            if seq < 10 {
                s.regular(seq)
            } else {
                s.block(seq, switch_ns + ((seq - 10) * BLOCK + 1) * new_ns, new_ns)
            }
        })
        .collect();
    let mut steps = vec![Step::Estimate(&est)];
    steps.extend(blocks.iter().map(Step::Block));
    let (out, summary) = s.run(&steps);
    assert_eq!(out.len(), 20);
    for (seq, o) in out.iter().enumerate() {
        let want = if seq == 10 { cf::RATE_CHANGE } else { 0 };
        assert_eq!(o.flags, want, "block {seq}");
        assert_eq!(o.sample_period_ns, blocks[seq].sample_period_ns);
    }
    assert_eq!(summary.rate_change_blocks, 1);
    assert_eq!(summary.time_jump_blocks, 0, "the data time went on");
    assert!(summary.to_json().contains("\"rate_change_blocks\":1"));

    // A compensator that only ever saw the 400 Hz blocks.
    let mut fresh_steps = vec![Step::Estimate(&est)];
    fresh_steps.extend(blocks[10..].iter().map(Step::Block));
    let (fresh, _) = s.run(&fresh_steps);
    for (k, f) in fresh.iter().enumerate() {
        assert_eq!(f.flags, 0);
        assert_same_bits(&out[10 + k], f, &format!("block {}", 10 + k));
    }

    // The kernel with the vibration inside each interval, from the closed form.
    let mut worst = [0.0f64; 2];
    for (part, (range, period_ns)) in [(0..10usize, T_NS), (10..20, new_ns)]
        .into_iter()
        .enumerate()
    {
        let vib = within_interval(period_ns as f64 * 1e-9);
        let mut reference = kernel(&s, Some(&vib));
        for seq in range {
            let mut want = out[seq];
            for k in 0..BLOCK as usize {
                let r = reference.compensate(s.readings_g(&blocks[seq], k));
                for u in 0..3 {
                    let x = &r.units[u];
                    want.a1_g[k][u] = x.a1_g;
                    want.a2_g[k][u] = x.a2_g;
                    want.a3_g[k][u] = x.a3_g;
                    want.a4_g[k][u] = x.a4_g;
                    want.main_g[k][u] = x.main_g;
                    want.det_g[k][u] = x.det_g;
                    want.rand_g[k][u] = x.rand_g;
                }
            }
            worst[part] = worst[part].max(max_difference_g(&out[seq], &want));
        }
    }
    // What the re-mapping changes: the VE corrections of the 400 Hz blocks with the
    // vibration inside 1.25 ms intervals (not re-mapped) instead of 2.5 ms ones.
    let mut stale_map = kernel(&s, Some(&within_interval(T_NS as f64 * 1e-9)));
    let mut change = 0.0f64;
    for seq in 10..20 {
        for k in 0..BLOCK as usize {
            let r = stale_map.compensate(s.readings_g(&blocks[seq], k));
            for u in 0..3 {
                change = change.max((r.units[u].a4_g - out[seq].a4_g[k][u]).abs());
            }
        }
    }
    let quadrature = [T_NS, new_ns].map(|t_ns| {
        let t_s = t_ns as f64 * 1e-9;
        let mean_r = within_interval(t_s).covariance_g2[0][0] / vibration().covariance_g2[0][0];
        band_within_fraction(20.0, 2000.0, t_s) / mean_r - 1.0
    });
    println!(
        "rate change 800 -> 400 Hz: |service - closed-form kernel| <= {:.1e} g before, {:.1e} g after \
         (band-fraction quadrature {:.1e}, {:.1e} relative); not re-mapping would be off by {change:.2e} g",
        worst[0], worst[1], quadrature[0], quadrature[1]
    );
    assert!(quadrature.iter().all(|q| q.abs() < 2e-8), "{quadrature:?}");
    assert!(worst[0] <= 1e-9 && worst[1] <= 1e-9, "{worst:?}");
    assert!(change > 1e-6, "the re-mapping is visible: {change:e} g");
}

/// The accelerometer clock jitters, glitches and steps back while `seq` and the sample
/// index go on. A block more than half a period (625 us) from where the previous one
/// and the sample index put it says `TIME_JUMP`; its timestamp still dates it against
/// the estimate, so a glitch forward is stale and a step back dates the estimate ahead
/// (both main error only) until estimates on the new time base arrive. A block lost on
/// the way is a gap, not a jump: the check goes by the sample index. Outputs that use
/// the estimate equal those of the same blocks with clean timestamps.
#[test]
fn accelerometer_clock_jumps_are_flagged_and_the_timestamps_date_the_estimate() {
    let s = Stream::shipped();
    let half = T_NS / 2;
    let back_ns = 10_000_000_000u64;
    let clean: Vec<AccelBlock> = (0..12).map(|seq| s.regular(seq)).collect();
    let end = |b: &AccelBlock| block_end_ns(b);
    let mut blocks = clean.clone();
    blocks[1].t0_ns += half; // jitter of half a period: within the tolerance
    blocks[3].t0_ns += half + 1; // 1 ns beyond it
    blocks[5].t0_ns += 5_000_000_000; // one corrupt timestamp, 5 s ahead
    for b in &mut blocks[7..] {
        b.t0_ns -= back_ns; // the clock steps back 10 s for good
    }
    let est0 = estimate(&s.axes, 0, START_NS);
    // The estimator's first estimate on the new time base, 0.2 s before block 9's end.
    let est1 = estimate(&s.axes, 1, end(&blocks[9]) - 200_000_000);
    // Block 10 is lost on the way.
    let sent = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 11];
    let mut steps = vec![Step::Estimate(&est0)];
    for &seq in &sent {
        if seq == 9 {
            steps.push(Step::Estimate(&est1));
        }
        steps.push(Step::Block(&blocks[seq]));
    }
    let (out, summary) = s.run(&steps);
    assert_eq!(out.len(), sent.len());

    let mut clean_steps = vec![Step::Estimate(&est0)];
    clean_steps.extend(clean.iter().map(Step::Block));
    let (reference, _) = s.run(&clean_steps);
    assert!(reference.iter().all(|o| o.flags == 0));

    let main_only = cf::MAIN_ONLY;
    let age = |seq: usize, e: &VibEstimate| end(&blocks[seq]) as i64 - e.end_ns as i64;
    let expected: [(u32, u64, i64); 11] = [
        (0, 0, age(0, &est0)),
        (0, 0, age(1, &est0)),
        (0, 0, age(2, &est0)),
        (cf::TIME_JUMP, 0, age(3, &est0)),
        (cf::TIME_JUMP, 0, age(4, &est0)),
        (
            cf::TIME_JUMP | cf::VIBRATION_ESTIMATE_STALE | main_only,
            0,
            age(5, &est0),
        ),
        (cf::TIME_JUMP, 0, age(6, &est0)),
        (
            cf::TIME_JUMP | cf::ESTIMATE_AHEAD | main_only,
            0,
            age(7, &est0),
        ),
        (cf::ESTIMATE_AHEAD | main_only, 0, age(8, &est0)),
        (0, 1, 200_000_000),
        (cf::INPUT_GAP, 1, 280_000_000),
    ];
    let mut worst_g = 0.0f64;
    for ((o, &seq), &(flags, estimate_seq, age_ns)) in out.iter().zip(&sent).zip(&expected) {
        assert_eq!(o.input_seq, seq as u64);
        assert_eq!(o.flags, flags, "block {seq}: flags {:#x}", o.flags);
        assert_eq!(
            (o.estimate_seq, o.estimate_age_ns),
            (estimate_seq, age_ns),
            "block {seq}"
        );
        assert_eq!(
            o.t0_ns, blocks[seq].t0_ns,
            "the timestamp is passed on as given"
        );
        if flags & main_only != 0 {
            assert_main_only(o, &format!("block {seq}"));
            assert_main_close(o, &reference[seq], NEWTON_G, &format!("block {seq}"));
        } else {
            worst_g = worst_g.max(max_difference_g(o, &reference[seq]));
        }
    }
    // The ages, written out: 40 ms; 5.24 s; -9.68 s.
    assert_eq!(expected[0].2, 40_000_000);
    assert_eq!(expected[5].2, 5_240_000_000);
    assert_eq!(expected[7].2, 320_000_000 - 10_000_000_000);
    println!("clock jumps: outputs using the estimate within {worst_g:.1e} g of the clean run");
    assert!(worst_g <= NEWTON_G, "{worst_g:e}");
    assert_eq!(
        (
            summary.time_jump_blocks,
            summary.ahead_blocks,
            summary.stale_blocks
        ),
        (5, 2, 1)
    );
    assert_eq!(
        (summary.accel.lost_messages, summary.accel.lost_samples),
        (1, BLOCK)
    );
    assert!(summary.to_json().contains("\"time_jump_blocks\":5"));
}

/// Clock skew between the streams: an estimate whose window ends more than
/// `max_estimate_lead_s` (0.5 s) after a block's last sample is not used for it (main
/// error only, `ESTIMATE_AHEAD`), and is used again once the blocks catch up with it;
/// one ending more than `max_estimate_age_s` (2 s) before is stale. At the limits the
/// estimate is used.
#[test]
fn estimates_dated_beyond_the_lead_limit_are_not_used_and_the_block_is_flagged() {
    let s = Stream::shipped();
    assert_eq!(s.config.model.max_estimate_lead_ns, 500_000_000);
    let blocks: Vec<AccelBlock> = (0..7).map(|seq| s.regular(seq)).collect();
    let end = |seq: usize| block_end_ns(&blocks[seq]);
    let hour_ns = 3_600_000_000_000u64;
    let estimates = [
        estimate(&s.axes, 0, end(0) + 500_000_000), // exactly at the lead limit
        estimate(&s.axes, 1, end(1) + 500_000_001), // 1 ns beyond it
        estimate(&s.axes, 2, end(3) + hour_ns),     // another clock, an hour ahead
        estimate(&s.axes, 3, end(4) - hour_ns),     // ... an hour behind
        estimate(&s.axes, 4, end(5) - 2_000_000_000), // exactly at the age limit
    ];
    // Block 2 meets estimate 1 again, 40 ms later; block 6 meets nothing new.
    let mut steps = Vec::new();
    for (seq, b) in blocks.iter().enumerate() {
        match seq {
            0 | 1 => steps.push(Step::Estimate(&estimates[seq])),
            3..=5 => steps.push(Step::Estimate(&estimates[seq - 1])),
            _ => {}
        }
        steps.push(Step::Block(b));
    }
    let (out, summary) = s.run(&steps);
    let (reference, _) = s.run(
        &std::iter::once(Step::Estimate(&estimates[0]))
            .chain(blocks.iter().map(Step::Block))
            .collect::<Vec<_>>(),
    );
    let ahead = cf::ESTIMATE_AHEAD | cf::MAIN_ONLY;
    let stale = cf::VIBRATION_ESTIMATE_STALE | cf::MAIN_ONLY;
    let expected: [(u32, u64, i64); 7] = [
        (0, 0, -500_000_000),
        (ahead, 1, -500_000_001),
        (0, 1, -460_000_001),
        (ahead, 2, -(hour_ns as i64)),
        (stale, 3, hour_ns as i64),
        (0, 4, 2_000_000_000),
        (stale, 4, 2_040_000_000),
    ];
    let mut worst_g = 0.0f64;
    for (seq, (o, &(flags, estimate_seq, age_ns))) in out.iter().zip(&expected).enumerate() {
        assert_eq!(o.flags, flags, "block {seq}: flags {:#x}", o.flags);
        assert_eq!(
            (o.estimate_seq, o.estimate_age_ns),
            (estimate_seq, age_ns),
            "block {seq}"
        );
        if flags & cf::MAIN_ONLY != 0 {
            assert_main_only(o, &format!("block {seq}"));
            assert_main_close(o, &reference[seq], NEWTON_G, &format!("block {seq}"));
        } else {
            worst_g = worst_g.max(max_difference_g(o, &reference[seq]));
        }
    }
    println!("clock skew: outputs using the estimate within {worst_g:.1e} g of the reference");
    assert!(worst_g <= NEWTON_G, "{worst_g:e}");
    assert_eq!((summary.ahead_blocks, summary.stale_blocks), (2, 2));
    assert_eq!(summary.time_jump_blocks, 0);
    assert!(summary.to_json().contains("\"ahead_blocks\":2"));
}

/// A block its producer flagged `SATURATED` is compensated as read, and says
/// `INPUT_SATURATED`: bit for bit the kernel's stages on the same readings (no estimate
/// here, so main error only), and nothing else changes.
#[test]
fn a_saturated_input_block_is_compensated_as_read_and_flagged() {
    let s = Stream::shipped();
    let mut blocks: Vec<AccelBlock> = (0..4).map(|seq| s.regular(seq)).collect();
    // Unit 1 pinned at its (here: 2.5 g) range for a few samples.
    for k in 5..9 {
        blocks[1].output_v[k][0] = 2.5 * s.k1_v_per_g[0];
    }
    blocks[1].flags = accel_flags::SATURATED;
    blocks[2].flags = accel_flags::SATURATED | accel_flags::GAP_BEFORE;
    let (out, summary) = s.run(&blocks.iter().map(Step::Block).collect::<Vec<_>>());
    let missing = cf::ESTIMATE_MISSING | cf::MAIN_ONLY;
    let expected = [
        missing,
        missing | cf::INPUT_SATURATED,
        missing | cf::INPUT_SATURATED | cf::INPUT_GAP,
        missing,
    ];
    let mut reference = kernel(&s, None);
    for (seq, o) in out.iter().enumerate() {
        assert_eq!(o.flags, expected[seq], "block {seq}: flags {:#x}", o.flags);
        assert_main_only(o, &format!("block {seq}"));
        for k in 0..BLOCK as usize {
            let r = reference.compensate(s.readings_g(&blocks[seq], k));
            for u in 0..3 {
                let x = &r.units[u];
                for (got, want) in [
                    (o.a1_g[k][u], x.a1_g),
                    (o.a2_g[k][u], x.a2_g),
                    (o.main_g[k][u], x.main_g),
                ] {
                    assert_eq!(got.to_bits(), want.to_bits(), "block {seq} sample {k}");
                }
            }
        }
    }
    // The pinned readings come out as read: 2.5 g plus the model's main error removed.
    assert!(
        (out[1].a2_g[6][0] - 2.5).abs() < 0.01,
        "{}",
        out[1].a2_g[6][0]
    );
    assert_eq!(summary.saturated_blocks, 2);
    assert_eq!(summary.input_gap_blocks, 1);
    assert!(summary.to_json().contains("\"saturated_blocks\":2"));
}
