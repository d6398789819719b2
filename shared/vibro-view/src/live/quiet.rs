//! Log lines about clients, bounded. Every client can make the Foxglove SDK log: each
//! undecodable message, each unknown channel id of a subscription, each failed send is
//! a line of its own, so one hostile client wrote thousands (issue 31). The SDK and
//! the guard run on threads of their own, whose default `tracing` dispatcher is a
//! [`LogLimiter`]: it passes at most `burst` events per call site (one `tracing!` or
//! `log!` line of the source) per period to the process's own subscriber, counts the
//! rest, and at the end of each period writes one summary line per call site that
//! had lines left out, with the count and the last of them.

use std::cell::RefCell;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;
use tracing::dispatcher::{DefaultGuard, Dispatch};
use tracing::level_filters::LevelFilter;
use tracing::span;
use tracing::subscriber::{Interest, Subscriber};
use tracing::{Event, Level, Metadata};

/// Characters kept of a left-out line, for its summary.
const KEPT_CHARS: usize = 300;

/// A rate limit on log lines, per call site, in front of the dispatcher that was the
/// default when it was made.
#[derive(Clone)]
pub struct LogLimiter {
    state: Arc<State>,
    /// The limiter as a dispatcher, made once: each `Dispatch::new` re-registers every
    /// call site's interest.
    dispatch: Dispatch,
}

impl std::fmt::Debug for LogLimiter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogLimiter")
            .field("burst", &self.state.burst)
            .field("period", &self.state.period)
            .field("left_out", &self.left_out())
            .finish()
    }
}

struct State {
    inner: Dispatch,
    max_level: LevelFilter,
    burst: u32,
    period: Duration,
    sites: Mutex<HashMap<tracing::callsite::Identifier, Site>>,
    left_out: AtomicU64,
}

/// One call site's lines in the current period.
struct Site {
    meta: &'static Metadata<'static>,
    passed: u32,
    left_out: u64,
    /// The last line left out (its message and fields).
    last: String,
}

thread_local! {
    static GUARD: RefCell<Option<DefaultGuard>> = const { RefCell::new(None) };
}

impl LogLimiter {
    /// A limiter passing `burst` lines per call site per `period` (at least 1 and
    /// 1 ms) to the current default dispatcher (the process's subscriber, if one is set).
    pub fn new(burst: u32, period: Duration) -> Self {
        let inner = tracing::dispatcher::get_default(Dispatch::clone);
        let state = Arc::new(State {
            inner,
            // What the process's subscriber wants: the limiter widens nothing.
            max_level: LevelFilter::current(),
            burst: burst.max(1),
            period: period.max(Duration::from_millis(1)),
            sites: Mutex::new(HashMap::new()),
            left_out: AtomicU64::new(0),
        });
        let dispatch = Dispatch::new(Limited(Arc::clone(&state)));
        Self { state, dispatch }
    }

    /// The period [`LogLimiter::flush`] is to be called at.
    pub fn period(&self) -> Duration {
        self.state.period
    }

    /// Makes the limiter this thread's default dispatcher until
    /// [`LogLimiter::leave_this_thread`] (a runtime's `on_thread_start`).
    pub fn enter_this_thread(&self) {
        let guard = tracing::dispatcher::set_default(&self.dispatch);
        GUARD.with(|g| *g.borrow_mut() = Some(guard));
    }

    /// Gives this thread its former default dispatcher back.
    pub fn leave_this_thread() {
        GUARD.with(|g| drop(g.borrow_mut().take()));
    }

    /// Lines left out so far.
    pub fn left_out(&self) -> u64 {
        self.state.left_out.load(Ordering::Relaxed)
    }

    /// Ends the period: writes a summary line for each call site that had lines left
    /// out, at their level, and lets `burst` lines per call site through again.
    pub fn flush(&self) {
        let mut summaries = Vec::new();
        {
            let mut sites = self
                .state
                .sites
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            for site in sites.values_mut() {
                if site.left_out > 0 {
                    summaries.push((site.meta, site.left_out, std::mem::take(&mut site.last)));
                }
                site.passed = 0;
                site.left_out = 0;
            }
        }
        let period_s = self.state.period.as_secs_f64();
        // Straight to the process's subscriber: the summaries themselves are not limited
        // (at most one per call site per period).
        tracing::dispatcher::with_default(&self.state.inner, || {
            for (meta, n, last) in summaries {
                let source = match (meta.file(), meta.line()) {
                    (Some(f), Some(l)) => format!("{f}:{l}"),
                    _ => meta.name().to_string(),
                };
                let target = meta.target();
                macro_rules! summary {
                    ($level:expr) => {
                        tracing::event!(
                            target: "vibro_view::live",
                            $level,
                            left_out = n,
                            "{n} more log lines of {target} ({source}) left out in the last \
                             {period_s} s; the last: {last}"
                        )
                    };
                }
                match *meta.level() {
                    Level::ERROR => summary!(Level::ERROR),
                    Level::WARN => summary!(Level::WARN),
                    Level::INFO => summary!(Level::INFO),
                    Level::DEBUG => summary!(Level::DEBUG),
                    Level::TRACE => summary!(Level::TRACE),
                }
            }
        });
    }

    /// Whether `event` may pass; counts it (and keeps its text) when not.
    fn admit(state: &State, event: &Event<'_>) -> bool {
        let meta = event.metadata();
        let mut sites = state.sites.lock().unwrap_or_else(PoisonError::into_inner);
        let site = sites.entry(meta.callsite()).or_insert_with(|| Site {
            meta,
            passed: 0,
            left_out: 0,
            last: String::new(),
        });
        if site.passed < state.burst {
            site.passed += 1;
            return true;
        }
        site.left_out += 1;
        state.left_out.fetch_add(1, Ordering::Relaxed);
        site.last.clear();
        event.record(&mut Text(&mut site.last));
        if site.last.len() > KEPT_CHARS {
            let mut end = KEPT_CHARS;
            while !site.last.is_char_boundary(end) {
                end -= 1;
            }
            site.last.truncate(end);
            site.last.push('…');
        }
        false
    }
}

/// An event's message and fields as text (`message field=value ...`).
struct Text<'a>(&'a mut String);

impl tracing::field::Visit for Text<'_> {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if self.0.len() > KEPT_CHARS {
            return;
        }
        if !self.0.is_empty() {
            self.0.push(' ');
        }
        let _ = if field.name() == "message" {
            write!(self.0, "{value:?}")
        } else {
            write!(self.0, "{}={value:?}", field.name())
        };
    }
}

/// The limiter as a subscriber: everything but events goes to the inner dispatcher as
/// it is (spans, levels, interest). `current_span` is left at its default (unknown):
/// its type is `tracing-core`'s, not re-exported by `tracing`, and a subscriber built
/// on `tracing-subscriber`'s registry finds an event's span in its own span stack.
struct Limited(Arc<State>);

impl Subscriber for Limited {
    fn register_callsite(&self, meta: &'static Metadata<'static>) -> Interest {
        self.0.inner.register_callsite(meta)
    }

    fn max_level_hint(&self) -> Option<LevelFilter> {
        Some(self.0.max_level)
    }

    fn enabled(&self, meta: &Metadata<'_>) -> bool {
        self.0.inner.enabled(meta)
    }

    fn new_span(&self, span: &span::Attributes<'_>) -> span::Id {
        self.0.inner.new_span(span)
    }

    fn record(&self, span: &span::Id, values: &span::Record<'_>) {
        self.0.inner.record(span, values)
    }

    fn record_follows_from(&self, span: &span::Id, follows: &span::Id) {
        self.0.inner.record_follows_from(span, follows)
    }

    fn event(&self, event: &Event<'_>) {
        if LogLimiter::admit(&self.0, event) {
            self.0.inner.event(event);
        }
    }

    fn enter(&self, span: &span::Id) {
        self.0.inner.enter(span)
    }

    fn exit(&self, span: &span::Id) {
        self.0.inner.exit(span)
    }

    fn clone_span(&self, id: &span::Id) -> span::Id {
        self.0.inner.clone_span(id)
    }

    fn try_close(&self, id: span::Id) -> bool {
        self.0.inner.try_close(id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Counts the events it is given and keeps their text.
    #[derive(Default, Clone)]
    struct Sink(Arc<Mutex<Vec<String>>>);

    impl Subscriber for Sink {
        fn enabled(&self, _: &Metadata<'_>) -> bool {
            true
        }
        fn new_span(&self, _: &span::Attributes<'_>) -> span::Id {
            span::Id::from_u64(1)
        }
        fn record(&self, _: &span::Id, _: &span::Record<'_>) {}
        fn record_follows_from(&self, _: &span::Id, _: &span::Id) {}
        fn event(&self, event: &Event<'_>) {
            let mut s = String::new();
            event.record(&mut Text(&mut s));
            self.0.lock().unwrap().push(s);
        }
        fn enter(&self, _: &span::Id) {}
        fn exit(&self, _: &span::Id) {}
    }

    /// 1,000 lines from one call site and 3 from another, on a thread the limiter is
    /// the default of: `burst` of the first pass, all 3 of the second, and the flush
    /// writes one summary with the count left out and the last line; in the next
    /// period lines pass again, and a period with nothing left out has no summary.
    #[test]
    fn a_flood_from_one_call_site_is_cut_to_the_burst_and_summarised() {
        let sink = Sink::default();
        let lines = Arc::clone(&sink.0);
        let dispatch = Dispatch::new(sink);
        tracing::dispatcher::with_default(&dispatch, || {
            let limiter = LogLimiter::new(5, Duration::from_secs(10));
            let flood = |n: usize| {
                let l = limiter.clone();
                std::thread::spawn(move || {
                    l.enter_this_thread();
                    for id in 0..n {
                        tracing::error!("unknown channel: {id}");
                    }
                    for id in 0..3 {
                        tracing::warn!(id, "another site");
                    }
                    LogLimiter::leave_this_thread();
                })
                .join()
                .unwrap();
            };
            flood(1000);
            assert_eq!(limiter.left_out(), 995);
            let got = lines.lock().unwrap().clone();
            assert_eq!(got.len(), 5 + 3, "{got:?}");
            assert_eq!(got[4], "unknown channel: 4");
            limiter.flush();
            let got = lines.lock().unwrap().clone();
            assert_eq!(got.len(), 9, "{got:?}");
            let summary = &got[8];
            assert!(summary.contains("995 more log lines"), "{summary}");
            assert!(
                summary.contains("the last: unknown channel: 999"),
                "{summary}"
            );
            assert!(summary.contains("left_out=995"), "{summary}");
            flood(2);
            assert_eq!(lines.lock().unwrap().len(), 9 + 2 + 3);
            limiter.flush();
            assert_eq!(
                lines.lock().unwrap().len(),
                14,
                "nothing left out: no summary"
            );
            assert_eq!(limiter.left_out(), 995);
        });
    }
}
