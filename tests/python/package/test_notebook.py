"""The example notebook `examples/python/vibrocomp.ipynb`, run top to bottom as a new
user runs it: `vibrocomp demo` into a temporary folder, then the notebook's code cells
in order, in one namespace, as a script (no Jupyter kernel). The figures are checked by
their files (size, pixels, not blank) and by what they plot (the data of each line
against the lab's results and the session log); the lab's result against the
campaign's hidden truth.

Everything the test writes goes under pytest's temporary folder: the demo, the
figures, matplotlib's cache (when matplotlib is first imported here).
"""

import base64
import csv
import json
import math
import os
import struct
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import vibrocomp as vc

REPO = Path(__file__).resolve().parents[3]
NOTEBOOK_DIR = REPO / "examples" / "python"
NOTEBOOK = NOTEBOOK_DIR / "vibrocomp.ipynb"
CAMPAIGN = NOTEBOOK_DIR / "data" / "campaign-mount-k6.csv"
TRUTH = NOTEBOOK_DIR / "data" / "campaign-mount-k6.truth.json"

# The figures' size in pixels (figsize x dpi 100, as the notebook saves them).
RESIDUALS_PX = (900, 600)
STAGES_PX = (900, 800)
WINDOW = 400  # samples per 0.5 s window at 800 Hz, the demo's measure


def vibrocomp_bin() -> Path:
    return Path(os.environ.get("VIBROCOMP_BIN") or REPO / "target" / "debug" / "vibrocomp")


def code_cells():
    """The notebook's code cells: (index, source)."""
    nb = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    return [(i, "".join(c["source"])) for i, c in enumerate(nb["cells"]) if c["cell_type"] == "code"]


def run_cells(cells, ns):
    for i, source in cells:
        exec(compile(source, f"{NOTEBOOK.name}, cell {i}", "exec"), ns)


def notebook_env(mp, tmp: Path, demo_dir: Path, out_dir: Path):
    """The environment the notebook reads, set before any cell runs; the working
    directory a temporary one, so that nothing can land in the repository."""
    mp.setenv("VIBROCOMP_DEMO_DIR", str(demo_dir))
    mp.setenv("VIBROCOMP_NOTEBOOK_DIR", str(NOTEBOOK_DIR))
    mp.setenv("VIBROCOMP_NOTEBOOK_OUT", str(out_dir))
    mp.setenv("MPLBACKEND", "Agg")
    mp.setenv("MPLCONFIGDIR", str(tmp / "matplotlib"))
    mp.chdir(tmp)


@pytest.fixture(scope="module")
def notebook(tmp_path_factory):
    """The demo run into a temporary folder (about 2 s) and the notebook run over it:
    the notebook's namespace and its output folder."""
    exe = vibrocomp_bin()
    if not exe.is_file():
        pytest.skip(f"{exe} is missing: build it with `cargo build -p vibrocomp` or set VIBROCOMP_BIN")
    tmp = tmp_path_factory.mktemp("notebook")
    demo_dir = tmp / "demo"
    p = subprocess.run(
        [str(exe), "-q", "demo", "--out-dir", str(demo_dir)],
        capture_output=True, text=True, cwd=tmp, timeout=600,
    )
    assert p.returncode == 0, f"vibrocomp demo failed ({p.returncode}):\n{p.stdout}\n{p.stderr}"
    assert (demo_dir / "session.mcap").is_file()

    out_dir = tmp / "out"
    ns = {"__name__": "__notebook__"}
    files_before = sorted(NOTEBOOK_DIR.rglob("*"))
    with pytest.MonkeyPatch.context() as mp:
        notebook_env(mp, tmp, demo_dir, out_dir)
        run_cells(code_cells(), ns)
    files_after = sorted(NOTEBOOK_DIR.rglob("*"))
    yield SimpleNamespace(ns=ns, out=out_dir, files_before=files_before, files_after=files_after)

    import matplotlib.pyplot as plt

    for name in ("fig_residuals", "fig_stages"):
        if name in ns:
            plt.close(ns[name])


def png_size(path: Path):
    """Width and height from the PNG's IHDR chunk."""
    data = path.read_bytes()[:24]
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", f"{path} is not a PNG"
    return struct.unpack(">II", data[16:24])


def check_png(path: Path, size_px):
    import matplotlib.image as mpimg

    assert path.is_file(), f"{path} was not written"
    assert path.stat().st_size >= 20_000, f"{path}: {path.stat().st_size} bytes, a nearly empty figure"
    assert png_size(path) == size_px
    pixels = mpimg.imread(path)[..., :3]
    assert pixels.shape[:2] == (size_px[1], size_px[0])
    assert pixels.std() > 0.05, f"{path} is blank (std {pixels.std():.4f})"
    # Not only a frame on white: a good share of the pixels is drawn.
    assert (pixels.min(axis=2) < 0.9).mean() > 0.03


def campaign_freq_hz():
    """Each run's tone frequency from the campaign file itself (NaN without a tone)."""
    with open(CAMPAIGN, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    return {r["run_id"]: float(r["freq_hz"]) if r["freq_hz"] else math.nan for r in rows}


def test_a_missing_demo_is_explained(tmp_path, monkeypatch):
    """Without the demo's session the first cell stops, saying which command writes it,
    and writes nothing."""
    out_dir = tmp_path / "out"
    notebook_env(monkeypatch, tmp_path, tmp_path / "no-demo", out_dir)
    with pytest.raises(FileNotFoundError, match=r"cargo run --release -p vibrocomp -- demo"):
        run_cells(code_cells()[:1], {"__name__": "__notebook__"})
    assert not out_dir.exists()


def test_the_lab_finds_the_hidden_effects(notebook):
    ns = notebook.ns
    truth = json.loads(TRUTH.read_text(encoding="utf-8"))
    d, a = ns["d"], ns["a"]
    assert d.verdict.verdict == "effect"
    assert set(d.next_effects) == {"mount_resonance", "high_order_nonlinearity"} == set(truth["params"])
    assert set(a.model.effects) == set(truth["params"])

    fitted = {(p.effect, p.name): p for p in a.fit.params}
    expected = {(e, name) for e, params in truth["params"].items() for name in params}
    assert set(fitted) == expected
    for (effect, name), p in fitted.items():
        true_value = truth["params"][effect][name]
        assert p.sigma > 0
        assert abs(p.value - true_value) <= 4 * p.sigma, (
            f"{effect}.{name} = {p.value} +- {p.sigma}, truth {true_value}: "
            f"{(p.value - true_value) / p.sigma:+.2f} sigma"
        )

    assert ns["before"].summary.chi2_per_dof > 1e6
    assert ns["after"].summary.chi2_per_dof < 2
    assert len(ns["after"].rows) == len(ns["before"].rows) == truth["rows"]


def test_the_model_cell(notebook):
    """The VE grid: exact and paper over 0..2 g, both zero without vibration and growing
    with it."""
    ns = notebook.ns
    ab3_g = ns["ab3_g"]
    assert ab3_g[0] == 0.0 and ab3_g[-1] == 2.0
    for v in (ns["ve_exact"], ns["ve_paper"]):
        assert v.total_g.shape == ab3_g.shape
        assert v.total_g[0] == 0.0 and np.all(np.diff(v.total_g) > 0)
    one = vc.ve("AL-15", al3_g=1.0, ab3_g=ab3_g[-1], freq_hz=40.0, mode="paper")
    assert ns["ve_paper"].total_g[-1] == one.total_g


def test_the_residual_figure(notebook):
    ns = notebook.ns
    check_png(notebook.out / "residuals.png", RESIDUALS_PX)

    fig = ns["fig_residuals"]
    assert len(fig.axes) == 2
    freq_hz = campaign_freq_hz()
    for ax, name in zip(fig.axes, ("before", "after")):
        comparison = ns[name]
        series = [l for l in ax.get_lines() if l.get_label().startswith(f"{name}:")]
        assert len(series) == 1, [l.get_label() for l in ax.get_lines()]
        assert len(ax.get_lines()) == 2  # the residuals and the fitted resonance
        np.testing.assert_array_equal(series[0].get_ydata(), [r.z for r in comparison.rows])
        np.testing.assert_array_equal(series[0].get_xdata(), [freq_hz[r.run_id] for r in comparison.rows])
    # The fitted resonance is marked where the fit put it.
    resonance = next(p.value for p in ns["a"].fit.params if p.name == "freq_hz")
    for ax in fig.axes:
        marker = [l for l in ax.get_lines() if "resonance" in l.get_label()]
        assert len(marker) == 1 and np.all(np.asarray(marker[0].get_xdata()) == resonance)


def test_the_stage_figure(notebook):
    ns = notebook.ns
    check_png(notebook.out / "stages.png", STAGES_PX)

    comp, truth = ns["comp"], ns["truth"]
    np.testing.assert_array_equal(comp.samples["sample_index"], truth.samples["sample_index"])
    sensed_g = truth.samples["a_sensed_ia_g"][:, 0]
    t_s = comp.samples["t_ns"] / 1e9
    expected = {k: comp.samples[k][:, 0] - sensed_g for k in ("a1_g", "a2_g", "a4_g")}

    fig = ns["fig_stages"]
    assert len(fig.axes) == 3
    *sample_axes, means_axis = fig.axes

    per_sample = [l for ax in sample_axes for l in ax.get_lines()]
    assert len(per_sample) == 3
    for line, k in zip(per_sample, expected):
        np.testing.assert_array_equal(line.get_xdata(), t_s)
        np.testing.assert_array_equal(line.get_ydata(), expected[k])

    # The means over the windows compensated for the vibration (no MAIN_ONLY, bit 2).
    n = len(t_s) // WINDOW
    main_only = (comp.samples["flags"][: n * WINDOW] & (1 << 2)) != 0
    counted = ~main_only.reshape(n, WINDOW).any(axis=1)
    assert 0 < counted.sum() < n  # the first block is compensated for the main error only
    means = means_axis.get_lines()
    assert len(means) == 3 and means_axis.get_yscale() == "log"
    for line, k in zip(means, expected):
        mean_g = expected[k][: n * WINDOW].reshape(n, WINDOW).mean(axis=1)[counted]
        np.testing.assert_allclose(line.get_ydata(), np.abs(mean_g), rtol=1e-12, atol=0)
        np.testing.assert_allclose(
            line.get_xdata(), t_s[: n * WINDOW].reshape(n, WINDOW).mean(axis=1)[counted], rtol=1e-12
        )
    # Each stage cuts the mean error: a(1) > a(2) > a(4), in RMS over the windows.
    rms = [np.sqrt(np.mean(np.square(line.get_ydata()))) for line in means]
    assert rms[0] > 10 * rms[1] and rms[1] > 5 * rms[2], rms


def test_the_notebook_writes_its_figures_only(notebook):
    """The two figures in the output folder, nothing next to the notebook."""
    assert sorted(p.name for p in notebook.out.iterdir()) == ["residuals.png", "stages.png"]
    assert notebook.files_after == notebook.files_before


def test_the_committed_notebook_shows_its_results_and_plots(notebook):
    """The notebook is committed with its outputs, so that a forge shows its plots: run
    top to bottom once (execution counts 1..n), both figures as PNG, no progress-bar
    noise (stderr), and the figures it printed are the ones this run of its code gives
    (an edit to the code without running the notebook again fails here)."""
    nb = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    assert nb["nbformat"] == 4
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert code and len(nb["cells"]) <= 16
    assert [c["execution_count"] for c in code] == list(range(1, len(code) + 1))
    outputs = [o for c in code for o in c["outputs"]]
    assert all(c["outputs"] for c in code), "a code cell without output"
    assert not [o for o in outputs if o.get("name") == "stderr"]
    pngs = [o["data"]["image/png"] for o in outputs if "image/png" in o.get("data", {})]
    assert len(pngs) == 2
    for png in pngs:
        raw = base64.b64decode(png)
        assert raw[:8] == b"\x89PNG\r\n\x1a\n"
        width, height = struct.unpack(">II", raw[16:24])  # the IHDR chunk
        assert width >= 400 and height >= 300, (width, height)
    printed = "".join("".join(o["text"]) for o in outputs if o["output_type"] == "stream")
    ns = notebook.ns
    before, after, a = ns["before"], ns["after"], ns["a"]
    assert (
        f"chi2/dof: {before.summary.chi2_per_dof:.4g} with the passport alone, "
        f"{after.summary.chi2_per_dof:.3f} with {a.model.effects}"
    ) in printed
    for p in a.fit.params:
        assert f"{p.effect:<25} {p.name:<15} {p.value:12.6g} {p.sigma:10.2g}" in printed
    assert "session:  vibrocomp-demo/session.mcap" in printed  # no machine's own paths
