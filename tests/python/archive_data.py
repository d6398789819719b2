#!/usr/bin/env python3
"""An archive to replay (README, "Replaying an archive"; tests/python/package/
test_archive.py): tiny flight logs from two independent sources, a few damaged files,
campaign tables, two models and the manifest that lists them.

    python3 tests/python/archive_data.py --out DIR [--logs 200] [--tables 20] [--bin PATH] [--processes N]

Of the good logs, four fifths are the simulator's (cheap to make and to replay) and
one fifth the rig generator's. What it writes under DIR:

- ``logs/sim-*.mcap``: vibrocomp's simulator (``vibrocomp sim SCENARIO --duration-s D
  --seed S --out``), three flight scenarios, 1 or 1.5 s, a seed each; the log carries
  the simulator's ``/truth``, the reference the compensation is scored against.
- ``logs/rig-*.mcap``: the independent rig generator (tests/python/rig_generator.py,
  written from MODEL.md and RIG.md in numpy/scipy, no vibrocomp code), a shaker
  vibrating throughout in several orientations and tone frequencies, its CSVs turned
  into a log by ``vibrocomp log import --accel --vib --rig`` (the rig's static
  reference beside the readings), as tests/integration/rig_log.rs does; the rig file
  and the generator's truth stay under ``rigs/NAME/``, the CSVs are deleted. 3 s:
  the first 2 s of a rig log's compensated session have no error sample (readings,
  reference and output together), and ``log errors`` needs a whole window after that.
- ``logs/damaged-*.mcap``: a simulator log cut short, one cut inside its header, a
  file of random bytes, an empty file: each must come back as rows with ``problem``.
- ``tables/*.csv``: campaign tables in the lab's format (docs/lab.md), computed by
  the independent lab-battery generator (tests/python/lab_battery.py: MODEL.md's
  expectation of the conversion function over the stated vibration, numpy/scipy)
  on its separating design, half with a hidden sixth-order nonlinearity, plus
  Gaussian noise of the stated uncertainty.
- ``models/k6.toml``: the second model, the shipped one extended with a
  ``high_order_nonlinearity`` effect (``[[model]] model = ...``); the first is the
  shipped configuration.
- ``archive.toml``: the manifest (``format = "vibrocomp-archive/1"``), every path
  relative to it; ``small.toml``: six of its logs (two damaged) and two tables;
  ``index.json``: what is where (which logs are damaged, the unit ids), for the tests.

Unit ids: 10 triads of three units (``T01-AK1`` .. ``T10-AK3``); log k is flown by
triad ``k % 10``; table k belongs to unit ``k`` of the 30 (so 20 units have a table).

Everything derives from ``--seed``; the simulator's logs are bit-identical for the
same binary and seed, the rig generator's for the same numpy/scipy.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]

# Flight scenarios the simulator runs for a second or two (config/scenarios).
SIM_SCENARIOS = ("cyclone-4-short", "tactical-100s", "cyclone-4")
RIG_ORIENTATIONS = ("+z", "-z", "+x", "oblique1", "oblique2", "-y")
RIG_TONES_HZ = ("60", "90", "120", "45,75,150")
TRIADS = 10
UNITS = [f"T{t + 1:02d}-AK{u + 1}" for t in range(TRIADS) for u in range(3)]

K6_MODEL = """format = "vibrocomp-model/1"
mode = "exact"
passport = "AL-15"

# The shipped model extended with a sixth-order nonlinearity (docs/effects.md).
[[effect]]
kind = "high_order_nonlinearity"
k6_ppm_per_g5 = 0.05
k7_ppm_per_g6 = 0.0
"""


def binary(arg=None) -> Path:
    return Path(arg or os.environ.get("VIBROCOMP_BIN") or REPO / "target" / "debug" / "vibrocomp")


def _run(cmd):
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, cwd=REPO)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))}: exit {p.returncode}: {p.stderr.strip()}")
    return p.stdout


def sim_log(args):
    """One simulator log."""
    exe, out, scenario, duration_s, seed = args
    _run([exe, "-q", "sim", scenario, "--duration-s", duration_s, "--seed", seed, "--out", out, "--force"])
    return str(out)


def rig_log(args):
    """One rig-generator run imported as a log (tests/integration/rig_log.rs)."""
    exe, out, run_dir, seed, orientation, tone_hz, duration_s, resonance = args
    sys.path.insert(0, str(HERE))
    import rig_generator as rg

    cfg = rg.RunConfig(
        vibrate_throughout=True,
        duration_s=duration_s,
        sensor_rate_hz=6400.0,
        orientation=tuple(rg.orientation_vector(orientation)),
        orientation_name=orientation,
        tone_hz=tuple(float(f) for f in np.broadcast_to(np.array(tone_hz.split(","), float), 3)),
        resonance=rg.Resonance(150.0, 2.5) if resonance else None,
        seed=seed,
    )
    res = rg.simulate(cfg)
    rg.write_run(res, run_dir)
    up = res.truth["orientation"]
    rig = Path(run_dir) / "rig.toml"
    rig.write_text(
        'format = "vibrocomp-rig/1"\ntriad = "default"\n[sensors]\n'
        "sensitivity_v_per_g = 0.1\nac_corner_hz = 2.0\n[reference]\nkind = \"static\"\n"
        "[[reference.segment]]\nfrom_s = 0.0\nto_s = 3600.0\n"
        f"up = [{float(up[0])!r}, {float(up[1])!r}, {float(up[2])!r}]\n"
    )
    _run([exe, "-q", "log", "import", "--accel", Path(run_dir) / "accel.csv", "--vib", Path(run_dir) / "vib.csv",
          "--rig", rig, "--out", out, "--force"])
    # The log holds what the archive needs; the CSVs (0.5 MB a second) are left out.
    for name in ("accel.csv", "vib.csv", "reference.csv", "readings_truth.csv"):
        (Path(run_dir) / name).unlink()
    return str(out)


def campaign_table(args):
    """One campaign table from the lab battery's independent expectation."""
    path, seed, rows, hidden_k6 = args
    sys.path.insert(0, str(HERE))
    import lab_battery as lb

    rng = np.random.default_rng([seed, 7])
    P = lb.Passport()
    table_rows = lb.design(rng, rows)
    tab = lb.Table(table_rows)
    eff = {"high_order_nonlinearity": {"k6_ppm_per_g5": 0.05, "k7_ppm_per_g6": 0.0}} if hidden_k6 else {}
    ve = lb.ve(P, tab, eff)
    u = float(np.exp(rng.uniform(math.log(0.3e-6), math.log(2e-6)))) * rng.uniform(0.8, 1.25, tab.n)
    for r, v, s, e in zip(table_rows, ve, u, rng.normal(size=tab.n) * u):
        r.pop("_dir", None)
        r["ve_measured_g"] = float(v + e)
        r["ve_uncertainty_g"] = float(s)
    lb.write_csv(path, table_rows)
    return str(path)


def damage(good: Path, out_dir: Path, seed: int):
    """Damaged logs: cut at 60 %, cut inside the header, random bytes, empty."""
    data = good.read_bytes()
    rng = np.random.default_rng([seed, 99])
    made = {
        "damaged-truncated.mcap": data[: int(len(data) * 0.6)],
        "damaged-header.mcap": data[:20],
        "damaged-garbage.mcap": rng.integers(0, 256, 4096, dtype=np.uint8).tobytes(),
        "damaged-empty.mcap": b"",
    }
    for name, content in made.items():
        (out_dir / name).write_bytes(content)
    return sorted(made)


def manifest_text(logs, tables, window_s):
    """The manifest of `logs` ((path, units, rig or None)) and `tables` ((path, unit, _))."""
    lines = [
        "# An archive of tiny logs for tests/python/package/test_archive.py, written by",
        "# tests/python/archive_data.py (regenerate with it).",
        'format = "vibrocomp-archive/1"',
        f"window_s = {window_s!r}",
        'triad = "default"',
        "",
        "[lab]",
        "enabled = true",
        "max_effects = 1",
        'effects = ["high_order_nonlinearity", "mount_resonance"]',
        "",
        "[[model]]",
        'name = "shipped"',
        "",
        "[[model]]",
        'name = "k6"',
        'model = "models/k6.toml"',
    ]
    for path, units, rig in logs:
        lines += ["", "[[log]]", f'path = "{path}"', "units = [" + ", ".join(f'"{u}"' for u in units) + "]"]
        if rig:
            lines.append(f'rig = "{rig}"')
    for path, unit, _ in tables:
        lines += ["", "[[table]]", f'path = "{path}"', f'unit = "{unit}"']
    return "\n".join(lines) + "\n"


def generate(out, n_logs=200, n_tables=20, exe=None, processes=None, seed=1, table_rows=24, window_s=0.5):
    """Writes the archive under `out`; returns the index (also `out/index.json`)."""
    t0 = time.monotonic()
    out = Path(out)
    exe = binary(exe)
    if not exe.is_file():
        raise FileNotFoundError(f"{exe}: build it with `cargo build -p vibrocomp` or set VIBROCOMP_BIN")
    logs, rigs, tables, models = (out / d for d in ("logs", "rigs", "tables", "models"))
    for d in (logs, rigs, tables, models):
        d.mkdir(parents=True, exist_ok=True)
    n_damaged = 4
    n_good = n_logs - n_damaged
    n_sim = n_good * 4 // 5
    n_rig = n_good - n_sim
    sim_jobs = []
    for k in range(n_sim):
        scenario = SIM_SCENARIOS[k % len(SIM_SCENARIOS)]
        duration = ("1", "1.5")[k % 2]
        sim_jobs.append((exe, logs / f"sim-{k:03d}.mcap", scenario, duration, str(seed * 1000 + k)))
    rig_jobs = []
    for k in range(n_rig):
        rig_jobs.append((exe, logs / f"rig-{k:03d}.mcap", rigs / f"rig-{k:03d}", seed * 1000 + k,
                         RIG_ORIENTATIONS[k % len(RIG_ORIENTATIONS)], RIG_TONES_HZ[k % len(RIG_TONES_HZ)],
                         3.0, k % 5 == 0))
    table_jobs = [(tables / f"campaign-{k:02d}.csv", seed * 1000 + k, table_rows, k % 2 == 1) for k in range(n_tables)]
    with ProcessPoolExecutor(processes or os.cpu_count() or 1) as pool:
        futures = [pool.submit(sim_log, j) for j in sim_jobs]
        futures += [pool.submit(rig_log, j) for j in rig_jobs]
        futures += [pool.submit(campaign_table, j) for j in table_jobs]
        for f in futures:
            f.result()
    damaged = damage(logs / "sim-000.mcap", logs, seed)
    (models / "k6.toml").write_text(K6_MODEL)

    entries = [(f"logs/sim-{k:03d}.mcap", None) for k in range(n_sim)]
    entries += [(f"logs/rig-{k:03d}.mcap", f"rigs/rig-{k:03d}/rig.toml") for k in range(n_rig)]
    entries += [(f"logs/{name}", None) for name in damaged]
    logs_of = [(path, UNITS[3 * (k % TRIADS): 3 * (k % TRIADS) + 3], rig) for k, (path, rig) in enumerate(entries)]
    tables_of = [(f"tables/campaign-{k:02d}.csv", UNITS[k], k % 2 == 1) for k in range(n_tables)]
    (out / "archive.toml").write_text(manifest_text(logs_of, tables_of, window_s))
    # A few of the same files (two logs of each source, two damaged, two tables), for
    # the checks that need not run the whole archive.
    small_logs = [e for e in logs_of if "/sim-" in e[0]][:2] + [e for e in logs_of if "/rig-" in e[0]][:2]
    small_logs += [e for e in logs_of if "/damaged-" in e[0]][:2]
    (out / "small.toml").write_text(manifest_text(small_logs, tables_of[:2], window_s))
    index = {
        "logs": [{"path": p, "units": u, "rig": r} for p, u, r in logs_of],
        "damaged": [p for p, _, _ in logs_of if "/damaged-" in p],
        "tables": [{"path": p, "unit": u, "hidden_k6": k6} for p, u, k6 in tables_of],
        "small": {"logs": [{"path": p, "units": u, "rig": r} for p, u, r in small_logs],
                  "damaged": [p for p, _, _ in small_logs if "/damaged-" in p],
                  "tables": [{"path": p, "unit": u, "hidden_k6": k6} for p, u, k6 in tables_of[:2]]},
        "units": UNITS,
        "models": ["shipped", "k6"],
    }
    index["generated_s"] = time.monotonic() - t0
    (out / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    return index


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--logs", type=int, default=200, help="logs in all, 4 of them damaged")
    ap.add_argument("--tables", type=int, default=20)
    ap.add_argument("--table-rows", type=int, default=24)
    ap.add_argument("--window-s", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bin", default=None, help="vibrocomp binary (default target/debug/vibrocomp or VIBROCOMP_BIN)")
    ap.add_argument("--processes", type=int, default=None)
    a = ap.parse_args(argv)
    if a.logs < 8:
        ap.error("--logs: at least 8 (4 are damaged)")
    index = generate(a.out, a.logs, a.tables, a.bin, a.processes, a.seed, a.table_rows, a.window_s)
    print(json.dumps({"logs": len(index["logs"]), "damaged": len(index["damaged"]), "tables": len(index["tables"]),
                      "seconds": round(index["generated_s"], 1), "manifest": str(Path(a.out) / "archive.toml")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
