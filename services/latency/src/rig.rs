//! The rig: the synthetic accelerometer and vibration blocks, sent in real time
//! ([`pace`]), and the iceoryx2 rig that publishes them and stamps the compensated
//! blocks it receives ([`run_iceoryx`]).

use anyhow::bail;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, create_waitset, now_ns, StreamPublisher, StreamSubscriber};
use vibro_msgs::{AccelBlock, CompensatedBlock, ServiceNames, Stream, VibBlock};
use vibro_service::LoopMode;

use crate::histogram::Stamps;
use crate::Options;

/// The rig's synthetic signal: 1 g on every unit with a 12 Hz tone, and sensors seeing
/// the tone plus deterministic broadband noise.
struct Signal {
    k1_v_per_g: [f64; 3],
    sensitivity_v_per_g: f64,
    noise: u64,
}

impl Signal {
    fn accel_v(&self, t_s: f64) -> [f64; 3] {
        let a = 1.0 + 0.05 * (2.0 * std::f64::consts::PI * 12.0 * t_s).sin();
        [0, 1, 2].map(|u| a * self.k1_v_per_g[u])
    }

    fn vib_v(&mut self, t_s: f64) -> [f64; 3] {
        let tone = (2.0 * std::f64::consts::PI * 12.0 * t_s).sin();
        [0, 1, 2].map(|_| {
            // xorshift64*: cheap, deterministic, roughly uniform in [-1, 1).
            self.noise ^= self.noise >> 12;
            self.noise ^= self.noise << 25;
            self.noise ^= self.noise >> 27;
            let u =
                (self.noise.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
            self.sensitivity_v_per_g * (0.5 * tone + 2.0 * (u - 0.5))
        })
    }
}

/// The messages of the run, built once per block (no allocation in the loop).
pub(crate) struct RigStream {
    signal: Signal,
    accel: AccelBlock,
    vib: VibBlock,
    accel_period_ns: f64,
    vib_period_ns: f64,
    accel_block_ns: u64,
    vib_block_ns: u64,
    /// When each vibration block was published (`publish_ns`), in order: what a
    /// compensated block made by the waveform stage waited for ([`Self::stamp_vib`]).
    vib_publish_ns: Vec<u64>,
}

impl RigStream {
    pub(crate) fn new(opts: &Options, k1_v_per_g: [f64; 3]) -> Self {
        let accel_period_ns = 1e9 / opts.rate_hz;
        let vib_period_ns = 1e9 / opts.vib_rate_hz;
        let mut accel = AccelBlock::ZEROED;
        accel.count = opts.block_samples;
        accel.sample_period_ns = accel_period_ns.round() as u64;
        accel.source_id = 7;
        let mut vib = VibBlock::ZEROED;
        vib.count = opts.vib_block_samples;
        vib.sample_period_ns = vib_period_ns.round() as u64;
        vib.source_id = 7;
        Self {
            signal: Signal {
                k1_v_per_g,
                sensitivity_v_per_g: 0.1,
                noise: 0x9e37_79b9_7f4a_7c15,
            },
            accel,
            vib,
            accel_period_ns,
            vib_period_ns,
            accel_block_ns: (accel_period_ns * f64::from(opts.block_samples)) as u64,
            vib_block_ns: (vib_period_ns * f64::from(opts.vib_block_samples)) as u64,
            // The run's blocks and the tail's, sized once (no allocation in the loop).
            vib_publish_ns: Vec::with_capacity(
                (opts.duration_s * opts.vib_rate_hz / f64::from(opts.vib_block_samples)) as usize
                    + 64,
            ),
        }
    }

    /// Sets each compensated block's `last_vib_publish_ns`: the publish time of the
    /// newest vibration block published before the block's own publish (0: none).
    pub(crate) fn stamp_vib(&self, stamps: &mut [Stamps]) {
        for s in stamps {
            let n = self.vib_publish_ns.partition_point(|&t| t <= s.publish_ns);
            s.last_vib_publish_ns = n.checked_sub(1).map_or(0, |i| self.vib_publish_ns[i]);
        }
    }

    /// Fills accelerometer block `k` (samples `k * count ..`).
    fn accel_block(&mut self, k: u64) -> &AccelBlock {
        let n = u64::from(self.accel.count);
        let first = k * n;
        self.accel.seq = k;
        self.accel.first_sample_index = first;
        // The end of the first sample's interval, as the rig's packetizer stamps it.
        self.accel.t0_ns = ((first + 1) as f64 * self.accel_period_ns).round() as u64;
        for i in 0..n as usize {
            let t_s = (first + i as u64) as f64 * self.accel_period_ns * 1e-9;
            self.accel.output_v[i] = self.signal.accel_v(t_s);
        }
        self.accel.publish_ns = now_ns();
        &self.accel
    }

    fn vib_block(&mut self, k: u64) -> &VibBlock {
        let n = u64::from(self.vib.count);
        let first = k * n;
        self.vib.seq = k;
        self.vib.first_sample_index = first;
        self.vib.t0_ns = (first as f64 * self.vib_period_ns).round() as u64;
        for i in 0..n as usize {
            let t_s = (first + i as u64) as f64 * self.vib_period_ns * 1e-9;
            self.vib.sample_v[i] = self.signal.vib_v(t_s);
        }
        self.vib.publish_ns = now_ns();
        self.vib_publish_ns.push(self.vib.publish_ns);
        &self.vib
    }
}

/// Sends the run's blocks in real time: `send(Some(accel), None)` or `(None, Some(vib))`
/// in data-time order. Returns (accel, vib) blocks sent in the run.
///
/// After the run's last block the vibration stream goes on, in real time, until its
/// samples reach one vibration block past the last accelerometer block's end (the
/// sensors do not stop with the accelerometer): the compensator's waveform stage holds
/// each accelerometer block until the samples cover its readings plus the
/// interpolation's half-width, so without this tail the last block would wait for
/// the stage's silence rule and miss the rig. The tail's blocks are counted in the
/// returned vib count (the services take them).
pub(crate) fn pace(
    opts: &Options,
    stream: &mut RigStream,
    mut send_accel: impl FnMut(&AccelBlock) -> anyhow::Result<()>,
    mut send_vib: impl FnMut(&VibBlock) -> anyhow::Result<()>,
) -> anyhow::Result<(u64, u64)> {
    let end_ns = (opts.duration_s * 1e9) as u64;
    let start = Instant::now();
    let (mut ka, mut kv) = (0u64, 0u64);
    loop {
        // A block is due when its last sample has been taken.
        let due_a = (ka + 1) * stream.accel_block_ns;
        let due_v = (kv + 1) * stream.vib_block_ns;
        let due = due_a.min(due_v);
        if due > end_ns {
            break;
        }
        let now = start.elapsed().as_nanos() as u64;
        if due > now {
            std::thread::sleep(Duration::from_nanos(due - now));
        }
        if due_v <= due_a {
            send_vib(stream.vib_block(kv))?;
            kv += 1;
        } else {
            send_accel(stream.accel_block(ka))?;
            ka += 1;
        }
    }
    let tail_end_ns = ka * stream.accel_block_ns + stream.vib_block_ns;
    let mut tail = kv;
    while ka > 0 && tail * stream.vib_block_ns < tail_end_ns {
        let due = (tail + 1) * stream.vib_block_ns;
        let now = start.elapsed().as_nanos() as u64;
        if due > now {
            std::thread::sleep(Duration::from_nanos(due - now));
        }
        send_vib(stream.vib_block(tail))?;
        tail += 1;
    }
    Ok((ka, tail))
}

/// Receives compensated blocks until `stop` and the expected count, stamping each.
fn receive_iceoryx(
    prefix: String,
    (mode, realtime_priority): (LoopMode, Option<u8>),
    stop: Arc<AtomicBool>,
    ready: Arc<AtomicBool>,
    capacity: usize,
) -> anyhow::Result<Vec<Stamps>> {
    vibro_service::realtime::enter(realtime_priority)?;
    let names = ServiceNames::new(&prefix)?;
    let node = create_node("vibrocomp-latency-rx")?;
    let sub = StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated)?;
    ready.store(true, Ordering::Release);
    let waitset = create_waitset()?;
    let _guard = waitset
        .attach_notification(sub.listener())
        .map_err(|e| anyhow::anyhow!("attaching the receiver: {e:?}"))?;
    let mut out = Vec::with_capacity(capacity);
    loop {
        let mut any = false;
        while let Some(b) = sub.receive()? {
            let sub_recv_ns = now_ns();
            any = true;
            out.push(Stamps::of(&b, sub_recv_ns));
        }
        if stop.load(Ordering::Acquire) && !any {
            return Ok(out);
        }
        match mode {
            LoopMode::Event => {
                waitset
                    .wait_and_process_once_with_timeout(
                        |_| iceoryx2::prelude::CallbackProgression::Continue,
                        Duration::from_millis(20),
                    )
                    .map_err(|e| anyhow::anyhow!("receiver wait: {e:?}"))?;
                let _ = sub.clear_events();
            }
            LoopMode::Spin => {
                if any {
                    let _ = sub.clear_events();
                } else {
                    std::hint::spin_loop();
                }
            }
        }
    }
}

/// Runs the rig against a system listening on `prefix` over iceoryx2.
pub(crate) fn run_iceoryx(
    opts: &Options,
    prefix: &str,
    k1_v_per_g: [f64; 3],
) -> anyhow::Result<(u64, u64, Vec<Stamps>)> {
    let names = ServiceNames::new(prefix)?;
    let node = create_node("vibrocomp-latency")?;
    let mut accel = StreamPublisher::<AccelBlock>::open(&node, &names, Stream::Accel)?;
    let mut vib = StreamPublisher::<VibBlock>::open(&node, &names, Stream::Vib)?;
    let stop = Arc::new(AtomicBool::new(false));
    let ready = Arc::new(AtomicBool::new(false));
    let capacity = (opts.duration_s * opts.rate_hz / f64::from(opts.block_samples)) as usize + 16;
    let rx = {
        let (prefix, stop) = (prefix.to_string(), Arc::clone(&stop));
        let mode = (opts.mode, opts.realtime_priority);
        let ready = Arc::clone(&ready);
        std::thread::Builder::new()
            .name("latency-rx".into())
            .spawn(move || receive_iceoryx(prefix, mode, stop, ready, capacity))?
    };
    // The receiver subscribes, and the services' (or peers') inputs are connected,
    // before the first block. The receiver is not an `accel` subscriber: it says so
    // itself (waiting for two `accel` subscribers timed out on every run).
    let t = Instant::now();
    let connected = || {
        ready.load(Ordering::Acquire)
            && accel.subscriber_count() >= 1
            && vib.subscriber_count() >= 1
    };
    while !connected() {
        if rx.is_finished() || t.elapsed() > Duration::from_secs(10) {
            stop.store(true, Ordering::Release);
            if rx.is_finished() {
                rx.join()
                    .map_err(|_| anyhow::anyhow!("the receiver thread panicked"))??;
            }
            bail!(
                "the rig's ports on {prefix:?} did not connect within 10 s: receiver subscribed {}, {} accel and {} vib subscribers (want at least 1 each)",
                ready.load(Ordering::Acquire),
                accel.subscriber_count(),
                vib.subscriber_count()
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut stream = RigStream::new(opts, k1_v_per_g);
    // The sender at the real-time priority too, as a DAQ's driver thread runs: at
    // normal priority the estimator's window work (one below the compensator) can
    // preempt it between a block's publish stamp and its notification, and the
    // compensator then sees the block milliseconds late (1 % of the sensor blocks).
    vibro_service::realtime::enter(opts.realtime_priority)?;
    let (ka, kv) = pace(
        opts,
        &mut stream,
        |b| accel.publish(b).map(|_| ()).map_err(Into::into),
        |b| vib.publish(b).map(|_| ()).map_err(Into::into),
    )?;
    // The last outputs: a moment to arrive.
    std::thread::sleep(Duration::from_millis(300));
    stop.store(true, Ordering::Release);
    let mut stamps = rx
        .join()
        .map_err(|_| anyhow::anyhow!("the receiver thread panicked"))??;
    stream.stamp_vib(&mut stamps);
    Ok((ka, kv, stamps))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_carry_the_packetizer_stamps_and_the_signal() {
        // 800 Hz in blocks of 32: 1.25 ms a sample, 40 ms a block. Block 2 starts at
        // sample 64; its t0 is the end of that sample's interval: 65 x 1.25 ms.
        let opts = Options::default();
        let k1 = [0.5, 0.25, 2.0];
        let mut s = RigStream::new(&opts, k1);
        assert_eq!(s.accel_block_ns, 40_000_000);
        // 25.6 kHz in blocks of 512: 20 ms a block.
        assert_eq!(s.vib_block_ns, 20_000_000);
        let a = *s.accel_block(0);
        // At t = 0 the 12 Hz tone is 0: 1 g on every unit, k1 volts.
        assert_eq!(a.output_v[0], k1);
        let a = *s.accel_block(2);
        assert_eq!((a.seq, a.first_sample_index, a.count), (2, 64, 32));
        assert_eq!(a.t0_ns, 81_250_000);
        assert_eq!(a.sample_period_ns, 1_250_000);
        // Sample 64 at 80 ms: 1 + 0.05 sin(2 pi 12 Hz 0.08 s).
        let g = 1.0 + 0.05 * (2.0 * std::f64::consts::PI * 12.0 * 0.08).sin();
        assert!((a.output_v[0][2] - 2.0 * g).abs() < 1e-12);
        let v = *s.vib_block(1);
        // Vibration blocks are stamped at their first sample: 512 x 39.0625 us.
        assert_eq!((v.seq, v.first_sample_index, v.t0_ns), (1, 512, 20_000_000));
        assert!(v.sample_v[..512]
            .iter()
            .flatten()
            .all(|x| x.abs() <= 0.1 * 1.5));
    }

    #[test]
    fn the_sensor_stream_runs_one_block_past_the_last_accelerometer_block() {
        // 0.1 s: 2 accelerometer blocks (40 ms each, the third is due at 120 ms) and 5
        // vibration blocks (20 ms each) in the run; then the tail up to 80 + 20 ms of
        // samples: none more, the run's 5 blocks already reach 100 ms. At 0.09 s: 2 and
        // 4 in the run, and 1 in the tail.
        for (duration_s, run_vib, all_vib) in [(0.1, 5, 5), (0.09, 4, 5)] {
            let opts = Options {
                duration_s,
                ..Options::default()
            };
            let mut s = RigStream::new(&opts, [1.0; 3]);
            let mut vib_sent = 0;
            let (ka, kv) = pace(
                &opts,
                &mut s,
                |_| Ok(()),
                |_| {
                    vib_sent += 1;
                    Ok(())
                },
            )
            .unwrap();
            // The tail is counted with the run's blocks.
            let _ = run_vib;
            assert_eq!((ka, kv, vib_sent), (2, all_vib, all_vib), "{duration_s} s");
            // Each compensated block is stamped with the newest sensor block before it.
            let mut stamps = [s.vib_publish_ns[1] + 1, 0, u64::MAX].map(|publish_ns| Stamps {
                publish_ns,
                ..Stamps::default()
            });
            s.stamp_vib(&mut stamps);
            assert_eq!(stamps[0].last_vib_publish_ns, s.vib_publish_ns[1]);
            assert_eq!(stamps[1].last_vib_publish_ns, 0);
            assert_eq!(
                stamps[2].last_vib_publish_ns,
                *s.vib_publish_ns.last().unwrap()
            );
        }
    }
}
