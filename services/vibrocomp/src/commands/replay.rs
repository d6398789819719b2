//! `vibrocomp replay IN.mcap`: publishes the rig streams of a log into a running
//! system (`vibro_log::replay`), paced or as fast as possible in lock-step with the
//! services.

use anyhow::Context;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use vibro_log::{replay, Pace, ReplayOptions, ReplaySummary};
use vibro_msgs::ServiceNames;

use crate::flags::FlagProblems;
use crate::output::print_json;

/// Longest stretch of log time `--start-s` / `--duration-s` may name, s (about 31
/// years; a log's times are u64 ns, which end at 1.8e10 s).
const MAX_LOG_TIME_S: f64 = 1e9;
/// Longest `--wait-s`, s: a day.
const MAX_WAIT_S: f64 = 86_400.0;

#[derive(Debug, Clone, clap::Args)]
pub struct ReplayArgs {
    /// The log to replay (a simulator log, a recording, or an imported CSV).
    pub input: PathBuf,
    /// Speed as a multiple of the recorded pace (1 = real time).
    #[arg(long, conflicts_with = "as_fast_as_possible")]
    pub rate: Option<f64>,
    /// As fast as the services take it, lock-stepped with them (the default).
    #[arg(long)]
    pub as_fast_as_possible: bool,
    /// Skip the first seconds of the log.
    #[arg(long = "start-s", default_value_t = 0.0)]
    pub start_s: f64,
    /// Replay only this many seconds of the log.
    #[arg(long = "duration-s")]
    pub duration_s: Option<f64>,
    /// Topics to publish, comma-separated: /vib, /accel, /truth [default: those the log
    /// has; a log with /accel but no /vib is refused unless /accel is named here].
    #[arg(long, value_delimiter = ',')]
    pub topics: Vec<String>,
    /// Replay again and again (sequence numbers, sample indices and times continue)
    /// until Ctrl-C.
    #[arg(long = "loop")]
    pub loop_: bool,
    /// Service-name prefix of the system to replay into.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Seconds to wait for the services to be there.
    #[arg(long = "wait-s", default_value_t = 10.0)]
    pub wait_s: f64,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

impl ReplayArgs {
    /// The validated options.
    pub fn options(&self) -> anyhow::Result<ReplayOptions> {
        let names = ServiceNames::new(&self.prefix)
            .with_context(|| format!("--prefix {:?}", self.prefix))?;
        let pace = match self.rate {
            Some(x) => Pace::Rate(x),
            None => Pace::AsFastAsPossible,
        };
        // Every flag's rule, all at once, before any port opens.
        let mut p = FlagProblems::new();
        if let Some(x) = self.rate {
            p.rate("--rate", x);
        }
        // Log time in u64 ns: a start or length beyond MAX_LOG_TIME_S is no log's.
        p.seconds("--start-s", self.start_s, 0.0, MAX_LOG_TIME_S);
        if let Some(d) = self.duration_s {
            p.seconds("--duration-s", d, 1e-9, MAX_LOG_TIME_S);
        }
        let wait = p.seconds("--wait-s", self.wait_s, 1e-3, MAX_WAIT_S);
        p.finish()?;
        let mut o = ReplayOptions::new(names, pace);
        o.start_s = self.start_s;
        o.duration_s = self.duration_s;
        o.topics = (!self.topics.is_empty())
            .then(|| self.topics.iter().map(|t| t.trim().to_string()).collect());
        o.passes = if self.loop_ { 0 } else { 1 };
        o.connect_timeout = wait.unwrap_or_default();
        Ok(o)
    }
}

/// A progress bar over the messages of one pass (hidden when not on a terminal).
pub fn progress_bar(what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
    if !std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} messages ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(what.to_string());
    bar
}

/// Replays with a progress bar; `stop` ends it early.
pub fn replay_with_bar(
    args_input: &std::path::Path,
    options: &ReplayOptions,
    stop: &AtomicBool,
) -> anyhow::Result<ReplaySummary> {
    let bar = progress_bar("replaying");
    let summary = replay(args_input, options, stop, |done, per_pass| {
        if per_pass > 0 {
            bar.set_length(per_pass);
            bar.set_position(done % (per_pass + 1));
        }
    })
    .with_context(|| format!("replaying {}", args_input.display()));
    bar.finish_and_clear();
    summary
}

pub fn run(args: &ReplayArgs) -> anyhow::Result<()> {
    vibro_service::init_tracing();
    let options = args.options()?;
    // Ctrl-C / SIGTERM: stop after the current message, the ports released cleanly.
    let summary = vibro_service::run_service(|shutdown| {
        let input = args.input.clone();
        vibro_service::on_own_thread("vibrocomp-replay", shutdown, move |stop| {
            replay_with_bar(&input, &options, stop)
        })
    })??;
    if args.json {
        return print_json(&summary);
    }
    outln!(
        "Replayed {} messages of {} in {} pass(es) into {}: {:.1} s of log in {:.2} s ({:.1}x real time){}; undelivered {}",
        summary.messages,
        args.input.display(),
        summary.passes,
        args.prefix,
        summary.log_span_s,
        summary.elapsed_s,
        summary.real_time_factor,
        if summary.lockstepped {
            format!(", lock-stepped ({} waits, {:.2} s)", summary.lockstep_waits, summary.lockstep_wait_s)
        } else {
            String::new()
        },
        summary.undelivered
    )?;
    for (topic, n) in &summary.topics {
        outln!("  {topic:<10} {n:>9}")?;
    }
    for skipped in &summary.skipped_topics {
        outln!("  skipped {skipped}")?;
    }
    Ok(())
}
