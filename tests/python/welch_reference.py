#!/usr/bin/env python3
"""Independent reference for `vibrocomp estimate`: band PSD, band RMS, broadband RMS
and covariance of each window of a 3-column CSV, computed with scipy.signal.welch and
scipy.signal.csd (Hann, 50% overlap, constant detrend, one-sided density).

Band integration: Welch bin k stands for [k df - df/2, k df + df/2]; a band [lo, hi]
takes each bin with the fraction of that interval inside the band, so the integrated
width is exactly hi - lo (the rule docs/estimation.md states).

Used by tests/integration/estimate.rs; needs `pip install -r tests/python/requirements.txt`.

    welch_reference.py FILE --rate-hz 8192 [--window-s 1] [--overlap 0.5]
        [--welch-segment-s 0.25] [--band-hz 20,2000]
        [--psd-bands-hz 20-40,40-80,80-160,160-320,320-640]

Prints JSON: {"windows": [{"start_sample", "band_psd_g2_per_hz", "band_rms_g",
"rms_g", "covariance_g2"}, ...]}.
"""

import argparse
import json
import sys

import numpy as np
from scipy import signal


def read_csv(path):
    """Three numeric columns; an optional header row; '#' comments and blank lines skipped."""
    rows = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            cells = [c.strip() for c in line.split(",")]
            try:
                rows.append([float(c) for c in cells])
            except ValueError:
                if rows:
                    raise
                # header row
    return np.asarray(rows, dtype=float)


def band_power(freqs, density, lo, hi):
    df = freqs[1] - freqs[0]
    left = np.maximum(freqs - df / 2.0, lo)
    right = np.minimum(freqs + df / 2.0, hi)
    weight = np.clip((right - left) / df, 0.0, 1.0)
    return float(np.sum(weight * density) * df)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("file")
    p.add_argument("--rate-hz", type=float, required=True)
    p.add_argument("--window-s", type=float, default=1.0)
    p.add_argument("--overlap", type=float, default=0.5)
    p.add_argument("--welch-segment-s", type=float, default=0.25)
    p.add_argument("--band-hz", default="20,2000")
    p.add_argument("--psd-bands-hz", default="20-40,40-80,80-160,160-320,320-640")
    a = p.parse_args()

    fs = a.rate_hz
    x = read_csv(a.file)
    n = int(round(a.window_s * fs))
    hop = max(1, int(round(n * (1.0 - a.overlap))))
    nperseg = int(round(a.welch_segment_s * fs))
    lo, hi = (float(v) for v in a.band_hz.split(","))
    bands = [tuple(float(v) for v in b.split("-")) for b in a.psd_bands_hz.split(",")]
    kw = dict(fs=fs, window="hann", nperseg=nperseg, noverlap=nperseg // 2,
              detrend="constant", scaling="density", return_onesided=True)

    windows = []
    start = 0
    while start + n <= len(x):
        seg = x[start:start + n]
        freqs, pxx = signal.welch(seg, axis=0, **kw)
        cov = np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                _, pxy = signal.csd(seg[:, i], seg[:, j], **kw)
                cov[i, j] = band_power(freqs, pxy.real, lo, hi)
        band_psd = [[band_power(freqs, pxx[:, ax], blo, bhi) / (bhi - blo) for ax in range(3)]
                    for blo, bhi in bands]
        band_rms = [[float(np.sqrt(v * (bhi - blo))) for v in row]
                    for row, (blo, bhi) in zip(band_psd, bands)]
        windows.append({
            "start_sample": start,
            "band_psd_g2_per_hz": band_psd,
            "band_rms_g": band_rms,
            "rms_g": [float(np.sqrt(band_power(freqs, pxx[:, ax], lo, hi))) for ax in range(3)],
            "covariance_g2": cov.tolist(),
        })
        start += hop
    json.dump({"windows": windows}, sys.stdout)


if __name__ == "__main__":
    main()
