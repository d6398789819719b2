//! The sensors' stream is hostile input: blocks that jump, repeat, run backwards,
//! change rate, come flagged or carry non-finite samples are counted by kind, start a
//! new segment, and leave the readings they touch to the fallback (`Coverage::Never`);
//! the stream is taken up again right after, and no sequence stops the stage.

use vibro_physics::passport::Passport;
use vibro_physics::triad::TriadAxes;
use vibro_waveform::{Coverage, SensorChain, VibPush, WaveformStage};

const PERIOD_NS: u64 = 156_250; // 6.4 kHz
const N: usize = 512;

fn stage() -> WaveformStage {
    let p = vibro_config::resolve_passport("AL-15").expect("shipped");
    let mut spec = p.to_spec();
    spec.lambda.clear();
    let p = Passport::try_from_spec(&spec).expect("valid");
    WaveformStage::new(
        SensorChain {
            sensitivity_v_per_g: [0.1; 3],
            ac_corner_hz: 2.0,
            delay_s: 0.0,
        },
        TriadAxes::standard(),
        [p; 3],
        [vec![], vec![], vec![]],
    )
    .expect("chain")
}

fn block(k: u64) -> Vec<[f64; 3]> {
    (0..N)
        .map(|j| {
            let t = (k * N as u64 + j as u64) as f64 / 6400.0;
            let v = 0.1 * (2.0 * std::f64::consts::PI * 60.0 * t).sin();
            [v, 0.5 * v, -v]
        })
        .collect()
}

/// Pushes block `k` of a clean stream (seq k, index k N, t0 = k N P).
fn push(s: &mut WaveformStage, k: u64) -> VibPush {
    s.push_vib(
        k,
        k * N as u64,
        k * N as u64 * PERIOD_NS,
        PERIOD_NS,
        &block(k),
        false,
        false,
    )
}

/// The reading block (32 at 800 Hz) whose first interval ends at `t_ns`.
fn cover(s: &WaveformStage, t_ns: u64) -> Coverage {
    s.coverage(t_ns, 1_250_000, 32)
}

#[test]
fn a_clean_stream_covers_what_it_holds_and_waits_for_the_rest() {
    let mut s = stage();
    assert_eq!(cover(&s, 20_000_000), Coverage::NotYet, "nothing yet");
    assert_eq!(push(&mut s, 0), VibPush::Started);
    for k in 1..4 {
        assert_eq!(push(&mut s, k), VibPush::Continued);
    }
    // 4 blocks = 320 ms. A block of readings from 20 to 60 ms is covered.
    assert_eq!(cover(&s, 20_000_000), Coverage::Ready);
    // One ending past the last sample (plus the kernel's half-width) waits.
    assert_eq!(cover(&s, 300_000_000), Coverage::NotYet);
    // One starting before the first sample's kernel reach never will be.
    assert_eq!(cover(&s, 1_250_000), Coverage::Never);
    let c = s.counters();
    assert_eq!(
        (c.vib_blocks, c.breaks, c.repeated, c.refused),
        (4, 0, 0, 0)
    );
}

#[test]
fn jumps_repeats_backwards_rate_changes_and_bad_blocks_are_counted_and_taken_up_again() {
    let mut s = stage();
    for k in 0..4 {
        push(&mut s, k);
    }
    // The same block again, and an older one: dropped, counted, the stream goes on.
    assert_eq!(push(&mut s, 3), VibPush::Repeated);
    assert_eq!(push(&mut s, 1), VibPush::Repeated);
    assert_eq!(push(&mut s, 4), VibPush::Continued);
    // A lost block (5): a gap, a new segment from 6.
    assert_eq!(push(&mut s, 6), VibPush::Started);
    // Readings across the gap are never covered; after it they are once samples come.
    assert_eq!(
        cover(&s, 6 * N as u64 * PERIOD_NS - 20_000_000),
        Coverage::Never
    );
    push(&mut s, 7);
    push(&mut s, 8);
    assert_eq!(
        cover(&s, 6 * N as u64 * PERIOD_NS + 20_000_000),
        Coverage::Ready
    );
    // A block stamped 10 ms early (the clock stepped back): backwards.
    let t9 = 9 * N as u64 * PERIOD_NS - 10_000_000;
    assert_eq!(
        s.push_vib(9, 9 * N as u64, t9, PERIOD_NS, &block(9), false, false),
        VibPush::Started
    );
    // And one 10 ms late: a time jump.
    let t10 = t9 + N as u64 * PERIOD_NS + 10_000_000;
    assert_eq!(
        s.push_vib(10, 10 * N as u64, t10, PERIOD_NS, &block(10), false, false),
        VibPush::Started
    );
    // A rate change (5 kHz).
    let t11 = t10 + N as u64 * PERIOD_NS;
    assert_eq!(
        s.push_vib(11, 11 * N as u64, t11, 200_000, &block(11), false, false),
        VibPush::Started
    );
    // A saturated block and one with a NaN: refused, and the segment ends before them.
    let t12 = t11 + N as u64 * 200_000;
    assert_eq!(
        s.push_vib(12, 12 * N as u64, t12, 200_000, &block(12), true, false),
        VibPush::Refused
    );
    let mut bad = block(13);
    bad[100][1] = f64::NAN;
    let t13 = t12 + N as u64 * 200_000;
    assert_eq!(
        s.push_vib(13, 13 * N as u64, t13, 200_000, &bad, false, false),
        VibPush::Refused
    );
    // A GAP_BEFORE flag on an otherwise contiguous block.
    let t14 = t13 + N as u64 * 200_000;
    assert_eq!(
        s.push_vib(14, 14 * N as u64, t14, 200_000, &block(14), false, false),
        VibPush::Started
    );
    let t15 = t14 + N as u64 * 200_000;
    assert_eq!(
        s.push_vib(15, 15 * N as u64, t15, 200_000, &block(15), false, true),
        VibPush::Started
    );
    // A zero period.
    assert_eq!(
        s.push_vib(16, 16 * N as u64, t15, 0, &block(16), false, false),
        VibPush::Refused
    );
    let c = s.counters();
    assert_eq!(c.repeated, 2);
    assert_eq!(c.backwards, 1);
    assert_eq!(c.time_jumps, 1);
    assert_eq!(c.rate_changes, 1);
    assert_eq!(c.refused, 3);
    // gaps: block 6 and the GAP_BEFORE block.
    assert_eq!(c.gaps, 2);
    assert_eq!(
        c.breaks,
        c.gaps + c.backwards + c.time_jumps + c.rate_changes
    );
    // The stream is taken up again after all that.
    let t17 = t15 + N as u64 * 200_000;
    assert_eq!(
        s.push_vib(17, 16 * N as u64, t17, 200_000, &block(17), false, false),
        VibPush::Started
    );
    let t18 = t17 + N as u64 * 200_000;
    assert_eq!(
        s.push_vib(18, 17 * N as u64, t18, 200_000, &block(18), false, false),
        VibPush::Continued
    );
}

#[test]
fn a_chain_that_breaks_a_rule_is_refused_with_key_value_and_rule() {
    let p = vibro_config::resolve_passport("AL-15").expect("shipped");
    let err = WaveformStage::new(
        SensorChain {
            sensitivity_v_per_g: [0.1; 3],
            ac_corner_hz: 0.5,
            delay_s: -0.002,
        },
        TriadAxes::standard(),
        [p; 3],
        [vec![], vec![], vec![]],
    )
    .err()
    .expect("refused");
    assert!(
        err.to_string()
            .contains("delay_s = -0.002: must be from 0 to 1 s"),
        "{err}"
    );
}

/// A producer that starts again on the same time base (a replay run twice): its first
/// blocks look like copies of what the stream holds; after three in a row the stage
/// takes it as a restart, so that no such sequence silences it.
#[test]
fn a_replay_run_twice_is_taken_up_after_three_copies() {
    let mut s = stage();
    for k in 0..8 {
        push(&mut s, k);
    }
    for k in 0..3 {
        assert_eq!(push(&mut s, k), VibPush::Repeated, "block {k}");
    }
    assert_eq!(push(&mut s, 3), VibPush::Started);
    for k in 4..8 {
        assert_eq!(push(&mut s, k), VibPush::Continued);
    }
    // The new segment starts at block 3 (240 ms): readings after it are covered again.
    assert_eq!(cover(&s, 300_000_000), Coverage::Ready);
}

/// Hostile streams: random `seq`, index, time stamps, periods (down to 1 ns and up to
/// 100 s), flags and values (NaN, infinities, 1e300), interleaved with reading blocks
/// of random timing and values. Nothing panics, the ring never grows past its cap, and
/// every reading block gets an answer: solved (finite, or NaN for a non-finite
/// reading) or refused as never covered.
#[test]
fn no_sequence_of_blocks_panics_or_grows_without_bound() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(46);
    let mut s = stage();
    let pick = |rng: &mut rand_chacha::ChaCha8Rng, good: u64| -> u64 {
        match rng.random_range(0..6) {
            0 => rng.random(),
            1 => 0,
            2 => u64::MAX - rng.random_range(0..3),
            _ => good,
        }
    };
    let (mut seq, mut index, mut t0) = (0u64, 0u64, 1_000_000_000u64);
    for round in 0..3000 {
        let period = match rng.random_range(0..8) {
            0 => 1,
            1 => 100_000_000_000,
            2 => rng.random_range(1..10_000_000),
            _ => PERIOD_NS,
        };
        let n = rng.random_range(0..=N);
        let values: Vec<[f64; 3]> = (0..n)
            .map(|_| match rng.random_range(0..40) {
                0 => [f64::NAN, 0.0, 0.0],
                1 => [f64::INFINITY, 1e300, -1e300],
                _ => [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    0.0,
                ],
            })
            .collect();
        let b_seq = pick(&mut rng, seq);
        let b_index = pick(&mut rng, index);
        let b_t0 = pick(&mut rng, t0);
        s.push_vib(
            b_seq,
            b_index,
            b_t0,
            period,
            &values,
            rng.random_range(0..20) == 0,
            rng.random_range(0..20) == 0,
        );
        seq = seq.wrapping_add(1);
        index = index.wrapping_add(n as u64);
        t0 = t0.wrapping_add(n as u64 * PERIOD_NS);
        if round % 2 == 0 {
            let reading_period = match rng.random_range(0..6) {
                0 => 1,
                1 => rng.random(),
                _ => 1_250_000,
            };
            let count = rng.random_range(0..=32);
            let end = pick(&mut rng, t0.saturating_sub(100_000_000));
            let readings: Vec<[f64; 3]> = (0..count)
                .map(|_| match rng.random_range(0..30) {
                    0 => [f64::NAN; 3],
                    1 => [1e300, -1e300, 0.0],
                    _ => [rng.random_range(-5.0..5.0), 0.5, 1.0],
                })
                .collect();
            if s.coverage(end, reading_period, count) == Coverage::Ready {
                let mut out = vec![[0.0; 3]; count];
                s.compensate(end, reading_period, &readings, &mut out);
            }
        }
    }
    let c = s.counters();
    assert!(c.vib_blocks == 3000);
    assert!(c.breaks > 100 && c.refused > 10, "{c:?}");
}
