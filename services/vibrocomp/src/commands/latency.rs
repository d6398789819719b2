//! `vibrocomp latency`: how late a compensated sample arrives, and how much of that is
//! ours; with `--soak`, the vibrocomp pipeline alone for a long run (issue 18). The
//! harness is `vibro_latency` (its crate documentation says what is measured and
//! how); this file parses and checks the flags, calls it and prints its report.

use anyhow::Context;
use std::path::PathBuf;
use vibro_latency::{LatencyReport, Options, PipelineRun, Report, SoakReport};
use vibro_msgs::ServiceNames;
use vibro_service::LoopMode;

use crate::output::print_json;

use crate::flags::FlagProblems;
/// The hidden `latency-peer` command: the harness's own peers, defined beside it.
pub use vibro_latency::{run_peer, PeerCommand};

#[derive(Debug, Clone, clap::Args)]
pub struct LatencyArgs {
    /// Length of each pipeline's run, s.
    #[arg(long = "duration-s", default_value_t = 5.0)]
    pub duration_s: f64,
    /// Accelerometer sample rate, Hz.
    #[arg(long = "rate-hz", default_value_t = 800.0)]
    pub rate_hz: f64,
    /// Accelerometer samples per block (1..32).
    #[arg(long = "block-samples", default_value_t = 32)]
    pub block_samples: u32,
    /// Vibration-sensor sample rate, Hz (the estimator's configuration must match).
    #[arg(long = "vib-rate-hz", default_value_t = 25600.0)]
    pub vib_rate_hz: f64,
    /// Vibration-sensor samples per block (1..512).
    #[arg(long = "vib-block-samples", default_value_t = 512)]
    pub vib_block_samples: u32,
    /// Loop mode of the services and of the rig's receiver: event or spin.
    #[arg(long, default_value = "event")]
    pub mode: LoopMode,
    /// Data time left out at the start, s.
    #[arg(long = "warmup-s", default_value_t = 1.5)]
    pub warmup_s: f64,
    /// Only the vibrocomp pipeline (no bare-iceoryx2 and socket baselines).
    #[arg(long)]
    pub no_baselines: bool,
    /// Soak: the vibrocomp pipeline only, for `--duration-s`, with every accelerometer
    /// block's input sequence checked, the services' resident memory sampled every
    /// second, and the end-to-end histogram; a 10x vibration rate is `--vib-rate-hz
    /// 256000`.
    #[arg(long)]
    pub soak: bool,
    /// With `--soak`: a background load, `vibrocomp lab diagnose INPUT` run in a loop
    /// in a child process for the whole soak (a campaign table or a log, docs/lab.md).
    #[arg(long, value_name = "INPUT", requires = "soak")]
    pub load: Option<PathBuf>,
    /// With `--load`: how many diagnose loops run side by side.
    #[arg(long = "load-jobs", default_value_t = 1, requires = "load")]
    pub load_jobs: u32,
    /// The vibrocomp pipeline's service-name prefix [default: a private one,
    /// `vclat-PID/`]. The baselines always use private prefixes.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Run the services' hot loops and the rig's receiver under SCHED_FIFO at this
    /// priority (1..=99; needs CAP_SYS_NICE), as a real-time deployment would: a block
    /// then wakes its process ahead of any normal-priority work, a `--load` included.
    #[arg(long, value_name = "1..99", value_parser = clap::value_parser!(u8).range(1..=99))]
    pub realtime_priority: Option<u8>,
    /// Run the vibrocomp pipeline with the live view attached (`vibrocomp view` on a
    /// free port of 127.0.0.1) and one Foxglove client subscribed to every view channel
    /// and reading all it is sent: what a connected viewer costs the services.
    #[arg(long)]
    pub view: bool,
    /// 2: also the vibrocomp pipeline across two hosts on this machine (the services
    /// in another iceoryx2 root, two Zenoh bridges over a Unix socket between), and a
    /// bare Zenoh publisher/subscriber pair over loopback TCP as its baseline
    /// (docs/bridge.md).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub hosts: u8,
    /// The compensator's stage: `waveform` (as shipped: each reading solved from the
    /// vibration samples) or `estimate` (the paper's stages (17)-(20) only).
    #[arg(long, value_name = "waveform|estimate", value_parser = ["waveform", "estimate"])]
    pub stage: Option<String>,
    /// Print the measured latencies as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &LatencyArgs) -> anyhow::Result<()> {
    let options = options(args)?;
    let stage = args
        .stage
        .as_deref()
        .map(vibro_latency::Stage::parse)
        .transpose()
        .map_err(|rule| anyhow::anyhow!("--stage {rule}"))?;
    match vibro_latency::run_with_stage(&options, stage)? {
        Report::Soak(soak) if args.json => print_json(&soak),
        Report::Soak(soak) => print_soak(&soak),
        Report::Pipelines(report) if args.json => print_json(&report),
        Report::Pipelines(report) => print_latency(&options, &report),
    }
}

/// The flags, checked, as the harness's options.
fn options(args: &LatencyArgs) -> anyhow::Result<Options> {
    let mut problems = FlagProblems::new();
    problems.seconds(
        "--duration-s",
        args.duration_s,
        vibro_latency::MIN_DURATION_S,
        vibro_latency::MAX_DURATION_S,
    );
    problems.rule(
        "--rate-hz",
        args.rate_hz,
        vibro_latency::rate_problem(args.rate_hz, vibro_latency::ACCEL_RATE_RANGE_HZ),
    );
    problems.rule(
        "--vib-rate-hz",
        args.vib_rate_hz,
        vibro_latency::rate_problem(args.vib_rate_hz, vibro_latency::VIB_RATE_RANGE_HZ),
    );
    problems.count(
        "--block-samples",
        args.block_samples.into(),
        (!(1..=vibro_msgs::ACCEL_BLOCK_MAX as u32).contains(&args.block_samples))
            .then(|| format!("must be 1..={}", vibro_msgs::ACCEL_BLOCK_MAX)),
    );
    problems.count(
        "--vib-block-samples",
        args.vib_block_samples.into(),
        (!(1..=vibro_msgs::VIB_BLOCK_MAX as u32).contains(&args.vib_block_samples))
            .then(|| format!("must be 1..={}", vibro_msgs::VIB_BLOCK_MAX)),
    );
    problems.rule(
        "--warmup-s",
        args.warmup_s,
        vibro_latency::warmup_problem(args.warmup_s, args.duration_s),
    );
    problems.finish()?;
    anyhow::ensure!(
        (1..=64).contains(&args.load_jobs),
        "--load-jobs = {}: must be 1..=64",
        args.load_jobs
    );
    if let Some(input) = &args.load {
        anyhow::ensure!(
            input.is_file(),
            "--load {}: not a file (a campaign table or an MCAP log for `lab diagnose`)",
            input.display()
        );
    }
    if let Some(p) = &args.prefix {
        ServiceNames::new(p).with_context(|| format!("--prefix {p:?}"))?;
    }
    Ok(Options {
        duration_s: args.duration_s,
        rate_hz: args.rate_hz,
        block_samples: args.block_samples,
        vib_rate_hz: args.vib_rate_hz,
        vib_block_samples: args.vib_block_samples,
        mode: args.mode,
        warmup_s: args.warmup_s,
        baselines: !args.no_baselines,
        soak: args.soak,
        load: args.load.clone().map(|input| vibro_latency::Load {
            input,
            jobs: args.load_jobs,
        }),
        prefix: args.prefix.clone(),
        realtime_priority: args.realtime_priority,
        view: args.view,
        two_hosts: args.hosts == 2,
    })
}

fn print_latency(options: &Options, report: &LatencyReport) -> anyhow::Result<()> {
    outln!(
        "Latency, {} mode: {} s per pipeline, accelerometer blocks of {} at {} Hz, vibration blocks of {} at {} Hz (first {} s left out)",
        report.mode, report.duration_s, report.block_samples, report.rate_hz, report.vib_block_samples, report.vib_rate_hz, options.warmup_s
    )?;
    for r in &report.runs {
        outln!(
            "{}: {} blocks sent, {} received, lost samples {}; CPU {}",
            r.pipeline,
            r.accel_blocks_sent,
            r.compensated_received,
            r.lost_samples,
            r.cpu_percent
                .iter()
                .map(|(n, p)| format!("{n} {p:.1}%"))
                .collect::<Vec<_>>()
                .join(", ")
        )?;
        for l in &r.losses {
            outln!("  lost: {} {} = {}", l.process, l.counter, l.count)?;
        }
        print_hops(r)?;
        if let Some(v) = &r.view {
            outln!(
                "  live view on ws://{}: its client subscribed to {} channels and received {} \
                 messages; the view dropped {}",
                v.listen,
                v.client_channels,
                v.client_messages,
                v.view_summary["dropped"]
            )?;
        }
    }
    if let Some(r) = &report.ratios {
        outln!(
            "vibrocomp / bare iceoryx2, end to end: p50 {:.2}x ({:+.1} us), p99 {:.2}x ({:+.1} us); vibrocomp / Unix sockets: p50 {:.2}x, p99 {:.2}x",
            r.vs_bare_p50, r.added_p50_us, r.vs_bare_p99, r.added_p99_us, r.vs_sockets_p50, r.vs_sockets_p99
        )?;
    }
    Ok(())
}

fn print_soak(r: &SoakReport) -> anyhow::Result<()> {
    outln!(
        "Soak, {} mode ({}), prefix {}: {} s, accelerometer blocks of {} at {} Hz, vibration blocks of {} at {} Hz (estimator configuration: {}); first {} s left out",
        r.mode,
        r.realtime_priority.map_or_else(|| "normal scheduling".to_string(), |p| format!("SCHED_FIFO priority {p}")),
        r.prefix, r.duration_s, r.block_samples, r.rate_hz, r.vib_block_samples, r.vib_rate_hz, r.estimator_config, r.warmup_s
    )?;
    let a = &r.accel;
    outln!(
        "accelerometer blocks: {} sent, {} answered, {} missing, {} duplicate, {} out of order; input sequence {}",
        a.sent, a.answered, a.missing, a.duplicates, a.out_of_order,
        if a.continuous { "continuous" } else { "NOT continuous" }
    )?;
    let s = &r.services;
    outln!(
        "services: compensator received {} accelerometer blocks, lost {}; estimator received {} of {} vibration blocks, lost {}, rate mismatches {}, {} estimates ({} flagged); window -> estimate {}",
        s.compensator_accel_received, s.compensator_lost, s.estimator_vib_received, r.run.vib_blocks_sent,
        s.estimator_lost, s.estimator_rate_mismatches, s.estimates_published, s.estimates_flagged,
        s.estimator_window
    )?;
    outln!(
        "lost: {}; CPU {}",
        r.lost,
        r.run
            .cpu_percent
            .iter()
            .map(|(n, p)| format!("{n} {p:.1}%"))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    match &r.load {
        Some(l) => outln!(
            "load: `vibrocomp lab diagnose {}` x{}: {} runs started, {} completed, CPU {:.1}% of one core over {:.1} s, {}",
            l.input, l.jobs, l.runs_started, l.runs_completed, l.cpu_percent, l.wall_s,
            if l.stopped { "stopped" } else { "NOT stopped cleanly" }
        )?,
        None => outln!("load: none")?,
    }
    outln!(
        "machine: {} cores, {:.1}% busy over the soak (everything it ran)",
        r.cores,
        r.machine_busy_percent
    )?;
    outln!(
        "memory (KiB, every second; flat = RssAnon at most {} KiB above its first sample after the warm-up; VmRSS also counts the iceoryx2 segments' pages as they are first touched):",
        r.memory_flat_bound_kib
    )?;
    for m in &r.memory {
        outln!(
            "  {:<12} {} samples of VmRSS: first {}, after warm-up {}, last {}, max {}, growth {}, slope {:+.1} KiB/min; RssAnon {} -> {}, growth after warm-up {}; VmRSS growth over the second half {}: {}",
            m.process, m.samples, m.first_kib, m.after_warmup_kib, m.last_kib, m.max_kib,
            m.growth_after_warmup_kib, m.slope_kib_per_min, m.anon_first_kib, m.anon_last_kib,
            m.anon_growth_after_warmup_kib,
            m.second_half_growth_kib,
            if m.flat { "flat" } else { "NOT flat" }
        )?;
    }
    print_hops(&r.run)?;
    let h = &r.end_to_end_histogram;
    outln!("end to end per accelerometer block, {} blocks:", h.count)?;
    outln!("  {:>10}{:>12}{:>12}", "percentile", "us", "blocks <=")?;
    for p in &h.percentiles {
        outln!(
            "  {:>10}{:>12.1}{:>12}",
            p.percentile,
            p.value_us,
            p.blocks_at_or_below
        )?;
    }
    outln!("  {:>20}{:>10}", "latency, us", "blocks")?;
    for b in h.buckets.iter().filter(|b| b.blocks > 0) {
        let range = match b.upper_us {
            Some(u) => format!("{} .. {}", b.lower_us, u),
            None => format!("> {}", b.lower_us),
        };
        outln!("  {:>20}{:>10}", range, b.blocks)?;
    }
    outln!(
        "p99.9 {:.1} us against one accelerometer sample period {:.1} us: {}",
        r.run.end_to_end.p999_us,
        r.target_p999_us,
        if r.p999_met { "met" } else { "NOT met" }
    )?;
    Ok(())
}

fn print_hops(r: &PipelineRun) -> anyhow::Result<()> {
    outln!(
        "  {:<26}{:>10}{:>10}{:>10}{:>10}{:>10}",
        "hop, us",
        "p50",
        "p90",
        "p99",
        "p99.9",
        "max"
    )?;
    for (name, h) in [
        ("rig -> service receive", &r.rig_to_service),
        ("service receive -> publish", &r.processing),
        ("publish -> subscriber", &r.service_to_subscriber),
        ("end to end", &r.end_to_end),
    ] {
        outln!(
            "  {:<26}{:>10.1}{:>10.1}{:>10.1}{:>10.1}{:>10.1}",
            name,
            h.p50_us,
            h.p90_us,
            h.p99_us,
            h.p999_us,
            h.max_us
        )?;
    }
    Ok(())
}
