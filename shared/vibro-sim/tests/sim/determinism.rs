//! Reproducibility: the same scenario and seed give bit-identical output whatever the
//! chunking; another seed gives other output; switching an effect on leaves the
//! random draws of the other sources unchanged (common random numbers).

use crate::common::*;
use vibro_effects::{BlockCtx, Effect, MeanContext};
use vibro_physics::vibration::Vibration;
use vibro_sim::Simulator;

/// Cyclone-4 (tones, p1-table3 random, sensors with noise) shortened to `seconds`.
fn cyclone(seconds: f64, seed: u64) -> vibro_sim::Scenario {
    parse(
        &shipped_text("cyclone-4-short")
            .replace("duration_s = 20.0", &format!("duration_s = {seconds}"))
            .replace("seed = 4", &format!("seed = {seed}")),
    )
}

/// FNV-1a over every sample and timestamp of a run.
fn hash(r: &Record) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for rows in [&r.body_g, &r.sensor_v, &r.accel_v] {
        for row in rows.iter() {
            row.iter().for_each(|v| eat(v.to_bits()));
        }
    }
    for t in &r.truth {
        t.a_l_unit_g.iter().flatten().for_each(|v| eat(v.to_bits()));
        t.exact_mean_output_g.iter().for_each(|v| eat(v.to_bits()));
        t.exact_ve_g.iter().for_each(|v| eat(v.to_bits()));
    }
    r.sensor_time_ns
        .iter()
        .chain(&r.output_end_ns)
        .for_each(|t| eat(*t));
    h
}

#[test]
fn same_seed_is_bit_identical_and_another_seed_differs() {
    let run = |seed| record(&mut Simulator::new(&cyclone(2.0, seed), Vec::new()).unwrap());
    let (a, b, c) = (run(4), run(4), run(5));
    assert_eq!(a.accel_v.len(), 1600);
    assert_eq!(a.sensor_v.len(), 51_200);
    assert_eq!(hash(&a), hash(&b));
    assert_ne!(hash(&a), hash(&c));
    // Not just the hash: the samples themselves differ everywhere.
    let same = a
        .sensor_v
        .iter()
        .zip(&c.sensor_v)
        .filter(|(x, y)| x == y)
        .count();
    assert!(same < 10, "{same} identical sensor samples across seeds");
    // The truth does not depend on the seed (the flight is deterministic).
    assert_eq!(a.truth[100].a_l_unit_g, c.truth[100].a_l_unit_g);
    // Timestamps: 25.6 kHz sensor samples, 800 Hz outputs stamped at their end.
    assert_eq!(a.sensor_time_ns[1], 39_062);
    assert_eq!(a.sensor_time_ns[51_199], 1_999_960_937);
    assert_eq!(a.output_end_ns[0], 1_250_000);
    assert_eq!(*a.output_end_ns.last().unwrap(), 2_000_000_000);
}

/// A stateful effect on every hook: a first-order low-pass of the unit input, a
/// sample-counted gain on the sensor, and a leaky integral of the input added to the
/// output. Its output would change if the simulator lost or repeated samples, or
/// handed a hook blocks out of order, at chunk boundaries.
struct StatefulProbe {
    low_pass: [[f64; 3]; 3],
    integral: [f64; 3],
    samples: [u64; 3],
    alpha: f64,
}

impl StatefulProbe {
    fn new() -> Self {
        Self {
            low_pass: [[0.0; 3]; 3],
            integral: [0.0; 3],
            samples: [0; 3],
            alpha: 0.0,
        }
    }
}

impl Effect for StatefulProbe {
    fn kind(&self) -> &'static str {
        "stateful_probe"
    }
    fn reset(&mut self, internal_rate_hz: f64) {
        *self = Self::new();
        self.alpha = 1.0 - (-2.0 * std::f64::consts::PI * 50.0 / internal_rate_hz).exp();
    }
    fn at_sensor(&mut self, ctx: &BlockCtx, _body: &[[f64; 3]], sensor_g: &mut [f64]) {
        let n = &mut self.samples[ctx.unit];
        for s in sensor_g.iter_mut() {
            *s *= 1.0 + 0.01 * ((*n % 1000) as f64 / 1000.0);
            *n += 1;
        }
    }
    fn at_unit_input(&mut self, ctx: &BlockCtx, vib: &mut [[f64; 3]]) {
        let s = &mut self.low_pass[ctx.unit];
        for v in vib.iter_mut() {
            for (si, vi) in s.iter_mut().zip(v.iter_mut()) {
                *si += self.alpha * (*vi - *si);
                *vi = *si;
            }
        }
    }
    fn at_unit_output(&mut self, ctx: &BlockCtx, input: &[[f64; 3]], out: &mut [f64]) {
        let q = &mut self.integral[ctx.unit];
        for (o, a) in out.iter_mut().zip(input) {
            *q = 0.999 * *q + 1e-6 * a[2];
            *o += *q;
        }
    }
    fn mean_shift_g(&self, _ctx: &MeanContext<'_>) -> vibro_effects::Result<f64> {
        Ok(0.0)
    }
}

#[test]
fn chunk_size_does_not_change_the_output() {
    let s = cyclone(1.0, 9);
    let run = |chunk: Option<usize>, probe: bool| {
        let effects: Vec<Box<dyn Effect>> = if probe {
            vec![Box::new(StatefulProbe::new())]
        } else {
            Vec::new()
        };
        let mut sim = Simulator::new(&s, effects).unwrap();
        if let Some(n) = chunk {
            sim.set_chunk_output_samples(n).unwrap();
        }
        record(&mut sim)
    };
    for probe in [false, true] {
        let reference = run(None, probe);
        for n in [1, 7, 333, 800] {
            let other = run(Some(n), probe);
            for (name, same) in [
                ("body", other.body_g == reference.body_g),
                ("sensor", other.sensor_v == reference.sensor_v),
                ("accel", other.accel_v == reference.accel_v),
                ("truth", other.truth == reference.truth),
                (
                    "times",
                    other.sensor_time_ns == reference.sensor_time_ns
                        && other.output_end_ns == reference.output_end_ns,
                ),
            ] {
                assert!(
                    same,
                    "chunk of {n} output samples changes the {name} stream (probe {probe})"
                );
            }
        }
    }
    // The probe itself changes the output (so the comparison above had something to see).
    assert_ne!(run(None, true).accel_v, run(None, false).accel_v);
}

/// Sets the kurtosis of the random part (what the "non_gaussian" effect does).
struct Kurtosis(f64);

impl Effect for Kurtosis {
    fn kind(&self) -> &'static str {
        "test_kurtosis"
    }
    fn adjust_body_vibration(&self, vib: &mut Vibration) {
        vib.kurtosis = [self.0; 3];
    }
    fn mean_shift_g(&self, _ctx: &MeanContext<'_>) -> vibro_effects::Result<f64> {
        Ok(0.0)
    }
}

/// Shifts the phase of the tones on body axis y.
struct PhaseY;

impl Effect for PhaseY {
    fn kind(&self) -> &'static str {
        "test_phase_y"
    }
    fn adjust_body_vibration(&self, vib: &mut Vibration) {
        let tones: Vec<_> = vib.tones().to_vec();
        vib.clear_tones();
        for mut t in tones {
            t.phase_rad[1] += 1.0;
            vib.push_tone(t).unwrap();
        }
    }
    fn mean_shift_g(&self, _ctx: &MeanContext<'_>) -> vibro_effects::Result<f64> {
        Ok(0.0)
    }
}

#[test]
fn an_effect_does_not_reshuffle_the_other_random_draws() {
    // Random vibration only: with kurtosis 6 each sample is the Gaussian one times
    // sqrt(w) of its segment, one of two values (vibro_physics ScaleMixture).
    let random_only = parse(
        &shipped_text("cyclone-4-short")
            .replace("duration_s = 20.0", "duration_s = 2.0")
            .replace(
                "amplitude_g = [0.5, 1.2, 1.2]",
                "amplitude_g = [0.0, 0.0, 0.0]",
            )
            .replace(
                "rms_g = [1.4, 1.4, 1.4]",
                "rms_g = [1.4, 1.4, 1.4]\nkurtosis_segment_s = 0.05",
            ),
    );
    let off = record(&mut Simulator::new(&random_only, Vec::new()).unwrap());
    let on = record(&mut Simulator::new(&random_only, vec![Box::new(Kurtosis(6.0))]).unwrap());
    let mix = vibro_physics::abs_mean::ScaleMixture::for_kurtosis(6.0);
    let roots = [mix.scale[0].sqrt(), mix.scale[1].sqrt()];
    let segment = 1280; // 0.05 s at 25.6 kHz
    let mut high = 0;
    for (s, (a, b)) in off
        .body_g
        .chunks(segment)
        .zip(on.body_g.chunks(segment))
        .enumerate()
    {
        let ratio = b[0][0] / a[0][0];
        let state = roots.iter().position(|r| (ratio - r).abs() < 1e-12);
        assert!(
            state.is_some(),
            "segment {s}: ratio {ratio} is neither sqrt(w) {roots:?}"
        );
        high += usize::from(state == Some(1));
        for (x, y) in a.iter().zip(b) {
            for i in 0..3 {
                assert!(
                    (y[i] - ratio * x[i]).abs() <= 1e-12 * x[i].abs().max(1e-3),
                    "segment {s}"
                );
            }
        }
    }
    println!("kurtosis 6: {high} of 40 segments in the high state");
    assert!(high > 0 && high < 40, "both states must occur");
    // Tones and random: a phase change on y leaves the x and z vibration, the sensor
    // noise of units 0 and 2, and their outputs bit-identical.
    let s = cyclone(1.0, 4);
    let off = record(&mut Simulator::new(&s, Vec::new()).unwrap());
    let on = record(&mut Simulator::new(&s, vec![Box::new(PhaseY)]).unwrap());
    for (a, b) in off.body_g.iter().zip(&on.body_g) {
        assert_eq!((a[0], a[2]), (b[0], b[2]));
    }
    assert!(off.body_g.iter().zip(&on.body_g).any(|(a, b)| a[1] != b[1]));
    for (a, b) in off.sensor_v.iter().zip(&on.sensor_v) {
        assert_eq!((a[0], a[2]), (b[0], b[2]));
    }
}
