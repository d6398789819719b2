#!/usr/bin/env python3
"""Each compensated reading against what the unit sensed: a recorded vibrocomp session
scored with the independent rig generator's per-reading truth (``readings_truth.csv``).

A perfect compensator outputs, per reading, the interval mean of the acceleration the
unit sensed along its IA (``sensed{u}_g``; MODEL.md section 12). The compensator's
error is ``a4_g - sensed_g``. Per window of ``--window-s`` (default 2 s) its mean is
taken; the figure is the RMS of the window means, per unit and over the three units
together (all (window, unit) means pooled), for

- ``all``: every window whose readings are all covered by /compensated;
- ``waveform``: the windows whose blocks all carry WAVEFORM (bit 11, 2048: the
  waveform stage answered);
- ``fallback``: the windows with any block carrying WAVEFORM_FALLBACK (bit 12, 4096:
  the estimate stage answered because vibration samples were missing);
- ``compensated``: the windows with no MAIN_ONLY block (4; as ``stage_errors.py``
  counts them): the start of a session, before the first estimate, is main-only.

Windows with a reading /compensated does not have are left out and counted. The
uncompensated error (``error_g`` of the truth, the noise-free reading minus sensed) is
given over the same windows, for orientation; ``--truth-only RUN_DIR`` prints that alone.

Time matching. ``vibrocomp log import`` (docs/logs.md, "log import";
shared/vibro-log/src/import/blocks.rs ``grid_ns``) puts accel.csv's row ``n`` at
``AccelBlock.t0_ns + k sample_period_ns = round((t_first + n T) 1e9)`` ns, ``t_first``
the first row's ``time_s`` and ``T`` the period, and ``first_sample_index`` counts rows
from 0: a ``time_s`` is the latch time (the END of the reading's interval), unshifted.
The compensator copies ``first_sample_index``, ``t0_ns`` and ``sample_period_ns`` from its
input. A compensated reading at ``t0_ns + k sample_period_ns`` is matched to the truth
row nearest that time, and the run fails when any reading is more than
``--tolerance`` (default 1 %) of a period away from its row, or before the first / after
the last row. The sample index's offset from the row index is reported.

Usage:
    python3 tests/python/waveform_errors.py SESSION.mcap RUN_DIR [--window-s 2]
    python3 tests/python/waveform_errors.py --truth-only RUN_DIR [--window-s 2]

Requires: pip install -r tests/python/requirements.txt (mcap, mcap-protobuf-support).
"""

import argparse
import csv
import json
import math
import os
import sys

import numpy as np

UNITS = 3
MAIN_ONLY = 4
WAVEFORM = 2048
WAVEFORM_FALLBACK = 4096
FLAG_NAMES = {
    1: "VIBRATION_ESTIMATE_STALE", 2: "ESTIMATE_MISSING", 4: "MAIN_ONLY", 8: "INPUT_GAP",
    16: "NON_FINITE_INPUT", 32: "ESTIMATE_FLAGGED", 64: "RATE_CHANGE", 128: "TIME_JUMP",
    256: "ESTIMATE_AHEAD", 512: "INPUT_SATURATED", 1024: "MODEL_EFFECTS", 2048: "WAVEFORM",
    4096: "WAVEFORM_FALLBACK",
}
TRUTH_COLUMNS = ["time_s"] + [f"sensed{u}_g" for u in (1, 2, 3)] + [f"error{u}_g" for u in (1, 2, 3)]


def read_truth(run_dir):
    """readings_truth.csv: (time_s (J,), sensed_g (J, 3), error_g (J, 3))."""
    path = os.path.join(run_dir, "readings_truth.csv")
    with open(path) as f:
        lines = [ln for ln in f if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    if rows[0] != TRUTH_COLUMNS:
        raise ValueError(f"{path}: header {rows[0]}, want {TRUTH_COLUMNS}")
    a = np.array([[float(c) for c in r] for r in rows[1:]], dtype=np.float64)
    if len(a) < 2 or np.any(np.diff(a[:, 0]) <= 0):
        raise ValueError(f"{path}: need at least two rows with increasing time_s")
    return a[:, 0], a[:, 1:4], a[:, 4:7]


def read_session(path):
    """/compensated blocks: a list of (first_sample_index, t0_ns, sample_period_ns, flags,
    a4_g (count, 3))."""
    try:
        from mcap.reader import make_reader
        from mcap_protobuf.decoder import DecoderFactory
    except ImportError as e:  # pragma: no cover - the message is the point
        raise SystemExit(f"waveform_errors.py: missing Python package ({e}); "
                         "run `pip install -r tests/python/requirements.txt`") from None
    blocks = []
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _schema, _channel, _message, msg in reader.iter_decoded_messages(topics=["/compensated"]):
            a4 = np.asarray(msg.a4_g, dtype=np.float64).reshape(-1, UNITS)
            blocks.append((int(msg.first_sample_index), int(msg.t0_ns), int(msg.sample_period_ns),
                           int(msg.flags), a4))
    if not blocks:
        raise ValueError(f"{path}: no /compensated messages")
    return blocks


def flag_counts(blocks):
    counts = {}
    for *_, flags, _a4 in blocks:
        for bit in range(32):
            if flags & (1 << bit):
                name = FLAG_NAMES.get(1 << bit, f"bit{bit}")
                counts[name] = counts.get(name, 0) + 1
    return counts


def match(blocks, t_s, tolerance=0.01):
    """Each compensated reading's truth row: {row: (a4 (3,), flags)}, and facts.

    Raises ValueError when a reading lies more than ``tolerance`` periods from every row.
    """
    n = len(t_s)
    period = (t_s[-1] - t_s[0]) / (n - 1)
    out, offsets, worst, duplicates = {}, set(), 0.0, 0
    for first, t0_ns, period_ns, flags, a4 in blocks:
        for k, row in enumerate(a4):
            t = (t0_ns + k * period_ns) * 1e-9
            j = int(round((t - t_s[0]) / period))
            if not 0 <= j < n:
                raise ValueError(f"compensated reading at {t:.9f} s (sample {first + k}) is outside the truth's "
                                 f"{t_s[0]:.9f} .. {t_s[-1]:.9f} s")
            dt = abs(t - t_s[j])
            if dt > tolerance * period:
                raise ValueError(f"compensated reading at {t:.9f} s (sample {first + k}) is {dt:.3e} s from "
                                 f"the nearest truth row ({t_s[j]:.9f} s): more than {tolerance:g} of a period "
                                 f"({period:.3e} s); the time conventions disagree")
            worst = max(worst, dt)
            offsets.add(first + k - j)
            duplicates += j in out
            out[j] = (row, flags)
    return out, {"max_time_diff_s": worst, "sample_index_minus_row": sorted(offsets),
                 "duplicate_readings": duplicates}


def window_rows(n_rows, per_window):
    return [range(w * per_window, (w + 1) * per_window) for w in range(n_rows // per_window)]


def rms_figures(means):
    """means: (windows, 3) -> per unit and pooled RMS (null when there is no window)."""
    m = np.asarray(means, dtype=np.float64).reshape(-1, UNITS)

    def rms(x):
        return float(np.sqrt(np.mean(x * x))) if x.size else None

    return {"windows": int(len(m)), "all_units_rms_g": rms(m.ravel()),
            "units": [{"unit": u + 1, "rms_g": rms(m[:, u])} for u in range(UNITS)]}


def per_window_samples(t_s, window_s):
    period = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    return max(1, int(math.floor(window_s / period + 0.5)))


def truth_only(t_s, error_g, window_s):
    n = per_window_samples(t_s, window_s)
    means = [error_g[list(w)].mean(axis=0) for w in window_rows(len(t_s), n)]
    return {"window_readings": n, "readings": len(t_s), "uncompensated": rms_figures(means)}


def measure(blocks, t_s, sensed_g, error_g, window_s=2.0, tolerance=0.01):
    matched, facts = match(blocks, t_s, tolerance)
    n = per_window_samples(t_s, window_s)
    sel = {"all": [], "compensated": [], "waveform": [], "fallback": []}
    unc = []
    incomplete = 0
    for w in window_rows(len(t_s), n):
        if any(j not in matched for j in w):
            incomplete += 1
            continue
        rows = list(w)
        a4 = np.array([matched[j][0] for j in rows])
        flags = [matched[j][1] for j in rows]
        mean = (a4 - sensed_g[rows]).mean(axis=0)
        sel["all"].append(mean)
        unc.append(error_g[rows].mean(axis=0))
        if not any(f & MAIN_ONLY for f in flags):
            sel["compensated"].append(mean)
        if all(f & WAVEFORM for f in flags):
            sel["waveform"].append(mean)
        if any(f & WAVEFORM_FALLBACK for f in flags):
            sel["fallback"].append(mean)
    return {
        "window_s": window_s,
        "window_readings": n,
        "readings_truth": len(t_s),
        "readings_matched": len(matched),
        **facts,
        "blocks": len(blocks),
        "blocks_per_flag": flag_counts(blocks),
        "windows_left_out": incomplete,
        "all": rms_figures(sel["all"]),
        "compensated": rms_figures(sel["compensated"]),
        "waveform": rms_figures(sel["waveform"]),
        "fallback": rms_figures(sel["fallback"]),
        "uncompensated": rms_figures(unc),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("session", nargs="?", help="recorded session (MCAP with /compensated)")
    ap.add_argument("run", nargs="?", help="the generator's run folder (readings_truth.csv)")
    ap.add_argument("--truth-only", metavar="RUN_DIR", help="only the truth's uncompensated error")
    ap.add_argument("--window-s", type=float, default=2.0)
    ap.add_argument("--tolerance", type=float, default=0.01, help="time matching, fraction of a period")
    a = ap.parse_args(argv)
    if not a.window_s > 0:
        ap.error(f"--window-s {a.window_s}: must be > 0")
    try:
        if a.truth_only:
            t_s, _sensed, err = read_truth(a.truth_only)
            result = {"run": a.truth_only, "window_s": a.window_s, **truth_only(t_s, err, a.window_s)}
        else:
            if not (a.session and a.run):
                ap.error("give SESSION.mcap RUN_DIR, or --truth-only RUN_DIR")
            t_s, sensed, err = read_truth(a.run)
            result = {"session": a.session, "run": a.run,
                      **measure(read_session(a.session), t_s, sensed, err, a.window_s, a.tolerance)}
    except Exception as e:  # any reader, decoder or data problem, with its file
        print(f"waveform_errors.py: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    json.dump(result, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
