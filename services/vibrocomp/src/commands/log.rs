//! `vibrocomp log`: inspect, repair, import and measure MCAP logs (docs/logs.md).
//!
//! - `info` summarises a log with `vibro_log::inspect::read_info`: channels, counts,
//!   time span, sequence losses, metadata and attachments.
//! - `recover` rewrites a log left by a crash up to its last complete chunk
//!   (`vibro_log::inspect::recover_log`) and says what was kept and what was lost.
//! - `import` (module [`import`]) turns rig data recorded as CSV into a log with the
//!   simulator's topics and wire types, so that it replays like a simulated flight
//!   (`vibro_log::import`).
//! - `errors` (module [`errors`]) measures a recorded session against its reference:
//!   the stage-error table of `vibrocomp demo` (`vibro_log::session`).

mod errors;
mod import;

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use vibro_log::inspect::{read_info, recover_log, RecoverOutput};
use vibro_mcap::LogInfo;

use crate::output::print_json;
pub use errors::ErrorsArgs;
pub use import::ImportArgs;

/// Inspect, repair, import and measure MCAP logs.
#[derive(Debug, Subcommand)]
pub enum LogCommand {
    /// Channels, message counts, time span, sequence losses, metadata and attachments.
    Info(InfoArgs),
    /// Rewrite a log left by a crash up to its last complete chunk.
    Recover(RecoverArgs),
    /// Turn rig data recorded as CSV into a log with the simulator's topics and types.
    Import(ImportArgs),
    /// Each compensation stage's error in a recorded session against its reference
    /// (the simulator's truth), mean over windows: the table `demo` prints.
    Errors(ErrorsArgs),
}

pub fn run(cmd: LogCommand) -> anyhow::Result<()> {
    match cmd {
        LogCommand::Info(args) => info(&args),
        LogCommand::Recover(args) => recover(&args),
        LogCommand::Import(args) => import::run(&args),
        LogCommand::Errors(args) => errors::run(&args),
    }
}

// ---------------------------------------------------------------------------------
// Shared helpers

/// A time on the data time base, in seconds with every nanosecond shown.
fn fmt_ns(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

fn fmt_opt_ns(ns: Option<u64>) -> String {
    ns.map_or_else(|| "-".to_string(), |t| format!("{} s", fmt_ns(t)))
}

/// A number rounded to 10 significant digits, shortest form: a measured rate of
/// 999.9999999999998 Hz reads 1000.
fn fmt_sig(x: f64) -> String {
    format!("{x:.9e}")
        .parse::<f64>()
        .map_or_else(|_| x.to_string(), |r| r.to_string())
}

/// Prints what `write` produced on stdout; a closed pipe (`| head`) ends it quietly.
fn print_text(write: impl FnOnce(&mut String) -> std::fmt::Result) -> anyhow::Result<()> {
    let mut text = String::new();
    write(&mut text).context("formatting the output")?;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("writing to stdout"),
    }
}

// ---------------------------------------------------------------------------------
// log info

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The MCAP log.
    pub file: PathBuf,
    /// Print the summary as JSON (`vibro_mcap::LogInfo`).
    #[arg(long)]
    pub json: bool,
}

fn info(args: &InfoArgs) -> anyhow::Result<()> {
    let info = read_info(&args.file)?;
    if args.json {
        return print_json(&info);
    }
    print_text(|out| write_info(out, &info))
}

fn write_info(out: &mut String, info: &LogInfo) -> std::fmt::Result {
    writeln!(
        out,
        "{}: {} bytes, profile {:?}, written by {:?}",
        info.path.display(),
        info.file_bytes,
        info.profile,
        info.library
    )?;
    let chunks = info.chunks.map_or_else(
        || "no statistics record".to_string(),
        |c| format!("{c} chunks"),
    );
    writeln!(
        out,
        "  {} messages on {} channels, {chunks}; log time {} .. {} ({:.3} s)",
        info.messages,
        info.channels.len(),
        fmt_opt_ns(info.first_log_time_ns),
        fmt_opt_ns(info.last_log_time_ns),
        info.duration_s
    )?;
    // The two clocks (docs/logs.md, "Time"): the data's (log time) and, in a recording,
    // the recorder's receive time (publish time), which a replay compresses.
    writeln!(
        out,
        "  publish time {} .. {} ({:.3} s; in a recording the receive time, the log time \
         the data's)",
        fmt_opt_ns(info.first_publish_time_ns),
        fmt_opt_ns(info.last_publish_time_ns),
        info.publish_span_s
    )?;
    let gaps: u64 = info.channels.iter().map(|c| c.gaps).sum();
    let out_of_order: u64 = info.channels.iter().map(|c| c.out_of_order).sum();
    let resyncs: u64 = info.channels.iter().map(|c| c.resyncs).sum();
    let restarts: u64 = info.channels.iter().map(|c| c.restarts).sum();
    if info.lost == 0 && out_of_order == 0 && info.jumps == 0 && resyncs == 0 && restarts == 0 {
        info.write_no_losses(out)?;
    } else {
        // Each loss once (vibro_mcap::LogInfo::lost): by sequence, and the blocks in
        // the file that got no output.
        let by_sequence = info.lost.saturating_sub(info.inputs_without_output);
        write!(
            out,
            "  losses: {by_sequence} messages lost in {gaps} sequence gaps, {out_of_order} out of order"
        )?;
        if restarts > 0 {
            write!(out, "; {restarts} restarts (a sequence back to 0)")?;
        }
        if resyncs > 0 {
            write!(
                out,
                "; {resyncs} resyncs, {} counted lost at a seq ahead of its stream and taken back when it resumed",
                info.retracted
            )?;
        }
        // Which blocks: every compensated channel's, by seq (all are in --json).
        for c in info.channels.iter().filter(|c| c.inputs_without_output > 0) {
            write!(
                out,
                "; {} accelerometer blocks without compensated output on {} ({}{})",
                c.inputs_without_output,
                c.topic,
                c.unanswered,
                c.inputs_topic
                    .as_deref()
                    .map_or_else(String::new, |t| format!(" on {t}"))
            )?;
        }
        if info.jumps > 0 {
            write!(
                out,
                "; {} sequence jumps too big to be losses (over {} messages skipped: a corrupt or renumbered sequence, not counted)",
                info.jumps,
                vibro_mcap::MAX_LOST_MESSAGES
            )?;
        }
        if info.inputs_without_output > 0 {
            write!(out, "; {} lost in all", info.lost)?;
        }
        writeln!(out)?;
    }
    info.write_recoveries(out)?;
    // Topics as wide as the longest (`/heartbeat/compensator` is 22 characters).
    let tw = info
        .channels
        .iter()
        .map(|c| c.topic.len())
        .max()
        .unwrap_or(0)
        .max(6);
    let kind_of = |c: &vibro_mcap::ChannelInfo| {
        c.kind.clone().unwrap_or_else(|| {
            // A view channel's schema without its package (docs/view.md).
            c.message_type
                .strip_prefix("vibrocomp.view.v1.")
                .map_or_else(|| c.message_type.clone(), |t| format!("view {t}"))
        })
    };
    let kw = info
        .channels
        .iter()
        .map(|c| kind_of(c).len())
        .max()
        .unwrap_or(0)
        .max(17);
    if !info.channels.is_empty() {
        writeln!(
            out,
            "  {:<tw$} {:<kw$} {:>9}  {:>21}  {:>21}  {:>11}  {:>21}  {:>6}  {:>5}  {:>12}",
            "topic",
            "type",
            "messages",
            "first log time, s",
            "last log time, s",
            "span, s",
            "sequence",
            "lost",
            "gaps",
            "out of order"
        )?;
    }
    for c in &info.channels {
        let kind = kind_of(c);
        let sequence = match (c.first_sequence, c.last_sequence) {
            (Some(a), Some(b)) => format!("{a}..{b}"),
            _ => "-".to_string(),
        };
        writeln!(
            out,
            "  {:<tw$} {:<kw$} {:>9}  {:>21}  {:>21}  {:>11.3}  {:>21}  {:>6}  {:>5}  {:>12}",
            c.topic,
            kind,
            c.messages,
            c.first_log_time_ns.map_or_else(|| "-".to_string(), fmt_ns),
            c.last_log_time_ns.map_or_else(|| "-".to_string(), fmt_ns),
            c.span_s,
            sequence,
            c.lost,
            c.gaps,
            c.out_of_order
        )?;
    }
    if info.metadata.is_empty() {
        writeln!(out, "  metadata: none")?;
    } else {
        writeln!(out, "  metadata:")?;
        for m in &info.metadata {
            writeln!(out, "    {} ({} entries)", m.name, m.entries.len())?;
            for (k, v) in &m.entries {
                writeln!(out, "      {k} = {v}")?;
            }
        }
    }
    if info.attachments.is_empty() {
        writeln!(out, "  attachments: none")?;
    } else {
        writeln!(out, "  attachments:")?;
        for a in &info.attachments {
            writeln!(out, "    {} ({}, {} bytes)", a.name, a.media_type, a.bytes)?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------
// log recover

#[derive(Debug, Args)]
pub struct RecoverArgs {
    /// The damaged log (a crash: no summary, a truncated last chunk).
    pub damaged: PathBuf,
    /// Where to write the repaired log (not DAMAGED itself).
    pub out: PathBuf,
    /// Overwrite OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

fn recover(args: &RecoverArgs) -> anyhow::Result<()> {
    let output = recover_log(&args.damaged, &args.out, args.force)?;
    if args.json {
        print_json(&output)?;
    } else {
        print_text(|out| write_recover(out, &output))?;
    }
    // Written, but with losses: its own exit status (docs/logs.md), after the report.
    match output.exit_code {
        0 => Ok(()),
        code => Err(crate::output::ExitStatus(code).into()),
    }
}

fn write_recover(out: &mut String, o: &RecoverOutput) -> std::fmt::Result {
    let r = &o.report;
    writeln!(
        out,
        "Recovered {} ({} bytes) into {} ({} bytes)",
        r.input.display(),
        r.input_bytes,
        r.output.display(),
        r.output_bytes
    )?;
    writeln!(
        out,
        "  kept: {} messages in {} complete chunks, {} attachment(s), {} metadata record(s)",
        r.messages_recovered, r.chunks_recovered, r.attachments, r.metadata
    )?;
    for c in &o.channels {
        let sequence = match (c.first_sequence, c.last_sequence) {
            (Some(a), Some(b)) => format!("sequence {a}..{b}"),
            _ => "no messages".to_string(),
        };
        writeln!(
            out,
            "    {:<14} {:>9} messages, {sequence}, log time {} .. {}",
            c.topic,
            c.messages,
            fmt_opt_ns(c.first_log_time_ns),
            fmt_opt_ns(c.last_log_time_ns)
        )?;
    }
    let chunk_loss = if r.chunks_skipped > 0 {
        format!(
            "{} messages in {} chunk(s) whose CRC or compression was broken; ",
            r.messages_in_skipped_chunks, r.chunks_skipped
        )
    } else {
        String::new()
    };
    if r.input_complete && r.damage.is_empty() {
        writeln!(
            out,
            "  lost: nothing (the file was complete: its data section ends with a data-end record)"
        )?;
    } else if r.input_complete {
        writeln!(
            out,
            "  lost: {chunk_loss}{} damaged region(s) skipped; the file's end was read (it ends with a data-end record)",
            r.damage.len()
        )?;
    } else {
        if !r.damage.is_empty() {
            writeln!(
                out,
                "  lost: {chunk_loss}{} damaged region(s) skipped",
                r.damage.len()
            )?;
        }
        writeln!(
            out,
            "  lost: {} bytes after byte {}{}",
            o.lost_bytes,
            r.valid_prefix_bytes,
            r.stop_reason
                .as_ref()
                .map(|s| format!(" ({s})"))
                .unwrap_or_default()
        )?;
    }
    for d in &r.damage {
        let messages = d
            .messages
            .map_or_else(String::new, |m| format!(", {m} messages"));
        writeln!(
            out,
            "  damaged: bytes {}..{}{messages}: {}",
            d.start_byte, d.end_byte, d.what
        )?;
    }
    if r.messages_orphaned > 0 {
        writeln!(
            out,
            "  dropped: {} messages whose channel, or its schema, survives nowhere intact",
            r.messages_orphaned
        )?;
    }
    if r.chunks_repaired > 0 {
        writeln!(
            out,
            "  repaired: {} chunk(s) whose header was damaged, read all the same (their CRC proves their records)",
            r.chunks_repaired
        )?;
    }
    writeln!(out, "  result: {}", o.result)
}
