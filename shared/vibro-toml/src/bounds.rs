//! Bounds on what a configuration file may hold: the file's size, and the length of
//! each of its strings and lists.
//!
//! A configuration is input like any other: a value can be a megabyte long, a list can
//! hold a hundred thousand entries, and the file itself can be `/dev/zero`. Each reader
//! reads its file with [`read_file`] (at most [`MAX_FILE_BYTES`], refused before it is
//! read whole), and each validation checks every string and list against a bound
//! chosen from what the value means (a Zenoh key, a path, an id, the endpoints of one
//! bridge), before it looks at the value's meaning: a value over its bound is reported
//! with [`text`] or [`list`], quoted by [`crate::echo::excerpt`], and is not checked
//! further (that would quote it whole, or do work in proportion to it).
//!
//! ```
//! let mut problems = Vec::new();
//! let key = "a".repeat(1 << 20);
//! assert!(!vibro_toml::bounds::text("key_prefix", &key, 256, &mut problems));
//! assert!(problems[0].starts_with("key_prefix = \"aaaa"), "{problems:?}");
//! assert!(problems[0].ends_with("(1048576 bytes): at most 256 bytes"), "{problems:?}");
//! assert!(problems[0].len() < 300);
//! assert!(!vibro_toml::bounds::list("zenoh.listen", 100_000, 64, &mut problems));
//! assert_eq!(problems[1], "zenoh.listen: 100000 entries: at most 64");
//! ```

use crate::echo::excerpt;
use std::io::Read;
use std::path::Path;

/// Largest configuration file read, in bytes (1 MiB). The largest shipped configuration
/// is under 8 KiB, and 1 MiB holds a TOML lab manifest of the most runs it may list
/// (`vibro_lab`'s 10 000). Parsing the worst 1 MiB measured (one array of 524 000
/// integers) took 90 MB and 0.09 s; a 2 GiB file took 10.5 GB and 49 s before it was
/// refused, and quoted itself whole in the error.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Longest path a configuration names, in bytes: Linux's `PATH_MAX` (4096, the NUL
/// included). A longer one cannot be opened.
pub const MAX_PATH_BYTES: usize = 4095;

/// Longest name or id (a triad's id, a unit's name, a column's name, a scenario's
/// name, a shipped id a path may stand for): a word or a few, with room to spare.
pub const MAX_NAME_BYTES: usize = 128;

/// Longest free text (a scenario's description): a paragraph.
pub const MAX_TEXT_BYTES: usize = 4096;

/// `value` quoted for a message: as Rust's `{:?}` quotes it when it is short and
/// printable (what the messages have always shown), else its [`excerpt`] in quotes.
///
/// ```
/// use vibro_toml::bounds::quote;
/// assert_eq!(quote("rig b/"), "\"rig b/\"");
/// assert!(quote(&"x".repeat(5000)).ends_with("… (4880 more bytes cut)\""));
/// ```
pub fn quote(value: &str) -> String {
    match excerpt(value) {
        std::borrow::Cow::Borrowed(v) => format!("{v:?}"),
        std::borrow::Cow::Owned(cut) => format!("\"{cut}\""),
    }
}

/// Whether `value`, found at `key`, has at most `max_bytes` bytes; if not, adds
/// `key = "…" (N bytes): at most M bytes` to `problems` (the value quoted by
/// [`excerpt`]).
pub fn text(key: &str, value: &str, max_bytes: usize, problems: &mut Vec<String>) -> bool {
    if value.len() <= max_bytes {
        return true;
    }
    problems.push(format!(
        "{key} = {} ({} bytes): at most {max_bytes} bytes",
        quote(value),
        value.len()
    ));
    false
}

/// [`text`] of a path (a `PathBuf` read from the file), shown lossily if it is not
/// UTF-8.
pub fn path(key: &str, value: &Path, max_bytes: usize, problems: &mut Vec<String>) -> bool {
    if value.as_os_str().len() <= max_bytes {
        return true;
    }
    let shown = value.to_string_lossy();
    problems.push(format!(
        "{key} = {} ({} bytes): at most {max_bytes} bytes",
        quote(&shown),
        value.as_os_str().len()
    ));
    false
}

/// Whether the list at `key`, of `len` entries, has at most `max`; if not, adds
/// `key: N entries: at most M` to `problems`.
pub fn list(key: &str, len: usize, max: usize, problems: &mut Vec<String>) -> bool {
    if len <= max {
        return true;
    }
    problems.push(format!("{key}: {len} entries: at most {max}"));
    false
}

/// [`text`] of every string of a list (`key[i]`), after [`list`] of the list itself:
/// whether all are within their bounds. The entries of a list over its bound are not
/// looked at (there may be a hundred thousand of them).
pub fn texts(
    key: &str,
    values: &[String],
    max_entries: usize,
    max_bytes: usize,
    problems: &mut Vec<String>,
) -> bool {
    if !list(key, values.len(), max_entries, problems) {
        return false;
    }
    let mut ok = true;
    for (i, v) in values.iter().enumerate() {
        ok &= text(&format!("{key}[{i}]"), v, max_bytes, problems);
    }
    ok
}

/// The text of the configuration file at `path`, if it has at most
/// [`MAX_FILE_BYTES`] bytes: a bigger file is refused by the size it says it has,
/// before anything is read, and a file that does not say (a device, a pipe) is read no
/// further than one byte past the bound. The error of a file too big says its size and
/// the bound; the others are the operating system's, or invalid UTF-8.
pub fn read_file(path: &Path) -> std::io::Result<String> {
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if meta.is_file() && meta.len() > MAX_FILE_BYTES {
        return Err(too_big(&format!("{} bytes", meta.len())));
    }
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(too_big(&format!("more than {MAX_FILE_BYTES} bytes")));
    }
    String::from_utf8(bytes).map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "stream did not contain valid UTF-8",
        )
    })
}

fn too_big(size: &str) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::FileTooLarge,
        format!("{size}: a configuration file holds at most {MAX_FILE_BYTES} bytes (1 MiB)"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strings_and_lists_over_their_bound_are_reported_with_key_value_and_rule() {
        let mut p = Vec::new();
        assert!(text("name", "AL-15", 5, &mut p));
        assert!(list("unit", 3, 3, &mut p));
        assert!(p.is_empty());
        assert!(!text("name", "AL-15x", 5, &mut p));
        assert_eq!(p, ["name = \"AL-15x\" (6 bytes): at most 5 bytes"]);
        let long = Path::new("/x").join("y".repeat(5000));
        assert!(!path("tls.certificate", &long, MAX_PATH_BYTES, &mut p));
        assert!(p[1].contains("(5003 bytes): at most 4095 bytes"), "{p:?}");
        assert!(p[1].contains("more bytes cut"), "{p:?}");
        p.clear();
        let values: Vec<String> = vec!["a".into(), "b".repeat(9), "c".into()];
        assert!(!texts("allow_zids", &values, 8, 8, &mut p));
        assert_eq!(
            p,
            ["allow_zids[1] = \"bbbbbbbbb\" (9 bytes): at most 8 bytes"]
        );
        p.clear();
        assert!(!texts("allow_zids", &values, 2, 8, &mut p));
        assert_eq!(p, ["allow_zids: 3 entries: at most 2"]);
    }

    #[test]
    fn a_file_over_the_bound_is_refused_before_it_is_read() {
        let dir = std::env::temp_dir().join(format!("vibro-toml-bounds-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let small = dir.join("small.toml");
        std::fs::write(&small, "a = 1\n").unwrap();
        assert_eq!(read_file(&small).unwrap(), "a = 1\n");
        // A sparse file of 2 GiB: refused by its size, in no time and no memory.
        let big = dir.join("big.toml");
        let f = std::fs::File::create(&big).unwrap();
        f.set_len(2 << 30).unwrap();
        let started = std::time::Instant::now();
        let e = read_file(&big).unwrap_err();
        let elapsed = started.elapsed();
        // One byte over the bound.
        let over = dir.join("over.toml");
        std::fs::write(&over, vec![b'#'; MAX_FILE_BYTES as usize + 1]).unwrap();
        let e_over = read_file(&over).unwrap_err();
        let exact = dir.join("exact.toml");
        std::fs::write(&exact, vec![b'#'; MAX_FILE_BYTES as usize]).unwrap();
        let exact_len = read_file(&exact).map(|t| t.len());
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(e.kind(), std::io::ErrorKind::FileTooLarge);
        assert_eq!(
            e.to_string(),
            "2147483648 bytes: a configuration file holds at most 1048576 bytes (1 MiB)"
        );
        assert!(elapsed.as_secs_f64() < 0.5, "{elapsed:?}");
        assert!(
            e_over.to_string().starts_with("1048577 bytes: "),
            "{e_over}"
        );
        assert_eq!(exact_len.unwrap(), MAX_FILE_BYTES as usize);
        // A device that never ends: read one byte past the bound, then refused.
        let e = read_file(Path::new("/dev/zero")).unwrap_err();
        assert!(
            e.to_string().starts_with("more than 1048576 bytes: "),
            "{e}"
        );
    }
}
