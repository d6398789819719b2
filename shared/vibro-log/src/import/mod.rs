//! Importing rig data recorded as CSV: a log with the simulator's topics and wire types
//! (`/accel` AccelBlock, `/vib` VibBlock), so that it replays like a simulated flight
//! (docs/logs.md, "log import").
//!
//! Each file is read twice. The first pass (the scanner, `scan.rs`, over the CSV
//! reader of `csv.rs`) validates every row (every problem, up to [`MAX_PROBLEMS`] per
//! file, is reported at once, and nothing is written) and finds the sample rate and
//! the gaps on the time grid (`timeline.rs`). The second (the block maker,
//! `blocks.rs`) cuts the rows into blocks as the rig's [`crate::rig::Packetizer`] does
//! and checks each row against the uniform time grid; [`import`] writes the blocks of
//! both streams in time order into a temporary file that is renamed over the output
//! only when the log is complete.
//!
//! The options are checked all at once ([`ImportPlan::try_from`] an [`ImportOptions`]);
//! the caller draws the progress ([`ImportProgress`]) and prints the [`ImportReport`].
//!
//! ```no_run
//! use vibro_log::import::{import, ImportOptions, ImportPlan};
//! # fn main() -> vibro_log::Result<()> {
//! let options = ImportOptions::new(Some("accel.csv".into()), Some("vib.csv".into()), "rig.mcap".into());
//! // Every bad option at once, then the output (exists? an input?).
//! let plan = ImportPlan::try_from(&options)?;
//! let report = import(&plan, &mut ())?;
//! println!("{} messages into {}", report.messages, report.out);
//! # Ok(())
//! # }
//! ```

mod blocks;
mod csv;
mod lines;
mod plan;
mod progress;
mod reference;
mod scan;
mod timeline;
mod write;

use serde::Serialize;
use vibro_msgs::Stream;
use vibro_msgs::{ACCEL_BLOCK_MAX, VIB_BLOCK_MAX};

pub use lines::{LineReader, MAX_LINE_BYTES};
pub use plan::{ImportOptions, ImportPlan};
pub use progress::ImportProgress;
pub use write::{import, read_csv_blocks, ImportReport, ReferenceReport, StreamReport};

/// At most this many problems are listed per CSV file before reading stops.
pub const MAX_PROBLEMS: usize = 20;
/// The nominal period is the median interval of the first rows, this many intervals at
/// most: robust to a gap among them, and known before the file has been read through.
const RATE_PROBE_INTERVALS: usize = 1000;
/// An interval longer than this many periods is a gap (shorter ones must be one period).
const GAP_PERIODS: f64 = 1.5;
/// Default tolerance on row times, as a fraction of the sample period.
pub const DEFAULT_PERIOD_TOLERANCE: f64 = 0.1;
/// The largest time a `u64` of nanoseconds holds, in seconds (rounded down).
const MAX_TIME_S: f64 = 1.8e10;

/// Which stream a CSV file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ImportKind {
    /// Accelerometer outputs (`--accel`): `/accel`, AccelBlock.
    Accel,
    /// Vibration-sensor outputs (`--vib`): `/vib`, VibBlock.
    Vib,
}

impl ImportKind {
    /// `accel` or `vib`: the flag, the metadata keys' prefix.
    pub fn name(self) -> &'static str {
        match self {
            ImportKind::Accel => "accel",
            ImportKind::Vib => "vib",
        }
    }

    /// The stream it becomes.
    pub fn stream(self) -> Stream {
        match self {
            ImportKind::Accel => Stream::Accel,
            ImportKind::Vib => Stream::Vib,
        }
    }

    /// The documented columns: time, then one per unit.
    pub fn columns(self) -> [&'static str; 4] {
        match self {
            ImportKind::Accel => ["time_s", "u1_v", "u2_v", "u3_v"],
            ImportKind::Vib => ["time_s", "vd1_v", "vd2_v", "vd3_v"],
        }
    }

    pub(crate) fn units(self) -> [&'static str; 3] {
        match self {
            ImportKind::Accel => ["AK1", "AK2", "AK3"],
            ImportKind::Vib => ["VD1", "VD2", "VD3"],
        }
    }

    /// The wire field the unit columns fill.
    pub(crate) fn field(self) -> &'static str {
        match self {
            ImportKind::Accel => "output_v",
            ImportKind::Vib => "sample_v",
        }
    }

    /// What the time column means, which is what the block's `t0_ns` means.
    pub(crate) fn time_meaning(self) -> &'static str {
        match self {
            ImportKind::Accel => "time the reading was latched, the end of its averaging interval",
            ImportKind::Vib => "time the sample was taken",
        }
    }

    /// The wire type's capacity in samples.
    pub fn max_block(self) -> usize {
        match self {
            ImportKind::Accel => ACCEL_BLOCK_MAX,
            ImportKind::Vib => VIB_BLOCK_MAX,
        }
    }

    /// The option that gives its rate.
    pub fn rate_flag(self) -> &'static str {
        match self {
            ImportKind::Accel => "--accel-rate-hz",
            ImportKind::Vib => "--vib-rate-hz",
        }
    }
}
