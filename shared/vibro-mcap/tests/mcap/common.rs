//! Test fixtures: known messages of every type and scratch directories.

use std::path::PathBuf;
use vibro_mcap::Message;
use vibro_msgs::{
    AccelBlock, CompensatedBlock, CompensationMode, Heartbeat, ServiceId, ServiceState, TruthBlock,
    VibBlock, VibEstimate, ACCEL_BLOCK_MAX,
};

/// A fresh, empty directory for one test.
pub fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("vibro-mcap")
        .join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A value per slot that no conversion could produce by accident; every seventh is a
/// value that lossy code would change.
pub fn value(seed: u64, i: usize) -> f64 {
    match i % 7 {
        0 => -0.0,
        3 => f64::MIN_POSITIVE / 16.0, // subnormal
        5 => -f64::MAX,
        _ => -1.6698 + seed as f64 * 1e-3 + i as f64 * 1.25e-7,
    }
}

fn fill(rows: &mut [[f64; 3]], count: usize, seed: u64) {
    for (i, row) in rows.iter_mut().take(count).enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = value(seed, 3 * i + j);
        }
    }
}

pub fn accel(seq: u64) -> AccelBlock {
    let mut m = AccelBlock::ZEROED;
    m.seq = seq;
    m.first_sample_index = seq * 10;
    m.t0_ns = 1_000_000_000 + seq * 10_000_000;
    m.sample_period_ns = 1_000_000;
    m.publish_ns = 5_000 + seq;
    fill(&mut m.output_v, 10, seq);
    m.count = 10;
    m.source_id = 7;
    m.flags = if seq == 0 {
        0
    } else {
        vibro_msgs::accel_flags::SATURATED
    };
    m
}

pub fn vib(seq: u64) -> VibBlock {
    let mut m = VibBlock::ZEROED;
    m.seq = seq;
    m.first_sample_index = seq * 256;
    m.t0_ns = 1_000_000_000 + seq * 10_000_000;
    m.sample_period_ns = 39_062;
    m.publish_ns = 6_000 + seq;
    fill(&mut m.sample_v, 256, seq + 100);
    m.count = 256;
    m.source_id = 7;
    m.flags = vibro_msgs::vib_flags::GAP_BEFORE;
    m
}

pub fn estimate(seq: u64) -> VibEstimate {
    let mut m = VibEstimate::ZEROED;
    m.seq = seq;
    m.index = seq + 1;
    m.source_seq = seq * 2;
    m.publish_ns = 7_000 + seq;
    m.start_ns = 1_000_000_000 + seq * 500_000_000;
    m.end_ns = m.start_ns + 1_000_000_000;
    m.center_ns = m.start_ns + 500_000_000;
    m.broadband_f_lo_hz = 20.0;
    m.broadband_f_hi_hz = 2000.0;
    m.broadband_rms_g = [1.4, 1.3, value(seq, 0)];
    m.broadband_rms_u_g = [0.01, 0.02, 0.03];
    m.broadband_covariance_g2 = [[1.96, 0.1, 0.2], [0.1, 1.69, 0.3], [0.2, 0.3, 1.21]];
    m.broadband_covariance_u_g2 = [[0.01; 3]; 3];
    m.broadband_kurtosis = [3.0, 3.1, 2.9];
    m.broadband_kurtosis_u = [0.05; 3];
    m.broadband_welch_segments = 15;
    m.welch_segment_samples = 2048;
    m.tone_count = 2;
    m.tone_frequency_hz[..2].copy_from_slice(&[12.004, 24.5]);
    m.tone_frequency_u_hz[..2].copy_from_slice(&[0.001, 0.01]);
    m.tone_amplitude_g[0] = [1.2, 1.2, 0.5];
    m.tone_amplitude_g[1] = [0.1, 0.2, value(seq, 3)];
    m.tone_phase_rad[0] = [0.0, -0.0, 3.0];
    m.tone_snr_db[0] = [40.0, 41.0, 42.0];
    m.band_count = 5;
    for b in 0..5 {
        m.band_f_lo_hz[b] = 20.0 * f64::from(1u32 << b);
        m.band_f_hi_hz[b] = 40.0 * f64::from(1u32 << b);
        m.band_psd_g2_per_hz[b] = [0.016, 0.017, 0.018];
        m.band_rms_g[b] = [value(seq, b), 0.5, 0.25];
    }
    m.samples = 8192;
    m.valid_samples = 8190;
    m.saturated_samples = [0, 2, 0];
    m.flags = vibro_msgs::estimate_flags::GAP;
    m
}

pub fn compensated(seq: u64) -> CompensatedBlock {
    let mut m = CompensatedBlock::ZEROED;
    m.seq = seq;
    m.input_seq = seq + 1000;
    m.first_sample_index = seq * 10;
    m.t0_ns = 1_000_000_000 + seq * 10_000_000;
    m.sample_period_ns = 1_000_000;
    m.estimate_seq = seq / 50;
    m.input_publish_ns = 5_000 + seq;
    m.recv_ns = 5_100 + seq;
    m.publish_ns = 5_200 + seq;
    m.estimate_age_ns = -250_000_000;
    let n = 10;
    fill(&mut m.a1_g, n, seq + 1);
    fill(&mut m.a2_g, n, seq + 2);
    fill(&mut m.a3_g, n, seq + 3);
    fill(&mut m.a4_g, n, seq + 4);
    fill(&mut m.main_g, n, seq + 5);
    fill(&mut m.det_g, n, seq + 6);
    fill(&mut m.rand_g, n, seq + 7);
    m.count = n as u32;
    m.source_id = 7;
    m.flags = vibro_msgs::compensation_flags::VIBRATION_ESTIMATE_STALE;
    m.mode = CompensationMode::Exact.code();
    m
}

pub fn truth(seq: u64) -> TruthBlock {
    let mut m = TruthBlock::ZEROED;
    m.seq = seq;
    m.first_sample_index = seq * 10;
    m.t0_ns = 1_000_000_000 + seq * 10_000_000;
    m.sample_period_ns = 1_000_000;
    m.publish_ns = 8_000 + seq;
    fill(&mut m.a_l_ia_g, ACCEL_BLOCK_MAX, seq + 20);
    fill(&mut m.vib_error_ia_g, ACCEL_BLOCK_MAX, seq + 21);
    fill(&mut m.a_sensed_ia_g, ACCEL_BLOCK_MAX, seq + 22);
    m.count = ACCEL_BLOCK_MAX as u32;
    m.source_id = 7;
    m.flags = vibro_msgs::truth_flags::VIB_ERROR_KNOWN;
    m
}

pub fn heartbeat(seq: u64) -> Heartbeat {
    Heartbeat {
        seq,
        publish_ns: 9_000 + seq,
        uptime_ns: seq * 1_000_000_000,
        received: 100 * seq,
        published: 99 * seq,
        lost: 3,
        stale: 1,
        latency_p50_ns: 45_000,
        latency_p99_ns: 120_000,
        input_samples_to_output: 6_400,
        input_samples_per_output: 12_800,
        out_of_order: 7 * seq + 2,
        resyncs: seq + 1,
        service: ServiceId::Compensator.code(),
        state: ServiceState::Running.code(),
        _pad: [0; 6],
    }
}

pub fn log_line(seq: u64) -> vibro_msgs::LogLine {
    let mut m = vibro_msgs::LogLine::new(
        ServiceId::Compensator,
        vibro_msgs::LogLevel::Warn,
        &format!("vibro_compensator: stale estimate – line {seq} ✓"),
    );
    m.seq = seq;
    m.publish_ns = 9_500 + seq;
    m.wall_ns = 1_790_000_000_000_000_000 + seq;
    m
}

/// A topic, its message type, and the fixture message for a sequence number.
pub type Topic = (&'static str, vibro_msgs::MessageKind, fn(u64) -> Message);

/// The topic each fixture is recorded on, and the message for sequence `seq`.
pub fn topics() -> [Topic; 7] {
    use vibro_msgs::MessageKind as K;
    [
        ("/accel", K::AccelBlock, |s| accel(s).into()),
        ("/vib", K::VibBlock, |s| vib(s).into()),
        ("/estimate", K::VibEstimate, |s| estimate(s).into()),
        ("/compensated", K::CompensatedBlock, |s| {
            compensated(s).into()
        }),
        ("/truth", K::TruthBlock, |s| truth(s).into()),
        ("/heartbeat/compensator", K::Heartbeat, |s| {
            heartbeat(s).into()
        }),
        ("/log/compensator", K::LogLine, |s| log_line(s).into()),
    ]
}
