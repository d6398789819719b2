#!/usr/bin/env python3
"""How much of a unit's vibration error changes from one window to the next, from the
independent rig generator's own fine-grained truth (not through vibrocomp).

A compensator that works from vibration estimates (a tone's amplitude and phase, a
band's mean power, each over the estimator's window) removes the error the estimate
predicts; what the vibration did inside the current window beyond that stays. Over
2 s windows this study splits each unit's rectified error (the conversion function
minus its linear part, evaluated on the fine time grid and averaged, as the generator's
readings are) into:

- ``tone``: the tone alone (deterministic: no scatter);
- ``random``: the random vibration alone;
- ``cross``: what the two give together beyond their sum.

For each part it prints the RMS of the window's mean about the run's mean, and about a
lagged estimate (windows of 1 s every 0.25 s, the last one ending 0.25 s before each
sample: what an estimate-based compensator has at hand), with and without the
generator's 150 Hz, Q 2.5 mount. Used for docs/logs.md; not run by the test suite.

    python3 tests/python/fluctuation_study.py --seeds 101,102,103 --tones 60,150
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rig_generator as rg  # noqa: E402

WINDOW_S = 2.0


def lagged_mean(x, s, e, fs, lat_s, win_s=1.0, hop_s=0.25):
    ests = []
    for t in range(s, e, int(fs * 0.05)):
        end = np.floor((t / fs - lat_s) / hop_s) * hop_s
        ie = int(end * fs)
        ests.append(x[max(ie - int(win_s * fs), 0) : ie].mean())
    return float(np.mean(ests))


def run_parts(seed, orientation, tone_hz, mount, lat_s):
    args = ["run", "--out", "unused", "--seed", str(seed), "--vibrate-throughout",
            "--duration-s", "10", "--sensor-rate-hz", "6400"]
    if mount:
        args += ["--resonance-f0-hz", "150", "--resonance-q", "2.5"]
    cfg, triad = rg.config_from_args(rg.build_parser().parse_args(args))
    cfg.orientation = tuple(rg.orientation_vector(orientation))
    cfg.orientation_name = orientation
    cfg.tone_hz = (tone_hz,) * 3
    res = rg.simulate(cfg, triad, keep_fine=True)
    fs = cfg.fine_rate_hz
    g = cfg.gravity_g * np.asarray(cfg.orientation)[:, None]
    tone_u, rand_u = res.fine["tone_unit"], res.fine["rand_unit"]
    rows = []
    for u in triad:
        p = u.passport

        def rectified(a):
            a3, a1, a2 = u.e_ia @ a, u.e_oa @ a, u.e_pa @ a
            return p.af(a3, a1, a2) - p.a0_g - (p.k1 * p.lam * a3 + p.m1 * a1 + p.m2 * a2)

        total = rectified(g + tone_u + rand_u)
        tone = rectified(g + tone_u)
        rand = rectified(g + rand_u)
        parts = (tone, rand, total - tone - rand)
        w = int(WINDOW_S * fs)
        for k in range(1, total.size // w):  # the first window: no estimate yet
            s, e = k * w, (k + 1) * w
            rows.append([(x[s:e].mean() - x.mean(), x[s:e].mean() - lagged_mean(x, s, e, fs, lat_s))
                         for x in parts])
    return np.array(rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="101,102,103")
    ap.add_argument("--orientations", default="+x,-x,+y,+z")
    ap.add_argument("--tones", default="60,150")
    ap.add_argument("--latency-s", type=float, default=0.25,
                    help="the estimate a sample uses ends this long before it")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    orients = a.orientations.split(",")
    print("RMS over 2 s windows and units, ug: about the run's mean | about a lagged estimate")
    for tone_hz in (float(t) for t in a.tones.split(",")):
        for mount in (False, True):
            d = np.concatenate([run_parts(s, o, tone_hz, mount, a.latency_s) for s in seeds for o in orients])
            rms = np.sqrt((d ** 2).mean(axis=0)) * 1e6
            label = "150 Hz mount" if mount else "no mount    "
            print(f"tone {tone_hz:5.0f} Hz, {label}: "
                  + "  ".join(f"{n} {rms[i, 0]:6.1f} | {rms[i, 1]:6.1f}"
                              for i, n in enumerate(("tone", "random", "cross"))), flush=True)


if __name__ == "__main__":
    main()
