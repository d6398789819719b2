//! The exact compensation kernel in a loop, for a profiler: the criterion benchmark's
//! triad, vibration and readings, without criterion's machinery, so that
//! `valgrind --tool=callgrind` counts the kernel's instructions per sample (a figure
//! that does not depend on what else the machine is doing; see BENCHMARKS.md).
//!
//! ```sh
//! cargo build --release -p vibro-physics --example prof_kernel
//! valgrind --tool=callgrind target/release/examples/prof_kernel 100000
//! ```

use std::hint::black_box;
use vibro_physics::compensation::{Mode, TriadCompensator};
use vibro_physics::passport::{Passport, PassportSpec};
use vibro_physics::triad::TriadAxes;
use vibro_physics::vibration::Vibration;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let spec: PassportSpec =
        toml::from_str(include_str!("../../../config/accelerometers/al-15.toml"))?;
    let passport = Passport::try_from_spec(&spec)?;
    let mut vib = Vibration::single_tone(12.0, [1.2, 1.2, 0.5]);
    vib.covariance_g2 = [[1.0, 0.0, 0.3], [0.0, 1.0, 0.0], [0.3, 0.0, 1.96]];
    let mut triad = TriadCompensator::new(TriadAxes::standard(), [passport; 3], Mode::Exact);
    for i in 0..3 {
        triad.set_vibration(i, &vib)?;
    }
    let samples: u64 = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 1_000_000,
    };
    let mut iterations = 0u64;
    let start = std::time::Instant::now();
    for k in 0..samples {
        // As in the benchmark: 0.1 mg per sample, a 0.1 g jump every 1000 samples.
        let d = (k % 1000) as f64 * 1e-4;
        let out = triad.compensate(black_box([0.3 + d, -0.2 + d, 2.0 + d]));
        iterations += u64::from(out.iterations);
    }
    let elapsed = start.elapsed();
    println!(
        "samples {samples}  Newton steps per sample {:.3}  ns per sample {:.1}",
        iterations as f64 / samples as f64,
        elapsed.as_nanos() as f64 / samples as f64
    );
    Ok(())
}
