//! The performance target: 600 s of Cyclone-4 (3 vibration channels at 25.6 kHz,
//! 3 accelerometers at the 25.6 kHz internal rate) in under 30 s on one core, in
//! release. Ignored by default (it measures, it does not check logic):
//!
//! ```text
//! cargo test --release -p vibro-sim --test sim -- --ignored --nocapture cyclone_4_600_s
//! ```

use std::ops::ControlFlow;
use std::time::Instant;
use vibro_sim::{resolve_scenario, Simulator};

#[test]
#[ignore]
fn cyclone_4_600_s_in_release() {
    let s = resolve_scenario("cyclone-4").unwrap();
    let start = Instant::now();
    let mut sim = Simulator::new(&s, Vec::new()).unwrap();
    let built = start.elapsed();
    let mut checksum = 0.0;
    let counts = sim
        .run(|c| {
            checksum += c.accel_v().iter().map(|r| r[0] + r[1] + r[2]).sum::<f64>();
            checksum += c.sensor_v().last().map_or(0.0, |r| r[0]);
            ControlFlow::Continue(())
        })
        .unwrap();
    let elapsed = start.elapsed();
    println!(
        "cyclone-4, 600 s: {} internal, {} sensor, {} output samples in {:.2} s (setup {:.3} s), {:.0} ns per internal sample; checksum {checksum:.6e}",
        counts.internal,
        counts.sensor,
        counts.output,
        elapsed.as_secs_f64(),
        built.as_secs_f64(),
        elapsed.as_nanos() as f64 / counts.internal as f64
    );
    assert_eq!(counts.output, 480_000);
    assert!(elapsed.as_secs_f64() < 30.0);
}
