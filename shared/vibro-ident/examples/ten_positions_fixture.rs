//! Prints the synthetic ten-position campaigns of `config/campaigns/`:
//!
//! ```text
//! cargo run -q -p vibro-ident --example ten_positions_fixture > config/campaigns/ten-positions-al15.csv
//! cargo run -q -p vibro-ident --example ten_positions_fixture -- 0.2 0.42 0.8 > config/campaigns/three-amplitudes-al15.csv
//! ```
//!
//! Arguments: the vibration amplitudes aB in g (default 0.42), ten positions each.
//! The data are noise-free and follow MODEL.md section 5's formulas for the AL-15
//! passport, so identification must give back section 5's components exactly.

use vibro_ident::cos_deg;

/// AL-15 passport (config/accelerometers/al-15.toml), acceleration units.
const K1_V_PER_G: f64 = -1.6698;
const A0_G: f64 = 3.324e-3;
const D1A: f64 = 15e-6;
const K2_PER_G: f64 = 105e-6;
const K3_PER_G2: f64 = 87e-6;
const K4_PER_G3: f64 = 10e-6;
const K5_PER_G4: f64 = 0.9e-6;
const M31_PER_G: f64 = 11.6e-6;
const M32_PER_G: f64 = 11.6e-6;
/// Stated standard uncertainty of each dU, V (not applied as noise).
const U_SIGMA_V: f64 = 2e-6;

const HEADER: &str = "\
# Passport AL-15 (config/accelerometers/al-15.toml): K1 = -1.6698 V/g, a0 = 3.324e-3 g,
#   d1A = 15e-6, k2 = 105e-6 /g, k3 = 87e-6 /g^2, k4 = 10e-6 /g^3, k5 = 0.9e-6 /g^4,
#   m31 = m32 = 11.6e-6 /g, lambda = k1 = 1.
# Positions: TP k = 1..8 at (k-1)*45 deg with aB along IA; TP9 and TP10 at 90 deg
#   (IA horizontal) with aB along IA and OA (TP9) or IA and PA (TP10).
# Components at aB3 = aB, MODEL.md section 5 [P1 (15)-(16)]:
#   d0(1) = 0.637*d1A*aB3 + 0.5*k2*aB3^2 + 0.375*k4*aB3^4
#   d0(2) = 0.5*m31*aB3*aB1, d0(3) = 0.5*m32*aB3*aB2
#   delta(1) = 1.5*k3*aB3^2 + 1.875*k5*aB3^4, delta(2) = 3*k4*aB3^2, delta(3) = 5*k5*aB3^2
# Columns: g3 = cos(angle_deg) (gravity on IA, g = 1 g);
#   u_still_v = K1*(a0 + g3)   (the still output; only the difference dU matters)
#   u_vib_v   = u_still_v + K1*(d0(1) + d0(2) + d0(3) + delta(1)*g3 + delta(2)*g3^2 + delta(3)*g3^3)  [P1 (21)]
#     with d0(2) only where aB1_g > 0 and d0(3) only where aB2_g > 0
#   u_sigma_v = 2e-6: the stated standard uncertainty of dU = u_vib_v - u_still_v.
";

fn main() {
    let mut amplitudes_g = Vec::new();
    for arg in std::env::args().skip(1) {
        match arg.parse::<f64>() {
            Ok(a) if a.is_finite() && a > 0.0 => amplitudes_g.push(a),
            _ => {
                eprintln!("{arg:?}: each argument must be a vibration amplitude > 0 g");
                std::process::exit(2);
            }
        }
    }
    if amplitudes_g.is_empty() {
        amplitudes_g.push(0.42);
    }
    let list = amplitudes_g
        .iter()
        .map(f64::to_string)
        .collect::<Vec<_>>()
        .join(" ");
    let (name, args) = if amplitudes_g == [0.42] {
        ("ten-positions-al15.csv", String::new())
    } else {
        ("three-amplitudes-al15.csv", format!(" -- {list}"))
    };
    println!(
        "# Synthetic shake-table campaign of the AL-15 (MODEL.md section 9), NOISE-FREE: the ten \
         standard positions at aB = {list} g."
    );
    println!(
        "# Regenerate: cargo run -q -p vibro-ident --example ten_positions_fixture{args} > \
         config/campaigns/{name}"
    );
    print!("{HEADER}");
    println!("tp,angle_deg,aB3_g,aB1_g,aB2_g,u_still_v,u_vib_v,u_sigma_v");
    for (tp, a3) in amplitudes_g
        .iter()
        .flat_map(|a| (1..=10u32).map(move |tp| (tp, *a)))
    {
        let (angle_deg, a_b1_g, a_b2_g) = match tp {
            9 => (90.0, a3, 0.0),
            10 => (90.0, 0.0, a3),
            k => (f64::from(k - 1) * 45.0, 0.0, 0.0),
        };
        let d01 = 0.637 * D1A * a3 + 0.5 * K2_PER_G * a3.powi(2) + 0.375 * K4_PER_G3 * a3.powi(4);
        let d02 = 0.5 * M31_PER_G * a3 * a_b1_g;
        let d03 = 0.5 * M32_PER_G * a3 * a_b2_g;
        let delta1 = 1.5 * K3_PER_G2 * a3.powi(2) + 1.875 * K5_PER_G4 * a3.powi(4);
        let delta2 = 3.0 * K4_PER_G3 * a3.powi(2);
        let delta3 = 5.0 * K5_PER_G4 * a3.powi(2);
        let g3 = cos_deg(angle_deg);
        let ve_g = d01 + d02 + d03 + delta1 * g3 + delta2 * g3 * g3 + delta3 * g3 * g3 * g3;
        let u_still_v = K1_V_PER_G * (A0_G + g3);
        let u_vib_v = u_still_v + K1_V_PER_G * ve_g;
        println!("{tp},{angle_deg},{a3},{a_b1_g},{a_b2_g},{u_still_v},{u_vib_v},{U_SIGMA_V}");
    }
}
