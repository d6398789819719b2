//! Service names: every stream lives under one configurable prefix, so that tests (and
//! two systems on one machine) never meet.

use crate::{Error, Result, ServiceId};

/// The prefix used when the configuration does not name one.
pub const DEFAULT_PREFIX: &str = "vibrocomp/";

/// Longest service name iceoryx2 accepts (`iceoryx2::constants::MAX_SERVICE_NAME_LENGTH`
/// in 0.10.0; a test checks it against `ServiceName::max_len()`).
pub const MAX_SERVICE_NAME_LEN: usize = 255;

/// Suffix of the event service that sits beside each publish-subscribe stream: a
/// publisher notifies it after publishing, so a subscriber can sleep in a `WaitSet`.
pub const EVENT_SUFFIX: &str = "/event";

/// A publish-subscribe stream of the system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Stream {
    /// [`crate::AccelBlock`]s: `{prefix}accel`.
    Accel,
    /// [`crate::VibBlock`]s: `{prefix}vib`.
    Vib,
    /// [`crate::VibEstimate`]s: `{prefix}estimate`.
    Estimate,
    /// [`crate::CompensatedBlock`]s: `{prefix}compensated`.
    Compensated,
    /// [`crate::TruthBlock`]s: `{prefix}truth`.
    Truth,
    /// [`crate::Heartbeat`]s of one service: `{prefix}heartbeat/{service}`.
    Heartbeat(ServiceId),
    /// [`crate::Heartbeat`]s a service publishes after each wake-up that took input:
    /// `{prefix}progress/{service}`. `received` then counts every input message the
    /// service has consumed and acted on, so a lock-stepped replay knows when the
    /// outputs of what it sent are out (`vibrocomp replay --as-fast-as-possible`).
    Progress(ServiceId),
    /// [`crate::LogLine`]s of one service: `{prefix}log/{service}`.
    Log(ServiceId),
}

impl Stream {
    /// Every stream, heartbeats of every service included.
    pub fn all() -> Vec<Stream> {
        let mut all = vec![
            Stream::Accel,
            Stream::Vib,
            Stream::Estimate,
            Stream::Compensated,
            Stream::Truth,
        ];
        all.extend(ServiceId::ALL.iter().map(|&s| Stream::Heartbeat(s)));
        all.extend(ServiceId::ALL.iter().map(|&s| Stream::Progress(s)));
        all.extend(ServiceId::ALL.iter().map(|&s| Stream::Log(s)));
        all
    }

    /// The wire type the stream carries.
    pub const fn kind(self) -> crate::MessageKind {
        use crate::MessageKind as K;
        match self {
            Stream::Accel => K::AccelBlock,
            Stream::Vib => K::VibBlock,
            Stream::Estimate => K::VibEstimate,
            Stream::Compensated => K::CompensatedBlock,
            Stream::Truth => K::TruthBlock,
            Stream::Heartbeat(_) | Stream::Progress(_) => K::Heartbeat,
            Stream::Log(_) => K::LogLine,
        }
    }

    /// The name below the prefix, e.g. `accel` or `heartbeat/estimator`.
    pub fn suffix(self) -> String {
        match self {
            Stream::Accel => "accel".to_string(),
            Stream::Vib => "vib".to_string(),
            Stream::Estimate => "estimate".to_string(),
            Stream::Compensated => "compensated".to_string(),
            Stream::Truth => "truth".to_string(),
            Stream::Heartbeat(service) => format!("heartbeat/{service}"),
            Stream::Progress(service) => format!("progress/{service}"),
            Stream::Log(service) => format!("log/{service}"),
        }
    }
}

/// The longest name any stream or event service adds after the prefix.
pub fn max_suffix_len() -> usize {
    Stream::all()
        .into_iter()
        .map(|s| s.suffix().len() + EVENT_SUFFIX.len())
        .max()
        .unwrap_or(0)
}

/// The service names of one system, all under one validated prefix.
///
/// ```
/// use vibro_msgs::{ServiceId, ServiceNames, Stream};
/// let names = ServiceNames::new("rig-a/")?;
/// assert_eq!(names.stream(Stream::Accel), "rig-a/accel");
/// assert_eq!(names.event(Stream::Accel), "rig-a/accel/event");
/// assert_eq!(names.stream(Stream::Heartbeat(ServiceId::Estimator)), "rig-a/heartbeat/estimator");
/// assert!(ServiceNames::new("rig a").is_err());
/// # Ok::<(), vibro_msgs::Error>(())
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServiceNames {
    prefix: String,
}

impl Default for ServiceNames {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.to_string(),
        }
    }
}

impl ServiceNames {
    /// Validates `prefix`: not empty; ends with `/`; does not start with `/`; only ASCII
    /// letters, digits and `_ - . /`; no empty segment (`//`); short enough that the
    /// longest name below it fits iceoryx2's limit of [`MAX_SERVICE_NAME_LEN`] bytes.
    pub fn new(prefix: &str) -> Result<Self> {
        let fail = |rule: String| {
            Err(Error::InvalidPrefix {
                prefix: prefix.to_string(),
                rule,
            })
        };
        if prefix.is_empty() {
            return fail("must not be empty".to_string());
        }
        if let Some(bad) = prefix
            .chars()
            .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/')))
        {
            return fail(format!(
                "character {bad:?} not allowed (use ASCII letters, digits, '_', '-', '.', '/')"
            ));
        }
        if !prefix.ends_with('/') {
            return fail("must end with '/'".to_string());
        }
        if prefix.starts_with('/') {
            return fail("must not start with '/'".to_string());
        }
        if prefix.contains("//") {
            return fail("must not contain an empty segment '//'".to_string());
        }
        let max_prefix_len = MAX_SERVICE_NAME_LEN - max_suffix_len();
        if prefix.len() > max_prefix_len {
            return fail(format!(
                "{} bytes long, at most {max_prefix_len} allowed so that every service name \
                 fits iceoryx2's {MAX_SERVICE_NAME_LEN}-byte limit",
                prefix.len()
            ));
        }
        Ok(Self {
            prefix: prefix.to_string(),
        })
    }

    /// The validated prefix, ending with `/`.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The publish-subscribe service name of `stream`.
    pub fn stream(&self, stream: Stream) -> String {
        format!("{}{}", self.prefix, stream.suffix())
    }

    /// The event service beside `stream`: `{stream name}/event`.
    pub fn event(&self, stream: Stream) -> String {
        format!("{}{}{EVENT_SUFFIX}", self.prefix, stream.suffix())
    }

    /// `{prefix}accel`.
    pub fn accel(&self) -> String {
        self.stream(Stream::Accel)
    }

    /// `{prefix}vib`.
    pub fn vib(&self) -> String {
        self.stream(Stream::Vib)
    }

    /// `{prefix}estimate`.
    pub fn estimate(&self) -> String {
        self.stream(Stream::Estimate)
    }

    /// `{prefix}compensated`.
    pub fn compensated(&self) -> String {
        self.stream(Stream::Compensated)
    }

    /// `{prefix}truth`.
    pub fn truth(&self) -> String {
        self.stream(Stream::Truth)
    }

    /// `{prefix}heartbeat/{service}`.
    pub fn heartbeat(&self, service: ServiceId) -> String {
        self.stream(Stream::Heartbeat(service))
    }

    /// `{prefix}progress/{service}`.
    pub fn progress(&self, service: ServiceId) -> String {
        self.stream(Stream::Progress(service))
    }

    /// The iceoryx2 name of `stream`'s publish-subscribe service.
    #[cfg(feature = "ipc")]
    pub fn service_name(&self, stream: Stream) -> Result<iceoryx2::prelude::ServiceName> {
        to_service_name(&self.stream(stream))
    }

    /// The iceoryx2 name of the event service beside `stream`.
    #[cfg(feature = "ipc")]
    pub fn event_service_name(&self, stream: Stream) -> Result<iceoryx2::prelude::ServiceName> {
        to_service_name(&self.event(stream))
    }
}

#[cfg(feature = "ipc")]
fn to_service_name(name: &str) -> Result<iceoryx2::prelude::ServiceName> {
    iceoryx2::prelude::ServiceName::new(name).map_err(|e| Error::ServiceName {
        name: name.to_string(),
        reason: format!("{e:?}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rule_of(prefix: &str) -> String {
        match ServiceNames::new(prefix) {
            Err(Error::InvalidPrefix { prefix: p, rule }) => {
                assert_eq!(p, prefix, "the error names the value");
                rule
            }
            other => panic!("{prefix:?} accepted: {other:?}"),
        }
    }

    #[test]
    fn names_sit_under_the_prefix() {
        let n = ServiceNames::default();
        assert_eq!(n.prefix(), "vibrocomp/");
        assert_eq!(n.accel(), "vibrocomp/accel");
        assert_eq!(n.vib(), "vibrocomp/vib");
        assert_eq!(n.estimate(), "vibrocomp/estimate");
        assert_eq!(n.compensated(), "vibrocomp/compensated");
        assert_eq!(n.truth(), "vibrocomp/truth");
        assert_eq!(
            n.heartbeat(ServiceId::Compensator),
            "vibrocomp/heartbeat/compensator"
        );
        assert_eq!(n.event(Stream::Vib), "vibrocomp/vib/event");
        assert_eq!(
            n.event(Stream::Heartbeat(ServiceId::Sim)),
            "vibrocomp/heartbeat/sim/event"
        );
        assert_eq!(
            n.service_name(Stream::Truth).unwrap().as_str(),
            "vibrocomp/truth"
        );
        assert_eq!(
            ServiceNames::new("a/b-c_d.e/").unwrap().accel(),
            "a/b-c_d.e/accel"
        );
    }

    #[test]
    fn every_stream_name_is_distinct() {
        let n = ServiceNames::default();
        let mut names: Vec<String> = Stream::all()
            .into_iter()
            .flat_map(|s| [n.stream(s), n.event(s)])
            .collect();
        let total = names.len();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), total);
        // Five data streams, a heartbeat, a progress and a log stream per service.
        assert_eq!(total, 2 * (5 + 3 * ServiceId::ALL.len()));
    }

    #[test]
    fn invalid_prefixes_are_rejected_with_their_rule() {
        assert_eq!(rule_of(""), "must not be empty");
        assert_eq!(rule_of("vibrocomp"), "must end with '/'");
        assert_eq!(rule_of("/vibrocomp/"), "must not start with '/'");
        assert_eq!(rule_of("a//b/"), "must not contain an empty segment '//'");
        assert!(rule_of("rig a/").starts_with("character ' ' not allowed"));
        assert!(rule_of("iox2://x/").starts_with("character ':' not allowed"));
        assert!(rule_of("ré/").starts_with("character 'é' not allowed"));
    }

    #[test]
    fn the_longest_prefix_fits_and_one_more_byte_does_not() {
        let longest = MAX_SERVICE_NAME_LEN - max_suffix_len();
        // "heartbeat/compensator/event" is the longest suffix.
        assert_eq!(max_suffix_len(), "heartbeat/compensator/event".len());
        let ok = format!("{}/", "p".repeat(longest - 1));
        let names = ServiceNames::new(&ok).unwrap();
        for s in Stream::all() {
            assert!(names.event(s).len() <= MAX_SERVICE_NAME_LEN);
            names.event_service_name(s).unwrap();
            names.service_name(s).unwrap();
        }
        let too_long = format!("{}/", "p".repeat(longest));
        let rule = rule_of(&too_long);
        assert!(
            rule.contains(&format!("{} bytes long", longest + 1)),
            "{rule}"
        );
        assert!(rule.contains(&format!("at most {longest}")), "{rule}");
    }

    #[test]
    fn the_name_limit_is_iceoryx2s() {
        assert_eq!(
            MAX_SERVICE_NAME_LEN,
            iceoryx2::prelude::ServiceName::max_len()
        );
    }

    #[test]
    fn the_error_message_names_value_and_rule() {
        let e = ServiceNames::new("vibrocomp").unwrap_err();
        assert_eq!(
            e.to_string(),
            "service-name prefix \"vibrocomp\": must end with '/'"
        );
    }
}
