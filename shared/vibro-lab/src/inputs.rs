//! The lab's inputs read into one table (docs/lab.md): campaign tables (CSV, from a
//! file or as text), MCAP logs with a reference (`log_table`) and shake-table campaign
//! manifests (`campaign`), joined. One home for the command line and the Python
//! package.

use std::path::{Path, PathBuf};

use crate::log_table::{LogOptions, LogTableSummary};
use crate::{CampaignTable, LabModel};

/// One input of the lab.
#[derive(Debug, Clone)]
pub enum Input {
    /// A file: `.mcap` is a log, `.toml` or a CSV opening with `# vibrocomp-campaign/1`
    /// a manifest, any other a campaign table.
    Path(PathBuf),
    /// A campaign table's CSV text; `name` stands for the file in errors, `dir`
    /// resolves its passport files.
    Table {
        text: String,
        name: String,
        dir: PathBuf,
    },
}

/// What the lab read: the inputs as one table, and for each log what became of its
/// windows.
#[derive(Debug)]
pub struct Loaded {
    pub table: CampaignTable,
    pub logs: Vec<LogTableSummary>,
    /// For each manifest, what the lab adjusted to its records (its estimator's bands).
    pub manifests: Vec<ManifestSummary>,
}

/// A lab command's result with what became of its inputs beside it: in JSON, `inner`'s
/// keys with `log` (the one log's summary), `logs` (every log's, when there are
/// several) and `manifests` (when any was read); in text, the inputs' summary lines
/// before the result's own. The command line and the Python package print the same.
#[derive(serde::Serialize)]
pub struct WithInputs<'a, T: serde::Serialize> {
    #[serde(flatten)]
    inner: &'a T,
    #[serde(skip_serializing_if = "Option::is_none")]
    log: Option<&'a LogTableSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    logs: Option<&'a [LogTableSummary]>,
    /// The manifests read, each with its estimator bands when clipped.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    manifests: &'a [ManifestSummary],
}

impl<'a, T: serde::Serialize> WithInputs<'a, T> {
    pub fn new(
        inner: &'a T,
        logs: &'a [LogTableSummary],
        manifests: &'a [ManifestSummary],
    ) -> Self {
        Self {
            inner,
            log: (logs.len() == 1).then(|| &logs[0]),
            logs: (logs.len() > 1).then_some(logs),
            manifests,
        }
    }

    /// The inputs' summary lines: each log's windows, each manifest's bands.
    pub fn write_text(&self, o: &mut String) {
        for s in self
            .log
            .iter()
            .copied()
            .chain(self.logs.unwrap_or_default())
        {
            crate::text::write_log_summary(o, s);
        }
        for s in self.manifests {
            crate::text::write_manifest_summary(o, s);
        }
    }
}

/// A manifest read: its runs, and the estimator's bands when they were clipped to what
/// its reference can see (`campaign::clip_bands`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ManifestSummary {
    pub manifest: String,
    pub runs: usize,
    /// The first clipped run's clip, and how many runs were clipped.
    pub band_clipped: Option<crate::campaign::BandClip>,
    pub runs_band_clipped: usize,
}

impl ManifestSummary {
    /// The summary of `result`, measured from the manifest at `path`.
    pub fn new(path: &Path, result: &crate::campaign::CampaignResult) -> Self {
        let clipped: Vec<_> = result.runs.iter().filter_map(|r| r.band_clipped).collect();
        Self {
            manifest: path.display().to_string(),
            runs: result.runs.len(),
            band_clipped: clipped.first().copied(),
            runs_band_clipped: clipped.len(),
        }
    }
}

/// Reads `inputs` into one table for `model`. `log_options` is asked for when a log
/// or a manifest is read (a log needs all of it, a manifest its estimator);
/// `progress(done, of)` follows a manifest's runs.
pub fn load<E: From<crate::Error>>(
    inputs: &[Input],
    model: &LabModel,
    log_options: &mut dyn FnMut() -> Result<LogOptions, E>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Loaded, E> {
    let mut tables = Vec::with_capacity(inputs.len());
    let mut logs = Vec::new();
    let mut manifests = Vec::new();
    for input in inputs {
        match input {
            Input::Table { text, name, dir } => {
                tables.push(CampaignTable::parse(text, Path::new(name), dir, model)?);
            }
            Input::Path(path) if is_log(path) => {
                let (table, mut summary) =
                    crate::log_table::table_from_log(path, model, &log_options()?)?;
                // `CampaignTable::joined` keeps the tables' rows in input order.
                summary.first_row = tables
                    .iter()
                    .map(|t: &CampaignTable| t.conditions.len())
                    .sum();
                tables.push(table);
                logs.push(summary);
            }
            Input::Path(path) if crate::campaign::is_manifest(path) => {
                let manifest = crate::campaign::Manifest::load(path)?;
                let estimator = log_options()?.estimator;
                let result = crate::campaign::measure_campaign(&manifest, &estimator, progress)?;
                manifests.push(ManifestSummary::new(path, &result));
                tables.push(result.table);
            }
            Input::Path(path) => tables.push(CampaignTable::load(path, model)?),
        }
    }
    Ok(Loaded {
        table: CampaignTable::joined(tables)?,
        logs,
        manifests,
    })
}

/// Whether `path` names an MCAP log (its extension, any case).
pub fn is_log(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}
