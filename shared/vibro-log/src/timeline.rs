//! The recording's data timeline and its jump rule: where a message with a data time
//! goes in a log (`record`, and `vibrocomp log compensate`'s session).

/// The most a message's data time may differ from the recording's timeline and still
/// be on it: a minute, far beyond any stream's own latency (an estimate's window end
/// lags its blocks by about a window) and any gap a subscriber's buffer hides, far below
/// a corrupt or forged `t0_ns` (`u64::MAX` is 584 years away).
pub const MAX_TIMELINE_STEP_NS: u64 = 60_000_000_000;

/// How many messages in a row, off the timeline and consistent among themselves, move
/// the timeline to them ([`Timeline`]).
pub const TIMELINE_RESYNC_AFTER: u32 = 8;

/// Where a message with a data time goes on the recording's timeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Placement {
    /// On the timeline: written at its own data time.
    On(u64),
    /// Off the timeline: written at the timeline's time (the argument), counted, and
    /// kept out of what is derived from time (the view channels).
    Off(u64),
    /// The messages off the timeline agreed long enough: the timeline moved to this
    /// one, written at its own time.
    Resync(u64),
}

/// The jump rule of the data timeline. A block's `t0_ns` comes from outside the
/// process: one corrupt or forged value (`u64::MAX`) must not stamp every later
/// heartbeat and log line 584 years ahead, nor stretch the log's time range.
///
/// - The first data time starts the timeline.
/// - A data time within [`MAX_TIMELINE_STEP_NS`] of the timeline is on it; the timeline
///   follows the latest such time.
/// - Any other is off it: written at the timeline's time and counted. The timeline
///   moves to a new place only when [`TIMELINE_RESYNC_AFTER`] messages in a row are off
///   it and within the step of each other (a producer that really restarted on another
///   clock, a replay of another log); any message on the old timeline in between shows
///   it alive and clears them. The few messages before a real move keep their own time
///   in the message, only their log time is the old timeline's.
#[derive(Debug, Clone, Default)]
pub struct Timeline {
    now_ns: Option<u64>,
    /// The run of messages off the timeline: (latest data time, count).
    candidate: Option<(u64, u32)>,
    /// Times the timeline moved.
    pub resyncs: u64,
}

impl Timeline {
    /// The timeline's time, once a data time started it.
    pub fn now_ns(&self) -> Option<u64> {
        self.now_ns
    }

    /// Places a message whose data time is `t_ns`.
    pub fn place(&mut self, t_ns: u64) -> Placement {
        let Some(now) = self.now_ns else {
            self.now_ns = Some(t_ns);
            return Placement::On(t_ns);
        };
        if t_ns.abs_diff(now) <= MAX_TIMELINE_STEP_NS {
            self.candidate = None;
            self.now_ns = Some(now.max(t_ns));
            return Placement::On(t_ns);
        }
        let run = match self.candidate {
            Some((last, n)) if t_ns.abs_diff(last) <= MAX_TIMELINE_STEP_NS => {
                (last.max(t_ns), n + 1)
            }
            _ => (t_ns, 1),
        };
        if run.1 >= TIMELINE_RESYNC_AFTER {
            self.candidate = None;
            self.now_ns = Some(run.0);
            self.resyncs += 1;
            Placement::Resync(t_ns)
        } else {
            self.candidate = Some(run);
            Placement::Off(now)
        }
    }
}
