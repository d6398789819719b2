//! Hot reload: rewriting the configuration file with another mode changes the mode of
//! the outputs within a couple of seconds, without a restart; an invalid file is
//! refused and the running model kept.

use crate::support::*;
use std::time::{Duration, Instant};
use vibro_compensator::Config;
use vibro_msgs::CompensationMode;

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
    let service = Running::start(Config::load(&path).unwrap());
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
