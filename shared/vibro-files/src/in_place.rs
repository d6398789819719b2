//! Files written in place: a live recording (chunk by chunk, so that a crash leaves
//! what `vibrocomp log recover` restores) and the logs a process appends to.
//!
//! Each is opened with `O_NOFOLLOW` (a link, dangling or not, fails with `ELOOP`: its
//! target is neither written nor created) and `O_NONBLOCK` (a FIFO without a reader
//! fails at once with `ENXIO` instead of blocking in `open()`, one with a reader opens
//! and is refused by the `fstat` that follows). Only after `fstat` shows a regular file
//! of its own is it truncated (`ftruncate`) or written; `O_NONBLOCK` is then cleared.

use std::fs::{File, OpenOptions};
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::os::unix::io::AsRawFd;
use std::path::Path;

use crate::kind::{existing_kind, Kind};
use crate::whole::{check_output, folder_of};
use crate::{Error, Result};

/// Opens `path` for a live recording written in place: created if missing; without
/// `force` an existing file is refused (`O_EXCL`); with it, an existing regular file is
/// emptied. A symbolic link (dangling or not), a FIFO, a device, a socket or a
/// directory is refused either way, without following, blocking or truncating; so is
/// a file with several names (hard links), and a file another user owns in a shared
/// sticky folder such as `/tmp` (what is written would be theirs to read).
pub fn create_in_place(path: &Path, force: bool) -> Result<File> {
    let mut options = OpenOptions::new();
    options
        .write(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    if force {
        options.create(true);
    } else {
        options.create_new(true);
    }
    let file = open(path, &options, force)?;
    if force {
        file.set_len(0)
            .map_err(|e| Error::io(path, "empty it", e))?;
    }
    Ok(file)
}

/// Opens the log `path` for appending (a supervised process's stderr): created if
/// missing, never emptied; refused as [`create_in_place`] refuses, without the
/// `--force` rule (appending keeps what is there).
pub fn open_append(path: &Path) -> Result<File> {
    let mut options = OpenOptions::new();
    options
        .append(true)
        .create(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    open(path, &options, true)
}

/// Opens the lock file `path` (read and write, created if missing, never emptied here):
/// a file several processes open by a name anyone may guess, such as the prefix claim
/// of `vibrocomp up` in the temporary folder. Refused as [`create_in_place`] refuses:
/// a planted link is not followed, a FIFO does not block.
pub fn open_lock(path: &Path) -> Result<File> {
    let mut options = OpenOptions::new();
    options
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    open(path, &options, true)
}

/// Refuses a recording's path as [`check_output`] refuses any output (with `inputs`
/// and `force`), then makes sure this user can write it without changing it: an
/// existing file is opened for writing (not emptied), a missing one is created and
/// removed. For `record` and `up --record`, before any port opens or any service
/// starts; the recorder then opens it with [`create_in_place`].
pub fn check_in_place(path: &Path, inputs: &[&Path], force: bool) -> Result<()> {
    check_output(path, inputs, force)?;
    match existing_kind(path) {
        Ok(None) => {
            drop(create_in_place(path, false)?);
            std::fs::remove_file(path).map_err(|e| Error::io(path, "remove the probe", e))
        }
        _ => {
            let mut options = OpenOptions::new();
            options
                .write(true)
                .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
            open(path, &options, force).map(drop)
        }
    }
}

/// Opens `path` with `options` (which carry `O_NOFOLLOW | O_NONBLOCK`), refuses what
/// is not a regular file of its own, and clears `O_NONBLOCK`.
fn open(path: &Path, options: &OpenOptions, force: bool) -> Result<File> {
    let file = options.open(path).map_err(|e| open_error(path, e, force))?;
    let meta = file
        .metadata()
        .map_err(|e| Error::io(path, "inspect it", e))?;
    let kind = Kind::of(meta.file_type());
    if kind != Kind::Regular {
        return Err(Error::refused(path, kind.refusal(path)));
    }
    if meta.nlink() > 1 {
        return Err(Error::refused(
            path,
            format!(
                "has {} names (hard links): refused, written in place it would change the others too; remove it or name another file",
                meta.nlink()
            ),
        ));
    }
    if let Some(problem) = foreign_in_sticky_folder(path, &meta) {
        return Err(Error::refused(path, problem));
    }
    clear_nonblocking(&file).map_err(|e| Error::io(path, "open it", e))?;
    Ok(file)
}

/// Why opening `path` failed, as the rule says it: a link (`ELOOP` under
/// `O_NOFOLLOW`), an existing file without `--force` (`EEXIST` under `O_EXCL`), a FIFO
/// without a reader (`ENXIO` under `O_NONBLOCK`), a directory (`EISDIR`), a missing
/// folder; else the operating system's reason.
fn open_error(path: &Path, e: std::io::Error, force: bool) -> Error {
    match existing_kind(path) {
        Ok(Some(Kind::Regular)) if e.kind() == std::io::ErrorKind::AlreadyExists && !force => {
            Error::exists(path)
        }
        Ok(Some(kind)) if kind != Kind::Regular => Error::refused(path, kind.refusal(path)),
        Ok(None) if !folder_of(path).is_dir() => Error::refused(
            path,
            format!("its folder {} does not exist", folder_of(path).display()),
        ),
        _ => Error::io(path, "create it", e),
    }
}

/// Why a file in a shared sticky folder (`/tmp`) that another user owns is refused,
/// if it is one: written in place, what this command writes would stay readable to
/// that user, who may also have made it a hard link. Linux's `fs.protected_regular`
/// refuses the same open when it is on; it is off on many systems.
fn foreign_in_sticky_folder(path: &Path, meta: &std::fs::Metadata) -> Option<String> {
    // SAFETY: geteuid has no preconditions.
    let me = unsafe { libc::geteuid() };
    if meta.uid() == me {
        return None;
    }
    let folder = folder_of(path);
    let folder_meta = std::fs::metadata(folder).ok()?;
    let sticky = folder_meta.mode() & libc::S_ISVTX != 0;
    if !sticky || folder_meta.uid() == meta.uid() {
        return None;
    }
    Some(format!(
        "belongs to user {} in the shared folder {} (sticky, others may write there): refused, written in place it would stay theirs; remove it or name another file",
        meta.uid(),
        folder.display()
    ))
}

/// Makes writes to `file` block again (it was opened `O_NONBLOCK` so that the open
/// itself could not).
fn clear_nonblocking(file: &File) -> std::io::Result<()> {
    let fd = file.as_raw_fd();
    // SAFETY: fcntl on a descriptor this function's caller owns, for the duration of
    // the call.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write as _;
    use std::os::unix::fs::symlink;
    use std::time::{Duration, Instant};

    fn mkfifo(path: &Path) {
        use std::os::unix::ffi::OsStrExt;
        let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    fn nonblocking(file: &File) -> bool {
        // SAFETY: fcntl on a descriptor the test owns.
        let flags = unsafe { libc::fcntl(file.as_raw_fd(), libc::F_GETFL) };
        flags & libc::O_NONBLOCK != 0
    }

    #[test]
    fn a_new_recording_is_created_and_an_existing_one_needs_force() {
        let dir = tempfile::TempDir::new().unwrap();
        let out = dir.path().join("x.mcap");
        let mut f = create_in_place(&out, false).unwrap();
        assert!(!nonblocking(&f), "O_NONBLOCK left set");
        f.write_all(b"first").unwrap();
        drop(f);
        let e = create_in_place(&out, false).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "output {}: exists; pass --force to overwrite it",
                out.display()
            )
        );
        assert_eq!(std::fs::read(&out).unwrap(), b"first");
        let f = create_in_place(&out, true).unwrap();
        assert_eq!(f.metadata().unwrap().len(), 0, "not emptied with --force");
        check_in_place(&out, &[], true).unwrap();
        let e = check_in_place(&out, &[], false).unwrap_err().to_string();
        assert!(e.ends_with("exists; pass --force to overwrite it"), "{e}");
        // The probe of a missing file leaves nothing.
        let new = dir.path().join("new.mcap");
        check_in_place(&new, &[], false).unwrap();
        assert!(!new.exists());
    }

    /// A link (to a file, or dangling) is refused with and without --force: the target
    /// keeps its bytes, a dangling target is not created.
    #[test]
    fn a_link_is_never_followed() {
        let dir = tempfile::TempDir::new().unwrap();
        let target = dir.path().join("target");
        std::fs::write(&target, "kept").unwrap();
        let link = dir.path().join("link.mcap");
        symlink(&target, &link).unwrap();
        let dangling = dir.path().join("dangling.mcap");
        let missing = dir.path().join("missing");
        symlink(&missing, &dangling).unwrap();
        for force in [false, true] {
            for (path, to) in [(&link, &target), (&dangling, &missing)] {
                for e in [
                    create_in_place(path, force).unwrap_err(),
                    open_append(path).unwrap_err(),
                    check_in_place(path, &[], force).unwrap_err(),
                ] {
                    assert_eq!(
                        e.to_string(),
                        format!("output {}: is a symbolic link to {}: refused, not followed (a link may lead where this command must not write); name the target itself", path.display(), to.display())
                    );
                }
            }
        }
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept");
        assert!(!missing.exists(), "the dangling link's target was created");
    }

    /// A FIFO is refused at once, with or without a reader, and never written.
    #[test]
    fn a_fifo_never_blocks() {
        let dir = tempfile::TempDir::new().unwrap();
        let fifo = dir.path().join("fifo.mcap");
        mkfifo(&fifo);
        let started = Instant::now();
        for force in [false, true] {
            let e = create_in_place(&fifo, force).unwrap_err().to_string();
            assert!(
                e.contains("is a FIFO (named pipe), not a regular file"),
                "{e}"
            );
        }
        assert!(open_append(&fifo).is_err());
        // With a reader the open succeeds; fstat refuses it.
        let reader = OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(&fifo)
            .unwrap();
        let e = create_in_place(&fifo, true).unwrap_err().to_string();
        assert!(e.contains("is a FIFO"), "{e}");
        drop(reader);
        assert!(started.elapsed() < Duration::from_secs(2));
    }

    /// A device is refused even with --force, and not truncated or written.
    #[test]
    fn a_device_is_refused_even_with_force() {
        for force in [false, true] {
            let e = create_in_place(Path::new("/dev/null"), force)
                .unwrap_err()
                .to_string();
            assert_eq!(e, "output /dev/null: is a character device, not a regular file: refused even with --force (an output is only ever a regular file of its own)");
        }
        assert!(open_append(Path::new("/dev/null")).is_err());
        let e = create_in_place(Path::new("/tmp"), true)
            .unwrap_err()
            .to_string();
        assert!(e.ends_with("is a directory, not a file"), "{e}");
    }

    #[test]
    fn a_file_with_two_names_is_not_written_in_place() {
        let dir = tempfile::TempDir::new().unwrap();
        let a = dir.path().join("a");
        std::fs::write(&a, "kept").unwrap();
        let b = dir.path().join("b.mcap");
        std::fs::hard_link(&a, &b).unwrap();
        let e = create_in_place(&b, true).unwrap_err().to_string();
        assert!(e.contains("has 2 names (hard links): refused"), "{e}");
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "kept");
    }

    #[test]
    fn an_appended_log_keeps_what_it_holds() {
        let dir = tempfile::TempDir::new().unwrap();
        let log = dir.path().join("x.log");
        open_append(&log).unwrap().write_all(b"one\n").unwrap();
        open_append(&log).unwrap().write_all(b"two\n").unwrap();
        assert_eq!(std::fs::read_to_string(&log).unwrap(), "one\ntwo\n");
    }

    /// As root: another user's link in a sticky folder to a root-only file is not
    /// followed, and another user's regular file there is not written in place.
    #[test]
    fn another_users_planted_files_in_a_sticky_folder_are_refused() {
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            eprintln!("not root: another user's files cannot be made; skipped");
            return;
        }
        use std::os::unix::ffi::OsStrExt;
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::TempDir::new().unwrap();
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o1777)).unwrap();
        let secret = dir.path().join("secret");
        std::fs::write(&secret, "root only").unwrap();
        std::fs::set_permissions(&secret, std::fs::Permissions::from_mode(0o600)).unwrap();
        let chown = |p: &Path| {
            let c = std::ffi::CString::new(p.as_os_str().as_bytes()).unwrap();
            // SAFETY: a NUL-terminated path.
            assert_eq!(unsafe { libc::lchown(c.as_ptr(), 65534, 65534) }, 0);
        };
        let link = dir.path().join("x.mcap");
        symlink(&secret, &link).unwrap();
        chown(&link);
        let theirs = dir.path().join("theirs.mcap");
        std::fs::write(&theirs, "").unwrap();
        chown(&theirs);
        for force in [false, true] {
            let e = create_in_place(&link, force).unwrap_err().to_string();
            assert!(e.contains("is a symbolic link"), "{e}");
        }
        let e = create_in_place(&theirs, true).unwrap_err().to_string();
        assert!(
            e.contains("belongs to user 65534 in the shared folder"),
            "{e}"
        );
        assert_eq!(std::fs::read_to_string(&secret).unwrap(), "root only");
    }
}
