//! `vibrocomp log`: inspect, repair and import MCAP logs (docs/logs.md).
//!
//! - `info` summarises a log with `vibro_mcap::info`: channels, counts, time span,
//!   sequence losses, metadata and attachments.
//! - `recover` rewrites a log left by a crash up to its last complete chunk
//!   (`vibro_mcap::recover`) and says what was kept and what was lost.
//! - `import` (module [`import`]) turns rig data recorded as CSV into a log with the
//!   simulator's topics and wire types, so that it replays like a simulated flight
//!   (`vibro_log::import`).

mod import;

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use serde::Serialize;
use vibro_log::output::{check_output, PartFile};
use vibro_mcap::{LogInfo, RecoverReport};

use crate::output::print_json;
pub use import::ImportArgs;

/// Inspect, repair and import MCAP logs.
#[derive(Debug, Subcommand)]
pub enum LogCommand {
    /// Channels, message counts, time span, sequence losses, metadata and attachments.
    Info(InfoArgs),
    /// Rewrite a log left by a crash up to its last complete chunk.
    Recover(RecoverArgs),
    /// Turn rig data recorded as CSV into a log with the simulator's topics and types.
    Import(ImportArgs),
}

pub fn run(cmd: LogCommand) -> anyhow::Result<()> {
    match cmd {
        LogCommand::Info(args) => info(&args),
        LogCommand::Recover(args) => recover(&args),
        LogCommand::Import(args) => import::run(&args),
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

/// Reads a log's summary; a damaged one gets the command that repairs it.
/// Every MCAP file starts with these 8 bytes.
const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Refuses what is not an MCAP log at all (a missing file, a folder, an empty or
/// foreign file) with the reason, before the MCAP reader's terser errors.
fn check_mcap_file(path: &Path) -> anyhow::Result<u64> {
    use std::io::Read as _;
    let meta =
        std::fs::metadata(path).with_context(|| format!("{}: cannot open it", path.display()))?;
    if meta.is_dir() {
        bail!("{}: is a directory, not an MCAP log", path.display());
    }
    if meta.len() == 0 {
        bail!("{}: empty file (0 bytes), not an MCAP log", path.display());
    }
    let mut head = Vec::with_capacity(MCAP_MAGIC.len());
    std::fs::File::open(path)
        .and_then(|f| f.take(MCAP_MAGIC.len() as u64).read_to_end(&mut head))
        .with_context(|| format!("{}: cannot read it", path.display()))?;
    if !MCAP_MAGIC.starts_with(&head) {
        bail!(
            "{}: not an MCAP log: it does not start with the MCAP magic bytes 89 4D 43 41 50 30 0D 0A",
            path.display()
        );
    }
    Ok(meta.len())
}

fn read_info(path: &Path) -> anyhow::Result<LogInfo> {
    check_mcap_file(path)?;
    vibro_mcap::info(path).map_err(|e| {
        // Said once, with the command that recovers it (not as a context over the
        // library's own text, which names the library function).
        if let vibro_mcap::Error::Unfinished { chunks, .. } = e {
            let p = path.display();
            let keep = if chunks == 0 {
                format!("no complete chunk: `vibrocomp log recover {p} OUT.mcap` keeps only what precedes the first chunk, if anything")
            } else {
                format!("{chunks} complete chunk(s) readable; recover them with: vibrocomp log recover {p} OUT.mcap")
            };
            return anyhow::anyhow!(
                "{p} is damaged: unfinished MCAP file (no footer: the writer stopped before finishing it, e.g. killed or out of disk): {keep}"
            );
        }
        let damaged = matches!(
            e,
            vibro_mcap::Error::Truncated { .. }
                | vibro_mcap::Error::NotFinished { .. }
                | vibro_mcap::Error::ChunkCrc { .. }
        );
        let context = if damaged {
            format!(
                "{} is damaged (`vibrocomp log recover {} OUT.mcap` keeps everything up to its last complete chunk)",
                path.display(),
                path.display()
            )
        } else {
            format!("cannot read the log {}", path.display())
        };
        anyhow::Error::new(e).context(context)
    })
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
    if info.lost == 0 && out_of_order == 0 && info.jumps == 0 {
        writeln!(out, "  losses: none (every sequence advances by 1)")?;
    } else {
        let by_sequence = info.lost - info.inputs_without_output;
        write!(
            out,
            "  losses: {by_sequence} messages lost in {gaps} sequence gaps, {out_of_order} out of order"
        )?;
        if info.inputs_without_output > 0 {
            // Where: the first gap of each channel that has one (all are in --json).
            let wheres: Vec<String> = info
                .channels
                .iter()
                .filter_map(|c| {
                    let g = c.input_gaps.first()?;
                    let more = if c.inputs_without_output > g.missing {
                        format!(
                            " and {} more in later gaps",
                            c.inputs_without_output - g.missing
                        )
                    } else {
                        String::new()
                    };
                    Some(format!(
                        "input_seq {} -> {} on {}{more}",
                        g.from, g.to, c.topic
                    ))
                })
                .collect();
            write!(
                out,
                "; {} accelerometer blocks without compensated output ({})",
                info.inputs_without_output,
                wheres.join("; ")
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
        writeln!(out)?;
    }
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

/// One channel of the repaired log.
#[derive(Debug, Serialize)]
struct KeptChannel {
    topic: String,
    messages: u64,
    first_log_time_ns: Option<u64>,
    last_log_time_ns: Option<u64>,
    first_sequence: Option<u32>,
    last_sequence: Option<u32>,
    lost: u64,
}

/// What `log recover --json` prints: the library's report, the bytes lost, and the
/// channels of the repaired log.
#[derive(Debug, Serialize)]
struct RecoverOutput {
    #[serde(flatten)]
    report: RecoverReport,
    /// Bytes of the damaged file after the last record read whole (0 for a complete
    /// file, whose summary section is rebuilt).
    lost_bytes: u64,
    channels: Vec<KeptChannel>,
}

fn recover(args: &RecoverArgs) -> anyhow::Result<()> {
    let input_bytes = check_mcap_file(&args.damaged).context("the damaged log to recover")?;
    check_output(&args.out, &[&args.damaged], args.force)?;
    let part = PartFile::beside(&args.out);
    let mut report = match vibro_mcap::recover(&args.damaged, part.path()) {
        Ok(report) => report,
        // Without a complete header there is no profile, schema or chunk to keep.
        Err(vibro_mcap::Error::Truncated { .. }) => bail!(
            "{}: nothing to recover: it ends before its MCAP header record is complete ({input_bytes} bytes)",
            args.damaged.display()
        ),
        Err(e) => {
            return Err(anyhow::Error::new(e))
                .with_context(|| format!("recovering {}", args.damaged.display()))
        }
    };
    part.commit(&args.out)?;
    report.output = args.out.clone();
    let kept = read_info(&args.out).context("reading back the recovered log")?;
    let output = RecoverOutput {
        // After a complete file's data-end record come its summary and footer, which
        // the new file has its own of: nothing is lost there.
        lost_bytes: if report.input_complete {
            0
        } else {
            report.input_bytes.saturating_sub(report.valid_prefix_bytes)
        },
        channels: kept
            .channels
            .iter()
            .map(|c| KeptChannel {
                topic: c.topic.clone(),
                messages: c.messages,
                first_log_time_ns: c.first_log_time_ns,
                last_log_time_ns: c.last_log_time_ns,
                first_sequence: c.first_sequence,
                last_sequence: c.last_sequence,
                lost: c.lost,
            })
            .collect(),
        report,
    };
    if args.json {
        return print_json(&output);
    }
    print_text(|out| write_recover(out, &output))
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
            "  dropped: {} messages whose channel was defined only in a skipped chunk",
            r.messages_orphaned
        )?;
    }
    Ok(())
}
