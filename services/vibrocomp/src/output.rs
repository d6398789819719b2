//! Printing results: a readable table for people, JSON (`--json`) for scripts.

use serde::Serialize;

/// Prints `value` as pretty JSON on stdout. A closed pipe (`vibrocomp ... --json | head`)
/// ends the output quietly instead of panicking.
pub fn print_json<T: Serialize>(value: &T) -> anyhow::Result<()> {
    use std::io::Write;
    let text = serde_json::to_string_pretty(value)?;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}") {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// Prints text on stdout; a closed pipe (`vibrocomp ... | head`) ends the output
/// quietly instead of panicking.
pub fn print_text(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// Formats an acceleration in g with an engineering prefix chosen for readability
/// (g, mg, ug), keeping four significant digits.
pub fn fmt_g(value_g: f64) -> String {
    let abs = value_g.abs();
    if abs == 0.0 {
        "0 g".to_string()
    } else if abs >= 0.1 {
        format!("{value_g:.4} g")
    } else if abs >= 1e-4 {
        format!("{:.4} mg", value_g * 1e3)
    } else if abs >= 1e-8 {
        format!("{:.4} ug", value_g * 1e6)
    } else {
        format!("{value_g:.1e} g")
    }
}

/// Formats a ratio such as an error reduction: `34.5x`, or `>1e6x` beyond a million.
pub fn fmt_ratio(ratio: f64) -> String {
    if ratio > 1e6 {
        ">1e6x".to_string()
    } else {
        format!("{ratio:.1}x")
    }
}
