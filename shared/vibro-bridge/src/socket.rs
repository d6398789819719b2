//! The directory of a bridge's Unix socket: the operating system's access control is
//! what keeps other users away from a `unixsock-stream/` endpoint, so the bridge
//! makes sure there is some before Zenoh binds or connects.
//!
//! Connecting to a Unix socket needs search permission on every directory of its path
//! (unix(7), "Pathname socket ownership and permissions"). A directory owned by the
//! bridge's user with no group or other permission (mode 0700) therefore refuses
//! every other user but root, whatever the socket's own mode (which follows the
//! umask). The bridge creates the directory if it is missing, on the listening and
//! the connecting side alike (either may start first), and refuses to start when:
//!
//! - it is not a directory (a symbolic link included), belongs to another user, or
//!   gives its group or others any permission: somebody else could reach the socket,
//!   or, on the connecting side, stand in for the listening bridge;
//! - a directory above it can be written by another user and has no sticky bit: that
//!   user could rename it away and put a directory of theirs in its place (`/tmp`,
//!   mode 1777, is fine). Owners other than root and this user are refused too.
//!
//! What this does not guard against: root, and other processes of the same user
//! (who own the directory anyway).
//!
//! **The default folder.** A socket named without a folder (`unixsock-stream/rig-a.sock`)
//! goes in this user's own ([`default_socket_dir`]): `$XDG_RUNTIME_DIR/vibrocomp-bridge`
//! when that variable names a directory of this user's with mode 0700 (systemd's
//! `/run/user/UID`, which no other user can write in), else
//! `$TMPDIR/vibrocomp-bridge-UID` (`/tmp/vibrocomp-bridge-0` for root). A folder shared
//! by every user (`/tmp/vibrocomp-bridge`, the default before) let the first user to
//! create it lock everybody else out; in `/tmp` another user can still create this
//! user's folder first on purpose, which the check above refuses naming its owner;
//! only `$XDG_RUNTIME_DIR` rules that out. The bridges of one host find each other
//! when they run as the same user with the same `XDG_RUNTIME_DIR` and `TMPDIR`.

use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

/// The effective user id of this process.
pub fn effective_uid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// The folder of the sockets named without one (module docs, "The default folder"),
/// for this process's user and environment.
pub fn default_socket_dir() -> PathBuf {
    default_socket_dir_for(
        std::env::var_os("XDG_RUNTIME_DIR").map(PathBuf::from),
        effective_uid(),
        &std::env::temp_dir(),
    )
}

/// [`default_socket_dir`] for the user `uid` with `XDG_RUNTIME_DIR` = `runtime_dir`
/// and the temporary folder `tmp`.
pub fn default_socket_dir_for(runtime_dir: Option<PathBuf>, uid: u32, tmp: &Path) -> PathBuf {
    if let Some(run) = runtime_dir.filter(|d| d.is_absolute()) {
        // Not followed if a link: the folder itself must be this user's alone.
        let ours = std::fs::symlink_metadata(&run)
            .is_ok_and(|m| m.is_dir() && m.uid() == uid && m.mode() & 0o077 == 0);
        if ours {
            return run.join("vibrocomp-bridge");
        }
    }
    let tmp = if tmp.is_absolute() {
        tmp
    } else {
        Path::new("/tmp")
    };
    tmp.join(format!("vibrocomp-bridge-{uid}"))
}

/// Creates `dir` (mode 0700) if it is missing, then checks it and the directories
/// above it as the module doc says; the error says what is wrong and the rule.
pub fn secure_dir(dir: &Path) -> Result<(), String> {
    if std::fs::symlink_metadata(dir).is_err() {
        match std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(dir)
        {
            Ok(()) => {
                // The umask may have taken bits off 0700 (never added any).
                let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700));
            }
            // Another bridge made it meanwhile: it is checked below like any other.
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => {
                return Err(format!(
                    "cannot create the directory {}: {e}",
                    dir.display()
                ))
            }
        }
    }
    check_dir(dir)
}

/// [`secure_dir`] without creating anything (configuration validation): a missing
/// `dir` passes when the directories above it that exist would keep it safe.
pub fn check_dir(dir: &Path) -> Result<(), String> {
    let uid = effective_uid();
    let above = match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => dir.ancestors().skip(1),
        Err(e) => return Err(format!("cannot read the directory {}: {e}", dir.display())),
        Ok(meta) => {
            let mode = meta.mode() & 0o7777;
            if !meta.file_type().is_dir() {
                return Err(format!(
                    "{} is not a directory (a symbolic link is refused too): the socket's directory must be a real directory of this user's, mode 0700",
                    dir.display()
                ));
            }
            if meta.uid() != uid || mode & 0o077 != 0 {
                return Err(format!(
                    "the directory {} belongs to uid {} with mode {mode:04o}: it must belong to this process's user (uid {uid}) and give its group and others no permission (mode 0700; chmod 700, or remove it and let the bridge create it), or other users could reach the socket",
                    dir.display(),
                    meta.uid(),
                ));
            }
            dir.ancestors().skip(1)
        }
    };
    for above in above {
        if above.as_os_str().is_empty() {
            continue;
        }
        let meta = match std::fs::metadata(above) {
            // Made, mode 0700, by `secure_dir`.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => {
                return Err(format!(
                    "cannot read the directory {}: {e}",
                    above.display()
                ))
            }
            Ok(m) => m,
        };
        let mode = meta.mode() & 0o7777;
        let owner_ok = meta.uid() == 0 || meta.uid() == uid;
        let sticky = mode & 0o1000 != 0;
        if !meta.is_dir() || !owner_ok || (mode & 0o022 != 0 && !sticky) {
            return Err(format!(
                "{} (uid {}, mode {mode:04o}) is above the socket's directory {}: it must be a directory of root's or of this process's user (uid {uid}), writable by nobody else unless sticky (like /tmp), or another user could replace the socket's directory",
                above.display(),
                meta.uid(),
                dir.display()
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    /// A folder of this test's, removed on drop.
    struct Tmp(PathBuf);

    impl Tmp {
        fn new(what: &str) -> Self {
            let d = std::env::temp_dir().join(format!("vbs-{what}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&d);
            std::fs::create_dir_all(&d).unwrap();
            std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o755)).unwrap();
            Self(d)
        }
    }

    impl Drop for Tmp {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn mode(p: &Path) -> u32 {
        std::fs::symlink_metadata(p).unwrap().mode() & 0o7777
    }

    #[test]
    fn a_missing_directory_is_made_0700_and_then_accepted() {
        let t = Tmp::new("make");
        let d = t.0.join("a/b");
        // Validation creates nothing.
        check_dir(&d).unwrap();
        assert!(!t.0.join("a").exists());
        secure_dir(&d).unwrap();
        assert_eq!(mode(&d), 0o700);
        assert_eq!(mode(&t.0.join("a")), 0o700);
        secure_dir(&d).unwrap();
    }

    #[test]
    fn a_directory_others_may_enter_is_refused_with_its_mode_and_the_rule() {
        let t = Tmp::new("open");
        for m in [0o755, 0o710, 0o701, 0o777] {
            let d = t.0.join(format!("d{m:o}"));
            std::fs::create_dir(&d).unwrap();
            std::fs::set_permissions(&d, std::fs::Permissions::from_mode(m)).unwrap();
            let e = secure_dir(&d).unwrap_err();
            assert!(e.contains(&format!("mode {m:04o}")), "{e}");
            assert!(e.contains("mode 0700"), "{e}");
        }
    }

    #[test]
    fn a_symbolic_link_or_a_file_is_refused() {
        let t = Tmp::new("link");
        let real = t.0.join("real");
        std::fs::create_dir(&real).unwrap();
        std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o700)).unwrap();
        let link = t.0.join("link");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        assert!(secure_dir(&link).unwrap_err().contains("not a directory"));
        let file = t.0.join("file");
        std::fs::write(&file, "").unwrap();
        assert!(secure_dir(&file).unwrap_err().contains("not a directory"));
    }

    #[test]
    fn a_directory_below_one_others_may_write_is_refused_unless_sticky() {
        let t = Tmp::new("above");
        let shared = t.0.join("shared");
        std::fs::create_dir(&shared).unwrap();
        std::fs::set_permissions(&shared, std::fs::Permissions::from_mode(0o777)).unwrap();
        let d = shared.join("sock");
        for e in [check_dir(&d).unwrap_err(), secure_dir(&d).unwrap_err()] {
            assert!(e.contains("mode 0777") && e.contains("replace"), "{e}");
        }
        std::fs::set_permissions(&shared, std::fs::Permissions::from_mode(0o1777)).unwrap();
        secure_dir(&d).unwrap();
    }

    /// Issue 46, item 8: the default folder is this user's, never the folder every
    /// user shared (`/tmp/vibrocomp-bridge`): `$XDG_RUNTIME_DIR`'s when it is this
    /// user's alone, else one named with the uid.
    #[test]
    fn the_default_folder_is_this_users_own() {
        let uid = effective_uid();
        let here = default_socket_dir();
        assert_ne!(here, Path::new("/tmp/vibrocomp-bridge"));
        assert!(
            here.ends_with(format!("vibrocomp-bridge-{uid}"))
                || std::env::var_os("XDG_RUNTIME_DIR")
                    .is_some_and(|x| here == Path::new(&x).join("vibrocomp-bridge")),
            "{}",
            here.display()
        );
        let t = Tmp::new("xdg");
        let run = t.0.join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::set_permissions(&run, std::fs::Permissions::from_mode(0o700)).unwrap();
        let tmp = t.0.join("tmp");
        let ours = default_socket_dir_for(Some(run.clone()), uid, &tmp);
        assert_eq!(ours, run.join("vibrocomp-bridge"));
        let fallback = tmp.join(format!("vibrocomp-bridge-{uid}"));
        // Unset, relative, missing, or others may enter it: the folder named with the uid.
        assert_eq!(default_socket_dir_for(None, uid, &tmp), fallback);
        let relative = Some(PathBuf::from("run"));
        assert_eq!(default_socket_dir_for(relative, uid, &tmp), fallback);
        let missing = Some(t.0.join("missing"));
        assert_eq!(default_socket_dir_for(missing, uid, &tmp), fallback);
        std::fs::set_permissions(&run, std::fs::Permissions::from_mode(0o755)).unwrap();
        assert_eq!(
            default_socket_dir_for(Some(run.clone()), uid, &tmp),
            fallback
        );
        // Another user's runtime folder (as root, uid 65534's).
        std::fs::set_permissions(&run, std::fs::Permissions::from_mode(0o700)).unwrap();
        assert_eq!(
            default_socket_dir_for(Some(run.clone()), uid.wrapping_add(1), &tmp),
            tmp.join(format!("vibrocomp-bridge-{}", uid.wrapping_add(1)))
        );
        assert_eq!(
            default_socket_dir_for(None, 0, Path::new("relative")),
            Path::new("/tmp/vibrocomp-bridge-0")
        );
    }

    /// As root: a directory of another user (uid 65534), mode 0700, is refused.
    #[test]
    fn a_directory_of_another_user_is_refused() {
        if effective_uid() != 0 {
            eprintln!("*** SKIPPED a_directory_of_another_user_is_refused: not root, cannot give a directory away ***");
            return;
        }
        let t = Tmp::new("owner");
        let d = t.0.join("theirs");
        std::fs::create_dir(&d).unwrap();
        std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o700)).unwrap();
        std::os::unix::fs::chown(&d, Some(65534), Some(65534)).unwrap();
        let e = secure_dir(&d).unwrap_err();
        assert!(e.contains("belongs to uid 65534"), "{e}");
    }
}
