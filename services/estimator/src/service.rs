//! The estimator's hot loop: `{prefix}vib` → `vibro_dsp::Estimator` → `{prefix}estimate`.

use crate::common::{
    count_first, data_stream_config, estimate_stream_config, now_ns, Continuity,
    HeartbeatPublisher, HeartbeatReport, JsonObject, Latency, LoopMode, Quantiles, Shutdown,
    StreamCounters,
};
use crate::Config;
use anyhow::{anyhow, Context};
use iceoryx2::prelude::CallbackProgression;
use tracing::{debug, info, warn};
use vibro_dsp::{Estimate, Estimator, SampleBlock};
use vibro_ipc::{
    cleanup_dead_nodes, create_node, create_waitset, StreamPublisher, StreamSubscriber,
};
use vibro_msgs::{
    estimate_flags, vib_flags, ServiceId, ServiceState, Stream, VibBlock, VibEstimate, WireMessage,
};

/// What the estimator did, returned by [`run`] when it stops (and printed by `--json`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    /// Time the hot loop ran.
    pub uptime_s: f64,
    /// The `{prefix}vib` stream: received, lost (by `seq` and by `first_sample_index`),
    /// out of order, restarts, malformed.
    pub vib: StreamCounters,
    /// Blocks whose `sample_period_ns` disagrees with the configured rate by more than
    /// 1 ns: their samples were kept out (a gap), the estimates over them flagged
    /// `RATE_MISMATCH`.
    pub rate_mismatches: u64,
    /// Blocks flagged `GAP_BEFORE` or `SATURATED` by their producer.
    pub producer_flagged: u64,
    /// The estimator's own totals (time gaps, dropped blocks, non-finite samples, ...).
    pub dsp: vibro_dsp::Counters,
    /// Estimates published on `{prefix}estimate`.
    pub estimates_published: u64,
    /// Estimates published with a quality flag other than `TONE_FREE` (gap, non-finite,
    /// out of order, insufficient data, saturation, rate mismatch).
    pub estimates_flagged: u64,
    /// Estimates a subscriber's full buffer did not take (after the back-pressure timeout).
    pub undelivered: u64,
    /// Other publish failures (loan, send).
    pub publish_errors: u64,
    /// Receive failures.
    pub receive_errors: u64,
    pub heartbeats: u64,
    /// From receiving the block that completed a window to publishing its estimate.
    pub latency: Quantiles,
}

impl Summary {
    /// The summary as one JSON object.
    pub fn to_json(&self) -> String {
        let d = &self.dsp;
        let mut dsp = JsonObject::new();
        dsp.u64("blocks_accepted", d.blocks_accepted)
            .u64("blocks_dropped", d.blocks_dropped)
            .u64("sequence_gaps", d.sequence_gaps)
            .u64("gap_samples", d.gap_samples)
            .u64("restarts", d.restarts)
            .u64("non_finite_samples", d.non_finite_samples)
            .u64("saturated_samples", d.saturated_samples)
            .u64("estimates", d.estimates);
        let mut o = JsonObject::new();
        o.str("service", "estimator")
            .f64("uptime_s", self.uptime_s)
            .object("vib", self.vib.to_json())
            .u64("rate_mismatches", self.rate_mismatches)
            .u64("producer_flagged", self.producer_flagged)
            .object("dsp", dsp)
            .u64("estimates_published", self.estimates_published)
            .u64("estimates_flagged", self.estimates_flagged)
            .u64("undelivered", self.undelivered)
            .u64("publish_errors", self.publish_errors)
            .u64("receive_errors", self.receive_errors)
            .u64("heartbeats", self.heartbeats)
            .object("latency", self.latency.to_json());
        o.finish()
    }
}

/// Runs the estimator until `shutdown` is triggered: the hot loop on its own thread,
/// this call blocking until it ends. Returns the final counters.
pub fn run(config: Config, shutdown: Shutdown) -> anyhow::Result<Summary> {
    let handle = std::thread::Builder::new()
        .name("vibro-estimator".into())
        .spawn(move || hot_loop(config, shutdown))
        .context("spawning the estimator's hot-loop thread")?;
    handle
        .join()
        .map_err(|_| anyhow!("the estimator's hot loop panicked"))?
}

/// [`run`] for a tokio task: awaits the hot thread without blocking the runtime.
pub async fn run_async(config: Config, shutdown: Shutdown) -> anyhow::Result<Summary> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::Builder::new()
        .name("vibro-estimator".into())
        .spawn(move || {
            let _ = tx.send(hot_loop(config, shutdown));
        })
        .context("spawning the estimator's hot-loop thread")?;
    rx.await
        .map_err(|_| anyhow!("the estimator's hot loop ended without a result (it panicked)"))?
}

/// Mirrors one `vibro_dsp::Estimate` into the wire type, field by field (values that
/// could not be estimated stay NaN, as the estimator gives them). The stream
/// bookkeeping (`seq`, `source_seq`, `publish_ns`) is the caller's.
pub fn mirror_estimate(e: &Estimate, m: &mut VibEstimate) {
    m.index = e.index;
    m.start_ns = e.start_ns;
    m.end_ns = e.end_ns;
    m.center_ns = e.center_ns;
    m.samples = saturating_u32(e.samples);
    m.valid_samples = saturating_u32(e.valid_samples);
    m.saturated_samples = e.saturated_samples.map(saturating_u32);
    let b = &e.broadband;
    m.broadband_f_lo_hz = b.f_lo_hz;
    m.broadband_f_hi_hz = b.f_hi_hz;
    m.broadband_rms_g = b.rms_g;
    m.broadband_rms_u_g = b.rms_u_g;
    m.broadband_covariance_g2 = b.covariance_g2;
    m.broadband_covariance_u_g2 = b.covariance_u_g2;
    m.broadband_kurtosis = b.kurtosis;
    m.broadband_kurtosis_u = b.kurtosis_u;
    m.broadband_welch_segments = saturating_u32(b.welch_segments);
    // Both lists hold at most vibro_dsp::MAX_TONES / MAX_BANDS = the wire capacities
    // (checked by vibro-msgs' tests); `zip` bounds the copy anyway.
    let mut tones = 0;
    for (k, t) in (0..m.tone_frequency_hz.len()).zip(e.tones.iter()) {
        m.tone_frequency_hz[k] = t.frequency_hz;
        m.tone_frequency_u_hz[k] = t.frequency_u_hz;
        m.tone_amplitude_g[k] = t.amplitude_g;
        m.tone_amplitude_u_g[k] = t.amplitude_u_g;
        m.tone_phase_rad[k] = t.phase_rad;
        m.tone_phase_u_rad[k] = t.phase_u_rad;
        m.tone_snr_db[k] = t.snr_db;
        tones += 1;
    }
    m.tone_count = tones;
    let mut bands = 0;
    for (i, band) in (0..m.band_f_lo_hz.len()).zip(e.bands.iter()) {
        m.band_f_lo_hz[i] = band.f_lo_hz;
        m.band_f_hi_hz[i] = band.f_hi_hz;
        m.band_psd_g2_per_hz[i] = band.psd_g2_per_hz;
        m.band_psd_u_g2_per_hz[i] = band.psd_u_g2_per_hz;
        m.band_rms_g[i] = band.rms_g;
        bands += 1;
    }
    m.band_count = bands;
    let f = &e.flags;
    let mut flags = 0;
    for (set, bit) in [
        (f.tone_free, estimate_flags::TONE_FREE),
        (f.gap, estimate_flags::GAP),
        (f.non_finite, estimate_flags::NON_FINITE),
        (f.out_of_order, estimate_flags::OUT_OF_ORDER),
        (f.insufficient_data, estimate_flags::INSUFFICIENT_DATA),
    ] {
        if set {
            flags |= bit;
        }
    }
    for (axis, &sat) in f.saturated.iter().enumerate() {
        if sat {
            flags |= estimate_flags::SATURATED_AXIS0 << axis;
        }
    }
    m.flags = flags;
}

fn saturating_u32(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// Everything the hot loop counts; no allocation after start.
struct Counters {
    vib: StreamCounters,
    rate_mismatches: u64,
    producer_flagged: u64,
    estimates_published: u64,
    estimates_flagged: u64,
    undelivered: u64,
    publish_errors: u64,
    receive_errors: u64,
}

fn hot_loop(config: Config, shutdown: Shutdown) -> anyhow::Result<Summary> {
    let started_ns = now_ns();
    let names = &config.names;
    let node = create_node("vibro-estimator").context("creating the estimator's iceoryx2 node")?;
    let cleaned = cleanup_dead_nodes(&node);
    if cleaned > 0 {
        info!(cleaned, "removed the resources of dead iceoryx2 nodes");
    }
    let vib = StreamSubscriber::<VibBlock>::create(
        &node,
        &names.vib(),
        &names.event(Stream::Vib),
        &data_stream_config(),
    )
    .with_context(|| format!("subscribing to {}", names.vib()))?;
    let mut estimates = StreamPublisher::<VibEstimate>::create(
        &node,
        &names.estimate(),
        &names.event(Stream::Estimate),
        &estimate_stream_config(),
    )
    .with_context(|| format!("publishing on {}", names.estimate()))?;
    let mut heartbeat = HeartbeatPublisher::create(&node, names, ServiceId::Estimator)?;
    let mut progress = HeartbeatPublisher::progress(&node, names, ServiceId::Estimator)?;

    let waitset = create_waitset().context("creating the estimator's wait set")?;
    let _vib_guard = waitset
        .attach_notification(vib.listener())
        .with_context(|| format!("attaching {} to the wait set", names.event(Stream::Vib)))?;
    let _poll_guard = waitset
        .attach_interval(config.service.shutdown_poll)
        .context("attaching the shutdown-poll interval to the wait set")?;
    let _heartbeat_guard = waitset
        .attach_interval(config.service.heartbeat_period)
        .context("attaching the heartbeat interval to the wait set")?;

    let mut estimator = Estimator::new(config.estimator.clone());
    let expected_period_ns = config.estimator.sample_period_ns();
    let mut continuity = Continuity::new();
    let mut latency = Latency::new()?;
    let mut c = Counters {
        vib: StreamCounters::default(),
        rate_mismatches: 0,
        producer_flagged: 0,
        estimates_published: 0,
        estimates_flagged: 0,
        undelivered: 0,
        publish_errors: 0,
        receive_errors: 0,
    };
    let mut estimate_seq = 0u64;
    let mut fatal: Option<vibro_dsp::Error> = None;
    // The time span `[from, to)` of the blocks dropped for their rate since the last
    // estimate that started after them: the estimates whose windows overlap it are
    // flagged RATE_MISMATCH.
    let mut mismatch_span: Option<(u64, u64)> = None;

    let heartbeat_ns = config.service.heartbeat_period.as_nanos() as u64;
    let summary_ns = config.service.summary_period.as_nanos() as u64;
    let mut next_heartbeat_ns = started_ns;
    let mut next_summary_ns = started_ns.saturating_add(summary_ns);
    let mut last_period = (
        c.vib,
        c.estimates_published,
        c.estimates_flagged,
        c.rate_mismatches,
    );
    let mut period_start_ns = started_ns;

    info!(
        vib = %names.vib(),
        estimate = %names.estimate(),
        loop_mode = %config.service.loop_mode,
        sample_rate_hz = config.estimator.sample_rate_hz(),
        window_samples = config.estimator.window_samples(),
        hop_samples = config.estimator.hop_samples(),
        source = %config.source,
        "estimator running"
    );

    let spin = config.service.loop_mode == LoopMode::Spin;
    while !shutdown.is_triggered() {
        if !spin {
            waitset
                .wait_and_process_once_with_timeout(
                    |_| CallbackProgression::Continue,
                    config.service.shutdown_poll,
                )
                .context("waiting on the estimator's wait set")?;
            if let Err(e) = vib.clear_events() {
                if count_first(&mut c.receive_errors) {
                    warn!("{e}");
                }
            }
        }
        let mut received_any = false;
        loop {
            let sample = match vib.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => {
                    if count_first(&mut c.receive_errors) {
                        warn!("{e}");
                    }
                    break;
                }
            };
            received_any = true;
            let recv_ns = now_ns();
            let block: &VibBlock = &sample;
            c.vib.received += 1;
            if let Err(e) = block.validate() {
                // The samples beyond the capacity do not exist: drop the block; the
                // estimator then sees its seq missing and flags the window GAP.
                if count_first(&mut c.vib.malformed) {
                    warn!(seq = block.seq, "dropping a malformed block: {e}");
                }
                continue;
            }
            let arrival =
                continuity.check(block.seq, block.first_sample_index, u64::from(block.count));
            c.vib.record(&arrival);
            if arrival.restarted {
                // The producer started again (a new replay, a restarted rig): a new
                // time base, so a new window rather than "out of order" blocks.
                estimator.reset();
                mismatch_span = None;
            }
            if block.flags & vib_flags::ALL != 0 {
                c.producer_flagged += 1;
            }
            // A block at another rate than the estimator's: its samples would sit at the
            // wrong times in the window, so they are kept out. (0: the producer does not
            // say; an empty block has no samples at any rate.)
            let rate_mismatch = block.count > 0
                && block.sample_period_ns != 0
                && (block.sample_period_ns as f64 - expected_period_ns).abs() > 1.0;
            let samples_raw = if rate_mismatch {
                if count_first(&mut c.rate_mismatches) {
                    warn!(
                        seq = block.seq,
                        sample_period_ns = block.sample_period_ns,
                        expected_ns = expected_period_ns,
                        "vibration blocks do not match estimator.sample_rate_hz: their samples \
                         are kept out of the estimates (further ones are counted)"
                    );
                }
                let from = block.t0_ns;
                let to = from.saturating_add(
                    block
                        .sample_period_ns
                        .saturating_mul(u64::from(block.count)),
                );
                mismatch_span = Some(match mismatch_span {
                    Some((f, t)) => (f.min(from), t.max(to)),
                    None => (from, to),
                });
                // Handed over empty: the estimator takes its seq (no false sequence
                // gap), and the next block's timestamp shows the samples missing.
                &[][..]
            } else {
                block.samples_v()
            };
            // Out-of-order blocks go to the estimator too: it drops them by their
            // timestamps and flags the next estimate OUT_OF_ORDER.
            let input = SampleBlock {
                seq: block.seq,
                t0_ns: block.t0_ns,
                samples_raw,
            };
            let source_seq = block.seq;
            let pushed = estimator.push_block(&input, |e| {
                let over_mismatch = match mismatch_span {
                    Some((from, to)) => {
                        if e.start_ns >= to {
                            // Estimates come in time order: none will overlap it again.
                            mismatch_span = None;
                        }
                        e.start_ns < to && e.end_ns > from
                    }
                    None => false,
                };
                let mut publish_ns = 0;
                let result = estimates.publish_with(|m| {
                    mirror_estimate(e, m);
                    if over_mismatch {
                        m.flags |= estimate_flags::RATE_MISMATCH;
                    }
                    m.seq = estimate_seq;
                    m.source_seq = source_seq;
                    publish_ns = now_ns();
                    m.publish_ns = publish_ns;
                });
                estimate_seq += 1;
                match result {
                    Ok(_) => {}
                    Err(vibro_ipc::Error::Undelivered { .. }) => c.undelivered += 1,
                    Err(err) => {
                        if count_first(&mut c.publish_errors) {
                            warn!("{err}");
                        }
                        return;
                    }
                }
                c.estimates_published += 1;
                let f = &e.flags;
                if f.gap
                    || f.non_finite
                    || f.out_of_order
                    || f.insufficient_data
                    || f.saturated.contains(&true)
                    || over_mismatch
                {
                    c.estimates_flagged += 1;
                }
                latency.record(publish_ns.saturating_sub(recv_ns));
            });
            if let Err(e) = pushed {
                // Only an internal FFT failure (a bug) errors; stop with it.
                fatal = Some(e);
                break;
            }
        }
        if let Some(e) = fatal.take() {
            return Err(e).context("estimating a vibration window");
        }
        if received_any {
            // Once per wake-up: every estimate the blocks completed is out.
            let report = HeartbeatReport {
                received: c.vib.received,
                published: c.estimates_published,
                lost: c.vib.lost_messages,
                stale: c.estimates_flagged,
                latency: Quantiles::default(),
                state: ServiceState::Running,
                input_samples_to_output: estimator.samples_to_next_estimate(),
                input_samples_per_output: estimator.samples_per_estimate(),
            };
            if let Err(e) = progress.publish(&report) {
                debug!("progress: {e}");
            }
        }
        if spin {
            if received_any {
                // Keep the event buffer from filling while nobody waits on it.
                let _ = vib.clear_events();
            } else {
                std::hint::spin_loop();
            }
        }

        let now = now_ns();
        if now >= next_heartbeat_ns {
            next_heartbeat_ns = now.saturating_add(heartbeat_ns);
            let period = latency.period();
            let lost_now = c.vib.lost_messages + c.vib.lost_samples + c.vib.malformed;
            let lost_before =
                last_period.0.lost_messages + last_period.0.lost_samples + last_period.0.malformed;
            let state = if c.vib.received == 0 {
                ServiceState::Starting
            } else if lost_now > lost_before
                || c.estimates_flagged > last_period.2
                || c.rate_mismatches > last_period.3
            {
                ServiceState::Degraded
            } else {
                ServiceState::Running
            };
            let report = HeartbeatReport {
                received: c.vib.received,
                published: c.estimates_published,
                lost: c.vib.lost_messages,
                stale: c.estimates_flagged,
                latency: period,
                state,
                input_samples_to_output: estimator.samples_to_next_estimate(),
                input_samples_per_output: estimator.samples_per_estimate(),
            };
            if let Err(e) = heartbeat.publish(&report) {
                debug!("heartbeat: {e}");
            }
        }
        if now >= next_summary_ns {
            next_summary_ns = now.saturating_add(summary_ns);
            let dt_s = (now.saturating_sub(period_start_ns)) as f64 * 1e-9;
            let q = latency.period();
            info!(
                "estimator: {:.1} blocks/s, {} estimates ({} flagged), lost {} blocks / {} samples, rate mismatches {}, latency p50 {:.1} us p99 {:.1} us, dsp gap samples {}, non-finite {}",
                (c.vib.received - last_period.0.received) as f64 / dt_s.max(1e-9),
                c.estimates_published - last_period.1,
                c.estimates_flagged - last_period.2,
                c.vib.lost_messages - last_period.0.lost_messages,
                c.vib.lost_samples - last_period.0.lost_samples,
                c.rate_mismatches - last_period.3,
                q.p50_ns as f64 * 1e-3,
                q.p99_ns as f64 * 1e-3,
                estimator.counters().gap_samples,
                estimator.counters().non_finite_samples,
            );
            latency.reset_period();
            last_period = (
                c.vib,
                c.estimates_published,
                c.estimates_flagged,
                c.rate_mismatches,
            );
            period_start_ns = now;
            let cleaned = cleanup_dead_nodes(&node);
            if cleaned > 0 {
                info!(cleaned, "removed the resources of dead iceoryx2 nodes");
            }
        }
    }

    let report = HeartbeatReport {
        received: c.vib.received,
        published: c.estimates_published,
        lost: c.vib.lost_messages,
        stale: c.estimates_flagged,
        latency: latency.period(),
        state: ServiceState::Stopping,
        input_samples_to_output: estimator.samples_to_next_estimate(),
        input_samples_per_output: estimator.samples_per_estimate(),
    };
    if let Err(e) = heartbeat.publish(&report) {
        debug!("final heartbeat: {e}");
    }
    let summary = Summary {
        uptime_s: now_ns().saturating_sub(started_ns) as f64 * 1e-9,
        vib: c.vib,
        rate_mismatches: c.rate_mismatches,
        producer_flagged: c.producer_flagged,
        dsp: estimator.counters(),
        estimates_published: c.estimates_published,
        estimates_flagged: c.estimates_flagged,
        undelivered: c.undelivered,
        publish_errors: c.publish_errors,
        receive_errors: c.receive_errors,
        heartbeats: heartbeat.sent(),
        latency: latency.total(),
    };
    info!(
        received = summary.vib.received,
        lost_blocks = summary.vib.lost_messages,
        estimates = summary.estimates_published,
        p50_us = summary.latency.p50_ns as f64 * 1e-3,
        p99_us = summary.latency.p99_ns as f64 * 1e-3,
        "estimator stopped"
    );
    // The wait set, the ports and the node are released here, by Drop.
    Ok(summary)
}
