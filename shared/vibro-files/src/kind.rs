//! What stands at an output path, and why the rule refuses it.

use std::fs::FileType;
use std::path::Path;

/// What stands at an output path, as `lstat` (a link not followed) or `fstat` sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Regular,
    Directory,
    /// Never followed: it may point at a file this command must not write.
    Symlink,
    Fifo,
    CharDevice,
    BlockDevice,
    Socket,
    Other,
}

impl Kind {
    pub(crate) fn of(t: FileType) -> Kind {
        use std::os::unix::fs::FileTypeExt;
        if t.is_file() {
            Kind::Regular
        } else if t.is_dir() {
            Kind::Directory
        } else if t.is_symlink() {
            Kind::Symlink
        } else if t.is_fifo() {
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

    /// What it is, for a message ("a FIFO (named pipe)").
    fn what(self) -> &'static str {
        match self {
            Kind::Regular => "a regular file",
            Kind::Directory => "a directory",
            Kind::Symlink => "a symbolic link",
            Kind::Fifo => "a FIFO (named pipe)",
            Kind::CharDevice => "a character device",
            Kind::BlockDevice => "a block device",
            Kind::Socket => "a socket",
            Kind::Other => "a special file",
        }
    }

    /// Why an output file of this kind at `path` is refused, even with `--force` (empty
    /// for a regular file, which only `--force` decides about).
    pub(crate) fn refusal(self, path: &Path) -> String {
        match self {
            Kind::Regular => String::new(),
            Kind::Directory => "is a directory, not a file".to_string(),
            Kind::Symlink => format!(
                "is a symbolic link to {}: refused, not followed (a link may lead where this command must not write); name the target itself",
                link_target(path)
            ),
            k => format!(
                "is {}, not a regular file: refused even with --force (an output is only ever a regular file of its own)",
                k.what()
            ),
        }
    }

    /// Why a folder of results of this kind at `path` is refused.
    pub(crate) fn folder_refusal(self, path: &Path) -> String {
        match self {
            Kind::Directory => String::new(),
            Kind::Symlink => format!(
                "is a symbolic link to {}: refused, not followed (a link may lead where this command must not write); name the folder itself",
                link_target(path)
            ),
            k => format!("exists and is {}, not a folder", k.what()),
        }
    }
}

/// The kind of what exists at `path` without following a last symbolic link; `None`
/// if nothing does.
pub(crate) fn existing_kind(path: &Path) -> std::io::Result<Option<Kind>> {
    match std::fs::symlink_metadata(path) {
        Ok(meta) => Ok(Some(Kind::of(meta.file_type()))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e),
    }
}

/// Longest link target quoted in a message, in characters.
const TARGET_CHARS: usize = 120;

/// A link's target as a message quotes it: anyone who can write the folder chose it,
/// so control characters are escaped and it is cut at [`TARGET_CHARS`] characters
/// ("… (N more bytes cut)"). Written here rather than with `vibro_toml::echo`: this
/// crate sits below the TOML one (the MCAP recorder uses it).
fn link_target(link: &Path) -> String {
    let target = match std::fs::read_link(link) {
        Ok(t) => t,
        Err(e) => return format!("an unreadable target ({e})"),
    };
    let text = target.to_string_lossy();
    let mut shown = String::new();
    let mut cut_at = text.len();
    for (n, (at, c)) in text.char_indices().enumerate() {
        if n == TARGET_CHARS {
            cut_at = at;
            break;
        }
        if c.is_control() {
            shown.extend(c.escape_default());
        } else {
            shown.push(c);
        }
    }
    if cut_at < text.len() {
        shown.push_str(&format!("… ({} more bytes cut)", text.len() - cut_at));
    }
    shown
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hostile_link_target_is_escaped_and_cut() {
        let dir = tempfile::TempDir::new().unwrap();
        let link = dir.path().join("l");
        let target = format!("/a\n\x1b[31m{}", "x".repeat(500));
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let shown = link_target(&link);
        assert!(shown.starts_with("/a\\n\\u{1b}[31mxxx"), "{shown}");
        // 120 characters kept of 508 (each one byte).
        assert!(shown.ends_with("… (388 more bytes cut)"), "{shown}");
        assert!(!shown.contains('\n') && !shown.contains('\x1b'));
    }
}
