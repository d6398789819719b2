//! The one rule for every file a command writes (README, "Files"):
//!
//! - an existing output is never replaced unless `--force` is given (the message names
//!   the file and says `--force`);
//! - an output that is one of the command's inputs is refused, and so is one that is
//!   not a regular file (a directory, a device, a FIFO, a symbolic link), even with
//!   `--force`;
//! - a file appears only when complete: it is written under a temporary name beside
//!   its destination and renamed over it at the end, so that a failure leaves neither a
//!   half-written file nor a clobbered one.
//!
//! A folder of results (`demo --out-dir`, `lab report --out`) holding a previous run's
//! files is refused the same way unless `--force`; each file in it is written as above.
//!
//! The one exception to "only when complete" is a live recording (`record`, `up
//! --record`): it is written in place, chunk by chunk, so that a crash leaves the
//! chunks `vibrocomp log recover` restores. The overwrite rule holds for it too.
//!
//! The checks are the log library's (`vibro_log::output`), shared with `log import`.

use anyhow::Context;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use vibro_log::output::{check_output, PartFile};

/// The help line of every `--force` flag.
pub const FORCE_HELP: &str = "Replace output files that exist (never an input, a directory, a device or a link); without it an existing output is refused";

/// Refuses `out` unless it may be written ([module rules](self)): call it for every
/// output before the command does any work.
pub fn check(out: &Path, inputs: &[&Path], force: bool) -> anyhow::Result<()> {
    check_output(out, inputs, force)?;
    Ok(())
}

/// Writes `out` through `write`, which gets the temporary path to create; renames it
/// over `out` when `write` succeeded (a failure removes it). `out` was [`check`]ed;
/// without `force`, an `out` that appeared since is not replaced either.
pub fn write_with<T>(
    out: &Path,
    force: bool,
    write: impl FnOnce(&Path) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let part = PartFile::beside(out);
    let value = write(part.path())?;
    if !force && std::fs::symlink_metadata(out).is_ok() {
        anyhow::bail!(
            "output {}: appeared while it was being written; pass --force to overwrite it",
            out.display()
        );
    }
    part.commit(out)?;
    Ok(value)
}

/// Writes `out` through a buffered writer ([`write_with`]), flushed and synced before
/// the rename.
pub fn write_file(
    out: &Path,
    force: bool,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    write_with(out, force, |tmp| {
        let file = std::fs::File::create(tmp)
            .with_context(|| format!("{}: cannot create", out.display()))?;
        let mut w = std::io::BufWriter::new(file);
        write(&mut w)?;
        w.flush()
            .and_then(|()| w.get_ref().sync_all())
            .with_context(|| format!("{}: cannot write", out.display()))?;
        Ok(())
    })
}

/// Writes `bytes` to `out` ([`write_with`]).
pub fn write_bytes(out: &Path, force: bool, bytes: &[u8]) -> anyhow::Result<()> {
    write_file(out, force, |w| {
        w.write_all(bytes)
            .with_context(|| format!("{}: cannot write", out.display()))
    })
}

/// A folder of results: created if missing; refused if it is not a folder, or (without
/// `force`) if it holds any of `files` from a previous run.
pub fn check_dir(dir: &Path, files: &[&str], force: bool) -> anyhow::Result<()> {
    match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => anyhow::bail!("output folder {}: cannot inspect it: {e}", dir.display()),
        Ok(m) if !m.is_dir() => anyhow::bail!(
            "output folder {}: exists and is not a folder",
            dir.display()
        ),
        Ok(_) => {}
    }
    let previous: Vec<&str> = files
        .iter()
        .copied()
        .filter(|f| std::fs::symlink_metadata(dir.join(f)).is_ok())
        .collect();
    if !previous.is_empty() && !force {
        anyhow::bail!(
            "output folder {} holds a previous run ({}); pass --force to overwrite it",
            dir.display(),
            previous.join(", ")
        );
    }
    for f in files {
        // Each file of the folder follows the rule of a single output.
        check(&dir.join(f), &[], force)?;
    }
    Ok(())
}

/// Creates the folder [`check_dir`] accepted.
pub fn create_dir(dir: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    Ok(dir.to_path_buf())
}

/// Refuses a recording's path (written in place, module docs) that exists as a regular
/// file unless `force`, or that is one of `inputs`. Anything else (a device, a missing
/// folder) is left to the recorder, which says why it cannot write there.
pub fn check_recording(out: &Path, inputs: &[&Path], force: bool) -> anyhow::Result<()> {
    for input in inputs {
        if vibro_log::output::same_file(input, out) {
            anyhow::bail!(
                "output {} is the input {}: write to another file",
                out.display(),
                input.display()
            );
        }
    }
    let regular = std::fs::symlink_metadata(out).is_ok_and(|m| m.file_type().is_file());
    if regular && !force {
        anyhow::bail!(
            "output {}: exists; pass --force to overwrite it",
            out.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_nothing_and_an_existing_file_needs_force() {
        let dir = std::env::temp_dir().join(format!("vibrocomp-files-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("out.csv");
        let failed = write_file(&out, false, |w| {
            w.write_all(b"half")?;
            anyhow::bail!("stopped")
        });
        assert!(failed.is_err());
        assert_eq!(
            std::fs::read_dir(&dir).unwrap().count(),
            0,
            "a part file left"
        );
        write_bytes(&out, false, b"one").unwrap();
        let e = check(&out, &[], false).unwrap_err().to_string();
        assert!(e.contains("out.csv") && e.contains("--force"), "{e}");
        check(&out, &[], true).unwrap();
        write_bytes(&out, true, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "two");
        let e = check_dir(&dir, &["out.csv", "x"], false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("previous run (out.csv)") && e.contains("--force"),
            "{e}"
        );
        check_dir(&dir, &["out.csv"], true).unwrap();
        check_dir(&dir.join("new"), &["out.csv"], false).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
