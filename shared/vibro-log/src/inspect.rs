//! Reading a log's summary and repairing a damaged log, with the reasons a person
//! needs (`vibrocomp log info`, `log recover`; docs/logs.md): what is not an MCAP log
//! at all is refused by name before the MCAP reader's terser errors, and a damaged
//! log is named with the command that recovers it.

use std::io::Read as _;
use std::path::Path;

use serde::Serialize;
use vibro_mcap::{LogInfo, RecoverReport};

use crate::output::{check_output, PartFile};
use crate::{Error, Result};

/// Every MCAP file starts with these 8 bytes.
pub const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

fn not_a_log(path: &Path, problem: String) -> Error {
    Error::Input {
        path: path.to_path_buf(),
        problem,
    }
}

/// Refuses what is not an MCAP log at all (a missing file, a folder, an empty or
/// foreign file) with the reason; returns the file's size in bytes.
pub fn check_mcap_file(path: &Path) -> Result<u64> {
    check_log_file(path, true)
}

/// [`check_mcap_file`]; without `require_magic`, a file that does not start with the
/// MCAP magic passes (`log recover`: a garbled magic may precede intact chunks).
fn check_log_file(path: &Path, require_magic: bool) -> Result<u64> {
    let read_error = |action: &str| {
        let path = path.to_path_buf();
        let action = action.to_string();
        move |source| Error::ReadInput {
            path,
            action,
            source,
        }
    };
    let meta = std::fs::metadata(path).map_err(read_error("cannot open it"))?;
    if meta.is_dir() {
        return Err(not_a_log(path, "is a directory, not an MCAP log".into()));
    }
    if meta.len() == 0 {
        return Err(not_a_log(
            path,
            "empty file (0 bytes), not an MCAP log".into(),
        ));
    }
    let mut head = Vec::with_capacity(MCAP_MAGIC.len());
    std::fs::File::open(path)
        .and_then(|f| f.take(MCAP_MAGIC.len() as u64).read_to_end(&mut head))
        .map_err(read_error("cannot read it"))?;
    if require_magic && !MCAP_MAGIC.starts_with(&head) {
        return Err(not_a_log(
            path,
            "not an MCAP log: it does not start with the MCAP magic bytes 89 4D 43 41 50 30 0D 0A"
                .into(),
        ));
    }
    Ok(meta.len())
}

/// A log's summary (`vibro_mcap::info`) after [`check_mcap_file`]; a damaged log is
/// named with the command that recovers it.
pub fn read_info(path: &Path) -> Result<LogInfo> {
    check_mcap_file(path)?;
    vibro_mcap::info(path).map_err(|e| read_error(path, e))
}

/// An error of reading the log `path` with the reason a person needs: a damaged log
/// (unfinished, truncated, a bad chunk) is named with the command that recovers it.
pub(crate) fn read_error(path: &Path, e: vibro_mcap::Error) -> Error {
    let p = path.display();
    if let vibro_mcap::Error::Unfinished { chunks, .. } = e {
        let keep = if chunks == 0 {
            format!("no complete chunk before the damage; `vibrocomp log recover {p} OUT.mcap` looks for intact chunks after it and says so if there is nothing to keep")
        } else {
            format!("{chunks} complete chunk(s) readable; recover them with: vibrocomp log recover {p} OUT.mcap")
        };
        return Error::Unfinished {
            path: path.to_path_buf(),
            keep,
        };
    }
    let damaged = matches!(
        e,
        vibro_mcap::Error::Truncated { .. }
            | vibro_mcap::Error::NotFinished { .. }
            | vibro_mcap::Error::ChunkCrc { .. }
    );
    Error::ReadLog {
        context: if damaged {
            format!("{p} is damaged (`vibrocomp log recover {p} OUT.mcap` keeps everything up to its last complete chunk)")
        } else {
            format!("cannot read the log {p}")
        },
        source: e,
    }
}

/// One channel of a repaired log.
#[derive(Debug, Clone, Serialize)]
pub struct KeptChannel {
    pub topic: String,
    pub messages: u64,
    pub first_log_time_ns: Option<u64>,
    pub last_log_time_ns: Option<u64>,
    pub first_sequence: Option<u32>,
    pub last_sequence: Option<u32>,
    pub lost: u64,
}

/// What a repair kept: the library's report, the bytes lost, and the channels of the
/// repaired log as read back.
#[derive(Debug, Clone, Serialize)]
pub struct RecoverOutput {
    #[serde(flatten)]
    pub report: RecoverReport,
    /// Bytes of the damaged file after the last record read whole (0 for a complete
    /// file, whose summary section is rebuilt).
    pub lost_bytes: u64,
    pub channels: Vec<KeptChannel>,
    /// What the recovery comes to, in one line (the last of `log recover`'s report).
    pub result: String,
    /// `log recover`'s exit status: 0, or [`EXIT_RECOVERED_WITH_LOSSES`] when
    /// something the damaged file holds is not in the new one
    /// (`vibro_mcap::RecoverReport::losses`).
    pub exit_code: u8,
}

impl RecoverOutput {
    /// The text `vibrocomp log recover` prints: what was read and written, the
    /// channels kept, what was lost and why, the verdict.
    pub fn write_text(&self, out: &mut impl std::fmt::Write) -> std::fmt::Result {
        let o = self;
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
                vibro_mcap::fmt_opt_log_ns(c.first_log_time_ns),
                vibro_mcap::fmt_opt_log_ns(c.last_log_time_ns)
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
}

/// `log recover`'s exit status when it wrote the new file but lost some of the damaged
/// one (a skipped chunk, a damaged region, messages without their channel): neither
/// success (0) nor failure (1, nothing written), so that a script can tell them apart.
pub const EXIT_RECOVERED_WITH_LOSSES: u8 = 3;

/// The one-line verdict of a recovery.
fn recovery_result(r: &RecoverReport, lost_bytes: u64) -> String {
    let kept = match r.expected {
        Some(e) => format!("{} of {} messages kept", r.messages_recovered, e.messages),
        None => format!("{} messages kept", r.messages_recovered),
    };
    if !r.losses {
        return if r.cut_short && lost_bytes > 0 {
            format!(
                "recovered: {kept}; nothing lost but the record the file ends inside, cut short (what a crash leaves: its last {lost_bytes} bytes)"
            )
        } else {
            format!("recovered, nothing lost: {kept}")
        };
    }
    let dropped = if r.messages_dropped_exact {
        format!(
            "{} messages dropped (counted by the input's statistics)",
            r.messages_dropped
        )
    } else if r.messages_dropped > 0 {
        format!("at least {} messages dropped", r.messages_dropped)
    } else {
        "an unknown number of messages dropped".to_string()
    };
    let regions = r.damage.len();
    format!(
        "recovered with losses (exit status {EXIT_RECOVERED_WITH_LOSSES}): {kept}, {dropped}; {} chunk(s) skipped, {regions} region(s) of the input not copied, {} bytes in all",
        r.chunks_skipped, r.bytes_skipped
    )
}

/// Rewrites the log `damaged` (a crash: no summary, a truncated last chunk) into `out`
/// up to its last complete chunk (`vibro_mcap::recover`), `out` appearing only when
/// complete (an existing file only with `force`); reads the result back.
pub fn recover_log(damaged: &Path, out: &Path, force: bool) -> Result<RecoverOutput> {
    let input_bytes =
        check_log_file(damaged, false).map_err(|e| Error::RecoverInput(Box::new(e)))?;
    check_output(out, &[damaged], force)?;
    let part = PartFile::beside(out)?;
    let mut report = match vibro_mcap::recover(damaged, part.path()) {
        Ok(report) => report,
        // Without a complete header there is no profile, schema or chunk to keep.
        Err(vibro_mcap::Error::Truncated { .. }) => {
            return Err(not_a_log(
                damaged,
                format!("nothing to recover: it ends before its MCAP header record is complete ({input_bytes} bytes)"),
            ))
        }
        // Nothing intact: the library says why, once (its error has no source to
        // repeat it).
        Err(vibro_mcap::Error::Malformed { reason, .. }) => return Err(not_a_log(damaged, reason)),
        Err(source) => {
            return Err(Error::ReadLog {
                context: format!("recovering {}", damaged.display()),
                source,
            })
        }
    };
    part.commit(out, force)?;
    report.output = out.to_path_buf();
    let kept = read_info(out).map_err(|e| Error::ReadBack(Box::new(e)))?;
    // After a complete file's data-end record come its summary and footer, which the
    // new file has its own of: nothing is lost there.
    let lost_bytes = if report.input_complete {
        0
    } else {
        report.input_bytes.saturating_sub(report.valid_prefix_bytes)
    };
    Ok(RecoverOutput {
        lost_bytes,
        result: recovery_result(&report, lost_bytes),
        exit_code: if report.losses {
            EXIT_RECOVERED_WITH_LOSSES
        } else {
            0
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
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_file as file;

    #[test]
    fn what_is_not_a_log_is_named() {
        let empty = file("empty.mcap", b"");
        assert_eq!(
            check_mcap_file(&empty).unwrap_err().to_string(),
            format!("{}: empty file (0 bytes), not an MCAP log", empty.display())
        );
        let text = file("text.mcap", b"hello");
        assert!(check_mcap_file(&text)
            .unwrap_err()
            .to_string()
            .ends_with("does not start with the MCAP magic bytes 89 4D 43 41 50 30 0D 0A"));
        let dir = empty.parent().unwrap();
        assert_eq!(
            check_mcap_file(dir).unwrap_err().to_string(),
            format!("{}: is a directory, not an MCAP log", dir.display())
        );
        // The first bytes of a log are enough to pass (its size is returned).
        let head = file("head.mcap", &MCAP_MAGIC[..4]);
        assert_eq!(check_mcap_file(&head).unwrap(), 4);
    }

    #[test]
    fn an_unfinished_log_names_the_command_that_recovers_it() {
        let head = file("unfinished.mcap", MCAP_MAGIC);
        let e = read_info(&head).unwrap_err().to_string();
        assert!(e.contains("vibrocomp log recover"), "{e}");
    }
}
