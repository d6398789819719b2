//! The estimator's transport: `{prefix}vib` → [`InProcess`] → `{prefix}estimate`, with
//! the wait set, heartbeats and the periodic summary. What happens to each block is
//! the core's (`crate::core`).

use crate::Config;
use anyhow::{anyhow, Context};
use iceoryx2::prelude::CallbackProgression;
use tracing::{debug, info, warn};
use vibro_estimator_core::{InProcess, Summary};
use vibro_ipc::{
    cleanup_dead_nodes, create_node, create_waitset, StreamPublisher, StreamSubscriber,
};
use vibro_msgs::{ServiceId, ServiceState, Stream, VibBlock, VibEstimate};
use vibro_service::{
    data_stream_config, estimate_stream_config, now_ns, HeartbeatPublisher, HeartbeatReport,
    LoopMode, Quantiles, Shutdown,
};

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

/// The heartbeat of the core's counters so far, with `latency` and in `state`.
fn heartbeat_report(core: &InProcess, latency: Quantiles, state: ServiceState) -> HeartbeatReport {
    let c = core.counters();
    HeartbeatReport {
        received: c.vib.received,
        published: c.estimates_published,
        lost: c.vib.lost_messages,
        stale: c.estimates_flagged,
        latency,
        state,
        input_samples_to_output: core.samples_to_next_estimate(),
        input_samples_per_output: core.samples_per_estimate(),
        out_of_order: c.vib.out_of_order,
        resyncs: c.vib.resyncs,
    }
}

fn hot_loop(config: Config, shutdown: Shutdown) -> anyhow::Result<Summary> {
    let started_ns = now_ns();
    // First, so that everything the loop sets up and runs is under the policy.
    vibro_service::realtime::enter(config.service.realtime_priority)?;
    if let Some(priority) = config.service.realtime_priority {
        tracing::info!(priority, "the hot loop runs under SCHED_FIFO");
    }
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

    let mut core = InProcess::new(&config.estimator)?;

    let heartbeat_ns = config.service.heartbeat_period.as_nanos() as u64;
    let summary_ns = config.service.summary_period.as_nanos() as u64;
    let mut next_heartbeat_ns = started_ns;
    let mut next_summary_ns = started_ns.saturating_add(summary_ns);
    let mut last_period = core.counters();
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
                if core.count_receive_error() {
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
                    if core.count_receive_error() {
                        warn!("{e}");
                    }
                    break;
                }
            };
            received_any = true;
            let recv_ns = now_ns();
            if let Err(e) = core.on_block(&sample, recv_ns, &mut estimates) {
                // Only an internal FFT failure (a bug) errors; stop with it.
                return Err(e).context("estimating a vibration window");
            }
        }
        if received_any {
            // Once per wake-up: every estimate the blocks completed is out.
            let report = heartbeat_report(&core, Quantiles::default(), ServiceState::Running);
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
            let c = core.counters();
            let period = core.latency_mut().period();
            // A seq or sample-index jump, an out-of-order block or a resync
            // (vibro_service::continuity) degrades like a loss.
            let lost_now = c.vib.lost_messages
                + c.vib.lost_samples
                + c.vib.malformed
                + c.vib.seq_jumps
                + c.vib.index_jumps;
            let lost_before = last_period.vib.lost_messages
                + last_period.vib.lost_samples
                + last_period.vib.malformed
                + last_period.vib.seq_jumps
                + last_period.vib.index_jumps;
            let disordered = c.vib.disorder() > last_period.vib.disorder();
            let state = if c.vib.received == 0 {
                ServiceState::Starting
            } else if lost_now > lost_before
                || disordered
                || c.estimates_flagged > last_period.estimates_flagged
                || c.rate_mismatches > last_period.rate_mismatches
            {
                ServiceState::Degraded
            } else {
                ServiceState::Running
            };
            let report = heartbeat_report(&core, period, state);
            if let Err(e) = heartbeat.publish(&report) {
                debug!("heartbeat: {e}");
            }
        }
        if now >= next_summary_ns {
            next_summary_ns = now.saturating_add(summary_ns);
            let dt_s = (now.saturating_sub(period_start_ns)) as f64 * 1e-9;
            let q = core.latency_mut().period();
            let c = core.counters();
            let dsp = core.dsp_counters();
            info!(
                "estimator: {:.1} blocks/s, {} estimates ({} flagged), lost {} blocks / {} samples, out of order {} blocks, resyncs {}, rate mismatches {}, latency p50 {:.1} us p99 {:.1} us, dsp gap samples {}, non-finite {}",
                (c.vib.received - last_period.vib.received) as f64 / dt_s.max(1e-9),
                c.estimates_published - last_period.estimates_published,
                c.estimates_flagged - last_period.estimates_flagged,
                // Saturating: a resync can take back a loss counted earlier.
                c.vib.lost_messages.saturating_sub(last_period.vib.lost_messages),
                c.vib.lost_samples.saturating_sub(last_period.vib.lost_samples),
                c.vib.out_of_order - last_period.vib.out_of_order,
                c.vib.resyncs - last_period.vib.resyncs,
                c.rate_mismatches - last_period.rate_mismatches,
                q.p50_ns as f64 * 1e-3,
                q.p99_ns as f64 * 1e-3,
                dsp.gap_samples,
                dsp.non_finite_samples,
            );
            core.tell_disorder();
            core.latency_mut().reset_period();
            last_period = core.counters();
            period_start_ns = now;
            let cleaned = cleanup_dead_nodes(&node);
            if cleaned > 0 {
                info!(cleaned, "removed the resources of dead iceoryx2 nodes");
            }
        }
    }

    let latency = core.latency_mut().period();
    let report = heartbeat_report(&core, latency, ServiceState::Stopping);
    if let Err(e) = heartbeat.publish(&report) {
        debug!("final heartbeat: {e}");
    }
    let summary = Summary {
        uptime_s: now_ns().saturating_sub(started_ns) as f64 * 1e-9,
        heartbeats: heartbeat.sent(),
        ..core.summary()
    };
    info!(
        received = summary.vib.received,
        lost_blocks = summary.vib.lost_messages,
        seq_jumps = summary.vib.seq_jumps,
        index_jumps = summary.vib.index_jumps,
        out_of_order = summary.vib.out_of_order,
        resyncs = summary.vib.resyncs,
        estimates = summary.estimates_published,
        p50_us = summary.latency.p50_ns as f64 * 1e-3,
        p99_us = summary.latency.p99_ns as f64 * 1e-3,
        "estimator stopped"
    );
    // The wait set, the ports and the node are released here, by Drop.
    Ok(summary)
}
