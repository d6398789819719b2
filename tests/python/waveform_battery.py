#!/usr/bin/env python3
"""Time-domain battery for the model lab: rigs with one hidden effect (or a pair), made
by the independent rig generator (``rig_generator.py``), imported into MCAP logs with
their rig files, diagnosed by ``vibrocomp lab diagnose LOG... --json`` on the waveform
path, and scored.

    python3 tests/python/waveform_battery.py --out DIR [--size ci|full] [--members a,b]
        [--seed N] [--bin target/debug/vibrocomp] [--jobs N] [--generate-only] [--fit-delay]

Every member is a set of runs (``--size ci``: 2 runs x 4 s, 6.4 kHz sensors, fine grid
25.6 kHz; ``--size full``: 8 runs x 8 s, 25.6 kHz sensors, fine grid 51.2 kHz), each
vibrating throughout (flight-like: the filters in their periodic steady state) under a
static reference (the rig file's ``[reference]``) at an orientation of its own, in turn
``+z, oblique1, -x, oblique2, +y, -z, +x, -y`` (both obliques give every unit gravity on
IA, OA and PA at once). Common to every run: 800 Hz readings, 2 ug white reading noise,
no drift, vibration sensors at 0.1 V/g with a 2 Hz first-order AC coupling and 1 mg
noise, no acquisition delay (the rig file states ``delay_s = 0.0``; ``--fit-delay``
leaves it out so that the lab fits the chain's delay, scored against 0), tone phases
drawn from the seed (``U(0, 2 pi)`` per axis and run: phase differences between axes
that the same-frequency designs need), AL-15 passports on the default triad. Tones
are per body axis x, y, z (each unit's IA, OA, PA are body axes: AK1 IA x, AK2 IA y,
AK3 IA z), at whole numbers of periods over the run.

Members (hidden effect -> the lab's parameters, docs/effects.md names; the design and
why it shows the effect):

- ``nothing``: tones 30/60/120 Hz (the sets rotate per run), 1.5 g, random 0.002 g^2/Hz
  over 20..640 Hz. Expects verdict ``noise``.
- ``mount_resonance`` (freq_hz 150, q 2.5; the generator's ``base`` form is docs'
  ``T(s) = (wn^2 + 2 zeta wn s)/(s^2 + 2 zeta wn s + wn^2)``, ``zeta = 1/(2 q)``): even
  runs tones around the resonance (120/150/180, 135/165/100, ... Hz on x/y/z), odd
  runs one frequency on all axes (150, 130, 170, 140 Hz), 1.5 g, plus random
  20..640 Hz, 0.002 g^2/Hz: the units see |T| up to 2.7 times the sensors' amplitudes
  with the phase of T, the random part's spectrum reshaped, and (odd runs) the m31/m32
  cross terms with OA and PA through T too, which tells it from a unit response.
- ``unit_response`` (natural_freq_hz 1500, damping_ratio 0.35): even runs IA tones at
  1000..1400 Hz (|H| 1.3..1.9), odd runs one frequency on all axes (1200, 1350, 1100,
  1000 Hz), 2 g, random 20..2000 Hz, 0.001 g^2/Hz: the rectification (k2 a3^2 ...)
  sees |H| aB3, the OA/PA cross terms arg H (OA, PA untouched: not a mount). Note: the
  library's biquad is prewarped at the natural frequency; at 6.4 kHz (CI) the bilinear
  image of H is 11 % off |H|^2 at 1200 Hz (rig_generator selfcheck 5), the generator's
  H is the continuous one: a lab that evaluates the biquad at the sensor rate may fit
  a biased natural frequency at CI size.
- ``sensor_error`` (gain_error 0.05 on unit 1, AK2's sensor VD2): tones 30/60/120 Hz at
  2 g and random 0.002 g^2/Hz: unit 1's VE is predicted from a vibration 5 % too big
  (k2 term 10 %, about 35 ug); the other units' sensors are true.
- ``vibropendulous`` (c_rad_per_g 2e-4, tau_s 0.002): the same frequency on all three
  axes per run (60, 200, 40, 120, 300, 80, 160, 100 Hz) at 2 g, so PA and IA are
  coherent with a seed-drawn phase difference: mean ``c 0.5 aB3 aB2 Re(HP e^{j dphi})``
  up to ~200 ug, and ``|HP|, arg HP`` over several frequencies separate c from tau.
- ``anisoelastic`` (k_ae_per_g 3e-5): the same frequency on all axes (OA and PA
  coherent) at 2 g: ``k_ae 0.5 aB1 aB2 cos(dphi)`` up to 60 ug, plus ``k_ae aL1 aL2`` in
  the oblique orientations.
- ``high_order_nonlinearity`` (k6_ppm_per_g5 0.05, k7_ppm_per_g6 0.01, docs' example):
  big IA amplitudes, tones 4 g at 30/60/120 Hz and random 0.004 g^2/Hz (1.6 g RMS):
  ``k6 E[a3^6]`` about 100 ug, ``k7 E[a3^7]`` (odd: through aL3, signs flip with the
  orientation) about 100 ug.
- ``heating`` (c_g_per_g2 1e-5, tau_s 2): shaker runs (still half the run's length,
  vibrating its length, still half again): the IA power alternates per run (tones 3 g,
  then 4 g, random 0.002 g^2/Hz), the bias warms from 0 when the vibration starts over
  a time constant of half the CI run and cools after it: equilibrium 50..90 ug. Vibrating
  throughout, a 2 s lag over a 4 s run is nearly a drift, which each run's own offset
  and slope (the lab's nuisance) take.
- ``saturation`` (range_g 8): IA tones of 6.5 g at 30/60/120 Hz plus random 0.002 g^2/Hz
  (1.1 g RMS) on 1 g of gravity: the output reaches the range on the side gravity
  pushes (clipping by several hundred ug on average, signed by aL3).
- ``scale_factor_frequency`` (corner_hz 800, lambda_hf 1.3): IA tones 4 g at
  1200/1600/2000 Hz and random 20..2000 Hz, 0.001 g^2/Hz: its mean needs the passport's
  d1A (15 ppm): ``0.5 k1 d1A E[sign(a3)(L v3 - v3)]`` of a few ug. Possibly below what
  a CI-sized design can see (the member that may not be possible); per reading its
  linear part ``k1 (L - 1) a3`` is large (mg) but averages out of a window's VE.
- pairs: ``mount_resonance+vibropendulous`` (frequency per run all axes around the
  mount, 150/60/120/200/180/40/100/250 Hz, 1.5 g, random), ``unit_response+
  high_order_nonlinearity`` (runs alternate 30/60/120 Hz at 4 g, where k6/k7 dominate,
  and 1000/1250/1400 Hz at 3 g, where the response does), ``mount_resonance+
  sensor_error`` (the mount design, gain_error 0.04 on unit 2), ``anisoelastic+heating``
  (the same frequency on all axes, amplitudes alternating 1 g / 3 g); the mount pair
  uses the mount design.

Scoring (``score``, a pure function of the member's truth and the diagnosis JSON): a
member passes when ``path`` is ``"waveform"``, the verdict is ``"effect"``, ``found``
is exactly the hidden kinds (as a set: nothing spurious), and every hidden parameter
(and any reported parameter of a found kind whose truth is known, e.g. k7 = 0, a
misalignment = 0, the chain's ``delay_s`` = 0) is within 3 sigma of its truth,
``pull = (value - truth) / sigma``; ``nothing`` passes on verdict ``"noise"``. A table
goes to stdout and everything to ``--out/battery.json``.

Preview (before the waveform diagnosis existed; ``--require-path any`` on today's
statistics path, which the battery maps onto its interface, ``normalize``): CI size,
seed 4400: 2 of 14 pass (``nothing``; ``vibropendulous`` with pulls +0.6, -2.0); the
statistics path has 12 rows a member at CI size and calls most members ``noise`` and
the mount/unit-response ones ``confounded``. At full size one member's statistics
diagnosis ran into its 600 s budget (``high_order_nonlinearity``: ``unexplained``).
Not a verdict on the waveform path.

Generation time per member: printed and stored in battery.json (``generate_s_per_run``,
``import_s_per_run``, ``member_wall_s``). Measured on the 2-CPU development machine,
one job: CI size 1.0 s a run (generator; import 0.05 s), 2.1 s a member; full size
2.4 s a run (import 0.15 s), 20 s a member (8 runs). All 14 members at CI size: 29 s.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))

ORIENTATIONS = ["+z", "oblique1", "-x", "oblique2", "+y", "-z", "+x", "-y"]

SIZES = {
    # runs, seconds per run, sensor rate (Hz), oversample (fine grid = sensor rate x this)
    "ci": {"runs": 2, "duration_s": 4.0, "sensor_hz": 6400, "oversample": 4},
    "full": {"runs": 8, "duration_s": 8.0, "sensor_hz": 25600, "oversample": 2},
}

# The lab's parameter names per kind (docs/effects.md), with the value a parameter has
# when the member leaves it out (None: no default; such a parameter is always hidden).
LAB_PARAMS = {
    "mount_resonance": {"freq_hz": None, "q": None},
    "unit_response": {"natural_freq_hz": None, "damping_ratio": None},
    "sensor_error": {"gain_error": 0.0, "misalignment_oa_rad": 0.0, "misalignment_pa_rad": 0.0},
    "vibropendulous": {"c_rad_per_g": None, "tau_s": None},
    "anisoelastic": {"k_ae_per_g": None},
    "high_order_nonlinearity": {"k6_ppm_per_g5": 0.0, "k7_ppm_per_g6": 0.0},
    "heating": {"c_g_per_g2": None, "tau_s": None},
    "saturation": {"range_g": None},
    "scale_factor_frequency": {"corner_hz": None, "lambda_hf": None},
}

# ---------------------------------------------------------------------------------------
# Designs: the generator's vibration options for run i


def tones(sets, amp_g):
    """Tones per axis x, y, z from ``sets`` (one "fx,fy,fz" per run, in turn), ``amp_g``
    (one number, or one per run in turn)."""
    def make(i):
        a = amp_g[i % len(amp_g)] if isinstance(amp_g, (list, tuple)) else amp_g
        return ["--tone-hz", sets[i % len(sets)], "--tone-amp-g", repr(float(a))]
    return make


def random(psd, band=(20.0, 640.0)):
    return ["--random-psd", repr(psd), "--random-band-hz", f"{band[0]!r},{band[1]!r}"]


def same_freq(freqs, amp_g):
    """The same frequency on all three axes per run (coherent axes, phases from the seed)."""
    return tones([f"{f},{f},{f}" for f in freqs], amp_g)


LOW = ["30,60,120", "45,75,105", "40,90,120", "35,50,110"]
MOUNT = ["120,150,180", "135,165,100", "150,110,170", "160,140,125"]
HIGH_IA = ["1000,1250,1400", "1300,1100,1200", "1400,1000,1150", "1200,1350,1050"]
SFF = ["1200,1600,2000", "2000,1200,1600", "1600,2000,1200", "1400,1800,1000"]


def member_table():
    """Each member: hidden effects (kind, lab params, unit or None) and its design."""
    mount = ("mount_resonance", {"freq_hz": 150.0, "q": 2.5}, None)
    ur = ("unit_response", {"natural_freq_hz": 1500.0, "damping_ratio": 0.35}, None)
    vp = ("vibropendulous", {"c_rad_per_g": 2e-4, "tau_s": 0.002}, None)
    ae = ("anisoelastic", {"k_ae_per_g": 3e-5}, None)
    hon = ("high_order_nonlinearity", {"k6_ppm_per_g5": 0.05, "k7_ppm_per_g6": 0.01}, None)
    heat = ("heating", {"c_g_per_g2": 1e-5, "tau_s": 2.0}, None)

    def design(tone_fn, rnd):
        return lambda i: tone_fn(i) + rnd

    low = design(tones(LOW, 1.5), random(0.002))

    def alternate(even, odd):
        return lambda i: even(i) if i % 2 == 0 else odd(i // 2)

    # mount: tones around the resonance, one frequency per axis, then all axes at one
    # frequency (OA/PA coherent with IA: the m31, m32 cross terms see the mount on OA and
    # PA too, which a unit response on IA alone cannot mimic)
    mount_design = alternate(design(tones(MOUNT, 1.5), random(0.002)),
                             design(same_freq([150, 130, 170, 140], 1.5), random(0.002)))
    return {
        "nothing": {"effects": [], "design": low},
        "mount_resonance": {"effects": [mount], "design": mount_design},
        "unit_response": {"effects": [ur], "design": alternate(
            design(tones(HIGH_IA, 2.0), random(0.001, (20.0, 2000.0))),
            design(same_freq([1200, 1350, 1100, 1000], 2.0), random(0.001, (20.0, 2000.0))))},
        "sensor_error": {"effects": [("sensor_error", {"gain_error": 0.05}, 1)],
                         "design": design(tones(LOW, 2.0), random(0.002))},
        "vibropendulous": {"effects": [vp],
                           "design": design(same_freq([60, 200, 40, 120, 300, 80, 160, 100], 2.0), random(0.002))},
        "anisoelastic": {"effects": [ae],
                         "design": design(same_freq([60, 200, 40, 120, 300, 80, 160, 100], 2.0), random(0.002))},
        "high_order_nonlinearity": {"effects": [hon], "design": design(tones(LOW, 3.0), random(0.002))},
        # heating: shaker runs (still, vibrating, still): the bias rises with the
        # vibration and falls after it, which a run's own offset and drift (the lab's
        # nuisance) cannot take; vibrating throughout, a 2 s lag is nearly a drift.
        "heating": {"effects": [heat], "design": design(tones(LOW, [3.0, 4.0]), random(0.002)),
                    "shaker": True},
        "saturation": {"effects": [("saturation", {"range_g": 8.0}, None)],
                       "design": design(tones(LOW, 4.5), random(0.002))},
        "scale_factor_frequency": {"effects": [("scale_factor_frequency", {"corner_hz": 800.0, "lambda_hf": 1.3},
                                                None)],
                                   "design": design(tones(SFF, 4.0), random(0.001, (20.0, 2000.0)))},
        "mount_resonance+vibropendulous": {
            "effects": [mount, vp],
            "design": design(same_freq([150, 60, 120, 200, 180, 40, 100, 250], 1.0), random(0.002))},
        "unit_response+high_order_nonlinearity": {
            "effects": [ur, hon],
            "design": lambda i: (tones(LOW, 3.0)(i) + random(0.002) if i % 2 == 0
                                 else tones(HIGH_IA, 2.0)(i) + random(0.001, (20.0, 2000.0)))},
        "mount_resonance+sensor_error": {
            "effects": [mount, ("sensor_error", {"gain_error": 0.04}, 2)],
            "design": mount_design},
        "anisoelastic+heating": {
            "effects": [ae, heat],
            "design": design(same_freq([60, 200, 40, 120, 300, 80, 160, 100], [3.0, 4.0]), random(0.002)),
            "shaker": True},
    }


MEMBERS = member_table()
SINGLES = [m for m in MEMBERS if "+" not in m and m != "nothing"]


def generator_args(effects):
    """The rig generator's options that hide ``effects`` (lab names -> generator options)."""
    out = []
    gains = [0.0, 0.0, 0.0]
    for kind, p, unit in effects:
        if kind == "mount_resonance":
            out += ["--resonance-f0-hz", repr(p["freq_hz"]), "--resonance-q", repr(p["q"]),
                    "--resonance-form", "base"]
        elif kind == "unit_response":
            out += ["--unit-response-hz", repr(p["natural_freq_hz"]),
                    "--unit-response-damping", repr(p["damping_ratio"])]
        elif kind == "sensor_error":
            gains[unit] = p["gain_error"]
        else:
            spec = ",".join(f"{k}={v!r}" for k, v in p.items())
            if unit is not None:
                spec += f",units={unit}"
            out += ["--effect", f"{kind}:{spec}"]
    if any(gains):
        out += ["--sensor-gain-error", ",".join(repr(g) for g in gains)]
    return out


def member_truth(name):
    """The member's truth for scoring: hidden kinds, and per kind its parameters (the
    hidden values, plus the defaults of the parameters it leaves out) and unit."""
    m = MEMBERS[name]
    kinds = {}
    for kind, p, unit in m["effects"]:
        params = {k: v for k, v in LAB_PARAMS[kind].items() if v is not None}
        params.update(p)
        kinds[kind] = {"params": params, "hidden": sorted(p), "unit": unit}
    return {"member": name, "expect_verdict": "noise" if not kinds else "effect", "kinds": kinds}


# ---------------------------------------------------------------------------------------
# Generation and import


def generate_run(run, seed, run_index, name, size, fit_delay):
    """One run of a member: the generator, then ``rig.toml``. Returns seconds taken."""
    sz = SIZES[size]
    m = MEMBERS[name]
    t0 = time.perf_counter()
    if m.get("shaker"):
        # Still half the run's length, vibrating its length, still half its length.
        timing = ["--still-s", repr(sz["duration_s"] / 2), "--vib-s", repr(sz["duration_s"])]
    else:
        timing = ["--vibrate-throughout", "--duration-s", repr(sz["duration_s"])]
    args = [sys.executable, os.path.join(HERE, "rig_generator.py"), "run", "--out", run,
            "--seed", str(seed), *timing,
            f"--orientation={ORIENTATIONS[run_index % len(ORIENTATIONS)]}",
            "--sensor-rate-hz", str(sz["sensor_hz"]), "--oversample", str(sz["oversample"]),
            "--unit-noise-ug", "2", *m["design"](run_index), *generator_args(m["effects"])]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    write_rig(run, fit_delay)
    return time.perf_counter() - t0


def write_rig(run, fit_delay):
    """The rig file (as waveform_study.py's): the sensors' chain and a static reference."""
    up = json.load(open(os.path.join(run, "truth.json")))["orientation"]
    rig = os.path.join(run, "rig.toml")
    with open(rig, "w") as f:
        f.write('format = "vibrocomp-rig/1"\ntriad = "default"\n[sensors]\n'
                "sensitivity_v_per_g = 0.1\nac_corner_hz = 2.0\n"
                + ("" if fit_delay else "delay_s = 0.0\n")
                + '[reference]\nkind = "static"\n[[reference.segment]]\nfrom_s = 0.0\nto_s = 3600.0\n'
                f"up = [{up[0]!r}, {up[1]!r}, {up[2]!r}]\n")
    return rig


def import_log(binary, run):
    log = run + ".mcap"
    subprocess.run([binary, "log", "import", "--accel", os.path.join(run, "accel.csv"),
                    "--vib", os.path.join(run, "vib.csv"), "--rig", os.path.join(run, "rig.toml"),
                    "--out", log, "--force", "--json"], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.PIPE)
    return log


def make_member(binary, out, name, size, seed, jobs, fit_delay, do_import=True):
    """Generate (in parallel, ``jobs``) and import a member's runs: logs and timings."""
    sz = SIZES[size]
    folder = os.path.join(out, name)
    os.makedirs(folder, exist_ok=True)
    t0 = time.perf_counter()

    def one(i):
        run = os.path.join(folder, f"run{i:02d}")
        g = generate_run(run, seed * 100 + i, i, name, size, fit_delay)
        t1 = time.perf_counter()
        log = import_log(binary, run) if do_import else None
        return run, log, g, time.perf_counter() - t1

    with ThreadPoolExecutor(max_workers=max(1, jobs)) as ex:
        runs = list(ex.map(one, range(sz["runs"])))
    return {
        "runs": [r[0] for r in runs],
        "logs": [r[1] for r in runs],
        "generate_s_per_run": [r[2] for r in runs],
        "import_s_per_run": [r[3] for r in runs],
        "member_wall_s": time.perf_counter() - t0,
    }


def diagnose(binary, logs, extra=(), timeout_s=None):
    t0 = time.perf_counter()
    p = subprocess.run([binary, "lab", "diagnose", *logs, "--json", *extra], capture_output=True, text=True,
                       timeout=timeout_s)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"lab diagnose exited {p.returncode}: {p.stderr.strip()[-2000:]}")
    result = json.loads(p.stdout)
    result.setdefault("elapsed_s", wall)
    return result, wall


# ---------------------------------------------------------------------------------------
# Scoring (pure)

PULL_LIMIT = 3.0


def normalize(result):
    """The diagnosis in the battery's interface (``path``, ``verdict``, ``found``, ``params``
    with ``kind``, ``chi2_per_dof``, ``elapsed_s``). The waveform diagnosis prints it so;
    the statistics path's JSON of today (``verdict`` an object with ``kinds`` and
    ``params`` keyed ``effect``; the paths counted in ``comparison.paths``) is mapped onto it."""
    out = dict(result)
    v = result.get("verdict")
    if isinstance(v, dict):
        out["verdict"] = v.get("verdict")
        out.setdefault("found", v.get("kinds") or ([v["kind"]] if v.get("kind") else []))
        out.setdefault("params", v.get("params") or [])
        out.setdefault("chi2_per_dof", v.get("chi2_per_dof_after", v.get("chi2_per_dof")))
    if "path" not in out:
        paths = (result.get("comparison") or {}).get("paths") or {}
        used = sorted(k for k, n in paths.items() if n)
        out["path"] = used[0] if len(used) == 1 else ("mixed" if used else None)
    out["params"] = [dict(p, kind=p.get("kind", p.get("effect"))) for p in out.get("params") or []]
    out.setdefault("found", [])
    return out


def _match(params, kind, name, unit):
    """The reported parameter ``kind.name`` (for ``unit`` when the JSON carries units)."""
    hits = [p for p in params if p.get("kind") == kind and p.get("name") == name]
    if unit is not None and any("unit" in p for p in hits):
        hits = [p for p in hits if p.get("unit") == unit]
    return hits[0] if hits else None


def _pull(value, sigma, truth):
    if value is None or sigma is None:
        return None
    try:
        value, sigma = float(value), float(sigma)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(value) and math.isfinite(sigma)) or sigma <= 0:
        return None
    return (value - truth) / sigma


def score(truth, result, delay_truth_s=0.0, require_path="waveform"):
    """Score one member's diagnosis (a dict from ``lab diagnose --json``) against its
    ``truth`` (``member_truth``). Returns ``{"pass": bool, "reasons": [...], "params": [...]}``.

    Pass: ``path`` is ``"waveform"``; for ``nothing`` the verdict is ``"noise"``; else the
    verdict is ``"effect"``, ``found`` is exactly the hidden kinds, every hidden parameter
    is reported with ``|pull| <= 3``, and so is every reported parameter of a hidden kind
    whose truth is known (a default left out) and the chain's ``delay_s``.
    """
    reasons = []
    rows = []
    result = normalize(result)
    if require_path != "any" and result.get("path") != require_path:
        reasons.append(f"path {result.get('path')!r}, not 'waveform'")
    verdict = result.get("verdict")
    found = result.get("found") or []
    hidden = set(truth["kinds"])
    if verdict != truth["expect_verdict"]:
        reasons.append(f"verdict {verdict!r}, expected {truth['expect_verdict']!r}")
    if set(found) != hidden:
        missing, spurious = sorted(hidden - set(found)), sorted(set(found) - hidden)
        if missing:
            reasons.append(f"missed {', '.join(missing)}")
        if spurious:
            reasons.append(f"spurious {', '.join(spurious)}")
    params = result.get("params") or []
    for kind, k in truth["kinds"].items():
        for name, t in k["params"].items():
            p = _match(params, kind, name, k["unit"])
            required = name in k["hidden"]
            if p is None:
                if required:
                    reasons.append(f"{kind}.{name} not reported")
                    rows.append({"kind": kind, "name": name, "truth": t, "value": None, "sigma": None,
                                 "pull": None, "ok": False})
                continue
            pull = _pull(p.get("value"), p.get("sigma"), t)
            ok = pull is not None and abs(pull) <= PULL_LIMIT
            if not ok:
                reasons.append(f"{kind}.{name} = {p.get('value')} +- {p.get('sigma')} vs {t}"
                               + (f": pull {pull:+.2f}" if pull is not None else ": no usable sigma"))
            rows.append({"kind": kind, "name": name, "truth": t, "value": p.get("value"), "sigma": p.get("sigma"),
                         "pull": pull, "ok": ok, **({"unit": p["unit"]} if "unit" in p else {})})
    for p in params:
        if p.get("kind") == "sensor_chain" and p.get("name") == "delay_s":  # (the rig states no delay)
            pull = _pull(p.get("value"), p.get("sigma"), delay_truth_s)
            ok = pull is not None and abs(pull) <= PULL_LIMIT
            if not ok:
                reasons.append(f"sensor_chain.delay_s = {p.get('value')} +- {p.get('sigma')} vs {delay_truth_s}")
            rows.append({"kind": "sensor_chain", "name": "delay_s", "truth": delay_truth_s, "value": p.get("value"),
                         "sigma": p.get("sigma"), "pull": pull, "ok": ok})
    return {"pass": not reasons, "reasons": reasons, "params": rows, "verdict": verdict, "found": list(found),
            "chi2_per_dof": result.get("chi2_per_dof"), "elapsed_s": result.get("elapsed_s")}


def format_row(name, s):
    """One member's line(s) of the table."""
    def num(x, fmt):
        return format(x, fmt) if isinstance(x, (int, float)) and not isinstance(x, bool) else str(x)

    head = (f"{name:40s} {'PASS' if s['pass'] else 'FAIL'}  {str(s['verdict']):11s} "
            f"{','.join(map(str, s['found'])) or '-':40s} "
            f"chi2/dof {num(s['chi2_per_dof'], '.3g'):>7}  {num(s['elapsed_s'], '.1f')} s")
    lines = [head]
    for r in s["params"]:
        val = "n/a" if r["value"] is None else f"{num(r['value'], '.6g')} +- {num(r['sigma'], '.2g')}"
        pull = "n/a" if r["pull"] is None else f"{r['pull']:+.2f}"
        lines.append(f"    {r['kind'] + '.' + r['name']:45s} {val:28s} truth {r['truth']:<10.6g} pull {pull}"
                     + ("" if r["ok"] else "  <-"))
    for why in s["reasons"]:
        lines.append(f"    ! {why}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------
# CLI


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--size", choices=sorted(SIZES), default="ci")
    ap.add_argument("--members", default="all", help="comma-separated, 'all' or 'singles' (" + ", ".join(MEMBERS) + ")")
    ap.add_argument("--seed", type=int, default=4400)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "debug", "vibrocomp"))
    ap.add_argument("--jobs", type=int, default=max(1, min(8, (os.cpu_count() or 2) // 2)),
                    help="runs generated and imported in parallel")
    ap.add_argument("--fit-delay", action="store_true",
                    help="leave delay_s out of the rig files: the lab fits the chain's delay (truth 0)")
    ap.add_argument("--generate-only", action="store_true", help="generate and import, no diagnosis")
    ap.add_argument("--no-import", action="store_true", help="with --generate-only: the generator only")
    ap.add_argument("--diagnose-arg", action="append", default=[], help="passed on to lab diagnose")
    ap.add_argument("--diagnose-timeout-s", type=float, default=1800.0,
                    help="a member's diagnosis is an error after this long")
    ap.add_argument("--require-path", choices=["waveform", "statistics", "any"], default="waveform",
                    help="the diagnosis path a pass needs (any: a preview on the statistics path)")
    a = ap.parse_args(argv)
    if a.members == "all":
        names = list(MEMBERS)
    elif a.members == "singles":
        names = ["nothing"] + SINGLES
    else:
        names = [s.strip() for s in a.members.split(",") if s.strip()]
    unknown = [n for n in names if n not in MEMBERS]
    if unknown:
        ap.error(f"unknown members {unknown}; known: {', '.join(MEMBERS)}")
    if not a.no_import and not os.path.exists(a.bin):
        ap.error(f"{a.bin} not found: cargo build -p vibrocomp")
    os.makedirs(a.out, exist_ok=True)
    report = {"size": a.size, "design": SIZES[a.size], "seed": a.seed, "fit_delay": a.fit_delay, "members": []}
    passed = 0
    for k, name in enumerate(names):
        truth = member_truth(name)
        entry = {"member": name, "truth": truth, "generator_args": generator_args(MEMBERS[name]["effects"])}
        try:
            made = make_member(a.bin, a.out, name, a.size, a.seed + k, a.jobs, a.fit_delay,
                               do_import=not a.no_import)
            entry.update(made)
            gen = sum(made["generate_s_per_run"])
            print(f"{name}: {len(made['runs'])} runs generated in {gen:.1f} s "
                  f"({gen / len(made['runs']):.2f} s a run), imported in {sum(made['import_s_per_run']):.1f} s, "
                  f"member wall {made['member_wall_s']:.1f} s", flush=True)
            if not a.generate_only:
                result, wall = diagnose(a.bin, made["logs"], a.diagnose_arg, a.diagnose_timeout_s)
                s = score(truth, result, require_path=a.require_path)
                entry.update(diagnosis=result, diagnose_wall_s=wall, score=s)
                passed += s["pass"]
                print(format_row(name, s), flush=True)
        except Exception as e:  # keep going: one broken member must not lose the others
            err = getattr(e, "stderr", None)
            entry["error"] = f"{type(e).__name__}: {e}" + (f"\n{err.decode() if isinstance(err, bytes) else err}"
                                                            if err else "")
            print(f"{name}: ERROR {entry['error']}", file=sys.stderr, flush=True)
        report["members"].append(entry)
        with open(os.path.join(a.out, "battery.json"), "w") as f:  # after every member
            json.dump(report, f, indent=1, default=str)
    if not a.generate_only:
        print(f"{passed} of {len(names)} members pass; {os.path.join(a.out, 'battery.json')}")
        return 0 if passed == len(names) else 1
    return 1 if any("error" in e for e in report["members"]) else 0


if __name__ == "__main__":
    sys.exit(main())
