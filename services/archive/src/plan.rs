//! The plan: a deterministic list of jobs, each with a stable id. Every log is
//! compensated with every model (`compensate/<log index>/<model name>`, logs in the
//! manifest's order, models within each log), then every unit is diagnosed by the lab
//! (`lab/<unit id>`, units in order of first appearance). A job is self-contained: it
//! carries absolute paths and its options, so that any process that can read the files
//! runs it ([`crate::run_job`]).

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use crate::manifest::{LabSettings, Manifest, ModelSpec};

/// One job of the batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Job {
    /// Stable id: `compensate/<log index>/<model name>` or `lab/<unit id>`.
    pub id: String,
    pub task: Task,
}

/// What a job does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Task {
    /// A log through the offline estimator and compensator with one model, its errors
    /// measured against its reference.
    Compensate(CompensateTask),
    /// One unit's data (its position's windows in each of its logs, its tables' rows)
    /// diagnosed by the lab.
    Lab(LabTask),
}

/// [`Task::Compensate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompensateTask {
    /// The log, absolute.
    pub log: PathBuf,
    /// The log as the manifest names it (the table's `log` column).
    pub log_label: String,
    /// The unit at each triad position, AK1 first.
    pub units: Vec<String>,
    pub model: ModelSpec,
    pub rig: Option<PathBuf>,
    pub window_s: f64,
    /// `default` or a triad file (absolute).
    pub triad: String,
    /// Where the session MCAP is written (a scratch file of the output folder).
    pub session: PathBuf,
    pub keep_session: bool,
}

/// One log a unit was recorded in, and its position there.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct UnitLog {
    pub path: PathBuf,
    pub label: String,
    /// 0-based triad position (AK1 = 0).
    pub position: usize,
}

/// A campaign table of a unit.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct UnitTable {
    pub path: PathBuf,
    pub label: String,
}

/// [`Task::Lab`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LabTask {
    pub unit: String,
    pub logs: Vec<UnitLog>,
    pub tables: Vec<UnitTable>,
    pub triad: String,
    pub lab: LabSettings,
}

impl Job {
    /// `compensate` or `lab`.
    pub fn kind(&self) -> &'static str {
        match self.task {
            Task::Compensate(_) => "compensate",
            Task::Lab(_) => "lab",
        }
    }
}

/// The plan of `manifest`, with the sessions written under `sessions_dir`.
pub fn plan(manifest: &Manifest, sessions_dir: &Path) -> Vec<Job> {
    let mut jobs = Vec::new();
    for (i, log) in manifest.logs.iter().enumerate() {
        for (j, model) in manifest.models.iter().enumerate() {
            let id = format!("compensate/{i}/{}", model.name);
            // By index: a model's name may hold any printable character.
            let session = sessions_dir.join(format!("log{i}-model{j}.mcap"));
            jobs.push(Job {
                id,
                task: Task::Compensate(CompensateTask {
                    log: log.path.clone(),
                    log_label: log.label.clone(),
                    units: log.units.clone(),
                    model: model.clone(),
                    rig: log.rig.clone(),
                    window_s: manifest.window_s,
                    triad: manifest.triad.clone(),
                    session,
                    keep_session: manifest.keep_sessions,
                }),
            });
        }
    }
    if manifest.lab.enabled {
        for unit in manifest.units() {
            let logs = manifest
                .logs
                .iter()
                .filter_map(|l| {
                    l.units
                        .iter()
                        .position(|u| *u == unit)
                        .map(|position| UnitLog {
                            path: l.path.clone(),
                            label: l.label.clone(),
                            position,
                        })
                })
                .collect();
            let tables = manifest
                .tables
                .iter()
                .filter(|t| t.unit == unit)
                .map(|t| UnitTable {
                    path: t.path.clone(),
                    label: t.label.clone(),
                })
                .collect();
            jobs.push(Job {
                id: format!("lab/{unit}"),
                task: Task::Lab(LabTask {
                    unit,
                    logs,
                    tables,
                    triad: manifest.triad.clone(),
                    lab: manifest.lab.clone(),
                }),
            });
        }
    }
    jobs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_is_every_log_times_every_model_then_every_unit() {
        let dir = tempfile::TempDir::new().unwrap();
        for f in ["a.mcap", "b.mcap", "t.csv"] {
            std::fs::write(dir.path().join(f), "x").unwrap();
        }
        let text = "format = \"vibrocomp-archive/1\"\n[[model]]\nname = \"one\"\n[[model]]\nname = \"two\"\n\
                    [[log]]\npath = \"a.mcap\"\nunits = [\"U1\", \"U2\"]\n\
                    [[log]]\npath = \"b.mcap\"\nunits = [\"U2\"]\n\
                    [[table]]\npath = \"t.csv\"\nunit = \"U3\"\n";
        let m = Manifest::parse(text, &dir.path().join("m.toml")).unwrap();
        let jobs = plan(&m, Path::new("/out/sessions"));
        let ids: Vec<&str> = jobs.iter().map(|j| j.id.as_str()).collect();
        assert_eq!(
            ids,
            [
                "compensate/0/one",
                "compensate/0/two",
                "compensate/1/one",
                "compensate/1/two",
                "lab/U1",
                "lab/U2",
                "lab/U3"
            ]
        );
        let Task::Lab(u2) = &jobs[5].task else {
            panic!()
        };
        let positions: Vec<(String, usize)> = u2
            .logs
            .iter()
            .map(|l| (l.label.clone(), l.position))
            .collect();
        assert_eq!(positions, [("a.mcap".into(), 1), ("b.mcap".into(), 0)]);
        // A job survives its JSON (what a worker process gets).
        let json = serde_json::to_string(&jobs[1]).unwrap();
        assert_eq!(serde_json::from_str::<Job>(&json).unwrap(), jobs[1]);
        let Task::Compensate(c) = &jobs[3].task else {
            panic!()
        };
        assert_eq!(c.session, Path::new("/out/sessions/log1-model1.mcap"));
    }
}
