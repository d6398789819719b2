//! Hot reload: rewriting the configuration file with another mode changes the mode of
//! the outputs within a couple of seconds, without a restart; an invalid file is
//! refused and the running model kept.

use crate::support::*;
use std::time::{Duration, Instant};
use vibro_compensator::Config;
use vibro_msgs::CompensationMode;
use vibro_service::ServiceConfig;

fn mode_of(rig: &mut Rig, seq: u64) -> CompensationMode {
    let out = rig.roundtrip(&accel_block(
        seq,
        seq * 32_000_000,
        &[[-1.6698, 0.0, 0.0]; 32],
    ));
    CompensationMode::try_from(out.mode).unwrap()
}

#[test]
fn a_changed_model_file_is_picked_up_and_a_bad_one_refused() {
    let dir = TempDir::new();
    let prefix = prefix();
    let path = dir.path("compensator.toml");
    std::fs::write(&path, config_text(&prefix, "exact", "default", "event")).unwrap();
    let mut rig = Rig::new(&prefix);
    let service = Running::start(vibro_compensator::run, Config::load(&path).unwrap());
    rig.wait_for_service();
    let mut seq = 0;
    let mut next = || {
        seq += 1;
        seq - 1
    };
    assert_eq!(mode_of(&mut rig, next()), CompensationMode::Exact);

    replace_file(&path, &config_text(&prefix, "paper", "default", "event"));
    let changed = Instant::now();
    let mut switched = None;
    while changed.elapsed() < Duration::from_secs(3) {
        if mode_of(&mut rig, next()) == CompensationMode::Paper {
            switched = Some(changed.elapsed());
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let switched = switched.expect("the new mode within 3 s");
    println!(
        "hot reload: outputs in the new mode {:.0} ms after the file changed",
        switched.as_secs_f64() * 1e3
    );

    // An invalid file: logged, the paper model stays.
    replace_file(&path, &config_text(&prefix, "fast", "default", "event"));
    let start = Instant::now();
    while start.elapsed() < Duration::from_millis(400) {
        assert_eq!(mode_of(&mut rig, next()), CompensationMode::Paper);
        std::thread::sleep(Duration::from_millis(20));
    }
    // Fixed again, as-published this time.
    replace_file(
        &path,
        &config_text(&prefix, "as-published", "default", "event"),
    );
    let start = Instant::now();
    while mode_of(&mut rig, next()) != CompensationMode::AsPublished {
        assert!(
            start.elapsed() < Duration::from_secs(3),
            "as-published within 3 s"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let summary = service.stop();
    assert_eq!(summary.reloads_applied, 2);
    assert_eq!(summary.reload_errors, 1);
    assert_eq!(summary.mode, CompensationMode::AsPublished);
    assert_eq!(summary.accel.lost_messages, 0);
}

/// The extended model (`model = ...`) is watched like the configuration: rewriting
/// the model file with another coefficient changes the outputs within a few seconds,
/// by the effect's closed form (`anisoelastic`: `k_ae E[v1 v2]`, docs/effects.md); a
/// bad model file is refused and the running model kept.
#[test]
fn a_changed_extended_model_is_picked_up_live() {
    let dir = TempDir::new();
    let prefix = prefix();
    let path = dir.path("compensator.toml");
    let model = dir.path("model.toml");
    let write_model = |k: &str| {
        replace_file(
            &model,
            &format!("mode = \"exact\"\n[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = {k}\n"),
        )
    };
    write_model("0.0");
    std::fs::write(
        &path,
        config_text(&prefix, "exact", "default", "event").replacen(
            "triad = \"default\"\n",
            "triad = \"default\"\nmodel = \"model.toml\"\n",
            1,
        ),
    )
    .unwrap();
    let config = Config::load(&path).unwrap();
    let axes = config.model.triad.axes;
    let mut rig = Rig::new(&prefix);
    let service = Running::start(vibro_compensator::run, config);
    rig.wait_for_service();
    let vib = BodyVibration::rig();
    // E[v1 v2] per unit, from the body-frame description.
    let e12 = axes.units.map(|u| {
        let v = vib.at_unit(&u);
        v.tones()
            .iter()
            .map(|t| {
                0.5 * t.amplitude_g[0] * t.amplitude_g[1] * (t.phase_rad[0] - t.phase_rad[1]).cos()
            })
            .sum::<f64>()
            + v.covariance_g2[0][1]
    });
    let mut seq = 0u64;
    let mut step = |rig: &mut Rig| {
        let block = accel_block(seq, seq * 32_000_000, &[[-1.6698, 0.2, 0.3]; 32]);
        rig.send_estimate(&vib.estimate(&axes, seq + 1, block_end_ns(&block)));
        seq += 1;
        rig.roundtrip(&block)
    };
    let first = step(&mut rig);
    assert_ne!(
        first.flags & vibro_msgs::compensation_flags::MODEL_EFFECTS,
        0
    );
    let k_ae = 2.0e-5;
    write_model("2.0e-5");
    let changed = Instant::now();
    let moved = loop {
        let out = step(&mut rig);
        // Newton's warm start moves the stages by ~1e-16 g from block to block; the
        // effect is 1e-6 g.
        if (out.rand_g[0][0] - first.rand_g[0][0]).abs() > 1e-9 {
            break out;
        }
        assert!(
            changed.elapsed() < Duration::from_secs(3),
            "the new model within 3 s"
        );
        std::thread::sleep(Duration::from_millis(10));
    };
    println!(
        "hot reload: the new extended model {:.0} ms after the file changed",
        changed.elapsed().as_secs_f64() * 1e3
    );
    for u in 0..3 {
        let d = moved.rand_g[0][u] - first.rand_g[0][u];
        assert!(
            (d - k_ae * e12[u]).abs() < 1e-15,
            "unit {u}: {d:e} vs {:e}",
            k_ae * e12[u]
        );
    }
    // A bad model file: refused, the running model kept.
    replace_file(
        &model,
        "mode = \"exact\"\n[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 5.0\n",
    );
    let start = Instant::now();
    while start.elapsed() < Duration::from_millis(400) {
        let out = step(&mut rig);
        assert!((out.rand_g[0][0] - moved.rand_g[0][0]).abs() < 1e-14);
        std::thread::sleep(Duration::from_millis(20));
    }
    let summary = service.stop();
    assert_eq!(summary.reloads_applied, 1);
    assert!(summary.reload_errors >= 1);
    assert_eq!(summary.model_effect_errors, 0);
}
