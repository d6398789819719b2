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

/// What stands at an output path, as the temporary file renamed over it would see it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Regular,
    Directory,
    /// Not followed: `rename` replaces the link itself, not the file it points to.
    Symlink,
    Fifo,
    CharDevice,
    BlockDevice,
    Socket,
    Other,
}

impl Kind {
    /// Why an output of this kind is refused, even with `--force`.
    fn refusal(self, out: &Path) -> String {
        let special = |what: &str| {
            format!(
                "is {what}, not a regular file: refused even with --force (the output would replace it with a regular file)"
            )
        };
        match self {
            Kind::Regular => String::new(),
            Kind::Directory => "is a directory, not a file".to_string(),
            Kind::Symlink => {
                let target = std::fs::read_link(out).map_or_else(
                    |e| format!("an unreadable target ({e})"),
                    |t| t.display().to_string(),
                );
                format!(
                    "is a symbolic link to {target}: refused, not followed (the output would replace the link, not the file it points to); name the target itself"
                )
            }
            Kind::Fifo => special("a FIFO (named pipe)"),
            Kind::CharDevice => special("a character device"),
            Kind::BlockDevice => special("a block device"),
            Kind::Socket => special("a socket"),
            Kind::Other => special("a special file"),
        }
    }
}

/// The kind of what exists at `path` without following a last symbolic link, or
/// `None` if nothing does.
fn existing_kind(path: &Path) -> std::io::Result<Option<Kind>> {
    let meta = match std::fs::symlink_metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e),
    };
    let t = meta.file_type();
    let kind = if t.is_file() {
        Kind::Regular
    } else if t.is_dir() {
        Kind::Directory
    } else if t.is_symlink() {
        Kind::Symlink
    } else {
        special_kind(&t)
    };
    Ok(Some(kind))
}

#[cfg(unix)]
fn special_kind(t: &std::fs::FileType) -> Kind {
    use std::os::unix::fs::FileTypeExt;
    if t.is_fifo() {
        Kind::Fifo
    } else if t.is_char_device() {
        Kind::CharDevice
    } else if t.is_block_device() {
        Kind::BlockDevice
    } else if t.is_socket() {
        Kind::Socket
    } else {
        Kind::Other
    }
}

#[cfg(not(unix))]
fn special_kind(_: &std::fs::FileType) -> Kind {
    Kind::Other
}

/// Refuses an output that exists (without `force`), is a directory, is in a folder that
/// does not exist, or is one of the inputs; and, even with `force`, one that is not a
/// regular file: a device (`/dev/full`), a FIFO, a socket, or a symbolic link, which
/// the temporary file renamed over it would replace (a link is not followed).
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
    let exists = match existing_kind(out) {
        Ok(None) => false,
        Ok(Some(Kind::Regular)) => true,
        Ok(Some(kind)) => return Err(refused(kind.refusal(out))),
        Err(e) => return Err(refused(format!("cannot inspect it: {e}"))),
    };
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
    if exists && !force {
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

    /// Renames the complete file to `out`, unless something other than a regular file
    /// appeared there since [`check_output`] (the rename would replace it).
    pub fn commit(mut self, out: &Path) -> Result<()> {
        if let Ok(Some(kind)) = existing_kind(out) {
            if kind != Kind::Regular {
                return Err(Error::OutputFile {
                    path: out.to_path_buf(),
                    problem: kind.refusal(out),
                });
            }
        }
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

    /// `--force` replaces a regular file only: a FIFO, a socket, a directory and a
    /// symbolic link are refused with what they are, and stay what they were, also when
    /// one appears between the check and the commit.
    #[cfg(unix)]
    #[test]
    fn force_never_replaces_what_is_not_a_regular_file() {
        use std::os::unix::fs::FileTypeExt;
        let dir = std::env::temp_dir().join(format!("vibro-log-special-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let input = dir.join("in.csv");
        std::fs::write(&input, "x").unwrap();
        let fifo = dir.join("fifo.mcap");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let socket = dir.join("socket.mcap");
        let _listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
        let target = dir.join("target.mcap");
        std::fs::write(&target, "kept").unwrap();
        let link = dir.join("link.mcap");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let msg = |out: &Path| check_output(out, &[&input], true).unwrap_err().to_string();
        assert_eq!(
            msg(&fifo),
            format!("output {}: is a FIFO (named pipe), not a regular file: refused even with --force (the output would replace it with a regular file)", fifo.display())
        );
        assert!(
            msg(&socket).contains(": is a socket, not a regular file: refused even with --force")
        );
        assert!(msg(&dir).ends_with(": is a directory, not a file"));
        assert_eq!(
            msg(&link),
            format!("output {}: is a symbolic link to {}: refused, not followed (the output would replace the link, not the file it points to); name the target itself", link.display(), target.display())
        );
        // A FIFO made after the check is not replaced by the commit either.
        let late = dir.join("late.mcap");
        assert!(check_output(&late, &[&input], true).is_ok());
        let part = PartFile::beside(&late);
        std::fs::write(part.path(), "log").unwrap();
        let made = std::process::Command::new("mkfifo")
            .arg(&late)
            .status()
            .unwrap();
        assert!(made.success());
        let err = part.commit(&late).unwrap_err().to_string();
        assert!(err.contains("is a FIFO"), "{err}");
        for (path, is) in [
            (&fifo, "fifo"),
            (&late, "fifo"),
            (&socket, "socket"),
            (&link, "link"),
        ] {
            let t = std::fs::symlink_metadata(path).unwrap().file_type();
            let kept = match is {
                "fifo" => t.is_fifo(),
                "socket" => t.is_socket(),
                _ => t.is_symlink(),
            };
            assert!(kept, "{} is no longer a {is}", path.display());
        }
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
