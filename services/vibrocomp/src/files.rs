//! The one rule for every file a command writes (README, "Files"):
//!
//! - an existing output is never replaced unless `--force` is given (the message names
//!   the file and says `--force`);
//! - an output that is one of the command's inputs is refused, and so is one that is
//!   not a regular file (a directory, a device, a FIFO, a socket, a symbolic link,
//!   dangling or not: never followed), even with `--force`;
//! - a file appears only when complete: it is written under an unpredictable temporary
//!   name beside its destination and renamed over it at the end, so that a failure
//!   leaves neither a half-written file nor a clobbered one.
//!
//! A folder of results (`demo --out-dir`, `lab report --out`) is never a link, and one
//! holding a previous run's files is refused unless `--force`; each file in it is
//! written as above.
//!
//! The one exception to "only when complete" is a live recording (`record`, `up
//! --record`): it is written in place, chunk by chunk, so that a crash leaves the
//! chunks `vibrocomp log recover` restores. It is opened without following a link or
//! blocking on a FIFO, and emptied only once it is known to be a regular file.
//!
//! The rule has one home, the `vibro-files` crate, which the libraries that write
//! (the MCAP recorder, the log import and recovery, the lab's model) call too; this
//! module gives its functions to the commands with `anyhow` errors. A new writing
//! command calls these functions and adds itself to the table of the integration test
//! `file_safety::every_writing_command_keeps_the_file_rule`.

use std::io::Write as _;
use std::path::Path;

pub use vibro_files::FORCE_HELP;

/// Refuses `out` unless it may be written ([module rules](self)): call it for every
/// output before the command does any work.
pub fn check(out: &Path, inputs: &[&Path], force: bool) -> anyhow::Result<()> {
    Ok(vibro_files::check_output(out, inputs, force)?)
}

/// Writes `out` through a buffered writer on its part file, flushed and synced before
/// the rename ([`vibro_files::write_with`]). `out` was [`check`]ed; without `force`,
/// an `out` that appeared since is not replaced either.
pub fn write_file(
    out: &Path,
    force: bool,
    write: impl FnOnce(&mut std::io::BufWriter<&std::fs::File>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    vibro_files::write_with(out, force, |part| {
        let mut w = std::io::BufWriter::new(part.file());
        write(&mut w)?;
        w.flush().map_err(|e| vibro_files::Error::Io {
            path: out.to_path_buf(),
            action: "write it",
            source: e,
        })?;
        anyhow::Ok(())
    })
}

/// Writes `bytes` to `out` ([`write_file`]).
pub fn write_bytes(out: &Path, force: bool, bytes: &[u8]) -> anyhow::Result<()> {
    Ok(vibro_files::write_bytes(out, force, bytes)?)
}

/// A folder of results: refused if it is not a folder (a link to one included), or
/// (without `force`) if it holds any of `files` from a previous run.
pub fn check_dir(dir: &Path, files: &[&str], force: bool) -> anyhow::Result<()> {
    Ok(vibro_files::check_dir(dir, files, force)?)
}

/// Creates the folder [`check_dir`] accepted.
pub fn create_dir(dir: &Path) -> anyhow::Result<()> {
    Ok(vibro_files::create_dir(dir)?)
}

/// Refuses a recording's path (written in place, module docs) as any output, and one
/// this user cannot write, before any port opens or any service starts
/// ([`vibro_files::check_in_place`]); `record` and `up --record` both call it.
pub fn check_recording(out: &Path, inputs: &[&Path], force: bool) -> anyhow::Result<()> {
    Ok(vibro_files::check_in_place(out, inputs, force)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_nothing_and_an_existing_file_needs_force() {
        let dir = tempfile::TempDir::new().unwrap();
        let out = dir.path().join("out.csv");
        let failed = write_file(&out, false, |w| {
            w.write_all(b"half")?;
            anyhow::bail!("stopped")
        });
        assert!(failed.is_err());
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "a part file left"
        );
        write_bytes(&out, false, b"one").unwrap();
        let e = check(&out, &[], false).unwrap_err().to_string();
        assert!(e.contains("out.csv") && e.contains("--force"), "{e}");
        check(&out, &[], true).unwrap();
        write_file(&out, true, |w| Ok(w.write_all(b"two")?)).unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "two");
        let e = check_dir(dir.path(), &["out.csv", "x"], false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("previous run (out.csv)") && e.contains("--force"),
            "{e}"
        );
        check_dir(dir.path(), &["out.csv"], true).unwrap();
        check_dir(&dir.path().join("new"), &["out.csv"], false).unwrap();
    }
}
