//! `vibrocomp log import`: rig data recorded as CSV into a log with the simulator's
//! topics and wire types (docs/logs.md). The import is `vibro_log::import`; this is its
//! command line: the flags, the progress bar and the report.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use indicatif::ProgressBar;
use vibro_log::import::{
    import, ImportOptions, ImportPlan, ImportProgress, ImportReport, DEFAULT_PERIOD_TOLERANCE,
};
use vibro_msgs::{ACCEL_BLOCK_MAX, VIB_BLOCK_MAX};

use super::{fmt_sig, print_text};
use crate::output::print_json;

/// Inputs smaller than this are imported without a progress bar.
const PROGRESS_MIN_BYTES: u64 = 4 << 20;

#[derive(Debug, Args)]
pub struct ImportArgs {
    /// Accelerometer CSV: columns time_s, u1_v, u2_v, u3_v (time the reading was
    /// latched, in s; unit outputs of AK1..AK3 in V). Becomes `/accel` (AccelBlock).
    #[arg(long, value_name = "CSV", required_unless_present = "vib")]
    pub accel: Option<PathBuf>,
    /// Vibration-sensor CSV: columns time_s, vd1_v, vd2_v, vd3_v (sample time in s;
    /// sensor outputs of VD1..VD3 in V). Becomes `/vib` (VibBlock).
    #[arg(long, value_name = "CSV")]
    pub vib: Option<PathBuf>,
    /// The MCAP log to write.
    #[arg(long, value_name = "OUT.mcap")]
    pub out: PathBuf,
    /// Accelerometer output rate (default: measured from the time column).
    #[arg(long)]
    pub accel_rate_hz: Option<f64>,
    /// Vibration-sensor sample rate (default: measured from the time column).
    #[arg(long)]
    pub vib_rate_hz: Option<f64>,
    /// Samples per AccelBlock, 1..=32.
    #[arg(long, default_value_t = ACCEL_BLOCK_MAX)]
    pub accel_block_samples: usize,
    /// Samples per VibBlock, 1..=512.
    #[arg(long, default_value_t = VIB_BLOCK_MAX)]
    pub vib_block_samples: usize,
    /// `source_id` of every block (the producer: rig or simulator instance).
    #[arg(long, default_value_t = 1)]
    pub source_id: u32,
    /// How far a row's time may be from the uniform sample grid, as a fraction of the
    /// sample period (0 < tolerance < 0.5).
    #[arg(long, default_value_t = DEFAULT_PERIOD_TOLERANCE)]
    pub period_tolerance: f64,
    /// A rig file (docs/logs.md, "A rig's own data"): the triad, the vibration
    /// sensors' chain and the reference (static orientations, a centrifuge or a
    /// stream). Writes the reference channel (`/truth`, flagged SENSED_UNKNOWN), the
    /// triad's passports and the sensor chain into the log, so that the lab and `log
    /// errors` take it as it is. Needs --accel.
    #[arg(long, value_name = "RIG.toml")]
    pub rig: Option<PathBuf>,
    /// The reference stream's CSV (time_s and one column per body axis, in g) of a
    /// rig whose reference is a stream (`[reference] kind = "stream"`).
    #[arg(long, value_name = "CSV", requires = "rig")]
    pub reference: Option<PathBuf>,
    /// Overwrite OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

impl From<&ImportArgs> for ImportOptions {
    fn from(args: &ImportArgs) -> Self {
        ImportOptions {
            accel: args.accel.clone(),
            vib: args.vib.clone(),
            out: args.out.clone(),
            accel_rate_hz: args.accel_rate_hz,
            vib_rate_hz: args.vib_rate_hz,
            accel_block_samples: args.accel_block_samples,
            vib_block_samples: args.vib_block_samples,
            source_id: args.source_id,
            period_tolerance: args.period_tolerance,
            force: args.force,
            tool: format!("vibrocomp {} log import", env!("CARGO_PKG_VERSION")),
            rig: args.rig.clone(),
            reference: args.reference.clone(),
        }
    }
}

/// A progress bar over the bytes of both passes; hidden unless stderr is a terminal and
/// the inputs are large.
struct Bar(ProgressBar);

impl ImportProgress for Bar {
    fn start(&mut self, total_bytes: u64) {
        if total_bytes >= PROGRESS_MIN_BYTES {
            let template = "{msg} {bar:40} {bytes}/{total_bytes} ({eta} left)";
            self.0 = crate::output::progress_bar(total_bytes, template);
        }
    }

    fn pass(&mut self, name: &'static str) {
        self.0.set_message(name);
    }

    fn position(&mut self, bytes: u64) {
        self.0.set_position(bytes);
    }

    fn finish(&mut self) {
        self.0.finish_and_clear();
    }
}

pub(super) fn run(args: &ImportArgs) -> anyhow::Result<()> {
    let plan = ImportPlan::try_from(&ImportOptions::from(args))?;
    let report = import(&plan, &mut Bar(ProgressBar::hidden()))?;
    if args.json {
        return print_json(&report);
    }
    print_text(|out| write_import(out, &report))
}

fn write_import(out: &mut String, r: &ImportReport) -> std::fmt::Result {
    writeln!(
        out,
        "Imported {} stream(s) into {}: {} messages, {} chunks, {} bytes, in {:.2} s ({:.2e} rows/s)",
        r.streams.len(),
        r.out,
        r.messages,
        r.chunks,
        r.bytes,
        r.elapsed_s,
        r.rows_per_s
    )?;
    if let Some(x) = &r.reference {
        writeln!(
            out,
            "  {:<7} the {} reference of {}{}: {} readings, {} without a reference (between orientations)",
            x.topic,
            x.kind,
            x.rig,
            x.file.as_deref().map(|f| format!(" ({f})")).unwrap_or_default(),
            x.readings,
            x.readings_without_reference
        )?;
    }
    for s in &r.streams {
        writeln!(
            out,
            "  {:<7} {}: {} rows -> {} {}s of up to {} samples, {} gap(s), {} sample(s) missing",
            s.topic,
            s.file,
            s.rows,
            s.blocks,
            s.message_type,
            s.block_samples,
            s.gaps,
            s.missing_samples
        )?;
        writeln!(
            out,
            "          rate {} Hz, period {} ns ({})",
            fmt_sig(s.rate_hz),
            s.sample_period_ns,
            s.rate_from
        )?;
        writeln!(
            out,
            "          time {} .. {} s; every row within {:.2e} s of the uniform grid",
            fmt_sig(s.first_time_s),
            fmt_sig(s.last_time_s),
            s.max_time_residual_s
        )?;
        let columns: Vec<String> = s
            .columns
            .iter()
            .map(|(n, c)| format!("{n} (column {c})"))
            .collect();
        writeln!(
            out,
            "          columns: {}{}",
            columns.join(", "),
            if s.ignored_columns.is_empty() {
                String::new()
            } else {
                format!("; ignored: {}", s.ignored_columns.join(", "))
            }
        )?;
    }
    Ok(())
}
