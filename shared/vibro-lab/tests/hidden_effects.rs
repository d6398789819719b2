//! Hidden-effect tests (issue 6): the real time-domain simulator runs a shake-table
//! campaign with one physical effect switched on; the lab, given the model of MODEL.md
//! alone, must find that effect, and the model with the fitted effect added must bring
//! the residual down at least 10x or to within 2x the noise floor.

use std::path::Path;
use std::time::Instant;
use vibro_lab::{
    add_effect, compare, diagnose, BaseMode, CampaignTable, DiagnoseOptions, LabModel, Verdict,
};

const BASE: &str = include_str!("scenarios/hidden-base.toml");

/// Resolution of the simulated VE measurement, g: Gaussian noise of this standard
/// deviation is added to every measured VE (seeded), and the uncertainty says so. A
/// real rig's section-8 measurement is good to about 1e-4 g (MODEL.md section 8); the
/// simulated effects here are 1e-6 to 1e-3 g, so 0.3 ug keeps them well resolved, and
/// above the sensor chain's own amplitude error (about 1e-5 of the amplitude).
const RESOLUTION_G: f64 = 3e-7;

/// Standard normal draws: SplitMix64 into Box-Muller.
struct Gaussian(u64);

impl Gaussian {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn next(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Simulates the base campaign with `effect` (an `[[effect]]` table, or "" for none)
/// and returns its lab table.
fn campaign(effect: &str, grid_filter: Option<&str>) -> CampaignTable {
    let mut text = BASE.to_string();
    if let Some(f) = grid_filter {
        text = f.to_string();
    }
    text.push_str(effect);
    let scenario = vibro_sim::parse_scenario(&text, "hidden.toml", None).expect("scenario");
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

/// The diagnosis of `table` by the model of MODEL.md alone, exact mode.
fn diagnose_base(table: &CampaignTable) -> vibro_lab::Diagnosis {
    diagnose(
        &LabModel::base(BaseMode::Exact),
        table,
        &DiagnoseOptions::default(),
    )
    .expect("diagnose")
}

struct Found {
    rms_before_g: f64,
    rms_after_g: f64,
    noise_floor_g: f64,
}

/// Diagnose, check `kind` is found first, add it, check the residual falls.
fn find_and_add(kind: &str, effect: &str, truth: &[(&str, f64)]) -> Found {
    let t0 = Instant::now();
    let table = campaign(effect, None);
    let t_sim = t0.elapsed();
    let model = LabModel::base(BaseMode::Exact);
    let d = diagnose(&model, &table, &DiagnoseOptions::default()).expect("diagnose");
    let t_diag = t0.elapsed();
    let ranking: Vec<String> = d
        .candidates
        .iter()
        .map(|c| {
            format!(
                "{} {:.1}",
                c.kind,
                c.fit.as_ref().map_or(f64::NAN, |f| f.delta_bic)
            )
        })
        .collect();
    match &d.verdict {
        Verdict::Effect { kind: k, .. } => assert_eq!(k, kind, "ranking: {ranking:?}"),
        v => panic!("{kind}: verdict {v:?}; ranking {ranking:?}"),
    }
    assert_eq!(d.candidates[0].kind, kind);
    let (extended, fit) = add_effect(&model, &table, kind).expect("add");
    let after = compare(&extended, &table).expect("compare");
    let before = &d.comparison.summary;
    let found = Found {
        rms_before_g: before.rms_residual_g,
        rms_after_g: after.summary.rms_residual_g,
        noise_floor_g: before.noise_floor_g,
    };
    let limit = (found.rms_before_g / 10.0).max(2.0 * found.noise_floor_g);
    println!(
        "FIGURES {kind}: n {} rms before {:.3e} g after {:.3e} g (limit {:.3e}) noise floor {:.3e} g delta_bic {:.1} params {:?} truth {truth:?} next {:?} sim {:.2?} diagnose {:.2?}",
        table.conditions.len(),
        found.rms_before_g,
        found.rms_after_g,
        limit,
        found.noise_floor_g,
        fit.delta_bic,
        fit.params.iter().map(|p| (p.name.as_str(), p.value, p.sigma)).collect::<Vec<_>>(),
        ranking.get(1),
        t_sim,
        t_diag - t_sim,
    );
    assert!(
        found.rms_after_g <= limit,
        "{kind}: {:.3e} > {limit:.3e}",
        found.rms_after_g
    );
    for (name, want) in truth {
        let p = fit.params.iter().find(|p| p.name == *name).expect("param");
        // Phases enter through cos(): +-phase fit alike.
        let value = if name.ends_with("_deg") {
            p.value.abs()
        } else {
            p.value
        };
        assert!(
            (value - want.abs()).abs() <= 0.02 * want.abs(),
            "{kind}.{name}: fitted {} +- {} vs truth {want}",
            p.value,
            p.sigma
        );
    }
    found
}

#[test]
fn mount_resonance_is_found_and_its_error_removed() {
    find_and_add(
        "mount_resonance",
        "\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56\n",
        &[("freq_hz", 48.0), ("q", 1.56)],
    );
}

fn effect(text: &str) -> String {
    format!("\n[[effect]]\n{text}\n")
}

#[test]
fn axis_phase_is_found_and_its_error_removed() {
    find_and_add(
        "axis_phase",
        &effect("kind = \"axis_phase\"\nphase_x_deg = 60.0\nphase_y_deg = -40.0"),
        &[("phase_x_deg", 60.0), ("phase_y_deg", 40.0)],
    );
}

#[test]
fn vibropendulous_is_found_and_its_error_removed() {
    find_and_add(
        "vibropendulous",
        &effect("kind = \"vibropendulous\"\nc_rad_per_g = 2.0e-4\ntau_s = 0.002"),
        &[("c_rad_per_g", 2.0e-4), ("tau_s", 0.002)],
    );
}

#[test]
fn anisoelastic_is_found_and_its_error_removed() {
    find_and_add(
        "anisoelastic",
        &effect("kind = \"anisoelastic\"\nk_ae_per_g = 2.0e-5"),
        &[("k_ae_per_g", 2.0e-5)],
    );
}

#[test]
fn saturation_is_found_and_its_error_removed() {
    find_and_add(
        "saturation",
        &effect("kind = \"saturation\"\nrange_g = 3.5"),
        &[("range_g", 3.5)],
    );
}

#[test]
fn high_order_nonlinearity_is_found_and_its_error_removed() {
    find_and_add(
        "high_order_nonlinearity",
        &effect("kind = \"high_order_nonlinearity\"\nk6_ppm_per_g5 = 0.05\nk7_ppm_per_g6 = 0.01"),
        &[("k6_ppm_per_g5", 0.05), ("k7_ppm_per_g6", 0.01)],
    );
}

/// With one record length the lab fits the steady-state coefficient (library.rs), so
/// the fitted value is not compared with `c_g_per_g2`.
#[test]
fn heating_is_found_and_its_error_removed() {
    find_and_add(
        "heating",
        &effect("kind = \"heating\"\nc_g_per_g2 = 2.0e-6\ntau_s = 1.0"),
        &[],
    );
}

#[test]
fn a_sensor_gain_error_is_found_and_its_error_removed() {
    find_and_add(
        "sensor_error",
        &effect("kind = \"sensor_error\"\ngain_error = 0.03"),
        &[("gain_error", 0.03)],
    );
}

/// Nothing hidden: the model passes the chi-square test and nothing is attributed.
#[test]
fn without_a_hidden_effect_nothing_is_reported() {
    let table = campaign("", None);
    let d = diagnose_base(&table);
    let s = &d.comparison.summary;
    println!(
        "FIGURES none: n {} rms {:.3e} g chi2/dof {:.3} p {:.3} best {} {:.1}",
        s.n,
        s.rms_residual_g,
        s.chi2_per_dof,
        s.p_value,
        d.candidates[0].kind,
        d.candidates[0]
            .fit
            .as_ref()
            .map_or(f64::NAN, |f| f.delta_bic)
    );
    assert!(
        matches!(d.verdict, Verdict::Noise { .. }),
        "{:?}",
        d.verdict
    );
    assert!(
        d.candidates.iter().all(|c| !c.supported),
        "a candidate is supported"
    );
}

/// The scale factor's frequency dependence (lambda(w), [P1 (1)]) is kept out of the
/// library (library.rs): its VE, `0.5 k1 d1A E[sign(a3) (L v3 - v3)]`, is odd in
/// the flight acceleration in a way no candidate reproduces. It must be reported as
/// structure the library does not explain, not given to a wrong effect.
#[test]
fn an_effect_outside_the_library_is_unexplained_not_misattributed() {
    let table = campaign(
        &effect("kind = \"scale_factor_frequency\"\ncorner_hz = 60.0\nlambda_hf = 1.5"),
        None,
    );
    let d = diagnose_base(&table);
    let s = &d.comparison.summary;
    println!(
        "FIGURES outside: n {} rms {:.3e} g chi2/dof {:.1} verdict {:?}",
        s.n, s.rms_residual_g, s.chi2_per_dof, d.verdict
    );
    assert!(
        matches!(d.verdict, Verdict::Unexplained { .. }),
        "{:?}",
        d.verdict
    );
}

/// One frequency and one amplitude along IA: a mount resonance only scales the
/// amplitude there, as a sensor gain error does, and the lab must say it cannot tell
/// them apart, and suggest conditions that would (another frequency).
#[test]
fn a_design_that_cannot_tell_two_effects_apart_is_called_confounded() {
    let narrow = BASE
        .split("[[campaign.grid]]")
        .next()
        .unwrap()
        .to_string()
        + "[[campaign.grid]]\nangle_deg = [0.0, 90.0, 180.0]\ntilt_toward = \"oa\"\ndirection = [\"ia\"]\ntone_amplitude_g = [2.0]\ntone_freq_hz = [40.0]\n";
    let table = campaign(
        &effect("kind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56"),
        Some(&narrow),
    );
    let d = diagnose_base(&table);
    println!(
        "FIGURES confounded: n {} verdict {:?}",
        table.conditions.len(),
        d.verdict
    );
    let Verdict::Confounded {
        kinds, suggestions, ..
    } = &d.verdict
    else {
        panic!("{:?}", d.verdict);
    };
    assert!(kinds.iter().any(|k| k == "mount_resonance"), "{kinds:?}");
    assert!(kinds.len() >= 2);
    assert!(!suggestions.is_empty());
    assert!(
        suggestions[0].description.contains("Hz") && suggestions[0].separation_sigma > 3.0,
        "{:?}",
        suggestions[0]
    );
}
