//! CPU per block of the waveform stage as the compensator runs it (issue 43): three
//! vibration sensors at 25.6 kHz in blocks of 512 (20 ms) and accelerometer readings
//! at 800 Hz in blocks of 32 (40 ms), pushed and solved in step: per 40 ms of data two
//! sensor blocks are pushed and one block of 32 readings is solved (64 grid points
//! per reading: twice the sensor rate). The base model, and the base model with a
//! `mount_resonance` path effect on every unit (its filter runs on each grid point).
//!
//! `cargo bench -p vibro-waveform --bench stage` prints the time per 40 ms block; the
//! share of one core is that time over 40 ms (the budget is 5 %, 2 ms per block).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::f64::consts::TAU;
use std::hint::black_box;
use vibro_effects::Effect;
use vibro_physics::passport::Passport;
use vibro_physics::triad::TriadAxes;
use vibro_waveform::{Coverage, SensorChain, WaveformStage};

const SENSOR_HZ: f64 = 25_600.0;
const VIB_BLOCK: usize = 512;
/// 1e9 / 25.6 kHz, rounded as a producer stamps it.
const SENSOR_PERIOD_NS: u64 = 39_063;
const READING_PERIOD_NS: u64 = 1_250_000;
const READINGS: usize = 32;
const SENSITIVITY_V_PER_G: f64 = 0.1;
/// Data per step: one accelerometer block, two sensor blocks.
const STEPS: usize = 250;

fn passport() -> Passport {
    let p = vibro_config::resolve_passport("AL-15").expect("shipped passport");
    let mut spec = p.to_spec();
    // λ(ω) = 1, as in the stage (crate docs).
    spec.lambda.clear();
    Passport::try_from_spec(&spec).expect("valid passport")
}

/// Sensor samples in volts for `STEPS` steps: tones in broadband noise, 3 g rms.
fn sensor_samples() -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let tones = [(45.0, 2.0), (97.3, 1.0), (310.0, 0.5)];
    (0..(STEPS + 1) * 2 * VIB_BLOCK)
        .map(|k| {
            let t_s = k as f64 / SENSOR_HZ;
            std::array::from_fn(|a| {
                let noise: f64 = StandardNormal.sample(&mut rng);
                let det: f64 = tones
                    .iter()
                    .map(|(f, amp)| amp * (TAU * f * t_s + a as f64).sin())
                    .sum();
                SENSITIVITY_V_PER_G * (det + 1.5 * noise)
            })
        })
        .collect()
}

fn effects(with_resonance: bool, p: &Passport) -> [Vec<Box<dyn Effect>>; 3] {
    if !with_resonance {
        return [vec![], vec![], vec![]];
    }
    let table: toml::Table = "kind = \"mount_resonance\"\nfreq_hz = 150.0\nq = 2.5"
        .parse()
        .expect("effect table");
    [0, 1, 2].map(|_| {
        vibro_effects::model::build_effects(std::slice::from_ref(&table), p).expect("effect")
    })
}

/// The stage and its stream, stepped one accelerometer block at a time.
struct Rig {
    stage: WaveformStage,
    samples: Vec<[f64; 3]>,
    next_vib: u64,
    next_block: u64,
    readings_g: [[f64; 3]; READINGS],
    out_g: [[f64; 3]; READINGS],
}

impl Rig {
    fn new(with_resonance: bool) -> Self {
        let p = passport();
        let chain = SensorChain {
            sensitivity_v_per_g: [SENSITIVITY_V_PER_G; 3],
            ac_corner_hz: 0.5,
            delay_s: 0.0,
        };
        let stage = WaveformStage::new(
            chain,
            TriadAxes::standard(),
            [p; 3],
            effects(with_resonance, &p),
        )
        .expect("chain");
        Self {
            stage,
            samples: sensor_samples(),
            next_vib: 0,
            next_block: 0,
            readings_g: [[0.0, 0.0, 1.0]; READINGS],
            out_g: [[0.0; 3]; READINGS],
        }
    }

    fn push_vib(&mut self) {
        // The data repeats; the stream's indices and stamps run on.
        let n = self.samples.len() / VIB_BLOCK;
        let seq = self.next_vib;
        let first = seq * VIB_BLOCK as u64;
        let at = (seq as usize % n) * VIB_BLOCK;
        self.stage.push_vib(
            seq,
            first,
            first * SENSOR_PERIOD_NS,
            SENSOR_PERIOD_NS,
            &self.samples[at..at + VIB_BLOCK],
            false,
            false,
        );
        self.next_vib += 1;
    }

    /// Two sensor blocks pushed, then the next accelerometer block solved.
    fn step(&mut self) {
        self.push_vib();
        self.push_vib();
        let k = self.next_block;
        let first_end_ns = (k * READINGS as u64 + 1) * READING_PERIOD_NS;
        // The first block waits for one sensor block more (its interpolation's tail).
        while self
            .stage
            .coverage(first_end_ns, READING_PERIOD_NS, READINGS)
            == Coverage::NotYet
        {
            self.push_vib();
        }
        self.stage.compensate(
            first_end_ns,
            READING_PERIOD_NS,
            black_box(&self.readings_g),
            &mut self.out_g,
        );
        black_box(&self.out_g);
        self.next_block += 1;
    }
}

fn stage(c: &mut Criterion) {
    let mut group =
        c.benchmark_group("waveform stage, 25.6 kHz x 3 sensors, 32 readings at 800 Hz");
    // One element: one accelerometer block (40 ms of data).
    group.throughput(Throughput::Elements(1));
    for (name, resonance) in [("base model", false), ("mount_resonance", true)] {
        let mut rig = Rig::new(resonance);
        // Warm: the ring, the grid and the effects' state sized and started.
        for _ in 0..4 {
            rig.step();
        }
        let before = rig.stage.counters();
        group.bench_function(name, |b| b.iter(|| rig.step()));
        let after = rig.stage.counters();
        assert_eq!(after.breaks, before.breaks, "{name}: the stream broke");
        assert_eq!(after.unconverged, before.unconverged, "{name}: Newton");
    }
    group.finish();
}

criterion_group!(benches, stage);
criterion_main!(benches);
