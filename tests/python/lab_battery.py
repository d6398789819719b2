#!/usr/bin/env python3
"""An independent generator of campaign tables with hidden effects, for the model
lab's battery (issue 32, item 4).

Written from shared/spec/MODEL.md, docs/effects.md and docs/lab.md alone, in numpy and
scipy; nothing of vibrocomp's Rust code (vibro-physics, vibro-sim, vibro-effects) is
used or transcribed. The passport is read from config/accelerometers/al-15.toml.

    python3 tests/python/lab_battery.py selfcheck [--bin PATH] [--mc-samples N] [--json FILE]
    python3 tests/python/lab_battery.py battery --out DIR --seed N [--members all|ci] [--rows R] [--only NAMES]

What it computes
----------------
The measured VE of MODEL.md section 8, `(<U2> - 0.5 (<U1> + <U3>)) / K1`, is, in
acceleration units, the mean output under vibration minus the output at rest:
`VE = E[aF(a(t))] - aF(aL)` with (FP) of MODEL.md section 2 (lambda = 1, as the
lab takes it). It is computed as a direct numerical expectation of the instantaneous
output, the effects applied to the instantaneous signals and output as docs/effects.md
describes their hooks, over

- the tone's phase theta, uniform: Gauss-Legendre on 32 equal panels of [0, 2 pi),
  split further at the kinks of the integrand (a3 = 0 for the asymmetry term |a3|,
  the output crossing +-range_g under saturation), 12 nodes a panel: exact to
  rounding for the trigonometric polynomials of (FP) (a uniform 4096-point rule is
  exact for them too, but not for the kinks, whose O(h^2) error would be 1e-7 g under
  saturation);
- the Gaussian random part: the IA component innermost, x3 = sigma3 z, by composite
  Gauss-Legendre on |z| <= 10 (24 panels, 16 nodes), split at the same kinks (found
  on a grid and refined by bisection); OA, PA (and the vibropendulous high-passed IA
  component) as their regression on x3 plus a residual integrated by Gauss-Hermite
  (6 nodes a dimension, exact for the polynomial dependence);
- a tone and a random part together: the phase outermost by the midpoint rule (256
  nodes; the integrand is smooth and periodic once the random part is integrated).

The linear part of (FP), a0 + k1 a3 + m1 a1 + m2 a2, whose mean is its value at aL
(the vibration has zero mean), is subtracted inside the integrand to keep the
cancellation of the O(1 g) output out of the 1e-6 g VE (exact, not an approximation).

Effects (docs/effects.md), in the simulator's order: what the sensor states, then the
body vibration, the vibration path, the unit's output, the clip:

- `sensor_error` (gain_error g only; the lab fits no misalignment): the table states
  what the IA vibration sensor measured, `(1 + g)` times the truth: the IA tone
  amplitude, the IA RMS and the IA covariances cov31, cov32 (from the reading
  `(1 + g) v_IA`) are divided by `1 + g`; OA and PA are as stated. No mean term.
- `axis_phase` (phase_x_deg on OA, phase_y_deg on PA, phase_z_deg on IA, the lab's
  frame): every tone's phase on that axis is moved by the offset before anything else
  sees the vibration (hook `adjust_body_vibration`: "before samples are drawn"), so
  the downstream effects (vibropendulous, anisoelastic, saturation) see the shifted
  phases too. The table states the shaker's phases (phase31 = phi3 - phi1, 0 here).
- `mount_resonance` (freq_hz, q, all axes): the table states the base vibration; the
  unit sees it through the transmissibility T(s) = (wn^2 + 2 zeta wn s) /
  (s^2 + 2 zeta wn s + wn^2), zeta = 1/(2 q): each tone times |T(f)|, shifted by
  arg T(f); the flat band's spectrum times |T(f)|^2 (the covariance times its band
  average). T is evaluated as the biquad of docs/effects.md, the bilinear transform
  prewarped at freq_hz, at the simulator's internal rate (docs/effects.md "Filters are
  discrete-time at the simulator's internal rate"; 25600 Hz, the default of
  config/scenarios/README.md), `--filter-rate-hz inf` for the analog T.
- `high_order_nonlinearity`: out += k6 a3^6 + k7 a3^7, k6 in ppm/g^5 (1e-6 g/g^6).
- `vibropendulous`: out += c HP[a3](t) a2(t), HP(s) = s tau / (1 + s tau) on the total
  IA acceleration (zero at DC), a2 the total PA acceleration. A tone enters HP with
  |HP(f)| and arg HP(f); the random part as a fourth jointly Gaussian variable w =
  HP[x3] with cov(w, x_j) = int Re HP(f) S_3j(f) df and var w = int |HP|^2 S_33 df
  over the band (after the mount, when there is one). HP is the plain bilinear image
  at the same rate (see "Ambiguities").
- `anisoelastic`: out += k_ae a1 a2.
- `heating`: tau db/dt = c v3^2 - b from b = 0 at the start of the vibrating record,
  v3 the IA vibration reaching the unit; over a record of T = vibrating_s seconds the
  mean bias is c P (1 - tau/T (1 - exp(-T/tau))), P = E[v3^2], added to the output
  before the clip as a constant (its slow variation inside the clip changes the mean
  by ~ var_t(b) times the output density: below 1e-12 g here).
- `saturation`: the output, with every term above, clipped to +-range_g.

The battery
-----------
Members of 2 or 3 effects (all 28 pairs and 6 triples; `--members ci`: 8 pairs and 2
triples at 140 rows) on a campaign that can separate them (`design`), the effects'
parameters drawn in realistic ranges (`draw_params`) and then turned so that their
strengths (the RMS over the table of each effect's marginal VE change: the joint VE
minus the joint VE without it) stand in a ratio drawn log-uniformly from 1:1 to
1000:1; measurement noise of 0.3..2 ug (stated as ve_uncertainty_g, drawn with the
seed). The weakest effect must be detectable: its chi2 sum((dVE/u)^2) >= 100, and so
is the part of it the other effects' parameters cannot absorb (`unique_chi2`, weighted
least squares on their Jacobian columns); else the member is drawn again. Two
"confounded" members use one tone frequency: a mount resonance along IA (a sensor gain
error 1/|T(f)| - 1 gives the same table) and a vibropendulous coupling on IA-PA and IA
rows (an axis phase on PA with 0.5 m32 (cos d - 1) = 0.5 c Re HP gives the same).

The lab's parameters: the battery's truth.json states each hidden effect's parameters
by the lab's library names (shared/vibro-lab/src/library.rs): for heating the lab fits
the steady-state coefficient with tau fixed short, so the truth of `c_g_per_g2` is
c (1 - tau/T (1 - exp(-T/tau))) (the physical c and tau are under "physical"); for
axis_phase with the table's phases all 0 only cos(offset) is observable, so the
truth is +-offset modulo 360 ("sign_observable": false). Each offset's sign is free on
its own too; with an anisoelastic term (which takes cos(d_OA - d_PA)) a flip of one
sign is made up by k_ae, so truth.json also lists such sets ("equivalent_params"),
each checked to give the member's table to rounding.

Ambiguities found in docs/effects.md (and docs/lab.md)
------------------------------------------------------
1. heating: the mean formula covers the vibrating record from cold; docs/effects.md
   does not say whether the still record after it (MODEL.md section 8's U3) still
   carries the decaying bias (it would remove about tau/(2 T3) (1 - e^(-T/tau)) of it:
   27 % for tau = 120 s). The battery uses tau = 1 s and T = 300 s (a tail of 0.17 %,
   below the fits' resolution), so the choice does not matter; heating is kept.
2. vibropendulous: docs/effects.md gives HP(s) but not its discretisation (the mount's
   "bilinear transform prewarped at freq_hz" is stated, HP's is not); the generator
   takes the plain bilinear transform at 25600 Hz. Against the analog HP the effect
   moves by 4e-5 of itself at 100 Hz and 6e-5 at 250 Hz (selfcheck (d)): below the
   noise of these tables, so kept.
3. The lab's rate for the filters (docs/lab.md does not state it): 25600 Hz assumed
   (docs/effects.md: the simulator's internal rate). The analog mount differs by
   3e-5 of the effect at 100 Hz, 1e-5 at 250 Hz (selfcheck (d)).
4. Composition (docs/lab.md "The prediction" against docs/effects.md): the lab adds
   each non-path effect's mean under the vibration reaching the unit, each alone; the
   physics of docs/effects.md composes them: axis_phase shifts the phases the
   vibropendulous and anisoelastic terms and the saturation see, and saturation clips
   the k6/k7, vibropendulous, anisoelastic and heating terms with (FP). The generator
   follows the physics and reports, per member, the chi-square of (joint VE - the
   lab's additive composition) over the stated uncertainties ("composition_gap_chi2"
   in truth.json); a large one means no library fit can meet the noise.
   `--composition lab` writes the tables with the lab's composition instead, so that
   the members where the two differ test the search alone.
5. The table has no cov12 column: the random rows never vibrate OA and PA together.

Selfcheck (2026-11-27, the binary built from main that day): the base model agrees
with MODEL.md's closed forms to 7e-15 (relative); every effect agrees with its Monte
Carlo within 1.8 standard errors (the filters' tones, on an FFT bin, to 8e-12); and with
the binary's `lab compare --model` on 24 conditions to at most 5e-14 of the effect's
largest change: no effect is dropped (`DROPPED` is empty).
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
from numpy.polynomial.hermite_e import hermegauss
from numpy.polynomial.legendre import leggauss
from scipy import integrate, signal, special

ROOT = Path(__file__).resolve().parents[2]
PASSPORT_FILE = ROOT / "config" / "accelerometers" / "al-15.toml"
FILTER_RATE_HZ = 25600.0
TWO_PI = 2.0 * math.pi

EFFECTS = (
    "mount_resonance",
    "high_order_nonlinearity",
    "saturation",
    "vibropendulous",
    "anisoelastic",
    "heating",
    "axis_phase",
    "sensor_error",
)
# Effects left out of the battery after the selfcheck's comparison with the binary
# (kind -> reason); see the module doc and `selfcheck`.
DROPPED = {}

# The lab's fitted parameters (shared/vibro-lab/src/library.rs).
LAB_PARAMS = {
    "mount_resonance": ("freq_hz", "q"),
    "high_order_nonlinearity": ("k6_ppm_per_g5", "k7_ppm_per_g6"),
    "saturation": ("range_g",),
    "vibropendulous": ("c_rad_per_g", "tau_s"),
    "anisoelastic": ("k_ae_per_g",),
    "heating": ("c_g_per_g2",),
    "axis_phase": ("phase_x_deg", "phase_y_deg"),
    "sensor_error": ("gain_error",),
}

COLUMNS = (
    "run_id,passport,aL1_g,aL2_g,aL3_g,freq_hz,aB1_g,aB2_g,aB3_g,phase31_deg,"
    "phase32_deg,sigma1_g,sigma2_g,sigma3_g,cov31_g2,cov32_g2,kurtosis3,ve_measured_g,"
    "ve_uncertainty_g,band_lo_hz,band_hi_hz,vibrating_s"
).split(",")


# --------------------------------------------------------------------------- passport


class Passport:
    """(FP) coefficients in acceleration units (g, 1/g, ...), from the passport file."""

    def __init__(self, path=PASSPORT_FILE):
        with open(path, "rb") as f:
            d = tomllib.load(f)
        self.id = d["id"]
        self.a0 = d["a0_g"]
        self.k1 = d["k1"]
        self.d1a = d["d1a_ppm"] * 1e-6
        self.k2 = d["k2_ppm_per_g"] * 1e-6
        self.k3 = d["k3_ppm_per_g2"] * 1e-6
        self.k4 = d["k4_ppm_per_g3"] * 1e-6
        self.k5 = d["k5_ppm_per_g4"] * 1e-6
        self.m1 = d["m1_ppm"] * 1e-6
        self.m2 = d["m2_ppm"] * 1e-6
        self.m31 = d["m31_ppm_per_g"] * 1e-6
        self.m32 = d["m32_ppm_per_g"] * 1e-6

    def with_(self, **kw):
        p = Passport.__new__(Passport)
        p.__dict__.update(self.__dict__)
        p.__dict__.update(kw)
        return p


# --------------------------------------------------------------------------- filters


def _bilinear_s(f_hz, rate_hz, prewarp_hz):
    """The Laplace variable the bilinear image of an analog filter sees at `f_hz`."""
    f = np.asarray(f_hz, float)
    if not math.isfinite(rate_hz):
        return 1j * TWO_PI * f
    if prewarp_hz and 0 < prewarp_hz < 0.4 * rate_hz:
        k = TWO_PI * prewarp_hz / math.tan(math.pi * prewarp_hz / rate_hz)
    else:
        k = 2.0 * rate_hz
    return 1j * k * np.tan(np.pi * f / rate_hz)


def mount_T(f_hz, f0, q, rate_hz=FILTER_RATE_HZ):
    s = _bilinear_s(f_hz, rate_hz, f0)
    wn = TWO_PI * f0
    zeta = 1.0 / (2.0 * q)
    return (wn * wn + 2 * zeta * wn * s) / (s * s + 2 * zeta * wn * s + wn * wn)


def hp_H(f_hz, tau, rate_hz=FILTER_RATE_HZ):
    s = _bilinear_s(f_hz, rate_hz, 0.0)
    return s * tau / (1.0 + s * tau)


_CACHE = {}


def cached(key, fn):
    if key not in _CACHE:
        _CACHE[key] = fn()
    return _CACHE[key]


def band_integral(fun, lo, hi, points=()):
    """int_lo^hi fun(f) df to ~1e-14 relative (adaptive, split at `points`)."""
    pts = sorted(p for p in points if lo < p < hi)
    edges = [lo] + pts + [hi]
    total = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        v, _ = integrate.quad(fun, a, b, epsabs=0.0, epsrel=1e-13, limit=400)
        total += v
    return total


# --------------------------------------------------------------------------- tables


class Table:
    """Conditions as the lab's table states them (arrays over rows)."""

    def __init__(self, rows):
        n = len(rows)
        self.n = n
        self.rows = rows
        g = lambda k, d=0.0: np.array([r.get(k, d) if r.get(k) is not None else d for r in rows], float)
        self.aL = np.stack([g("aL1_g"), g("aL2_g"), g("aL3_g")], 1)
        self.has_tone = np.array([r.get("freq_hz") is not None for r in rows])
        self.f = g("freq_hz", 1.0)
        self.aB = np.stack([g("aB1_g"), g("aB2_g"), g("aB3_g")], 1)
        self.ph31 = np.radians(g("phase31_deg"))
        self.ph32 = np.radians(g("phase32_deg"))
        self.has_rand = np.array([r.get("sigma3_g") is not None for r in rows])
        C = np.zeros((n, 3, 3))
        C[:, 0, 0] = g("sigma1_g") ** 2
        C[:, 1, 1] = g("sigma2_g") ** 2
        C[:, 2, 2] = g("sigma3_g") ** 2
        C[:, 2, 0] = C[:, 0, 2] = g("cov31_g2")
        C[:, 2, 1] = C[:, 1, 2] = g("cov32_g2")
        self.C = C
        self.lo = g("band_lo_hz", 0.0)
        self.hi = g("band_hi_hz", 0.0)
        self.T = g("vibrating_s", 300.0)
        self.aB[~self.has_tone] = 0.0


class Unit:
    """The vibration reaching the unit and the output terms, per row."""


def unit_view(tab, eff, rate=FILTER_RATE_HZ):
    """What the unit sees: the stated vibration through the sensor error, the axis
    phases and the mount (module doc); the vibropendulous and heating terms."""
    n = tab.n
    u = Unit()
    u.aL = tab.aL.copy()
    u.has_tone = tab.has_tone
    u.has_rand = tab.has_rand
    u.f = tab.f
    A = tab.aB.copy()
    phi = np.stack([-tab.ph31, -tab.ph32, np.zeros(n)], 1)
    C = tab.C.copy()
    if "sensor_error" in eff:
        k = 1.0 + eff["sensor_error"].get("gain_error", 0.0)
        A[:, 2] /= k
        C[:, 2, :] /= k
        C[:, :, 2] /= k
    if "axis_phase" in eff:
        p = eff["axis_phase"]
        phi = phi + np.radians(
            [p.get("phase_x_deg", 0.0), p.get("phase_y_deg", 0.0), p.get("phase_z_deg", 0.0)]
        )[None, :]
    Cbase = C.copy()  # the true base vibration, before the mount
    gain2 = None
    if "mount_resonance" in eff:
        f0 = eff["mount_resonance"]["freq_hz"]
        q = eff["mount_resonance"]["q"]
        T = mount_T(tab.f, f0, q, rate)
        A = A * np.abs(T)[:, None]
        phi = phi + np.angle(T)[:, None]
        gain2 = lambda f: float(np.abs(mount_T(f, f0, q, rate)) ** 2)
        for i in np.nonzero(tab.has_rand)[0]:
            lo, hi = tab.lo[i], tab.hi[i]
            if not hi > lo:
                raise ValueError(f"row {i}: mount_resonance on a random row needs its band")
            C[i] *= cached(("T2", f0, q, lo, hi, rate),
                           lambda: band_integral(gain2, lo, hi, [f0]) / (hi - lo))
    u.A, u.phi, u.C = A, phi, C
    # vibropendulous: HP of the IA tone; the joint moments of w = HP[x3]
    u.Hm = np.zeros(n)
    u.Ha = np.zeros(n)
    u.wcov = np.zeros((n, 3))
    u.wvar = np.zeros(n)
    if "vibropendulous" in eff:
        tau = eff["vibropendulous"]["tau_s"]
        H = hp_H(tab.f, tau, rate)
        u.Hm, u.Ha = np.abs(H), np.angle(H)
        pts = [eff["mount_resonance"]["freq_hz"]] if gain2 else []
        for i in np.nonzero(tab.has_rand)[0]:
            lo, hi = tab.lo[i], tab.hi[i]
            if not hi > lo:
                raise ValueError(f"row {i}: vibropendulous on a random row needs its band")
            g2 = gain2 if gain2 else (lambda f: 1.0)
            key = ("HP", tau, lo, hi, rate, tuple(sorted(eff.get("mount_resonance", {}).items())))
            re, ab = cached(key, lambda: (
                band_integral(lambda f: float(hp_H(f, tau, rate).real) * g2(f), lo, hi, pts) / (hi - lo),
                band_integral(lambda f: float(abs(hp_H(f, tau, rate)) ** 2) * g2(f), lo, hi, pts) / (hi - lo)))
            u.wcov[i] = Cbase[i, 2, :] * re
            u.wvar[i] = Cbase[i, 2, 2] * ab
    # heating: the mean bias over the record
    u.bias = np.zeros(n)
    if "heating" in eff:
        c = eff["heating"]["c_g_per_g2"]
        tau = eff["heating"]["tau_s"]
        P = 0.5 * A[:, 2] ** 2 + C[:, 2, 2]
        u.bias = c * P * (1.0 - tau / tab.T * (-np.expm1(-tab.T / tau)))
    e = {}
    e["k6"] = eff.get("high_order_nonlinearity", {}).get("k6_ppm_per_g5", 0.0) * 1e-6
    e["k7"] = eff.get("high_order_nonlinearity", {}).get("k7_ppm_per_g6", 0.0) * 1e-6
    e["cvp"] = eff.get("vibropendulous", {}).get("c_rad_per_g", 0.0)
    e["kae"] = eff.get("anisoelastic", {}).get("k_ae_per_g", 0.0)
    e["R"] = eff.get("saturation", {}).get("range_g", math.inf)
    u.e = e
    return u


# --------------------------------------------------------------------------- the output


def _lin(P, a1, a2, a3):
    return P.a0 + P.k1 * a3 + P.m1 * a1 + P.m2 * a2


def _nonlin(P, e, a1, a2, a3, hp3, bias):
    """The output minus its linear part (module doc)."""
    nl = 0.5 * P.k1 * P.d1a * np.abs(a3) + a3 * a3 * (P.k2 + a3 * (P.k3 + a3 * (P.k4 + a3 * P.k5)))
    nl = nl + a3 * (P.m31 * a1 + P.m32 * a2)
    if e["k6"] or e["k7"]:
        a6 = (a3 * a3 * a3) ** 2
        nl = nl + a6 * (e["k6"] + e["k7"] * a3)
    if e["cvp"]:
        nl = nl + e["cvp"] * hp3 * a2
    if e["kae"]:
        nl = nl + e["kae"] * a1 * a2
    return nl + bias


def _g(P, e, a1, a2, a3, hp3, bias):
    """The instantaneous output (clipped) minus its linear part."""
    nl = _nonlin(P, e, a1, a2, a3, hp3, bias)
    R = e["R"]
    if not math.isfinite(R):
        return nl
    lin = _lin(P, a1, a2, a3)
    y = lin + nl
    return np.where(np.abs(y) <= R, nl, np.clip(y, -R, R) - lin)


def _y(P, e, a1, a2, a3, hp3, bias):
    return _lin(P, a1, a2, a3) + _nonlin(P, e, a1, a2, a3, hp3, bias)


def _crossings(F, lo, hi, grid, shape, iters=60):
    """Roots of the elementwise F(x), x of shape `shape + (k,)`, on [lo, hi]: sign
    changes on a uniform grid of `grid` cells, refined by bisection. Returns
    `shape + (K,)` roots, padded with `lo` (a duplicate edge makes an empty panel)."""
    xs = lo + (hi - lo) * np.arange(grid + 1) / grid
    v = F(np.broadcast_to(xs, shape + (grid + 1,)).copy())
    sv = np.sign(v)
    ch = sv[..., :-1] * sv[..., 1:] < 0
    K = int(ch.sum(-1).max()) if ch.size else 0
    if K == 0:
        return np.full(shape + (1,), float(lo))
    rank = np.cumsum(ch, -1) - 1
    idx = np.nonzero(ch)
    slot = idx[:-1] + (rank[idx],)
    a = np.full(shape + (K,), float(lo))
    b = a.copy()
    va = np.zeros(shape + (K,))
    a[slot] = xs[idx[-1]]
    b[slot] = xs[idx[-1] + 1]
    va[slot] = v[idx]
    for _ in range(iters):
        m = 0.5 * (a + b)
        vm = F(m)
        left = np.sign(vm) == np.sign(va)
        a = np.where(left, m, a)
        va = np.where(left, vm, va)
        b = np.where(left, b, m)
    return 0.5 * (a + b)


class Quad:
    """Quadrature settings."""

    theta_panels = 32
    theta_nodes = 12
    theta_mid = 256  # the phase, outermost over a random part
    z_max = 10.0
    z_panels = 24
    z_nodes = 16
    gh = 6


def _gl_panels(edges, n):
    """Nodes and weights of n-point Gauss-Legendre on each panel [edges_k, edges_k+1]
    (last axis); shapes (..., P, n)."""
    x, w = leggauss(n)
    a = edges[..., :-1, None]
    b = edges[..., 1:, None]
    h = 0.5 * (b - a)
    return 0.5 * (a + b) + h * x, h * w


def tone_means(P, u, rows, Q=Quad):
    """E[g] over the phase for tone-only rows (vectorised over rows)."""
    rows = np.asarray(rows, int)
    if len(rows) == 0:
        return np.zeros(0)
    e = u.e
    aL = u.aL[rows]
    A = u.A[rows]
    phi = u.phi[rows]
    Hm = u.Hm[rows]
    Ha = u.Ha[rows]
    bias = u.bias[rows]
    n = len(rows)

    def sig(th):
        a1 = aL[:, 0, None] + A[:, 0, None] * np.sin(th + phi[:, 0, None])
        a2 = aL[:, 1, None] + A[:, 1, None] * np.sin(th + phi[:, 1, None])
        a3 = aL[:, 2, None] + A[:, 2, None] * np.sin(th + phi[:, 2, None])
        hp3 = Hm[:, None] * A[:, 2, None] * np.sin(th + phi[:, 2, None] + Ha[:, None])
        return a1, a2, a3, hp3

    edges = [np.broadcast_to(np.linspace(0.0, TWO_PI, Q.theta_panels + 1), (n, Q.theta_panels + 1))]
    # |a3| kinks: aL3 + A3 sin(th + phi3) = 0
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.arcsin(np.clip(-aL[:, 2] / np.where(A[:, 2] > 0, A[:, 2], 1.0), -1, 1))
    has = A[:, 2] > np.abs(aL[:, 2])
    k1 = np.where(has, np.mod(s - phi[:, 2], TWO_PI), 0.0)
    k2 = np.where(has, np.mod(math.pi - s - phi[:, 2], TWO_PI), 0.0)
    edges.append(np.stack([k1, k2], 1))
    if math.isfinite(e["R"]):
        for level in (e["R"], -e["R"]):
            def F(th, level=level):
                # th has shape (n, m) or a scattered (n, m) array
                a1, a2, a3, hp3 = sig(th)
                return _y(P, e, a1, a2, a3, hp3, bias[:, None]) - level
            edges.append(_crossings(F, 0.0, TWO_PI, 4096, (n,)))
    E = np.sort(np.concatenate(edges, 1), 1)
    th, w = _gl_panels(E, Q.theta_nodes)
    th = th.reshape(n, -1)
    w = w.reshape(n, -1)
    a1, a2, a3, hp3 = sig(th)
    g = _g(P, e, a1, a2, a3, hp3, bias[:, None])
    return (g * w).sum(1) / TWO_PI


def random_mean(P, u, i, Q=Quad):
    """E[g] for one row with a random part (and maybe a tone)."""
    e = u.e
    aL = u.aL[i]
    C = u.C[i]
    vp = bool(e["cvp"]) and u.wvar[i] > 0
    # the Gaussian vector (x1, x2, x3[, w])
    if vp:
        Cf = np.zeros((4, 4))
        Cf[:3, :3] = C
        Cf[3, :3] = Cf[:3, 3] = u.wcov[i]
        Cf[3, 3] = u.wvar[i]
        others = [0, 1, 3]
    else:
        Cf = C
        others = [0, 1]
    s3 = math.sqrt(C[2, 2])
    o = np.array(others)
    if s3 > 0:
        beta = Cf[o, 2] / C[2, 2]
        Cr = Cf[np.ix_(o, o)] - np.outer(Cf[o, 2], Cf[o, 2]) / C[2, 2]
    else:
        beta = np.zeros(len(o))
        Cr = Cf[np.ix_(o, o)]
    Cr = 0.5 * (Cr + Cr.T)
    lam, V = np.linalg.eigh(Cr)
    scale = max(np.abs(np.diag(Cf)).max(), 1e-300)
    keep = lam > 1e-13 * scale
    k = int(keep.sum())
    xg, wg = hermegauss(Q.gh)
    wg = wg / math.sqrt(TWO_PI)
    if k:
        grids = np.meshgrid(*([xg] * k), indexing="ij")
        U = np.stack([gg.ravel() for gg in grids], 1)
        W = np.ones(len(U))
        for gg in np.meshgrid(*([wg] * k), indexing="ij"):
            W = W * gg.ravel()
        r = U @ (V[:, keep] * np.sqrt(lam[keep])).T  # (Nr, len(o))
    else:
        r = np.zeros((1, len(o)))
        W = np.ones(1)
    r1, r2 = r[:, 0], r[:, 1]
    rw = r[:, 2] if vp else np.zeros(len(r))
    b1, b2 = beta[0], beta[1]
    bw = beta[2] if vp else 0.0
    tone = bool(u.has_tone[i])
    A, phi = u.A[i], u.phi[i]
    if tone:
        th = TWO_PI * (np.arange(Q.theta_mid) + 0.5) / Q.theta_mid
        wth = np.full(Q.theta_mid, 1.0 / Q.theta_mid)
    else:
        th = np.zeros(1)
        wth = np.ones(1)
        A = np.zeros(3)
    total = 0.0
    chunk = max(1, 4096 // max(1, len(W)))
    zu = np.linspace(-Q.z_max, Q.z_max, Q.z_panels + 1)
    for c0 in range(0, len(th), chunk):
        t = th[c0:c0 + chunk][:, None]  # (m, 1)
        m = len(t)
        s1 = A[0] * np.sin(t + phi[0])
        s2 = A[1] * np.sin(t + phi[1])
        sv = A[2] * np.sin(t + phi[2])
        hpt = u.Hm[i] * A[2] * np.sin(t + phi[2] + u.Ha[i])
        mu3 = aL[2] + sv  # (m, 1)
        # (m, Nr) offsets of the other variables
        mu1 = aL[0] + s1 + r1[None, :]
        mu2 = aL[1] + s2 + r2[None, :]
        muw = hpt + rw[None, :]
        bias = u.bias[i]
        if s3 == 0:
            a3 = np.broadcast_to(mu3, mu1.shape)
            g = _g(P, e, mu1, mu2, a3, muw, bias)
            total += float(((g * W[None, :]).sum(1) * wth[c0:c0 + chunk]).sum())
            continue

        def at(z):
            # z (m, Nr, K): the signals
            a3 = mu3[:, :, None] + s3 * z
            a1 = mu1[:, :, None] + b1 * s3 * z
            a2 = mu2[:, :, None] + b2 * s3 * z
            hp3 = muw[:, :, None] + bw * s3 * z
            return a1, a2, a3, hp3

        shape = (m, len(W))
        edges = [np.broadcast_to(zu, shape + (len(zu),))]
        zk = np.clip(-mu3 / s3, -Q.z_max, Q.z_max)  # (m, 1)
        edges.append(np.broadcast_to(zk[:, :, None], shape + (1,)))
        if math.isfinite(e["R"]):
            for level in (e["R"], -e["R"]):
                def F(z, level=level):
                    a1, a2, a3, hp3 = at(z)
                    return _y(P, e, a1, a2, a3, hp3, bias) - level
                edges.append(_crossings(F, -Q.z_max, Q.z_max, 160, shape))
        Ez = np.sort(np.concatenate(edges, -1), -1)
        z, wz = _gl_panels(Ez, Q.z_nodes)
        z = z.reshape(shape + (-1,))
        wz = wz.reshape(shape + (-1,)) * np.exp(-0.5 * z * z) / math.sqrt(TWO_PI)
        a1, a2, a3, hp3 = at(z)
        g = _g(P, e, a1, a2, a3, hp3, bias)
        inner = (g * wz).sum(-1)  # (m, Nr)
        total += float(((inner * W[None, :]).sum(1) * wth[c0:c0 + chunk]).sum())
    return total


def still_g(P, u, rows):
    """g at rest (no vibration, no heating bias, HP of a constant = 0)."""
    aL = u.aL[rows]
    return _g(P, u.e, aL[:, 0], aL[:, 1], aL[:, 2], 0.0, 0.0)


def ve(P, tab, eff, rate=FILTER_RATE_HZ, Q=Quad):
    """The measured VE of every row (g) with the hidden effects `eff`."""
    u = unit_view(tab, eff, rate)
    out = np.zeros(tab.n)
    tone_only = np.nonzero(u.has_tone & ~u.has_rand)[0]
    out[tone_only] = tone_means(P, u, tone_only, Q)
    for i in np.nonzero(u.has_rand)[0]:
        out[i] = random_mean(P, u, i, Q)
    none = ~u.has_tone & ~u.has_rand
    rows = np.arange(tab.n)
    out[none] = still_g(P, u, rows[none])
    return out - still_g(P, u, rows)


PATH_EFFECTS = ("sensor_error", "mount_resonance")


def lab_composition(P, tab, eff, rate=FILTER_RATE_HZ):
    """docs/lab.md "The prediction": the base VE under the true vibration through the
    path (sensor, mount), plus each other effect's change under that vibration, alone."""
    path = {k: v for k, v in eff.items() if k in PATH_EFFECTS}
    base = ve(P, tab, path, rate)
    total = base.copy()
    for k, v in eff.items():
        if k in PATH_EFFECTS:
            continue
        one = dict(path)
        one[k] = v
        total += ve(P, tab, one, rate) - base
    return total


# --------------------------------------------------------------------------- closed forms


def _even_moment_sin(j):
    """E[sin^j] for theta uniform."""
    return 0.0 if j % 2 else math.comb(j, j // 2) / 2.0**j


def _even_moment_gauss(k):
    return 0.0 if k % 2 else float(np.prod(np.arange(k - 1, 0, -2))) if k else 1.0


def closed_ve(P, aL, A, ph31, ph32, C):
    """MODEL.md section 6, term by term (one tone with IA-OA, IA-PA phases, Gaussian)."""
    aL3 = aL[2]
    A3 = A[2]
    s3 = math.sqrt(C[2, 2])
    total = 0.0
    for n, kn in ((2, P.k2), (3, P.k3), (4, P.k4), (5, P.k5)):
        m = 0.0
        for i in range(n + 1):
            for j in range(n - i + 1):
                k = n - i - j
                m += (math.factorial(n) / (math.factorial(i) * math.factorial(j) * math.factorial(k))
                      * aL3**i * A3**j * _even_moment_sin(j) * s3**k * _even_moment_gauss(k))
        total += kn * (m - aL3**n)
    total += P.m31 * (0.5 * A3 * A[0] * math.cos(ph31) + C[2, 0])
    total += P.m32 * (0.5 * A3 * A[1] * math.cos(ph32) + C[2, 1])
    total += 0.5 * P.k1 * P.d1a * (abs_mean(aL3, A3, s3) - abs(aL3))
    return total


def abs_mean(aL, A, s):
    """E|aL + A sin(theta) + x|, x ~ N(0, s^2) (MODEL.md section 6)."""
    if s == 0:
        if abs(aL) >= A:
            return abs(aL)
        return (2 / math.pi) * (aL * math.asin(aL / A) + math.sqrt(A * A - aL * aL))

    def folded(mu):
        return s * math.sqrt(2 / math.pi) * math.exp(-mu * mu / (2 * s * s)) + mu * (
            1 - 2 * special.ndtr(-mu / s))
    if A == 0:
        return folded(aL)
    v, _ = integrate.quad(lambda t: folded(aL + A * math.sin(t)), 0, TWO_PI,
                          epsabs=0, epsrel=2e-14, limit=400)
    return v / TWO_PI


def published_ve(P, aL3, aB3, aB1=0.0, aB2=0.0, sigma3=0.0, K31=0.0, K32=0.0, d1a=True):
    """MODEL.md section 5 ([P1 (13)-(16)]), deterministic plus random parts."""
    da = P.d1a if d1a else 0.0
    det = (0.637 * P.k1 * da * aB3 + 0.5 * P.k2 * aB3**2 + 0.375 * P.k4 * aB3**4
           + 0.5 * P.m31 * aB3 * aB1 + 0.5 * P.m32 * aB3 * aB2
           + (1.5 * P.k3 * aB3**2 + 1.875 * P.k5 * aB3**4) * aL3
           + 3 * P.k4 * aB3**2 * aL3**2 + 5 * P.k5 * aB3**2 * aL3**3)
    rnd = (0.125 * P.k1 * da * sigma3 + P.k2 * sigma3**2 + P.k4 * sigma3**4
           + P.m31 * K31 + P.m32 * K32
           + (3 * P.k3 * sigma3**2 + 5 * P.k5 * sigma3**4) * aL3
           + 6 * P.k4 * sigma3**2 * aL3**2 + 10 * P.k5 * sigma3**2 * aL3**3)
    return det, rnd


# --------------------------------------------------------------------------- table rows


def tone_row(rid, aL, f, aB, ph31=0.0, ph32=0.0, T=300.0):
    return {"run_id": rid, "aL1_g": aL[0], "aL2_g": aL[1], "aL3_g": aL[2], "freq_hz": f,
            "aB1_g": aB[0], "aB2_g": aB[1], "aB3_g": aB[2], "phase31_deg": ph31,
            "phase32_deg": ph32, "vibrating_s": T}


def random_row(rid, aL, sig, cov31, cov32, band, T=300.0, tone=None):
    r = {"run_id": rid, "aL1_g": aL[0], "aL2_g": aL[1], "aL3_g": aL[2],
         "sigma1_g": sig[0], "sigma2_g": sig[1], "sigma3_g": sig[2], "cov31_g2": cov31,
         "cov32_g2": cov32, "band_lo_hz": band[0], "band_hi_hz": band[1], "vibrating_s": T}
    if tone:
        f, aB, ph31, ph32 = tone
        r.update({"freq_hz": f, "aB1_g": aB[0], "aB2_g": aB[1], "aB3_g": aB[2],
                  "phase31_deg": ph31, "phase32_deg": ph32})
    return r


def write_csv(path, rows, passport="AL-15"):
    def cell(v):
        if v is None:
            return ""
        if isinstance(v, str):
            return v
        return repr(float(v))
    with open(path, "w") as f:
        f.write(",".join(COLUMNS) + "\n")
        for r in rows:
            out = []
            for c in COLUMNS:
                if c == "passport":
                    out.append(passport)
                else:
                    out.append(cell(r.get(c)))
            f.write(",".join(out) + "\n")


def model_toml(eff):
    lines = ['format = "vibrocomp-model/1"', 'mode = "exact"', 'passport = "AL-15"']
    for k, v in eff.items():
        lines.append("[[effect]]")
        lines.append(f'kind = "{k}"')
        for name, val in v.items():
            lines.append(f"{name} = {float(val)!r}")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- selfcheck


def _rel(a, b):
    return abs(a - b) / max(abs(b), 1e-300)


def selfcheck_closed(P, report):
    """(a) the base model against MODEL.md's closed forms."""
    worst = 0.0
    lines = []
    cases = [
        # aL, A, ph31, ph32 (deg), sigmas, cov31, cov32
        ((0, 0, 1.0), (0, 0, 2.0), 0, 0, (0, 0, 0), 0, 0),
        ((0, 0, -1.0), (0, 0, 0.5), 0, 0, (0, 0, 0), 0, 0),
        ((0, 0, 10.0), (0, 0, 0.42), 0, 0, (0, 0, 0), 0, 0),
        ((0.3, 0.2, 0.0), (1.2, 0.8, 3.0), 25, -70, (0, 0, 0), 0, 0),
        ((0, 0, 1.0), (0, 0, 0), 0, 0, (0, 0, 1.5), 0, 0),
        ((0, 0, -0.4), (0, 0, 0), 0, 0, (0.7, 0, 0.7), 0.49, 0),
        ((1.0, 0, 0.0), (0, 0, 0), 0, 0, (0, 1.1, 1.1), 0, 1.21),
        ((0, 0, 0.5), (0.4, 0.9, 1.7), 40, 110, (0.3, 0.5, 0.8), 0.1, -0.2),
        ((0, 0, 2.0), (0, 0, 1.0), 0, 0, (0, 0, 0.3), 0, 0),
    ]
    for aL, A, p31, p32, sg, c31, c32 in cases:
        rows = []
        if any(sg):
            rows.append(random_row("x", aL, sg, c31, c32, (20, 500),
                                   tone=(40.0, A, p31, p32) if any(A) else None))
        else:
            rows.append(tone_row("x", aL, 40.0, A, p31, p32))
        tab = Table(rows)
        got = ve(P, tab, {})[0]
        want = closed_ve(P, np.array(aL, float), np.array(A, float), math.radians(p31),
                         math.radians(p32), tab.C[0])
        r = _rel(got, want)
        worst = max(worst, r)
        lines.append(f"  aL {aL} tone {A} ph ({p31},{p32}) sigma {sg} cov ({c31},{c32}): "
                     f"generator {got:.15e} closed {want:.15e} rel {r:.1e}")
    # the k2 term alone: VE = k2 aB^2/2 for a pure tone, k2 sigma^2 for the random part
    only_k2 = P.with_(d1a=0, k3=0, k4=0, k5=0, m31=0, m32=0)
    for aL3, A in ((1.0, 2.0), (-1.0, 0.5), (0.0, 3.0)):
        got = ve(only_k2, Table([tone_row("x", (0, 0, aL3), 80.0, (0, 0, A))]), {})[0]
        want = 0.5 * P.k2 * A * A
        r = _rel(got, want)
        worst = max(worst, r)
        lines.append(f"  k2 alone, aL3 {aL3} aB3 {A}: {got:.15e} vs k2 aB^2/2 {want:.15e} rel {r:.1e}")
    # the published formulas (section 5) where they are exact: the polynomial terms
    # of a tone (d1A out, cross terms in phase); the random part with MODEL.md 6's
    # corrections 3 k4 sigma^4 and 15 k5 sigma^4
    nod = P.with_(d1a=0.0)
    for aL3, A3, A1, A2 in ((10.0, 0.42, 0.8, 1.5), (1.0, 2.0, 0.0, 0.0), (-1.0, 3.0, 1.0, 0.0)):
        got = ve(nod, Table([tone_row("x", (0, 0, aL3), 40.0, (A1, A2, A3))]), {})[0]
        det, _ = published_ve(nod, aL3, A3, A1, A2, d1a=False)
        r = _rel(got, det)
        worst = max(worst, r)
        lines.append(f"  published tone aL3 {aL3} aB (1,2,3) ({A1},{A2},{A3}), d1A out: "
                     f"{got:.15e} vs {det:.15e} rel {r:.1e}")
    for aL3, s3, s1, K31 in ((1.0, 1.5, 0.0, 0.0), (-2.0, 0.8, 0.6, 0.3)):
        sg = (s1, 0.0, s3)
        got = ve(nod, Table([random_row("x", (0, 0, aL3), sg, K31, 0.0, (20, 500))]), {})[0]
        _, rnd = published_ve(nod, aL3, 0.0, sigma3=s3, K31=K31, d1a=False)
        rnd += 2 * P.k4 * s3**4 + 10 * P.k5 * s3**4 * aL3
        r = _rel(got, rnd)
        worst = max(worst, r)
        lines.append(f"  published random aL3 {aL3} sigma3 {s3} K31 {K31} (+2 k4 s^4 + 10 k5 s^4 aL3), "
                     f"d1A out: {got:.15e} vs {rnd:.15e} rel {r:.1e}")
    # [P1 Table 4]: components 13.39 ug + 0.2307 + 0.5292 + 0.7938 mg = 1.5671 mg, and
    # with the cross terms at aB1 = aB2 = 0.8 g (1.95 ug each) the total 1.571 mg
    det0, _ = published_ve(P, 10.0, 0.42)
    det, _ = published_ve(P, 10.0, 0.42, 0.8, 0.8)
    ex = ve(P, Table([tone_row("x", (0, 0, 10.0), 40.0, (0.8, 0.8, 0.42))]), {})[0]
    lines.append(f"  [P1 Table 4] as published: components {det0 * 1e3:.4f} mg (paper 1.5671), total with "
                 f"aB1 = aB2 = 0.8 g {det * 1e3:.4f} mg (paper 1.571); exact (generator) {ex * 1e3:.4f} mg "
                 f"(the 0.637 d1A aB3 = {0.637 * P.d1a * 0.42 * 1e6:.2f} ug term is 0 exactly: aB3 < aL3)")
    ok = worst <= 1e-12 and abs(det0 * 1e3 - 1.5671) < 5e-5 and abs(det * 1e3 - 1.571) < 5e-4
    report["closed_forms"] = {"worst_rel": worst, "table4_mg": det * 1e3, "table4_exact_mg": ex * 1e3, "ok": ok}
    print(f"(a) base model against MODEL.md's closed forms: worst relative difference {worst:.1e} "
          f"({'ok' if ok else 'FAIL'}, limit 1e-12)")
    for line in lines:
        print(line)
    return ok


def _fp_nonlin(P, a1, a2, a3):
    """(FP) minus its linear part, written again for the Monte Carlo."""
    return (0.5 * P.k1 * P.d1a * np.abs(a3) + P.k2 * a3**2 + P.k3 * a3**3 + P.k4 * a3**4
            + P.k5 * a3**5 + P.m31 * a3 * a1 + P.m32 * a3 * a2)


def _fp(P, a1, a2, a3):
    return P.a0 + P.k1 * a3 + P.m1 * a1 + P.m2 * a2 + _fp_nonlin(P, a1, a2, a3)


def _band_noise(rng, n, fs, lo, hi, k):
    """k independent periodic records of n samples whose spectrum is flat over
    [lo, hi] Hz with unit variance: every FFT bin in the band at the same amplitude with
    a uniform random phase (a random-phase multisine: Gaussian in the limit of many
    bins, its variance and spectrum exact in every record)."""
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    inb = (freqs >= lo) & (freqs <= hi)
    K = int(inb.sum())
    X = np.zeros((k, len(freqs)), complex)
    X[:, inb] = np.exp(1j * rng.uniform(0, TWO_PI, (k, K)))
    x = np.fft.irfft(X, n, axis=1)
    return x / (math.sqrt(2.0 * K) / n)


def _mc_iid(P, eff_kind, params, cond, n, rng, batches=20):
    """Monte Carlo of one effect's VE change: iid draws of the phase and the Gaussian
    part; common random numbers; per-batch changes. Returns (mean, standard error)."""
    aL, A, phi, C = cond
    L = np.linalg.cholesky(C + 1e-300 * np.eye(3)) if np.all(np.linalg.eigvalsh(C) > 0) else None
    if L is None:
        lam, V = np.linalg.eigh(C)
        L = V * np.sqrt(np.clip(lam, 0, None))
    per = n // batches
    out = []
    for _ in range(batches):
        th = rng.uniform(0, TWO_PI, per)
        x = rng.normal(size=(per, 3)) @ L.T
        a = [aL[i] + A[i] * np.sin(th + phi[i]) + x[:, i] for i in range(3)]
        y0 = _fp(P, *a)
        s0 = _fp(P, *aL)
        if eff_kind == "high_order_nonlinearity":
            k6 = params["k6_ppm_per_g5"] * 1e-6
            k7 = params["k7_ppm_per_g6"] * 1e-6
            d = k6 * a[2] ** 6 + k7 * a[2] ** 7
            ds = k6 * aL[2] ** 6 + k7 * aL[2] ** 7
        elif eff_kind == "saturation":
            R = params["range_g"]
            d = np.clip(y0, -R, R) - y0
            ds = np.clip(s0, -R, R) - s0
        elif eff_kind == "anisoelastic":
            d = params["k_ae_per_g"] * a[0] * a[1]
            ds = params["k_ae_per_g"] * aL[0] * aL[1]
        elif eff_kind == "axis_phase":
            # the linear part of (FP) has mean L(aL) with or without the offsets: left
            # out of the difference (a control variate)
            dph = np.radians([params["phase_x_deg"], params["phase_y_deg"], params.get("phase_z_deg", 0.0)])
            b = [aL[i] + A[i] * np.sin(th + phi[i] + dph[i]) + x[:, i] for i in range(3)]
            d = _fp_nonlin(P, *b) - _fp_nonlin(P, *a)
            ds = 0.0
        else:
            raise ValueError(eff_kind)
        out.append(np.mean(d) - ds)
    out = np.array(out)
    return out.mean(), out.std(ddof=1) / math.sqrt(batches)


def _digital(b, a, fs, prewarp_hz=None):
    """scipy's bilinear transform of the analog b(s)/a(s), prewarped at prewarp_hz."""
    if prewarp_hz:
        w = TWO_PI * prewarp_hz
        fs_eff = w / (2.0 * math.tan(w / (2.0 * fs)))
    else:
        fs_eff = fs
    return signal.bilinear(b, a, fs_eff)


def _periodic_filter(bz, az, x):
    """The steady-state response of a periodic record (filter two periods, keep the
    second)."""
    y = signal.lfilter(bz, az, np.concatenate([x, x], -1), axis=-1)
    return y[..., x.shape[-1]:]


def _mc_time_domain(P, kind, params, cfg, rng, records=8, n=1 << 17, fs=FILTER_RATE_HZ):
    """Monte Carlo of a filtering effect in the time domain: periodic records of a tone
    on an FFT bin plus flat band noise, filtered by lfilter (scipy's bilinear), the
    output's mean with the effect minus without. Returns (mean, standard error) and the
    stated condition for the generator."""
    aL, f_req, A, phi, C, band = cfg
    k = max(1, round(f_req * n / fs))
    f = k * fs / n
    t = np.arange(n) / fs
    res = []
    for _ in range(records):
        v = np.zeros((3, n))
        if f_req:
            for i in range(3):
                v[i] += A[i] * np.sin(TWO_PI * f * t + phi[i])
        if C is not None:
            lam, V = np.linalg.eigh(C)
            L = V * np.sqrt(np.clip(lam, 0, None))
            z = _band_noise(rng, n, fs, band[0], band[1], 3)
            v += L @ z
        a = [aL[i] + v[i] for i in range(3)]
        y0 = _fp(P, *a)
        if kind == "mount_resonance":
            wn = TWO_PI * params["freq_hz"]
            zeta = 1.0 / (2.0 * params["q"])
            bz, az = _digital([2 * zeta * wn, wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs, params["freq_hz"])
            vu = _periodic_filter(bz, az, v)
            y1 = _fp(P, *[aL[i] + vu[i] for i in range(3)])
        elif kind == "vibropendulous":
            tau = params["tau_s"]
            bz, az = _digital([tau, 0.0], [tau, 1.0], fs)
            hp = _periodic_filter(bz, az, v[2])
            y1 = y0 + params["c_rad_per_g"] * hp * a[1]
        else:
            raise ValueError(kind)
        res.append(np.mean(y1 - y0))
    res = np.array(res)
    return res.mean(), res.std(ddof=1) / math.sqrt(records), f


def _mc_heating(P, params, rng, records=4, fs=2048.0, T=300.0):
    """The thermal lag integrated exactly over each sample (exponential integrator) from
    b = 0, driven by v3^2 of a tone plus flat band noise; mean bias over the record."""
    c, tau = params["c_g_per_g2"], params["tau_s"]
    n = int(T * fs)
    t = np.arange(n) / fs
    A3, f, s3, band = 1.5, 40.0, 0.8, (20.0, 500.0)
    h = 1.0 / fs
    decay = math.exp(-h / tau)
    res = []
    for _ in range(records):
        v3 = A3 * np.sin(TWO_PI * f * t + rng.uniform(0, TWO_PI)) + s3 * _band_noise(rng, n, fs, *band, 1)[0]
        drive = c * v3**2
        # b_{k+1} = decay b_k + (1 - decay) drive_k: a first-order IIR filter
        b = signal.lfilter([1.0 - decay], [1.0, -decay], drive)
        bprev = np.concatenate([[0.0], b[:-1]])
        # mean over each sample interval of the exact solution with drive held
        mean_k = drive + (bprev - drive) * tau / h * (1.0 - decay)
        res.append(mean_k.mean())
    res = np.array(res)
    cond = tone_row("h", (0, 0, 1.0), f, (0, 0, A3))
    cond.update({"sigma1_g": 0.0, "sigma2_g": 0.0, "sigma3_g": s3, "cov31_g2": 0.0,
                 "cov32_g2": 0.0, "band_lo_hz": band[0], "band_hi_hz": band[1], "vibrating_s": T})
    return res.mean(), res.std(ddof=1) / math.sqrt(records), cond


def selfcheck_mc(P, report, n, rng):
    """(b) each effect alone against a Monte Carlo of its hooks."""
    print(f"(b) each effect alone against a Monte Carlo ({n:.0e} samples a case; z = (generator - MC) / MC's standard error):")
    results = {}
    ok_all = True
    iid_cases = {
        "high_order_nonlinearity": ({"k6_ppm_per_g5": 0.05, "k7_ppm_per_g6": 0.01},
                                    ((0, 0, 1.0), (0, 0, 2.0), (0, 0, 0), np.diag([0, 0, 0.25]))),
        "saturation": ({"range_g": 3.0},
                       ((0.3, 0, 1.0), (0.8, 0, 2.0), (0.4, 0, 0), np.array([[0.09, 0, 0.12], [0, 0, 0], [0.12, 0, 0.25]]))),
        "anisoelastic": ({"k_ae_per_g": 2e-4},
                         ((0.5, 0.3, 1.0), (1.2, 0.8, 0.5), (0.0, 0.5, 0.0), np.diag([0.25, 0.16, 0.09]))),
        "axis_phase": ({"phase_x_deg": 60.0, "phase_y_deg": -40.0},
                       ((0, 0, 0.5), (1.5, 2.0, 2.0), (0.0, 0.0, 0.0), np.diag([0.0, 0.0, 0.0]))),
    }
    for kind, (params, (aL, A, phi, C)) in iid_cases.items():
        aL, A, phi = np.array(aL, float), np.array(A, float), np.array(phi, float)
        mc, se = _mc_iid(P, kind, params, (aL, A, phi, C), n, rng)
        # the generator: the table states phase31 = phi3 - phi1 (deg), phase32
        ph31 = math.degrees(phi[2] - phi[0])
        ph32 = math.degrees(phi[2] - phi[1])
        if np.any(C):
            row = random_row("x", aL, np.sqrt(np.diag(C)), C[2, 0], C[2, 1], (20, 500),
                             tone=(40.0, A, ph31, ph32))
        else:
            row = tone_row("x", aL, 40.0, A, ph31, ph32)
        tab = Table([row])
        if kind == "anisoelastic" and C[0, 1]:
            raise ValueError("no cov12 in the table")
        gen = ve(P, tab, {kind: params})[0] - ve(P, tab, {})[0]
        z = (gen - mc) / se
        ok = abs(z) < 4 and abs(gen) > 10 * se
        ok_all &= ok
        results[kind] = {"generator_g": gen, "mc_g": mc, "se_g": se, "z": z, "ok": ok}
        print(f"  {kind:24s} generator {gen:+.6e} g  MC {mc:+.6e} +- {se:.1e} g  z {z:+.2f}  {'ok' if ok else 'FAIL'}")
    # sensor_error: the unit under the true vibration; the table states what the IA
    # sensor measured from the same samples, (1 + g) times the truth
    g = 0.03
    aL = np.array([0.0, 0.0, 1.0])
    A3, s3, s1, c31 = 2.0, 0.8, 0.5, 0.2
    C = np.array([[s1 * s1, 0, c31], [0, 0, 0], [c31, 0, s3 * s3]])
    lam, V = np.linalg.eigh(C)
    L = V * np.sqrt(np.clip(lam, 0, None))
    per = n // 20
    diffs, effect = [], []
    for _ in range(20):
        th = rng.uniform(0, TWO_PI, per)
        x = rng.normal(size=(per, 3)) @ L.T
        a3 = aL[2] + A3 * np.sin(th) + x[:, 2]
        a1 = x[:, 0]
        # the linear part of (FP) (mean exactly its value at aL) left out: a control variate
        mc = np.mean(_fp_nonlin(P, a1, 0 * a1, a3)) - _fp_nonlin(P, 0.0, 0.0, aL[2])
        meas3 = (1 + g) * x[:, 2]  # the IA sensor's reading of the random part
        row = random_row("x", aL, (math.sqrt(np.mean(a1**2)), 0.0, math.sqrt(np.mean(meas3**2))),
                         float(np.mean(meas3 * a1)), 0.0, (20, 500), tone=(40.0, (0, 0, (1 + g) * A3), 0.0, 0.0))
        tab = Table([row])
        gen = ve(P, tab, {"sensor_error": {"gain_error": g}})[0]
        diffs.append(gen - mc)
        effect.append(gen - ve(P, tab, {})[0])
    diffs = np.array(diffs)
    se = diffs.std(ddof=1) / math.sqrt(len(diffs))
    z = diffs.mean() / se
    size = float(np.mean(effect))
    ok = abs(z) < 4 and abs(size) > 10 * se
    ok_all &= ok
    results["sensor_error"] = {"generator_minus_mc_g": float(diffs.mean()), "se_g": se, "z": z,
                               "effect_g": size, "ok": ok}
    print(f"  {'sensor_error':24s} effect {size:+.6e} g; generator at the sensor's reading - MC mean "
          f"{diffs.mean():+.2e} +- {se:.1e} g  z {z:+.2f}  {'ok' if ok else 'FAIL'}")
    # heating
    params = {"c_g_per_g2": 2e-6, "tau_s": 1.0}
    mc, se, cond = _mc_heating(P, params, rng)
    tab = Table([cond])
    gen = ve(P, tab, {"heating": params})[0] - ve(P, tab, {})[0]
    z = (gen - mc) / se
    ok = abs(z) < 4 and abs(gen) > 10 * se
    ok_all &= ok
    results["heating"] = {"generator_g": gen, "mc_g": mc, "se_g": se, "z": z, "ok": ok}
    print(f"  {'heating':24s} generator {gen:+.6e} g  MC {mc:+.6e} +- {se:.1e} g  z {z:+.2f}  {'ok' if ok else 'FAIL'}")
    # filtering effects in the time domain
    td_cases = {
        "mount_resonance": [
            ({"freq_hz": 48.0, "q": 1.56}, ((0, 0, 1.0), 40.0, (0.5, 0.0, 2.0), (0.0, 0.0, 0.0), None, None)),
            ({"freq_hz": 48.0, "q": 1.56}, ((0, 0, -1.0), 0.0, (0, 0, 0), (0, 0, 0),
                                            np.array([[0.5, 0, 0.5], [0, 0, 0], [0.5, 0, 0.5]]), (20.0, 250.0))),
        ],
        "vibropendulous": [
            ({"c_rad_per_g": 1e-3, "tau_s": 0.002}, ((0, 0, 1.0), 120.0, (0.0, 1.5, 1.5), (0.0, 0.3, 0.0), None, None)),
            ({"c_rad_per_g": 1e-3, "tau_s": 0.002}, ((0, 0, 0.0), 0.0, (0, 0, 0), (0, 0, 0),
                                                     np.array([[0, 0, 0], [0, 1.0, 0.6], [0, 0.6, 1.0]]), (20.0, 500.0))),
        ],
    }
    for kind, cases in td_cases.items():
        for params, cfg in cases:
            aL, f_req, A, phi, C, band = cfg
            mc, se, f = _mc_time_domain(P, kind, params, cfg, rng, records=16, n=max(1 << 14, n // 8))
            if f_req:
                row = tone_row("x", aL, f, A, math.degrees(phi[2] - phi[0]), math.degrees(phi[2] - phi[1]))
            else:
                row = random_row("x", aL, np.sqrt(np.diag(C)), C[2, 0], C[2, 1], band)
            tab = Table([row])
            gen = ve(P, tab, {kind: params})[0] - ve(P, tab, {})[0]
            # a tone on a bin has no sampling error: compare relatively there
            if f_req:
                ok = abs(gen - mc) <= 1e-9 * abs(gen) + 1e-15
                how = f"rel {abs(gen - mc) / abs(gen):.1e}"
            else:
                z = (gen - mc) / se
                ok = abs(z) < 4 and abs(gen) > 10 * se
                how = f"z {z:+.2f}"
            ok_all &= ok
            what = f"tone {f:.3f} Hz" if f_req else f"band {band[0]:.0f}-{band[1]:.0f} Hz"
            results[f"{kind} ({what})"] = {"generator_g": gen, "mc_g": mc, "se_g": se, "ok": ok}
            print(f"  {kind:24s} {what}: generator {gen:+.9e} g  time domain {mc:+.9e} +- {se:.1e} g  {how}  {'ok' if ok else 'FAIL'}")
    report["monte_carlo"] = results
    return ok_all


def _bin_path(arg):
    if arg:
        return arg
    if os.environ.get("VIBROCOMP_BIN"):
        return os.environ["VIBROCOMP_BIN"]
    return str(ROOT / "target" / "debug" / "vibrocomp")


def binary_predictions(binary, rows, eff, workdir):
    """`vibrocomp lab compare TABLE [--model FILE] --json`: predicted_g per row."""
    table = Path(workdir) / "t.csv"
    rows = [dict(r, ve_measured_g=0.0, ve_uncertainty_g=1e-6) for r in rows]
    write_csv(table, rows)
    args = [binary, "lab", "compare", str(table), "--json", "-q"]
    if eff:
        model = Path(workdir) / "m.toml"
        model.write_text(model_toml(eff))
        args += ["--model", str(model)]
    out = subprocess.run(args, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: {out.stderr}")
    d = json.loads(out.stdout)
    return np.array([r["predicted_g"] for r in d["rows"]])


def check_rows():
    """A handful of conditions for the comparison with the binary."""
    rows = []
    k = 0
    for aL in ((0, 0, 1.0), (1.0, 0, 0.0), (0, 0, -1.0)):
        for f, A, d in ((25.0, 2.5, "ia"), (48.0, 1.0, "ia-oa"), (95.0, 3.0, "ia-pa"), (180.0, 2.0, "oa-pa"), (250.0, 1.5, "ia")):
            aB = {"ia": (0, 0, A), "ia-oa": (A, 0, A), "ia-pa": (0, A, A), "oa-pa": (A, A, 0)}[d]
            k += 1
            rows.append(tone_row(f"T{k}", aL, f, aB))
        for s, d, band in ((1.5, "ia", (20.0, 500.0)), (1.0, "ia-pa", (20.0, 250.0)), (2.0, "ia-oa", (100.0, 1000.0))):
            sig = {"ia": (0, 0, s), "ia-oa": (s, 0, s), "ia-pa": (0, s, s)}[d]
            c31 = s * s if d == "ia-oa" else 0.0
            c32 = s * s if d == "ia-pa" else 0.0
            k += 1
            rows.append(random_row(f"R{k}", aL, sig, c31, c32, band))
    return rows


CHECK_EFFECTS = {
    "mount_resonance": {"freq_hz": 48.0, "q": 1.56},
    "high_order_nonlinearity": {"k6_ppm_per_g5": 0.05, "k7_ppm_per_g6": 0.01},
    "saturation": {"range_g": 3.5},
    "vibropendulous": {"c_rad_per_g": 2e-4, "tau_s": 0.002},
    "anisoelastic": {"k_ae_per_g": 2e-5},
    "heating": {"c_g_per_g2": 2e-6, "tau_s": 1.0},
    "axis_phase": {"phase_x_deg": 60.0, "phase_y_deg": -40.0},
    "sensor_error": {"gain_error": 0.03},
}


def selfcheck_binary(P, report, binary):
    """(c) each effect alone against the binary's prediction (`lab compare --model`)."""
    if not Path(binary).exists():
        print(f"(c) skipped: no binary at {binary} (--bin or VIBROCOMP_BIN)")
        report["binary"] = {"skipped": binary}
        return True
    rows = check_rows()
    tab = Table(rows)
    res = {}
    with tempfile.TemporaryDirectory() as wd:
        b0 = binary_predictions(binary, rows, {}, wd)
        g0 = ve(P, tab, {})
        d = np.abs(b0 - g0)
        rel = float(d.max() / np.abs(g0).max())
        res["base"] = {"max_abs_g": float(d.max()), "max_rel_of_ve": rel}
        print(f"(c) against the binary ({binary}, `lab compare --model`) on {len(rows)} conditions "
              f"(tones 25..250 Hz along IA, IA-OA, IA-PA, OA-PA; random rows with their bands; aL3 = +1, 0, -1 g):")
        print(f"  {'base model (exact)':24s} max |binary - generator| {d.max():.2e} g, {rel:.1e} of the largest VE")
        for kind, params in CHECK_EFFECTS.items():
            b1 = binary_predictions(binary, rows, {kind: params}, wd)
            g1 = ve(P, tab, {kind: params})
            db = b1 - b0
            dg = g1 - g0
            diff = np.abs(db - dg)
            scale = float(np.max(np.abs(dg)))
            rel_eff = float(diff.max() / scale) if scale else float("inf")
            rel_ve = float(diff.max() / np.abs(g1).max())
            worst = int(np.argmax(diff))
            agree = rel_eff <= 1e-6
            res[kind] = {"params": params, "max_abs_g": float(diff.max()), "max_rel_of_effect": rel_eff,
                         "max_rel_of_ve": rel_ve, "effect_max_g": scale, "worst_row": rows[worst]["run_id"],
                         "agree_1e-6": agree,
                         "per_row": [{"run_id": r["run_id"], "binary_change_g": float(x), "generator_change_g": float(y)}
                                     for r, x, y in zip(rows, db, dg)]}
            print(f"  {kind:24s} effect up to {scale:.3e} g; max |binary - generator| {diff.max():.2e} g = "
                  f"{rel_eff:.1e} of the effect's largest change, {rel_ve:.1e} of the largest VE (row {rows[worst]['run_id']})"
                  f"  {'agree' if agree else 'DISAGREE (> 1e-6)'}")
    report["binary"] = res
    return True


def selfcheck_rates(P, report):
    """How much the filters' discretisation matters (module doc, ambiguities 2 and 3)."""
    rows = [tone_row("a", (0, 0, 1.0), 250.0, (0, 2.0, 2.0)), tone_row("b", (0, 0, 1.0), 100.0, (0, 2.0, 2.0))]
    tab = Table(rows)
    g0 = ve(P, tab, {})
    out = {}
    for kind, params in (("mount_resonance", {"freq_hz": 48.0, "q": 1.56}),
                         ("vibropendulous", {"c_rad_per_g": 2e-4, "tau_s": 0.002})):
        d = ve(P, tab, {kind: params}) - g0
        a = ve(P, tab, {kind: params}, rate=math.inf) - g0
        rel = np.abs(d - a) / np.abs(d)
        out[kind] = {"rel_250hz": float(rel[0]), "rel_100hz": float(rel[1])}
        print(f"  {kind}: digital (25600 Hz) against analog: {rel[1]:.1e} of the effect at 100 Hz, {rel[0]:.1e} at 250 Hz")
    report["discretisation"] = out


def cmd_selfcheck(args):
    P = Passport()
    rng = np.random.default_rng(args.seed)
    report = {}
    t0 = time.time()
    ok = selfcheck_closed(P, report)
    ok &= selfcheck_mc(P, report, args.mc_samples, rng)
    selfcheck_binary(P, report, _bin_path(args.bin))
    print("(d) the filters' discretisation (docs/effects.md: digital at the simulator's rate):")
    selfcheck_rates(P, report)
    report["seconds"] = time.time() - t0
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1, default=float))
    print(f"selfcheck {'passed' if ok else 'FAILED'} in {time.time() - t0:.1f} s")
    return 0 if ok else 1


# --------------------------------------------------------------------------- battery


DIRS = {
    "ia": lambda A: (0.0, 0.0, A),
    "ia-oa-45": lambda A: (A, 0.0, A),
    "ia-pa-45": lambda A: (0.0, A, A),
    "oa-pa-45": lambda A: (A, A, 0.0),
}
ORIENT = {"up": (0.0, 0.0, 1.0), "horizontal": (1.0, 0.0, 0.0), "down": (0.0, 0.0, -1.0)}
BANDS = ((20.0, 250.0), (20.0, 500.0), (50.0, 1000.0), (100.0, 2000.0))


def design(rng, n_rows, T=300.0):
    """The separating campaign (45 deg rows scaled by sqrt 2: both axes get the
    amplitude): tones 20..250 Hz at 0.5..3 g along IA (40 %), IA-OA, IA-PA, OA-PA
    (20 % each) in three orientations; 12 % random rows 0.5..2 g RMS along IA, IA-OA,
    IA-PA over a stated flat band."""
    rows = []
    n_rand = max(3, round(0.12 * n_rows))
    n_tone = n_rows - n_rand
    dirs = ["ia", "ia", "ia-oa-45", "ia-pa-45", "oa-pa-45"]
    orients = list(ORIENT)
    for k in range(n_tone):
        d = dirs[k % len(dirs)]
        o = orients[(k // len(dirs)) % 3]
        f = float(np.exp(rng.uniform(math.log(20.0), math.log(250.0))))
        A = float(rng.uniform(0.5, 3.0))
        rows.append(tone_row(f"T{k + 1:03d}", ORIENT[o], round(f, 3), tuple(round(x, 4) for x in DIRS[d](A))))
        rows[-1]["_dir"] = d
    rdirs = ["ia", "ia-oa-45", "ia-pa-45"]
    for k in range(n_rand):
        d = rdirs[k % 3]
        o = orients[(k // 3) % 3]
        s = round(float(rng.uniform(0.5, 2.0)), 4)
        band = BANDS[int(rng.integers(len(BANDS)))]
        sig = {"ia": (0.0, 0.0, s), "ia-oa-45": (s, 0.0, s), "ia-pa-45": (0.0, s, s)}[d]
        rows.append(random_row(f"R{k + 1:03d}", ORIENT[o], sig, s * s if d == "ia-oa-45" else 0.0,
                               s * s if d == "ia-pa-45" else 0.0, band, T))
        rows[-1]["_dir"] = d
    return rows


def design_one_frequency_ia(rng, n_rows, f=40.0):
    """Confounded: one tone frequency, along IA only, 0.5..3 g, three orientations."""
    rows = []
    orients = list(ORIENT.values())
    for k in range(n_rows):
        A = round(float(rng.uniform(0.5, 3.0)), 4)
        rows.append(tone_row(f"T{k + 1:03d}", orients[k % 3], f, (0.0, 0.0, A)))
    return rows


def design_one_frequency_ia_pa(rng, n_rows, f=80.0):
    """Confounded: one tone frequency, IA-PA at 45 deg and IA alone, three orientations."""
    rows = []
    orients = list(ORIENT.values())
    for k in range(n_rows):
        A = round(float(rng.uniform(0.5, 3.0)), 4)
        d = (0.0, A, A) if k % 2 == 0 else (0.0, 0.0, A)
        rows.append(tone_row(f"T{k + 1:03d}", orients[(k // 2) % 3], f, d))
    return rows


def draw_params(kind, rng):
    """Realistic parameters (docs/lab.md "What the tests show")."""
    sgn = lambda: float(rng.choice([-1.0, 1.0]))
    lu = lambda a, b: float(np.exp(rng.uniform(math.log(a), math.log(b))))
    if kind == "mount_resonance":
        return {"freq_hz": lu(30.0, 160.0), "q": float(rng.uniform(1.2, 4.0))}
    if kind == "high_order_nonlinearity":
        k7 = sgn() * lu(0.002, 0.03) if rng.uniform() < 0.5 else 0.0
        return {"k6_ppm_per_g5": sgn() * lu(0.02, 0.2), "k7_ppm_per_g6": k7}
    if kind == "saturation":
        return {"range_g": float(rng.uniform(3.0, 6.0))}
    if kind == "vibropendulous":
        return {"c_rad_per_g": sgn() * lu(5e-5, 5e-4), "tau_s": lu(5e-4, 5e-3)}
    if kind == "anisoelastic":
        return {"k_ae_per_g": sgn() * lu(5e-6, 5e-5)}
    if kind == "heating":
        return {"c_g_per_g2": sgn() * lu(5e-7, 5e-6), "tau_s": 1.0}
    if kind == "axis_phase":
        return {"phase_x_deg": sgn() * float(rng.uniform(20, 90)), "phase_y_deg": sgn() * float(rng.uniform(20, 90))}
    if kind == "sensor_error":
        return {"gain_error": sgn() * float(rng.uniform(0.01, 0.05))}
    raise ValueError(kind)


# how each effect's strength is turned: a linear knob (scale these keys), or a
# one-dimensional monotone one
LINEAR_KNOB = {
    "high_order_nonlinearity": ("k6_ppm_per_g5", "k7_ppm_per_g6"),
    "vibropendulous": ("c_rad_per_g",),
    "anisoelastic": ("k_ae_per_g",),
    "heating": ("c_g_per_g2",),
    "sensor_error": ("gain_error",),
}
# plausibility caps on the scaled parameters (and the lab's bounds)
CAPS = {
    "k6_ppm_per_g5": 5.0, "k7_ppm_per_g6": 1.0, "c_rad_per_g": 5e-3, "k_ae_per_g": 1e-3,
    "c_g_per_g2": 1e-4, "gain_error": 0.3,
}


def _scaled(params, kind, s):
    p = dict(params)
    if kind in LINEAR_KNOB:
        for k in LINEAR_KNOB[kind]:
            p[k] = params[k] * s
    elif kind == "axis_phase":
        for k in ("phase_x_deg", "phase_y_deg"):
            p[k] = params[k] * s
    elif kind == "saturation":
        p["range_g"] = params["range_g"] * s
    return p


def _within_caps(kind, p):
    for k, v in p.items():
        if k in CAPS and abs(v) > CAPS[k]:
            return False
    if kind == "axis_phase" and max(abs(p["phase_x_deg"]), abs(p["phase_y_deg"])) > 170:
        return False
    if kind == "saturation" and not 1.5 <= p["range_g"] <= 30:
        return False
    return True


def lab_truth(kind, p, T):
    """The parameters the lab fits, by its library's names."""
    if kind == "heating":
        c, tau = p["c_g_per_g2"], p["tau_s"]
        return {"c_g_per_g2": c * (1.0 - tau / T * (-math.expm1(-T / tau)))}
    return {k: p[k] for k in LAB_PARAMS[kind]}


def marginal_changes(P, tab, eff):
    """Each effect's marginal VE change in the member (joint minus joint without it)."""
    joint = ve(P, tab, eff)
    out = {}
    for k in eff:
        rest = {kk: vv for kk, vv in eff.items() if kk != k}
        out[k] = joint - ve(P, tab, rest)
    return joint, out


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def _jacobian_cols(P, tab, eff, kind, base):
    """Finite-difference columns of the joint VE in `kind`'s lab parameters."""
    cols = []
    for name in LAB_PARAMS[kind]:
        e2 = {k: dict(v) for k, v in eff.items()}
        p = e2[kind]
        v = p.get(name, 0.0)
        if kind == "heating":
            name_p = "c_g_per_g2"
            v = p[name_p]
        else:
            name_p = name
        h = 1e-4 * (abs(v) if v else {"k7_ppm_per_g6": 1e-3, "phase_x_deg": 1.0, "phase_y_deg": 1.0}.get(name, 1e-6))
        if kind == "axis_phase":
            h = 0.5
        p[name_p] = v + h
        cols.append((ve(P, tab, e2) - base) / h)
    return cols


def unique_chi2(P, tab, eff, u, kind, change, joint):
    """chi2 of `kind`'s change left after the other effects' parameters absorb what
    they can (weighted least squares on their Jacobian columns)."""
    cols = []
    for k in eff:
        if k != kind:
            cols += _jacobian_cols(P, tab, eff, k, joint)
    y = change / u
    if not cols:
        return float(y @ y)
    J = np.stack(cols, 1) / u[:, None]
    coef, *_ = np.linalg.lstsq(J, y, rcond=None)
    r = y - J @ coef
    return float(r @ r)


def draw_member(P, kinds, rng, n_rows, name, max_tries=40):
    """Draws a member: design, parameters with a strength ratio, noise. The weakest
    effect must be detectable: its chi2 sum((dVE/u)^2) at least 100, and so is what is
    left of it after the other effects' parameters absorb what they can (weighted least
    squares on their Jacobian columns, `unique_chi2`); else the member is drawn again."""
    for attempt in range(max_tries):
        rows = design(rng, n_rows)
        tab = Table(rows)
        u0 = float(np.exp(rng.uniform(math.log(0.3e-6), math.log(2e-6))))
        u = u0 * rng.uniform(0.8, 1.25, tab.n)
        eff = {k: draw_params(k, rng) for k in kinds}
        # the anchor keeps its drawn strength; the others are turned to their targets
        order = [k for k in ("mount_resonance", "saturation", "axis_phase") if k in kinds]
        anchor = order[0] if order else kinds[0]
        R = float(np.exp(rng.uniform(0.0, math.log(1000.0))))
        logs = [0.0, math.log(R)] if len(kinds) == 2 else [0.0, float(rng.uniform(0, math.log(R))), math.log(R)]
        rng.shuffle(logs)
        target_rel = dict(zip(kinds, logs))
        ok = True
        for _ in range(4):  # strengths interact (saturation): iterate
            joint, ch = marginal_changes(P, tab, eff)
            S = {k: _rms(ch[k]) for k in kinds}
            if S[anchor] == 0:
                ok = False
                break
            for k in kinds:
                if k == anchor:
                    continue
                want = S[anchor] * math.exp(target_rel[k] - target_rel[anchor])
                if S[k] == 0:
                    ok = False
                    break
                ratio = want / S[k]
                if k in LINEAR_KNOB:
                    eff[k] = _scaled(eff[k], k, ratio)
                elif k == "axis_phase":
                    # strength ~ 1 - cos(d) ~ d^2: scale the phases by the square root
                    eff[k] = _scaled(eff[k], k, min(ratio, 4.0) ** 0.5)
                elif k == "saturation":
                    # a lower range rectifies more: one step of the range's log-slope
                    eff[k] = _scaled(eff[k], k, ratio ** -0.25)
                if not _within_caps(k, eff[k]):
                    ok = False
                    break
            if not ok:
                break
        if not ok:
            continue
        joint, ch = marginal_changes(P, tab, eff)
        S = {k: _rms(ch[k]) for k in kinds}
        chi2 = {k: float(np.sum((ch[k] / u) ** 2)) for k in kinds}
        if min(chi2.values()) < 100:
            continue
        ratio = max(S.values()) / min(S.values())
        if ratio > 2000:
            continue
        uniq = {k: unique_chi2(P, tab, eff, u, k, ch[k], joint) for k in kinds}
        if min(uniq.values()) < 100:
            continue
        additive = lab_composition(P, tab, eff)
        gap = joint - additive
        return rows, tab, eff, u, (joint, additive), {"rms_g": S, "chi2": chi2, "unique_chi2": uniq,
                                           "ratio": ratio, "composition_gap_chi2": float(np.sum((gap / u) ** 2)),
                                           "composition_gap_max_g": float(np.max(np.abs(gap))), "attempts": attempt + 1}
    raise RuntimeError(f"{name}: could not draw a detectable member of {kinds}")


def equivalent_params(eff, u, joint, table_of):
    """Other parameter sets this design cannot tell from `eff`: with the table's
    phases all 0 the axis phases enter the IA cross terms through cos(offset) alone,
    so each offset's sign is free; the anisoelastic product takes cos(d_OA - d_PA), so
    a flip of one sign is made up by k_ae cos(d_OA - d_PA) / cos(d_OA' - d_PA'). Each
    such set is kept only when its table (this generator's physics) equals the
    member's to 1e-6 of the noise (chi2 of the difference below 1e-12; `table_of`: the
    member's VE for a parameter set, in the battery's composition)."""
    if "axis_phase" not in eff:
        return []
    ph = eff["axis_phase"]
    dx, dy = ph.get("phase_x_deg", 0.0), ph.get("phase_y_deg", 0.0)
    out = []
    for sx, sy in ((1, -1), (-1, 1), (-1, -1)):
        e = {k: dict(v) for k, v in eff.items()}
        e["axis_phase"]["phase_x_deg"] = sx * dx
        e["axis_phase"]["phase_y_deg"] = sy * dy
        if "anisoelastic" in e:
            c_new = math.cos(math.radians(sx * dx - sy * dy))
            if abs(c_new) < 1e-3:
                continue
            e["anisoelastic"]["k_ae_per_g"] = eff["anisoelastic"]["k_ae_per_g"] * math.cos(math.radians(dx - dy)) / c_new
            if not _within_caps("anisoelastic", e["anisoelastic"]):
                continue
        diff = table_of(e) - joint
        if float(np.sum((diff / u) ** 2)) < 1e-12:
            out.append(e)
    return out


def confounded_member(P, which, rng, n_rows):
    """One tone frequency: a design that cannot separate two effects."""
    u0 = 0.5e-6
    if which == "mount-vs-sensor":
        rows = design_one_frequency_ia(rng, n_rows)
        eff = {"mount_resonance": {"freq_hz": 48.0, "q": 1.56}}
        partner = ("sensor_error",)
    else:
        rows = design_one_frequency_ia_pa(rng, n_rows)
        eff = {"vibropendulous": {"c_rad_per_g": -2e-5, "tau_s": 0.002}}
        partner = ("axis_phase",)
    tab = Table(rows)
    u = u0 * rng.uniform(0.8, 1.25, tab.n)
    joint = ve(P, tab, eff)
    base = ve(P, tab, {})
    change = joint - base
    additive = joint  # one effect: no composition
    # the partner at its equivalent value: a sensor gain 1/|T(f)| - 1 gives the unit
    # the same IA amplitude; an axis phase on PA with 0.5 m32 (cos d - 1) = 0.5 c Re HP
    # the same IA x PA term
    f = rows[0]["freq_hz"]
    if partner[0] == "sensor_error":
        g = 1.0 / abs(complex(mount_T(f, 48.0, 1.56))) - 1.0
        pe = {"sensor_error": {"gain_error": g}}
    else:
        re = complex(hp_H(f, 0.002)).real
        d = math.degrees(math.acos(1.0 + eff["vibropendulous"]["c_rad_per_g"] * re / P.m32))
        pe = {"axis_phase": {"phase_x_deg": 0.0, "phase_y_deg": d}}
    pc = ve(P, tab, pe) - base
    corr = float(np.dot(change / u, pc / u) / (np.linalg.norm(change / u) * np.linalg.norm(pc / u)))
    apart = float(np.sqrt(np.sum(((change - pc) / u) ** 2)))
    info = {"rms_g": {k: _rms(change) for k in eff}, "chi2": {k: float(np.sum((change / u) ** 2)) for k in eff},
            "confounder": partner[0], "confounder_params": pe[partner[0]], "confounder_correlation": corr,
            "confounder_chi2_apart": apart ** 2}
    return rows, tab, eff, u, (joint, additive), info


ALL_PAIRS = [(a, b) for i, a in enumerate(EFFECTS) for b in EFFECTS[i + 1:]]
ALL_TRIPLES = [
    ("mount_resonance", "high_order_nonlinearity", "anisoelastic"),
    ("axis_phase", "sensor_error", "heating"),
    ("vibropendulous", "heating", "high_order_nonlinearity"),
    ("mount_resonance", "vibropendulous", "sensor_error"),
    ("saturation", "anisoelastic", "heating"),
    ("mount_resonance", "axis_phase", "anisoelastic"),
]
CI_PAIRS = [
    ("mount_resonance", "high_order_nonlinearity"),
    ("saturation", "anisoelastic"),
    ("heating", "mount_resonance"),
    ("axis_phase", "high_order_nonlinearity"),
    ("vibropendulous", "anisoelastic"),
    ("sensor_error", "anisoelastic"),
    ("mount_resonance", "vibropendulous"),
    ("sensor_error", "heating"),
]
CI_TRIPLES = [
    ("mount_resonance", "high_order_nonlinearity", "anisoelastic"),
    ("axis_phase", "sensor_error", "heating"),
]
SHORT = {
    "mount_resonance": "mount", "high_order_nonlinearity": "k6", "saturation": "sat",
    "vibropendulous": "vp", "anisoelastic": "ae", "heating": "heat", "axis_phase": "phase",
    "sensor_error": "sensor",
}


def cmd_battery(args):
    P = Passport()
    t0 = time.time()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    dropped = set(DROPPED) if not args.include_dropped else set()
    if args.members == "ci":
        sets = CI_PAIRS + CI_TRIPLES
        n_rows = args.rows or 140
    else:
        sets = ALL_PAIRS + ALL_TRIPLES
        n_rows = args.rows or 400
    sets = [s for s in sets if not dropped & set(s)]
    index = {"generator": "tests/python/lab_battery.py", "seed": args.seed, "members_set": args.members,
             "composition": args.composition,
             "passport": P.id, "filter_rate_hz": FILTER_RATE_HZ, "dropped_effects": DROPPED, "members": []}
    specs = [("effect", s) for s in sets] + [("confounded", "mount-vs-sensor"), ("confounded", "vp-vs-phase")]
    only = set(args.only.split(",")) if args.only else None
    for m, (expect, what) in enumerate(specs):
        rng = np.random.default_rng([args.seed, m])
        t1 = time.time()
        if expect == "effect":
            name = f"{m + 1:02d}-" + "+".join(SHORT[k] for k in what)
        else:
            name = f"{m + 1:02d}-confounded-{what}"
        if only is not None and name not in only:
            continue
        if expect == "effect":
            rows, tab, eff, u, joint, info = draw_member(P, list(what), rng, n_rows, name)
        else:
            rows, tab, eff, u, joint, info = confounded_member(P, what, rng, max(24, n_rows // 4))
        joint, additive = joint
        truth_ve = joint if args.composition == "physical" else additive
        noise = rng.normal(size=tab.n) * u
        for r, v, s, e in zip(rows, truth_ve, u, noise):
            r["ve_measured_g"] = float(v + e)
            r["ve_uncertainty_g"] = float(s)
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        write_csv(d / "table.csv", rows)
        T = float(tab.T[0])
        table_of = (lambda e: ve(P, tab, e)) if args.composition == "physical" else (lambda e: lab_composition(P, tab, e))
        equivalent = equivalent_params(eff, u, truth_ve, table_of) if expect == "effect" else []
        truth = {
            "member": name,
            "expect": expect,
            "kinds": list(eff),
            "params": {k: lab_truth(k, v, T) for k, v in eff.items()},
            "equivalent_params": [{k: lab_truth(k, v, T) for k, v in e.items()} for e in equivalent],
            "physical": eff,
            "sign_observable": {"axis_phase": False} if "axis_phase" in eff else {},
            "noise": {"ve_uncertainty_g_min": float(u.min()), "ve_uncertainty_g_max": float(u.max()),
                      "ve_uncertainty_g_rms": _rms(u), "seed": [args.seed, m]},
            "rows": tab.n,
            "design": "one-frequency" if expect == "confounded" else "separating",
            "composition": args.composition,
            "strength": info,
            "generated_s": time.time() - t1,
        }
        if expect == "confounded":
            truth["confounder"] = info["confounder"]
        (d / "truth.json").write_text(json.dumps(truth, indent=1))
        index["members"].append({"name": name, "dir": name, "kinds": list(eff), "expect": expect, "rows": tab.n})
        if not args.quiet:
            s = info
            extra = (f"ratio {s['ratio']:.0f}:1, weakest chi2 {min(s['chi2'].values()):.0f}, "
                     f"composition gap chi2 {s['composition_gap_chi2']:.3g}" if expect == "effect"
                     else f"correlation with {s['confounder']} {s['confounder_correlation']:.6f}")
            print(f"{name}: {tab.n} rows, {extra} ({time.time() - t1:.1f} s)", file=sys.stderr)
    index["generated_s"] = time.time() - t0
    (out / "battery.json").write_text(json.dumps(index, indent=1))
    print(json.dumps({"members": len(index["members"]), "seconds": index["generated_s"], "out": str(out)}))
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("selfcheck", help="closed forms, Monte Carlo, and the binary")
    s.add_argument("--bin", help="the vibrocomp binary (default target/debug/vibrocomp or VIBROCOMP_BIN)")
    s.add_argument("--mc-samples", type=int, default=1_000_000)
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--json", help="write the figures as JSON")
    b = sub.add_parser("battery", help="write the battery's tables")
    b.add_argument("--out", required=True)
    b.add_argument("--seed", type=int, required=True)
    b.add_argument("--members", choices=("all", "ci"), default="ci")
    b.add_argument("--rows", type=int, default=0, help="rows per member (default 140 ci, 400 all)")
    b.add_argument("--include-dropped", action="store_true", help="also the effects DROPPED lists")
    b.add_argument("--only", help="comma-separated member names (e.g. 18-sat+sensor): only these, "
                   "drawn as in the whole set")
    b.add_argument("--composition", choices=("physical", "lab"), default="physical",
                   help="the measured VE from the effects composed as docs/effects.md's physics "
                        "(default) or added as docs/lab.md's prediction does (module doc, ambiguity 4)")
    b.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    if args.cmd == "selfcheck":
        return cmd_selfcheck(args)
    return cmd_battery(args)


if __name__ == "__main__":
    sys.exit(main())
