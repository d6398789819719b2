//! The periodic [`Heartbeat`] every service publishes on `{prefix}heartbeat/{service}`.

#[cfg(feature = "ipc")]
use crate::now_ns;
use crate::Quantiles;
#[cfg(feature = "ipc")]
use anyhow::Context;
#[cfg(feature = "ipc")]
use vibro_ipc::{IpcNode, StreamPublisher};
use vibro_msgs::ServiceState;
#[cfg(feature = "ipc")]
use vibro_msgs::{Heartbeat, ServiceId, ServiceNames, Stream};

/// What a service reports in one heartbeat (cumulative counters).
#[derive(Debug, Clone, Copy)]
pub struct HeartbeatReport {
    pub received: u64,
    pub published: u64,
    pub lost: u64,
    pub stale: u64,
    /// Latency over the last period.
    pub latency: Quantiles,
    pub state: ServiceState,
    /// Contiguous input samples still needed before the next output; 0: not reported
    /// (`Heartbeat::input_samples_to_output`).
    pub input_samples_to_output: u64,
    /// Input samples between outputs after the next; 0: not reported.
    pub input_samples_per_output: u64,
    /// Input messages dropped as out of order, over all inputs
    /// (`Heartbeat::out_of_order`).
    pub out_of_order: u64,
    /// Input streams taken up again after a run of out-of-order messages, over all
    /// inputs (`Heartbeat::resyncs`; `crate::continuity`).
    pub resyncs: u64,
}

#[cfg(feature = "ipc")]
/// Publishes one service's heartbeats.
pub struct HeartbeatPublisher {
    publisher: StreamPublisher<Heartbeat>,
    service: ServiceId,
    started_ns: u64,
    seq: u64,
}

#[cfg(feature = "ipc")]
impl HeartbeatPublisher {
    pub fn create(
        node: &IpcNode,
        names: &ServiceNames,
        service: ServiceId,
    ) -> anyhow::Result<Self> {
        Self::open(node, names, service, Stream::Heartbeat(service))
    }

    /// The publisher of the service's progress messages (`{prefix}progress/{service}`):
    /// a heartbeat after each wake-up that took input, for lock-stepped replays.
    pub fn progress(
        node: &IpcNode,
        names: &ServiceNames,
        service: ServiceId,
    ) -> anyhow::Result<Self> {
        Self::open(node, names, service, Stream::Progress(service))
    }

    fn open(
        node: &IpcNode,
        names: &ServiceNames,
        service: ServiceId,
        stream: Stream,
    ) -> anyhow::Result<Self> {
        let publisher = StreamPublisher::create(
            node,
            &names.stream(stream),
            &names.event(stream),
            &crate::data_stream_config(),
        )
        .with_context(|| format!("publishing on {}", names.stream(stream)))?;
        Ok(Self {
            publisher,
            service,
            started_ns: now_ns(),
            seq: 0,
        })
    }

    /// Heartbeats published so far.
    pub fn sent(&self) -> u64 {
        self.seq
    }

    /// Publishes one heartbeat. Nobody listening is fine; a full subscriber is counted
    /// by the transport and reported as an error here.
    pub fn publish(&mut self, report: &HeartbeatReport) -> vibro_ipc::Result<usize> {
        let now = now_ns();
        let hb = Heartbeat {
            seq: self.seq,
            publish_ns: now,
            uptime_ns: now.saturating_sub(self.started_ns),
            received: report.received,
            published: report.published,
            lost: report.lost,
            stale: report.stale,
            latency_p50_ns: report.latency.p50_ns,
            latency_p99_ns: report.latency.p99_ns,
            input_samples_to_output: report.input_samples_to_output,
            input_samples_per_output: report.input_samples_per_output,
            out_of_order: report.out_of_order,
            resyncs: report.resyncs,
            service: self.service.code(),
            state: report.state.code(),
            ..Heartbeat::ZEROED
        };
        self.seq += 1;
        self.publisher.publish(&hb)
    }
}
