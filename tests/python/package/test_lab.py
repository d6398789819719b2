"""The lab from Python against the command line: compare, diagnose and add give the
same content as `--json` (the same effects, parameters to 1e-12 relative), on a
campaign file, a DataFrame, a dict of arrays, a shake-table manifest of raw runs and
a log with a reference; the extended model is the file `lab add --out` writes, byte
for byte, and reads back; the errors carry the command line's message, file, line and
key."""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

import vibrocomp as vc
from conftest import REPO

CAMPAIGN = REPO / "examples" / "python" / "data" / "campaign-mount-k6.csv"
FOUND = ["mount_resonance", "high_order_nonlinearity"]


def without_timing(d):
    """A diagnosis without what depends on the clock (the budget's elapsed times)."""
    d = dict(d)
    budget = dict(d.pop("budget"))
    budget.pop("elapsed_s")
    budget["stages"] = [{k: v for k, v in s.items() if k != "elapsed_s"} for s in budget["stages"]]
    return d, budget


def close(a, b, rel=1e-12):
    """Equal within `rel` relative, recursively (a fit's parameters)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k], rel) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(close(x, y, rel) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float):
        return a == b or abs(a - b) <= rel * max(abs(a), abs(b)) or (math.isnan(a) and math.isnan(b))
    return a == b


def test_compare_is_the_command_lines_json(cli):
    c = vc.lab.compare(CAMPAIGN)
    assert c.to_dict() == cli("lab", "compare", CAMPAIGN)
    assert c.summary.n == 200 and c.summary.chi2_per_dof > 1e6
    frame = c.to_frame()
    assert list(frame["z"]) == [r.z for r in c.rows]


def test_diagnose_finds_the_command_lines_effects_with_the_same_parameters(cli):
    calls = []
    d = vc.lab.diagnose(CAMPAIGN, progress=lambda done, of, what: calls.append((done, of)))
    want = cli("lab", "diagnose", CAMPAIGN)
    got_rest, got_budget = without_timing(d.to_dict())
    want_rest, want_budget = without_timing(want)
    assert close(got_rest, want_rest), "the diagnosis differs from the command line's"
    assert got_budget == want_budget
    assert d.verdict.verdict == "effect" and d.next_effects == FOUND
    assert calls and calls[-1][0] == calls[-1][1], "the progress callback saw the candidates fitted"


def test_save_keeps_the_command_lines_file_rule(tmp_path):
    """`Model.save` writes as the command line does (README, "Files"): never through a
    symbolic link (dangling or not), into a FIFO or a device, even with `overwrite`;
    an existing file only with `overwrite`; nothing left behind. (Before, `overwrite`
    wrote through a link into its target and blocked on a FIFO.)"""
    m = vc.Model('format = "vibrocomp-model/1"\nmode = "exact"\n')
    target = tmp_path / "target.toml"
    target.write_text("kept")
    link = tmp_path / "link.toml"
    link.symlink_to(target)
    dangling = tmp_path / "dangling.toml"
    dangling.symlink_to(tmp_path / "missing.toml")
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    for path, says in [
        (link, "is a symbolic link to"),
        (dangling, "is a symbolic link to"),
        (fifo, "is a FIFO"),
        ("/dev/null", "is a character device"),
    ]:
        for overwrite in [True, False]:
            with pytest.raises(vc.VibrocompError, match=says) as e:
                m.save(path, overwrite=overwrite)
            assert str(path) in str(e.value)
    assert target.read_text() == "kept"
    assert not (tmp_path / "missing.toml").exists()
    mine = tmp_path / "model.toml"
    m.save(mine)
    with pytest.raises(FileExistsError, match="pass --force to overwrite it"):
        m.save(mine)
    m.save(mine, overwrite=True)
    assert mine.read_text() == m.text
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "dangling.toml", "fifo.toml", "link.toml", "model.toml", "target.toml"
    ]


def test_add_writes_the_command_lines_model_and_reads_it_back(cli, tmp_path):
    out = tmp_path / "cli-model.toml"
    want = cli("lab", "add", ",".join(FOUND), "--from", CAMPAIGN, "--out", out)
    a = vc.lab.add(FOUND, CAMPAIGN)
    assert a.effects == want["effects"] == FOUND
    got = a.to_dict()
    assert close(got, {k: v for k, v in want.items() if k != "out"})
    for p, w in zip(a.fit.params, want["fit"]["params"]):
        assert p.name == w["name"] and abs(p.value - w["value"]) <= 1e-12 * abs(w["value"])
    assert a.model.text == out.read_text(), "the model is the file `lab add --out` writes"
    mine = tmp_path / "model.toml"
    a.model.save(mine)
    with pytest.raises(FileExistsError):
        a.model.save(mine)
    back = vc.Model.load(mine)
    assert back.effects == FOUND and back.mode == "exact"
    after = vc.lab.compare(CAMPAIGN, model=back)
    assert after.to_dict() == cli("lab", "compare", CAMPAIGN, "--model", mine) | {"table": after.table}
    assert after.summary.chi2_per_dof < 2
    # `diagnosed` is `lab add --diagnosed`.
    d = vc.lab.add("diagnosed", CAMPAIGN)
    assert d.model.text == a.model.text


def test_the_fit_finds_the_hidden_truth_within_its_uncertainty():
    truth = __import__("json").loads((CAMPAIGN.with_suffix("").with_suffix(".truth.json")).read_text())
    a = vc.lab.add(FOUND, CAMPAIGN)
    for p in a.fit.params:
        t = truth["params"][p.effect][p.name]
        assert abs(p.value - t) <= 4 * p.sigma, (p.effect, p.name, p.value, t, p.sigma)


def test_a_dataframe_and_a_dict_of_arrays_are_the_file(cli):
    pd = pytest.importorskip("pandas")
    df = pd.read_csv(CAMPAIGN, comment="#")
    from_file = vc.lab.compare(CAMPAIGN)
    for table in (df, {c: df[c].to_numpy() for c in df.columns}):
        c = vc.lab.compare(table)
        assert c.summary == from_file.summary
        assert [(r.run_id, r.residual_g, r.z) for r in c.rows] == [(r.run_id, r.residual_g, r.z) for r in from_file.rows]
    d = vc.lab.diagnose(df)
    assert d.next_effects == FOUND
    t = vc.lab.table(CAMPAIGN)
    assert list(t["run_id"]) == list(df["run_id"]) and np.array_equal(t["ve_measured_g"], df["ve_measured_g"])


def test_a_manifest_of_raw_runs_is_the_command_lines(cli, tmp_path):
    gen = subprocess.run(
        [sys.executable, str(REPO / "tests" / "python" / "rig_generator.py"), "campaign", "--out", str(tmp_path),
         "--sensor-rate-hz", "6400", "--orientations", "+z,oblique1", "--tone-freqs-hz", "40",
         "--still-s", "2", "--vib-s", "3"],
        capture_output=True, text=True, env={"PYTHONDONTWRITEBYTECODE": "1", "PATH": "/usr/bin:/bin"},
    )
    assert gen.returncode == 0, gen.stderr
    manifest = tmp_path / "campaign.toml"
    manifest.write_text(
        'format = "vibrocomp-campaign/1"\nruns = "runs.csv"\n[segments]\nstill_before_s = [0.0, 2.0]\n'
        "vibrating_s = [2.2, 4.9]\nstill_after_s = [5.1, 7.0]\n"
    )
    c = vc.lab.compare(manifest)
    assert c.to_dict() == cli("lab", "compare", manifest)
    assert c.summary.n == 6, "two runs of a triad"


def test_a_log_with_a_reference_is_the_command_lines(cli, demo_dir):
    flight = demo_dir / "flight.mcap"
    c = vc.lab.compare(flight, pool_windows=2)
    want = cli("lab", "compare", flight, "--pool-windows", "2", "--path", "windows")
    assert c.to_dict() == want
    assert c.log is not None and c.log["conditions"] == c.summary.n
    both = vc.lab.compare(flight, CAMPAIGN)
    assert both.to_dict() == cli("lab", "compare", flight, CAMPAIGN)
    assert both.logs is None and both.log is not None
    # A log with vibration samples is evaluated as the compensator does (the waveform
    # stage over its samples), the table from the statistics; `path="statistics"`
    # takes the statistics for all, as `--path statistics` does.
    assert {r.path for r in both.rows} == {"waveform", "statistics"}
    assert c.paths["waveform"] > 0.5 * c.summary.n
    assert c.paths["waveform"] + c.paths["statistics"] == c.summary.n
    assert all(r.window["readings"] > 0 for r in c.rows if r.path == "waveform")
    stats = vc.lab.compare(flight, pool_windows=2, path="statistics")
    assert stats.to_dict() == cli("lab", "compare", flight, "--pool-windows", "2", "--path", "statistics")
    assert {r.path for r in stats.rows} == {"statistics"}
    with pytest.raises(ValueError, match="path = \"waves\""):
        vc.lab.compare(flight, path="waves")


def test_a_bad_table_is_the_command_lines_error(cli, tmp_path):
    bad = tmp_path / "bad.csv"
    lines = CAMPAIGN.read_text().splitlines()
    # Line 7 of the file: the third condition, with an impossible uncertainty.
    cells = lines[6].split(",")
    cells[18] = "-1"
    lines[6] = ",".join(cells)
    bad.write_text("\n".join(lines) + "\n")
    want = cli("lab", "compare", bad, check=False)["error"]
    with pytest.raises(vc.VibrocompError) as e:
        vc.lab.compare(bad)
    got = e.value.to_dict()
    assert got == {k: v for k, v in want.items() if k != "exit_code"}
    assert got["file"] == str(bad) and "line 7" in got["message"]


def test_a_bad_model_file_is_the_command_lines_error(cli, tmp_path):
    bad = tmp_path / "model.toml"
    bad.write_text('mode = "exact"\nbogus = 3\n')
    want = cli("lab", "compare", CAMPAIGN, "--model", bad, check=False)["error"]
    with pytest.raises(vc.VibrocompError) as e:
        vc.Model.load(bad)
    got = e.value.to_dict()
    for k in ("file", "line", "column", "key"):
        assert got.get(k) == want.get(k), (k, got, want)
    assert want["message"] == "lab compare: " + got["message"]
    assert (got["line"], got["column"], got["key"]) == (2, 1, "bogus")


def test_requests_the_lab_refuses_are_errors_not_crashes():
    with pytest.raises(vc.VibrocompError, match="empirical"):
        vc.lab.add("empirical", CAMPAIGN, freeze=True)
    with pytest.raises(vc.VibrocompError):
        vc.lab.add("no_such_effect", CAMPAIGN)
    with pytest.raises(vc.VibrocompError):
        vc.lab.compare(REPO / "no-such-file.csv")
    with pytest.raises(TypeError):
        vc.lab.compare(42)
    with pytest.raises(vc.VibrocompError):
        vc.lab.compare({"run_id": ["a"], "passport": ["AL-15"]})
