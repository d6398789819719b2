//! No silent loss and no panic on bad input: sequence and sample-index gaps are counted
//! and flagged, duplicates and malformed blocks dropped and counted, non-finite samples
//! give NaN outputs with a flag. Runs the hot loop in spin mode.

use crate::support::*;
use vibro_compensator::Config;
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{Heartbeat, ServiceId, ServiceState, Stream};
use vibro_service::{LoopMode, ServiceConfig};

/// The compensator in spin mode on a fresh prefix, its rig, and a subscriber to its
/// heartbeats (with the node that holds it): `(k1, rig, node, heartbeats, service)`.
fn start_watched() -> (
    [f64; 3],
    Rig,
    vibro_ipc::IpcNode,
    vibro_ipc::StreamSubscriber<Heartbeat>,
    Running<vibro_compensator::Summary>,
) {
    let prefix = prefix();
    let mut config = Config::shipped().unwrap().with_prefix(&prefix).unwrap();
    // The estimate stage's rules: no vibration samples in these streams.
    config.model.waveform.stage = vibro_compensator::Stage::Estimate;
    config.service.loop_mode = LoopMode::Spin;
    let k1 = config.model.k1_v_per_g();
    let rig = Rig::new(&prefix);
    let node = vibro_ipc::create_node("vct-cmp-test-hb").unwrap();
    let hb = Stream::Heartbeat(ServiceId::Compensator);
    let heartbeats = vibro_ipc::StreamSubscriber::<Heartbeat>::create(
        &node,
        &rig.names.stream(hb),
        &rig.names.event(hb),
        &vibro_service::data_stream_config(),
    )
    .unwrap();
    let service = Running::start(vibro_compensator::run, config);
    rig.wait_for_service();
    (k1, rig, node, heartbeats, service)
}

#[test]
fn gaps_duplicates_malformed_and_non_finite_input_are_counted_and_flagged() {
    let (k1, mut rig, _node, heartbeats, service) = start_watched();

    let one_g = [[k1[0], 0.0, 0.0]; 32]; // 1 g on unit 1, 0 on the others
    let block = |seq: u64| accel_block(seq, seq * 32_000_000, &one_g);

    for seq in [0, 1] {
        assert_eq!(rig.roundtrip(&block(seq)).flags & cf::INPUT_GAP, 0);
    }
    // Block 2 lost on the way.
    let out = rig.roundtrip(&block(3));
    assert_ne!(out.flags & cf::INPUT_GAP, 0);
    // A duplicate is dropped (no output); the next block is fine.
    rig.send(&block(3));
    let out = rig.roundtrip(&block(4));
    assert_eq!(out.flags & cf::INPUT_GAP, 0);
    // A malformed block is dropped; the block after it is flagged.
    let mut bad = block(5);
    bad.count = 40;
    rig.send(&bad);
    let out = rig.roundtrip(&block(6));
    assert_ne!(out.flags & cf::INPUT_GAP, 0);
    // The producer says it lost samples.
    let mut told = block(7);
    told.flags = vibro_msgs::accel_flags::GAP_BEFORE;
    assert_ne!(rig.roundtrip(&told).flags & cf::INPUT_GAP, 0);
    // A NaN sample: that sample's outputs are NaN, the others are compensated.
    let mut nan = block(8);
    nan.output_v[3][1] = f64::NAN;
    nan.output_v[5][2] = 1e300;
    let out = rig.roundtrip(&nan);
    assert_ne!(out.flags & cf::NON_FINITE_INPUT, 0);
    for k in 0..32 {
        let bad = k == 3 || k == 5;
        for u in 0..3 {
            assert_eq!(out.a4_g[k][u].is_nan(), bad, "sample {k} unit {u}");
        }
    }
    assert!((out.a4_g[0][0] - 1.0).abs() < 1e-2, "{}", out.a4_g[0][0]);
    // An empty block still gets its (empty) output.
    let empty = accel_block(9, 9 * 32_000_000, &[]);
    let out = rig.roundtrip(&empty);
    assert_eq!(out.count, 0);

    let mut beat = None;
    assert!(wait_until(std::time::Duration::from_secs(5), || {
        while let Some(h) = heartbeats.receive().unwrap() {
            beat = Some(*h);
        }
        beat.is_some_and(|h| h.published == 8)
    }));
    let summary = service.stop();
    let beat = beat.unwrap();
    assert_eq!((beat.received, beat.lost, beat.stale), (10, 2, 8));
    assert_eq!((beat.out_of_order, beat.resyncs), (1, 0), "the duplicate");

    let a = summary.accel;
    assert_eq!(a.received, 10);
    assert_eq!(a.lost_messages, 2, "seq 2 and the malformed seq 5");
    assert_eq!(a.lost_samples, 64);
    assert_eq!((a.out_of_order, a.malformed), (1, 1));
    assert_eq!(summary.published, 8);
    assert_eq!(summary.input_gap_blocks, 3);
    assert_eq!(summary.non_finite_samples, 2);
    assert_eq!(summary.missing_blocks, 8);
    println!(
        "spin mode: recv->publish p50 {} ns, p99 {} ns over {} blocks",
        summary.latency.p50_ns, summary.latency.p99_ns, summary.latency.count
    );
}

/// Issue 31, item 1, as a watcher sees it: one block 500,000 ahead of the stream (a
/// glitched counter) and the three real blocks after it taken as out of order, then the
/// fourth resyncs the stream. The heartbeat says so: `out_of_order` 3, `resyncs` 1,
/// `degraded`, and no loss once the resync takes the 499,989 back. Before schema v5
/// the heartbeat had no field for either count (it said `running`, lost 0).
#[test]
fn a_block_ahead_of_the_stream_shows_in_the_heartbeat() {
    let (k1, mut rig, _node, heartbeats, service) = start_watched();

    let one_g = [[k1[0], 0.0, 0.0]; 32];
    let block = |seq: u64, at: u64| accel_block(seq, at * 32_000_000, &one_g);
    for seq in 0..=10 {
        rig.roundtrip(&block(seq, seq));
    }
    // The glitch: the counter of block 11 reads 500,000.
    rig.roundtrip(&block(500_000, 11));
    for seq in 11..=13 {
        rig.send(&block(seq, seq + 1));
    }
    let out = rig.roundtrip(&block(14, 15));
    assert_ne!(out.flags & cf::INPUT_GAP, 0, "the resync is flagged");
    for seq in 15..=20 {
        assert_eq!(rig.roundtrip(&block(seq, seq + 1)).flags & cf::INPUT_GAP, 0);
    }

    let mut beat = None;
    let mut degraded = false;
    assert!(wait_until(std::time::Duration::from_secs(5), || {
        while let Some(h) = heartbeats.receive().unwrap() {
            degraded |= h.state == ServiceState::Degraded.code();
            beat = Some(*h);
        }
        beat.is_some_and(|h| h.published == 19)
    }));
    let summary = service.stop();
    let beat = beat.unwrap();
    assert_eq!(
        (beat.received, beat.published, beat.lost),
        (22, 19, 0),
        "{beat:?}"
    );
    assert_eq!((beat.out_of_order, beat.resyncs), (3, 1), "{beat:?}");
    assert!(degraded, "no heartbeat said degraded");
    assert_eq!((summary.accel.out_of_order, summary.accel.resyncs), (3, 1));
}
