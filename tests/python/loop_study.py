#!/usr/bin/env python3
"""The rig loop over many unit-runs: the independent rig generator's runs (orientations x
tone frequencies, 20..640 Hz random vibration, 10 s vibrating throughout) with and
without a hidden 150 Hz, Q 2.5 mount, each imported with a rig file, replayed through
``vibrocomp up`` (the rig's estimator configuration: 6.4 kHz, AC coupling at 2 Hz) and
measured by ``vibrocomp log errors --window-s 2``:

- ``floor``: the rig without the mount, base model;
- ``base``: with the mount, base model;
- ``m640`` / ``m2000``: with the mount, the mount as an extended model (its true
  parameters), the estimator's broadband band 20..640 / 20..2000 Hz.

Prints each run's per-unit vibration-removed RMS (ug) and the pooled RMS per tone and
overall; writes ``study.json`` in ``--out``. Used for docs/logs.md's figures; not run by
the test suite (about 50 s per run with the test profile's binary).

    python3 tests/python/loop_study.py --bin target/debug/vibrocomp --out /tmp/loop \
        --tones 60,120,150
"""

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
ORIENTATIONS = ["+x", "-x", "+y", "-y", "+z", "-z", "oblique1", "oblique2"]


def generate(out, seed, orientation, tone_hz, mount):
    args = [sys.executable, os.path.join(HERE, "rig_generator.py"), "run", "--out", out,
            "--seed", str(seed), "--vibrate-throughout", "--duration-s", "10",
            f"--orientation={orientation}", "--tone-hz", str(tone_hz),
            "--sensor-rate-hz", "6400"]
    if mount:
        args += ["--resonance-f0-hz", "150", "--resonance-q", "2.5"]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL)


def import_log(binary, run):
    up = json.load(open(os.path.join(run, "truth.json")))["orientation"]
    rig = os.path.join(run, "rig.toml")
    with open(rig, "w") as f:
        f.write('format = "vibrocomp-rig/1"\ntriad = "default"\n[sensors]\n'
                "sensitivity_v_per_g = 0.1\nac_corner_hz = 2.0\n[reference]\n"
                'kind = "static"\n[[reference.segment]]\nfrom_s = 0.0\nto_s = 3600.0\n'
                f"up = [{up[0]!r}, {up[1]!r}, {up[2]!r}]\n")
    log = run + ".mcap"
    subprocess.run([binary, "log", "import", "--accel", os.path.join(run, "accel.csv"),
                    "--vib", os.path.join(run, "vib.csv"), "--rig", rig, "--out", log,
                    "--force", "--json"], check=True, stdout=subprocess.DEVNULL)
    return log


def session(binary, log, estimator, compensator, out):
    prefix = f"ls{os.getpid()}x{int(time.time() * 1000) % 100000}/"
    up = subprocess.Popen([binary, "up", "--json", "--prefix", prefix, "--record", out,
                           "--force", "--estimator-config", estimator,
                           "--compensator-config", compensator],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(6)  # the services' start
        subprocess.run([binary, "replay", log, "--prefix", prefix, "--json"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(timeout=60)
    v = json.loads(subprocess.run([binary, "log", "errors", out, "--window-s", "2", "--json"],
                                  check=True, capture_output=True, text=True).stdout)
    return [u["vibration_removed_rms_g"] * 1e6 for u in v["errors"]["units"]]


def configs(out):
    shipped = os.path.join(ROOT, "config", "services")
    est = open(os.path.join(shipped, "estimator.toml")).read()
    paths = {}
    for band in ("640", "2000"):
        text = (est.replace("sample_rate_hz = 25600.0", "sample_rate_hz = 6400.0")
                .replace("ac_corner_hz = 0.5 ", "ac_corner_hz = 2.0 ")
                .replace("broadband_band_hz = [20.0, 2000.0]", f"broadband_band_hz = [20.0, {band}.0]"))
        assert "sample_rate_hz = 6400.0" in text and "ac_corner_hz = 2.0 " in text
        paths[band] = os.path.join(out, f"estimator-{band}.toml")
        open(paths[band], "w").write(text)
    model = os.path.join(out, "mount.toml")
    open(model, "w").write('mode = "exact"\n[[effect]]\nkind = "mount_resonance"\n'
                           "freq_hz = 150.0\nq = 2.5\n")
    comp = open(os.path.join(shipped, "compensator.toml")).read()
    paths["base"] = os.path.join(out, "base.toml")
    open(paths["base"], "w").write(comp)
    paths["with"] = os.path.join(out, "with-model.toml")
    open(paths["with"], "w").write(comp.replace('triad = "default"',
                                                f'model = {json.dumps(model)}\ntriad = "default"'))
    return paths


def pooled(rows, key):
    xs = [x for r in rows for x in r[key]]
    return math.sqrt(sum(x * x for x in xs) / len(xs))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "debug", "vibrocomp"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--tones", default="60,120,150")
    ap.add_argument("--orientations", default=",".join(ORIENTATIONS))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    cfg = configs(a.out)
    results = {}
    for i, o in enumerate(a.orientations.split(",")):
        for j, t in enumerate(a.tones.split(",")):
            seed = 200 + 10 * i + j
            runs = {}
            for mount in (False, True):
                run = os.path.join(a.out, f"{'m' if mount else 'n'}{seed}")
                generate(run, seed, o, t, mount)
                runs[mount] = import_log(a.bin, run)
            r = {}
            for key, (mount, comp, band) in {"floor": (False, "base", "640"),
                                             "base": (True, "base", "640"),
                                             "m640": (True, "with", "640"),
                                             "m2000": (True, "with", "2000")}.items():
                out = os.path.join(a.out, f"s{seed}-{key}.mcap")
                r[key] = session(a.bin, runs[mount], cfg[band], cfg[comp], out)
            results[f"{o}/{t}"] = r
            print(o, t, {k: [round(x, 1) for x in v] for k, v in r.items()}, flush=True)
    json.dump(results, open(os.path.join(a.out, "study.json"), "w"), indent=1)
    for t in a.tones.split(",") + [None]:
        rows = [v for k, v in results.items() if t is None or k.endswith("/" + t)]
        p = {k: pooled(rows, k) for k in ("floor", "base", "m640", "m2000")}
        worse = [m / b for v in rows for m, b in zip(v["m640"], v["base"])]
        print(f"tone {t or 'all'}: " + ", ".join(f"{k} {x:.1f} ug" for k, x in p.items())
              + f"; model / floor {p['m640'] / p['floor']:.2f}; worse than the base model on "
              f"{sum(w > 1 for w in worse)} of {len(worse)} unit-runs (at most x{max(worse):.2f})")


if __name__ == "__main__":
    main()
