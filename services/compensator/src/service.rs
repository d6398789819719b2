//! The compensator's transport: `{prefix}accel` + `{prefix}estimate` →
//! [`Compensation`] → `{prefix}compensated`, with the wait set, the hot-reload
//! channel, heartbeats and the periodic summary. What happens to each message is the
//! core's (`crate::core`).

use crate::config::Config;
use crate::core::{Compensation, Summary};
use crate::reload::{self, ModelUpdate};
use anyhow::{anyhow, Context};
use iceoryx2::prelude::CallbackProgression;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::sync::Arc;
use tracing::{debug, info, warn};
use vibro_ipc::{
    cleanup_dead_nodes, create_node, create_waitset, StreamPublisher, StreamSubscriber,
};
use vibro_msgs::{
    AccelBlock, CompensatedBlock, ServiceId, ServiceState, Stream, VibBlock, VibEstimate,
};
use vibro_physics::compensation::TriadCompensator;
use vibro_service::{
    count_first, data_stream_config, estimate_stream_config, now_ns, ConfigSource,
    HeartbeatPublisher, HeartbeatReport, LoopMode, Quantiles, Shutdown,
};

/// Runs the compensator until `shutdown` is triggered, on a tokio runtime of its own
/// (for the hot-reload watcher); the hot loop runs on a dedicated thread. Do not call
/// it from inside a tokio runtime: use [`run_async`] there.
pub fn run(config: Config, shutdown: Shutdown) -> anyhow::Result<Summary> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .context("starting the compensator's tokio runtime")?;
    runtime.block_on(run_async(config, shutdown))
}

/// Runs the compensator until `shutdown` is triggered: the hot loop on its own thread,
/// the hot-reload watcher (when the configuration is a file and `reload_poll_s > 0`)
/// as a task on the current runtime.
pub async fn run_async(config: Config, shutdown: Shutdown) -> anyhow::Result<Summary> {
    // Built here so the hot thread starts with its tables allocated.
    let compensator = config.model.compensator();
    let (update_tx, update_rx) = std::sync::mpsc::channel();
    let reload_errors = Arc::new(AtomicU64::new(0));
    let watcher = match (&config.source, config.reload_poll) {
        (ConfigSource::File(path), Some(poll)) => Some(tokio::spawn(reload::watch(
            path.clone(),
            config.clone(),
            poll,
            update_tx,
            Arc::clone(&reload_errors),
            shutdown.clone(),
        ))),
        _ => None,
    };
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::Builder::new()
        .name("vibro-compensator".into())
        .spawn(move || {
            let _ = tx.send(hot_loop(config, compensator, update_rx, shutdown));
        })
        .context("spawning the compensator's hot-loop thread")?;
    let result = rx
        .await
        .map_err(|_| anyhow!("the compensator's hot loop ended without a result (it panicked)"));
    if let Some(w) = watcher {
        w.abort();
    }
    let mut summary = result??;
    summary.reload_errors = reload_errors.load(Ordering::Relaxed);
    Ok(summary)
}

/// What the transport reports of the core.
impl Compensation {
    /// The heartbeat of the counters so far, in `state`, with the period's latency.
    fn heartbeat_report(&self, state: ServiceState) -> HeartbeatReport {
        self.counters_report(self.latency.period(), state)
    }

    /// The heartbeat of the counters so far, with `latency`, in `state`.
    fn counters_report(&self, latency: Quantiles, state: ServiceState) -> HeartbeatReport {
        HeartbeatReport {
            received: self.s.accel.received,
            published: self.s.published,
            // A dropped malformed block shows as a missing seq: counted once.
            lost: self.s.accel.lost_messages,
            // A block the estimate stage answered for want of samples is one made with
            // a missing input, like a stale estimate's.
            stale: self.s.stale_blocks
                + self.s.missing_blocks
                + self.s.ahead_blocks
                + self.s.fallback_blocks,
            latency,
            state,
            // The readings the waveform stage holds for their vibration samples (0
            // when none): a lock-stepped replay waits for them at its end.
            input_samples_to_output: self.held_readings(),
            input_samples_per_output: 0,
            out_of_order: self.s.accel.out_of_order + self.s.estimates.out_of_order,
            resyncs: self.s.accel.resyncs + self.s.estimates.resyncs,
        }
    }
}

/// Takes every pending estimate (the newest wins); returns whether there was one.
/// On an empty stream this is one shared-memory poll, no system call.
fn drain_estimates(estimates: &StreamSubscriber<VibEstimate>, st: &mut Compensation) -> bool {
    let mut any = false;
    loop {
        match estimates.receive() {
            Ok(Some(e)) => {
                any = true;
                st.on_estimate(&e);
            }
            Ok(None) => return any,
            Err(e) => {
                if count_first(&mut st.s.receive_errors) {
                    warn!("{e}");
                }
                return any;
            }
        }
    }
}

/// Takes every pending vibration-sensor block (the waveform stage's samples); on an
/// empty stream one shared-memory poll.
fn drain_vib(
    vib: Option<&StreamSubscriber<VibBlock>>,
    st: &mut Compensation,
    out: &mut StreamPublisher<CompensatedBlock>,
) -> bool {
    let Some(vib) = vib else {
        return false;
    };
    let mut any = false;
    loop {
        match vib.receive() {
            Ok(Some(b)) => {
                any = true;
                st.on_vib(&b, now_ns(), out);
            }
            Ok(None) => return any,
            Err(e) => {
                if count_first(&mut st.s.receive_errors) {
                    warn!("{e}");
                }
                return any;
            }
        }
    }
}

fn hot_loop(
    config: Config,
    compensator: TriadCompensator,
    updates: Receiver<Box<ModelUpdate>>,
    shutdown: Shutdown,
) -> anyhow::Result<Summary> {
    let started_ns = now_ns();
    // First, so that everything the loop sets up and runs is under the policy.
    vibro_service::realtime::enter(config.service.realtime_priority)?;
    if let Some(priority) = config.service.realtime_priority {
        tracing::info!(priority, "the hot loop runs under SCHED_FIFO");
    }
    let names = &config.names;
    let node =
        create_node("vibro-compensator").context("creating the compensator's iceoryx2 node")?;
    let cleaned = cleanup_dead_nodes(&node);
    if cleaned > 0 {
        info!(cleaned, "removed the resources of dead iceoryx2 nodes");
    }
    let accel = StreamSubscriber::<AccelBlock>::create(
        &node,
        &names.accel(),
        &names.event(Stream::Accel),
        &data_stream_config(),
    )
    .with_context(|| format!("subscribing to {}", names.accel()))?;
    let estimates = StreamSubscriber::<VibEstimate>::create(
        &node,
        &names.estimate(),
        &names.event(Stream::Estimate),
        &estimate_stream_config(),
    )
    .with_context(|| format!("subscribing to {}", names.estimate()))?;
    // The waveform stage's samples (`stage = "waveform"`).
    let vib = match config.model.waveform.stage {
        crate::config::Stage::Waveform => Some(
            StreamSubscriber::<VibBlock>::create(
                &node,
                &names.vib(),
                &names.event(Stream::Vib),
                &data_stream_config(),
            )
            .with_context(|| format!("subscribing to {}", names.vib()))?,
        ),
        crate::config::Stage::Estimate => None,
    };
    let mut compensated = StreamPublisher::<CompensatedBlock>::create(
        &node,
        &names.compensated(),
        &names.event(Stream::Compensated),
        &data_stream_config(),
    )
    .with_context(|| format!("publishing on {}", names.compensated()))?;
    let mut heartbeat = HeartbeatPublisher::create(&node, names, ServiceId::Compensator)?;
    let mut progress = HeartbeatPublisher::progress(&node, names, ServiceId::Compensator)?;

    let waitset = create_waitset().context("creating the compensator's wait set")?;
    let _accel_guard = waitset
        .attach_notification(accel.listener())
        .with_context(|| format!("attaching {} to the wait set", names.event(Stream::Accel)))?;
    let _estimate_guard = waitset
        .attach_notification(estimates.listener())
        .with_context(|| {
            format!(
                "attaching {} to the wait set",
                names.event(Stream::Estimate)
            )
        })?;
    let _vib_guard =
        match &vib {
            Some(v) => Some(waitset.attach_notification(v.listener()).with_context(|| {
                format!("attaching {} to the wait set", names.event(Stream::Vib))
            })?),
            None => None,
        };
    let _poll_guard = waitset
        .attach_interval(config.service.shutdown_poll)
        .context("attaching the shutdown-poll interval to the wait set")?;
    let _heartbeat_guard = waitset
        .attach_interval(config.service.heartbeat_period)
        .context("attaching the heartbeat interval to the wait set")?;

    let mut st = Compensation::new(config.model.clone(), compensator)?;

    let heartbeat_ns = config.service.heartbeat_period.as_nanos() as u64;
    let summary_ns = config.service.summary_period.as_nanos() as u64;
    let mut next_heartbeat_ns = started_ns;
    let mut next_summary_ns = started_ns.saturating_add(summary_ns);
    let mut last = st.s.clone();
    let mut period_start_ns = started_ns;
    let mut updates_open = true;

    info!(
        accel = %names.accel(),
        estimate = %names.estimate(),
        compensated = %names.compensated(),
        mode = config.model.mode.name(),
        triad = %config.model.triad.id,
        passports = ?config.model.triad.passports.map(|p| p.id().to_string()),
        loop_mode = %config.service.loop_mode,
        source = %config.source,
        stage = config.model.waveform.stage.name(),
        sensitivity_v_per_g = ?config.model.waveform.chain.sensitivity_v_per_g,
        ac_corner_hz = config.model.waveform.chain.ac_corner_hz,
        delay_s = config.model.waveform.chain.delay_s,
        max_wait_ms = ?config.model.waveform.max_wait_ns.map(|ns| ns as f64 * 1e-6),
        model = ?config.model.effects.as_ref().map(|(p, _)| p.display().to_string()),
        "compensator running"
    );

    let spin = config.service.loop_mode == LoopMode::Spin;
    while !shutdown.is_triggered() {
        if !spin {
            waitset
                .wait_and_process_once_with_timeout(
                    |_| CallbackProgression::Continue,
                    config.service.shutdown_poll,
                )
                .context("waiting on the compensator's wait set")?;
            if let Some(v) = &vib {
                if let Err(e) = v.clear_events() {
                    if count_first(&mut st.s.receive_errors) {
                        warn!("{e}");
                    }
                }
            }
            for result in [accel.clear_events(), estimates.clear_events()] {
                if let Err(e) = result {
                    if count_first(&mut st.s.receive_errors) {
                        warn!("{e}");
                    }
                }
            }
        }
        // Reloaded models: looked at once per wake-up, the newest wins.
        while updates_open {
            match updates.try_recv() {
                Ok(update) => st.take_update(*update),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => updates_open = false,
            }
        }
        let mut received_any = drain_estimates(&estimates, &mut st);
        // Samples first: a sensor block published before an accelerometer block is
        // taken before it, so that the held blocks are decided in publish order.
        received_any |= drain_vib(vib.as_ref(), &mut st, &mut compensated);
        if received_any {
            // The tables of the estimate the next block will want, built now rather
            // than on that block's latency.
            st.prepare();
        }
        loop {
            match accel.receive() {
                Ok(Some(block)) => {
                    received_any = true;
                    let recv_ns = now_ns();
                    // An estimate published before this block is visible now: take it,
                    // so each block uses the latest estimate sent before it.
                    drain_estimates(&estimates, &mut st);
                    drain_vib(vib.as_ref(), &mut st, &mut compensated);
                    st.on_accel(&block, recv_ns, &mut compensated);
                }
                Ok(None) => break,
                Err(e) => {
                    if count_first(&mut st.s.receive_errors) {
                        warn!("{e}");
                    }
                    break;
                }
            }
        }
        // Held blocks whose wait is over by the wall clock (crate::waveform); a
        // release tells the progress stream too, as input would.
        let before = st.s.published;
        st.release(now_ns(), &mut compensated);
        if received_any || st.s.published != before {
            // Once per wake-up: every block taken so far is compensated and published.
            // No latency: quantiles per wake-up would cost the hot loop for nothing.
            let report = st.counters_report(Quantiles::default(), ServiceState::Running);
            if let Err(e) = progress.publish(&report) {
                debug!("progress: {e}");
            }
        }
        if spin {
            if received_any {
                // Keep the event buffers from filling while nobody waits on them.
                let _ = accel.clear_events();
                let _ = estimates.clear_events();
                if let Some(v) = &vib {
                    let _ = v.clear_events();
                }
            } else {
                std::hint::spin_loop();
            }
        }

        let now = now_ns();
        if now >= next_heartbeat_ns {
            next_heartbeat_ns = now.saturating_add(heartbeat_ns);
            let s = &st.s;
            // A seq or sample-index jump, an out-of-order message or a resync
            // (vibro_service::continuity) degrades like a loss.
            let degraded = s.accel.lost_messages + s.accel.lost_samples + s.accel.malformed
                > last.accel.lost_messages + last.accel.lost_samples + last.accel.malformed
                || s.accel.seq_jumps + s.accel.index_jumps
                    > last.accel.seq_jumps + last.accel.index_jumps
                || s.accel.disorder() + s.estimates.disorder()
                    > last.accel.disorder() + last.estimates.disorder()
                || s.stale_blocks + s.missing_blocks + s.ahead_blocks + s.fallback_blocks
                    > last.stale_blocks
                        + last.missing_blocks
                        + last.ahead_blocks
                        + last.fallback_blocks
                || s.time_jump_blocks > last.time_jump_blocks
                || s.undelivered > last.undelivered;
            let state = if s.accel.received == 0 {
                ServiceState::Starting
            } else if degraded {
                ServiceState::Degraded
            } else {
                ServiceState::Running
            };
            if let Err(e) = heartbeat.publish(&st.heartbeat_report(state)) {
                debug!("heartbeat: {e}");
            }
        }
        if now >= next_summary_ns {
            next_summary_ns = now.saturating_add(summary_ns);
            let dt_s = (now.saturating_sub(period_start_ns) as f64 * 1e-9).max(1e-9);
            let q = st.latency.period();
            let s = &st.s;
            info!(
                "compensator ({}, {} stage): {:.1} blocks/s, waveform {} fallback {} blocks ({} held), {} estimates ({} rejected), lost {} blocks / {} samples, out of order {} blocks / {} estimates, resyncs {} / {}, stale {} missing {} ahead {} blocks, rate changes {}, time jumps {}, saturated {}, undelivered {}, latency p50 {:.1} us p99 {:.1} us",
                s.mode,
                s.stage,
                (s.accel.received - last.accel.received) as f64 / dt_s,
                s.waveform_blocks - last.waveform_blocks,
                s.fallback_blocks - last.fallback_blocks,
                st.waveform.as_ref().map_or(0, |w| w.held()),
                s.estimates.received - last.estimates.received,
                s.estimates_rejected - last.estimates_rejected,
                // Saturating: a resync can take back a loss counted earlier.
                s.accel.lost_messages.saturating_sub(last.accel.lost_messages),
                s.accel.lost_samples.saturating_sub(last.accel.lost_samples),
                s.accel.out_of_order - last.accel.out_of_order,
                s.estimates.out_of_order - last.estimates.out_of_order,
                s.accel.resyncs - last.accel.resyncs,
                s.estimates.resyncs - last.estimates.resyncs,
                s.stale_blocks - last.stale_blocks,
                s.missing_blocks - last.missing_blocks,
                s.ahead_blocks - last.ahead_blocks,
                s.rate_change_blocks - last.rate_change_blocks,
                s.time_jump_blocks - last.time_jump_blocks,
                s.saturated_blocks - last.saturated_blocks,
                s.undelivered - last.undelivered,
                q.p50_ns as f64 * 1e-3,
                q.p99_ns as f64 * 1e-3,
            );
            // What the hot loop did not tell at once (vibro_service::DisorderLog).
            st.accel_disorder.period("accelerometer", &st.s.accel);
            st.estimate_disorder
                .period("vibration estimate", &st.s.estimates);
            st.latency.reset_period();
            last = st.s.clone();
            period_start_ns = now;
            let cleaned = cleanup_dead_nodes(&node);
            if cleaned > 0 {
                info!(cleaned, "removed the resources of dead iceoryx2 nodes");
            }
        }
    }

    if let Err(e) = heartbeat.publish(&st.heartbeat_report(ServiceState::Stopping)) {
        debug!("final heartbeat: {e}");
    }
    // Blocks still held go out with what the samples give them (nothing is lost).
    st.finish(&mut compensated);
    let mut summary = st.summary();
    summary.uptime_s = now_ns().saturating_sub(started_ns) as f64 * 1e-9;
    summary.heartbeats = heartbeat.sent();
    summary.latency = st.latency.total();
    info!(
        received = summary.accel.received,
        published = summary.published,
        lost_blocks = summary.accel.lost_messages,
        seq_jumps = summary.accel.seq_jumps,
        index_jumps = summary.accel.index_jumps,
        out_of_order = summary.accel.out_of_order,
        resyncs = summary.accel.resyncs,
        estimates_out_of_order = summary.estimates.out_of_order,
        estimate_resyncs = summary.estimates.resyncs,
        stale_blocks = summary.stale_blocks,
        missing_blocks = summary.missing_blocks,
        p50_us = summary.latency.p50_ns as f64 * 1e-3,
        p99_us = summary.latency.p99_ns as f64 * 1e-3,
        stage = summary.stage,
        waveform_blocks = summary.waveform_blocks,
        fallback_blocks = summary.fallback_blocks,
        waveform = %summary.waveform.as_ref().map(|w| w.to_json().finish()).unwrap_or_default(),
        "compensator stopped"
    );
    // The wait set, the ports and the node are released here, by Drop.
    Ok(summary)
}
