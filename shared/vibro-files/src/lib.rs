//! # vibro-files: the file rule
//!
//! One job: every file a vibrocomp command or library writes where a user (or anyone
//! else) can name it is opened here, by the rule of the README's "Files" section:
//!
//! - an existing output is never replaced unless `--force` is given (the message names
//!   the file and says `--force`);
//! - an output that is one of the command's inputs is refused, and so is one that is
//!   not a regular file of its own (a directory, a device, a FIFO, a socket, a symbolic
//!   link: dangling or not), even with `--force`. A link is never followed, so a link
//!   another user planted in a shared folder such as `/tmp` cannot turn a command run
//!   as root into a write to the file it points to; a dangling link never creates its
//!   target; a FIFO never blocks the command;
//! - a file appears only when complete: [`PartFile`] writes it under an unpredictable
//!   temporary name beside its destination (created with `O_EXCL`, so never through a
//!   planted link) and renames it over the destination at the end, without replacing
//!   an output that appeared meanwhile unless `--force`;
//! - a live recording (`record`, `up --record`), written in place chunk by chunk so that
//!   a crash leaves what `vibrocomp log recover` restores, is opened by
//!   [`create_in_place`]: `O_NOFOLLOW | O_NONBLOCK | O_CREAT` (plus `O_EXCL` without
//!   `--force`), and truncated only after `fstat` showed a regular file;
//! - a folder of results ([`check_dir`], [`create_dir`]) is never a link, and its files
//!   follow the rule of single outputs.
//!
//! A command calls [`check_output`] (or [`check_in_place`] for a recording, or
//! [`check_dir`]) for every output before it does any work, then writes through
//! [`write_with`] / [`write_bytes`] / [`PartFile`] or [`create_in_place`]. A new writing
//! command (`log compensate`, the batch outputs) calls the same functions; nothing else
//! in the workspace opens an output for writing. Logs a process appends to (a
//! supervised service's stderr) are opened by [`open_append`], which refuses the same
//! things without the `--force` rule (appending never loses what is there); a lock
//! file by [`open_lock`].
//!
//! The rule is checked where the file is opened, not only before: a check followed by
//! `File::create` would still follow a link planted between the two.

mod folder;
mod in_place;
mod kind;
mod whole;

use std::path::PathBuf;

pub use folder::{check_dir, create_dir};
pub use in_place::{check_in_place, create_in_place, open_append, open_lock};
pub use whole::{check_output, same_file, write_bytes, write_with, PartFile};

/// What the file rule refuses, and the I/O errors of writing an output.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An existing output, without `--force` (a caller may map it to its own "file
    /// exists" error, as the Python package does).
    #[error("output {path}: exists; pass --force to overwrite it")]
    Exists { path: PathBuf },
    /// An output refused: it is not a regular file of its own, or appeared while it
    /// was written (`problem` says what it is and why it is refused).
    #[error("output {path}: {problem}")]
    Refused { path: PathBuf, problem: String },
    /// A folder of results refused.
    #[error("output folder {path}: {problem}")]
    FolderRefused { path: PathBuf, problem: String },
    /// An output file that is one of the inputs.
    #[error("output {out} is the input {input}: write to another file (the input is read while the output is written)")]
    IsInput { out: PathBuf, input: PathBuf },
    /// An output that cannot be created, written or inspected; `source` says why.
    #[error("output {path}: cannot {action}")]
    Io {
        path: PathBuf,
        /// What failed: "create it", "write it", "create a temporary file beside it".
        action: &'static str,
        source: std::io::Error,
    },
    /// A complete file that cannot take its final name.
    #[error("cannot rename {from} to {to}")]
    Rename {
        from: PathBuf,
        to: PathBuf,
        source: std::io::Error,
    },
}

pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    fn refused(path: &std::path::Path, problem: impl Into<String>) -> Error {
        Error::Refused {
            path: path.to_path_buf(),
            problem: problem.into(),
        }
    }

    fn exists(path: &std::path::Path) -> Error {
        Error::Exists {
            path: path.to_path_buf(),
        }
    }

    fn io(path: &std::path::Path, action: &'static str, source: std::io::Error) -> Error {
        Error::Io {
            path: path.to_path_buf(),
            action,
            source,
        }
    }
}

/// The help line of every `--force` flag.
pub const FORCE_HELP: &str = "Replace output files that exist (never an input, a directory, a device, a FIFO or a link); without it an existing output is refused";
