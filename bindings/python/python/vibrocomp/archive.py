"""Replaying an archive (README, "Replaying an archive"): every log of an archive
compensated with every model and scored against its reference, and every unit's
data diagnosed by the lab, into one Parquet table and an HTML report.

    import vibrocomp as vc
    s = vc.archive.run("archive.toml", "results")                  # this machine
    s = vc.archive.run("archive.toml", "results", client=client)   # a Dask cluster
    df = s.table()                                                 # results.parquet, pandas

    python -m vibrocomp.archive archive.toml --out results [--dask tcp://host:8786]

What runs where. The library (`vibro_archive`, through `_vibrocomp.Archive`) reads the
manifest, keeps the journal `OUT/journal.jsonl` and writes `OUT/results.parquet` and
`OUT/report.html`, in this process only. It hands out the jobs the journal does not
hold yet as self-contained JSON (absolute paths); a job is run by `_run_job` in any
process that has the package installed (the workers import `vibrocomp`, nothing
else: no code of the caller travels), and its result comes back as JSON to be
recorded here as it arrives. So a run that stops (Ctrl-C, a lost machine) resumes
where it stopped: the jobs the journal holds are not run again. A folder whose
journal belongs to another manifest is refused, unless `restart=True` (its results
are dropped and the batch starts over).

Scheduling is not ours. Locally, a `concurrent.futures.ProcessPoolExecutor` of
`workers` processes (spawned, not forked: a fork of a process holding Rust threads
and a Dask client is unsafe); one worker runs the jobs in this process. On Dask,
`client.map` with `retries=2` and Dask's own handling of a lost worker (its tasks
are run again elsewhere; the journal takes a job's first result only, so a task run
twice is recorded once). A damaged log is not a failure: its job returns rows with
`problem` set. A task that Dask finally gives up on (a worker that kept dying on
it) is recorded as its job's `failed` row with the task's error as `problem`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Dict, Iterable, List, Optional, Union

from .errors import VibrocompError

PathLike = Union[str, "os.PathLike[str]"]

# The table's columns that say when and where a job ran, not what it found: two runs
# of one archive agree on every other column.
TIMING_COLUMNS = ("elapsed_s", "worker")

# Dask keys: stable across runs (the job's id), so that the dashboard and the logs
# name a job the same way every time.
_KEY_PREFIX = "vibrocomp-archive-"


@dataclass
class ArchiveSummary:
    """What a run did: the command line's `--json` (`vibrocomp archive run`), the
    same keys (`to_dict()` gives it back), and where this call ran the jobs."""

    manifest: Path
    out_dir: Path
    jobs_total: int  # jobs of the plan
    done_now: int  # run and recorded by this call
    skipped: int  # held by the journal when the call began (not run again)
    failed: int  # jobs (of all recorded) with a `failed` row
    pending: int  # not recorded (0 after a complete run)
    duplicates: int  # results of a job recorded before, ignored (a task run twice)
    torn_bytes: int  # a torn last journal line cut off when the folder was opened
    rows: int  # rows of the table
    results: Path  # OUT/results.parquet
    report: Path  # OUT/report.html
    journal: Path  # OUT/journal.jsonl
    elapsed_s: float
    scheduler: str = ""  # "local:N" (N processes) or the Dask scheduler's address
    given_up: int = 0  # Dask tasks that failed for good, recorded as `failed` rows

    @classmethod
    def _from_json(cls, d: Dict[str, Any], **extra) -> "ArchiveSummary":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            # The library's summary grew a key this class does not have: say so
            # rather than drop it (the two must not drift apart).
            raise VibrocompError(f"archive summary: keys {unknown} unknown to vibrocomp.archive.ArchiveSummary")
        paths = {"manifest", "out_dir", "results", "report", "journal"}
        return cls(**{k: Path(v) if k in paths else v for k, v in d.items()}, **extra)

    def __repr__(self) -> str:
        """One line: the folder, the jobs by outcome, the table's rows and the time, s
        (every field: `to_dict()`)."""
        given_up = f", {self.given_up} given up" if self.given_up else ""
        return (
            f"ArchiveSummary({str(self.out_dir)!r}: {self.jobs_total} jobs, {self.done_now} done now, "
            f"{self.skipped} skipped, {self.failed} failed, {self.pending} pending{given_up}; "
            f"{self.rows} rows; {self.elapsed_s:.1f} s on {self.scheduler or '?'})"
        )

    def table(self):
        """`results.parquet` as a pandas DataFrame (read with pyarrow)."""
        try:
            import pyarrow.parquet as pq
        except ImportError as e:
            raise VibrocompError(
                f"archive: reading {self.results} needs pyarrow and pandas (pip install 'vibrocomp[archive]')"
            ) from e
        return pq.read_table(self.results).to_pandas()

    def to_dict(self) -> dict:
        """The summary as the command line's JSON (`archive run --json`): every field,
        paths as strings."""
        return {f.name: str(v) if isinstance(v, Path) else v for f in fields(self) for v in [getattr(self, f.name)]}


def _run_job(job: str) -> str:
    """Runs one job (the library's JSON) and returns its result's JSON. Module-level
    and importing only `vibrocomp`, so that a pool process or a Dask worker runs it
    by reference (`vibrocomp.archive._run_job`) with nothing but the package."""
    from . import _vibrocomp

    return _vibrocomp.archive_job(job)


def _job_id(job: str) -> str:
    return str(json.loads(job)["id"])


def _lab_first(jobs: List[str]) -> List[str]:
    """The jobs with the lab's first: a unit's diagnosis reads all of its logs and takes
    10 to 50 times a compensation, so starting them last leaves the other workers idle
    at the end (longest first). The table does not depend on the order (the library
    writes it in the plan's)."""
    return sorted(jobs, key=lambda job: json.loads(job).get("task", {}).get("kind") != "lab")


def _failed_result(job: str, message: str, worker: str) -> str:
    """A result of `job` that says it failed: one `failed` row with `message` as its
    `problem` (the library's, as its local engine records a job whose worker died)."""
    from . import _vibrocomp

    return _vibrocomp.archive_failed(job, message, worker)


class _Progress:
    """A progress bar: tqdm's when it is installed, else a counter on stderr; nothing
    unless stderr is a terminal and `enabled`."""

    def __init__(self, total: int, enabled: bool, what: str):
        self.total = total
        self.done = 0
        self.bar = None
        self.counter = False
        if not enabled or total == 0 or not sys.stderr.isatty():
            return
        try:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=what, unit="job", file=sys.stderr)
        except ImportError:
            self.counter = True
            self.what = what
            self.last = 0.0

    def update(self) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(1)
        elif self.counter:
            now = time.monotonic()
            if now - self.last >= 0.2 or self.done == self.total:
                self.last = now
                sys.stderr.write(f"\r{self.what}: {self.done}/{self.total} jobs")
                sys.stderr.flush()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        elif self.counter:
            sys.stderr.write("\n")
            sys.stderr.flush()


class _Recorder:
    """Records results in the archive as they arrive (a result of a job recorded
    before is ignored by the library, and counted there as a duplicate)."""

    def __init__(self, archive, progress: _Progress):
        self.archive = archive
        self.progress = progress

    def __call__(self, result: str) -> None:
        if self.archive.record(result):
            self.progress.update()


def _run_local(jobs: List[str], workers: int, record: _Recorder) -> None:
    if workers == 1:
        # Nothing to spread: no process to start, Ctrl-C stops between two jobs.
        for job in jobs:
            record(_run_job(job))
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
    futures = [pool.submit(_run_job, job) for job in jobs]
    try:
        for future in as_completed(futures):
            record(future.result())
    except BaseException:
        # Ctrl-C or a broken pool: what is recorded stays in the journal.
        for future in futures:
            future.cancel()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_dask(jobs: List[str], client, record: _Recorder) -> int:
    """Runs the jobs as Dask tasks; returns how many Dask gave up on (each recorded
    as a `failed` row)."""
    from distributed import as_completed

    ids = [_job_id(job) for job in jobs]
    futures = client.map(_run_job, jobs, key=[_KEY_PREFIX + i for i in ids], retries=2, pure=False)
    job_of = {f.key: job for f, job in zip(futures, jobs)}
    failed = 0
    try:
        for future in as_completed(futures):
            job = job_of[future.key]
            try:
                result = future.result()
            except Exception as error:
                # Dask gave up on it (after `retries`, or a worker that kept dying on
                # it: KilledWorker); `run_job` itself never fails.
                message = f"the Dask task failed for good: {type(error).__name__}: {error}"
                result = _failed_result(job, message, f"dask {client.scheduler.address}")
                failed += 1
            record(result)
            future.release()
    except BaseException:
        client.cancel(futures)
        raise
    return failed


def _connect(client):
    """A `distributed.Client`, or one connected to a scheduler's address."""
    if isinstance(client, str):
        try:
            from distributed import Client
        except ImportError as e:
            raise VibrocompError(
                f"archive: --dask {client}: Dask is not installed (pip install 'vibrocomp[dask]')"
            ) from e
        return Client(client), True
    return client, False


def run(
    manifest: PathLike,
    out: PathLike,
    *,
    client=None,
    workers: Optional[int] = None,
    restart: bool = False,
    progress: bool = True,
) -> ArchiveSummary:
    """Runs the archive of `manifest` into the folder `out` (made if missing) and
    returns the summary; the table is `out/results.parquet`, the report
    `out/report.html`, the journal `out/journal.jsonl`.

    `client`: a `distributed.Client` (or a scheduler's address) to run the jobs on a
    Dask cluster; None runs them on `workers` processes of this machine (default: its
    CPU count). `restart`: start over in a folder whose journal belongs to another
    manifest (its results are dropped; without it such a folder is refused; the
    same manifest's journal is always resumed). `progress`: a bar on stderr when it
    is a terminal.
    """
    from . import _vibrocomp

    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise VibrocompError(f"archive: workers = {workers!r}: must be a whole number >= 1")
    if client is not None and workers is not None:
        raise VibrocompError("archive: workers and client exclude each other (a cluster has its own workers)")
    archive = _vibrocomp.Archive(os.fspath(manifest), os.fspath(out), restart)
    jobs = _lab_first(archive.pending())
    bar = _Progress(len(jobs), progress, "archive")
    record = _Recorder(archive, bar)
    scheduler = ""
    given_up = 0
    try:
        if client is None:
            n = workers or os.cpu_count() or 1
            scheduler = f"local:{n}"
            if jobs:
                _run_local(jobs, min(n, len(jobs)), record)
        else:
            client, own = _connect(client)
            try:
                scheduler = str(client.scheduler.address)
                if jobs:
                    given_up = _run_dask(jobs, client, record)
            finally:
                if own:
                    client.close()
    finally:
        bar.close()
    return ArchiveSummary._from_json(json.loads(archive.finish()), scheduler=scheduler, given_up=given_up)


# ---------------------------------------------------------------------------------
# python -m vibrocomp.archive: what `vibrocomp archive run --dask` runs


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m vibrocomp.archive",
        description="Every log of an archive compensated with every model, every unit diagnosed by the lab: "
        "OUT/results.parquet and OUT/report.html, resumable (OUT/journal.jsonl).",
    )
    p.add_argument("manifest", help="the archive's manifest (TOML, format = \"vibrocomp-archive/1\")")
    p.add_argument("--out", required=True, help="the results folder (made if missing)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--dask", metavar="ADDR", help="a Dask scheduler's address (tcp://host:8786)")
    where.add_argument("--workers", type=int, metavar="N", help="processes on this machine (default: CPU count)")
    p.add_argument(
        "--restart",
        action="store_true",
        help="start over in a folder whose journal belongs to another manifest (its results are dropped)",
    )
    p.add_argument("--json", action="store_true", help="the summary (or the error) as JSON on stdout")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Optional[Iterable[str]] = None) -> int:
    """`python -m vibrocomp.archive MANIFEST --out DIR [--dask ADDR | --workers N]`
    (what `vibrocomp archive run --dask` runs): `run` with the command line's
    arguments (`argv`, default `sys.argv[1:]`); prints the summary (or, with `--json`,
    the summary or the error as JSON) and returns the exit code."""
    args = _parser().parse_args(None if argv is None else list(argv))
    if args.workers is not None and args.workers < 1:
        _parser().error(f"--workers {args.workers}: must be at least 1")
    try:
        s = run(
            args.manifest,
            args.out,
            client=args.dask,
            workers=args.workers,
            restart=args.restart,
            progress=not args.no_progress and not args.json,
        )
    except VibrocompError as e:
        if args.json:
            print(json.dumps({"error": {**e.to_dict(), "exit_code": 1}}))
        else:
            print(f"error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        # A scheduler that does not answer (distributed raises OSError on timeout).
        message = f"archive: {args.dask or 'local run'}: {e}"
        if args.json:
            print(json.dumps({"error": {"message": message, "chain": [message], "exit_code": 1}}))
        else:
            print(f"error: {message}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(s.to_dict()))
    else:
        print(
            f"{s.jobs_total} jobs: {s.done_now} run now on {s.scheduler}, {s.skipped} done before, "
            f"{s.failed} failed; {s.rows} rows in {s.results} ({s.elapsed_s:.1f} s), report {s.report}"
        )
    return 0


if __name__ == "__main__":
    # Run as `python -m vibrocomp.archive`, this file is `__main__`; the functions the
    # workers run must be `vibrocomp.archive`'s (what they can import), so the real
    # module runs the command.
    from vibrocomp.archive import main as _main

    sys.exit(_main())
