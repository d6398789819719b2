//! The latency and soak harness behind `vibrocomp latency`: how late a compensated
//! sample arrives, and how much of that is ours.
//!
//! The process calling [`run`] is the rig: it publishes vibration-sensor and
//! accelerometer blocks in real time at the given rates and receives the compensated
//! blocks, and it measures from the timestamps the messages carry (all `CLOCK_MONOTONIC`, one clock for every
//! process): rig publish -> compensator receive (`recv_ns - input_publish_ns`),
//! compensator receive -> publish (`publish_ns - recv_ns`), compensator publish ->
//! subscriber receive, and end to end. Three pipelines, one after the other, with the
//! same rig, rates and messages:
//!
//! - **vibrocomp**: the real estimator and compensator processes over iceoryx2;
//! - **bare iceoryx2**: a forwarder process with the same hot-loop structure (WaitSet or
//!   spin) that answers each accelerometer block with a compensated block holding its
//!   timestamps and nothing computed, and a sink process that takes the vibration
//!   blocks: the transport alone, for both streams;
//! - **Unix sockets**: one process running the estimator's and the compensator's logic
//!   (`vibro_estimator::InProcess`, `vibro_compensator::InProcess`, the hot loops' own
//!   handlers) on two threads, fed over two Unix stream sockets with the same
//!   fixed-size messages, answering on the accelerometer socket.
//!
//! Each histogram is an HdrHistogram (1 ns .. 60 s, 3 significant digits); the blocks
//! of the first `--warmup-s` of data (before the first vibration estimate, and while
//! caches warm) are left out. CPU use is each process's user + system time from
//! `/proc/PID/stat` over the run, in percent of one core.
//!
//! The estimator runs with `sample_rate_hz = --vib-rate-hz` (a private copy of its
//! default configuration when the rates differ: it refuses blocks at any other rate).
//!
//! **The compensator's stage** (issue 43): its default configuration's `stage`
//! (`waveform` as shipped), or the one [`run_with_stage`] is given (a private copy of
//! its default configuration with `stage` set; `vibrocomp latency --stage`). With the waveform stage the compensator holds each accelerometer block
//! until the vibration samples cover its readings (plus the interpolation's
//! half-width), so the rig keeps the sensors' stream going for one vibration block
//! after the run (`rig::pace`) and the report adds two hops: accelerometer publish ->
//! compensated publish (with the wait), and last input publish -> compensated publish
//! (the vibration block that released the block: without the wait), and the fraction
//! of blocks the stage made (flag `WAVEFORM`).
//!
//! **Soak** (`--soak`, issue 18): the vibrocomp pipeline alone for `--duration-s`,
//! optionally beside a background load (`--load INPUT`: a child process running
//! `vibrocomp lab diagnose INPUT` in a loop, `--load-jobs` at a time, for the whole
//! soak, stopped at its end). It reports every accelerometer block answered (from the
//! compensated blocks' `input_seq`) and the services' own counters, the services'
//! resident memory (`VmRSS` from `/proc/PID/status`, one sample a second: first,
//! last, max, growth and slope after the warm-up), the end-to-end latency's
//! percentiles and buckets per accelerometer block, and p99.9 against one
//! accelerometer sample period. The target is reported, never enforced: a soak that
//! misses it still exits 0.
//!
//! **Processes.** The harness starts the services with [`vibro_system::SystemSpec`]
//! and its own peers as `latency-peer ...` subcommands, both from
//! `std::env::current_exe()`: it must run inside the `vibrocomp` executable, whose
//! hidden `latency-peer` command calls [`run_peer`] with the parsed [`PeerCommand`].
//! The peers' command line is defined here, beside the code that writes it, so that
//! the two cannot drift apart. A service-side harness: errors are `anyhow`, with
//! context at every I/O boundary.
//!
//! ```no_run
//! let options = vibro_latency::Options {
//!     duration_s: 2.0,
//!     warmup_s: 0.5,
//!     ..vibro_latency::Options::default()
//! };
//! match vibro_latency::run(&options)? {
//!     vibro_latency::Report::Pipelines(r) => println!("{} pipelines", r.runs.len()),
//!     vibro_latency::Report::Soak(s) => println!("p99.9 met: {}", s.p999_met),
//! }
//! # Ok::<(), anyhow::Error>(())
//! ```

mod cpu;
mod histogram;
mod hosts;
mod load;
mod memory;
mod peers;
mod pipelines;
mod rig;
mod soak;
mod view;

pub use histogram::{BucketRow, EndToEndHistogram, HopUs, PercentileRow};
pub use load::LoadReport;
pub use memory::{MemorySummary, MEMORY_FLAT_BOUND_KIB};
pub use peers::{run_peer, PeerCommand};
pub use pipelines::{LatencyReport, Loss, PipelineRun, Ratios};
pub use soak::{AccelCheck, ServiceCounts, SoakReport};
pub use view::ViewLoad;

use anyhow::{bail, Context};
use std::path::{Path, PathBuf};
use vibro_service::supervise::private_prefix;
use vibro_service::{LoopMode, ServiceConfig};

/// What to run: the validated flags of `vibrocomp latency`. The defaults are the
/// command's.
#[derive(Debug, Clone)]
pub struct Options {
    /// Length of each pipeline's run (of the soak with [`Options::soak`]).
    pub duration_s: f64,
    /// Accelerometer sample rate.
    pub rate_hz: f64,
    /// Accelerometer samples per block, `1..=ACCEL_BLOCK_MAX`.
    pub block_samples: u32,
    /// Vibration-sensor sample rate (the estimator runs at it).
    pub vib_rate_hz: f64,
    /// Vibration-sensor samples per block, `1..=VIB_BLOCK_MAX`.
    pub vib_block_samples: u32,
    /// Loop mode of the services and of the rig's receiver.
    pub mode: LoopMode,
    /// Data time left out at the start, `0 <= warmup_s < duration_s`.
    pub warmup_s: f64,
    /// Also the bare-iceoryx2 and socket baselines (and bare Zenoh with two hosts).
    pub baselines: bool,
    /// The soak instead of the pipelines: the vibrocomp pipeline only, checked block by
    /// block, with the services' memory sampled.
    pub soak: bool,
    /// With `soak`: the background load.
    pub load: Option<Load>,
    /// The vibrocomp pipeline's service-name prefix, valid [default: a private one,
    /// `vclat-PID/`]. The baselines always use private prefixes.
    pub prefix: Option<String>,
    /// `SCHED_FIFO` priority of the services' hot loops and the rig's receiver.
    pub realtime_priority: Option<u8>,
    /// The vibrocomp pipeline with the live view and one Foxglove client attached.
    pub view: bool,
    /// Also the vibrocomp pipeline across two hosts on this machine (and bare Zenoh).
    pub two_hosts: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            duration_s: 5.0,
            rate_hz: 800.0,
            block_samples: 32,
            vib_rate_hz: 25600.0,
            vib_block_samples: 512,
            mode: LoopMode::Event,
            warmup_s: 1.5,
            baselines: true,
            soak: false,
            load: None,
            prefix: None,
            realtime_priority: None,
            view: false,
            two_hosts: false,
        }
    }
}

/// The soak's background load: `vibrocomp lab diagnose INPUT` run in a loop, `jobs`
/// at a time, in a child process for the whole soak.
#[derive(Debug, Clone)]
pub struct Load {
    /// A campaign table or a log (docs/lab.md); an existing file.
    pub input: PathBuf,
    /// `1..=64`.
    pub jobs: u32,
}

/// The longest run, s: the view's `--duration-s` bound (31 years; the harness keeps
/// fixed-size histograms, so only the soak's memory samples grow with it).
pub const MAX_DURATION_S: f64 = 1e9;
/// The shortest run, s.
pub const MIN_DURATION_S: f64 = 1e-3;
/// The accelerometer rates the harness paces, Hz: a block period of at least 10 us
/// (one sample at 100 kHz); beyond it the rig's pacing loop would spin without
/// sleeping (`--rate-hz 1e300` hung at 31 % CPU with no output).
pub const ACCEL_RATE_RANGE_HZ: (f64, f64) = (1.0, 1e5);
/// The vibration-sensor rates, Hz: the simulator's sensor-rate rule (`rates.sensor_hz`,
/// 100..=1e6).
pub const VIB_RATE_RANGE_HZ: (f64, f64) = (100.0, 1e6);

/// The problem of a rate outside `range`, if any.
pub fn rate_problem(rate_hz: f64, range: (f64, f64)) -> Option<String> {
    (!(rate_hz.is_finite() && rate_hz >= range.0 && rate_hz <= range.1))
        .then(|| format!("must be finite within {}..={} Hz", range.0, range.1))
}

/// The problem of a warm-up against the run's length, if any.
pub fn warmup_problem(warmup_s: f64, duration_s: f64) -> Option<&'static str> {
    (!(warmup_s.is_finite() && warmup_s >= 0.0 && warmup_s < duration_s))
        .then_some("must be finite, >= 0 and shorter than --duration-s")
}

impl Options {
    /// The ranges [`run`] relies on (the command checks them first, naming its flags).
    fn check(&self) -> anyhow::Result<()> {
        let mut problems = Vec::new();
        if vibro_service::check_seconds(
            "duration_s",
            self.duration_s,
            MIN_DURATION_S,
            MAX_DURATION_S,
            &mut problems,
        )
        .is_none()
        {
            anyhow::bail!("{}", problems.join("; "));
        }
        if let Some(p) = rate_problem(self.rate_hz, ACCEL_RATE_RANGE_HZ) {
            anyhow::bail!("rate_hz = {:e}: {p}", self.rate_hz);
        }
        if let Some(p) = rate_problem(self.vib_rate_hz, VIB_RATE_RANGE_HZ) {
            anyhow::bail!("vib_rate_hz = {:e}: {p}", self.vib_rate_hz);
        }
        anyhow::ensure!(
            (1..=vibro_msgs::ACCEL_BLOCK_MAX as u32).contains(&self.block_samples)
                && (1..=vibro_msgs::VIB_BLOCK_MAX as u32).contains(&self.vib_block_samples),
            "block_samples = {}, vib_block_samples = {}: must be 1..={} and 1..={}",
            self.block_samples,
            self.vib_block_samples,
            vibro_msgs::ACCEL_BLOCK_MAX,
            vibro_msgs::VIB_BLOCK_MAX
        );
        if let Some(p) = warmup_problem(self.warmup_s, self.duration_s) {
            anyhow::bail!(
                "warmup_s = {:e}: {p} ({:e} s)",
                self.warmup_s,
                self.duration_s
            );
        }
        Ok(())
    }
}

/// What [`run`] measured.
#[derive(Debug)]
pub enum Report {
    /// The pipelines, one after the other (vibrocomp first).
    Pipelines(LatencyReport),
    /// The soak.
    Soak(Box<SoakReport>),
}

/// The compensator's stage in the vibrocomp pipeline (its configuration's `stage`).
pub use vibro_compensator::Stage;

/// [`run_with_stage`] with the compensator's configured stage.
pub fn run(options: &Options) -> anyhow::Result<Report> {
    run_with_stage(options, None)
}

/// Runs the pipelines (or the soak) with the compensator's `stage` (`None`: its
/// configuration's) and returns what they measured. Its temporary files (the
/// processes' shared log, private estimator and compensator configurations) are
/// removed before it returns, an error or not.
pub fn run_with_stage(options: &Options, stage: Option<Stage>) -> anyhow::Result<Report> {
    options.check()?;
    let prefix = match &options.prefix {
        Some(p) => p.clone(),
        None => private_prefix("vclat"),
    };
    let k1 = vibro_compensator::Config::load_default()?
        .model
        .triad
        .passports
        .map(|p| p.k1_v_per_g);
    let tmp = |what: &str| {
        std::env::temp_dir().join(format!("vibrocomp-latency-{}.{what}", std::process::id()))
    };
    let log = tmp("log");
    // The estimator's configuration follows --vib-rate-hz (its blocks are refused at
    // any other rate).
    let estimator_config = estimator_config_for(options.vib_rate_hz, &tmp("estimator.toml"))?;
    let compensator_config = match stage {
        Some(s) => Some(compensator_config_for(s, &tmp("compensator.toml"))?),
        None => None,
    };
    let configs = (estimator_config.as_deref(), compensator_config.as_deref());
    let result = if options.soak {
        soak::run_soak(options, k1, &log, &prefix, configs).map(|r| Report::Soak(Box::new(r)))
    } else {
        pipelines::run_pipelines(options, k1, &log, &prefix, configs).map(Report::Pipelines)
    };
    let _ = std::fs::remove_file(&log);
    for p in [&estimator_config, &compensator_config]
        .into_iter()
        .flatten()
    {
        let _ = std::fs::remove_file(p);
    }
    result
}

/// The compensator's default configuration (the file, else the shipped text) with
/// `stage` set, written to `path` and validated.
fn compensator_config_for(stage: Stage, path: &Path) -> anyhow::Result<PathBuf> {
    type C = vibro_compensator::Config;
    let default = Path::new(<C as ServiceConfig>::DEFAULT_CONFIG_PATH);
    let (text, source) = if default.is_file() {
        (
            vibro_service::read_config_file(default)?,
            default.display().to_string(),
        )
    } else {
        (
            <C as ServiceConfig>::shipped_text().to_string(),
            "the shipped compensator configuration".to_string(),
        )
    };
    let mut table: toml::Table = text.parse().with_context(|| source.clone())?;
    table.insert("stage".into(), toml::Value::String(stage.name().into()));
    vibro_files::write_bytes(path, true, toml::to_string(&table)?.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    <C as ServiceConfig>::load(path)
        .with_context(|| format!("{source} with stage = {:?} is not valid", stage.name()))?;
    Ok(path.to_path_buf())
}

/// The estimator's configuration for `--vib-rate-hz`: `None` (its default one) when
/// the default's `sample_rate_hz` is that rate; else the default's text with
/// `[estimator] sample_rate_hz` set to it, written to `path` and validated.
fn estimator_config_for(vib_rate_hz: f64, path: &Path) -> anyhow::Result<Option<PathBuf>> {
    let default = Path::new(<vibro_estimator::Config as ServiceConfig>::DEFAULT_CONFIG_PATH);
    let (text, source) = if default.is_file() {
        (
            // At most a configuration file's bound, a bigger one refused unread.
            vibro_service::read_config_file(default)?,
            default.display().to_string(),
        )
    } else {
        (
            <vibro_estimator::Config as ServiceConfig>::shipped_text().to_string(),
            "the shipped estimator configuration".to_string(),
        )
    };
    let mut table: toml::Table = text.parse().with_context(|| source.clone())?;
    let Some(est) = table.get_mut("estimator").and_then(|v| v.as_table_mut()) else {
        bail!("{source}: no [estimator] table");
    };
    if est.get("sample_rate_hz").and_then(|v| v.as_float()) == Some(vib_rate_hz) {
        return Ok(None);
    }
    est.insert("sample_rate_hz".into(), toml::Value::Float(vib_rate_hz));
    // A name in /tmp anyone may guess: never through a planted link (`vibro_files`).
    vibro_files::write_bytes(path, true, toml::to_string(&table)?.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    <vibro_estimator::Config as ServiceConfig>::load(path).with_context(|| {
        format!("--vib-rate-hz = {vib_rate_hz}: {source} at this sample rate is not valid")
    })?;
    Ok(Some(path.to_path_buf()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_valid_and_out_of_range_options_are_refused() {
        Options::default().check().unwrap();
        for bad in [
            Options {
                block_samples: 0,
                ..Options::default()
            },
            Options {
                vib_block_samples: vibro_msgs::VIB_BLOCK_MAX as u32 + 1,
                ..Options::default()
            },
            Options {
                rate_hz: f64::NAN,
                ..Options::default()
            },
            Options {
                warmup_s: 5.0,
                ..Options::default()
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn the_compensator_runs_the_stage_it_is_given() {
        let path = std::env::temp_dir().join(format!(
            "vibro-latency-test-{}.compensator.toml",
            std::process::id()
        ));
        for stage in [Stage::Estimate, Stage::Waveform] {
            assert_eq!(compensator_config_for(stage, &path).unwrap(), path);
            let text = std::fs::read_to_string(&path).unwrap();
            let table: toml::Table = text.parse().unwrap();
            assert_eq!(table["stage"].as_str(), Some(stage.name()));
            assert_eq!(Stage::parse(stage.name()).unwrap(), stage);
        }
        let _ = std::fs::remove_file(&path);
        assert!(Stage::parse("fast").is_err());
    }

    #[test]
    fn the_estimator_follows_the_vibration_rate() {
        // Run from this crate's folder: the shipped configuration (25.6 kHz).
        let path = std::env::temp_dir().join(format!(
            "vibro-latency-test-{}.estimator.toml",
            std::process::id()
        ));
        assert_eq!(estimator_config_for(25600.0, &path).unwrap(), None);
        let written = estimator_config_for(51200.0, &path).unwrap();
        assert_eq!(written.as_deref(), Some(path.as_path()));
        // Written, and valid (checked by loading it), at the new rate.
        let text = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        let table: toml::Table = text.parse().unwrap();
        assert_eq!(
            table["estimator"]["sample_rate_hz"].as_float(),
            Some(51200.0)
        );
    }

    #[test]
    fn ratios_compare_end_to_end_medians_and_tails() {
        let hop = |p50_us, p99_us| HopUs {
            p50_us,
            p99_us,
            ..HopUs::default()
        };
        let r = Ratios::new(&hop(300.0, 900.0), &hop(100.0, 300.0), &hop(200.0, 450.0));
        assert_eq!((r.vs_bare_p50, r.vs_bare_p99), (3.0, 3.0));
        assert_eq!((r.added_p50_us, r.added_p99_us), (200.0, 600.0));
        assert_eq!((r.vs_sockets_p50, r.vs_sockets_p99), (1.5, 2.0));
    }
}
