//! A flight: the accelerometer outputs, averaged, tend to the exact mean output of the
//! truth (the VE emerges from the signal along a varying flight acceleration), and the
//! truth's flight acceleration is the profile's, rotated to each unit's axes.

use crate::common::*;
use vibro_sim::{ScenarioKind, Simulator};

#[test]
fn flight_outputs_average_to_the_exact_mean_output_of_the_truth() {
    // Cyclone-4 stretched to 60 s (same profile shape, sweep 8 -> 16 Hz in 60 s), with
    // every AL-15's nonlinear coefficients times 50 so that the VE (1e-2..1e-1 g)
    // stands far above the spread of a 60 s mean.
    let text = shipped_text("cyclone-4")
        .replace("duration_s = 600.0", "duration_s = 60.0")
        .replace("t_s = 150.0", "t_s = 15.0")
        .replace("t_s = 151.0", "t_s = 15.1")
        .replace("t_s = 400.0", "t_s = 40.0")
        .replace("t_s = 401.0", "t_s = 40.1")
        .replace("t_s = 600.0", "t_s = 60.0");
    let mut s = parse(&text);
    let p = exaggerated("AL-15", 50.0);
    if let ScenarioKind::Flight(f) = &mut s.kind {
        f.triad.passports = [p; 3];
    }
    let f = s.flight().unwrap().clone();
    let mut sim = Simulator::new(&s, Vec::new()).unwrap();
    let r = record(&mut sim);
    assert_eq!(r.accel_v.len(), 48_000);
    for unit in 0..3 {
        let residual: Vec<f64> = r
            .accel_v
            .iter()
            .zip(&r.truth)
            .map(|(a, t)| a[unit] / p.k1_v_per_g - t.exact_mean_output_g[unit])
            .collect();
        let (mean, se) = batch_mean(&residual, 20);
        let ve: f64 =
            r.truth.iter().map(|t| t.exact_ve_g[unit]).sum::<f64>() / r.truth.len() as f64;
        let z = mean / se;
        println!("unit {unit}: <U/K1 - E[aF]> = {mean:+.3e} +- {se:.1e} g (z = {z:+.2}); mean exact VE {ve:+.4e} g = {:.0} sigma", ve / se);
        assert!(z.abs() < 4.0, "unit {unit}: z = {z}");
        assert!(ve.abs() > 10.0 * se, "unit {unit}: the VE must be resolved");
    }
    // The truth's flight acceleration: AK1 (IA = +x, OA = +y, PA = +z) sees
    // [aL_y, aL_z, aL_x]; the mean over the 32 internal samples (at t = n/fs) of an
    // output interval on a linear segment is the value at their middle.
    let k = 12_345;
    let mid_s = (k as f64 * 32.0 + 15.5) / 25_600.0;
    let want = f.profile.at(mid_s);
    let got = r.truth[k].a_l_unit_g;
    assert!(
        (got[0][2] - want[0]).abs() < 1e-12 && got[0][0] == 0.0,
        "{got:?} vs {want:?}"
    );
    assert!(
        (got[1][1] - want[0]).abs() < 1e-12,
        "AK2 (IA = +y, OA = +z, PA = +x): aL2 = aL_x"
    );
    assert!(
        (got[2][0] - want[0]).abs() < 1e-12,
        "AK3 (IA = +z, OA = +x): aL1 = aL_x"
    );
}
