//! The journal `journal.jsonl`: a header line (the format and the manifest's hash),
//! then one line per finished job (its [`JobResult`]), appended (`O_APPEND`) and
//! synced line by line, so that a killed batch loses at most the line it was writing.
//! On open, a torn last line is cut off; a journal begun by another manifest is refused
//! unless the batch is restarted (`restart` always begins the journal again).
//!
//! The journal is opened by `vibro_files` (never through a link, never a FIFO or a
//! device).

use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::{Error, JobResult, Result};

/// The journal's `format`.
pub const JOURNAL_FORMAT: &str = "vibrocomp-archive-journal/1";

#[derive(Debug, Serialize, Deserialize)]
struct Header {
    format: String,
    manifest: String,
    jobs: usize,
}

/// An open journal, appending.
#[derive(Debug)]
pub(crate) struct Journal {
    path: PathBuf,
    file: File,
}

/// What an opened journal held.
#[derive(Debug)]
pub(crate) struct Opened {
    pub journal: Journal,
    /// Every result line, in file order (duplicates included).
    pub results: Vec<JobResult>,
    /// Bytes of a torn last line cut off (0: none).
    pub torn_bytes: usize,
}

fn io<'a>(path: &'a Path, action: &'static str) -> impl FnOnce(std::io::Error) -> Error + 'a {
    move |source| Error::JournalIo {
        path: path.to_path_buf(),
        action,
        source,
    }
}

impl Journal {
    /// Opens (or creates) the journal `path` of the manifest whose hash is `hash`
    /// (module docs).
    pub fn open(path: &Path, hash: &str, jobs: usize, restart: bool) -> Result<Opened> {
        let mut results = Vec::new();
        let mut torn_bytes = 0;
        let mut fresh = true;
        if std::fs::symlink_metadata(path).is_ok() {
            let mut file = vibro_files::open_lock(path)?;
            let mut bytes = Vec::new();
            file.read_to_end(&mut bytes).map_err(io(path, "read it"))?;
            // A last piece without its newline was torn mid-write: never kept.
            let lines = complete_lines(&bytes);
            let mut keep = 0usize;
            let mut iter = lines.iter().enumerate().peekable();
            if let Some((_, first)) = iter.next() {
                match serde_json::from_slice::<Header>(first) {
                    Ok(h) if !restart && h.format == JOURNAL_FORMAT && h.manifest == hash => {
                        fresh = false;
                        keep = first.len() + 1;
                    }
                    Ok(h) if !restart => {
                        return Err(Error::OtherManifest {
                            path: path.to_path_buf(),
                            found: h.manifest,
                            expected: hash.to_string(),
                        })
                    }
                    Ok(_) => {}
                    Err(e) if !restart && iter.peek().is_some() => {
                        return Err(Error::Journal {
                            path: path.to_path_buf(),
                            line: 1,
                            problem: format!(
                                "not the journal's header ({e}); pass --restart to start the batch over"
                            ),
                        })
                    }
                    // A torn header (the batch was killed at its start): begun again.
                    Err(_) => {}
                }
            }
            if !fresh {
                while let Some((i, line)) = iter.next() {
                    match serde_json::from_slice::<JobResult>(line) {
                        Ok(r) => {
                            results.push(r);
                            keep += line.len() + 1;
                        }
                        // The last line, damaged: cut off as a torn one.
                        Err(_) if iter.peek().is_none() => break,
                        Err(e) => {
                            return Err(Error::Journal {
                                path: path.to_path_buf(),
                                line: i + 1,
                                problem: format!("not a job's result: {e}"),
                            })
                        }
                    }
                }
                torn_bytes = bytes.len() - keep;
            } else {
                keep = 0;
            }
            if keep < bytes.len() {
                file.set_len(keep as u64)
                    .map_err(io(path, "cut its torn last line"))?;
                file.sync_all().map_err(io(path, "sync it"))?;
            }
        }
        let file = vibro_files::open_append(path)?;
        let mut journal = Journal {
            path: path.to_path_buf(),
            file,
        };
        if fresh {
            let header = Header {
                format: JOURNAL_FORMAT.into(),
                manifest: hash.into(),
                jobs,
            };
            let line = serde_json::to_string(&header).map_err(|e| Error::Journal {
                path: path.to_path_buf(),
                line: 1,
                problem: e.to_string(),
            })?;
            journal.append(&line)?;
        }
        Ok(Opened {
            journal,
            results,
            torn_bytes,
        })
    }

    /// Appends `line` and a newline, and syncs the file.
    pub fn append(&mut self, line: &str) -> Result<()> {
        let mut bytes = Vec::with_capacity(line.len() + 1);
        bytes.extend_from_slice(line.as_bytes());
        bytes.push(b'\n');
        self.file
            .write_all(&bytes)
            .map_err(io(&self.path, "append to it"))?;
        self.file.sync_data().map_err(io(&self.path, "sync it"))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The lines of `bytes` that end with a newline (without it).
fn complete_lines(bytes: &[u8]) -> Vec<&[u8]> {
    let mut lines: Vec<&[u8]> = bytes.split(|b| *b == b'\n').collect();
    // The piece after the last newline: empty, or a line torn mid-write.
    lines.pop();
    lines
}
