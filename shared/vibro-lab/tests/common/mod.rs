//! What the hidden-effect tests share: the simulated campaigns (the real time-domain
//! simulator, `vibro_sim`) turned into lab tables with measurement noise.

#![allow(dead_code)]

use std::path::Path;
use vibro_lab::CampaignTable;

/// The base campaign: tones along IA, IA+OA, IA+PA and OA+PA (84 conditions).
pub const BASE: &str = include_str!("../scenarios/hidden-base.toml");
/// Tones up to and past a servo loop's natural frequency (200..2400 Hz).
pub const KILOHERTZ: &str = include_str!("../scenarios/hidden-kilohertz.toml");
/// Random vibration along IA, described as Gaussian and as kurtosis 6.
pub const RANDOM: &str = include_str!("../scenarios/hidden-random.toml");

/// Resolution of the simulated VE measurement, g: Gaussian noise of this standard
/// deviation is added to every measured VE (seeded), and the uncertainty says so. A
/// real rig's section-8 measurement is good to about 1e-4 g (MODEL.md section 8); the
/// simulated effects here are 1e-6 to 1e-3 g, so 0.3 ug keeps them well resolved, and
/// above the sensor chain's own amplitude error (about 1e-5 of the amplitude).
pub const RESOLUTION_G: f64 = 3e-7;

/// Standard normal draws: SplitMix64 into Box-Muller.
pub struct Gaussian(pub u64);

impl Gaussian {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    pub fn next(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Simulates the campaign of scenario text `base` with `effect` appended and returns
/// its lab table, the measurement noise added.
pub fn campaign_of(base: &str, effect: &str) -> CampaignTable {
    let mut text = base.to_string();
    text.push_str(effect);
    // Relative references (a PSD table) are to files beside the scenarios.
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenarios");
    let scenario = vibro_sim::parse_scenario(&text, "hidden.toml", Some(&dir)).expect("scenario");
    let summaries = vibro_sim::run_campaign(
        &scenario,
        &vibro_sim::CampaignOptions { threads: 2 },
        &mut |_| {},
    )
    .expect("campaign");
    let mut table =
        CampaignTable::from_campaign(Path::new("hidden.csv"), &scenario, &summaries, RESOLUTION_G)
            .expect("table");
    let mut noise = Gaussian(0x5EED);
    for c in &mut table.conditions {
        c.ve_measured_g += RESOLUTION_G * noise.next();
    }
    table
}

/// An `[[effect]]` table to append to a scenario.
pub fn effect(text: &str) -> String {
    format!("\n[[effect]]\n{text}\n")
}
