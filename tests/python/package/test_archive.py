"""Replaying an archive (`vibrocomp.archive`, `vibrocomp archive run`): the issue's
"Done when".

An archive of 200 tiny logs and 20 campaign tables (tests/python/archive_data.py:
logs from the simulator and from the independent rig generator, four damaged files,
tables from the independent lab battery; two models), generated once per session,
is run on one process and on two (the command line's `--workers`), and on a Dask
`LocalCluster` of two worker processes through `vibrocomp.archive.run(client=...)`,
once undisturbed and once with a worker killed mid-run. Every table must be the same
apart from the timing columns, hold every job of the plan exactly once, and say what
went wrong with each damaged log. No timings are asserted (BENCHMARKS.md has them).

`VIBROCOMP_ARCHIVE_LOGS=N` makes a smaller archive (at least 8 logs) for a quick run.
"""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import vibrocomp as vc
from conftest import REPO, binary

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")

sys.path.insert(0, str(REPO / "tests" / "python"))
import archive_data  # noqa: E402

TIMING = ["elapsed_s", "worker"]
COLUMNS = [
    "job", "kind", "log", "unit", "model", "stage", "window_s", "windows", "error_g", "verdict",
    "effect", "param", "value", "sigma", "problem", "elapsed_s", "worker",
]
N_LOGS = int(os.environ.get("VIBROCOMP_ARCHIVE_LOGS", "200"))
N_TABLES = 20


@pytest.fixture(scope="session")
def archive(tmp_path_factory):
    """The archive (its folder, index.json's content), generated once."""
    if not binary().is_file():
        pytest.skip(f"{binary()} is missing: build it with `cargo build -p vibrocomp`")
    out = tmp_path_factory.mktemp("archive")
    index = archive_data.generate(out, n_logs=N_LOGS, n_tables=N_TABLES)
    return out, index


@pytest.fixture(scope="session")
def small(archive):
    """Six of the archive's logs (two damaged) and two tables (archive_data.py's
    small.toml), for the checks that need not run the whole archive: its manifest
    and its index."""
    root, index = archive
    return root / "small.toml", {**index["small"], "models": index["models"]}


def cli_has_archive() -> bool:
    p = subprocess.run([str(binary()), "archive", "run", "--help"], capture_output=True, text=True)
    return p.returncode == 0


def cli_run(manifest, out, *args):
    p = subprocess.run(
        [str(binary()), "archive", "run", str(manifest), "--out", str(out), *map(str, args), "--json"],
        capture_output=True, text=True, cwd=REPO,
    )
    assert p.returncode == 0, f"vibrocomp archive run {args}: {p.stderr}{p.stdout}"
    return json.loads(p.stdout)


def local_run(manifest, out, workers):
    """One run on `workers` processes of this machine: the command line's `--workers`
    (its own engine) when it has `archive run`, else the Python package's pool."""
    if cli_has_archive():
        cli_run(manifest, out, "--workers", workers)
    else:
        vc.archive.run(manifest, out, workers=workers, progress=False)
    return out / "results.parquet"


def read(path):
    df = pd.read_parquet(path)
    assert list(df.columns) == COLUMNS
    return df


def without_timing(df):
    return df.drop(columns=TIMING).reset_index(drop=True)


def expected_jobs(index):
    """The plan (services/archive/src/plan.rs): every log with every model, then
    every unit in order of first appearance."""
    ids = [f"compensate/{i}/{m}" for i in range(len(index["logs"])) for m in index["models"]]
    units = []
    for u in [u for log in index["logs"] for u in log["units"]] + [t["unit"] for t in index["tables"]]:
        if u not in units:
            units.append(u)
    return ids + [f"lab/{u}" for u in units]


def check_table(df, index, out, lost=()):
    """Every job of the plan exactly once (in the table and the journal), in the plan's
    order; every damaged log's jobs failed with its problem; the good logs' did not
    (but the jobs in `lost`, those a cluster gave up on)."""
    jobs = expected_jobs(index)
    first = df.drop_duplicates("job")["job"].tolist()
    assert first == jobs, "the table's jobs are the plan's, in its order"
    # A job's rows are together: a job recorded twice would come back as a second run.
    runs = (df["job"] != df["job"].shift()).sum()
    assert runs == len(jobs)
    journal = [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines() if line.strip()]
    done = [j["job"] for j in journal if "job" in j]
    assert sorted(done) == sorted(jobs), "the journal holds every job once"
    labels = {log["path"]: i for i, log in enumerate(index["logs"])}
    for path in index["damaged"]:
        rows = df[df["job"].str.startswith(f"compensate/{labels[path]}/")]
        assert len(rows) == len(index["models"]), path
        assert (rows["verdict"] == "failed").all() and rows["problem"].notna().all(), path
        assert rows["problem"].str.contains(Path(path).name, regex=False).all(), rows["problem"].tolist()
    good = df[(df["kind"] == "compensate") & ~df["log"].isin(index["damaged"]) & ~df["job"].isin(set(lost))]
    assert good["problem"].isna().all(), good[good["problem"].notna()][["job", "problem"]].head().to_dict("records")
    assert (good["verdict"] == "ok").all()
    # The estimate stage has no number where no window had an estimate (1 s logs).
    assert good[good["stage"] != "estimate_stage"]["error_g"].notna().all()
    assert (good[good["error_g"].isna()]["windows"] == 0).all()
    lab = df[df["kind"] == "lab"]
    assert set(lab["unit"]) == {j.split("/", 1)[1] for j in jobs if j.startswith("lab/")}


@pytest.fixture(scope="session")
def one_process(archive):
    root, index = archive
    out = root / "out-1"
    t0 = time.monotonic()
    path = local_run(root / "archive.toml", out, 1)
    print(f"1 process: {time.monotonic() - t0:.1f} s")
    return read(path)


@pytest.fixture(scope="session")
def cluster():
    distributed = pytest.importorskip("distributed")
    c = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40
    )
    client = distributed.Client(c)
    yield client
    client.close()
    c.close()


def test_one_process_two_processes_and_a_cluster_give_one_table(archive, one_process, cluster):
    root, index = archive
    check_table(one_process, index, root / "out-1")
    two = read(local_run(root / "archive.toml", root / "out-2", 2))
    check_table(two, index, root / "out-2")
    pd.testing.assert_frame_equal(without_timing(two), without_timing(one_process))
    s = vc.archive.run(root / "archive.toml", root / "out-dask", client=cluster, progress=False)
    assert s.done_now == s.jobs_total == len(expected_jobs(index)) and s.given_up == 0
    dask = s.table()
    check_table(dask, index, root / "out-dask")
    pd.testing.assert_frame_equal(without_timing(dask), without_timing(one_process))
    # The cluster's jobs ran in its two worker processes, not here.
    workers = set(dask["worker"])
    assert len(workers) == 2 and not any(w.endswith(f"/{os.getpid()}") for w in workers), workers


def test_a_worker_killed_mid_run_loses_no_job_and_counts_none_twice(archive, one_process, cluster):
    root, index = archive
    out = root / "out-killed"
    journal = out / "journal.jsonl"
    pids = cluster.run(os.getpid)
    victim = sorted(pids)[0]
    outcome = {}

    def run():
        try:
            outcome["summary"] = vc.archive.run(root / "archive.toml", out, client=cluster, progress=False)
        except BaseException as e:  # noqa: BLE001 - handed to the test's thread
            outcome["error"] = e

    t = threading.Thread(target=run)
    t.start()
    deadline = time.monotonic() + 120
    killed = False
    while t.is_alive() and time.monotonic() < deadline:
        lines = journal.read_text().count("\n") if journal.exists() else 0
        if lines >= 10:
            os.kill(pids[victim], signal.SIGKILL)
            killed = True
            break
        time.sleep(0.05)
    t.join(600)
    assert not t.is_alive()
    assert killed, "the run ended before a worker could be killed: make the archive bigger"
    assert "error" not in outcome, outcome.get("error")
    s = outcome["summary"]
    assert s.given_up == 0
    df = s.table()
    check_table(df, index, out)
    pd.testing.assert_frame_equal(without_timing(df), without_timing(one_process))
    # The killed worker's results before its death count; its nanny started a new
    # process, which took its share of what was left.
    workers = set(df["worker"])
    assert any(w.endswith(f"/{pids[victim]}") for w in workers) and len(workers) == 3, workers
    cluster.wait_for_workers(2, timeout=60)


def test_a_run_resumes_from_its_journal(small, tmp_path):
    """A run cut short (its journal's last lines gone, the last one torn) runs only
    what is missing, and the table is the uninterrupted run's; the package's own
    process pool (`workers=2`) and one process (`workers=1`) give one table. A folder
    of another manifest's run is refused unless `restart=True`."""
    manifest, index = small
    whole = vc.archive.run(manifest, tmp_path / "whole", workers=2, progress=False)
    assert whole.done_now == whole.jobs_total == len(expected_jobs(index)) and whole.duplicates == 0
    check_table(whole.table(), index, tmp_path / "whole")
    reference = without_timing(whole.table())
    again = vc.archive.run(manifest, tmp_path / "whole", workers=2, progress=False)
    assert again.done_now == 0 and again.skipped == whole.jobs_total, "a finished run has nothing left to do"
    pd.testing.assert_frame_equal(without_timing(again.table()), reference)
    cut = tmp_path / "cut"
    cut.mkdir()
    lines = (tmp_path / "whole" / "journal.jsonl").read_text().splitlines(keepends=True)
    keep = len(lines) // 2
    (cut / "journal.jsonl").write_text("".join(lines[:keep]) + lines[keep][: len(lines[keep]) // 2])
    resumed = vc.archive.run(manifest, cut, workers=1, progress=False)
    done_before = keep - 1  # the first line is the journal's header
    assert resumed.skipped == done_before and resumed.torn_bytes > 0
    assert resumed.done_now == whole.jobs_total - done_before
    check_table(resumed.table(), index, cut)
    pd.testing.assert_frame_equal(without_timing(resumed.table()), reference)
    # Another manifest (another window) in that folder: refused, unless restarted.
    other = manifest.parent / "small-other.toml"
    other.write_text(manifest.read_text().replace("window_s = 0.5", "window_s = 0.25"))
    with pytest.raises(vc.VibrocompError, match="another manifest"):
        vc.archive.run(other, cut, workers=1, progress=False)
    restarted = vc.archive.run(other, cut, workers=1, restart=True, progress=False)
    assert restarted.done_now == restarted.jobs_total == whole.jobs_total and restarted.skipped == 0
    check_table(restarted.table(), index, cut)
    assert (restarted.table()["window_s"].dropna() == 0.25).all()


def test_python_m_vibrocomp_archive_on_a_scheduler_is_the_library_run(small, cluster, tmp_path):
    """What `vibrocomp archive run --dask ADDR` runs, and the command itself when built."""
    manifest, index = small
    address = cluster.scheduler.address
    p = subprocess.run(
        [sys.executable, "-m", "vibrocomp.archive", str(manifest), "--out", str(tmp_path / "m"), "--dask", address,
         "--json"],
        capture_output=True, text=True, cwd=REPO,
    )
    assert p.returncode == 0, p.stderr
    assert "RuntimeWarning" not in p.stderr, p.stderr
    got = json.loads(p.stdout)
    assert got["scheduler"] == address and got["done_now"] == got["jobs_total"] == len(expected_jobs(index))
    check_table(read(got["results"]), index, tmp_path / "m")
    local = vc.archive.run(manifest, tmp_path / "local", workers=1, progress=False)
    reference = without_timing(local.table())
    pd.testing.assert_frame_equal(without_timing(read(got["results"])), reference)
    if cli_has_archive():
        p = subprocess.run(
            [str(binary()), "archive", "run", str(manifest), "--out", str(tmp_path / "cli"), "--dask", address,
             "--json"],
            capture_output=True, text=True, cwd=REPO,
        )
        assert p.returncode == 0, p.stderr
        # `--json` reaches the Python side: the summary, as JSON, on stdout.
        assert json.loads(p.stdout)["scheduler"] == address, p.stdout
        pd.testing.assert_frame_equal(without_timing(read(tmp_path / "cli" / "results.parquet")), reference)


def test_a_bad_manifest_is_a_vibrocomp_error_with_its_line_and_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "vibrocomp-archive/1"\nwindow_s = -1.0\n[[model]]\nname = "m"\n')
    with pytest.raises(vc.VibrocompError) as e:
        vc.archive.run(bad, tmp_path / "out", workers=1, progress=False)
    assert e.value.file == str(bad) and e.value.line == 2 and e.value.key == "window_s", e.value.to_dict()
    p = subprocess.run(
        [sys.executable, "-m", "vibrocomp.archive", str(bad), "--out", str(tmp_path / "out"), "--json"],
        capture_output=True, text=True,
    )
    assert p.returncode == 1
    err = json.loads(p.stdout)["error"]
    assert err["key"] == "window_s" and err["line"] == 2 and err["exit_code"] == 1
    with pytest.raises(vc.VibrocompError, match="workers"):
        vc.archive.run(bad, tmp_path / "out", workers=0)


def test_a_job_dask_gives_up_on_is_a_failed_row(small, tmp_path):
    """A cluster that gives a task no second chance when its worker dies
    (`allowed-failures = 0`): the jobs running on the killed worker come back as
    `failed` rows saying why, every other job as on one process."""
    distributed = pytest.importorskip("distributed")
    import dask

    manifest, index = small
    reference = without_timing(vc.archive.run(manifest, tmp_path / "local", workers=1, progress=False).table())
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        c = distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40
        )
        client = distributed.Client(c)
        try:
            pids = client.run(os.getpid)
            out = tmp_path / "dask"
            outcome = {}

            def run():
                outcome["summary"] = vc.archive.run(manifest, out, client=client, progress=False)

            t = threading.Thread(target=run)
            t.start()
            # As soon as the tasks run (before the first result: a small archive is quick).
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not client.processing().get(sorted(pids)[0]):
                time.sleep(0.005)
            os.kill(pids[sorted(pids)[0]], signal.SIGKILL)
            t.join(300)
        finally:
            client.close()
            c.close()
    s = outcome["summary"]
    assert s.given_up >= 1 and s.done_now == s.jobs_total
    df = s.table()
    lost = df[df["problem"].fillna("").str.contains("the Dask task failed for good: KilledWorker", regex=False)]
    assert lost["job"].nunique() == s.given_up and (lost["verdict"] == "failed").all()
    check_table(df, index, out, lost=set(lost["job"]))
    kept = ~df["job"].isin(set(lost["job"]))
    pd.testing.assert_frame_equal(
        without_timing(df[kept]), reference[reference["job"].isin(set(df[kept]["job"]))].reset_index(drop=True)
    )
