//! The compensator run in-process against the exact forward model: readings generated
//! by `vibro_physics::exact::MeanModel` from known flight accelerations and a known
//! vibration must come back as the truth, bit-for-bit what `TriadCompensator` gives
//! in-process; missing and stale estimates give main-only, flagged outputs.

use crate::support::*;
use vibro_compensator::{unit_vibrations, Config, EstimateMapping};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{estimate_flags, CompensatedBlock, CompensationMode};
use vibro_physics::compensation::{Mode, TriadCompensator};
use vibro_physics::exact::MeanModel;
use vibro_physics::triad::TriadAxes;
use vibro_service::{now_ns, ServiceConfig};

/// The flight: body acceleration at sample `n` (1..5 g along z, a little on x and y).
fn body_g(n: usize) -> [f64; 3] {
    let t = n as f64 * 1e-3;
    [
        0.3 + 0.05 * (3.0 * t).sin(),
        -0.2 + 0.01 * t,
        1.0 + 4.0 * t / 0.64,
    ]
}

fn assert_same_bits(what: &str, got: f64, want: f64) {
    assert_eq!(got.to_bits(), want.to_bits(), "{what}: {got:e} vs {want:e}");
}

fn check_stages_bitwise(
    out: &CompensatedBlock,
    k: usize,
    reference: &vibro_physics::compensation::TriadStages,
) {
    for i in 0..3 {
        let r = &reference.units[i];
        for (name, got, want) in [
            ("a1", out.a1_g[k][i], r.a1_g),
            ("a2", out.a2_g[k][i], r.a2_g),
            ("a3", out.a3_g[k][i], r.a3_g),
            ("a4", out.a4_g[k][i], r.a4_g),
            ("main", out.main_g[k][i], r.main_g),
            ("det", out.det_g[k][i], r.det_g),
            ("rand", out.rand_g[k][i], r.rand_g),
        ] {
            assert_same_bits(
                &format!("block {} sample {k} unit {i} {name}", out.input_seq),
                got,
                want,
            );
        }
    }
}

fn percentile(v: &mut [u64], q: f64) -> u64 {
    v.sort_unstable();
    v[((v.len() - 1) as f64 * q).round() as usize]
}

#[test]
fn exact_mode_recovers_the_truth_bit_for_bit_with_the_kernel() {
    let dir = TempDir::new();
    let prefix = prefix();
    std::fs::write(dir.path("triad.toml"), FLIPPED_TRIAD).unwrap();
    let path = dir.path("compensator.toml");
    std::fs::write(&path, config_text(&prefix, "exact", "triad.toml", "event")).unwrap();
    let config = Config::load(&path).unwrap();
    let triad = vibro_config::load_triad(&dir.path("triad.toml")).unwrap();
    let axes: TriadAxes = triad.axes;
    let passports = triad.passports;

    let mut rig = Rig::new(&prefix);
    let service = Running::start(vibro_compensator::run, config);
    rig.wait_for_service();

    // Readings: the exact mean output of each unit under the vibration it sees.
    let truth = BodyVibration::rig();
    let models = [0, 1, 2].map(|u| {
        let mut m = MeanModel::new(passports[u]);
        m.set_vibration(&truth.at_unit(&axes.units[u])).unwrap();
        m
    });
    let t0_ns = 50_000_000_000u64;
    let estimate = truth.estimate(&axes, 0, t0_ns);
    rig.send_estimate(&estimate);

    // The reference: the same kernel, in-process, in the same call order.
    let mut reference = TriadCompensator::new(axes, passports, Mode::Exact);
    let vibs = unit_vibrations(&estimate, &axes, &EstimateMapping::default()).unwrap();
    for i in 0..3 {
        reference.set_vibration(i, &vibs.units[i]).unwrap();
    }

    let (mut worst_g, mut worst_bits) = (0.0f64, 0usize);
    let (mut inside, mut transit) = (Vec::new(), Vec::new());
    for seq in 0..20u64 {
        let mut output_v = [[0.0; 3]; 32];
        let mut truth_ia = [[0.0; 3]; 32];
        for k in 0..32 {
            let body = body_g(seq as usize * 32 + k);
            for u in 0..3 {
                let reading_g = models[u].mean_output_g(axes.units[u].to_unit(&body)).0;
                output_v[k][u] = reading_g * passports[u].k1_v_per_g;
                truth_ia[k][u] = axes.units[u].ia.project(&body);
            }
        }
        let block = accel_block(seq, t0_ns + seq * 32_000_000, &output_v);
        let out = rig.roundtrip(&block);
        let got_ns = now_ns();
        assert_eq!(out.flags, 0, "block {seq}");
        assert_eq!(
            CompensationMode::try_from(out.mode),
            Ok(CompensationMode::Exact)
        );
        assert_eq!((out.seq, out.count, out.source_id), (seq, 32, 7));
        assert_eq!(
            (out.first_sample_index, out.t0_ns, out.sample_period_ns),
            (seq * 32, block.t0_ns, 1_000_000)
        );
        assert_eq!(out.estimate_seq, 0);
        assert_eq!(out.estimate_age_ns, (block_end_ns(&block) - t0_ns) as i64);
        assert!(out.input_publish_ns <= out.recv_ns && out.recv_ns <= out.publish_ns);
        inside.push(out.publish_ns - out.recv_ns);
        transit.push(got_ns - out.input_publish_ns);
        for k in 0..32 {
            let readings_g = [0, 1, 2].map(|u| output_v[k][u] / passports[u].k1_v_per_g);
            let r = reference.compensate(readings_g);
            check_stages_bitwise(&out, k, &r);
            worst_bits += 7 * 3;
            for u in 0..3 {
                let err = (out.a4_g[k][u] - truth_ia[k][u]).abs();
                worst_g = worst_g.max(err);
                assert!(
                    err < 1e-9,
                    "block {seq} sample {k} unit {u}: a4 error {err:e} g"
                );
                // The vibration error is there to remove: a(2) is off by far more.
                assert!((out.a2_g[k][u] - truth_ia[k][u]).abs() > 1e-6);
            }
        }
    }
    let summary = service.stop();
    println!(
        "exact mode: worst |a4 - truth| = {worst_g:.2e} g over 640 samples x 3 units, {worst_bits} values bit-equal to the kernel; \
         recv->publish p50 {} ns max {} ns; publish->test-receive p50 {} ns p90 {} ns",
        percentile(&mut inside, 0.5),
        percentile(&mut inside, 1.0),
        percentile(&mut transit, 0.5),
        percentile(&mut transit, 0.9),
    );
    assert_eq!(summary.published, 20);
    assert_eq!(summary.samples, 640);
    assert_eq!(
        summary.vibration_updates, 1,
        "set per estimate, not per block"
    );
    assert_eq!(
        (
            summary.estimates_accepted,
            summary.stale_blocks,
            summary.missing_blocks
        ),
        (1, 0, 0)
    );
    assert_eq!(summary.accel.lost_messages, 0);
    assert_eq!(summary.latency.count, 20);
}

#[test]
fn missing_and_stale_estimates_give_flagged_main_only_outputs() {
    let prefix = prefix();
    let mut config = Config::shipped().unwrap().with_prefix(&prefix).unwrap();
    // The estimate stage's rules: no vibration samples in these streams.
    config.model.waveform.stage = vibro_compensator::Stage::Estimate;
    // The whole vibration, as in the other tests here (mean readings).
    config.model.estimate.within_output_interval = false;
    let axes = config.model.triad.axes;
    let passports = config.model.triad.passports;
    let mut rig = Rig::new(&prefix);
    let service = Running::start(vibro_compensator::run, config);
    rig.wait_for_service();

    let t0_ns = 20_000_000_000u64;
    let output_v = |seq: u64| -> Vec<[f64; 3]> {
        (0..32)
            .map(|k| {
                let body = body_g(seq as usize * 32 + k);
                [0, 1, 2]
                    .map(|u| (axes.units[u].ia.project(&body) + 3e-3) * passports[u].k1_v_per_g)
            })
            .collect()
    };
    let block = |seq: u64| accel_block(seq, t0_ns + seq * 32_000_000, &output_v(seq));
    let main_only = |out: &CompensatedBlock| {
        for k in 0..32 {
            for u in 0..3 {
                assert_same_bits("a3 = a2", out.a3_g[k][u], out.a2_g[k][u]);
                assert_same_bits("a4 = a2", out.a4_g[k][u], out.a2_g[k][u]);
                assert_eq!((out.det_g[k][u], out.rand_g[k][u]), (0.0, 0.0));
            }
        }
    };

    // No estimate yet: main error only, against a kernel that never had a vibration.
    let mut reference = TriadCompensator::new(axes, passports, Mode::Exact);
    for seq in 0..3 {
        let b = block(seq);
        let out = rig.roundtrip(&b);
        assert_eq!(out.flags, cf::ESTIMATE_MISSING | cf::MAIN_ONLY);
        assert_eq!((out.estimate_seq, out.estimate_age_ns), (0, 0));
        main_only(&out);
        for k in 0..32 {
            let readings_g = [0, 1, 2].map(|u| b.output_v[k][u] / passports[u].k1_v_per_g);
            let r = reference.compensate(readings_g);
            for u in 0..3 {
                assert_same_bits("a1", out.a1_g[k][u], r.units[u].a1_g);
                assert_same_bits("a2", out.a2_g[k][u], r.units[u].a2_g);
            }
        }
    }

    // An estimate 5 s older than the block: stale.
    let vib = BodyVibration::rig();
    let b3 = block(3);
    rig.send_estimate(&vib.estimate(&axes, 0, block_end_ns(&b3) - 5_000_000_000));
    let out = rig.roundtrip(&b3);
    assert_eq!(out.flags, cf::VIBRATION_ESTIMATE_STALE | cf::MAIN_ONLY);
    assert_eq!((out.estimate_seq, out.estimate_age_ns), (0, 5_000_000_000));
    main_only(&out);

    // A fresh one (TONE_FREE is information, not a quality problem): full compensation.
    let b4 = block(4);
    let mut fresh = vib.estimate(&axes, 1, block_end_ns(&b4) - 500_000_000);
    fresh.flags = estimate_flags::TONE_FREE;
    rig.send_estimate(&fresh);
    let out = rig.roundtrip(&b4);
    assert_eq!(out.flags, 0);
    assert_eq!((out.estimate_seq, out.estimate_age_ns), (1, 500_000_000));
    assert!(
        out.det_g[0]
            .iter()
            .chain(&out.rand_g[0])
            .all(|c| c.abs() > 1e-7),
        "{:?} {:?}",
        out.det_g[0],
        out.rand_g[0]
    );

    // An estimate with a gap in its window: used, and the output says so.
    let b5 = block(5);
    let mut gappy = vib.estimate(&axes, 2, block_end_ns(&b5) - 400_000_000);
    gappy.flags = estimate_flags::GAP;
    rig.send_estimate(&gappy);
    let out = rig.roundtrip(&b5);
    assert_eq!(out.flags, cf::ESTIMATE_FLAGGED);
    assert_eq!(out.estimate_seq, 2);

    // An unusable estimate (NaN covariance) is rejected: the previous one stays in use...
    let mut broken = vib.estimate(&axes, 3, block_end_ns(&b5));
    broken.broadband_covariance_g2[1][1] = f64::NAN;
    rig.send_estimate(&broken);
    let out = rig.roundtrip(&block(6));
    assert_eq!((out.flags, out.estimate_seq), (cf::ESTIMATE_FLAGGED, 2));
    // ...until it is stale: 2 s after its window end. (The block is dated 1.5 s after
    // where its sample index puts it, a clock jump: flagged, and its timestamp is what
    // the staleness rule uses.)
    let mut late = block(7);
    late.t0_ns = gappy.end_ns + 2_000_000_001 - 31 * 1_000_000;
    let out = rig.roundtrip(&late);
    assert_eq!(
        out.flags,
        cf::VIBRATION_ESTIMATE_STALE | cf::MAIN_ONLY | cf::TIME_JUMP
    );
    assert_eq!(out.estimate_age_ns, 2_000_000_001);
    main_only(&out);

    let summary = service.stop();
    assert_eq!((summary.missing_blocks, summary.stale_blocks), (3, 2));
    assert_eq!(
        (summary.estimates_accepted, summary.estimates_rejected),
        (3, 1)
    );
    assert_eq!(summary.flagged_estimate_blocks, 2);
    assert_eq!(summary.time_jump_blocks, 1);
    assert_eq!(summary.estimates.received, 4);
    // none -> (stale: still none) -> 1 -> 2 -> (rejected: 2 kept) -> stale: none.
    assert_eq!(summary.vibration_updates, 3);
    assert!(summary.to_json().contains("\"stale_blocks\":2"));
}
