//! The waveform stage (MODEL.md section 12) on rigs it did not make: the independent
//! generator (`tests/python/rig_generator.py`, numpy, written from MODEL.md) writes a
//! shaker's sensors and readings (AC-coupled sensors at 25.6 or 6.4 kHz, 800 Hz
//! readings with 2 ug noise and 0.2 ug/s drift, a DAQ delay, a hidden mount) and, per
//! reading, what each unit sensed. The estimator's and the compensator's cores run
//! in-process, the streams interleaved as they arrive live (each block when its last
//! sample is in), and the compensated readings are scored against the generator's
//! truth: the RMS over units and 2 s windows of the window mean of `a4 - sensed`.
//!
//! The physical limit is the generator's own: 2 ug of white noise per reading (0.05 ug
//! over a 2 s window) and a drift of 0.2 ug/s (up to 0.8 ug over a window's mean in an
//! 8 s run). Issue: at most 3 ug.

use std::path::Path;
use std::process::Command;
use vibro_compensator::{Config, InProcess, Stage};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{AccelBlock, CompensatedBlock, VibBlock, VibEstimate};
use vibro_service::ServiceConfig;

use crate::support::TempDir;

/// The generator's CSVs read back: `(time_s, values)` rows.
struct Rig {
    accel: Vec<(f64, [f64; 3])>,
    vib: Vec<(f64, [f64; 3])>,
    sensed: Vec<(f64, [f64; 3])>,
    sensor_hz: f64,
    /// Each unit's drift, g/s (`r_u (t - T/2)` in each reading).
    drift_g_per_s: [f64; 3],
}

fn read_csv(path: &Path, cols: usize) -> Vec<(f64, [f64; 3])> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.trim().parse().unwrap()).collect();
            assert!(v.len() > cols, "{}: {l}", path.display());
            (v[0], [v[1], v[2], v[3]])
        })
        .collect()
}

fn generate(dir: &Path, args: &[&str]) -> Rig {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out = Command::new("python3")
        .arg(repo.join("tests/python/rig_generator.py"))
        .args(["run", "--out"])
        .arg(dir)
        .args([
            "--vibrate-throughout",
            "--duration-s",
            "8",
            "--unit-noise-ug",
            "2",
            "--unit-drift-ug-per-s",
            "0.2",
        ])
        .args(args)
        .output()
        .expect("python3 runs (numpy and scipy: tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "rig_generator.py {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).unwrap()).unwrap();
    Rig {
        accel: read_csv(&dir.join("accel.csv"), 3),
        vib: read_csv(&dir.join("vib.csv"), 3),
        sensed: read_csv(&dir.join("readings_truth.csv"), 6),
        sensor_hz: truth["rates"]["sensor_hz"].as_f64().unwrap(),
        drift_g_per_s: [0, 1, 2].map(|u| truth["unit_drift"]["rate_g_per_s"][u].as_f64().unwrap()),
    }
}

/// One generator run: `tones` (per body axis) and the default random vibration, the
/// sensors at `sensor_hz` on the generator's 51.2 kHz fine grid, `extra` options after.
fn rig_run(
    dir: &Path,
    seed: &str,
    orientation: &str,
    tones: &str,
    sensor_hz: &str,
    extra: &[&str],
) -> Rig {
    let oversample = (51_200 / sensor_hz.parse::<u32>().unwrap())
        .max(1)
        .to_string();
    let mut args = vec![
        "--seed",
        seed,
        orientation,
        "--tone-hz",
        tones,
        "--sensor-rate-hz",
        sensor_hz,
        "--oversample",
        &oversample,
    ];
    args.extend_from_slice(extra);
    generate(dir, &args)
}

/// The rig's streams as wire blocks, in the order they arrive live (each when its last
/// sample is in; a sensor block first on a tie). `keep_vib(seq)`: which sensor blocks
/// reach the compensator (all reach the estimator, as in a rig where only the
/// compensator's subscription loses them).
enum Msg {
    Vib(Box<VibBlock>),
    Accel(Box<AccelBlock>),
}

fn messages(rig: &Rig) -> Vec<(u64, Msg)> {
    let ns = |t: f64| (t * 1e9).round() as u64;
    let vib_period = (1e9 / rig.sensor_hz).round() as u64;
    let mut out = Vec::new();
    for (seq, chunk) in rig.vib.chunks(512).enumerate() {
        let mut b = VibBlock {
            seq: seq as u64,
            first_sample_index: seq as u64 * 512,
            t0_ns: ns(chunk[0].0),
            sample_period_ns: vib_period,
            count: chunk.len() as u32,
            ..Default::default()
        };
        for (k, (_, v)) in chunk.iter().enumerate() {
            b.sample_v[k] = *v;
        }
        out.push((ns(chunk[chunk.len() - 1].0), 0, Msg::Vib(Box::new(b))));
    }
    for (seq, chunk) in rig.accel.chunks(32).enumerate() {
        let mut b = AccelBlock {
            seq: seq as u64,
            first_sample_index: seq as u64 * 32,
            t0_ns: ns(chunk[0].0),
            sample_period_ns: 1_250_000,
            count: chunk.len() as u32,
            ..Default::default()
        };
        for (k, (_, u)) in chunk.iter().enumerate() {
            b.output_v[k] = *u;
        }
        out.push((ns(chunk[chunk.len() - 1].0), 1, Msg::Accel(Box::new(b))));
    }
    out.sort_by_key(|(t, kind, _)| (*t, *kind));
    out.into_iter().map(|(t, _, m)| (t, m)).collect()
}

fn estimator_config(sensor_hz: f64) -> vibro_dsp::EstimatorConfig {
    let mut raw = vibro_dsp::EstimatorConfigRaw::new(sensor_hz, [0.1; 3]);
    raw.ac_corner_hz = Some(2.0);
    raw.broadband_band_hz = [20.0, 640.0];
    vibro_dsp::EstimatorConfig::try_from(raw).unwrap()
}

fn compensator_config(stage: Stage, delay_s: f64, model: Option<&Path>) -> Config {
    let mut text = Config::shipped_text().to_string();
    text = text.replacen("ac_corner_hz = 0.5 ", "ac_corner_hz = 2.0 ", 1);
    text = text.replacen("delay_s = 0.0 ", &format!("delay_s = {delay_s:?} "), 1);
    if let Some(m) = model {
        text = format!("model = {:?}\n{text}", m.display().to_string());
    }
    let mut c = Config::parse(&text, vibro_service::ConfigSource::Inline).unwrap();
    c.model.waveform.stage = stage;
    c
}

/// The compensated blocks of `rig` through the in-process cores.
fn compensate(rig: &Rig, config: &Config, keep_vib: impl Fn(u64) -> bool) -> Vec<CompensatedBlock> {
    let mut est = vibro_estimator_core::InProcess::new(&estimator_config(rig.sensor_hz)).unwrap();
    let mut comp = InProcess::new(config).unwrap();
    let mut out = Vec::new();
    let mut estimates: Vec<VibEstimate> = Vec::new();
    for (t_ns, m) in messages(rig) {
        match m {
            Msg::Vib(b) => {
                est.on_block(&b, t_ns, &mut estimates).unwrap();
                for e in estimates.drain(..) {
                    comp.on_estimate(&e);
                }
                if keep_vib(b.seq) {
                    comp.on_vib(&b, t_ns, &mut out);
                }
            }
            Msg::Accel(b) => comp.on_accel(&b, t_ns, &mut out),
        }
    }
    // The stream's end, as a replay marks it: nothing stays held.
    let last = rig.vib.len() as u64;
    let end = VibBlock {
        seq: last.div_ceil(512),
        first_sample_index: last,
        t0_ns: (rig.vib[rig.vib.len() - 1].0 * 1e9).round() as u64
            + (1e9 / rig.sensor_hz).round() as u64,
        sample_period_ns: (1e9 / rig.sensor_hz).round() as u64,
        flags: vibro_msgs::vib_flags::END_OF_STREAM,
        ..Default::default()
    };
    comp.on_vib(&end, u64::MAX / 2, &mut out);
    let before = out.len();
    comp.finish(&mut out);
    assert_eq!(
        out.len(),
        before,
        "held after the end of the sensors' stream"
    );
    out
}

/// Per 2 s window (1600 readings) and unit, the mean of `a4 - sensed`; with the flags
/// every block of the window carries, and those any block carries.
fn window_errors(rig: &Rig, blocks: &[CompensatedBlock]) -> Vec<([f64; 3], u32, u32)> {
    window_errors_less(rig, blocks, false)
}

/// [`window_errors`], less the generator's drift when `less_drift` (what is left beyond
/// the rig's own drift).
fn window_errors_less(
    rig: &Rig,
    blocks: &[CompensatedBlock],
    less_drift: bool,
) -> Vec<([f64; 3], u32, u32)> {
    let n = 1600;
    let mut sums = vec![([0.0; 3], 0usize, u32::MAX, 0u32); rig.sensed.len() / n];
    for b in blocks {
        for k in 0..b.count as usize {
            let i = b.first_sample_index as usize + k;
            let w = i / n;
            if w >= sums.len() {
                continue;
            }
            assert!(
                (b.t0_ns as f64 + k as f64 * 1.25e6 - rig.sensed[i].0 * 1e9).abs() < 1.0,
                "reading {i} off its truth's time"
            );
            for u in 0..3 {
                let drift = if less_drift {
                    rig.drift_g_per_s[u] * (rig.sensed[i].0 - 0.5 * 1.25e-3)
                } else {
                    0.0
                };
                sums[w].0[u] += b.a4_g[k][u] - rig.sensed[i].1[u] - drift;
            }
            sums[w].1 += 1;
            sums[w].2 &= b.flags;
            sums[w].3 |= b.flags;
        }
    }
    sums.into_iter()
        .filter(|s| s.1 == n)
        .map(|(s, _, all, any)| (s.map(|x| x / n as f64), all, any))
        .collect()
}

fn rms(v: impl Iterator<Item = f64>) -> (f64, usize) {
    let (mut s, mut n) = (0.0, 0);
    for x in v {
        s += x * x;
        n += 1;
    }
    ((s / n.max(1) as f64).sqrt(), n)
}

/// RMS over units and the windows whose every block the waveform stage made.
fn waveform_rms(rig: &Rig, blocks: &[CompensatedBlock]) -> (f64, usize) {
    let w = window_errors(rig, blocks);
    rms(w
        .iter()
        .filter(|(_, all, _)| all & cf::WAVEFORM != 0)
        .flat_map(|(e, ..)| e.iter().copied()))
}

fn score(name: &str, rig: &Rig, config: &Config) -> f64 {
    let blocks = compensate(rig, config, |_| true);
    assert_eq!(
        blocks.len(),
        rig.accel.len().div_ceil(32),
        "{name}: every block out"
    );
    let (wf, windows) = waveform_rms(rig, &blocks);
    let w = window_errors_less(rig, &blocks, true);
    let (beyond, _) = rms(w
        .iter()
        .filter(|(_, all, _)| all & cf::WAVEFORM != 0)
        .flat_map(|(e, ..)| e.iter().copied()));
    eprintln!("{name}: beyond the rig's drift {:.3} ug", beyond * 1e6);
    // The rig's white noise over a window is 2 ug / sqrt(1600) = 0.05 ug.
    assert!(beyond < 0.3e-6, "{name}: {beyond} g beyond the drift");
    let est = compensate(rig, &compensator_config(Stage::Estimate, 0.0, None), |_| {
        true
    });
    // Every block carries the estimate stage's answer in `a3` (the flags' contract).
    if config.model.effects.is_none() {
        for (b, e) in blocks.iter().zip(&est) {
            assert_eq!(b.input_seq, e.input_seq);
            if b.flags & cf::WAVEFORM != 0 {
                assert_eq!(b.a3_g, e.a4_g, "{name}: block {}", b.seq);
                assert_eq!(b.flags & cf::MAIN_ONLY, 0);
            }
        }
    }
    let w = window_errors(rig, &est);
    let (e, _) = rms(w
        .iter()
        .filter(|(_, _, any)| any & cf::MAIN_ONLY == 0)
        .flat_map(|(e, ..)| e.iter().copied()));
    eprintln!(
        "{name}: waveform stage {:.2} ug over {windows} windows x 3 units; estimate stage {:.2} ug",
        wf * 1e6,
        e * 1e6
    );
    assert!(
        windows >= 2,
        "{name}: {windows} windows made by the waveform stage"
    );
    wf
}

#[test]
fn nothing_hidden_at_25k6_leaves_the_rigs_noise() {
    let dir = TempDir::new();
    let rig = rig_run(&dir.0, "431", "--orientation=+x", "30,60,120", "25600", &[]);
    let wf = score(
        "nothing hidden, 25.6 kHz",
        &rig,
        &compensator_config(Stage::Waveform, 0.0, None),
    );
    assert!(wf < 3e-6, "{wf} g");
}

/// Every tone at 150 Hz through the generator's hidden 150 Hz, Q 2.5 mount, the sensors
/// at `sensor_hz` (the generator's 51.2 kHz grid), compensated with the
/// mount's true parameters: the waveform stage's RMS, g; and with the base model.
fn tones_on_the_mount(seed: &str, orientation: &str, sensor_hz: &str) -> (f64, f64) {
    let dir = TempDir::new();
    let rig = rig_run(
        &dir.0,
        seed,
        orientation,
        "150,150,150",
        sensor_hz,
        &["--resonance-f0-hz", "150", "--resonance-q", "2.5"],
    );
    let model = dir.path("mount.toml");
    std::fs::write(
        &model,
        "format = \"vibrocomp-model/1\"\nmode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 150.0\nq = 2.5\n",
    )
    .unwrap();
    let wf = score(
        &format!("{sensor_hz} Hz sensors, tones on a 150 Hz Q 2.5 mount, true model"),
        &rig,
        &compensator_config(Stage::Waveform, 0.0, Some(&model)),
    );
    let base = compensate(
        &rig,
        &compensator_config(Stage::Waveform, 0.0, None),
        |_| true,
    );
    (wf, waveform_rms(&rig, &base).0)
}

#[test]
fn every_tone_on_a_hidden_mount_with_its_true_parameters() {
    let (wf, base) = tones_on_the_mount("432", "--orientation=oblique1", "25600");
    assert!(wf < 3e-6, "{wf} g");
    // Without the mount in the model the stage leaves far more: the test can fail.
    eprintln!("the same without the mount: {:.1} ug", base * 1e6);
    assert!(base > 10.0 * wf, "{base} against {wf}");
}

/// Eight samples per reading with every tone on the resonance: 6.4 kHz sensors (the
/// quadrature on the grid the interpolation fills, issue 43's "8 samples per reading, a
/// tone on a resonance included").
#[test]
fn eight_samples_per_reading_with_every_tone_on_the_resonance() {
    let (wf, _) = tones_on_the_mount("436", "--orientation=+y", "6400");
    assert!(wf < 3e-6, "{wf} g");
}

#[test]
fn sensors_at_6k4_behind_a_stated_delay() {
    let dir = TempDir::new();
    let rig = rig_run(
        &dir.0,
        "433",
        "--orientation=-y",
        "45,75,105",
        "6400",
        &["--daq-delay-s", "0.00156"],
    );
    let wf = score(
        "6.4 kHz, 1.56 ms delay stated",
        &rig,
        &compensator_config(Stage::Waveform, 0.00156, None),
    );
    assert!(wf < 3e-6, "{wf} g");
    let (ignored, _) = waveform_rms(
        &rig,
        &compensate(
            &rig,
            &compensator_config(Stage::Waveform, 0.0, None),
            |_| true,
        ),
    );
    eprintln!("the delay ignored: {:.1} ug", ignored * 1e6);
    assert!(ignored > 5.0 * wf, "{ignored} against {wf}");
}

/// Sensor blocks lost on the way to the compensator: 10 % at random, then all of them
/// for 2 s. Every block comes out; those the samples do not cover are the estimate
/// stage's (flagged), with an error within 2x of the estimate stage's over the same
/// windows.
#[test]
fn lost_sensor_blocks_fall_back_to_the_estimate_stage() {
    let dir = TempDir::new();
    let rig = rig_run(&dir.0, "434", "--orientation=+z", "30,60,120", "6400", &[]);
    let config = compensator_config(Stage::Waveform, 0.0, None);
    let estimate = compensate(
        &rig,
        &compensator_config(Stage::Estimate, 0.0, None),
        |_| true,
    );
    let w_est = window_errors(&rig, &estimate);
    let vib_blocks = rig.vib.len().div_ceil(512) as u64;
    // A fixed pseudo-random 10 % (a multiplicative hash of the seq).
    let random = |seq: u64| (seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) % 10 != 3;
    // 2 s from t = 3 s: blocks 37..62 at 6.4 kHz in 512s.
    let cut = |seq: u64| !(37..62).contains(&seq);
    for (name, keep) in [
        ("10 % at random", &random as &dyn Fn(u64) -> bool),
        ("2 s cut", &cut),
    ] {
        let dropped = (0..vib_blocks).filter(|&s| !keep(s)).count();
        let blocks = compensate(&rig, &config, keep);
        assert_eq!(
            blocks.len(),
            rig.accel.len().div_ceil(32),
            "{name}: none lost"
        );
        let fallback = blocks
            .iter()
            .filter(|b| b.flags & cf::WAVEFORM_FALLBACK != 0)
            .count();
        let waveform = blocks
            .iter()
            .filter(|b| b.flags & cf::WAVEFORM != 0)
            .count();
        assert_eq!(
            fallback + waveform,
            blocks.len(),
            "{name}: each block says its stage"
        );
        assert!(
            fallback > 0,
            "{name}: {dropped} sensor blocks dropped, no fallback"
        );
        // Each fallback block is the estimate stage's answer, bit for bit.
        for b in blocks
            .iter()
            .filter(|b| b.flags & cf::WAVEFORM_FALLBACK != 0)
        {
            let e = estimate
                .iter()
                .find(|e| e.input_seq == b.input_seq)
                .unwrap();
            assert_eq!(
                b.a4_g[..b.count as usize],
                e.a4_g[..e.count as usize],
                "{name}"
            );
        }
        let w = window_errors(&rig, &blocks);
        let mixed: Vec<usize> = (0..w.len())
            .filter(|&i| w[i].2 & cf::WAVEFORM_FALLBACK != 0 && w_est[i].2 & cf::MAIN_ONLY == 0)
            .collect();
        let (got, n) = rms(mixed.iter().flat_map(|&i| w[i].0.iter().copied()));
        let (est, _) = rms(mixed.iter().flat_map(|&i| w_est[i].0.iter().copied()));
        eprintln!(
            "{name}: {dropped} of {vib_blocks} sensor blocks dropped, {fallback} of {} blocks fell back; windows with a fallback: {:.2} ug ({n}), the estimate stage there {:.2} ug",
            blocks.len(),
            got * 1e6,
            est * 1e6
        );
        assert!(
            got <= 2.0 * est,
            "{name}: {got} against the estimate stage's {est}"
        );
    }
}

/// The service over iceoryx2 gives, block for block and bit for bit, what the
/// in-process core gives on the same streams (timestamps aside): the three streams
/// published as they arrive live, the estimates from the estimator's in-process core.
/// The sensors' stream then stops for good while readings go on: the held blocks fall
/// back (late, by the streams' time), and the last one after the wall-clock silence;
/// none is lost.
#[test]
fn the_service_gives_the_in_process_blocks_and_loses_none_when_the_sensors_stop() {
    use vibro_ipc::{create_node, StreamPublisher};
    use vibro_msgs::Stream;
    use vibro_service::testing::{wait_until, Running};
    use vibro_service::{data_stream_config, now_ns};

    let dir = TempDir::new();
    let rig = rig_run(
        &dir.0,
        "435",
        "--orientation=oblique2",
        "30,60,120",
        "6400",
        &[],
    );
    let prefix = crate::support::prefix();
    let mut config = compensator_config(Stage::Waveform, 0.0, None)
        .with_prefix(&prefix)
        .unwrap();
    config.service.shutdown_poll = std::time::Duration::from_millis(20);
    // Sensor blocks after 6 s never come.
    let stop_ns = 6_000_000_000u64;
    let keep = |seq: u64| seq * 512 * 156_250 < stop_ns - 80_000_000;
    let want = compensate(&rig, &config, keep);

    let mut test_side = crate::support::Rig::new(&prefix);
    let node = create_node("vct-cmp-vib").unwrap();
    let names = vibro_msgs::ServiceNames::new(&prefix).unwrap();
    let mut vib: StreamPublisher<VibBlock> = StreamPublisher::create(
        &node,
        &names.vib(),
        &names.event(Stream::Vib),
        &data_stream_config(),
    )
    .unwrap();
    // The compensator's progress (a heartbeat per wake-up that took input): an
    // estimate goes out only once every block sent before it was taken, as a
    // lock-stepped replay does (the service takes every estimate it has before a block).
    let progress: vibro_ipc::StreamSubscriber<vibro_msgs::Heartbeat> =
        vibro_ipc::StreamSubscriber::create(
            &node,
            &names.progress(vibro_msgs::ServiceId::Compensator),
            &names.event(Stream::Progress(vibro_msgs::ServiceId::Compensator)),
            &data_stream_config(),
        )
        .unwrap();
    let mut taken = 0u64;
    let mut sent = 0u64;
    let service = Running::start(vibro_compensator::run, config);
    test_side.wait_for_service();
    assert!(wait_until(std::time::Duration::from_secs(10), || vib
        .subscriber_count()
        == 1));

    let mut est = vibro_estimator_core::InProcess::new(&estimator_config(rig.sensor_hz)).unwrap();
    let mut estimates: Vec<VibEstimate> = Vec::new();
    let mut got = Vec::new();
    let drain = |side: &crate::support::Rig, got: &mut Vec<CompensatedBlock>| {
        while let Some(b) = side.compensated.receive().unwrap() {
            got.push(*b);
        }
    };
    for (t_ns, m) in messages(&rig) {
        match m {
            Msg::Vib(b) => {
                est.on_block(&b, t_ns, &mut estimates).unwrap();
                if !estimates.is_empty() {
                    assert!(
                        wait_until(std::time::Duration::from_secs(10), || {
                            while let Some(h) = progress.receive().unwrap() {
                                taken = taken.max(h.received);
                            }
                            taken >= sent
                        }),
                        "the compensator took {taken} of {sent} blocks"
                    );
                }
                for e in estimates.drain(..) {
                    test_side.send_estimate(&e);
                }
                if keep(b.seq) {
                    let mut b = *b;
                    b.publish_ns = now_ns();
                    vib.publish(&b).unwrap();
                }
            }
            Msg::Accel(b) => {
                test_side.send(&b);
                sent += 1;
            }
        }
        // Live pacing is not needed, but the subscribers' buffers are bounded.
        std::thread::sleep(std::time::Duration::from_micros(300));
        drain(&test_side, &mut got);
    }
    // The last held block goes out after the sensors' silence (250 ms) at the latest.
    assert!(
        wait_until(std::time::Duration::from_secs(5), || {
            drain(&test_side, &mut got);
            got.len() == want.len()
        }),
        "{} of {} blocks",
        got.len(),
        want.len()
    );
    let summary = service.stop();
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(
            (g.seq, g.input_seq, g.flags),
            (w.seq, w.input_seq, w.flags),
            "block {}",
            w.seq
        );
        let stages =
            |b: &CompensatedBlock| [b.a1_g, b.a2_g, b.a3_g, b.a4_g, b.main_g, b.det_g, b.rand_g];
        for (a, b) in stages(g).iter().zip(stages(w).iter()) {
            for k in 0..w.count as usize {
                for u in 0..3 {
                    assert_eq!(
                        a[k][u].to_bits(),
                        b[k][u].to_bits(),
                        "block {} reading {k} unit {u}",
                        w.seq
                    );
                }
            }
        }
    }
    let w = summary.waveform.expect("waveform counts");
    eprintln!(
        "service: {} blocks, waveform {}, fallback {} (never {}, late {}, silent {}), max held {}",
        got.len(),
        summary.waveform_blocks,
        summary.fallback_blocks,
        w.fallback_never,
        w.fallback_late,
        w.fallback_silent,
        w.max_pending
    );
    assert_eq!(summary.published as usize, want.len());
    assert!(
        w.fallback_late >= 40,
        "after 6 s the blocks fall back by the streams' time"
    );
    assert!(summary.waveform_blocks >= 140);
}
