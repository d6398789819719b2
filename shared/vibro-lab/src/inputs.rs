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
                tables.push(result.table);
            }
            Input::Path(path) => tables.push(CampaignTable::load(path, model)?),
        }
    }
    Ok(Loaded {
        table: CampaignTable::joined(tables)?,
        logs,
    })
}

/// Whether `path` names an MCAP log (its extension, any case).
pub fn is_log(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}
