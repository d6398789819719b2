//! Topics of a log: the stream names below the prefix.

use vibro_msgs::{ServiceId, Stream};

/// The topic of `stream` in a log: `/` + its name below the prefix (`/accel`,
/// `/heartbeat/estimator`).
pub fn topic(stream: Stream) -> String {
    format!("/{}", stream.suffix())
}

/// The stream whose topic is `topic`, if any.
pub fn stream_of_topic(topic_name: &str) -> Option<Stream> {
    Stream::all().into_iter().find(|&s| topic(s) == topic_name)
}

/// The streams a rig (or the simulator) produces, which a replay publishes.
pub fn rig_streams() -> [Stream; 3] {
    [Stream::Vib, Stream::Accel, Stream::Truth]
}

/// What `vibrocomp record` records unless told otherwise: every data stream, the
/// services' heartbeats (not their per-wake-up progress messages) and their log lines.
pub const DEFAULT_RECORD_STREAMS: [Stream; 9] = [
    Stream::Vib,
    Stream::Accel,
    Stream::Truth,
    Stream::Estimate,
    Stream::Compensated,
    Stream::Heartbeat(ServiceId::Estimator),
    Stream::Heartbeat(ServiceId::Compensator),
    Stream::Log(ServiceId::Estimator),
    Stream::Log(ServiceId::Compensator),
];

#[cfg(feature = "ipc")]
/// Every known topic, for error messages.
pub(crate) fn known_topics() -> String {
    Stream::all()
        .into_iter()
        .map(topic)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_stream_round_trips_through_its_topic() {
        for s in Stream::all() {
            assert_eq!(stream_of_topic(&topic(s)), Some(s));
        }
        assert_eq!(topic(Stream::Accel), "/accel");
        assert_eq!(
            topic(Stream::Heartbeat(ServiceId::Estimator)),
            "/heartbeat/estimator"
        );
        assert_eq!(stream_of_topic("/nope"), None);
        assert_eq!(stream_of_topic("accel"), None);
    }
}
