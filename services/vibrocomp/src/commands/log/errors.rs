//! `vibrocomp log errors`: the stage-error table of a recorded session (docs/logs.md):
//! each compensation stage's error against the log's reference, mean over windows, as
//! `vibrocomp demo` prints it. The measure and the table are `vibro_log::session`.

use std::path::PathBuf;

use clap::Args;
use vibro_log::session::{log_errors, window_problem, DEFAULT_WINDOW_S};

use super::print_text;
use crate::flags::FlagProblems;
use crate::output::print_json;

#[derive(Debug, Args)]
pub struct ErrorsArgs {
    /// A recorded session: the compensated stream (/compensated), the readings (/accel)
    /// and a reference (/truth: the simulator's, or a rig's from `log import --rig`),
    /// with the passports `record` attaches.
    pub file: PathBuf,
    /// Averaging window of the error measure, s.
    #[arg(long = "window-s", default_value_t = DEFAULT_WINDOW_S)]
    pub window_s: f64,
    /// With a rig's reference (`log import --rig`): the triad (a file, or `default`)
    /// whose geometry turns the vibration sensors into the body's vibration, for each
    /// unit's fitted linear response (docs/logs.md).
    #[arg(long, default_value = "default")]
    pub triad: String,
    /// Print the figures as JSON: `{"log", "passports", "errors"}`, `errors` as in
    /// `vibrocomp demo --json`.
    #[arg(long)]
    pub json: bool,
}

pub(super) fn run(args: &ErrorsArgs) -> anyhow::Result<()> {
    let mut problems = FlagProblems::new();
    problems.rule("--window-s", args.window_s, window_problem(args.window_s));
    problems.finish()?;
    let triad = vibro_config::resolve_triad(&args.triad)
        .map_err(|e| anyhow::anyhow!("--triad {}: {e}", args.triad))?;
    let report = log_errors(&args.file, args.window_s, &triad)?;
    if args.json {
        return print_json(&report);
    }
    print_text(|out| report.write_text(out))
}
