//! The compensation kernel per triad sample, in each mode, and the per-estimate
//! vibration update. Target (issue "Latency and throughput"): at most 300 ns per triad
//! sample in exact mode.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use std::hint::black_box;
use vibro_physics::compensation::{Mode, TriadCompensator};
use vibro_physics::passport::{Passport, PassportSpec};
use vibro_physics::triad::TriadAxes;
use vibro_physics::vibration::Vibration;

/// The shipped AL-15 passport.
fn al15() -> Passport {
    let spec: PassportSpec =
        toml::from_str(include_str!("../../../config/accelerometers/al-15.toml"))
            .expect("the shipped passport parses");
    Passport::try_from_spec(&spec).expect("the shipped passport is valid")
}

/// Cyclone-4-like vibration: a tone on every axis and broadband random vibration, so
/// the exact mode uses its convolution table (the slowest path).
fn vibration() -> Vibration {
    let mut v = Vibration::single_tone(12.0, [1.2, 1.2, 0.5]);
    v.covariance_g2 = [[1.0, 0.0, 0.3], [0.0, 1.0, 0.0], [0.3, 0.0, 1.96]];
    v
}

fn kernel(c: &mut Criterion) {
    let mut group = c.benchmark_group("compensate_triad_sample");
    for mode in [Mode::AsPublished, Mode::Paper, Mode::Exact] {
        let mut t = TriadCompensator::new(TriadAxes::standard(), [al15(); 3], mode);
        for i in 0..3 {
            t.set_vibration(i, &vibration()).expect("valid vibration");
        }
        let mut k = 0u64;
        group.bench_with_input(BenchmarkId::from_parameter(mode.name()), &mode, |b, _| {
            b.iter(|| {
                // Readings that change every call, as a live stream's do: 0.1 mg per
                // sample, and a 0.1 g jump every 1000 samples.
                k = k.wrapping_add(1);
                let d = (k % 1000) as f64 * 1e-4;
                black_box(t.compensate(black_box([0.3 + d, -0.2 + d, 2.0 + d])))
            })
        });
        if mode == Mode::Exact {
            // No history: Newton's iteration from a(1) for every sample.
            group.bench_function("exact-once", |b| {
                b.iter(|| {
                    k = k.wrapping_add(1);
                    let d = (k % 1000) as f64 * 1e-4;
                    black_box(t.compensate_once(black_box([0.3 + d, -0.2 + d, 2.0 + d])))
                })
            });
        }
    }
    group.finish();
}

fn update(c: &mut Criterion) {
    let mut t = TriadCompensator::new(TriadAxes::standard(), [al15(); 3], Mode::Exact);
    let v = vibration();
    c.bench_function("set_vibration_triad_exact", |b| {
        b.iter(|| {
            for i in 0..3 {
                t.set_vibration(i, black_box(&v)).expect("valid vibration");
            }
        })
    });
}

criterion_group!(benches, kernel, update);
criterion_main!(benches);
