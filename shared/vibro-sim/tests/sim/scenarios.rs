//! The shipped scenarios load and say what RIG.md and MODEL.md say; broken scenarios
//! are reported with file, key path, value and rule, all problems at once.

use crate::common::*;
use vibro_sim::scenario::{Direction, EMBEDDED_SCENARIOS};
use vibro_sim::{resolve_scenario, Simulator};

#[test]
fn every_shipped_scenario_loads_from_its_file_and_embedded() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/scenarios");
    for (id, file, _) in EMBEDDED_SCENARIOS {
        let s = resolve_scenario(id).unwrap_or_else(|e| panic!("{id}: {e}"));
        assert_eq!(s.name, id);
        let name = std::path::Path::new(file).file_name().unwrap();
        let from_file = vibro_sim::load_scenario(&dir.join(name)).unwrap();
        assert_eq!(from_file.name, id, "{file}");
    }
}

#[test]
fn cyclone_4_is_the_flight_of_rig_md() {
    let s = resolve_scenario("cyclone-4").unwrap();
    let f = s.flight().unwrap();
    assert_eq!(f.duration_s, 600.0);
    // Longitudinal axis x: AK1's IA (RIG.md's "longitudinal (X)").
    assert_eq!(f.triad.axes.units[0].ia.to_string(), "+x");
    let mean = f.profile.mean(600.0);
    println!("cyclone-4 mean flight acceleration: {mean:?} g");
    assert!((mean[0] - 2.0).abs() < 1e-3, "mean aL = {} g", mean[0]);
    assert_eq!(f.profile.at(0.0), [1.0, 0.0, 0.0]);
    assert_eq!(f.profile.at(600.0), [5.0, 0.0, 0.0]);
    let short = resolve_scenario("cyclone-4-short").unwrap();
    let fs = short.flight().unwrap();
    assert_eq!(fs.duration_s, 20.0);
    assert!((fs.profile.mean(20.0)[0] - 2.0).abs() < 1e-3);
    assert_eq!(fs.profile.at(20.0), [5.0, 0.0, 0.0]);
    // What AK1 sees (MODEL.md section 10's example): aB3 = 0.5 g, aB1 = aB2 = 1.2 g,
    // sigma = 1.4 g on every axis.
    let sim = Simulator::new(&short, Vec::new()).unwrap();
    let v = sim.unit_vibration(0).unwrap();
    assert_eq!(v.tones()[0].amplitude_g, [1.2, 1.2, 0.5]);
    assert_eq!(v.tones()[0].freq_hz, 8.0);
    for i in 0..3 {
        assert!(
            (v.sigma_g(i) - 1.4).abs() < 1e-12,
            "sigma{} = {}",
            i + 1,
            v.sigma_g(i)
        );
    }
}

#[test]
fn tactical_flights_have_their_mean_accelerations() {
    for (id, duration_s, mean_g) in [("tactical-100s", 100.0, 5.1), ("tactical-300s", 300.0, 2.2)] {
        let s = resolve_scenario(id).unwrap();
        let f = s.flight().unwrap();
        assert_eq!(f.duration_s, duration_s);
        let m = f.profile.mean(duration_s);
        assert!((m[0] - mean_g).abs() < 1e-3, "{id}: mean {m:?}");
        let peak = f
            .profile
            .points()
            .iter()
            .map(|p| p.1[0])
            .fold(0.0, f64::max);
        assert_eq!(peak, 10.0, "{id}");
        let v = f.random.as_ref().unwrap().setup.variance_g2();
        assert!(v.iter().all(|s2| (s2 - 25.0).abs() < 1e-9), "{id}: {v:?}");
    }
}

#[test]
fn campaigns_expand_their_grids() {
    let grid = resolve_scenario("section8-grid").unwrap();
    let c = grid.campaign().unwrap();
    assert_eq!(c.conditions.len(), 3 * 3 * 3 * 2 + 3);
    assert!(c
        .conditions
        .iter()
        .any(|x| x.direction == Direction::IaPa45));
    let ten = resolve_scenario("ten-positions").unwrap();
    let c = ten.campaign().unwrap();
    assert_eq!(c.conditions.len(), 10);
    for (k, x) in c.conditions.iter().enumerate() {
        assert_eq!(x.tp as usize, k + 1);
        let ab = x.tone.unwrap().amplitude_g;
        match k {
            0..=7 => {
                assert_eq!(x.angle_deg, 45.0 * k as f64);
                assert_eq!(ab, [0.0, 0.0, 0.42]);
            }
            // sqrt(2) * 0.42 g at 45 deg: 0.42 g on each axis (MODEL.md section 9).
            8 => assert_eq!((x.a_l_unit_g, ab), ([1.0, 0.0, 0.0], [0.42, 0.0, 0.42])),
            _ => assert_eq!(ab, [0.0, 0.42, 0.42]),
        }
    }
    assert_eq!(
        c.conditions[2].a_l_unit_g,
        [1.0, 0.0, 0.0],
        "TP3: IA horizontal"
    );
    assert_eq!(c.conditions[4].a_l_unit_g, [0.0, 0.0, -1.0], "TP5: IA down");
    let random = resolve_scenario("random-runs").unwrap();
    let c = random.campaign().unwrap();
    assert_eq!(c.conditions.len(), 8);
    let band = c.conditions[0].random.as_ref().unwrap();
    assert!((band.setup.variance_g2()[2] - 38.4).abs() < 1e-9);
}

#[test]
fn errors_name_file_key_value_and_rule_all_at_once() {
    let text = shipped_text("cyclone-4-short")
        .replace("output_hz = 800", "output_hz = 1000")
        .replace("adc_bits = 24", "adc_bits = 40")
        .replace("t_s = 5.05", "t_s = 4.0")
        .replace(
            "rms_g = [1.4, 1.4, 1.4]",
            "rms_g = [1.4, -1.0, 1.4]\nkurtosis = [3.0, 2.0, 3.0]",
        )
        .replace("triad = \"default\"", "triad = \"nope\"");
    let e = vibro_sim::parse_scenario(&text, "bad.toml", None)
        .unwrap_err()
        .to_string();
    println!("{e}");
    for want in [
        "bad.toml: ",
        "rates.output_hz = 1000: must divide the internal rate 25600 Hz a whole number of times",
        "sensor.adc_bits = 40: must be 2..=32 bits",
        "flight.profile[2].t_s = 4: must be finite and greater than the previous t_s = 5",
        "flight.random.rms_g[1] = -1: must be finite within 0..=1000 g",
        "flight.random.kurtosis[1] = 2: must be within 3..=30",
        "flight.triad = \"nope\": ",
    ] {
        assert!(e.contains(want), "missing {want:?} in {e}");
    }
    let unknown =
        shipped_text("ten-positions").replace("still_s = 300.0", "still_s = 300.0\nstill_min = 5");
    let e = vibro_sim::parse_scenario(&unknown, "u.toml", None)
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("u.toml: ") && e.contains("still_min: unknown key"),
        "{e}"
    );
    let campaign = shipped_text("ten-positions")
        .replace("direction = [\"ia\"]", "direction = [\"ia\", \"oa\"]")
        .replace("vibrating_s = 300.0", "vibrating_s = 300.0001");
    let e = vibro_sim::parse_scenario(&campaign, "c.toml", None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            "campaign.grid[0].direction[1] = \"oa\": must be \"ia\", \"ia-oa-45\" or \"ia-pa-45\""
        ),
        "{e}"
    );
    assert!(
        e.contains("campaign.vibrating_s = 300.0001: must be a whole number of output intervals"),
        "{e}"
    );
}
