//! An opened output folder: the plan, the journal, the results recorded so far.

use serde::Serialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::journal::Journal;
use crate::manifest::Manifest;
use crate::plan::{plan, Job};
use crate::{Error, JobResult, Result, Row};

/// The journal's file name in the output folder.
pub const JOURNAL_FILE: &str = "journal.jsonl";
/// The results table's file name.
pub const RESULTS_FILE: &str = "results.parquet";
/// The report's file name.
pub const REPORT_FILE: &str = "report.html";
/// The scratch sessions' folder.
pub const SESSIONS_DIR: &str = "sessions";
/// The lock a run holds on its output folder.
pub const LOCK_FILE: &str = "lock";

/// Takes the output folder's lock (`flock`, released when the process ends, killed or
/// not): a second run in the same folder is refused rather than interleaved.
fn lock(path: &Path) -> Result<std::fs::File> {
    use std::os::unix::io::AsRawFd;
    let file = vibro_files::open_lock(path)?;
    // SAFETY: flock on a descriptor this function owns.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
        return Err(Error::Busy {
            path: path.to_path_buf(),
        });
    }
    Ok(file)
}

/// Removes the temporary session files (`.NAME.XXXXXXXXXXXX.part`) a killed run's
/// workers left in the sessions folder: regular files only, never through a link.
fn remove_stale_parts(sessions: &Path) {
    let Ok(entries) = std::fs::read_dir(sessions) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let regular = e.file_type().is_ok_and(|t| t.is_file());
        if regular && name.starts_with(".log") && name.ends_with(".part") {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// An opened output folder (`DIR`): the manifest's plan and the results its journal
/// holds (module docs of the crate).
#[derive(Debug)]
pub struct Archive {
    manifest: Manifest,
    out_dir: PathBuf,
    jobs: Vec<Job>,
    index: HashMap<String, usize>,
    results: Vec<Option<JobResult>>,
    journal: Journal,
    skipped: usize,
    done_now: usize,
    duplicates: usize,
    torn_bytes: usize,
    started: Instant,
    /// Held (`flock`) while the folder is open: one run at a time.
    _lock: std::fs::File,
}

/// What a batch did (`--json` prints it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArchiveSummary {
    pub manifest: PathBuf,
    pub out_dir: PathBuf,
    /// Jobs of the plan.
    pub jobs_total: usize,
    /// Jobs run and recorded by this run.
    pub done_now: usize,
    /// Jobs the journal already held when the run began (not run again).
    pub skipped: usize,
    /// Jobs (of all recorded) with a `failed` row.
    pub failed: usize,
    /// Jobs not recorded yet (0 after a complete run).
    pub pending: usize,
    /// Results of a job already recorded, ignored (first wins).
    pub duplicates: usize,
    /// Bytes of a torn last journal line cut off when the folder was opened.
    pub torn_bytes: usize,
    /// Rows of the table.
    pub rows: usize,
    pub results: PathBuf,
    pub report: PathBuf,
    pub journal: PathBuf,
    pub elapsed_s: f64,
}

impl Archive {
    /// Opens the output folder `out_dir` for the manifest `manifest`: creates it (never
    /// through a link), checks its outputs (`results.parquet`, `report.html`: a link,
    /// a folder, a FIFO or a device there is refused), and reads the journal a previous
    /// run left, whose jobs are not run again (one of another manifest is refused);
    /// `restart` starts the batch over, the journal emptied.
    pub fn open(manifest: &Path, out_dir: &Path, restart: bool) -> Result<Archive> {
        let started = Instant::now();
        let manifest = Manifest::load(manifest)?;
        vibro_files::check_dir(out_dir, &[], false)?;
        vibro_files::create_dir(out_dir)?;
        // Re-written by every run (from the journal): `force`, which still refuses
        // anything but a regular file.
        for f in [RESULTS_FILE, REPORT_FILE, JOURNAL_FILE, LOCK_FILE] {
            vibro_files::check_output(&out_dir.join(f), &[], true)?;
        }
        let lock = lock(&out_dir.join(LOCK_FILE))?;
        let sessions = out_dir.join(SESSIONS_DIR);
        vibro_files::check_dir(&sessions, &[], false)?;
        vibro_files::create_dir(&sessions)?;
        remove_stale_parts(&sessions);
        let abs_sessions = std::path::absolute(&sessions).unwrap_or(sessions);
        let jobs = plan(&manifest, &abs_sessions);
        let index: HashMap<String, usize> = jobs
            .iter()
            .enumerate()
            .map(|(i, j)| (j.id.clone(), i))
            .collect();
        let opened = Journal::open(
            &out_dir.join(JOURNAL_FILE),
            &manifest.hash(),
            jobs.len(),
            restart,
        )?;
        let mut results: Vec<Option<JobResult>> = vec![None; jobs.len()];
        let mut duplicates = 0;
        for r in opened.results {
            match index.get(&r.job) {
                Some(&i) if results[i].is_none() => results[i] = Some(r),
                // A second result of a job (or one of no job of this plan: the hash
                // says the plan is the same, so only a hand-edited journal has it).
                _ => duplicates += 1,
            }
        }
        let skipped = results.iter().filter(|r| r.is_some()).count();
        Ok(Archive {
            manifest,
            out_dir: out_dir.to_path_buf(),
            jobs,
            index,
            results,
            journal: opened.journal,
            skipped,
            done_now: 0,
            duplicates,
            torn_bytes: opened.torn_bytes,
            started,
            _lock: lock,
        })
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The output folder.
    pub fn out_dir(&self) -> &Path {
        &self.out_dir
    }

    /// Every job of the plan, in order.
    pub fn jobs(&self) -> &[Job] {
        &self.jobs
    }

    /// Jobs of the plan.
    pub fn total(&self) -> usize {
        self.jobs.len()
    }

    /// Jobs recorded (by this run or before it).
    pub fn done(&self) -> usize {
        self.results.iter().filter(|r| r.is_some()).count()
    }

    /// The jobs not recorded yet, in plan order.
    pub fn pending(&self) -> Vec<Job> {
        self.jobs
            .iter()
            .zip(&self.results)
            .filter(|(_, r)| r.is_none())
            .map(|(j, _)| j.clone())
            .collect()
    }

    /// Records a job's result: appended to the journal and synced. `false`: the job
    /// was recorded already, and this result is ignored (counted as a duplicate).
    pub fn record(&mut self, result: &JobResult) -> Result<bool> {
        let Some(&i) = self.index.get(&result.job) else {
            return Err(Error::UnknownJob {
                job: result.job.clone(),
            });
        };
        if self.results[i].is_some() {
            self.duplicates += 1;
            return Ok(false);
        }
        let line = serde_json::to_string(result).map_err(|e| Error::Journal {
            path: self.journal.path().to_path_buf(),
            line: 0,
            problem: format!("cannot encode the result of {}: {e}", result.job),
        })?;
        self.journal.append(&line)?;
        // What a resumed run will read back: the numbers as the journal writes them,
        // so that a table made now and one made from the journal later are the same.
        let stored = serde_json::from_str(&line).map_err(|e| Error::Journal {
            path: self.journal.path().to_path_buf(),
            line: 0,
            problem: format!("cannot read back the result of {}: {e}", result.job),
        })?;
        self.results[i] = Some(stored);
        self.done_now += 1;
        Ok(true)
    }

    /// The rows recorded so far, in plan order then row order, each with its job's
    /// `elapsed_s` and `worker`.
    pub fn rows(&self) -> Vec<(Row, f64, String)> {
        self.results
            .iter()
            .flatten()
            .flat_map(|r| {
                r.rows
                    .iter()
                    .map(|row| (row.clone(), r.elapsed_s, r.worker.clone()))
            })
            .collect()
    }

    /// Writes `results.parquet` and `report.html` (each under a temporary name, then
    /// renamed) from the results recorded, and says what the batch did.
    pub fn finish(self) -> Result<ArchiveSummary> {
        let rows = self.rows();
        let results = self.out_dir.join(RESULTS_FILE);
        let report = self.out_dir.join(REPORT_FILE);
        let bytes = crate::parquet_bytes(&rows).map_err(|message| Error::Parquet {
            path: results.clone(),
            message,
        })?;
        vibro_files::write_bytes(&results, true, &bytes)?;
        let plain: Vec<Row> = rows.iter().map(|(r, _, _)| r.clone()).collect();
        let html = crate::render_report(&self.manifest, &plain)?;
        vibro_files::write_bytes(&report, true, html.as_bytes())?;
        let failed = self.results.iter().flatten().filter(|r| r.failed()).count();
        Ok(ArchiveSummary {
            manifest: self.manifest.path.clone(),
            out_dir: self.out_dir.clone(),
            jobs_total: self.jobs.len(),
            done_now: self.done_now,
            skipped: self.skipped,
            failed,
            pending: self.results.iter().filter(|r| r.is_none()).count(),
            duplicates: self.duplicates,
            torn_bytes: self.torn_bytes,
            rows: rows.len(),
            results,
            report,
            journal: self.journal.path().to_path_buf(),
            elapsed_s: self.started.elapsed().as_secs_f64(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(dir: &Path, unit2: &str) -> PathBuf {
        std::fs::write(dir.join("t.csv"), "x").unwrap();
        let m = dir.join("m.toml");
        std::fs::write(
            &m,
            format!(
                "format = \"vibrocomp-archive/1\"\n[[model]]\nname = \"m\"\n\
                 [[table]]\npath = \"t.csv\"\nunit = \"U1\"\n[[table]]\npath = \"t.csv\"\nunit = \"{unit2}\"\n"
            ),
        )
        .unwrap();
        m
    }

    fn result(job: &str, value: f64) -> JobResult {
        JobResult {
            job: job.into(),
            rows: vec![Row {
                job: job.into(),
                kind: "lab".into(),
                value: Some(value),
                ..Row::default()
            }],
            elapsed_s: 1.0,
            worker: "w".into(),
        }
    }

    #[test]
    fn the_journal_counts_each_job_once_cuts_a_torn_line_and_belongs_to_its_manifest() {
        let _serial = crate::serial();
        let dir = tempfile::TempDir::new().unwrap();
        let m = manifest(dir.path(), "U2");
        let out = dir.path().join("out");
        let mut a = Archive::open(&m, &out, false).unwrap();
        assert_eq!((a.total(), a.pending().len()), (2, 2));
        // One run at a time in a folder.
        assert!(matches!(
            Archive::open(&m, &out, false),
            Err(Error::Busy { .. })
        ));
        assert!(a.record(&result("lab/U1", 0.1)).unwrap());
        assert!(!a.record(&result("lab/U1", 0.2)).unwrap());
        assert!(matches!(
            a.record(&result("lab/X", 0.0)),
            Err(Error::UnknownJob { .. })
        ));
        let s = a.finish().unwrap();
        assert_eq!((s.done_now, s.duplicates, s.pending, s.rows), (1, 1, 1, 1));
        assert!(s.results.is_file() && s.report.is_file());

        // A torn last line (a kill mid-write) is cut; what was recorded stays.
        let journal = out.join(JOURNAL_FILE);
        let mut text = std::fs::read_to_string(&journal).unwrap();
        let torn = "{\"job\":\"lab/U2\",\"rows\":[{\"jo";
        text.push_str(torn);
        std::fs::write(&journal, &text).unwrap();
        let mut a = Archive::open(&m, &out, false).unwrap();
        assert_eq!(
            a.pending()
                .iter()
                .map(|j| j.id.as_str())
                .collect::<Vec<_>>(),
            ["lab/U2"]
        );
        assert!(a.record(&result("lab/U2", 0.3)).unwrap());
        let s = a.finish().unwrap();
        assert_eq!(
            (s.skipped, s.done_now, s.torn_bytes, s.rows),
            (1, 1, torn.len(), 2)
        );
        let lines: Vec<String> = std::fs::read_to_string(&journal)
            .unwrap()
            .lines()
            .map(String::from)
            .collect();
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(lines[2].starts_with("{\"job\":\"lab/U2\""), "{lines:?}");

        // A journal line duplicated by hand: first wins, counted.
        std::fs::write(&journal, format!("{}\n{}\n", lines.join("\n"), lines[1])).unwrap();
        let a = Archive::open(&m, &out, false).unwrap();
        let rows = a.rows();
        assert_eq!(rows[0].0.value, Some(0.1));
        assert_eq!(a.finish().unwrap().duplicates, 1);

        // Another manifest: refused, unless restarted.
        let other = manifest(dir.path(), "U3");
        let e = Archive::open(&other, &out, false).unwrap_err().to_string();
        assert!(
            e.contains("written for another manifest") && e.contains("--restart"),
            "{e}"
        );
        let mut a = Archive::open(&other, &out, true).unwrap();
        assert_eq!(a.pending().len(), 2);
        let lines = std::fs::read_to_string(&journal).unwrap().lines().count();
        assert_eq!(lines, 1);
        assert!(a.record(&result("lab/U1", 0.5)).unwrap());
        drop(a);
        // Restarted with its own manifest: begun again too.
        let a = Archive::open(&other, &out, true).unwrap();
        assert_eq!(a.pending().len(), 2);
    }
}
