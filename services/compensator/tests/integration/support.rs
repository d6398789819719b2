//! Helpers shared by the tests: unique prefixes and directories, the service running
//! in-process, a rig of test publishers and subscribers, and the vibration truth.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;
use vibro_ipc::{create_node, IpcNode, StreamPublisher, StreamSubscriber};
use vibro_msgs::{AccelBlock, CompensatedBlock, ServiceNames, Stream, VibEstimate};
use vibro_physics::triad::{TriadAxes, UnitAxes};
use vibro_physics::vibration::{Tone, Vibration};
pub use vibro_service::testing::{wait_until, Running};
use vibro_service::{data_stream_config, estimate_stream_config, now_ns};

fn next_id() -> u32 {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A service-name prefix no other test (or test process) uses.
pub fn prefix() -> String {
    format!("vct-cmp-{}-{}/", std::process::id(), next_id())
}

/// A temporary directory, removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new() -> Self {
        let d = std::env::temp_dir().join(format!("vct-cmp-{}-{}", std::process::id(), next_id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Replaces `path` atomically (write then rename), as an editor or a deploy would.
pub fn replace_file(path: &Path, text: &str) {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text).unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

/// A compensator configuration file's text.
pub fn config_text(prefix: &str, mode: &str, triad: &str, loop_mode: &str) -> String {
    format!(
        r#"prefix = "{prefix}"
mode = "{mode}"
triad = "{triad}"
max_estimate_age_s = 2.0
reload_poll_s = 0.05
# These tests publish no vibration samples: the estimate stage's rules.
stage = "estimate"

[service]
loop_mode = "{loop_mode}"
heartbeat_period_s = 0.1
summary_period_s = 10.0
shutdown_poll_s = 0.02

# The readings of these tests are exact means over the whole vibration (the papers'
# mean readings), not per-sample outputs that resolve the slow vibration.
[estimate]
within_output_interval = false
"#
    )
}

/// A triad whose units have IAs along -y, +z and -x, with three different passports.
pub const FLIPPED_TRIAD: &str = r#"id = "flipped"
[[unit]]
name = "AK1"
passport = "AL-15"
ia = "-y"
oa = "+z"
pa = "-x"
[[unit]]
name = "AK2"
passport = "AL-1M"
ia = "+z"
oa = "-x"
pa = "+y"
[[unit]]
name = "AK3"
passport = "AKS-05"
ia = "-x"
oa = "-y"
pa = "z"
"#;

/// The test's side of the streams: it plays the rig and the estimator, and reads the
/// compensated blocks.
pub struct Rig {
    pub names: ServiceNames,
    pub accel: StreamPublisher<AccelBlock>,
    pub estimate: StreamPublisher<VibEstimate>,
    pub compensated: StreamSubscriber<CompensatedBlock>,
    _node: IpcNode,
}

impl Rig {
    pub fn new(prefix: &str) -> Self {
        let names = ServiceNames::new(prefix).unwrap();
        let node = create_node("vct-cmp-test").unwrap();
        let accel = StreamPublisher::create(
            &node,
            &names.accel(),
            &names.event(Stream::Accel),
            &data_stream_config(),
        )
        .unwrap();
        let estimate = StreamPublisher::create(
            &node,
            &names.estimate(),
            &names.event(Stream::Estimate),
            &estimate_stream_config(),
        )
        .unwrap();
        let compensated = StreamSubscriber::create(
            &node,
            &names.compensated(),
            &names.event(Stream::Compensated),
            &data_stream_config(),
        )
        .unwrap();
        Self {
            names,
            accel,
            estimate,
            compensated,
            _node: node,
        }
    }

    /// Waits until the service subscribed to both inputs.
    pub fn wait_for_service(&self) {
        assert!(
            wait_until(Duration::from_secs(10), || {
                self.accel.subscriber_count() == 1 && self.estimate.subscriber_count() == 1
            }),
            "the compensator did not subscribe"
        );
    }

    pub fn send_estimate(&mut self, e: &VibEstimate) {
        let mut e = *e;
        e.publish_ns = now_ns();
        self.estimate.publish(&e).unwrap();
    }

    /// Publishes a block (stamped now).
    pub fn send(&mut self, block: &AccelBlock) {
        let mut b = *block;
        b.publish_ns = now_ns();
        self.accel.publish(&b).unwrap();
    }

    /// The next compensated block, within 5 s.
    pub fn receive(&self) -> CompensatedBlock {
        let mut out = None;
        assert!(
            wait_until(Duration::from_secs(5), || {
                out = self.compensated.receive().unwrap().map(|s| *s);
                out.is_some()
            }),
            "no compensated block within 5 s"
        );
        out.unwrap()
    }

    /// Publishes a block and returns its compensated block.
    pub fn roundtrip(&mut self, block: &AccelBlock) -> CompensatedBlock {
        self.send(block);
        let out = self.receive();
        assert_eq!(out.input_seq, block.seq);
        out
    }
}

/// An accelerometer block: `count` samples of 1 ms from `t0_ns`, outputs in volts.
pub fn accel_block(seq: u64, t0_ns: u64, output_v: &[[f64; 3]]) -> AccelBlock {
    let mut b = AccelBlock::ZEROED;
    b.seq = seq;
    b.first_sample_index = seq * 32;
    b.t0_ns = t0_ns;
    b.sample_period_ns = 1_000_000;
    b.count = output_v.len() as u32;
    b.source_id = 7;
    b.output_v[..output_v.len()].copy_from_slice(output_v);
    b
}

/// The end of a block's last sample interval (what an estimate's age is measured to).
pub fn block_end_ns(b: &AccelBlock) -> u64 {
    b.t0_ns + b.sample_period_ns * (u64::from(b.count).max(1) - 1)
}

/// A vibration in the body frame: tones (frequency, amplitude and phase per body axis),
/// the random part's covariance and kurtosis per body axis.
pub struct BodyVibration {
    pub tones: Vec<(f64, [f64; 3], [f64; 3])>,
    pub covariance_g2: [[f64; 3]; 3],
    pub kurtosis: [f64; 3],
}

impl BodyVibration {
    pub fn rig() -> Self {
        Self {
            tones: vec![
                (12.0, [1.2, 1.2, 0.5], [0.4, -0.3, 0.1]),
                (31.0, [0.3, 0.2, 0.6], [2.0, -1.0, 0.7]),
            ],
            covariance_g2: [[1.0, 0.2, 0.3], [0.2, 1.44, -0.1], [0.3, -0.1, 1.96]],
            kurtosis: [3.0, 3.3, 2.8],
        }
    }

    /// Phasor of tone `k` on each body axis: `A e^{i phi}` as (re, im).
    fn phasor(&self, k: usize) -> ([f64; 3], [f64; 3]) {
        let (_, a, p) = self.tones[k];
        (
            [0, 1, 2].map(|i| a[i] * p[i].cos()),
            [0, 1, 2].map(|i| a[i] * p[i].sin()),
        )
    }

    /// What the vibration sensors report: sensor j measures along unit j's IA. Built
    /// from the phasors and the projection, independently of the service's mapping.
    pub fn estimate(&self, axes: &TriadAxes, seq: u64, end_ns: u64) -> VibEstimate {
        let mut e = VibEstimate::ZEROED;
        e.seq = seq;
        e.index = seq;
        e.start_ns = end_ns.saturating_sub(1_000_000_000);
        e.end_ns = end_ns;
        e.center_ns = end_ns.saturating_sub(500_000_000);
        e.tone_count = self.tones.len() as u32;
        for k in 0..self.tones.len() {
            let (re, im) = self.phasor(k);
            e.tone_frequency_hz[k] = self.tones[k].0;
            for (j, u) in axes.units.iter().enumerate() {
                let (r, i) = (u.ia.project(&re), u.ia.project(&im));
                e.tone_amplitude_g[k][j] = r.hypot(i);
                e.tone_phase_rad[k][j] = i.atan2(r);
            }
        }
        for (j, uj) in axes.units.iter().enumerate() {
            for (k, uk) in axes.units.iter().enumerate() {
                e.broadband_covariance_g2[j][k] = f64::from(uj.ia.sign)
                    * f64::from(uk.ia.sign)
                    * self.covariance_g2[uj.ia.body_index][uk.ia.body_index];
            }
            e.broadband_rms_g[j] = e.broadband_covariance_g2[j][j].sqrt();
            e.broadband_kurtosis[j] = self.kurtosis[uj.ia.body_index];
        }
        e
    }

    /// The vibration unit `u` sees in its axes `[OA, PA, IA]`: the phasors projected
    /// with `UnitAxes::to_unit`, the covariance as `P C P^T`.
    pub fn at_unit(&self, u: &UnitAxes) -> Vibration {
        let mut v = Vibration::none();
        for k in 0..self.tones.len() {
            let (re, im) = self.phasor(k);
            let (r, i) = (u.to_unit(&re), u.to_unit(&im));
            v.push_tone(Tone {
                freq_hz: self.tones[k].0,
                amplitude_g: [0, 1, 2].map(|a| r[a].hypot(i[a])),
                phase_rad: [0, 1, 2].map(|a| i[a].atan2(r[a])),
            })
            .unwrap();
        }
        let rows = [u.oa, u.pa, u.ia];
        for a in 0..3 {
            v.kurtosis[a] = self.kurtosis[rows[a].body_index];
            for b in 0..3 {
                v.covariance_g2[a][b] = f64::from(rows[a].sign)
                    * f64::from(rows[b].sign)
                    * self.covariance_g2[rows[a].body_index][rows[b].body_index];
            }
        }
        v
    }
}
