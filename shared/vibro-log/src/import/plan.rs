//! An import's options: as given ([`ImportOptions`]), then checked all at once into a
//! ready-to-use [`ImportPlan`].

use std::path::{Path, PathBuf};

use vibro_msgs::{ACCEL_BLOCK_MAX, VIB_BLOCK_MAX};

use super::{ImportKind, DEFAULT_PERIOD_TOLERANCE};
use crate::output::{check_output, same_file};
use crate::{Error, Result};

/// The options of an import as given (`vibrocomp log import`'s flags, whose names the
/// messages use), before they are checked.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// Accelerometer CSV (`--accel`): becomes `/accel` (AccelBlock).
    pub accel: Option<PathBuf>,
    /// Vibration-sensor CSV (`--vib`): becomes `/vib` (VibBlock).
    pub vib: Option<PathBuf>,
    /// The MCAP log to write (`--out`).
    pub out: PathBuf,
    /// Accelerometer output rate; `None`: measured from the time column.
    pub accel_rate_hz: Option<f64>,
    /// Vibration-sensor sample rate; `None`: measured from the time column.
    pub vib_rate_hz: Option<f64>,
    /// Samples per AccelBlock, 1..=32.
    pub accel_block_samples: usize,
    /// Samples per VibBlock, 1..=512.
    pub vib_block_samples: usize,
    /// `source_id` of every block (the producer: rig or simulator instance).
    pub source_id: u32,
    /// How far a row's time may be from the uniform sample grid, as a fraction of the
    /// sample period (0 < tolerance < 0.5).
    pub period_tolerance: f64,
    /// Overwrite `out` if it exists.
    pub force: bool,
    /// Who writes the log, for its `import` metadata (`tool`), e.g.
    /// `vibrocomp 0.1.0 log import`.
    pub tool: String,
    /// The rig file (`--rig`, `vibro_config::rig`): its reference becomes the log's
    /// reference channel, its triad's passports and sensor chain the log's.
    pub rig: Option<PathBuf>,
    /// The reference stream's CSV (`--reference`), for a rig whose reference is a stream.
    pub reference: Option<PathBuf>,
}

impl ImportOptions {
    /// The defaults of `vibrocomp log import` for the files given: rates measured,
    /// full blocks, source 1, a tenth of a period of tolerance, no overwriting.
    pub fn new(accel: Option<PathBuf>, vib: Option<PathBuf>, out: PathBuf) -> Self {
        Self {
            accel,
            vib,
            out,
            accel_rate_hz: None,
            vib_rate_hz: None,
            accel_block_samples: ACCEL_BLOCK_MAX,
            vib_block_samples: VIB_BLOCK_MAX,
            source_id: 1,
            period_tolerance: DEFAULT_PERIOD_TOLERANCE,
            force: false,
            tool: format!("vibro-log {}", env!("CARGO_PKG_VERSION")),
            rig: None,
            reference: None,
        }
    }
}

/// One CSV file to import, its options validated.
#[derive(Debug, Clone)]
pub(super) struct StreamSpec {
    pub(super) kind: ImportKind,
    pub(super) file: PathBuf,
    pub(super) rate_hz: Option<f64>,
    pub(super) block_samples: usize,
}

/// An import's options, validated: what [`super::import`] runs.
#[derive(Debug, Clone)]
pub struct ImportPlan {
    /// Vibration first: in a tie of block times it is written first, as the simulator
    /// does.
    pub(super) streams: Vec<StreamSpec>,
    pub(super) out: PathBuf,
    pub(super) source_id: u32,
    pub(super) tolerance: f64,
    pub(super) tool: String,
    /// The rig, validated, and the reference stream's file.
    pub(super) rig: Option<vibro_config::RigConfig>,
    pub(super) reference: Option<PathBuf>,
    /// Replace `out` if it exists (it is renamed over it when complete).
    pub(super) force: bool,
}

impl ImportPlan {
    /// The log to write.
    pub fn out(&self) -> &Path {
        &self.out
    }
}

impl TryFrom<&ImportOptions> for ImportPlan {
    type Error = Error;

    /// Checks every option and reports all problems at once ([`Error::ImportOptions`]),
    /// then the output file ([`check_output`]).
    fn try_from(args: &ImportOptions) -> Result<ImportPlan> {
        let mut problems = Vec::new();
        let mut streams = Vec::new();
        for (kind, file, rate_hz, block_samples, block_flag) in [
            (
                ImportKind::Vib,
                &args.vib,
                args.vib_rate_hz,
                args.vib_block_samples,
                "--vib-block-samples",
            ),
            (
                ImportKind::Accel,
                &args.accel,
                args.accel_rate_hz,
                args.accel_block_samples,
                "--accel-block-samples",
            ),
        ] {
            if let Some(r) = rate_hz {
                if !(r.is_finite() && (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&r)) {
                    // `{:e}` beyond the range: `{}` prints 1e300 with 301 digits.
                    let shown = if r.is_finite() {
                        format!("{r:e}")
                    } else {
                        format!("{r}")
                    };
                    problems.push(format!(
                        "{} = {shown}: must be finite and 1e-3 <= rate <= 1e9 Hz (a period between 1 ns and 1000 s)",
                        kind.rate_flag()
                    ));
                }
                if file.is_none() {
                    problems.push(format!(
                        "{} = {r} given without --{} CSV",
                        kind.rate_flag(),
                        kind.name()
                    ));
                }
            }
            if !(1..=kind.max_block()).contains(&block_samples) {
                problems.push(format!(
                    "{block_flag} = {block_samples}: must be 1..={} (the wire type's capacity)",
                    kind.max_block()
                ));
            }
            if let Some(file) = file {
                streams.push(StreamSpec {
                    kind,
                    file: file.clone(),
                    rate_hz,
                    block_samples,
                });
            }
        }
        if streams.is_empty() {
            problems.push("nothing to import: give --accel CSV, --vib CSV, or both".to_string());
        }
        let tolerance = args.period_tolerance;
        if !(tolerance.is_finite() && tolerance > 0.0 && tolerance < 0.5) {
            problems.push(format!(
                "--period-tolerance = {tolerance}: must be > 0 and < 0.5 (of a period), so that a whole number of periods is unambiguous"
            ));
        }
        if let [a, b] = streams.as_slice() {
            if same_file(&a.file, &b.file) {
                problems.push(format!(
                    "--accel and --vib name the same file {}: the streams have different columns",
                    a.file.display()
                ));
            }
        }
        let rig = match &args.rig {
            Some(path) => match vibro_config::load_rig(path) {
                Ok(rig) => Some(rig),
                Err(e) => {
                    problems.push(format!("--rig {}: {e}", path.display()));
                    None
                }
            },
            None => None,
        };
        if args.rig.is_some() && args.accel.is_none() {
            problems.push(
                "--rig given without --accel CSV: the reference is written beside the readings"
                    .to_string(),
            );
        }
        if let (Some(r), None) = (&args.reference, &args.rig) {
            problems.push(format!(
                "--reference {} given without --rig FILE: the rig file says what the \
                 reference is (reference.kind = \"stream\", its columns) and how the triad sits",
                r.display()
            ));
        }
        if !problems.is_empty() {
            return Err(Error::ImportOptions { problems });
        }
        let mut inputs: Vec<&Path> = streams.iter().map(|s| s.file.as_path()).collect();
        inputs.extend(args.rig.as_deref());
        inputs.extend(args.reference.as_deref());
        check_output(&args.out, &inputs, args.force)?;
        Ok(ImportPlan {
            streams,
            out: args.out.clone(),
            source_id: args.source_id,
            tolerance,
            tool: args.tool.clone(),
            rig,
            reference: args.reference.clone(),
            force: args.force,
        })
    }
}

/// The sample rates a CSV stream may be given: a period of at least 1 ns (the
/// timestamps' resolution) and at most 1000 s (no rig samples more slowly; 5e-324 Hz,
/// accepted before, made the period infinite).
const MIN_RATE_HZ: f64 = 1e-3;
const MAX_RATE_HZ: f64 = 1e9;

#[cfg(test)]
mod tests {
    use super::*;

    /// Every problem of the options at once, each naming the flag and its value.
    #[test]
    fn the_plan_lists_every_bad_option() {
        let mut o = ImportOptions::new(None, None, PathBuf::from("/nowhere/out.mcap"));
        o.accel_rate_hz = Some(f64::NAN);
        o.vib_block_samples = 513;
        o.period_tolerance = 0.5;
        let Err(Error::ImportOptions { problems }) = ImportPlan::try_from(&o) else {
            panic!("bad options accepted");
        };
        let text = problems.join("\n");
        let mut tiny = ImportOptions::new(Some(PathBuf::from("a.csv")), None, PathBuf::from("o"));
        tiny.accel_rate_hz = Some(5e-324);
        let Err(Error::ImportOptions { problems }) = ImportPlan::try_from(&tiny) else {
            panic!("a rate of 5e-324 Hz accepted");
        };
        assert!(
            problems[0].starts_with("--accel-rate-hz = 5e-324: must be finite and 1e-3"),
            "{problems:?}"
        );
        for want in [
            "--accel-rate-hz = NaN: must be finite",
            "--accel-rate-hz = NaN given without --accel CSV",
            "--vib-block-samples = 513: must be 1..=512",
            "nothing to import",
            "--period-tolerance = 0.5",
        ] {
            assert!(text.contains(want), "{want:?} not in:\n{text}");
        }
    }
}
