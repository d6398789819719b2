//! Prints the synthetic section-8 run `config/campaigns/shake-run-al15.csv`:
//!
//! ```text
//! cargo run -q -p vibro-ident --example shake_run_fixture > config/campaigns/shake-run-al15.csv
//! ```
//!
//! An AL-15 in TP3 (IA horizontal) under 0.42 g along IA: the VE is d0(1) of MODEL.md
//! section 5, 13.3908 ug; the output noise is AR(1), as a real unit's is correlated.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const K1_V_PER_G: f64 = -1.6698;
const A0_G: f64 = 3.324e-3;
/// d0(1) = 0.637*d1A*aB + 0.5*k2*aB^2 + 0.375*k4*aB^4 at aB = 0.42 g.
const VE_G: f64 =
    0.637 * 15e-6 * 0.42 + 0.5 * 105e-6 * 0.42 * 0.42 + 0.375 * 10e-6 * (0.42 * 0.42 * 0.42 * 0.42);
const N_SAMPLES: usize = 600;
const NOISE_SD_V: f64 = 5e-6;
const PHI: f64 = 0.5;
const SEED: u64 = 20;

fn main() {
    println!("# Synthetic shake-table run (MODEL.md section 8) of the AL-15, TP3 (IA horizontal).");
    println!("# Regenerate: cargo run -q -p vibro-ident --example shake_run_fixture > config/campaigns/shake-run-al15.csv");
    println!(
        "# still1_v = still2_v = K1*a0 + noise, vib_v = K1*(a0 + dV) + noise, K1 = -1.6698 V/g,"
    );
    println!(
        "#   a0 = 3.324e-3 g, dV = d0(1) = 0.637*d1A*aB + 0.5*k2*aB^2 + 0.375*k4*aB^4 = {VE_G:e} g"
    );
    println!("#   (aB = 0.42 g, d1A = 15e-6, k2 = 105e-6 /g, k4 = 10e-6 /g^3).");
    println!("# Noise: AR(1) x_k = {PHI}*x_(k-1) + e_k, stationary sd {NOISE_SD_V:e} V, ChaCha8 seed {SEED};");
    println!("#   {N_SAMPLES} samples per record, values rounded to 1e-10 V.");
    println!("still1_v,vib_v,still2_v");
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let innovation = match Normal::new(0.0, NOISE_SD_V * (1.0 - PHI * PHI).sqrt()) {
        Ok(n) => n,
        Err(e) => {
            eprintln!("bad noise parameters: {e}");
            std::process::exit(1);
        }
    };
    let still_v = K1_V_PER_G * A0_G;
    let vib_v = K1_V_PER_G * (A0_G + VE_G);
    let mut records = [Vec::new(), Vec::new(), Vec::new()];
    let mut x = 0.0;
    for (record, level_v) in records.iter_mut().zip([still_v, vib_v, still_v]) {
        for _ in 0..N_SAMPLES {
            x = PHI * x + innovation.sample(&mut rng);
            record.push(level_v + x);
        }
    }
    let [still1, vib, still2] = &records;
    for ((u1, u2), u3) in still1.iter().zip(vib).zip(still2) {
        println!("{u1:.10},{u2:.10},{u3:.10}");
    }
}
