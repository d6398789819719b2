//! An independent reader: the PyPI `mcap` reader with `mcap-protobuf-support` (which
//! builds its decoders from the schemas embedded in the file, as Foxglove does) must
//! decode every message of every channel, with CRCs checked, to the values written.
//! Doubles are compared by their bits. Fails, never skips, if Python or the packages
//! are missing.

use crate::common::{
    accel, compensated, estimate, heartbeat, log_line, scratch, topics, truth, vib,
};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use vibro_mcap::{Recorder, RecorderOptions};

const HINT: &str = "run `pip install -r tests/python/requirements.txt` from the workspace root";

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn run_check(file: &Path, expect_counts: &str) -> Value {
    let script = workspace_root().join("tests/python/mcap_check.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(file)
        .arg("--expect-counts")
        .arg(expect_counts)
        .output()
        .unwrap_or_else(|e| panic!("cannot run python3 {}: {e}; {HINT}", script.display()));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_ne!(
        out.status.code(),
        Some(3),
        "Python packages missing: {stderr}\n{HINT}"
    );
    assert!(
        out.status.success(),
        "mcap_check.py failed ({}): {stderr}\nstdout: {}",
        out.status,
        String::from_utf8_lossy(&out.stdout)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn bits(values: &[f64]) -> Vec<u64> {
    values.iter().map(|v| v.to_bits()).collect()
}

fn flat(rows: &[[f64; 3]], count: u32) -> Vec<u64> {
    bits(&rows[..count as usize].concat())
}

/// The bit patterns Python saw for one repeated double field.
fn seen_bits(channel: &Value, path: &str) -> Vec<u64> {
    channel["first_message_f64_bits"][path]
        .as_array()
        .unwrap_or_else(|| panic!("no repeated double {path} in {channel}"))
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect()
}

/// The bit pattern Python saw for one scalar double field.
fn seen_bit(channel: &Value, path: &str) -> u64 {
    channel["first_message_f64_bits"][path]
        .as_u64()
        .unwrap_or_else(|| panic!("no double {path} in {channel}"))
}

fn int(channel: &Value, field: &str) -> u64 {
    channel["first_message"][field]
        .as_u64()
        .unwrap_or_else(|| panic!("no integer {field} in {channel}"))
}

#[test]
fn the_python_reference_reader_decodes_every_type_to_the_written_values() {
    let dir = scratch("python");
    let path = dir.join("every-type.mcap");
    let options = RecorderOptions {
        chunk_size_bytes: 8 * 1024,
        ..RecorderOptions::default()
    };
    let mut recorder = Recorder::create(&path, options).unwrap();
    for (topic, kind, _) in topics() {
        recorder.add_channel(topic, kind).unwrap();
    }
    recorder
        .add_attachment("al15.toml", "application/toml", b"k1 = 1.0\n".to_vec())
        .unwrap();
    // Three messages per topic; the first (sequence 0) is compared field by field.
    for seq in 0..3u64 {
        for (i, (topic, _, make)) in topics().into_iter().enumerate() {
            let t = 1_000_000_000 + seq * 1_000_000 + i as u64;
            recorder
                .write(topic, t, t - 500, seq as u32, &make(seq))
                .unwrap();
        }
    }
    recorder.finish().unwrap();

    let counts: serde_json::Map<String, Value> = topics()
        .iter()
        .map(|(t, _, _)| (t.to_string(), Value::from(3)))
        .collect();
    let report = run_check(&path, &Value::Object(counts).to_string());
    assert_eq!(report["ok"], true);
    assert_eq!(report["attachments"], serde_json::json!(["al15.toml"]));
    let channels = &report["channels"];
    for (i, (topic, kind, _)) in topics().into_iter().enumerate() {
        let c = &channels[topic];
        assert_eq!(c["schema"], format!("vibrocomp.v1.{kind}"), "{topic}");
        assert_eq!(c["message_encoding"], "protobuf");
        assert_eq!(c["count"], 3);
        assert_eq!(c["first_log_time_ns"], 1_000_000_000 + i as u64);
        assert_eq!(c["last_log_time_ns"], 1_002_000_000 + i as u64);
        assert_eq!(c["first_publish_time_ns"], 1_000_000_000 + i as u64 - 500);
        assert_eq!(
            (&c["first_sequence"], &c["last_sequence"]),
            (&0.into(), &2.into())
        );
        assert_eq!(c["sequence_gaps"], 0);
    }

    let a = accel(0);
    let c = &channels["/accel"];
    assert_eq!(int(c, "seq"), a.seq);
    assert_eq!(int(c, "first_sample_index"), a.first_sample_index);
    assert_eq!(int(c, "t0_ns"), a.t0_ns);
    assert_eq!(int(c, "sample_period_ns"), a.sample_period_ns);
    assert_eq!(int(c, "publish_ns"), a.publish_ns);
    assert_eq!(int(c, "source_id"), u64::from(a.source_id));
    assert_eq!(int(c, "flags"), u64::from(a.flags));
    assert_eq!(seen_bits(c, "output_v"), flat(&a.output_v, a.count));
    // The readable copy shows the same numbers (negative zero included).
    assert_eq!(c["first_message"]["output_v"][1], a.output_v[0][1]);
    assert_eq!(c["first_message"]["output_v"][0].to_string(), "-0.0");

    let v = vib(0);
    let c = &channels["/vib"];
    assert_eq!(int(c, "sample_period_ns"), v.sample_period_ns);
    assert_eq!(int(c, "flags"), u64::from(v.flags));
    assert_eq!(seen_bits(c, "sample_v"), flat(&v.sample_v, v.count));
    assert_eq!(seen_bits(c, "sample_v").len(), 3 * 256);

    let e = estimate(0);
    let c = &channels["/estimate"];
    for (field, want) in [
        ("seq", e.seq),
        ("index", e.index),
        ("source_seq", e.source_seq),
        ("publish_ns", e.publish_ns),
        ("start_ns", e.start_ns),
        ("end_ns", e.end_ns),
        ("center_ns", e.center_ns),
        ("samples", e.samples.into()),
        ("valid_samples", e.valid_samples.into()),
        ("flags", e.flags.into()),
    ] {
        assert_eq!(int(c, field), want, "VibEstimate.{field}");
    }
    let m = &c["first_message"];
    assert_eq!(
        m["saturated_samples"],
        serde_json::json!(e.saturated_samples)
    );
    assert_eq!(m["broadband"]["welch_segments"], e.broadband_welch_segments);
    assert_eq!(
        m["broadband"]["welch_segment_samples"],
        e.welch_segment_samples
    );
    assert_eq!(
        seen_bit(c, "broadband.f_lo_hz"),
        e.broadband_f_lo_hz.to_bits()
    );
    assert_eq!(
        seen_bit(c, "broadband.f_hi_hz"),
        e.broadband_f_hi_hz.to_bits()
    );
    assert_eq!(seen_bits(c, "broadband.rms_g"), bits(&e.broadband_rms_g));
    assert_eq!(
        seen_bits(c, "broadband.rms_u_g"),
        bits(&e.broadband_rms_u_g)
    );
    assert_eq!(
        seen_bits(c, "broadband.covariance_g2"),
        flat(&e.broadband_covariance_g2, 3)
    );
    assert_eq!(
        seen_bits(c, "broadband.covariance_u_g2"),
        flat(&e.broadband_covariance_u_g2, 3)
    );
    assert_eq!(
        seen_bits(c, "broadband.kurtosis"),
        bits(&e.broadband_kurtosis)
    );
    assert_eq!(
        seen_bits(c, "broadband.kurtosis_u"),
        bits(&e.broadband_kurtosis_u)
    );
    assert_eq!(m["tones"].as_array().unwrap().len(), e.tone_count as usize);
    for k in 0..e.tone_count as usize {
        let p = |f: &str| format!("tones[{k}].{f}");
        assert_eq!(
            seen_bit(c, &p("frequency_hz")),
            e.tone_frequency_hz[k].to_bits()
        );
        assert_eq!(
            seen_bit(c, &p("frequency_u_hz")),
            e.tone_frequency_u_hz[k].to_bits()
        );
        assert_eq!(
            seen_bits(c, &p("amplitude_g")),
            bits(&e.tone_amplitude_g[k])
        );
        assert_eq!(
            seen_bits(c, &p("amplitude_u_g")),
            bits(&e.tone_amplitude_u_g[k])
        );
        assert_eq!(seen_bits(c, &p("phase_rad")), bits(&e.tone_phase_rad[k]));
        assert_eq!(
            seen_bits(c, &p("phase_u_rad")),
            bits(&e.tone_phase_u_rad[k])
        );
        assert_eq!(seen_bits(c, &p("snr_db")), bits(&e.tone_snr_db[k]));
    }
    assert_eq!(m["bands"].as_array().unwrap().len(), e.band_count as usize);
    for b in 0..e.band_count as usize {
        let p = |f: &str| format!("bands[{b}].{f}");
        assert_eq!(seen_bit(c, &p("f_lo_hz")), e.band_f_lo_hz[b].to_bits());
        assert_eq!(seen_bit(c, &p("f_hi_hz")), e.band_f_hi_hz[b].to_bits());
        assert_eq!(
            seen_bits(c, &p("psd_g2_per_hz")),
            bits(&e.band_psd_g2_per_hz[b])
        );
        assert_eq!(
            seen_bits(c, &p("psd_u_g2_per_hz")),
            bits(&e.band_psd_u_g2_per_hz[b])
        );
        assert_eq!(seen_bits(c, &p("rms_g")), bits(&e.band_rms_g[b]));
    }

    let k = compensated(0);
    let c = &channels["/compensated"];
    for (field, want) in [
        ("seq", k.seq),
        ("input_seq", k.input_seq),
        ("first_sample_index", k.first_sample_index),
        ("t0_ns", k.t0_ns),
        ("sample_period_ns", k.sample_period_ns),
        ("estimate_seq", k.estimate_seq),
        ("input_publish_ns", k.input_publish_ns),
        ("recv_ns", k.recv_ns),
        ("publish_ns", k.publish_ns),
        ("source_id", k.source_id.into()),
        ("flags", k.flags.into()),
        ("mode", k.mode.into()),
    ] {
        assert_eq!(int(c, field), want, "CompensatedBlock.{field}");
    }
    assert_eq!(c["first_message"]["estimate_age_ns"], k.estimate_age_ns);
    for (field, rows) in [
        ("a1_g", &k.a1_g),
        ("a2_g", &k.a2_g),
        ("a3_g", &k.a3_g),
        ("a4_g", &k.a4_g),
        ("main_g", &k.main_g),
        ("det_g", &k.det_g),
        ("rand_g", &k.rand_g),
    ] {
        assert_eq!(
            seen_bits(c, field),
            flat(rows, k.count),
            "CompensatedBlock.{field}"
        );
    }

    let t = truth(0);
    let c = &channels["/truth"];
    assert_eq!(int(c, "t0_ns"), t.t0_ns);
    assert_eq!(int(c, "flags"), u64::from(t.flags));
    assert_eq!(seen_bits(c, "a_l_ia_g"), flat(&t.a_l_ia_g, t.count));
    assert_eq!(
        seen_bits(c, "a_sensed_ia_g"),
        flat(&t.a_sensed_ia_g, t.count)
    );
    assert_eq!(
        seen_bits(c, "vib_error_ia_g"),
        flat(&t.vib_error_ia_g, t.count)
    );

    let h = heartbeat(0);
    let c = &channels["/heartbeat/compensator"];
    for (field, want) in [
        ("seq", h.seq),
        ("publish_ns", h.publish_ns),
        ("uptime_ns", h.uptime_ns),
        ("received", h.received),
        ("published", h.published),
        ("lost", h.lost),
        ("stale", h.stale),
        ("latency_p50_ns", h.latency_p50_ns),
        ("latency_p99_ns", h.latency_p99_ns),
        ("input_samples_to_output", h.input_samples_to_output),
        ("input_samples_per_output", h.input_samples_per_output),
        ("out_of_order", h.out_of_order),
        ("resyncs", h.resyncs),
        ("service", h.service.into()),
        ("state", h.state.into()),
    ] {
        assert_eq!(int(c, field), want, "Heartbeat.{field}");
    }

    let l = log_line(0);
    let c = &channels["/log/compensator"];
    for (field, want) in [
        ("seq", l.seq),
        ("publish_ns", l.publish_ns),
        ("wall_ns", l.wall_ns),
        ("service", l.service.into()),
        ("level", l.level.into()),
    ] {
        assert_eq!(int(c, field), want, "LogLine.{field}");
    }
    assert_eq!(
        c["first_message"]["text"].as_str(),
        Some(l.text().as_ref()),
        "LogLine.text"
    );
}

#[test]
fn the_python_check_fails_on_wrong_counts_and_on_a_damaged_file() {
    let dir = scratch("python-fail");
    let path = dir.join("one.mcap");
    let mut recorder = Recorder::create(&path, RecorderOptions::default()).unwrap();
    recorder
        .add_channel("/accel", vibro_msgs::MessageKind::AccelBlock)
        .unwrap();
    recorder.write("/accel", 1, 1, 0, &accel(0)).unwrap();
    recorder.finish().unwrap();
    let script = workspace_root().join("tests/python/mcap_check.py");

    let out = Command::new("python3")
        .arg(&script)
        .arg(&path)
        .args(["--expect-counts", r#"{"/accel": 2}"#])
        .output()
        .unwrap_or_else(|e| panic!("cannot run python3: {e}; {HINT}"));
    assert_ne!(out.status.code(), Some(3), "{HINT}");
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr)
        .contains("topic '/accel': expected 2 messages, found 1"));

    let mut bytes = std::fs::read(&path).unwrap();
    bytes.truncate(bytes.len() / 2);
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, bytes).unwrap();
    let out = Command::new("python3")
        .arg(&script)
        .arg(&cut)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "a truncated file must fail");
}
