//! The compensator's per-estimate update in a loop, for a profiler: the criterion
//! benchmark's triad and vibration, `TriadCompensator::set_vibration` on every unit.
//!
//! ```sh
//! cargo build --release -p vibro-physics --example prof_set_vibration
//! perf record -e cpu-clock -g target/release/examples/prof_set_vibration 2000
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
    let updates: u64 = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 1000,
    };
    let start = std::time::Instant::now();
    for _ in 0..updates {
        for i in 0..3 {
            triad.set_vibration(i, black_box(&vib))?;
        }
    }
    println!(
        "updates {updates}  us per triad update {:.1}",
        start.elapsed().as_secs_f64() * 1e6 / updates as f64
    );
    Ok(())
}
