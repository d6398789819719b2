#!/usr/bin/env python3
"""The waveform stage on the independent rig generator's runs: per reading, the
compensated output against what each unit sensed (``waveform_errors.py``).

Each run is 8 s vibrating throughout, 2 ug unit noise, 0.2 ug/s unit drift, 6.4 kHz
vibration sensors (AC coupling 2 Hz), 800 Hz readings, an orientation per run as
``loop_study.py``. Rig kinds (``--kind``):

- ``tones``: tones only (no random vibration), 30..120 Hz, rigid mount;
- ``mount``: tones 30..120 Hz and random vibration through a hidden 150 Hz, Q 2.5
  mount;
- ``tones150``: every tone at 150 Hz and random vibration, rigid mount;
- ``resonance``: every tone at 150 Hz through a hidden 150 Hz, Q 2.5 mount, random
  vibration 20..640 Hz;
- ``delay``: tones 30..120 Hz and random vibration, the sensors behind a stated
  1.56 ms acquisition delay (``delay_s`` under ``[sensors]`` of the rig file);
- ``nothing``: tones 30..120 Hz and random vibration, rigid mount, no delay.

Each run is generated, imported with its rig file (``vibrocomp log import --rig``),
replayed through ``vibrocomp up --record`` (``--model`` passed on when given) and
scored; the figures are printed per run and pooled (RMS over every run's window means),
and written to ``--out/study.json``. Not run by the test suite.

    python3 tests/python/waveform_study.py --kind delay --runs 4 --out /tmp/wf \
        [--bin target/debug/vibrocomp] [--model MODEL.toml]
"""

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)

import waveform_errors as we  # noqa: E402

ORIENTATIONS = ["+x", "-x", "+y", "-y", "+z", "-z", "oblique1", "oblique2"]
# Tone frequencies per body axis x, y, z (whole periods in 8 s), one set per run in turn.
TONE_SETS = ["30,60,120", "45,75,105", "40,90,120", "35,50,110"]
DELAY_S = 1.56e-3
SENSOR_HZ = 6400  # --sensor-hz; the delay kind is always at 6.4 kHz


def kind_args(kind, run_index):
    """The generator's options for a rig kind, and the rig's stated sensor delay (s) or None."""
    tones = ["--tone-hz", TONE_SETS[run_index % len(TONE_SETS)]]
    if kind == "tones":
        return tones + ["--random-psd", "0"], None
    if kind == "mount":
        return tones + ["--resonance-f0-hz", "150", "--resonance-q", "2.5"], None
    if kind == "tones150":
        return ["--tone-hz", "150"], None
    if kind == "resonance":
        return ["--tone-hz", "150", "--resonance-f0-hz", "150", "--resonance-q", "2.5"], None
    if kind == "delay":
        return tones + ["--daq-delay-s", repr(DELAY_S)], DELAY_S
    if kind == "nothing":
        return tones, None
    raise ValueError(f"unknown kind {kind!r}")


def generate(run, seed, orientation, kind, run_index):
    extra, delay = kind_args(kind, run_index)
    subprocess.run([sys.executable, os.path.join(HERE, "rig_generator.py"), "run", "--out", run,
                    "--seed", str(seed), "--vibrate-throughout", "--duration-s", "8",
                    f"--orientation={orientation}", "--sensor-rate-hz", str(SENSOR_HZ),
                    "--unit-noise-ug", "2", "--unit-drift-ug-per-s", "0.2",
                    # A fine grid of 51.2 kHz: the readings' own quadrature far below 1 ug.
                    "--oversample", str(max(1, 51200 // SENSOR_HZ)), *extra],
                   check=True, stdout=subprocess.DEVNULL)
    return delay


def import_log(binary, run, delay_s):
    up = json.load(open(os.path.join(run, "truth.json")))["orientation"]
    rig = os.path.join(run, "rig.toml")
    with open(rig, "w") as f:
        f.write('format = "vibrocomp-rig/1"\ntriad = "default"\n[sensors]\n'
                "sensitivity_v_per_g = 0.1\nac_corner_hz = 2.0\n"
                + (f"delay_s = {delay_s!r}\n" if delay_s else "")
                + '[reference]\nkind = "static"\n[[reference.segment]]\nfrom_s = 0.0\nto_s = 3600.0\n'
                f"up = [{up[0]!r}, {up[1]!r}, {up[2]!r}]\n")
    log = run + ".mcap"
    subprocess.run([binary, "log", "import", "--accel", os.path.join(run, "accel.csv"),
                    "--vib", os.path.join(run, "vib.csv"), "--rig", rig, "--out", log,
                    "--force", "--json"], check=True, stdout=subprocess.DEVNULL)
    return log


def session(binary, log, estimator, compensator, model, out, start_wait_s, rig=None):
    prefix = f"wf{os.getpid()}x{int(time.time() * 1000) % 100000}/"
    args = [binary, "up", "--json", "--prefix", prefix, "--record", out, "--force",
            "--estimator-config", estimator]
    if compensator:
        args += ["--compensator-config", compensator]
    if rig:
        # The sensors' chain (sensitivity, AC coupling, delay) from the rig file, into
        # both services: no hand-edited configuration.
        args += ["--rig", rig]
    if model:
        args += ["--model", model]
    stderr = open(out + ".up.log", "w")
    up = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        time.sleep(start_wait_s)  # the services' start
        if up.poll() is not None:
            raise RuntimeError(f"vibrocomp up exited with {up.returncode} (see {out}.up.log)")
        subprocess.run([binary, "replay", log, "--prefix", prefix, "--json"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    finally:
        if up.poll() is None:
            up.send_signal(signal.SIGINT)
            try:
                up.wait(timeout=60)
            except subprocess.TimeoutExpired:
                up.kill()
                up.wait()
        stderr.close()


def estimator_config(out):
    """The shipped estimator configuration at the rig's 6.4 kHz and 2 Hz AC coupling."""
    est = open(os.path.join(ROOT, "config", "services", "estimator.toml")).read()
    text = (est.replace("sample_rate_hz = 25600.0", f"sample_rate_hz = {SENSOR_HZ}.0")
            .replace("ac_corner_hz = 0.5 ", "ac_corner_hz = 2.0 ")
            .replace("broadband_band_hz = [20.0, 2000.0]", "broadband_band_hz = [20.0, 640.0]"))
    if f"sample_rate_hz = {SENSOR_HZ}.0" not in text or "ac_corner_hz = 2.0 " not in text:
        raise RuntimeError("config/services/estimator.toml changed: update estimator_config()")
    path = os.path.join(out, "estimator.toml")
    open(path, "w").write(text)
    return path


def compensator_config(out, delay_s, stage):
    """The shipped compensator configuration with the rig's sensor chain and `stage`."""
    text = open(os.path.join(ROOT, "config", "services", "compensator.toml")).read()
    new = (text.replace("ac_corner_hz = 0.5 ", "ac_corner_hz = 2.0 ")
           .replace("delay_s = 0.0 ", f"delay_s = {delay_s or 0.0!r} ")
           .replace('stage = "waveform" ', f'stage = "{stage}" '))
    if new.count("ac_corner_hz = 2.0 ") != 1 or f'stage = "{stage}" ' not in new:
        raise RuntimeError("config/services/compensator.toml changed: update compensator_config()")
    path = os.path.join(out, f"compensator-{stage}-{delay_s or 0}.toml")
    open(path, "w").write(new)
    return path


def pooled(results, category):
    """RMS over every run's window means: from each run's RMS and window count."""
    out = {}
    for key in ["all_units"] + [f"unit{u}" for u in (1, 2, 3)]:
        num = den = 0.0
        for r in results:
            fig = r[category]
            x = fig["all_units_rms_g"] if key == "all_units" else fig["units"][int(key[-1]) - 1]["rms_g"]
            n = fig["windows"] * (3 if key == "all_units" else 1)
            if x is not None and n:
                num += x * x * n
                den += n
        out[key + "_rms_g"] = math.sqrt(num / den) if den else None
    out["windows"] = sum(r[category]["windows"] for r in results)
    return out


def ug(x):
    return "  n/a " if x is None else f"{x * 1e6:6.2f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "debug", "vibrocomp"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--kind", choices=["tones", "tones150", "mount", "resonance", "delay", "nothing"],
                    default="nothing")
    ap.add_argument("--model", default=None, help="model file for `vibrocomp up --model` (optional)")
    ap.add_argument("--compensator-config", default=None,
                    help="default: the shipped one with the rig's sensors (2 Hz, its delay)")
    ap.add_argument("--stage", choices=["waveform", "estimate"], default="waveform")
    ap.add_argument("--window-s", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=500)
    ap.add_argument("--start-wait-s", type=float, default=6.0, help="wait for the services before replaying")
    ap.add_argument("--sensor-hz", type=int, default=6400, choices=[5000, 6400, 10000, 25600])
    a = ap.parse_args()
    global SENSOR_HZ
    SENSOR_HZ = 6400 if a.kind == "delay" else a.sensor_hz
    os.makedirs(a.out, exist_ok=True)
    est = estimator_config(a.out)
    results, failures = [], []
    for i in range(a.runs):
        orientation = ORIENTATIONS[i % len(ORIENTATIONS)]
        seed = a.seed + i
        run = os.path.join(a.out, f"{a.kind}{seed}")
        try:
            delay = generate(run, seed, orientation, a.kind, i)
            log = import_log(a.bin, run, delay)
            rec = os.path.join(a.out, f"s{seed}-{a.kind}.mcap")
            comp = a.compensator_config or (
                compensator_config(a.out, delay, a.stage) if a.stage != "waveform" else None)
            session(a.bin, log, est, comp, a.model, rec, a.start_wait_s,
                    rig=os.path.join(run, "rig.toml"))
            t_s, sensed, err = we.read_truth(run)
            r = we.measure(we.read_session(rec), t_s, sensed, err, a.window_s)
            r.update(run=run, session=rec, orientation=orientation, seed=seed)
        except Exception as e:  # keep going: one broken run must not lose the others
            failures.append({"run": run, "error": f"{type(e).__name__}: {e}"})
            print(f"run {i} ({run}): FAILED {type(e).__name__}: {e}", file=sys.stderr, flush=True)
            traceback.print_exc(limit=2)
            continue
        results.append(r)
        print(f"run {i} {orientation:8s} seed {seed}: all {ug(r['all']['all_units_rms_g'])} ug "
              f"({r['all']['windows']} windows), compensated {ug(r['compensated']['all_units_rms_g'])} ug "
              f"({r['compensated']['windows']}), waveform {ug(r['waveform']['all_units_rms_g'])} ug "
              f"({r['waveform']['windows']}), fallback {ug(r['fallback']['all_units_rms_g'])} ug "
              f"({r['fallback']['windows']}), uncompensated {ug(r['uncompensated']['all_units_rms_g'])} ug; "
              f"flags {r['blocks_per_flag']}", flush=True)
    categories = ("all", "compensated", "waveform", "fallback", "uncompensated")
    pool = {c: pooled(results, c) for c in categories} if results else {}
    study = {"kind": a.kind, "model": a.model, "window_s": a.window_s, "runs": results,
             "failures": failures, "pooled": pool}
    with open(os.path.join(a.out, "study.json"), "w") as f:
        json.dump(study, f, indent=1)
    for c, p in pool.items():
        print(f"pooled {c:13s}: {ug(p['all_units_rms_g'])} ug over {p['windows']} windows "
              f"(units {', '.join(ug(p[f'unit{u}_rms_g']) for u in (1, 2, 3))} ug)")
    print(f"{len(results)} runs, {len(failures)} failed; {os.path.join(a.out, 'study.json')}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
