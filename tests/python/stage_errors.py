#!/usr/bin/env python3
"""Independent reference for `vibrocomp log errors`: each compensation stage's error in a
recorded session against the simulator's truth, mean over windows, computed from the
raw messages with the PyPI `mcap` reader, the `mcap-protobuf-support` decoder and numpy
(none of vibrocomp's code).

The measure, as docs/logs.md ("log errors") states it: per accelerometer sample index
`i` and unit `u`, the uncompensated stage is `output_v / K1` (K1 = `K1_v_per_g` of the
passport attachment `passport-{u}-*.toml`), the main-removed stage `a2_g`, the
vibration-removed stage `a4_g` (/compensated), the reference `a_sensed_ia_g` (/truth).
Windows are `round(window_s / T)` samples, window `w` holding the indices
`w n .. (w + 1) n`; a window counts when each of its samples has all three inputs, and
is compensated when no sample's block carries MAIN_ONLY (4). Per window the error is
the mean of `stage - reference`; a stage's figure is the RMS of the window means over
the compensated windows, per unit and over the three units together.

Where the waveform stage made blocks (WAVEFORM, 2048), the estimate stage's answer is a
column of its own: `a3_g` of a WAVEFORM block, `a4_g` of the others, over the windows
in which no block's answer was main error only (MAIN_ONLY; in a WAVEFORM block
ESTIMATE_MISSING 2, VIBRATION_ESTIMATE_STALE 1 or ESTIMATE_AHEAD 256, which the
compensator sets together with MAIN_ONLY). Blocks are counted by stage: WAVEFORM,
WAVEFORM_FALLBACK (4096), neither.

Usage:
    python3 tests/python/stage_errors.py SESSION.mcap [--window-s 0.5]

Prints JSON with the fields of `vibrocomp log errors --json`'s `errors` that it
computes: window_samples, samples, windows, compensated_windows, blocks,
main_only_blocks, waveform_blocks, fallback_blocks, estimate_only_blocks,
estimate_stage (with WAVEFORM blocks), k1_v_per_g, all_units and units (each stage's
RMS, the reduction, and with WAVEFORM blocks estimate_stage_rms_g).

Requires: pip install -r tests/python/requirements.txt
"""

import argparse
import json
import math
import re
import sys
import tomllib

try:
    import numpy as np
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
except ImportError as e:  # pragma: no cover - the message is the point
    print(
        f"stage_errors.py: missing Python package ({e}); "
        "run `pip install -r tests/python/requirements.txt`",
        file=sys.stderr,
    )
    sys.exit(3)

MAIN_ONLY = 4
ESTIMATE_MAIN_ONLY = 1 | 2 | 256  # stale, missing, ahead
WAVEFORM = 2048
WAVEFORM_FALLBACK = 4096
UNITS = 3


def triples(values):
    """A repeated double of 3 * count values as a (count, 3) array, [sample][unit]."""
    return np.asarray(values, dtype=np.float64).reshape(-1, UNITS)


def read(path):
    readings, reference, a2, a4, main_only = {}, {}, {}, {}, {}
    est, est_main_only = {}, {}
    k1 = [None] * UNITS
    period_ns = None
    counts = dict.fromkeys(
        ["blocks", "main_only_blocks", "waveform_blocks", "fallback_blocks", "estimate_main_only"], 0
    )
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for a in reader.iter_attachments():
            m = re.match(r"passport-(\d+)-", a.name)
            if m and int(m.group(1)) < UNITS:
                k1[int(m.group(1))] = tomllib.loads(a.data.decode())["K1_v_per_g"]
        for _schema, channel, _message, msg in reader.iter_decoded_messages(
            topics=["/accel", "/truth", "/compensated"]
        ):
            first = msg.first_sample_index
            if channel.topic == "/accel":
                period_ns = period_ns or msg.sample_period_ns
                for k, row in enumerate(triples(msg.output_v)):
                    readings[first + k] = row
            elif channel.topic == "/truth":
                for k, row in enumerate(triples(msg.a_sensed_ia_g)):
                    reference[first + k] = row
            else:
                counts["blocks"] += 1
                flagged = bool(msg.flags & MAIN_ONLY)
                waveform = bool(msg.flags & WAVEFORM)
                est_flagged = bool(msg.flags & ESTIMATE_MAIN_ONLY) if waveform else flagged
                counts["main_only_blocks"] += flagged
                counts["waveform_blocks"] += waveform
                counts["fallback_blocks"] += (not waveform) and bool(msg.flags & WAVEFORM_FALLBACK)
                counts["estimate_main_only"] += est_flagged
                answer = triples(msg.a3_g) if waveform else triples(msg.a4_g)
                for k, (x2, x4) in enumerate(zip(triples(msg.a2_g), triples(msg.a4_g))):
                    a2[first + k] = x2
                    a4[first + k] = x4
                    main_only[first + k] = flagged
                    est[first + k] = answer[k]
                    est_main_only[first + k] = est_flagged
    if None in k1:
        raise RuntimeError(f"passports found for units {k1}: need all three")
    return readings, reference, a2, a4, main_only, est, est_main_only, np.array(k1), period_ns, counts


def rms(x):
    x = np.asarray(x, dtype=np.float64)
    return float(np.sqrt(np.mean(x * x)))


def stage(unc, main, vib):
    u, m, v = rms(unc), rms(main), rms(vib)
    return {
        "uncompensated_rms_g": u,
        "main_removed_rms_g": m,
        "vibration_removed_rms_g": v,
        "reduction": u / v if v > 0 else math.inf,
    }


def measure(path, window_s):
    readings, reference, a2, a4, main_only, est, est_main_only, k1, period_ns, counts = read(path)
    # Half away from zero, as Rust's f64::round (Python's round() goes to even).
    per_window = max(1, int(math.floor(window_s * 1e9 / period_ns + 0.5)))
    complete = sorted(set(readings) & set(reference) & set(a2))
    windows = {}
    for i in complete:
        windows.setdefault(i // per_window, []).append(i)
    whole = [w for w, rows in sorted(windows.items()) if len(rows) == per_window]
    compensated = [w for w in whole if not any(main_only[i] for i in windows[w])]
    # means[stage][window][unit]
    means = {"unc": [], "main": [], "vib": []}
    for w in compensated:
        rows = windows[w]
        ref = np.array([reference[i] for i in rows])
        means["unc"].append(np.mean(np.array([readings[i] for i in rows]) / k1 - ref, axis=0))
        means["main"].append(np.mean(np.array([a2[i] for i in rows]) - ref, axis=0))
        means["vib"].append(np.mean(np.array([a4[i] for i in rows]) - ref, axis=0))
    m = {s: np.array(v).reshape(-1, UNITS) for s, v in means.items()}
    result = {
        "window_samples": per_window,
        "samples": len(complete),
        "windows": len(whole),
        "compensated_windows": len(compensated),
        "blocks": counts["blocks"],
        "main_only_blocks": counts["main_only_blocks"],
        "waveform_blocks": counts["waveform_blocks"],
        "fallback_blocks": counts["fallback_blocks"],
        "estimate_only_blocks": counts["blocks"] - counts["waveform_blocks"] - counts["fallback_blocks"],
        "k1_v_per_g": k1.tolist(),
        "all_units": stage(m["unc"].ravel(), m["main"].ravel(), m["vib"].ravel()),
        "units": [
            {"unit": u + 1, **stage(m["unc"][:, u], m["main"][:, u], m["vib"][:, u])}
            for u in range(UNITS)
        ],
    }
    if counts["waveform_blocks"]:
        # The estimate stage's answer over the windows it compensated itself.
        by_estimate = [w for w in whole if not any(est_main_only[i] for i in windows[w])]
        e = np.array(
            [
                np.mean(
                    np.array([est[i] for i in windows[w]])
                    - np.array([reference[i] for i in windows[w]]),
                    axis=0,
                )
                for w in by_estimate
            ]
        ).reshape(-1, UNITS)
        result["estimate_stage"] = {
            "compensated_windows": len(by_estimate),
            "main_only_blocks": counts["estimate_main_only"],
        }
        nan_or = lambda x: rms(x) if len(x) else None  # noqa: E731 - JSON null, as serde's NaN
        result["all_units"]["estimate_stage_rms_g"] = nan_or(e.ravel())
        for u in range(UNITS):
            result["units"][u]["estimate_stage_rms_g"] = nan_or(e[:, u])
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--window-s", type=float, default=0.5)
    args = parser.parse_args()
    try:
        result = measure(args.file, args.window_s)
    except Exception as e:  # any reader, decoder or data problem
        print(f"stage_errors.py: {args.file}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    json.dump(result, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
