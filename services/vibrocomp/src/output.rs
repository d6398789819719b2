//! Printing results: a readable table for people, JSON (`--json`) for scripts.

use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};

/// `-q/--quiet` was given: no progress bars (and log lines at `error` only, through
/// `RUST_LOG`, which the services started as children inherit).
static QUIET: AtomicBool = AtomicBool::new(false);

/// Sets the `-q/--quiet` and `-v/--verbose` levels for this process and its children.
pub fn set_verbosity(quiet: bool, verbose: u8) {
    QUIET.store(quiet, Ordering::Relaxed);
    let level = match (quiet, verbose) {
        (true, _) => Some("error"),
        (false, 0) => None,
        (false, 1) => Some("debug"),
        (false, _) => Some("trace"),
    };
    if let Some(level) = level {
        // Before any thread starts (the first thing `main_with_args` does).
        std::env::set_var("RUST_LOG", level);
    }
}

/// Where a progress bar draws: stderr, or nowhere under `-q`.
pub fn progress_target() -> indicatif::ProgressDrawTarget {
    if QUIET.load(Ordering::Relaxed) {
        indicatif::ProgressDrawTarget::hidden()
    } else {
        indicatif::ProgressDrawTarget::stderr()
    }
}

/// A progress bar of `len` steps drawn with `template` (indicatif's), only when stderr
/// is a terminal: redirected stderr (scripts, tests) stays clean.
pub fn progress_bar(len: u64, template: &str) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::with_draw_target(Some(len), progress_target());
    if let Ok(style) = indicatif::ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar
}

/// A write to stdout failed because its reader closed the pipe (`vibrocomp ... | head`).
/// Every printing path returns it as an error so that the command stops there;
/// [`crate::main_with_args`] turns it into a quiet exit 0. It is its own type, not a
/// bare `io::Error`, so that a broken pipe elsewhere (a child process, a socket) is
/// still reported.
#[derive(Debug)]
pub struct StdoutClosed;

impl std::fmt::Display for StdoutClosed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("stdout was closed by its reader")
    }
}

impl std::error::Error for StdoutClosed {}

/// A command that did its work and printed its result, but whose exit status must
/// say that the result is partial (`log recover` with losses: 3). Returned as an error
/// so that the command stops there; [`crate::main_with_args`] exits with the status
/// and prints nothing more (the result, text or JSON, already says it).
#[derive(Debug)]
pub struct ExitStatus(pub u8);

impl std::fmt::Display for ExitStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "finished with exit status {}", self.0)
    }
}

impl std::error::Error for ExitStatus {}

/// The exit status `e` asks for, if it is an [`ExitStatus`].
pub fn exit_status(e: &anyhow::Error) -> Option<u8> {
    e.chain()
        .find_map(|cause| cause.downcast_ref::<ExitStatus>())
        .map(|s| s.0)
}

/// Whether `e` (anywhere in its chain) is a closed stdout.
pub fn is_stdout_closed(e: &anyhow::Error) -> bool {
    e.chain().any(|cause| cause.is::<StdoutClosed>())
}

fn stdout_error(e: std::io::Error) -> anyhow::Error {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        anyhow::Error::new(StdoutClosed)
    } else {
        anyhow::Error::new(e).context("writing to stdout")
    }
}

/// Writes formatted text on stdout: the one path of the commands' human output (through
/// [`out!`](crate::out) and [`outln!`](crate::outln)). `print!` would panic on a
/// closed pipe; this returns [`StdoutClosed`].
pub fn write_stdout(args: std::fmt::Arguments<'_>) -> anyhow::Result<()> {
    use std::io::Write;
    std::io::stdout()
        .lock()
        .write_fmt(args)
        .map_err(stdout_error)
}

/// Flushes stdout (at the end of a command), a closed pipe giving [`StdoutClosed`].
pub fn flush_stdout() -> anyhow::Result<()> {
    use std::io::Write;
    std::io::stdout().lock().flush().map_err(stdout_error)
}

/// `print!` for the commands' output: returns `anyhow::Result<()>` instead of panicking
/// on a closed pipe. Use with `?`.
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::output::write_stdout(format_args!($($arg)*))
    };
}

/// `println!` for the commands' output: returns `anyhow::Result<()>` instead of
/// panicking on a closed pipe. Use with `?`.
#[macro_export]
macro_rules! outln {
    () => {
        $crate::output::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::output::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// Prints `value` as pretty JSON on stdout (a closed pipe: [`StdoutClosed`]).
pub fn print_json<T: Serialize>(value: &T) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    outln!("{text}")?;
    flush_stdout()
}

/// Prints text on stdout (a closed pipe: [`StdoutClosed`]).
pub fn print_text(text: &str) -> anyhow::Result<()> {
    out!("{text}")?;
    flush_stdout()
}

/// Formats a plain number (a flag's value, a duration) as `{}` does while it is short
/// (0, or 1e-4 <= |x| < 1e6), and in exponent form beyond (`1e300`, `1.5e-9`) instead of
/// `{}`'s 300-digit decimals; non-finite values as `{}` (`NaN`, `inf`).
pub fn fmt_num(x: f64) -> String {
    let abs = x.abs();
    if !x.is_finite() || abs == 0.0 || (1e-4..1e6).contains(&abs) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Formats `x` with `decimals` decimals as `{:.N}` does while |x| < 1e9, and as
/// `{:.3e}` beyond, where fixed point would print hundreds of digits.
pub fn fmt_fixed(x: f64, decimals: usize) -> String {
    if x.is_finite() && x.abs() >= 1e9 {
        format!("{x:.3e}")
    } else {
        format!("{x:.decimals$}")
    }
}

/// Accelerations and ratios as every report prints them (the library's, so that the
/// tables rendered by `vibro_log` and by the commands read alike).
pub use vibro_log::text::{fmt_g, fmt_ratio};
