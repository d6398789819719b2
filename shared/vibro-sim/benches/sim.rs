//! Simulator throughput: 5 s of the Cyclone-4 flight (3 vibration channels at 25.6 kHz,
//! 3 accelerometers at the 25.6 kHz internal rate, tones and p1-table3 random
//! vibration). Target: 600 s of flight in under 30 s on one core, i.e. 5 s in under
//! 250 ms.

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::ops::ControlFlow;
use vibro_sim::{resolve_scenario, Simulator};

fn cyclone_5s(c: &mut Criterion) {
    let text = vibro_sim::scenario::EMBEDDED_SCENARIOS
        .iter()
        .find(|(id, _, _)| *id == "cyclone-4")
        .map(|(_, _, text)| text.replace("duration_s = 600.0", "duration_s = 5.0"))
        .expect("cyclone-4 is shipped");
    let scenario =
        vibro_sim::parse_scenario(&text, "cyclone-4 (5 s)", None).expect("valid scenario");
    // The shipped 600 s scenario also resolves (checked here so the bench fails loudly
    // if the embedded copy breaks).
    resolve_scenario("cyclone-4").expect("cyclone-4 resolves");
    let mut group = c.benchmark_group("simulate");
    group.sample_size(10);
    group.bench_function("cyclone-4 5 s", |b| {
        b.iter(|| {
            let mut sim = Simulator::new(&scenario, Vec::new()).expect("simulator");
            let mut sum = 0.0;
            sim.run(|chunk| {
                sum += chunk.accel_v().iter().map(|r| r[0]).sum::<f64>();
                ControlFlow::Continue(())
            })
            .expect("run");
            black_box(sum)
        })
    });
    group.finish();
}

criterion_group!(benches, cyclone_5s);
criterion_main!(benches);
