//! Cost per message of recording and reading, for the two high-rate streams:
//! `AccelBlock` (10 samples x 3 units) and `VibBlock` (256 samples x 3 axes, i.e. 100
//! blocks per second at 25.6 kHz). Samples are noise-like, so compression is honest.
//!
//! - `write_call/*`: what `Recorder::write` costs the caller (validate + copy into the
//!   queue), with the queue never full;
//! - `write_end_to_end/*`: sustained throughput of the writer thread (protobuf encoding,
//!   zstd chunks, file writes), `finish()` included;
//! - `read/*`: `Reader` decoding messages in log-time order from a finished file.
//!
//! `cargo bench -p vibro-mcap --bench mcap_io` also prints the file size per message.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};
use vibro_mcap::{Error, Message, Reader, Recorder, RecorderOptions};
use vibro_msgs::{AccelBlock, MessageKind, VibBlock};

/// Deterministic noise in about -3..3 (sum of uniforms), without a random-number crate.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        let mut sum = 0.0;
        for _ in 0..4 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            sum += (self.0 >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        }
        sum * 3.0
    }
}

fn accel_block(seq: u64, noise: &mut Noise) -> AccelBlock {
    let mut m = AccelBlock::ZEROED;
    m.seq = seq;
    m.first_sample_index = seq * 10;
    m.t0_ns = seq * 10_000_000;
    m.sample_period_ns = 1_000_000;
    m.count = 10;
    for row in m.output_v.iter_mut().take(10) {
        *row = [
            -1.6698 + 1e-3 * noise.next(),
            -1.6698 + 1e-3 * noise.next(),
            -3.3 + 1e-3 * noise.next(),
        ];
    }
    m
}

fn vib_block(seq: u64, noise: &mut Noise) -> VibBlock {
    let mut m = VibBlock::ZEROED;
    m.seq = seq;
    m.first_sample_index = seq * 256;
    m.t0_ns = seq * 10_000_000;
    m.sample_period_ns = 39_062;
    m.count = 256;
    for row in m.sample_v.iter_mut().take(256) {
        *row = [noise.next(), noise.next(), noise.next()];
    }
    m
}

fn messages(kind: MessageKind, n: u64) -> Vec<Message> {
    let mut noise = Noise(1);
    (0..n)
        .map(|s| match kind {
            MessageKind::AccelBlock => accel_block(s, &mut noise).into(),
            _ => vib_block(s, &mut noise).into(),
        })
        .collect()
}

fn scratch() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("vibro-mcap-bench");
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

const POOL: u64 = 1000;

/// Writes `iters` messages, retrying when the queue is full; returns the time spent in
/// successful `write` calls and the total time including `finish()`.
fn record(kind: MessageKind, iters: u64, pool: &[Message]) -> (Duration, Duration, u64) {
    let path = scratch().join(format!("write-{kind}.mcap"));
    let start = Instant::now();
    let mut recorder = Recorder::create(&path, RecorderOptions::default()).expect("create");
    let channel = recorder.add_channel("/x", kind).expect("channel");
    let mut in_calls = Duration::ZERO;
    for i in 0..iters {
        let m = pool[(i % POOL) as usize];
        loop {
            let t = Instant::now();
            match recorder.write_to(&channel, i, i, i as u32, m) {
                Ok(()) => {
                    in_calls += t.elapsed();
                    break;
                }
                Err(Error::QueueFull { .. }) => std::thread::sleep(Duration::from_micros(20)),
                Err(e) => panic!("{e}"),
            }
        }
    }
    let summary = recorder.finish().expect("finish");
    (in_calls, start.elapsed(), summary.bytes)
}

fn bench(c: &mut Criterion) {
    for kind in [MessageKind::AccelBlock, MessageKind::VibBlock] {
        let pool = messages(kind, POOL);

        let mut g = c.benchmark_group("write_call");
        g.throughput(Throughput::Elements(1));
        g.sample_size(10);
        g.bench_function(kind.name(), |b| {
            b.iter_custom(|iters| record(kind, iters, &pool).0)
        });
        g.finish();

        let mut g = c.benchmark_group("write_end_to_end");
        g.throughput(Throughput::Elements(1));
        g.sample_size(10);
        g.bench_function(kind.name(), |b| {
            b.iter_custom(|iters| record(kind, iters, &pool).1)
        });
        g.finish();

        // A file to read from, and its size per message.
        let (_, _, bytes) = record(kind, 10 * POOL, &pool);
        let path = scratch().join(format!("write-{kind}.mcap"));
        let read_path = scratch().join(format!("read-{kind}.mcap"));
        std::fs::rename(&path, &read_path).expect("rename");
        println!(
            "{kind}: {:.1} bytes per message in the file ({} bytes in memory)",
            bytes as f64 / (10 * POOL) as f64,
            kind.size_bytes()
        );

        let mut g = c.benchmark_group("read");
        g.throughput(Throughput::Elements(1));
        g.sample_size(10);
        g.bench_function(kind.name(), |b| {
            b.iter_custom(|iters| {
                let start = Instant::now();
                let mut left = iters;
                while left > 0 {
                    for record in Reader::open(&read_path).expect("open").take(left as usize) {
                        black_box(record.expect("record"));
                        left -= 1;
                    }
                }
                start.elapsed()
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
