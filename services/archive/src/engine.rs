//! The engines: the local one ([`run_local`]: worker processes on this machine, fed one
//! job at a time over their stdin), the worker's loop ([`serve_worker`]), and the
//! hand-over to the Python package's Dask engine ([`run_dask`]).
//!
//! Processes, not threads: a job that crashes (a stack overflow, an abort in a
//! dependency) or runs out of memory takes down its worker, not the batch. The parent
//! alone writes the journal, so that a result is recorded exactly once whatever the
//! workers do. A worker that dies mid-job is replaced and its job run again once, then
//! recorded as failed with the reason. Workers die with the parent: `PR_SET_PDEATHSIG`
//! (SIGKILL) when it is killed, and EOF on their stdin when it ends.

use std::collections::VecDeque;
use std::ffi::OsStr;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;

use crate::{Archive, ArchiveSummary, Error, Job, JobResult, Result};

/// How many times a job is started in a worker that dies before it answers: once,
/// then once more in a new worker.
const ATTEMPTS: u32 = 2;

/// The worker's loop (`vibrocomp archive worker`): one [`Job`] JSON per line in, one
/// [`JobResult`] JSON per line out (flushed), until EOF.
pub fn serve_worker(input: impl BufRead, mut output: impl Write) -> Result<()> {
    let io = |e: std::io::Error| Error::Worker {
        exe: PathBuf::from("-"),
        problem: format!("stdin/stdout: {e}"),
    };
    for line in input.lines() {
        let line = line.map_err(io)?;
        if line.trim().is_empty() {
            continue;
        }
        let job: Job = serde_json::from_str(&line).map_err(|e| Error::Worker {
            exe: PathBuf::from("-"),
            problem: format!("not a job: {e}"),
        })?;
        let result = crate::run_job(&job);
        let answer = serde_json::to_string(&result).map_err(|e| Error::Worker {
            exe: PathBuf::from("-"),
            problem: format!("cannot encode the result of {}: {e}", job.id),
        })?;
        writeln!(output, "{answer}").map_err(io)?;
        output.flush().map_err(io)?;
    }
    Ok(())
}

/// A line a worker's reader thread passes on: `(slot, generation, line or EOF)`.
type Message = (usize, u64, Option<String>);

struct Slot {
    child: Child,
    stdin: Option<ChildStdin>,
    generation: u64,
    /// The index (into the pending jobs) of the job it runs.
    job: Option<usize>,
}

/// The workers: killed and reaped if the run stops early (an error recording a
/// result), closed and waited for at the end.
struct Pool {
    exe: PathBuf,
    slots: Vec<Option<Slot>>,
    tx: mpsc::Sender<Message>,
    generation: u64,
}

impl Pool {
    fn spawn(&mut self, slot: usize) -> Result<()> {
        let mut cmd = Command::new(&self.exe);
        cmd.args(["archive", "worker"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        die_with_parent(&mut cmd);
        let mut child = cmd.spawn().map_err(|e| Error::Worker {
            exe: self.exe.clone(),
            problem: format!("cannot start it: {e}"),
        })?;
        let stdout = child.stdout.take();
        let stdin = child.stdin.take();
        self.generation += 1;
        let generation = self.generation;
        let tx = self.tx.clone();
        if let Some(stdout) = stdout {
            std::thread::spawn(move || {
                for line in BufReader::new(stdout).lines() {
                    match line {
                        Ok(line) => {
                            if tx.send((slot, generation, Some(line))).is_err() {
                                return;
                            }
                        }
                        Err(_) => break,
                    }
                }
                let _ = tx.send((slot, generation, None));
            });
        }
        tracing::trace!(slot, pid = child.id(), "archive worker started");
        self.slots[slot] = Some(Slot {
            child,
            stdin,
            generation,
            job: None,
        });
        Ok(())
    }

    /// Sends job `index` to the worker in `slot` (a write that fails means the worker
    /// died: its EOF follows, and the job is retried then).
    fn send(&mut self, slot: usize, index: usize, job: &Job) -> Result<()> {
        let line = serde_json::to_string(job).map_err(|e| Error::Worker {
            exe: self.exe.clone(),
            problem: format!("cannot encode job {}: {e}", job.id),
        })?;
        if let Some(s) = self.slots[slot].as_mut() {
            s.job = Some(index);
            if let Some(stdin) = s.stdin.as_mut() {
                if let Err(e) = writeln!(stdin, "{line}").and_then(|()| stdin.flush()) {
                    tracing::debug!(slot, "writing to a worker failed: {e}");
                }
            }
        }
        Ok(())
    }

    /// Closes the worker's stdin (it ends at EOF) and reaps it.
    fn close(&mut self, slot: usize) -> Option<std::process::ExitStatus> {
        let mut s = self.slots[slot].take()?;
        drop(s.stdin.take());
        s.child.wait().ok()
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        for s in self.slots.iter_mut().flatten() {
            let _ = s.child.kill();
            let _ = s.child.wait();
        }
    }
}

/// Makes the child die with this process: `PR_SET_PDEATHSIG` (SIGKILL) set in the
/// child before `exec`, and a child whose parent is already gone exits at once.
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: the closure runs in the forked child before exec and calls only
    // async-signal-safe functions (prctl, getppid, _exit), allocating nothing.
    let parent = std::process::id() as libc::pid_t;
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() != parent {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}

/// Runs the archive's pending jobs in `workers` processes `exe archive worker` (at
/// least 1, at most one per job), recording each result as it comes, then writes the
/// table and the report ([`Archive::finish`]). `progress(done, total)` counts the jobs
/// recorded, those of a previous run included.
pub fn run_local(
    mut archive: Archive,
    exe: &Path,
    workers: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ArchiveSummary> {
    let pending = archive.pending();
    let total = archive.total();
    let mut done = archive.done();
    progress(done, total);
    if pending.is_empty() {
        return archive.finish();
    }
    let workers = workers.clamp(1, pending.len());
    let (tx, rx) = mpsc::channel::<Message>();
    let mut pool = Pool {
        exe: exe.to_path_buf(),
        slots: (0..workers).map(|_| None).collect(),
        tx,
        generation: 0,
    };
    let mut queue: VecDeque<usize> = (0..pending.len()).collect();
    let mut attempts = vec![0u32; pending.len()];
    let mut remaining = pending.len();
    for slot in 0..workers {
        pool.spawn(slot)?;
        if let Some(i) = queue.pop_front() {
            attempts[i] += 1;
            pool.send(slot, i, &pending[i])?;
        }
    }
    while remaining > 0 {
        let Ok((slot, generation, line)) = rx.recv() else {
            break;
        };
        let current = pool.slots[slot]
            .as_ref()
            .is_some_and(|s| s.generation == generation);
        if !current {
            continue;
        }
        let job = pool.slots[slot].as_ref().and_then(|s| s.job);
        let answer = line.map(|l| {
            serde_json::from_str::<JobResult>(&l)
                .map_err(|e| format!("an answer that is not a result ({e})"))
        });
        match (job, answer) {
            (Some(i), Some(Ok(result))) if result.job == pending[i].id => {
                archive.record(&result)?;
                remaining -= 1;
                done += 1;
                progress(done, total);
                if let Some(s) = pool.slots[slot].as_mut() {
                    s.job = None;
                }
                match queue.pop_front() {
                    Some(next) => {
                        attempts[next] += 1;
                        pool.send(slot, next, &pending[next])?;
                    }
                    None => {
                        pool.close(slot);
                    }
                }
            }
            // Idle at EOF: it ended as it was told to.
            (None, None) => {
                pool.close(slot);
            }
            (job, answer) => {
                // Died mid-job, or said something else than the job's result.
                let why = match answer {
                    Some(Err(e)) => e,
                    Some(Ok(r)) => format!("the result of another job ({})", r.job),
                    None => String::new(),
                };
                if let Some(s) = pool.slots[slot].as_mut() {
                    let _ = s.child.kill();
                }
                let status = pool.close(slot);
                let reason = match (why.is_empty(), status) {
                    (false, _) => format!("the worker process gave {why}"),
                    (true, Some(st)) => format!("the worker process died ({st})"),
                    (true, None) => "the worker process died".to_string(),
                };
                tracing::warn!(slot, "{reason}");
                if let Some(i) = job {
                    if attempts[i] < ATTEMPTS {
                        queue.push_front(i);
                    } else {
                        let failed = JobResult::failed_job(
                            &pending[i],
                            format!("{reason} while running this job, {ATTEMPTS} times"),
                            "-".into(),
                        );
                        archive.record(&failed)?;
                        remaining -= 1;
                        done += 1;
                        progress(done, total);
                    }
                }
                if let Some(next) = queue.pop_front() {
                    pool.spawn(slot)?;
                    attempts[next] += 1;
                    pool.send(slot, next, &pending[next])?;
                }
            }
        }
    }
    for slot in 0..workers {
        pool.close(slot);
    }
    drop(pool);
    archive.finish()
}

/// Hands the batch to the Python package's Dask engine: `PYTHON -m vibrocomp.archive
/// MANIFEST --out DIR --dask ADDRESS [--restart] [--json]`, its exit status returned. Fails
/// clearly when the interpreter cannot be started or has no `vibrocomp.archive`.
pub fn run_dask(
    python: &OsStr,
    manifest: &Path,
    out: &Path,
    address: &str,
    restart: bool,
    json: bool,
) -> Result<std::process::ExitStatus> {
    let name = python.to_string_lossy().into_owned();
    let check = Command::new(python)
        .args([
            "-c",
            "import sys\ntry:\n    import vibrocomp.archive\nexcept ImportError as e:\n    print(e, file=sys.stderr)\n    sys.exit(3)\n",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .map_err(|e| Error::Python {
            problem: format!("cannot run the Python interpreter {name:?} ({e}); set VIBROCOMP_PYTHON to one with the vibrocomp package"),
        })?;
    if !check.status.success() {
        return Err(Error::Python {
            problem: format!(
                "{name:?} cannot import vibrocomp.archive ({}); install the Python package (pip install vibrocomp) or set VIBROCOMP_PYTHON",
                String::from_utf8_lossy(&check.stderr).trim()
            ),
        });
    }
    let mut cmd = Command::new(python);
    cmd.args(["-m", "vibrocomp.archive"])
        .arg(manifest)
        .arg("--out")
        .arg(out)
        .args(["--dask", address]);
    if restart {
        cmd.arg("--restart");
    }
    if json {
        cmd.arg("--json");
    }
    cmd.status().map_err(|e| Error::Python {
        problem: format!("cannot run {name:?}: {e}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A worker that dies on every job: each job is started twice, then recorded as
    /// failed with the reason, and the batch still writes its table.
    #[test]
    fn a_worker_that_dies_is_replaced_and_its_job_recorded_failed_after_two_tries() {
        let _serial = crate::serial();
        let dir = tempfile::TempDir::new().unwrap();
        std::fs::write(dir.path().join("t.csv"), "x").unwrap();
        std::fs::write(
            dir.path().join("m.toml"),
            "format = \"vibrocomp-archive/1\"\n[[model]]\nname = \"m\"\n\
             [[table]]\npath = \"t.csv\"\nunit = \"U1\"\n[[table]]\npath = \"t.csv\"\nunit = \"U2\"\n",
        )
        .unwrap();
        // Counts its starts, reads one job and dies.
        let exe = dir.path().join("worker.sh");
        let starts = dir.path().join("starts");
        std::fs::write(
            &exe,
            format!(
                "#!/bin/sh\necho x >> {}\nread line\nkill -9 $$\n",
                starts.display()
            ),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
        let archive =
            Archive::open(&dir.path().join("m.toml"), &dir.path().join("out"), false).unwrap();
        assert_eq!(archive.total(), 2);
        let mut seen = Vec::new();
        let s = run_local(archive, &exe, 2, &mut |d, t| seen.push((d, t))).unwrap();
        assert_eq!((s.done_now, s.failed, s.pending, s.rows), (2, 2, 0, 2));
        assert_eq!(seen.last(), Some(&(2, 2)));
        assert_eq!(std::fs::read_to_string(&starts).unwrap().lines().count(), 4);
        let journal = std::fs::read_to_string(dir.path().join("out/journal.jsonl")).unwrap();
        assert!(
            journal.contains("the worker process died (signal: 9 (SIGKILL))"),
            "{journal}"
        );
        // Run again: nothing left, nothing run.
        let archive =
            Archive::open(&dir.path().join("m.toml"), &dir.path().join("out"), false).unwrap();
        assert!(archive.pending().is_empty());
        let s = run_local(archive, &exe, 2, &mut |_, _| {}).unwrap();
        assert_eq!((s.done_now, s.skipped, s.rows), (0, 2, 2));
    }

    #[test]
    fn the_worker_answers_one_result_per_job() {
        let job = Job {
            id: "lab/U".into(),
            task: crate::Task::Lab(crate::plan::LabTask {
                unit: "U".into(),
                logs: Vec::new(),
                tables: vec![crate::plan::UnitTable {
                    path: "/nonexistent/t.csv".into(),
                    label: "t.csv".into(),
                }],
                triad: "default".into(),
                lab: crate::manifest::LabSettings {
                    enabled: true,
                    max_effects: 1,
                    effects: Vec::new(),
                    model: None,
                    estimator_config: None,
                },
            }),
        };
        let input = format!(
            "{}\n\n{}\n",
            serde_json::to_string(&job).unwrap(),
            serde_json::to_string(&job).unwrap()
        );
        let mut out = Vec::new();
        serve_worker(input.as_bytes(), &mut out).unwrap();
        let lines: Vec<JobResult> = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0].rows, lines[1].rows);
        let row = &lines[0].rows[0];
        assert_eq!(row.verdict.as_deref(), Some("failed"));
        assert!(
            row.problem
                .as_deref()
                .unwrap()
                .contains("/nonexistent/t.csv"),
            "{row:?}"
        );
    }
}
