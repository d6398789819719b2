//! `vibrocomp record OUT.mcap`: records the live streams of a running system into an
//! MCAP log (`vibro_log::record`), with the services' configurations and the
//! passports in use attached, until Ctrl-C / SIGTERM (or `--duration-s`).

use anyhow::Context;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use vibro_log::attachments::{LogExtras, RECORDER_METADATA};
use vibro_log::{record, stream_of_topic, topic, RecordOptions, DEFAULT_RECORD_STREAMS};
use vibro_msgs::{ServiceNames, Stream};
use vibro_service::{init_tracing, run_service, ServiceConfig};

use crate::flags::FlagProblems;
use crate::output::print_json;

#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    /// The log to write (an existing file only with --force). Written in place, chunk
    /// by chunk, so that a crash leaves what `vibrocomp log recover` restores.
    pub out: PathBuf,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Service-name prefix of the system to record.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Topics to record, comma-separated (`/vib,/accel,...`), or `all` (the progress
    /// messages included) [default: the data streams and the services' heartbeats].
    #[arg(long, value_delimiter = ',')]
    pub topics: Vec<String>,
    /// A file to store in the log (repeatable).
    #[arg(long = "attach", value_name = "FILE")]
    pub attach: Vec<PathBuf>,
    /// The estimator's configuration, attached [default: the one the service uses by
    /// default: config/services/estimator.toml if present, else the shipped copy].
    #[arg(long, value_name = "FILE")]
    pub estimator_config: Option<PathBuf>,
    /// The compensator's configuration, attached with the passports of its triad
    /// [default: as for the estimator].
    #[arg(long, value_name = "FILE")]
    pub compensator_config: Option<PathBuf>,
    /// Stop by itself after this many seconds.
    #[arg(long = "duration-s")]
    pub duration_s: Option<f64>,
    /// Record the wire streams only, without the view channels made to be plotted
    /// (`/view/...`, docs/view.md) [default: both].
    #[arg(long)]
    pub no_view: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Report {
    #[serde(flatten)]
    summary: vibro_log::RecordSummary,
    attachments: Vec<String>,
}

/// The streams named by `--topics`.
pub fn parse_topics(topics: &[String]) -> anyhow::Result<Vec<Stream>> {
    if topics.is_empty() {
        return Ok(DEFAULT_RECORD_STREAMS.to_vec());
    }
    if topics.len() == 1 && topics[0] == "all" {
        return Ok(Stream::all());
    }
    let mut streams = Vec::new();
    for t in topics {
        let t = t.trim();
        let stream = stream_of_topic(t).with_context(|| {
            format!(
                "--topics {t:?}: not a stream of the system (known: {})",
                Stream::all()
                    .into_iter()
                    .map(topic)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?;
        if !streams.contains(&stream) {
            streams.push(stream);
        }
    }
    Ok(streams)
}

/// The configuration text a service runs on: the file given, else its default rule.
fn config_text(
    given: Option<&Path>,
    default_path: &str,
    shipped: &'static str,
) -> anyhow::Result<(String, Vec<u8>)> {
    let path = given
        .map(Path::to_path_buf)
        .or_else(|| Some(PathBuf::from(default_path)).filter(|p| p.is_file()));
    match path {
        Some(p) => {
            // A configuration file's bound: a bigger one is refused unread.
            let bytes = vibro_service::read_config_file(&p)?.into_bytes();
            Ok((p.display().to_string(), bytes))
        }
        None => Ok((
            format!("{default_path} (shipped)"),
            shipped.as_bytes().to_vec(),
        )),
    }
}

/// Attachments: the files given, both services' configurations and the passports
/// (named by `vibro_log::attachments`).
fn attachments(args: &RecordArgs, out: &mut LogExtras) -> anyhow::Result<()> {
    for path in &args.attach {
        let data = std::fs::read(path).with_context(|| format!("--attach {}", path.display()))?;
        out.file(path, data);
    }
    let (name, text) = config_text(
        args.estimator_config.as_deref(),
        vibro_estimator::DEFAULT_CONFIG_PATH,
        vibro_estimator::Config::shipped_text(),
    )?;
    out.service_config("estimator", &name, text);
    let (name, text) = config_text(
        args.compensator_config.as_deref(),
        vibro_compensator::DEFAULT_CONFIG_PATH,
        vibro_compensator::Config::shipped_text(),
    )?;
    out.service_config("compensator", &name, text);
    let compensator = match &args.compensator_config {
        Some(p) => vibro_compensator::Config::load(p)?,
        None => vibro_compensator::Config::load_default()?,
    };
    let triad = &compensator.model.triad;
    for (i, p) in triad.passports.iter().enumerate() {
        let text = toml::to_string(&p.to_spec()).context("passport as TOML")?;
        out.passport(i, p.id(), text);
    }
    Ok(())
}

pub fn run(args: &RecordArgs) -> anyhow::Result<()> {
    init_tracing();
    let names =
        ServiceNames::new(&args.prefix).with_context(|| format!("--prefix {:?}", args.prefix))?;
    let streams = parse_topics(&args.topics)?;
    // Before any port opens: a duration `Duration` can hold and no recorder outlives
    // (about 31 years).
    let mut problems = FlagProblems::new();
    let duration = args
        .duration_s
        .and_then(|d| problems.seconds("--duration-s", d, 1e-3, 1e9));
    problems.finish()?;
    // README, "Files": the attached files and configurations are inputs.
    let mut inputs: Vec<&Path> = args.attach.iter().map(PathBuf::as_path).collect();
    inputs.extend(args.estimator_config.as_deref());
    inputs.extend(args.compensator_config.as_deref());
    crate::files::check_recording(&args.out, &inputs, args.force)?;
    let mut extras = LogExtras::recorded();
    extras.metadata(
        RECORDER_METADATA,
        BTreeMap::from([
            (
                "program".to_string(),
                format!("vibrocomp {}", env!("CARGO_PKG_VERSION")),
            ),
            ("pid".to_string(), std::process::id().to_string()),
        ]),
    );
    attachments(args, &mut extras)?;
    let attached: Vec<String> = extras.attachments().map(|a| a.name.clone()).collect();
    let mut options = RecordOptions::new(names, streams);
    options.extras = extras;
    options.view = !args.no_view;
    options.force = args.force;
    let out = args.out.clone();
    let summary = run_service(|shutdown| async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let flag = shutdown.clone();
        std::thread::Builder::new()
            .name("vibrocomp-recorder".into())
            .spawn(move || {
                let _ = tx.send(record(&out, &options, flag.flag(), || {}));
            })
            .context("spawning the recorder thread")?;
        if let Some(d) = duration {
            let timer = shutdown.clone();
            tokio::spawn(async move {
                tokio::time::sleep(d).await;
                timer.trigger();
            });
        }
        let result = rx.await.map_err(|_| {
            anyhow::anyhow!("the recorder thread ended without a result (it panicked)")
        })?;
        result.with_context(|| format!("recording {}", args.out.display()))
    })?;
    let report = Report {
        summary,
        attachments: attached,
    };
    if args.json {
        return print_json(&report);
    }
    let s = &report.summary;
    outln!(
        "Recorded {} messages from prefix {} into {} ({} bytes, {} chunks) over {:.1} s; lost {}",
        s.messages,
        s.prefix,
        s.path.display(),
        s.bytes,
        s.chunks,
        s.duration_s,
        s.lost
    )?;
    let view: u64 = s.view.values().sum();
    if view > 0 {
        outln!(
            "  {:<24} {:>9} view messages on {} channels (made to be plotted, docs/view.md)",
            "/view/...",
            view,
            s.view.len()
        )?;
    }
    for (topic, c) in &s.topics {
        // `seq` jumps (a corrupt or renumbered counter, not in `lost`) only when seen.
        let mut jumps = if c.jumps > 0 {
            format!("  seq jumps {}", c.jumps)
        } else {
            String::new()
        };
        // Resyncs, and the losses they took back (a `seq` ahead of the stream), only
        // when seen.
        if c.resyncs > 0 {
            jumps.push_str(&format!(
                "  resyncs {} ({} taken back)",
                c.resyncs, c.retracted
            ));
        }
        // Data times off the recording's timeline (written at the timeline's time).
        if c.off_timeline > 0 {
            jumps.push_str(&format!("  off the timeline {}", c.off_timeline));
        }
        outln!(
            "  {:<24} {:>9} recorded  lost {:>4}  out of order {:>3}  malformed {:>3}{jumps}",
            topic,
            c.recorded,
            c.lost,
            c.out_of_order,
            c.malformed
        )?;
    }
    if s.inputs_without_output > 0 {
        outln!(
            "  {} accelerometer blocks without compensated output: {}",
            s.inputs_without_output,
            s.unanswered
        )?;
    }
    Ok(())
}
