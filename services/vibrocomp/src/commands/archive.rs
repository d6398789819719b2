//! `vibrocomp archive run MANIFEST --out DIR`: every log compensated with every model
//! and every unit diagnosed, resumable, into one Parquet table and a report
//! (`vibro_archive`, docs/archive.md). `archive worker` is the local engine's worker.

use anyhow::Context;
use std::path::PathBuf;

#[derive(Debug, clap::Subcommand)]
pub enum ArchiveCommand {
    /// Run the batch a manifest lists (docs/archive.md); a killed run goes on where it
    /// stopped when run again with the same --out.
    Run(RunArgs),
    /// The local engine's worker: one job JSON per line on stdin, one result per line
    /// on stdout (internal).
    #[command(hide = true)]
    Worker,
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The batch's manifest (`format = "vibrocomp-archive/1"`).
    pub manifest: PathBuf,
    /// The output folder: journal.jsonl, results.parquet, report.html, sessions/.
    #[arg(long)]
    pub out: PathBuf,
    /// Worker processes (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub workers: Option<u32>,
    /// Start the batch over: the folder's journal (of this manifest or another) is
    /// emptied and every job run again.
    #[arg(long)]
    pub restart: bool,
    /// Run on a Dask cluster (`tcp://host:8786`) through the Python package
    /// (`python3 -m vibrocomp.archive`; interpreter from VIBROCOMP_PYTHON).
    #[arg(long, value_name = "ADDRESS", conflicts_with = "workers")]
    pub dask: Option<String>,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(cmd: &ArchiveCommand) -> anyhow::Result<()> {
    match cmd {
        ArchiveCommand::Worker => {
            let stdout = std::io::stdout();
            Ok(vibro_archive::serve_worker(
                std::io::stdin().lock(),
                stdout.lock(),
            )?)
        }
        ArchiveCommand::Run(a) => run_batch(a),
    }
}

fn run_batch(a: &RunArgs) -> anyhow::Result<()> {
    if let Some(address) = &a.dask {
        let python = std::env::var_os("VIBROCOMP_PYTHON").unwrap_or_else(|| "python3".into());
        let status =
            vibro_archive::run_dask(&python, &a.manifest, &a.out, address, a.restart, a.json)?;
        return match status.code() {
            Some(0) => Ok(()),
            Some(code) => Err(crate::output::ExitStatus(code.clamp(1, 255) as u8).into()),
            None => anyhow::bail!("{python:?} -m vibrocomp.archive: ended by {status}"),
        };
    }
    let archive = vibro_archive::Archive::open(&a.manifest, &a.out, a.restart)?;
    let workers = match a.workers {
        Some(n) => n as usize,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let exe =
        std::env::current_exe().context("finding the vibrocomp executable for the workers")?;
    let bar = crate::output::progress_bar(
        archive.total() as u64,
        "archive {bar:30} {pos}/{len} jobs {elapsed_precise} (eta {eta})",
    );
    let summary = vibro_archive::run_local(archive, &exe, workers, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    });
    bar.finish_and_clear();
    let s = summary?;
    if a.json {
        return crate::output::print_json(&s);
    }
    outln!(
        "{} jobs: {} run now, {} done before, {} failed, {} pending; {} duplicate results ignored",
        s.jobs_total,
        s.done_now,
        s.skipped,
        s.failed,
        s.pending,
        s.duplicates
    )?;
    outln!("{} rows: {}", s.rows, s.results.display())?;
    outln!("report: {}", s.report.display())
}
