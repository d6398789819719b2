//! Every wire type through real iceoryx2 publish-subscribe services: one message with
//! distinctive values (negative zero, subnormals, extremes, a NaN with a payload) goes in
//! and comes out byte-identical. Each run uses its own service-name prefix, and a
//! process-local node, so parallel runs never meet and nothing is left behind.

use iceoryx2::prelude::*;
use vibro_msgs::{
    AccelBlock, CompensatedBlock, CompensationMode, Heartbeat, ServiceId, ServiceNames,
    ServiceState, Stream, TruthBlock, VibBlock, VibEstimate, WireMessage, ACCEL_BLOCK_MAX,
    MAX_BANDS, MAX_TONES, VIB_BLOCK_MAX,
};

/// A quiet NaN with a payload: the bits must survive the trip untouched.
const NAN_WITH_PAYLOAD: f64 = f64::from_bits(0x7FF8_0000_DEAD_BEEF);

fn special(i: usize) -> f64 {
    match i % 7 {
        0 => -0.0,
        1 => f64::MIN_POSITIVE / 4.0, // subnormal
        2 => f64::MAX,
        3 => -f64::MAX,
        4 => NAN_WITH_PAYLOAD,
        5 => f64::INFINITY,
        _ => -1.6698 + i as f64 * 1e-3,
    }
}

fn fill(rows: &mut [[f64; 3]], base: usize) {
    for (i, row) in rows.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = special(base + 3 * i + j);
        }
    }
}

fn accel() -> AccelBlock {
    let mut m = AccelBlock::ZEROED;
    m.seq = u64::MAX;
    m.first_sample_index = 1 << 40;
    m.t0_ns = 1_700_000_000_123_456_789;
    m.sample_period_ns = 500_000;
    m.publish_ns = 42;
    fill(&mut m.output_v, 1);
    m.count = ACCEL_BLOCK_MAX as u32;
    m.source_id = 0xA1;
    m.flags = vibro_msgs::accel_flags::GAP_BEFORE;
    m
}

fn vib() -> VibBlock {
    let mut m = VibBlock::ZEROED;
    m.seq = 7;
    m.first_sample_index = 3584;
    m.t0_ns = 9_999;
    m.sample_period_ns = 39_062;
    m.publish_ns = 11;
    fill(&mut m.sample_v, 2);
    m.count = VIB_BLOCK_MAX as u32;
    m.source_id = 2;
    m.flags = vibro_msgs::vib_flags::SATURATED;
    m
}

fn estimate() -> VibEstimate {
    let mut m = VibEstimate::ZEROED;
    m.seq = 3;
    m.index = 4;
    m.source_seq = 5;
    m.publish_ns = 6;
    m.start_ns = 1_000_000_000;
    m.end_ns = 2_000_000_000;
    m.center_ns = 1_500_000_000;
    m.broadband_f_lo_hz = 20.0;
    m.broadband_f_hi_hz = 2000.0;
    m.broadband_rms_g = [1.4, -0.0, NAN_WITH_PAYLOAD];
    m.broadband_covariance_g2 = [[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 3.0]];
    m.broadband_kurtosis = [3.0, 3.1, 2.9];
    for k in 0..MAX_TONES {
        m.tone_frequency_hz[k] = 12.0 * (k + 1) as f64;
        m.tone_amplitude_g[k] = [1.2, 1.2, 0.5];
        m.tone_phase_rad[k] = [special(k), 0.25, -0.25];
    }
    for b in 0..MAX_BANDS {
        m.band_f_lo_hz[b] = 20.0 * 2f64.powi(b as i32);
        m.band_f_hi_hz[b] = 40.0 * 2f64.powi(b as i32);
        m.band_rms_g[b] = [special(b + 1), 0.5, 0.25];
    }
    m.samples = 8192;
    m.valid_samples = 8190;
    m.saturated_samples = [0, 1, 2];
    m.broadband_welch_segments = 15;
    m.tone_count = 2;
    m.band_count = 5;
    m.flags = vibro_msgs::estimate_flags::GAP | vibro_msgs::estimate_flags::SATURATED_AXIS0;
    m
}

fn compensated() -> CompensatedBlock {
    let mut m = CompensatedBlock::ZEROED;
    m.seq = 1;
    m.input_seq = 2;
    m.first_sample_index = 3;
    m.t0_ns = 4;
    m.sample_period_ns = 5;
    m.estimate_seq = 6;
    m.input_publish_ns = 7;
    m.recv_ns = 8;
    m.publish_ns = 9;
    m.estimate_age_ns = -123_456;
    fill(&mut m.a1_g, 3);
    fill(&mut m.a2_g, 4);
    fill(&mut m.a3_g, 5);
    fill(&mut m.a4_g, 6);
    fill(&mut m.main_g, 7);
    fill(&mut m.det_g, 8);
    fill(&mut m.rand_g, 9);
    m.count = 17;
    m.source_id = 10;
    m.flags = vibro_msgs::compensation_flags::VIBRATION_ESTIMATE_STALE;
    m.mode = CompensationMode::Exact.code();
    m
}

fn truth() -> TruthBlock {
    let mut m = TruthBlock::ZEROED;
    m.seq = 12;
    m.first_sample_index = 13;
    m.t0_ns = 14;
    m.sample_period_ns = 15;
    m.publish_ns = 16;
    fill(&mut m.a_l_ia_g, 10);
    fill(&mut m.vib_error_ia_g, 11);
    fill(&mut m.a_sensed_ia_g, 12);
    m.count = 1;
    m.source_id = 17;
    m.flags = vibro_msgs::truth_flags::VIB_ERROR_KNOWN;
    m
}

fn heartbeat() -> Heartbeat {
    Heartbeat {
        seq: 100,
        publish_ns: 101,
        uptime_ns: 102,
        received: 103,
        published: 104,
        lost: 105,
        stale: 106,
        latency_p50_ns: 107,
        latency_p99_ns: 108,
        input_samples_to_output: 109,
        input_samples_per_output: 110,
        out_of_order: 111,
        resyncs: 112,
        service: ServiceId::Estimator.code(),
        state: ServiceState::Degraded.code(),
        _pad: [0; 6],
    }
}

fn roundtrip<T: WireMessage>(
    node: &Node<local::Service>,
    names: &ServiceNames,
    stream: Stream,
    sent: T,
) {
    assert_eq!(T::KIND, stream.kind());
    let service = node
        .service_builder(&names.service_name(stream).unwrap())
        .publish_subscribe::<T>()
        .open_or_create()
        .unwrap();
    let subscriber = service.subscriber_builder().create().unwrap();
    let publisher = service.publisher_builder().create().unwrap();
    let events = node
        .service_builder(&names.event_service_name(stream).unwrap())
        .event()
        .open_or_create()
        .unwrap();
    let listener = events.listener_builder().create().unwrap();
    let notifier = events.notifier_builder().create().unwrap();

    publisher.send_copy(sent).unwrap();
    assert_eq!(notifier.notify().unwrap(), 1, "one listener notified");

    let mut woken = 0;
    listener.try_wait(|_| woken += 1).unwrap();
    assert_eq!(woken, 1, "{stream:?}: the event arrived");
    let sample = subscriber.receive().unwrap().expect("a sample");
    let received: &T = &sample;
    assert_eq!(
        received.bytes(),
        sent.bytes(),
        "{stream:?} changed in transit"
    );
    assert!(
        subscriber.receive().unwrap().is_none(),
        "exactly one sample"
    );
}

#[test]
fn every_type_crosses_iceoryx2_bit_identical() {
    let names = ServiceNames::new(&format!("vct-msgs-{}/", std::process::id())).unwrap();
    set_log_level(LogLevel::Error); // no config file here is expected, not news
    let node = NodeBuilder::new().create::<local::Service>().unwrap();

    roundtrip(&node, &names, Stream::Accel, accel());
    roundtrip(&node, &names, Stream::Vib, vib());
    roundtrip(&node, &names, Stream::Estimate, estimate());
    roundtrip(&node, &names, Stream::Compensated, compensated());
    roundtrip(&node, &names, Stream::Truth, truth());
    roundtrip(
        &node,
        &names,
        Stream::Heartbeat(ServiceId::Estimator),
        heartbeat(),
    );
    let mut line = vibro_msgs::LogLine::new(
        ServiceId::Compensator,
        vibro_msgs::LogLevel::Warn,
        "vibro_compensator: stale estimate – 1.2 s old ✓",
    );
    line.seq = 7;
    roundtrip(&node, &names, Stream::Log(ServiceId::Compensator), line);
    assert_eq!(
        line.text(),
        "vibro_compensator: stale estimate – 1.2 s old ✓"
    );
    // A line over the limit is cut at a character boundary.
    let long = "é".repeat(vibro_msgs::LOG_TEXT_MAX);
    let cut = vibro_msgs::LogLine::new(ServiceId::Estimator, vibro_msgs::LogLevel::Info, &long);
    assert_eq!(cut.text().len(), vibro_msgs::LOG_TEXT_MAX);
    assert!(cut.text().chars().all(|c| c == 'é'));
    // The values the comparison relies on really are special.
    let e = estimate();
    assert_eq!(e.broadband_rms_g[2].to_bits(), 0x7FF8_0000_DEAD_BEEF);
    assert!(e.broadband_rms_g[1].is_sign_negative());
    assert!(accel().output_v[0][0].is_subnormal());
}
