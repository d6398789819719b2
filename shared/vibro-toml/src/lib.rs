//! # vibro-toml
//!
//! Reads a TOML configuration file into its raw type (a `#[serde(deny_unknown_fields)]`
//! struct, STYLE.md "Config") so that the errors keep what the file's author needs:
//!
//! - a syntax or type error keeps toml's multi-line snippet: the line, and a caret
//!   under the offending text;
//! - **every** unknown key is reported at once (serde stops at the first), each with
//!   its table path, line and column, and a "did you mean" when a known key is a near
//!   miss.
//!
//! The unknown keys are found by the raw type itself: each `unknown field` error of
//! its deserializer names the key and the known ones and points at the key's span in
//! the spanned document (`toml::de::DeTable`); the key is taken out of the document and
//! the type deserialized again, until no unknown key is left. The rules stay in one
//! place (the raw type), and no second list of keys can drift from it.
//!
//! ```
//! #[derive(Debug, serde::Deserialize)]
//! #[serde(deny_unknown_fields)]
//! struct Raw { window_s: f64, hop_s: f64 }
//!
//! let e = vibro_toml::from_str::<Raw>("window_s = 1.0\nwindw_s = 2.0\nhop_s = 0.5\nhops = 1\n", "a.toml")
//!     .unwrap_err();
//! let text = e.to_string();
//! assert!(text.contains("line 2, column 1: windw_s: unknown key (did you mean window_s?)"), "{text}");
//! assert!(text.contains("line 4, column 1: hops: unknown key"), "{text}");
//! assert_eq!(e.location().line, Some(2));
//! ```

pub mod bounds;
pub mod echo;

use serde::de::DeserializeOwned;
use std::ops::Range;
use toml::de::{DeTable, DeValue};
use toml::Spanned;

/// Where in a file an error is: what `--json` errors carry (`file`, `line`, `key`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Location {
    pub file: String,
    /// 1-based.
    pub line: Option<usize>,
    /// 1-based, in characters.
    pub column: Option<usize>,
    /// The key's dotted path (`effects[0].corner_hz`).
    pub key: Option<String>,
}

/// A key the file's type does not know.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownKey {
    /// Dotted path of the key (`rates.sensr_hz`, `effects[1].kind`).
    pub key: String,
    pub line: usize,
    pub column: usize,
    /// The known key it is a near miss of.
    pub suggestion: Option<String>,
    /// The keys its table knows.
    pub known: Vec<String>,
}

/// Errors reading a TOML file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Error {
    /// A syntax error, or a value the type refuses: toml's own message with the line
    /// and a caret under the offending text.
    #[error("{file}: {}", snippet.trim_end())]
    Toml {
        file: String,
        line: Option<usize>,
        column: Option<usize>,
        key: Option<String>,
        snippet: String,
    },
    /// Keys the file's type does not know, every one of them.
    #[error("{file}: {}", unknown_text(keys))]
    UnknownKeys { file: String, keys: Vec<UnknownKey> },
}

fn unknown_text(keys: &[UnknownKey]) -> String {
    let lines: Vec<String> = keys
        .iter()
        .map(|k| {
            let hint = match &k.suggestion {
                Some(s) => format!(" (did you mean {s}?)"),
                None if k.known.is_empty() => " (this table takes no keys)".to_string(),
                None => format!(" (known: {})", k.known.join(", ")),
            };
            format!(
                "line {}, column {}: {}: unknown key{hint}",
                k.line, k.column, k.key
            )
        })
        .collect();
    match lines.len() {
        1 => lines[0].clone(),
        n => format!("{n} unknown keys:\n  {}", lines.join("\n  ")),
    }
}

impl Error {
    /// The message without the file's name (for an error type that names it itself).
    pub fn detail(&self) -> String {
        match self {
            Error::Toml { snippet, .. } => snippet.trim_end().to_string(),
            Error::UnknownKeys { keys, .. } => unknown_text(keys),
        }
    }

    /// The file, and the line and key of the (first) problem.
    pub fn location(&self) -> Location {
        match self {
            Error::Toml {
                file,
                line,
                column,
                key,
                ..
            } => Location {
                file: file.clone(),
                line: *line,
                column: *column,
                key: key.clone(),
            },
            Error::UnknownKeys { file, keys } => Location {
                file: file.clone(),
                line: keys.first().map(|k| k.line),
                column: keys.first().map(|k| k.column),
                key: keys.first().map(|k| k.key.clone()),
            },
        }
    }
}

/// Result of reading a TOML file.
pub type Result<T> = std::result::Result<T, Error>;

/// At most this many unknown keys are collected (each costs a deserialization).
const MAX_UNKNOWN: usize = 64;

/// Parses `text` (the file `file`) into `T`, reporting every unknown key at once
/// (module docs). A text longer than [`bounds::MAX_FILE_BYTES`] is refused unread,
/// whoever read it.
pub fn from_str<T: DeserializeOwned>(text: &str, file: &str) -> Result<T> {
    if text.len() as u64 > bounds::MAX_FILE_BYTES {
        return Err(Error::Toml {
            file: file.to_string(),
            line: None,
            column: None,
            key: None,
            snippet: format!(
                "{} bytes: a configuration file holds at most {} bytes (1 MiB)",
                text.len(),
                bounds::MAX_FILE_BYTES
            ),
        });
    }
    let mut root = DeTable::parse(text).map_err(|e| toml_error(file, text, None, e))?;
    let mut unknown: Vec<UnknownKey> = Vec::new();
    loop {
        let e = match T::deserialize(toml::de::Deserializer::from(root.clone())) {
            Ok(value) if unknown.is_empty() => return Ok(value),
            Ok(_) => break,
            Err(e) => e,
        };
        let taken = match (unknown_field(e.message()), e.span()) {
            (Some((name, known)), Some(span)) if unknown.len() < MAX_UNKNOWN => {
                take_key(root.get_mut(), &span, "").map(|path| {
                    let (line, column) = position(text, span.start);
                    UnknownKey {
                        // A key can be as long as the file: quoted by its excerpt.
                        key: echo::excerpt(&path).into_owned(),
                        line,
                        column,
                        suggestion: near_miss(&name, &known),
                        known,
                    }
                })
            }
            _ => None,
        };
        match taken {
            Some(k) => unknown.push(k),
            // Unknown keys first: another problem may be one of their doing.
            None if !unknown.is_empty() => break,
            None => {
                let key = e.span().and_then(|s| key_at(root.get_ref(), &s, ""));
                return Err(toml_error(file, text, key, e));
            }
        }
    }
    unknown.sort_by_key(|k| (k.line, k.column));
    Err(Error::UnknownKeys {
        file: file.to_string(),
        keys: unknown,
    })
}

fn toml_error(file: &str, text: &str, key: Option<String>, e: toml::de::Error) -> Error {
    let (line, column) = e
        .span()
        .map(|s| position(text, s.start))
        .map_or((None, None), |(l, c)| (Some(l), Some(c)));
    Error::Toml {
        file: file.to_string(),
        line,
        column,
        key: key.map(|k| echo::excerpt(&k).into_owned()),
        snippet: snippet(text, e.span(), &e),
    }
}

/// Longest line of the file a snippet quotes whole, in characters; of a longer one
/// (a 200 KB line of brackets), this many characters around the column.
const SNIPPET_MAX_CHARS: usize = echo::ECHO_MAX_CHARS;
/// Characters of a cut line shown before the column.
const SNIPPET_BEFORE_CHARS: usize = 40;
/// Longest line of toml's message kept whole (serde's messages quote the offending
/// value, which may be a megabyte long); a longer one is [`echo::excerpt`]ed.
const MESSAGE_MAX_CHARS: usize = 512;

/// toml's error as toml writes it (the line, a caret under the offending text, the
/// message), but with at most a line's worth of the file: a line longer than
/// [`SNIPPET_MAX_CHARS`] is shown as a window around the column, marked cut with `…`
/// at each end it was cut and followed by a note of its length. Control characters
/// but tabs are shown as U+FFFD, so that the quote cannot move a terminal's cursor
/// and the caret stays under its column.
fn snippet(text: &str, span: Option<Range<usize>>, e: &toml::de::Error) -> String {
    use std::fmt::Write as _;
    let Some(span) = span else {
        // No place in the file: toml's message alone, and the keys it names.
        return cap_lines(&e.to_string()) + "\n";
    };
    let mut out = String::new();
    let (line, column) = position(text, span.start);
    let content = text.split('\n').nth(line - 1).unwrap_or("");
    let content = content.strip_suffix('\r').unwrap_or(content);
    let n_chars = content.chars().count();
    let col0 = column - 1;
    let span_chars = text
        .get(span.start.min(text.len())..span.end.min(text.len()))
        .map_or(0, |s| s.chars().count());
    let (from, to) = if n_chars <= SNIPPET_MAX_CHARS {
        (0, n_chars)
    } else {
        let from = col0
            .saturating_sub(SNIPPET_BEFORE_CHARS)
            .min(n_chars - SNIPPET_MAX_CHARS);
        (from, from + SNIPPET_MAX_CHARS)
    };
    let lead = if from > 0 { "…" } else { "" };
    let trail = if to < n_chars { "…" } else { "" };
    let shown: String = content
        .chars()
        .skip(from)
        .take(to - from)
        .map(|c| {
            if c.is_control() && c != '\t' {
                '\u{fffd}'
            } else {
                c
            }
        })
        .collect();
    let gutter = " ".repeat(line.to_string().len() + 1);
    let caret_at = lead.chars().count() + col0.saturating_sub(from);
    let carets = span_chars.min(to.saturating_sub(col0)).max(1);
    let _ = writeln!(out, "TOML parse error at line {line}, column {column}");
    let _ = writeln!(out, "{gutter}|");
    let _ = writeln!(out, "{line} | {lead}{shown}{trail}");
    let _ = writeln!(
        out,
        "{gutter}|{}{}",
        " ".repeat(caret_at + 1),
        "^".repeat(carets)
    );
    if from > 0 || to < n_chars {
        let _ = writeln!(
            out,
            "{gutter}= line {line} cut: {n_chars} characters long, {} shown",
            to - from
        );
    }
    out.push_str(&cap_lines(e.message()));
    out.push('\n');
    out
}

/// `text` with each line longer than [`MESSAGE_MAX_CHARS`] cut to an excerpt.
fn cap_lines(text: &str) -> String {
    text.trim_end()
        .lines()
        .map(|l| {
            if l.chars().count() <= MESSAGE_MAX_CHARS {
                std::borrow::Cow::Borrowed(l)
            } else {
                echo::excerpt(l)
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// 1-based line and column (in characters) of byte `offset`.
fn position(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = text.get(..offset).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().unwrap_or("").chars().count() + 1;
    (line, column)
}

/// serde's `unknown field `x`, expected one of `a`, `b`` (or `expected `a``, or
/// `there are no fields`): the name and the known ones.
fn unknown_field(message: &str) -> Option<(String, Vec<String>)> {
    let rest = message.strip_prefix("unknown field `")?;
    let (name, rest) = rest.split_once('`')?;
    let known = rest
        .split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_string)
        .collect();
    Some((name.to_string(), known))
}

/// Where the key at `path` (a dotted path with array indices: `effect[0].freq_hz`) is
/// written in `text`: its line and column (1-based), or `None` when the text does not
/// parse or holds no such key. A path that ends at an element of an array of tables
/// (`effect[1]`) points at where that element starts. For problems found after
/// deserialization (a value against its rule), which serde's spans do not reach.
pub fn key_position(text: &str, path: &str) -> Option<(usize, usize)> {
    let root = DeTable::parse(text).ok()?;
    let mut table = root.get_ref();
    let mut segments = path.split('.').peekable();
    while let Some(segment) = segments.next() {
        let (name, index) = match segment.split_once('[') {
            Some((name, rest)) => (name, Some(rest.strip_suffix(']')?.parse::<usize>().ok()?)),
            None => (segment, None),
        };
        let (key, value) = table.get_key_value(name)?;
        let last = segments.peek().is_none();
        let (start, value) = match index {
            None => (key.span().start, value),
            Some(i) => match value.get_ref() {
                DeValue::Array(items) => {
                    let item = items.get(i)?;
                    (item.span().start, item)
                }
                _ => return None,
            },
        };
        if last {
            return Some(position(text, start));
        }
        match value.get_ref() {
            DeValue::Table(t) => table = t,
            _ => return None,
        }
    }
    None
}

/// Removes the entry whose key is at `span`; its dotted path.
fn take_key(table: &mut DeTable<'_>, span: &Range<usize>, path: &str) -> Option<String> {
    let hit = table
        .keys()
        .find(|k| k.span() == *span)
        .map(|k| k.get_ref().to_string());
    if let Some(name) = hit {
        table.remove(name.as_str());
        return Some(join(path, &name));
    }
    for (k, v) in table.iter_mut() {
        let here = join(path, k.get_ref());
        if let Some(found) = take_in_value(v.get_mut(), span, &here) {
            return Some(found);
        }
    }
    None
}

fn take_in_value(value: &mut DeValue<'_>, span: &Range<usize>, path: &str) -> Option<String> {
    match value {
        DeValue::Table(t) => take_key(t, span, path),
        DeValue::Array(items) => items
            .iter_mut()
            .enumerate()
            .find_map(|(i, item)| take_in_value(item.get_mut(), span, &format!("{path}[{i}]"))),
        _ => None,
    }
}

/// The dotted path of the innermost key whose key or value holds `span`.
fn key_at(table: &DeTable<'_>, span: &Range<usize>, path: &str) -> Option<String> {
    for (k, v) in table.iter() {
        let here = join(path, k.get_ref());
        if k.span() == *span {
            return Some(here);
        }
        if let Some(inner) = key_in_value(v, span, &here) {
            return Some(inner);
        }
    }
    None
}

fn key_in_value(v: &Spanned<DeValue<'_>>, span: &Range<usize>, path: &str) -> Option<String> {
    let inner = match v.get_ref() {
        DeValue::Table(t) => key_at(t, span, path),
        DeValue::Array(items) => items
            .iter()
            .enumerate()
            .find_map(|(i, item)| key_in_value(item, span, &format!("{path}[{i}]"))),
        _ => None,
    };
    let holds = v.span().start <= span.start && span.end <= v.span().end;
    inner.or_else(|| holds.then(|| path.to_string()))
}

fn join(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_string()
    } else {
        format!("{path}.{key}")
    }
}

/// Longest unknown key a "did you mean" is looked for.
const NEAR_MISS_MAX_BYTES: usize = 64;

/// The known key `name` is most likely a misspelling of: the same but for case, or
/// within an edit distance of a third of its length (at least 1).
fn near_miss(name: &str, known: &[String]) -> Option<String> {
    // No key of a configuration is this long; the edit distance of a key as long as
    // the file would cost its length times the known key's, in memory too.
    if name.len() > NEAR_MISS_MAX_BYTES {
        return None;
    }
    if let Some(k) = known.iter().find(|k| k.eq_ignore_ascii_case(name)) {
        return Some(k.clone());
    }
    let limit = (name.chars().count() / 3).max(1);
    known
        .iter()
        .map(|k| (edit_distance(name, k), k))
        .filter(|(d, _)| *d <= limit)
        .min_by_key(|(d, _)| *d)
        .map(|(_, k)| k.clone())
}

/// Edit distance in characters, a swap of neighbours counting one edit (optimal string
/// alignment: `nmae` is one edit from `name`).
fn edit_distance(a: &str, b: &str) -> usize {
    let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            let mut best = (d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1)
                .min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                best = best.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = best;
        }
    }
    d[a.len()][b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[test]
    fn a_key_path_is_found_where_it_is_written() {
        let text = "mode = \"exact\"\n[[effect]]\nkind = \"a\"\n\n[[effect]]\nkind = \"b\"\n  \
                    foo = 1\ninline = { x = { y = 2 } }\n[rates]\nsensor_hz = 5\n";
        assert_eq!(key_position(text, "mode"), Some((1, 1)));
        assert_eq!(key_position(text, "effect[1].foo"), Some((7, 3)));
        assert_eq!(key_position(text, "effect[0].kind"), Some((3, 1)));
        assert_eq!(key_position(text, "effect[1].inline.x.y"), Some((8, 18)));
        assert_eq!(key_position(text, "rates.sensor_hz"), Some((10, 1)));
        // An element of an array of tables: where it starts.
        let (line, _) = key_position(text, "effect[1]").unwrap();
        assert!((5..=6).contains(&line), "{line}");
        assert_eq!(key_position(text, "rates"), Some((9, 2)));
        for absent in [
            "effect[2].kind",
            "effect[0].foo",
            "mode.x",
            "effect[x]",
            "nope",
        ] {
            assert_eq!(key_position(text, absent), None, "{absent}");
        }
        assert_eq!(key_position("= broken", "mode"), None);
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Rates {
        sensor_hz: f64,
        output_hz: f64,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Effect {
        kind: String,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Raw {
        name: String,
        rates: Rates,
        #[serde(default)]
        effects: Vec<Effect>,
    }

    #[test]
    fn every_unknown_key_is_reported_with_its_table_and_line() {
        let text = "name = \"x\"\nnmae = \"y\"\n\n[rates]\nsensor_hz = 1.0\nsensr_hz = 2.0\noutput_hz = 3.0\n\n[[effects]]\nkind = \"a\"\n\n[[effects]]\nkind = \"b\"\nunits = [0]\n";
        let e = from_str::<Raw>(text, "s.toml").unwrap_err();
        let Error::UnknownKeys { keys, .. } = &e else {
            panic!("{e}")
        };
        let got: Vec<(&str, usize, Option<&str>)> = keys
            .iter()
            .map(|k| (k.key.as_str(), k.line, k.suggestion.as_deref()))
            .collect();
        assert_eq!(
            got,
            [
                ("nmae", 2, Some("name")),
                ("rates.sensr_hz", 6, Some("sensor_hz")),
                ("effects[1].units", 14, None),
            ]
        );
        assert_eq!(
            e.to_string(),
            "s.toml: 3 unknown keys:\n  line 2, column 1: nmae: unknown key (did you mean name?)\n  \
             line 6, column 1: rates.sensr_hz: unknown key (did you mean sensor_hz?)\n  \
             line 14, column 1: effects[1].units: unknown key (known: kind)"
        );
        assert_eq!(e.location().key.as_deref(), Some("nmae"));
    }

    #[test]
    fn a_syntax_error_keeps_the_caret_and_a_type_error_its_key() {
        let e = from_str::<Raw>("name = \"x\"\n[rates]\nsensor_hz = = 1\n", "s.toml").unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("3 | sensor_hz = = 1\n") && text.contains("|             ^"),
            "{text}"
        );
        assert_eq!(e.location().line, Some(3));
        let e = from_str::<Raw>(
            "name = \"x\"\n[rates]\nsensor_hz = \"fast\"\noutput_hz = 1.0\n",
            "s.toml",
        )
        .unwrap_err();
        let l = e.location();
        assert_eq!(
            (l.line, l.key.as_deref()),
            (Some(3), Some("rates.sensor_hz"))
        );
        assert!(e.to_string().contains("3 | sensor_hz = \"fast\""), "{e}");
    }

    /// Issue 46, item 8: a 200 KB line of nested brackets was quoted whole, twice
    /// (the line, then as many carets); the snippet now shows a line's worth around
    /// the column, says that it cut, and still points at the line and column.
    #[test]
    fn a_huge_line_is_quoted_by_a_window_around_its_column() {
        let text = format!("name = \"x\"\na={}", "[".repeat(200_000));
        let e = from_str::<Raw>(&text, "nested.toml").unwrap_err();
        let msg = e.to_string();
        assert!(msg.len() < 1024, "{} bytes:\n{msg}", msg.len());
        let l = e.location();
        let (line, column) = (l.line.unwrap(), l.column.unwrap());
        assert_eq!(line, 2, "{msg}");
        assert!(column > 2, "{msg}");
        assert!(
            msg.contains(&format!("TOML parse error at line 2, column {column}\n")),
            "{msg}"
        );
        assert!(
            msg.contains("= line 2 cut: 200002 characters long, 120 shown"),
            "{msg}"
        );
        // The caret stands under the column: the window starts 40 characters before
        // it, after the `…` that marks the cut.
        let lines: Vec<&str> = msg.lines().collect();
        let quoted = lines.iter().position(|l| l.starts_with("2 | ")).unwrap();
        let caret_line = lines[quoted + 1];
        let caret_at = caret_line.find('^').unwrap();
        let window: Vec<char> = lines[quoted].chars().collect();
        let under = window[caret_line[..caret_at].chars().count()];
        let expected = text
            .split('\n')
            .nth(1)
            .unwrap()
            .chars()
            .nth(column - 1)
            .unwrap();
        assert_eq!(under, expected, "{msg}");
        assert!(
            lines[quoted].starts_with("2 | …") && lines[quoted].ends_with('…'),
            "{msg}"
        );
    }

    /// A value that serde quotes in its message (half a megabyte where a number goes)
    /// and an unknown key as long as a file: an excerpt of each.
    #[test]
    fn huge_values_and_keys_are_quoted_by_an_excerpt() {
        let long = "x".repeat(500_000);
        let text = format!("name = \"x\"\n[rates]\nsensor_hz = \"{long}\"\noutput_hz = 1.0\n");
        let e = from_str::<Raw>(&text, "s.toml").unwrap_err();
        let msg = e.to_string();
        assert!(msg.len() < 2048, "{} bytes", msg.len());
        assert!(msg.contains("more bytes cut"), "{msg}");
        assert_eq!(e.location().line, Some(3));
        let text = format!("name = \"x\"\n{long} = 1\n[rates]\nsensor_hz = 1.0\noutput_hz = 1.0\n");
        let e = from_str::<Raw>(&text, "s.toml").unwrap_err();
        let msg = e.to_string();
        assert!(msg.len() < 1024, "{} bytes", msg.len());
        assert!(
            msg.contains("line 2, column 1: xxxx") && msg.contains("more bytes cut"),
            "{msg}"
        );
        // A text longer than a configuration file may be is not parsed.
        let huge = format!("# {}\n", "y".repeat(bounds::MAX_FILE_BYTES as usize));
        let e = from_str::<Raw>(&huge, "big.toml").unwrap_err();
        assert_eq!(
            e.to_string(),
            "big.toml: 1048579 bytes: a configuration file holds at most 1048576 bytes (1 MiB)"
        );
    }

    #[test]
    fn edit_distance_counts_characters() {
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(edit_distance("", "ab"), 2);
        assert_eq!(edit_distance("nmae", "name"), 1);
        assert_eq!(
            near_miss("Window_S", &["window_s".into()]).as_deref(),
            Some("window_s")
        );
        assert_eq!(near_miss("zzz", &["window_s".into()]), None);
    }
}
