//! The compensator's handling of one accelerometer block (32 samples, exact mode, with
//! a vibration estimate) without the transport, in a loop: what the latency command's
//! processing hop costs when the caches are warm.
//!
//! ```sh
//! cargo run --release -p vibro-compensator --example prof_block -- 20000
//! ```

use vibro_compensator::{Config, InProcess};
use vibro_msgs::{AccelBlock, CompensatedBlock, VibEstimate};
use vibro_service::ServiceConfig;

fn main() -> anyhow::Result<()> {
    let config = Config::load_default()?;
    let k1 = config.model.triad.passports.map(|p| p.k1_v_per_g);
    let mut comp = InProcess::new(&config)?;
    let blocks: u64 = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 20_000,
    };
    // One estimate: a 12 Hz tone on every sensor axis and 1.4 g RMS broadband.
    let mut e = VibEstimate::ZEROED;
    e.end_ns = 500_000_000;
    e.tone_count = 1;
    e.tone_frequency_hz[0] = 12.0;
    e.tone_amplitude_g[0] = [0.5, 1.2, 1.2];
    e.broadband_covariance_g2 = [[1.96, 0.0, 0.0], [0.0, 1.96, 0.0], [0.0, 0.0, 1.96]];
    e.broadband_kurtosis = [3.0; 3];
    comp.on_estimate(&e);
    let mut out: Vec<CompensatedBlock> = Vec::with_capacity(1);
    let mut b = AccelBlock::ZEROED;
    b.count = 32;
    b.sample_period_ns = 1_250_000;
    let start = std::time::Instant::now();
    let mut published = 0u64;
    for k in 0..blocks {
        b.seq = k;
        b.first_sample_index = 32 * k;
        // Always within the estimate's age limit: dated just after its window.
        b.t0_ns = 500_000_000 + (32 * k * 1_250_000) % 100_000_000;
        for i in 0..32 {
            let d = ((32 * k + i as u64) % 1000) as f64 * 1e-4;
            b.output_v[i] = [0.3 + d, -0.2 + d, 2.0 + d].map(|g| g * k1[0]);
        }
        out.clear();
        comp.on_accel(&b, 0, &mut out);
        published += out.len() as u64;
    }
    let s = comp.summary();
    println!(
        "blocks {blocks} published {published} stale {} missing {}  us per block {:.2}",
        s.stale_blocks,
        s.missing_blocks,
        start.elapsed().as_secs_f64() * 1e6 / blocks as f64
    );
    Ok(())
}
