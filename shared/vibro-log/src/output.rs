//! Writing a log file safely: the checks on an output path, and a file written under a
//! temporary name that replaces its destination only when complete (used by the CSV
//! import, and by `vibrocomp log recover`).

use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// Whether `a` and `b` name the same existing file (also through links).
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Refuses an output that exists (without `force`), is a directory, is in a folder that
/// does not exist, or is one of the inputs.
pub fn check_output(out: &Path, inputs: &[&Path], force: bool) -> Result<()> {
    let refused = |problem: String| Error::OutputFile {
        path: out.to_path_buf(),
        problem,
    };
    if out.file_name().is_none() {
        return Err(refused("must name a file".to_string()));
    }
    for input in inputs {
        if same_file(input, out) {
            return Err(Error::OutputIsInput {
                out: out.to_path_buf(),
                input: input.to_path_buf(),
            });
        }
    }
    if out.is_dir() {
        return Err(refused("is a directory, not a file".to_string()));
    }
    let folder = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !folder.is_dir() {
        return Err(refused(format!(
            "its folder {} does not exist",
            folder.display()
        )));
    }
    if out.exists() && !force {
        return Err(refused("exists; pass --force to overwrite it".to_string()));
    }
    Ok(())
}

/// A file written under a temporary name beside its destination and renamed over it
/// when complete, so that a failed command leaves neither a half-written log nor a
/// clobbered one. Removed on drop unless [`PartFile::commit`] ran.
#[derive(Debug)]
pub struct PartFile {
    path: PathBuf,
    committed: bool,
}

impl PartFile {
    /// A temporary name beside `out`: `.{name}.{pid}.part`.
    pub fn beside(out: &Path) -> PartFile {
        let name = out
            .file_name()
            .map_or_else(|| "log".into(), |n| n.to_string_lossy().into_owned());
        PartFile {
            path: out.with_file_name(format!(".{name}.{}.part", std::process::id())),
            committed: false,
        }
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Renames the complete file to `out`.
    pub fn commit(mut self, out: &Path) -> Result<()> {
        std::fs::rename(&self.path, out).map_err(|source| Error::Rename {
            from: self.path.clone(),
            to: out.to_path_buf(),
            source,
        })?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for PartFile {
    fn drop(&mut self) {
        if !self.committed {
            // Best effort: the command is failing already and reports why.
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_is_refused_with_its_reason() {
        let dir = std::env::temp_dir().join(format!("vibro-log-output-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let input = dir.join("in.csv");
        std::fs::write(&input, "x").unwrap();
        let msg = |out: &Path, force| check_output(out, &[&input], force).unwrap_err().to_string();
        assert_eq!(
            msg(&input, true),
            format!(
                "output {} is the input {}: write to another file (the input is read while the output is written)",
                input.display(),
                input.display()
            )
        );
        assert!(msg(&dir, true).ends_with(": is a directory, not a file"));
        assert!(msg(&dir.join("no/x.mcap"), true).contains("does not exist"));
        let out = dir.join("out.mcap");
        std::fs::write(&out, "x").unwrap();
        assert_eq!(
            msg(&out, false),
            format!(
                "output {}: exists; pass --force to overwrite it",
                out.display()
            )
        );
        assert!(check_output(&out, &[&input], true).is_ok());
        // An uncommitted part file is removed.
        let part = PartFile::beside(&out);
        std::fs::write(part.path(), "y").unwrap();
        let kept = part.path().to_path_buf();
        drop(part);
        assert!(!kept.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
