//! Whole-file outputs: checked before any work, written under a temporary name beside
//! the destination and renamed over it when complete.

use std::io::Write as _;
use std::path::Path;

use crate::kind::{existing_kind, Kind};
use crate::{Error, Result};

/// Whether `a` and `b` name the same existing file (also through links).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
        return x.dev() == y.dev() && x.ino() == y.ino();
    }
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// The folder an output is written in (`.` for a bare name).
pub(crate) fn folder_of(out: &Path) -> &Path {
    out.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Refuses an output that exists (without `force`), is in a folder that does not
/// exist, or is one of `inputs`; and, even with `force`, one that is not a regular
/// file: a directory, a device (`/dev/null`), a FIFO, a socket, or a symbolic link
/// (dangling or not: a link is never followed). Call it for every output before the
/// command does any work; the write itself ([`PartFile`], [`crate::create_in_place`])
/// holds to the same rule, whatever appeared in between.
pub fn check_output(out: &Path, inputs: &[&Path], force: bool) -> Result<()> {
    if out.file_name().is_none() {
        return Err(Error::refused(out, "must name a file"));
    }
    for input in inputs {
        if same_file(input, out) {
            return Err(Error::IsInput {
                out: out.to_path_buf(),
                input: input.to_path_buf(),
            });
        }
    }
    let exists = match existing_kind(out) {
        Ok(None) => false,
        Ok(Some(Kind::Regular)) => true,
        Ok(Some(kind)) => return Err(Error::refused(out, kind.refusal(out))),
        Err(e) => return Err(Error::io(out, "inspect it", e)),
    };
    let folder = folder_of(out);
    if !folder.is_dir() {
        return Err(Error::refused(
            out,
            format!("its folder {} does not exist", folder.display()),
        ));
    }
    if exists && !force {
        return Err(Error::exists(out));
    }
    Ok(())
}

/// Longest part of an output's name kept in its temporary name, in bytes: the
/// temporary name adds a dot, 12 random characters and `.part`, and a name may hold
/// 255 bytes.
const NAME_BYTES: usize = 200;

/// A file written under a temporary name beside its destination and renamed over it
/// when complete ([`PartFile::commit`]), so that a failed command leaves neither a
/// half-written output nor a clobbered one. Removed on drop unless committed.
///
/// The temporary file is created with `O_CREAT | O_EXCL` under an unpredictable name
/// (`.{name}.{12 random characters}.part`): a name another user could guess (the pid)
/// could be planted as a link in a shared folder, and the write would follow it.
#[derive(Debug)]
pub struct PartFile {
    temp: tempfile::NamedTempFile,
}

impl PartFile {
    /// Creates the temporary file beside `out` (mode 0666 less the umask, as any new
    /// output).
    pub fn beside(out: &Path) -> Result<PartFile> {
        use std::os::unix::fs::PermissionsExt;
        let Some(name) = out.file_name() else {
            return Err(Error::refused(out, "must name a file"));
        };
        let name = name.to_string_lossy();
        let mut end = name.len().min(NAME_BYTES);
        while !name.is_char_boundary(end) {
            end -= 1;
        }
        let temp = tempfile::Builder::new()
            .prefix(&format!(".{}.", &name[..end]))
            .suffix(".part")
            .rand_bytes(12)
            .permissions(std::fs::Permissions::from_mode(0o666))
            .tempfile_in(folder_of(out))
            .map_err(|e| Error::io(out, "create a temporary file beside it", e))?;
        Ok(PartFile { temp })
    }

    /// Where it is written: for a writer that opens it by name (the MCAP recorder,
    /// through [`crate::create_in_place`] with `force`, which never follows a link).
    pub fn path(&self) -> &Path {
        self.temp.path()
    }

    /// The file, open for writing.
    pub fn file(&self) -> &std::fs::File {
        self.temp.as_file()
    }

    /// Syncs the complete file and renames it to `out`. With `force`, it replaces a
    /// regular file at `out`, never anything else that appeared there since
    /// [`check_output`]; without, it replaces nothing (`RENAME_NOREPLACE`: an output
    /// that appeared meanwhile is refused, not overwritten).
    pub fn commit(self, out: &Path, force: bool) -> Result<()> {
        self.temp
            .as_file()
            .sync_all()
            .map_err(|e| Error::io(out, "write it", e))?;
        let from = self.temp.path().to_path_buf();
        let persisted = if force {
            if let Ok(Some(kind)) = existing_kind(out) {
                if kind != Kind::Regular {
                    return Err(Error::refused(out, kind.refusal(out)));
                }
            }
            self.temp.persist(out)
        } else {
            self.temp.persist_noclobber(out)
        };
        match persisted {
            Ok(_) => Ok(()),
            Err(e) if !force && e.error.kind() == std::io::ErrorKind::AlreadyExists => {
                let problem = match existing_kind(out) {
                    Ok(Some(kind)) if kind != Kind::Regular => kind.refusal(out),
                    _ => "appeared while it was being written; pass --force to overwrite it"
                        .to_string(),
                };
                Err(Error::refused(out, problem))
            }
            // The part file is removed when the error (which holds it) drops.
            Err(e) => Err(Error::Rename {
                from,
                to: out.to_path_buf(),
                source: e.error,
            }),
        }
    }
}

/// Writes `out` through `write`, which gets the part file to fill ([`PartFile`]),
/// and commits it when `write` succeeded (a failure removes it). `out` is checked
/// first ([`check_output`], without inputs: a command checks those before its work).
pub fn write_with<T, E: From<Error>>(
    out: &Path,
    force: bool,
    write: impl FnOnce(&PartFile) -> std::result::Result<T, E>,
) -> std::result::Result<T, E> {
    check_output(out, &[], force)?;
    let part = PartFile::beside(out)?;
    let value = write(&part)?;
    part.commit(out, force)?;
    Ok(value)
}

/// Writes `bytes` to `out` ([`write_with`]).
pub fn write_bytes(out: &Path, force: bool, bytes: &[u8]) -> Result<()> {
    write_with(out, force, |part| {
        part.file()
            .write_all(bytes)
            .map_err(|e| Error::io(out, "write it", e))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::{symlink, FileTypeExt};

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn an_output_is_refused_with_its_reason() {
        let dir = tempfile::TempDir::new().unwrap();
        let input = dir.path().join("in.csv");
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
        assert!(msg(dir.path(), true).ends_with(": is a directory, not a file"));
        assert!(msg(&dir.path().join("no/x.mcap"), true).contains("does not exist"));
        let out = dir.path().join("out.mcap");
        std::fs::write(&out, "x").unwrap();
        assert_eq!(
            msg(&out, false),
            format!(
                "output {}: exists; pass --force to overwrite it",
                out.display()
            )
        );
        assert!(check_output(&out, &[&input], true).is_ok());
        assert!(msg(Path::new("/dev/null"), true)
            .contains(": is a character device, not a regular file: refused even with --force"));
    }

    /// `--force` replaces a regular file only: a FIFO, a socket, a directory and a
    /// symbolic link are refused with what they are, and stay what they were, also when
    /// one appears between the check and the commit.
    #[test]
    fn force_never_replaces_what_is_not_a_regular_file() {
        let dir = tempfile::TempDir::new().unwrap();
        let p = |n: &str| dir.path().join(n);
        let fifo = p("fifo.mcap");
        assert_eq!(unsafe_mkfifo(&fifo), 0);
        let socket = p("socket.mcap");
        let _listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
        let target = p("target.mcap");
        std::fs::write(&target, "kept").unwrap();
        let link = p("link.mcap");
        symlink(&target, &link).unwrap();
        let msg = |out: &Path| check_output(out, &[], true).unwrap_err().to_string();
        assert_eq!(
            msg(&fifo),
            format!("output {}: is a FIFO (named pipe), not a regular file: refused even with --force (an output is only ever a regular file of its own)", fifo.display())
        );
        assert!(
            msg(&socket).contains(": is a socket, not a regular file: refused even with --force")
        );
        assert_eq!(
            msg(&link),
            format!("output {}: is a symbolic link to {}: refused, not followed (a link may lead where this command must not write); name the target itself", link.display(), target.display())
        );
        // A FIFO made after the check is not replaced by the commit either.
        let late = p("late.mcap");
        assert!(check_output(&late, &[], true).is_ok());
        let part = PartFile::beside(&late).unwrap();
        part.file().write_all(b"log").unwrap();
        assert_eq!(unsafe_mkfifo(&late), 0);
        let err = part.commit(&late, true).unwrap_err().to_string();
        assert!(err.contains("is a FIFO"), "{err}");
        let t = |path: &Path| std::fs::symlink_metadata(path).unwrap().file_type();
        assert!(t(&fifo).is_fifo() && t(&late).is_fifo());
        assert!(t(&socket).is_socket() && t(&link).is_symlink());
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept");
        // No part file left.
        assert_eq!(
            names(dir.path()),
            [
                "fifo.mcap",
                "late.mcap",
                "link.mcap",
                "socket.mcap",
                "target.mcap"
            ]
        );
    }

    fn unsafe_mkfifo(path: &Path) -> i32 {
        use std::os::unix::ffi::OsStrExt;
        let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
        // SAFETY: a NUL-terminated path.
        unsafe { libc::mkfifo(c.as_ptr(), 0o600) }
    }

    /// The part file's name cannot be guessed (two of them differ beyond the pid), it
    /// is made with O_EXCL, and a failed write leaves nothing.
    #[test]
    fn a_part_file_is_unpredictable_and_a_failure_leaves_nothing() {
        let dir = tempfile::TempDir::new().unwrap();
        let out = dir.path().join("x.mcap");
        let (a, b) = (
            PartFile::beside(&out).unwrap(),
            PartFile::beside(&out).unwrap(),
        );
        let name = |p: &PartFile| p.path().file_name().unwrap().to_string_lossy().into_owned();
        assert!(name(&a).starts_with(".x.mcap.") && name(&a).ends_with(".part"));
        assert_ne!(name(&a), name(&b));
        drop((a, b));
        let failed: std::result::Result<(), Error> = write_with(&out, false, |part| {
            part.file().write_all(b"half").unwrap();
            Err(Error::refused(&out, "stopped"))
        });
        assert!(failed.is_err());
        assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
        write_bytes(&out, false, b"one").unwrap();
        let e = write_bytes(&out, false, b"two").unwrap_err().to_string();
        assert!(e.contains("x.mcap") && e.contains("--force"), "{e}");
        write_bytes(&out, true, b"two").unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "two");
        assert_eq!(names(dir.path()), ["x.mcap"]);
    }

    /// Without `--force`, an output that appears while the part file is written is
    /// not replaced (RENAME_NOREPLACE), whatever it is.
    #[test]
    fn without_force_the_commit_replaces_nothing_that_appeared() {
        let dir = tempfile::TempDir::new().unwrap();
        let out = dir.path().join("x.csv");
        let target = dir.path().join("target");
        std::fs::write(&target, "kept").unwrap();
        let part = PartFile::beside(&out).unwrap();
        part.file().write_all(b"new").unwrap();
        std::fs::write(&out, "theirs").unwrap();
        let e = part.commit(&out, false).unwrap_err().to_string();
        assert!(
            e.ends_with("appeared while it was being written; pass --force to overwrite it"),
            "{e}"
        );
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "theirs");
        std::fs::remove_file(&out).unwrap();
        let part = PartFile::beside(&out).unwrap();
        symlink(&target, &out).unwrap();
        let e = part.commit(&out, false).unwrap_err().to_string();
        assert!(e.contains("is a symbolic link"), "{e}");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept");
        assert_eq!(names(dir.path()), ["target", "x.csv"]);
    }

    /// A planted link named like the part file of the old scheme
    /// (`.{name}.{pid}.part`) is neither followed nor replaced.
    #[test]
    fn a_link_at_the_old_predictable_part_name_is_not_followed() {
        let dir = tempfile::TempDir::new().unwrap();
        let out = dir.path().join("x.mcap");
        let target = dir.path().join("target");
        std::fs::write(&target, "kept").unwrap();
        let planted = dir
            .path()
            .join(format!(".x.mcap.{}.part", std::process::id()));
        symlink(&target, &planted).unwrap();
        write_bytes(&out, false, b"log").unwrap();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept");
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "log");
        assert!(std::fs::symlink_metadata(&planted)
            .unwrap()
            .file_type()
            .is_symlink());
    }
}
