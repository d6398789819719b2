#!/usr/bin/env python3
"""Independent shake-table rig generator: what a real rig records, sample by sample.

Written from the maths of ``shared/spec/MODEL.md`` (the conversion function and the
vibration-error formulas, with the papers' equation numbers) and ``shared/spec/RIG.md``
(the rig and its environments) alone, so that vibrocomp can be tested on data it did
not make (issue 30, "Real rigs, no simulator"). It does not use vibrocomp's simulator.

The rig
=======

An AL-15 triad (three pendulous accelerometers AK1..AK3; unit i has its input axis IA,
output axis OA and pendulum axis PA along signed body axes, from the triad file) sits
on a shaker, through an optional hidden mount resonance. Next to each unit, on the
shaker base, a piezoelectric vibration sensor VD1..VD3 measures along that unit's IA;
a triaxial DC-coupled reference accelerometer on the base measures body x, y, z.

Physical steps and their discretisation (all on one *fine grid* ``t_n = n / fs``,
``fs = sensor_rate * oversample`` when the accel rate divides it, else ``fs =
lcm(sensor_rate, accel_rate) * oversample`` (5 kHz or 10 kHz sensors with 800 Hz
readings: 20 kHz), ``n = 0..N`` with ``N = T_run * fs``; ``truth.json``'s ``rates``):

1. **Gravity.** Apparent acceleration of a still rig: ``g * d`` in body axes, ``d`` the
   orientation unit vector (the body direction pointing *up*, so that a unit whose IA
   is along ``d`` reads ``aL3 = +1 g``, as MODEL.md section 9 and RIG.md's "IA vertical
   (aL3 = 1 g)" count it). Constant per run.
2. **Base vibration** along each body axis i (MODEL.md section 3, [P1 (3)-(6)]):
   ``v_i(t) = env(t) * (A_i sin(2 pi f_i t + phi_i) + x_i(t))``. ``x_i`` is stationary
   Gaussian random vibration with a stated one-sided PSD ``S_i(f)`` (g^2/Hz), flat over
   a band (default 20..640 Hz) or piecewise flat from a band table. It is made in the
   frequency domain on the bins ``k / T_run`` of the band: ``x(t) = sum_k a_k cos(2 pi k
   t/T_run) + b_k sin(2 pi k t/T_run)`` with ``a_k, b_k ~ N(0, S(f_k) / T_run)`` independent,
   so ``x`` is exactly Gaussian with variance ``sum_k S(f_k)/T_run = int S df`` (MODEL.md
   section 3: ``sigma^2 = S * df``) and, since the draws do not depend on the rate, the
   *same* continuous signal is sampled at any fine rate (this is how the discretisation
   error is measured). Axes are independent (``K_3j(0) = 0``). ``env`` is 0 while
   still, 1 while vibrating, with raised-cosine ramps of ``ramp_s``.
3. **Hidden mount resonance** (optional), per body axis between base and units, a
   linear second-order system with DC gain exactly 1 (gravity passes unchanged):
   ``base``  form (default): ``H(s) = (w0^2 + 2 zeta w0 s) / (s^2 + 2 zeta w0 s + w0^2)``,
   the absolute-acceleration transmissibility of a mass on a spring-damper mount,
   ``|H(j w0)| = Q sqrt(1 + 1/Q^2)``; ``plain`` form: ``H(s) = w0^2 / (s^2 + 2 zeta w0 s +
   w0^2)``, ``|H(j w0)| = Q``; ``Q = 1/(2 zeta)``. Applied **exactly** by default
   (``--filter-method exact``): ``H(j 2 pi f)`` multiplies the run's DFT bins, which is
   the continuous system's response because every signal it acts on is periodic over
   the run (a shaker run starts and ends still; the random vibration is periodic by
   construction; in flight-like runs the tone goes through analytically, in steady
   state). ``--filter-method bilinear``: a digital filter on the fine grid, bilinear
   transform prewarped at f0 (exact at 0 and f0, frequency-warped elsewhere: 4 % at
   640 Hz with a 6.4 kHz grid, 0.3 % at 25.6 kHz; ``selfcheck``). The filter acts on the
   vibration only; gravity is added unfiltered (identical, DC gain 1). The units see
   the filtered vibration; the vibration sensors and the reference sit on the base and
   do not.
4. **Conversion function** of each unit, MODEL.md (FP) [P1 (1)-(2)], [P2 (1)], applied
   to the instantaneous acceleration at the unit projected on its axes
   ``a3 = e_IA . a``, ``a1 = e_OA . a``, ``a2 = e_PA . a``, at every fine sample::

       aF = a0 + k1*lambda*(1 + 0.5*d1A*sign(a3))*a3 + k2 a3^2 + k3 a3^3 + k4 a3^4
            + k5 a3^5 + m1*a1 + m2*a2 + m31*a3*a1 + m32*a3*a2,        U = K1 * aF

   with ``lambda(w) = 1`` (the unit's own frequency response is the optional hidden
   ``unit_response`` below).

   **Hidden effects** (docs/effects.md; all off by default, each recorded with its
   parameters in ``truth.json``'s ``effects``; an effect at zero strength is skipped,
   so such a rig is bit for bit the rig without it). In the simulator's chain order:

   a. *Path* (``--unit-response-hz F --unit-response-damping Z``, ``unit_response``):
      per unit, the IA component of the vibration at the unit (after the mount) goes
      through ``wn^2 / (s^2 + 2 Z wn s + wn^2)`` like the mount (exact: on the run's DFT
      bins; flight-like tones analytically; ``--filter-method bilinear``: prewarped at
      F); OA, PA and gravity (DC gain 1) are untouched. The (FP) and every output
      effect see ``a3 = aL3 + H[v3]``; ``sensed{u}_g`` stays the acceleration at the unit
      (before its own response), so ``error{u}_g`` carries the unit's dynamic error too.
   b. *Output* (``--effect kind:key=value,...[,units=0|1|2|0+2]``), added to the
      instantaneous ``aF`` at every fine sample, from the total acceleration at the unit
      ``a = (a1, a2, a3)`` (after the path), then the clip:

      - ``vibropendulous`` (``c_rad_per_g``, ``tau_s``): ``+ c HP[a3] a2``, ``HP(s) = s tau /
        (1 + s tau)`` on the total IA acceleration (gravity gives 0), ``a2`` total PA;
      - ``anisoelastic`` (``k_ae_per_g``): ``+ k_ae a1 a2``;
      - ``high_order_nonlinearity`` (``k6_ppm_per_g5``, ``k7_ppm_per_g6``): ``+ 1e-6 (k6 a3^6
        + k7 a3^7)``;
      - ``heating`` (``c_g_per_g2``, ``tau_s``): ``+ b``, ``tau db/dt = c v3^2 - b``, ``b = 0`` at
        the run start, ``v3`` the IA vibration at the unit (after the path);
      - ``scale_factor_frequency`` (``corner_hz``, ``lambda_hf``): ``+ k1 (1 + 0.5 d1A
        sign(a3)) (L[a3] - a3)``, ``L(s) = (1 + lambda_hf s/wc) / (1 + s/wc)`` (passport k1, d1A);
      - ``saturation`` (``range_g``): the whole output (all the above) clipped to
        ``+-range_g``, last whatever the order given.

      Filters: ``HP`` and ``L - 1`` (first-order high-passes of the vibration) are exact,
      on the run's DFT bins (flight-like: tones analytically, the periodic steady state
      as the other filters); on a shaker run they start at rest (the rig stood still), so
      the periodic response ``y_p`` is made causal exactly by ``y_p(t) - y_p(0) e^{-t/tau}``.
      The heating lag is solved exactly for ``v3^2`` linear between fine samples (first-
      order hold): 6e-7 relative at 6.4 kHz, 4e-8 at 25.6 kHz (``selfcheck`` 10).
   c. *Sensor* (``--sensor-gain-error G1,G2,G3``, ``sensor_error``, gain only): sensor k
      reads ``(1 + G_k)`` times the vibration along unit k's IA (before its sensitivity,
      AC coupling and noise; step 6).
5. **Readings**: each output reading is the mean of ``U`` over its averaging interval
   ``(t_j - T_a, t_j]``, ``T_a = 1 / accel_rate``, latched (time-stamped) at the end
   ``t_j = j T_a``, j = 1..J. (FP) is split into its linear part
   ``a0 + k1 lambda a3 + m1 a1 + m2 a2`` and the rest (asymmetry, k2..k5, m31, m32):

   - the linear part's mean is exact: gravity is constant, and the vibration at the
     unit is band-limited far below Nyquist and periodic over the run, so its
     continuous boxcar ``(1 - e^{-j w T_a})/(j w T_a)`` is applied in the frequency
     domain (flight-like runs: the tone analytically, in its steady state);
   - the rest (about 1e-4 of the signal, but all of the vibration error) is averaged
     by the trapezoid rule over the ``M + 1`` fine samples of the interval,
     ``M = fs / accel_rate`` (weights 1/2 at both ends): the exact mean of the
     piecewise-linear signal through the samples. Over many readings this is the mean
     of the fine samples, so the static error has no discretisation error beyond the
     sampling of the signal itself (``selfcheck`` and the tests measure it).
   - output effects: their constant parts exactly, their parts linear in the vibration
     (``c aL2 HP[v3]``, ``k_ae (aL1 v2 + aL2 v1)``, ``(6 k6 aL3^5 + 7 k7 aL3^6) v3``,
     ``k1 (L - 1)[v3]``) by the exact boxcar, the rest (``c HP[v3] v2``, ``k_ae v1 v2``, the
     higher powers, the heating bias, the clip's correction) by the trapezoid rule; the
     jump of ``0.5 k1 d1A sign(a3) (L - 1)[v3]`` is integrated exactly for the signals
     linear between samples (split at the zero of ``a3``; a plain trapezoid is O(h): 10 %
     for a 400 Hz tone at 6.4 kHz, this is 1.8e-2, 5e-4 at 25.6 kHz). A clipped reading
     mixes the exact boxcar with the trapezoid of the clip's correction, so it can pass
     the range by O((w h)^2 A) (1 mg for a 4 g, 60 Hz tone at 6.4 kHz; ``--oversample``).

   White output noise (``unit_noise_g`` RMS per reading, times K1) is added, and with
   ``--unit-drift-ug-per-s R`` a slow linear drift ``r_u t`` (t from the run start;
   averaged over the interval: ``r_u (t_j - T_a/2)``), ``r_u = +-R``, the sign per unit
   drawn from ``spawn_key = (run, 2)``.
6. **Vibration sensors**: ``V = sens * HP(e_IA . a_base) + noise``, 0.1 V/g by default,
   ``HP(s) = s / (s + 2 pi f_c)`` (AC coupling, f_c = 2 Hz, first order), applied like
   the mount (exact, or bilinear prewarped at f_c). The rig has stood still under
   gravity long before the record, so the response to gravity has decayed: the output
   carries the vibration only. Sampled at every ``fs / sensor_rate``-th fine sample
   (the sensor rate); white noise ``vib_noise_g`` RMS (referred to the input) added.
   With ``--daq-delay-s D`` (0 <= D <= 1 s; a linear-phase anti-alias filter's group
   delay, an ADC pipeline) the sample stamped ``s`` holds the signal at ``s - D``:
   exactly, as the other filters, the tone and the envelope at ``t - D`` analytically,
   the periodic random vibration by ``e^{-j w D}`` on the run's DFT bins (delay and AC
   coupling commute). The reference and the accelerometers are not delayed.
7. **Reference accelerometer** (base, body x, y, z, DC-coupled, in g): the total base
   acceleration at the sensor rate plus white noise ``ref_noise_g`` RMS. With
   ``--ref-sens-v-per-g S`` it is recorded as a rig records a piezoelectric reference
   (``ref_chain``): AC-coupled, in V, ``V = S * (HP(v_base(t - D)) + noise)``, ``HP(s) =
   s / (s + 2 pi f_r)`` (``--ref-hp-hz f_r``, first order, exact as step 6's), the sample
   stamped ``s`` holding the base at ``s - D`` (``--ref-delay-s D``, exact as step 6's
   delay); gravity gives 0 (the rig stood still long before the record). Columns
   ``ax_v, ay_v, az_v``. ``--write-rig`` writes ``rig.toml`` beside it: the vibration
   sensors' chain, the orientation as a static ``[reference]`` segment over the run and
   the reference's chain ``[reference.chain]`` (docs/logs.md, "A rig's own data").

Runs are ``still_s`` still / ``vib_s`` vibrating / ``still_s`` still (8/8/8 s by
default), or vibrating throughout (flight-like; the filters then start in the periodic
steady state). Every random part derives from the seed (numpy ``SeedSequence``):
conditions that the seed chooses (tone amplitudes and phases when not given) from
``spawn_key = (run, 0)``; the random vibration and the three noises from
``spawn_key = (run, 1, repeat, stream)``, so ``--repeat K`` re-draws only those.

Outputs per run (a folder): ``accel.csv`` (``time_s,u1_v,u2_v,u3_v``), ``vib.csv``
(``time_s,vd1_v,vd2_v,vd3_v``), ``reference.csv`` (``time_s,ax_g,ay_g,az_g``), in the CSV
format of ``vibrocomp log import`` (docs/logs.md: ``#`` comments, a header line, one row
per sample, numbers written with Python's ``repr`` so they read back bit for bit), and
``truth.json`` (everything used, and the true vibration error: for tests only).

``readings_truth.csv`` (same conventions; for tests only), one row per reading with
accel.csv's ``time_s``: ``time_s,sensed1_g,sensed2_g,sensed3_g,error1_g,error2_g,
error3_g``. ``sensed{u}_g`` is the mean over the reading's interval ``(t - T_a, t]`` of
what unit u senses along its IA, ``e_IA . (g d + v_unit)`` (gravity plus the vibration
at the unit, through the hidden mount when there is one), exactly (the continuous
boxcar of step 5's linear part); ``error{u}_g`` is the noise-free, drift-free reading
``U/K1`` minus ``sensed{u}_g``: the main error plus the vibration error of that very
reading (MODEL.md section 12), with every hidden output effect and the unit's own
response when they are on. A perfect compensator outputs ``sensed``; its output
minus ``sensed`` is its error (``waveform_errors.py``).

The true VE (``ve_time_domain_g``, MODEL.md section 3) is the mean noise-free reading
over the steady part of the vibrating segment minus the reading at rest, less the
first-order response ``grad(FP)(aL) . <v>`` to the window mean ``<v>`` of the vibration
itself: over a finite window a shaker's acceleration does not average to zero (it is
the table's velocity change over the window divided by its length: about 3e-4 g over
7.7 s for 0.002 g^2/Hz in 20..640 Hz), and that is input, not error. Both parts are in
the truth (``reading_shift_g = ve_time_domain_g + first_order_input_mean_g +
effects_mean_shift_g``, the last the window mean of what the output effects add); MODEL.md
section 8's measurement from the recorded outputs is there too.

Usage::

    rig_generator.py run --out DIR [options]           one run (K folders with --repeat K)
    rig_generator.py campaign --out DIR [options]      orientations x tone frequencies
    rig_generator.py selfcheck                         discretisation figures, hidden effects vs closed forms

(A negative orientation takes ``=``: ``--orientation=-y``.)
"""

from __future__ import annotations

import argparse
import copy
import csv
import dataclasses
import json
import math
import os
import sys
import time
import tomllib
from dataclasses import dataclass, field

import numpy as np
from scipy import signal, special

# ---------------------------------------------------------------------------------------
# Passport and triad


@dataclass
class Passport:
    """Coefficients of the conversion function (FP), MODEL.md section 2, in g units.

    ``k2..k5`` are in 1/g^(n-1), ``m31, m32`` in 1/g, ``d1a``, ``m1``, ``m2`` dimensionless,
    ``a0_g`` in g, ``K1_v_per_g`` in V/g (``U = K1 * aF``, so ``K0 = K1 * a0``, MODEL.md
    section 2). ``lam`` is lambda(w), taken constant.
    """

    id: str = "AL-15"
    a0_g: float = 3.324e-3
    k1: float = 1.0
    K1_v_per_g: float = -1.6698
    d1a: float = 15e-6
    k2: float = 105e-6
    k3: float = 87e-6
    k4: float = 10e-6
    k5: float = 0.9e-6
    m1: float = 1150e-6
    m2: float = 1150e-6
    m31: float = 11.6e-6
    m32: float = 11.6e-6
    lam: float = 1.0

    # TOML key -> (field, divisor); the project's passport files quote ppm.
    TOML_KEYS = {
        "a0_g": ("a0_g", 1.0),
        "k1": ("k1", 1.0),
        "K1_v_per_g": ("K1_v_per_g", 1.0),
        "d1a_ppm": ("d1a", 1e6),
        "k2_ppm_per_g": ("k2", 1e6),
        "k3_ppm_per_g2": ("k3", 1e6),
        "k4_ppm_per_g3": ("k4", 1e6),
        "k5_ppm_per_g4": ("k5", 1e6),
        "m1_ppm": ("m1", 1e6),
        "m2_ppm": ("m2", 1e6),
        "m31_ppm_per_g": ("m31", 1e6),
        "m32_ppm_per_g": ("m32", 1e6),
    }

    @classmethod
    def from_toml(cls, path):
        """Read a passport file (``config/accelerometers/*.toml``: keys with units)."""
        with open(path, "rb") as f:
            d = tomllib.load(f)
        p = cls(id=str(d.get("id", os.path.basename(path))))
        for key, (name, divisor) in cls.TOML_KEYS.items():
            if key in d:
                setattr(p, name, float(d[key]) / divisor)
        return p

    def to_dict(self):
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def af(self, a3, a1, a2):
        """(FP) in acceleration units, MODEL.md section 2 [P1 (1)-(2)], [P2 (1)].

        ``(1 + 0.5 d1A sign(a3)) a3 = a3 + 0.5 d1A |a3|`` is used (the same number).
        Works on scalars or arrays (element-wise).
        """
        a3 = np.asarray(a3, dtype=float)
        lin = self.k1 * self.lam * (a3 + 0.5 * self.d1a * np.abs(a3))
        # Horner for k2 a3^2 + ... + k5 a3^5
        poly = a3 * a3 * (self.k2 + a3 * (self.k3 + a3 * (self.k4 + a3 * self.k5)))
        return (
            self.a0_g
            + lin
            + poly
            + self.m1 * a1
            + self.m2 * a2
            + self.m31 * a3 * a1
            + self.m32 * a3 * a2
        )


AXIS_VECTORS = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


def axis_vector(name):
    """A signed body axis, ``"+x"`` .. ``"-z"`` (``"x"`` means ``"+x"``)."""
    n = name.strip().lower()
    if n in ("x", "y", "z"):
        n = "+" + n
    if n not in AXIS_VECTORS:
        raise ValueError(f"not a signed body axis: {name!r} (want +x, -y, ...)")
    return np.array(AXIS_VECTORS[n])


@dataclass
class Unit:
    """One accelerometer of the triad: its passport and signed body axes (RIG.md)."""

    name: str
    passport: Passport
    ia: str
    oa: str
    pa: str

    def __post_init__(self):
        letters = {s.strip().lower()[-1] for s in (self.ia, self.oa, self.pa)}
        if len(letters) != 3:
            raise ValueError(f"unit {self.name}: IA, OA, PA must be three body axes")

    @property
    def e_ia(self):
        return axis_vector(self.ia)

    @property
    def e_oa(self):
        return axis_vector(self.oa)

    @property
    def e_pa(self):
        return axis_vector(self.pa)

    def to_dict(self):
        return {
            "name": self.name,
            "ia": self.ia,
            "oa": self.oa,
            "pa": self.pa,
            "passport": self.passport.to_dict(),
        }


def default_triad(passport=None):
    """The shipped triad (``config/triads/default.toml``), AL-15 passports."""
    p = passport or Passport()
    return [
        Unit("AK1", p, "+x", "+y", "+z"),
        Unit("AK2", p, "+y", "+z", "+x"),
        Unit("AK3", p, "+z", "+x", "+y"),
    ]


def load_triad(path, passport_dir=None, passport=None):
    """Read a triad file (``[[unit]]`` with ``name, passport, ia, oa, pa``).

    Each unit's passport id is looked up among ``passport_dir/*.toml`` by their ``id``;
    ``passport`` (if given) overrides all of them; the id ``AL-15`` falls back to the
    built-in passport.
    """
    with open(path, "rb") as f:
        d = tomllib.load(f)
    found = {}
    if passport_dir and os.path.isdir(passport_dir):
        for fn in sorted(os.listdir(passport_dir)):
            if fn.endswith(".toml"):
                p = Passport.from_toml(os.path.join(passport_dir, fn))
                found[p.id] = p
    units = []
    for u in d["unit"]:
        if passport is not None:
            p = passport
        elif u.get("passport") in found:
            p = found[u["passport"]]
        elif u.get("passport", "AL-15") == "AL-15":
            p = Passport()
        else:
            raise ValueError(f"passport {u.get('passport')!r} not found in {passport_dir}")
        units.append(Unit(u["name"], p, u["ia"], u["oa"], u["pa"]))
    if len(units) != 3:
        raise ValueError("a triad has three units")
    return units


# ---------------------------------------------------------------------------------------
# Orientations

_S3 = 1.0 / math.sqrt(3.0)
ORIENTATIONS = {
    **AXIS_VECTORS,
    # two oblique ones: every unit sees a share of gravity on IA and on OA/PA
    "oblique1": (_S3, _S3, _S3),
    "oblique2": (0.5, -0.5, math.sqrt(0.5)),
}


def orientation_vector(spec):
    """A named orientation (``ORIENTATIONS``) or ``"x,y,z"`` (normalised)."""
    if isinstance(spec, str) and spec.strip() in ORIENTATIONS:
        return np.array(ORIENTATIONS[spec.strip()])
    v = np.array([float(s) for s in spec.split(",")] if isinstance(spec, str) else spec, float)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise ValueError(f"orientation must be a name or three numbers: {spec!r}")
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------------------------------
# Run configuration


@dataclass
class Resonance:
    """The hidden mount resonance (step 3 of the module doc)."""

    f0_hz: float = 150.0
    q: float = 2.5
    form: str = "base"  # "base": (w0^2 + 2 zeta w0 s)/(...);  "plain": w0^2/(...)

    @property
    def zeta(self):
        return 1.0 / (2.0 * self.q)

    def analog(self):
        w0 = 2 * math.pi * self.f0_hz
        z = self.zeta
        a = [1.0, 2 * z * w0, w0 * w0]
        if self.form == "base":
            b = [2 * z * w0, w0 * w0]
        elif self.form == "plain":
            b = [w0 * w0]
        else:
            raise ValueError(f"resonance form {self.form!r}: base or plain")
        return b, a

    def h(self, f_hz):
        """Continuous ``H(j 2 pi f)``."""
        b, a = self.analog()
        return signal.freqs(b, a, worN=2 * np.pi * np.atleast_1d(np.asarray(f_hz, float)))[1]

    def digital(self, fs):
        """Bilinear transform prewarped at f0: ``s = w0/tan(w0/(2 fs)) * (z-1)/(z+1)``."""
        b, a = self.analog()
        return bilinear_prewarped(b, a, self.f0_hz, fs)

    def settle_s(self):
        """Time for the free response to fall by e^-25: 25 / (zeta w0)."""
        return 25.0 / (self.zeta * 2 * math.pi * self.f0_hz)


@dataclass
class RunConfig:
    """Everything that defines a run. ``None`` tone amplitudes/phases: drawn from the seed."""

    orientation: tuple = (0.0, 0.0, 1.0)
    orientation_name: str = "+z"
    gravity_g: float = 1.0
    tone_hz: tuple = (60.0, 60.0, 60.0)
    tone_amp_g: tuple | None = None  # per body axis x, y, z; None: U(0.5, 2) from the seed
    tone_phase_rad: tuple | None = None  # None: U(0, 2 pi) from the seed
    # random vibration: list of (f_lo, f_hi, (S_x, S_y, S_z)) in Hz and g^2/Hz
    random_bands: list = field(default_factory=lambda: [(20.0, 640.0, (0.002, 0.002, 0.002))])
    resonance: Resonance | None = None
    filter_method: str = "exact"  # mount and AC coupling: "exact" (frequency domain) or "bilinear"
    accel_rate_hz: float = 800.0
    sensor_rate_hz: float = 25600.0
    oversample: int = 1
    still_s: float = 8.0
    vib_s: float = 8.0
    vibrate_throughout: bool = False
    duration_s: float = 24.0  # used when vibrating throughout
    ramp_s: float = 0.1
    settle_s: float | None = None  # None: max(0.1 s, the resonance's settle time)
    unit_noise_g: float = 10e-6
    vib_noise_g: float = 1e-3
    ref_noise_g: float = 1e-3
    vib_sens_v_per_g: float = 0.1
    vib_hp_hz: float = 2.0
    daq_delay_s: float = 0.0  # vibration sensors' acquisition delay: sample stamped s holds time s - D
    ref_sens_v_per_g: float | None = None  # None: DC-coupled reference in g; else AC-coupled in V (step 7)
    ref_hp_hz: float = 0.5  # the AC-coupled reference's first-order corner, Hz
    ref_delay_s: float = 0.0  # the AC-coupled reference's delay: sample stamped s holds time s - D
    unit_drift_ug_per_s: float = 0.0  # |r_u| of each unit's linear drift r_u t; signs from the seed
    unit_response: "UnitResponse | None" = None  # the units' own IA response (docs/effects.md unit_response)
    sensor_gain_error: tuple = (0.0, 0.0, 0.0)  # vibration sensor k reads (1 + G_k) x the vibration on unit k's IA
    effects: list = field(default_factory=list)  # OutputEffect, docs/effects.md at_unit_output effects
    write_rig: bool = False  # write rig.toml beside the CSVs (write_rig)
    seed: int = 30
    run_index: int = 0
    repeat: int = 0

    # derived --------------------------------------------------------------------------
    @property
    def fine_rate_hz(self):
        """``sensor_rate * oversample`` when the accel rate divides it (the original grid),
        else ``lcm(sensor_rate, accel_rate) * oversample`` (whole-number rates)."""
        fs = self.sensor_rate_hz * self.oversample
        if fs % self.accel_rate_hz == 0:
            return fs
        s, a = self.sensor_rate_hz, self.accel_rate_hz
        if not (s > 0 and a > 0 and float(s).is_integer() and float(a).is_integer()):
            return fs  # validate() refuses it
        return float(math.lcm(int(s), int(a)) * self.oversample)

    @property
    def sensor_stride(self):
        """Fine samples per sensor sample."""
        return int(round(self.fine_rate_hz / self.sensor_rate_hz))

    @property
    def t_run(self):
        return self.duration_s if self.vibrate_throughout else 2 * self.still_s + self.vib_s

    @property
    def t_on(self):
        return 0.0 if self.vibrate_throughout else self.still_s

    @property
    def t_off(self):
        return self.t_run if self.vibrate_throughout else self.still_s + self.vib_s

    @property
    def settle(self):
        if self.settle_s is not None:
            return self.settle_s
        s = max(0.1, self.resonance.settle_s() if self.resonance else 0.0)
        if self.unit_response is not None:
            s = max(s, self.unit_response.settle_s())
        return s

    def random_psd_per_axis(self):
        """Variance per body axis, ``sum S_i * (f_hi - f_lo)`` (MODEL.md section 3)."""
        return np.array([sum(s[i] * (hi - lo) for lo, hi, s in self.random_bands) for i in range(3)])

    def validate(self):
        fs = self.fine_rate_hz
        for what, x in (("fine", fs), ("sensor", self.sensor_rate_hz), ("accel", self.accel_rate_hz)):
            if not (x > 0 and float(x).is_integer()):
                raise ValueError(f"{what} rate must be a whole number of Hz: {x}")
        if fs % self.accel_rate_hz or fs % self.sensor_rate_hz:
            raise ValueError(f"the fine rate {fs} Hz is not a multiple of the accel and sensor rates")
        if abs(self.t_run * self.sensor_rate_hz - round(self.t_run * self.sensor_rate_hz)) > 1e-9:
            raise ValueError(f"run time {self.t_run} s is not a whole number of sensor periods")
        if self.ref_sens_v_per_g is not None and not (
            math.isfinite(self.ref_sens_v_per_g) and self.ref_sens_v_per_g != 0
            and 0 < self.ref_hp_hz < fs / 2 and 0.0 <= self.ref_delay_s <= min(1.0, self.still_s)
            and not self.vibrate_throughout
        ):
            raise ValueError(f"reference chain S = {self.ref_sens_v_per_g} V/g, f_r = {self.ref_hp_hz} Hz, "
                             f"D = {self.ref_delay_s} s: S finite and nonzero, 0 < f_r < fs/2, "
                             "0 <= D <= min(1 s, still_s), a shaker run")
        if not (0.0 <= self.daq_delay_s <= 1.0):
            raise ValueError(f"daq_delay_s = {self.daq_delay_s}: must be 0 <= D <= 1 s")
        if not self.vibrate_throughout and self.daq_delay_s > self.still_s:
            raise ValueError(f"daq_delay_s = {self.daq_delay_s} s: must not exceed still_s = {self.still_s} s "
                             "(the delayed vibration must end within the run)")
        if not math.isfinite(self.unit_drift_ug_per_s):
            raise ValueError(f"unit_drift_ug_per_s = {self.unit_drift_ug_per_s}: must be finite")
        for what, t in (("run", self.t_run), ("still", 0 if self.vibrate_throughout else self.still_s)):
            if abs(t * self.accel_rate_hz - round(t * self.accel_rate_hz)) > 1e-9:
                raise ValueError(f"{what} time {t} s is not a whole number of accel periods")
        for lo, hi, s in self.random_bands:
            if not (0 < lo < hi < fs / 2) or len(s) != 3:
                raise ValueError(f"bad random band {lo}..{hi} Hz for the fine rate {fs} Hz")
        if self.resonance and self.resonance.f0_hz >= fs / 2:
            raise ValueError("resonance above Nyquist of the fine grid")
        if not self.vibrate_throughout and 2 * self.ramp_s + self.settle >= self.vib_s:
            raise ValueError("vibrating segment shorter than its ramps and settle time")
        probs = self.unit_response.validate(fs) if self.unit_response else []
        if len(self.sensor_gain_error) != 3 or not all(math.isfinite(g) and abs(g) <= 0.5
                                                       for g in self.sensor_gain_error):
            probs.append(f"sensor_gain_error = {self.sensor_gain_error}: three numbers, each |g| <= 0.5")
        for e in self.effects:
            if not isinstance(e, OutputEffect):
                probs.append(f"effects: {e!r} is not an OutputEffect (parse_effect)")
        if probs:
            raise ValueError("; ".join(probs))


def _seedseq(cfg, *key):
    return np.random.SeedSequence(cfg.seed, spawn_key=(cfg.run_index,) + tuple(key))


STREAM_RANDOM_VIB, STREAM_UNIT_NOISE, STREAM_VIB_NOISE, STREAM_REF_NOISE = range(4)
# spawn_key (run, DRIFT_KEY): the signs of the units' drifts; apart from the conditions
# (run, 0) and the random parts (run, 1, ...), so that adding a drift disturbs neither.
DRIFT_KEY = 2


def drift_rates_g_per_s(cfg):
    """Each unit's drift rate ``r_u = R * sign_u`` (g/s), signs drawn from ``(run, DRIFT_KEY)``."""
    rng = np.random.default_rng(_seedseq(cfg, DRIFT_KEY))
    signs = np.where(rng.uniform(size=3) < 0.5, -1.0, 1.0)
    return cfg.unit_drift_ug_per_s * 1e-6 * signs


def resolve_conditions(cfg):
    """Fill in tone amplitudes/phases the seed chooses (``spawn_key = (run, 0)``).

    Returns a copy; the random parts of ``--repeat`` never touch this stream.
    """
    cfg = copy.deepcopy(cfg)
    rng = np.random.default_rng(_seedseq(cfg, 0))
    amps = rng.uniform(0.5, 2.0, 3)
    phases = rng.uniform(0.0, 2 * math.pi, 3)
    if cfg.tone_amp_g is None:
        cfg.tone_amp_g = tuple(float(a) for a in amps)
    if cfg.tone_phase_rad is None:
        cfg.tone_phase_rad = tuple(float(p) for p in phases)
    cfg.tone_hz = tuple(float(f) for f in np.broadcast_to(np.asarray(cfg.tone_hz, float), 3))
    cfg.tone_amp_g = tuple(float(a) for a in np.broadcast_to(np.asarray(cfg.tone_amp_g, float), 3))
    cfg.tone_phase_rad = tuple(float(p) for p in np.broadcast_to(np.asarray(cfg.tone_phase_rad, float), 3))
    cfg.orientation = tuple(float(v) for v in orientation_vector(cfg.orientation))
    return cfg


# ---------------------------------------------------------------------------------------
# Signal generation


def envelope(cfg, t):
    """0 still, 1 vibrating, raised-cosine ramps of ``ramp_s`` inside the vibrating segment."""
    if cfg.vibrate_throughout:
        return np.ones_like(t)
    env = ((t >= cfg.t_on) & (t <= cfg.t_off)).astype(float)
    if cfg.ramp_s > 0:
        up = (t >= cfg.t_on) & (t < cfg.t_on + cfg.ramp_s)
        env[up] = 0.5 * (1 - np.cos(np.pi * (t[up] - cfg.t_on) / cfg.ramp_s))
        down = (t > cfg.t_off - cfg.ramp_s) & (t <= cfg.t_off)
        env[down] = 0.5 * (1 - np.cos(np.pi * (cfg.t_off - t[down]) / cfg.ramp_s))
    return env


def random_vibration(cfg, n_fine):
    """Gaussian band-limited random vibration per body axis, samples n = 0..n_fine.

    Bins ``f_k = k / T_run`` with ``f_lo <= f_k < f_hi`` of each band carry
    ``a_k cos + b_k sin``, ``a_k, b_k ~ N(0, S / T_run)``: one-sided PSD S, variance
    ``S (f_hi - f_lo)`` per band (MODEL.md section 3, ``sigma^2 = S df``). The draws
    depend on T_run and the bands only, not on the sample rate. Periodic in T_run.
    """
    t_run = cfg.t_run
    rng = np.random.default_rng(_seedseq(cfg, 1, cfg.repeat, STREAM_RANDOM_VIB))
    k_max = 0
    bands = []
    for lo, hi, s in cfg.random_bands:
        k0 = int(math.ceil(lo * t_run - 1e-9))
        k1 = int(math.ceil(hi * t_run - 1e-9))  # exclusive
        bands.append((k0, k1, np.asarray(s, float)))
        k_max = max(k_max, k1)
    scale = np.zeros((3, k_max))
    for k0, k1, s in bands:
        scale[:, k0:k1] = np.sqrt(s / t_run)[:, None]
    draws = rng.standard_normal((3, 2, k_max))
    a = draws[:, 0, :] * scale
    b = draws[:, 1, :] * scale
    n = n_fine
    if k_max >= n // 2:
        raise ValueError("random band above Nyquist")
    spec = np.zeros((3, n // 2 + 1), complex)
    # numpy irfft: x[m] = (1/n) (Y0 + 2 sum Re(Y_k e^{j 2 pi k m / n}) + ...):
    # Y_k = (n/2)(a_k - j b_k) gives a_k cos + b_k sin.
    spec[:, :k_max] = 0.5 * n * (a - 1j * b)
    x = np.fft.irfft(spec, n=n, axis=1)
    return np.concatenate([x, x[:, :1]], axis=1)  # sample n_fine = sample 0 (periodic)


def tone(cfg, t):
    """``A_i sin(2 pi f_i t + phi_i)`` per body axis (MODEL.md section 3, deterministic)."""
    f = np.asarray(cfg.tone_hz)[:, None]
    a = np.asarray(cfg.tone_amp_g)[:, None]
    p = np.asarray(cfg.tone_phase_rad)[:, None]
    return a * np.sin(2 * np.pi * f * t[None, :] + p)


def bilinear_prewarped(b, a, f_warp_hz, fs):
    """Bilinear transform with ``s = w_p / tan(w_p / (2 fs)) * (z - 1)/(z + 1)``: exact at 0 and f_warp."""
    wp = 2 * math.pi * f_warp_hz
    return signal.bilinear(b, a, fs=wp / (2.0 * math.tan(wp / (2.0 * fs))))


@dataclass
class Lti:
    """A continuous transfer function ``b(s)/a(s)`` applied to the run's signals.

    ``method = "exact"``: in the frequency domain, ``Y(f) = H(j 2 pi f) X(f)`` on the
    run's DFT bins: exact for signals periodic over the run (the vibration is zero at
    both ends of a shaker run, and the random vibration is periodic by construction),
    no discretisation. ``method = "bilinear"``: a digital filter on the fine grid,
    bilinear transform prewarped at ``f_warp`` (exact gain and phase at 0 and f_warp),
    run forward in time from the state the past left (see ``apply``).
    """

    b: list
    a: list
    f_warp_hz: float
    method: str = "exact"

    def h(self, f_hz):
        w = 2 * np.pi * np.atleast_1d(np.asarray(f_hz, float))
        return signal.freqs(self.b, self.a, worN=w)[1]

    def h_effective(self, f_hz, fs):
        """The gain the generator actually applies at f (continuous or digital)."""
        if self.method == "exact":
            return self.h(f_hz)
        bz, az = bilinear_prewarped(self.b, self.a, self.f_warp_hz, fs)
        return signal.freqz(bz, az, worN=np.atleast_1d(np.asarray(f_hz, float)), fs=fs)[1]

    def apply(self, x, fs, prime=None):
        """Filter ``x`` (3, N+1), periodic over the run (sample N = sample 0).

        ``prime``: the signal just before t = 0 (bilinear method; None = zero past).
        """
        n = x.shape[1] - 1
        if self.method == "exact":
            spec = np.fft.rfft(x[:, :n], axis=1)
            hh = self.h(np.fft.rfftfreq(n, 1.0 / fs))
            if n % 2 == 0:
                hh[-1] = hh[-1].real
            y = np.fft.irfft(spec * hh, n=n, axis=1)
            return np.concatenate([y, y[:, :1]], axis=1)
        if self.method != "bilinear":
            raise ValueError(f"filter method {self.method!r}: exact or bilinear")
        bz, az = bilinear_prewarped(self.b, self.a, self.f_warp_hz, fs)
        if prime is not None and prime.shape[-1]:
            return signal.lfilter(bz, az, np.concatenate([prime, x], axis=1), axis=1)[:, prime.shape[-1]:]
        return signal.lfilter(bz, az, x, axis=1)


def high_pass(cfg):
    """AC coupling of the vibration sensors ``s / (s + w_c)`` (first order)."""
    return Lti([1.0, 0.0], [1.0, 2 * math.pi * cfg.vib_hp_hz], cfg.vib_hp_hz, cfg.filter_method)


def mount(cfg):
    """The hidden mount resonance as an ``Lti`` (None: rigid mount)."""
    if cfg.resonance is None:
        return None
    b, a = cfg.resonance.analog()
    return Lti(b, a, cfg.resonance.f0_hz, cfg.filter_method)


def tone_through(cfg, t, lti):
    """Each axis's tone in its steady state through ``lti`` (None: unchanged), on times ``t``."""
    out = np.zeros((3, len(t)))
    for k in range(3):
        f, a, ph = cfg.tone_hz[k], cfg.tone_amp_g[k], cfg.tone_phase_rad[k]
        if a == 0:
            continue
        g = complex(lti.h_effective(f, cfg.fine_rate_hz)[0]) if lti else 1.0 + 0j
        out[k] = abs(g) * a * np.sin(2 * np.pi * f * t + ph + math.atan2(g.imag, g.real))
    return out


def boxcar_readings(u, m):
    """Mean over each interval of M fine samples, exact for the piecewise-linear signal.

    ``u``: (..., J*M + 1) samples at n = 0..J*M. Reading j (1-based) covers
    ``n = (j-1)M .. jM`` with trapezoid weights (1/2 at both ends) / M.
    """
    j = (u.shape[-1] - 1) // m
    body = u[..., : j * m].reshape(u.shape[:-1] + (j, m)).sum(axis=-1)
    return (body - 0.5 * u[..., 0 : j * m : m] + 0.5 * u[..., m : j * m + 1 : m]) / m


def boxcar_response(f_hz, ta):
    """Response of a reading (mean over ``(t - ta, t]``, latched at t) to ``e^{j 2 pi f t}``."""
    w = 2 * np.pi * np.asarray(f_hz, float)
    return (1 - np.exp(-1j * w * ta)) / (1j * w * ta)


# ---------------------------------------------------------------------------------------
# Closed-form vibration error (MODEL.md sections 5 and 6)


def ve_published(p, aL3, aB3, aB1, aB2, sigma3, K31=0.0, K32=0.0):
    """The papers' VE, MODEL.md section 5: [P1 (13)-(16)], [P2 (3)-(5)].

    Deterministic [P1 (13), (15)-(16)] plus random [P1 (14), (16)], summed (as the
    compensation algorithm [P2 (19)-(20)] removes them one after the other).
    Amplitudes are unsigned; the papers take all axes in phase.
    """
    ld = p.lam * p.k1 * p.d1a
    det = (
        0.637 * ld * aB3 + 0.5 * p.k2 * aB3**2 + 0.375 * p.k4 * aB3**4  # d0(1)
        + 0.5 * p.m31 * aB3 * aB1  # d0(2)
        + 0.5 * p.m32 * aB3 * aB2  # d0(3)
        + (1.5 * p.k3 * aB3**2 + 1.875 * p.k5 * aB3**4) * aL3  # delta(1) aL3
        + 3 * p.k4 * aB3**2 * aL3**2  # delta(2) aL3^2
        + 5 * p.k5 * aB3**2 * aL3**3  # delta(3) aL3^3
    )
    s2 = sigma3**2
    rnd = (
        0.125 * ld * sigma3 + p.k2 * s2 + p.k4 * s2**2  # d0(1)
        + p.m31 * K31 + p.m32 * K32  # d0(2), d0(3)
        + (3 * p.k3 * s2 + 5 * p.k5 * s2**2) * aL3  # delta(1)
        + 6 * p.k4 * s2 * aL3**2  # delta(2)
        + 10 * p.k5 * s2 * aL3**3  # delta(3)
    )
    return float(det + rnd)


def mean_abs_tone_gauss(aL, c, sigma, n_theta=65536):
    """``E|aL + c sin(theta) + x|``, theta uniform, x ~ N(0, sigma^2) (MODEL.md section 6)."""
    c = abs(c)
    if sigma <= 0:
        if c > abs(aL):
            return (2 / math.pi) * (aL * math.asin(aL / c) + math.sqrt(c * c - aL * aL))
        return abs(aL)
    th = 2 * np.pi * np.arange(n_theta) / n_theta
    mu = aL + c * np.sin(th)
    # folded normal mean, MODEL.md section 6
    e = sigma * math.sqrt(2 / math.pi) * np.exp(-(mu**2) / (2 * sigma**2)) + mu * (
        1 - 2 * special.ndtr(-mu / sigma)
    )
    return float(e.mean())


def ve_exact(p, aL3, aL1, aL2, c3, sigma3, cross31=0.0, cross32=0.0):
    """Exact static VE, MODEL.md section 6: E[(FP)] under vibration minus (FP) at rest.

    ``a3 = aL3 + c3 sin(theta) + x``, theta uniform (a tone over whole periods), x ~
    N(0, sigma3^2). Powers: Gauss-Hermite in x (8 nodes) times a uniform theta grid
    (64 points), exact for the degree-5 polynomial. ``cross31 = E[v3 v1]`` of the
    vibration along IA and OA (tones: ``0.5 c3 c1 cos(phi3 - phi1)`` at one frequency,
    0 otherwise; plus ``K_31(0)``), likewise ``cross32``; ``E[a3 a1] = aL3 aL1 + cross31``.
    """
    z, w = np.polynomial.hermite.hermgauss(8)
    x = math.sqrt(2) * sigma3 * z
    wx = w / math.sqrt(math.pi)
    th = 2 * np.pi * np.arange(64) / 64
    a3 = aL3 + c3 * np.sin(th)[:, None] + x[None, :]
    wt = np.broadcast_to(wx[None, :] / 64, a3.shape)
    e = [float(np.sum(wt * a3**n)) for n in range(6)]
    mean_af = (
        p.a0_g
        + p.k1 * p.lam * (e[1] + 0.5 * p.d1a * mean_abs_tone_gauss(aL3, c3, sigma3))
        + p.k2 * e[2] + p.k3 * e[3] + p.k4 * e[4] + p.k5 * e[5]
        + p.m1 * aL1 + p.m2 * aL2
        + p.m31 * (aL3 * aL1 + cross31) + p.m32 * (aL3 * aL2 + cross32)
    )
    return float(mean_af - p.af(aL3, aL1, aL2))


def sigma2_through(cfg, axis, res):
    """``int S_axis(f) |H(j 2 pi f)|^2 df`` (``res`` None: ``|H| = 1``)."""
    total = 0.0
    for lo, hi, s in cfg.random_bands:
        if s[axis] == 0:
            continue
        if res is None:
            total += s[axis] * (hi - lo)
        else:
            f = np.linspace(lo, hi, 20001)
            total += s[axis] * np.trapezoid(np.abs(res.h(f)) ** 2, f)
    return total


# ---------------------------------------------------------------------------------------
# The simulation


@dataclass
class RunResult:
    cfg: RunConfig
    triad: list
    t_accel: np.ndarray  # (J,) latch times
    accel_v: np.ndarray  # (J, 3) recorded outputs (with noise)
    accel_clean_g: np.ndarray  # (J, 3) readings without noise, in g (aF)
    t_vib: np.ndarray  # (Ns,)
    vib_v: np.ndarray  # (Ns, 3)
    ref_g: np.ndarray  # (Ns, 3)
    truth: dict
    fine: dict  # fine-grid arrays, for tests: t, a_base, a_unit, rand_unit, tone_unit
    sensed_g: np.ndarray | None = None  # (J, 3) interval mean of e_IA . a at each unit
    drift_g_per_s: np.ndarray | None = None  # (3,) each unit's drift rate r_u

    @property
    def error_g(self):
        """(J, 3) noise-free, drift-free reading (U/K1) minus ``sensed_g``."""
        return self.accel_clean_g - self.sensed_g


def simulate(cfg: RunConfig, triad=None, keep_fine=False) -> RunResult:
    """Simulate one run (steps 1-7 of the module doc) and compute its truth."""
    triad = triad or default_triad()
    cfg = resolve_conditions(cfg)
    cfg.validate()
    fs = cfg.fine_rate_hz
    n = int(round(cfg.t_run * fs))
    t = np.arange(n + 1) / fs
    env = envelope(cfg, t)
    g_vec = cfg.gravity_g * np.asarray(cfg.orientation)
    m = int(round(fs / cfg.accel_rate_hz))
    j = n // m
    t_accel = np.arange(1, j + 1) / cfg.accel_rate_hz

    # step 2: base vibration (g), per body axis
    tone_b = tone(cfg, t) * env
    has_random = any(any(v > 0 for v in s) for _, _, s in cfg.random_bands)
    rand_raw = random_vibration(cfg, n) if has_random else None
    rand_b = rand_raw * env if has_random else np.zeros((3, n + 1))
    vib_b = tone_b + rand_b

    # step 3: mount resonance (vibration only; gravity passes with DC gain 1).
    # Flight-like runs are in their steady state from t = 0: the tone goes through
    # the mount analytically, the periodic random vibration through ``Lti.apply``
    # (bilinear: primed with the run's periodic tail, and the tone at negative times).
    mnt = mount(cfg)
    thr = cfg.vibrate_throughout
    prime_n = int(round(min(cfg.t_run, max(0.2, 3 * cfg.settle)) * fs)) if thr else 0
    rand_prime = rand_b[:, n - prime_n : n] if prime_n else None
    if mnt is None:
        tone_u, rand_u = tone_b, rand_b
    elif thr:
        tone_u = tone_through(cfg, t, mnt)
        rand_u = mnt.apply(rand_b, fs, rand_prime) if has_random else rand_b
    else:
        tone_u = mnt.apply(tone_b, fs)
        rand_u = mnt.apply(rand_b, fs) if has_random else rand_b
    vib_u = tone_u + rand_u
    a_unit = g_vec[:, None] + vib_u
    a_base = g_vec[:, None] + vib_b

    # step 5, linear part: exact continuous boxcar of the vibration at the unit, per axis
    box_u = exact_boxcar_readings(cfg, rand_u if thr else vib_u, m, j)
    if thr:
        box_u += steady_tone_boxcar(cfg, t_accel, mnt)

    # steps 4-5: conversion function at every fine sample, readings
    clean = np.empty((j, 3))
    nonlin_read = np.empty((j, 3))
    # the hidden effects (docs/effects.md): zero-strength ones are skipped, so that such a
    # rig is bit for bit the rig without them
    effects = [e for e in cfg.effects if not e.is_null()]
    body = body_sigs(cfg, vib_u, rand_u, mnt) if (effects or cfg.unit_response) else None
    eff_read = np.zeros((j, 3))
    unit_extra = [None] * 3
    for i, u in enumerate(triad):
        p = u.passport
        if cfg.unit_response is not None or any(e.acts_on(i) for e in effects):
            aL3, aL1, aL2 = u.e_ia @ g_vec, u.e_oa @ g_vec, u.e_pa @ g_vec
            lin_vib, nonlin_read[:, i], eff_read[:, i], _, unit_extra[i] = unit_effects(
                cfg, u, i, t, t_accel, m, j, body, box_u, a_unit, g_vec, effects)
            clean[:, i] = ((p.a0_g + p.k1 * p.lam * aL3 + p.m1 * aL1 + p.m2 * aL2) + lin_vib + nonlin_read[:, i]
                           + eff_read[:, i])
            continue
        a3, a1, a2 = u.e_ia @ a_unit, u.e_oa @ a_unit, u.e_pa @ a_unit
        lin = p.k1 * p.lam * a3 + p.m1 * a1 + p.m2 * a2
        nl = p.af(a3, a1, a2) - p.a0_g - lin  # (FP) minus its linear part
        aL3, aL1, aL2 = u.e_ia @ g_vec, u.e_oa @ g_vec, u.e_pa @ g_vec
        lin_vib = (p.k1 * p.lam * u.e_ia + p.m1 * u.e_oa + p.m2 * u.e_pa) @ box_u
        nonlin_read[:, i] = boxcar_readings(nl, m)
        clean[:, i] = (p.a0_g + p.k1 * p.lam * aL3 + p.m1 * aL1 + p.m2 * aL2) + lin_vib + nonlin_read[:, i]
    k1v = np.array([u.passport.K1_v_per_g for u in triad])
    rng_u = np.random.default_rng(_seedseq(cfg, 1, cfg.repeat, STREAM_UNIT_NOISE))
    noisy = clean + cfg.unit_noise_g * rng_u.standard_normal((j, 3))
    drift = drift_rates_g_per_s(cfg)
    if cfg.unit_drift_ug_per_s != 0:
        # r_u t averaged over the reading's interval (t_j - T_a, t_j]: r_u (t_j - T_a / 2)
        noisy = noisy + drift[None, :] * (t_accel - 0.5 / cfg.accel_rate_hz)[:, None]
    accel_v = k1v * noisy
    # per-reading truth: the interval mean of what each unit senses along its IA
    # (gravity + the vibration at the unit, exact boxcar), and the noise-free,
    # drift-free reading's error against it
    e_ia_units = np.array([u.e_ia for u in triad])
    sensed = (e_ia_units @ g_vec)[None, :] + (e_ia_units @ box_u).T

    # step 6: vibration sensors on the base, along each unit's IA, AC-coupled. Gravity
    # is constant and the rig stood still long before the record, so the AC coupling's
    # response to it has decayed to 0: only the vibration goes through the high-pass.
    ns = int(round(cfg.t_run * cfg.sensor_rate_hz))
    r = cfg.sensor_stride
    e_ia = np.array([u.e_ia for u in triad])
    hp = high_pass(cfg)
    # The acquisition delay D: the sample stamped s holds the sensor's signal at s - D.
    # Delay and AC coupling commute (both linear, time-invariant), so the base vibration
    # is delayed before the high-pass: the tone and the envelope analytically (t - D),
    # the periodic random vibration by e^{-j w D} on its DFT bins (exact: it is a sum of
    # the bins k / T_run). D = 0 takes the original path, bit for bit.
    dly = cfg.daq_delay_s
    if dly:
        env_d = envelope(cfg, t - dly)
        rand_d = delay_periodic(rand_raw, fs, dly) * env_d if has_random else np.zeros((3, n + 1))
        vib_b_d = tone(cfg, t - dly) * env_d + rand_d
    else:
        rand_d, vib_b_d = rand_b, vib_b
    if thr and cfg.filter_method == "exact":
        s_hp = e_ia @ tone_through(cfg, t - dly if dly else t, hp)
        if has_random:
            s_hp = s_hp + hp.apply(e_ia @ rand_d, fs)
    elif thr:
        # bilinear: run first over the vibration before t = 0 (tone at negative times,
        # periodic random tail), long enough for the AC coupling to settle (30 time constants)
        hp_n = min(n, int(math.ceil(30 / (2 * math.pi * cfg.vib_hp_hz) * fs)))
        t_prime = -np.arange(hp_n, 0, -1) / fs
        t_prime_d = t_prime - dly if dly else t_prime
        s_hp = hp.apply(e_ia @ vib_b_d, fs, e_ia @ (tone(cfg, t_prime_d) + rand_d[:, n - hp_n : n]))
    else:
        s_hp = hp.apply(e_ia @ vib_b_d, fs)
    if any(g != 0 for g in cfg.sensor_gain_error):
        # sensor k reads (1 + G_k) times the vibration along unit k's IA (docs/effects.md
        # sensor_error, gain only); linear, so before or after the AC coupling alike
        s_hp = s_hp * (1.0 + np.asarray(cfg.sensor_gain_error, float))[:, None]
    rng_v = np.random.default_rng(_seedseq(cfg, 1, cfg.repeat, STREAM_VIB_NOISE))
    vib_v = cfg.vib_sens_v_per_g * (
        s_hp[:, 0 : ns * r : r].T + cfg.vib_noise_g * rng_v.standard_normal((ns, 3))
    )
    t_vib = np.arange(ns) / cfg.sensor_rate_hz

    # step 7: reference accelerometer on the base
    rng_r = np.random.default_rng(_seedseq(cfg, 1, cfg.repeat, STREAM_REF_NOISE))
    ref_g = a_base[:, 0 : ns * r : r].T + cfg.ref_noise_g * rng_r.standard_normal((ns, 3))
    if cfg.ref_sens_v_per_g is not None:
        # AC-coupled in V (step 7, ``ref_chain``): the base vibration delayed by D (tone
        # and envelope at t - D, the periodic random vibration by e^{-j w D}), through
        # the first-order high-pass exactly (the run starts and ends still), at the
        # sensor rate; the same noise draws as the DC-coupled reference, referred to
        # the input.
        d_r = cfg.ref_delay_s
        env_r = envelope(cfg, t - d_r)
        rand_r = (delay_periodic(rand_raw, fs, d_r) if d_r else rand_raw) * env_r if has_random \
            else np.zeros((3, n + 1))
        hp_r = Lti([1.0, 0.0], [1.0, 2 * math.pi * cfg.ref_hp_hz], cfg.ref_hp_hz, cfg.filter_method)
        ref_hp = hp_r.apply(tone(cfg, t - d_r) * env_r + rand_r, fs)
        ref_g = cfg.ref_sens_v_per_g * (
            ref_hp[:, 0 : ns * r : r].T + cfg.ref_noise_g * rng_r.standard_normal((ns, 3))
        )

    fine = {"t": t, "a_base": a_base, "a_unit": a_unit, "rand_unit": rand_u, "tone_unit": tone_u,
            "nonlin_readings_g": nonlin_read, "vib_unit_readings_g": box_u,
            "effect_readings_g": eff_read, "unit_extra": unit_extra}
    res = RunResult(cfg, triad, t_accel, accel_v, clean, t_vib, vib_v, ref_g, {}, fine,
                    sensed_g=sensed, drift_g_per_s=drift)
    res.truth = make_truth(res)
    if not keep_fine:
        res.fine = {}
    return res


def delay_periodic(x, fs, delay_s):
    """``x(t - delay_s)`` for T_run-periodic, band-limited samples ``x`` (3, N+1): the
    factor ``e^{-j w D}`` on the run's DFT bins (exact for a sum of bins k / T_run)."""
    n = x.shape[1] - 1
    spec = np.fft.rfft(x[:, :n], axis=1)
    h = np.exp(-2j * np.pi * np.fft.rfftfreq(n, 1.0 / fs) * delay_s)
    if n % 2 == 0:
        h[-1] = h[-1].real  # the Nyquist bin of a real signal stays real (it is empty here)
    y = np.fft.irfft(spec * h, n=n, axis=1)
    return np.concatenate([y, y[:, :1]], axis=1)


def exact_boxcar_readings(cfg, x, m, j):
    """Continuous boxcar of band-limited, T_run-periodic signals ``x`` (3, N+1) at ``t = jM/fs``.

    The mean of ``x`` over ``(t - T_a, t]`` is applied in the frequency domain,
    ``(1 - e^{-j w T_a}) / (j w T_a)`` (the boxcar latched at its end), to the
    band-limited (sinc) interpolation of the samples: exact for the tone and random
    vibration, which lie far below Nyquist. The signal must be periodic over the run:
    it is (zero at both ends while still, or periodic random vibration).
    """
    n = x.shape[1] - 1
    fs = cfg.fine_rate_hz
    ta = 1.0 / cfg.accel_rate_hz
    spec = np.fft.rfft(x[:, :n], axis=1)
    w = 2 * np.pi * np.fft.rfftfreq(n, 1.0 / fs)
    h = np.ones_like(w, dtype=complex)
    nz = w > 0
    h[nz] = (1 - np.exp(-1j * w[nz] * ta)) / (1j * w[nz] * ta)
    if n % 2 == 0:
        h[-1] = h[-1].real  # the Nyquist bin of a real signal stays real
    y = np.fft.irfft(spec * h, n=n, axis=1)
    idx = (np.arange(1, j + 1) * m) % n
    return y[:, idx]


def steady_tone_boxcar(cfg, t_accel, lti):
    """Boxcar readings of each axis's tone at the unit in steady state (flight-like runs).

    The tone through the mount is ``|H| A sin(w t + phi + arg H)``; its mean over
    ``(t - T_a, t]`` is ``|H| A (cos(w (t - T_a) + psi) - cos(w t + psi)) / (w T_a)``.
    """
    ta = 1.0 / cfg.accel_rate_hz
    out = np.zeros((3, len(t_accel)))
    for k in range(3):
        f, a, ph = cfg.tone_hz[k], cfg.tone_amp_g[k], cfg.tone_phase_rad[k]
        if a == 0 or f == 0:
            continue
        g = complex(lti.h_effective(f, cfg.fine_rate_hz)[0]) if lti else 1.0 + 0j
        w = 2 * np.pi * f
        psi = ph + math.atan2(g.imag, g.real)
        out[k] = abs(g) * a * (np.cos(w * (t_accel - ta) + psi) - np.cos(w * t_accel + psi)) / (w * ta)
    return out


# ---------------------------------------------------------------------------------------
# Hidden effects (docs/effects.md): the unit's response, the sensors' gain, output effects


@dataclass
class UnitResponse:
    """The unit's own response to IA acceleration, ``wn^2 / (s^2 + 2 zeta wn s + wn^2)``
    (docs/effects.md ``unit_response``; DC gain 1, so gravity passes)."""

    natural_freq_hz: float
    damping_ratio: float

    def analog(self):
        wn = 2 * math.pi * self.natural_freq_hz
        return [wn * wn], [1.0, 2 * self.damping_ratio * wn, wn * wn]

    def h(self, f_hz):
        b, a = self.analog()
        return signal.freqs(b, a, worN=2 * np.pi * np.atleast_1d(np.asarray(f_hz, float)))[1]

    def settle_s(self):
        return 25.0 / (self.damping_ratio * 2 * math.pi * self.natural_freq_hz)

    def validate(self, fs):
        probs = []
        if not (math.isfinite(self.natural_freq_hz) and 0 < self.natural_freq_hz <= 1e6):
            probs.append(f"unit_response.natural_freq_hz = {self.natural_freq_hz}: must be finite and 0 < f <= 1e6 Hz")
        elif self.natural_freq_hz >= fs / 2:
            probs.append(f"unit_response.natural_freq_hz = {self.natural_freq_hz}: must be below the fine grid's "
                         f"Nyquist frequency {fs / 2} Hz")
        if not (math.isfinite(self.damping_ratio) and 0.01 <= self.damping_ratio <= 10):
            probs.append(f"unit_response.damping_ratio = {self.damping_ratio}: must be finite and 0.01 <= zeta <= 10")
        return probs


# kind -> {param: (default or None if required, rule text, check)}; names and ranges as
# docs/effects.md states them (the lab's library validates the same ranges).
OUTPUT_EFFECTS = {
    "vibropendulous": {
        "c_rad_per_g": (None, "must be finite and |c| <= 0.1 rad/g", lambda v: abs(v) <= 0.1),
        "tau_s": (None, "must be finite and 0 < tau <= 10 s", lambda v: 0 < v <= 10),
    },
    "anisoelastic": {
        "k_ae_per_g": (None, "must be finite and |k_ae| <= 0.01 1/g", lambda v: abs(v) <= 0.01),
    },
    "high_order_nonlinearity": {
        "k6_ppm_per_g5": (0.0, "must be finite and |k6| <= 1e4 ppm/g^5", lambda v: abs(v) <= 1e4),
        "k7_ppm_per_g6": (0.0, "must be finite and |k7| <= 1e4 ppm/g^6", lambda v: abs(v) <= 1e4),
    },
    "heating": {
        "c_g_per_g2": (None, "must be finite and |c| <= 0.1 g/g^2", lambda v: abs(v) <= 0.1),
        "tau_s": (None, "must be finite and 0 < tau <= 1e6 s", lambda v: 0 < v <= 1e6),
    },
    "saturation": {
        "range_g": (None, "must be finite and 0.1 <= range <= 1e4 g", lambda v: 0.1 <= v <= 1e4),
    },
    "scale_factor_frequency": {
        "corner_hz": (None, "must be finite and 0 < f <= 1e6 Hz", lambda v: 0 < v <= 1e6),
        "lambda_hf": (None, "must be finite and 0 < lambda_hf <= 10", lambda v: 0 < v <= 10),
    },
}

OUTPUT_EFFECT_MODELS = {
    "vibropendulous": "out += c_rad_per_g * HP[a3](t) * a2(t), HP(s) = s tau/(1 + s tau) on the total IA "
    "acceleration at the unit (after the path effects; zero at DC), a2 the total PA acceleration",
    "anisoelastic": "out += k_ae_per_g * a1(t) * a2(t) (total OA and PA accelerations)",
    "high_order_nonlinearity": "out += 1e-6 (k6_ppm_per_g5 a3^6 + k7_ppm_per_g6 a3^7) (total IA acceleration)",
    "heating": "tau db/dt = c_g_per_g2 v3(t)^2 - b, b(0) = 0 at the run start, v3 the IA vibration at the unit "
    "(after the path effects); out += b(t)",
    "saturation": "the whole output (FP plus every other effect's term) clipped to +-range_g, per fine sample",
    "scale_factor_frequency": "out += k1 (1 + 0.5 d1A sign(a3)) (L[a3] - a3), L(s) = (1 + lambda_hf s/wc)/(1 + s/wc), "
    "wc = 2 pi corner_hz, k1 and d1A from the unit's passport",
}


@dataclass
class OutputEffect:
    """One output effect of docs/effects.md (hook ``at_unit_output``), on ``units`` (None: all)."""

    kind: str
    params: dict
    units: tuple | None = None

    def acts_on(self, i):
        return self.units is None or i in self.units

    def is_null(self):
        """Zero strength: the effect changes nothing (skipped, so the data are bit-identical)."""
        p = self.params
        if self.kind == "vibropendulous":
            return p["c_rad_per_g"] == 0
        if self.kind == "anisoelastic":
            return p["k_ae_per_g"] == 0
        if self.kind == "high_order_nonlinearity":
            return p["k6_ppm_per_g5"] == 0 and p["k7_ppm_per_g6"] == 0
        if self.kind == "heating":
            return p["c_g_per_g2"] == 0
        if self.kind == "scale_factor_frequency":
            return p["lambda_hf"] == 1
        return False

    def to_dict(self):
        return {"kind": self.kind, **self.params, "units": list(self.units) if self.units is not None else [0, 1, 2],
                "hook": "at_unit_output", "model": OUTPUT_EFFECT_MODELS[self.kind], "zero_strength": self.is_null()}


def parse_effect(spec):
    """``kind:key=value,key=value`` (``units=0``, ``units=0+2``): an ``OutputEffect``.

    Unknown kinds and keys, missing required keys and values outside their range are
    reported all at once, naming the effect, key, value and rule (docs/effects.md).
    """
    kind, _, rest = spec.partition(":")
    kind = kind.strip()
    if kind not in OUTPUT_EFFECTS:
        raise ValueError(f"--effect {spec!r}: unknown kind {kind!r} (want one of {', '.join(OUTPUT_EFFECTS)})")
    table = OUTPUT_EFFECTS[kind]
    given, units, probs = {}, None, []
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq:
            probs.append(f"effect[{kind}] {item!r}: want key=value")
        elif key == "units":
            try:
                units = tuple(sorted({int(x) for x in value.split("+")}))
            except ValueError:
                units = ()
            if not units or any(u not in (0, 1, 2) for u in units):
                probs.append(f"effect[{kind}].units = {value!r}: must be unit indices 0, 1, 2 joined by '+'")
        elif key not in table:
            probs.append(f"effect[{kind}].{key}: unknown key (want {', '.join(table)}, units)")
        else:
            try:
                given[key] = float(value)
            except ValueError:
                probs.append(f"effect[{kind}].{key} = {value!r}: not a number")
    params = {}
    for key, (default, rule, ok) in table.items():
        if key not in given:
            if default is None:
                probs.append(f"effect[{kind}].{key}: required ({rule})")
            else:
                params[key] = default
            continue
        v = given[key]
        if not (math.isfinite(v) and ok(v)):
            probs.append(f"effect[{kind}].{key} = {v!r}: {rule}")
        params[key] = v
    if kind == "high_order_nonlinearity" and not given.keys() & table.keys():
        probs.append(f"effect[{kind}]: at least one of {', '.join(table)}")
    if probs:
        raise ValueError("; ".join(probs))
    return OutputEffect(kind, params, units)


@dataclass
class Sig:
    """A signal at the unit: ``per`` (N+1 fine samples, periodic over the run: the whole
    vibration of a shaker run, the random part of a flight-like one) plus steady tones
    ``Im(c e^{j 2 pi f t})`` (flight-like runs: each tone analytically, in steady state)."""

    per: np.ndarray
    tones: list

    def fine(self, t):
        out = self.per.copy()
        for f, c in self.tones:
            w = 2 * np.pi * f * t
            out += c.real * np.sin(w) + c.imag * np.cos(w)
        return out

    def through(self, lti, fs, prime_n=0, causal_tau_s=None, t=None):
        """Through ``lti`` (``Lti``; tones by its effective gain). ``prime_n``: bilinear
        flight-like runs run first over the periodic tail. ``causal_tau_s``: a first-order
        high-pass ``s tau/(1 + s tau)`` (times a constant) on a shaker run, whose input is
        0 at t = 0 and whose state was at rest: the periodic response ``y_p`` on the DFT
        bins becomes the causal one by ``y_p(t) - y_p(0) e^{-t/tau}`` (exact: the two
        differ by the free response that makes the low-pass state zero at t = 0)."""
        x = self.per[None, :]
        prime = x[:, x.shape[1] - 1 - prime_n : x.shape[1] - 1] if prime_n else None
        y = lti.apply(x, fs, prime)[0]
        if causal_tau_s is not None:
            y = y - y[0] * np.exp(-t / causal_tau_s)
        tones = [(f, c * complex(lti.h_effective(f, fs)[0])) for f, c in self.tones]
        return Sig(y, tones)

    def boxcar(self, cfg, t_accel, m, j):
        """Readings: the exact continuous boxcar (``exact_boxcar_readings``; tones analytically)."""
        out = exact_boxcar_readings(cfg, self.per[None, :], m, j)[0]
        ta = 1.0 / cfg.accel_rate_hz
        for f, c in self.tones:
            out = out + (c * complex(boxcar_response(f, ta)) * np.exp(2j * np.pi * f * t_accel)).imag
        return out


def body_sigs(cfg, vib_u, rand_u, mnt):
    """The vibration at the units per body axis as (per (3, N+1), tones [(axis, f, c)])."""
    if not cfg.vibrate_throughout:
        return vib_u, []
    tones = []
    for k in range(3):
        f, a, ph = cfg.tone_hz[k], cfg.tone_amp_g[k], cfg.tone_phase_rad[k]
        if a == 0:
            continue
        g = complex(mnt.h_effective(f, cfg.fine_rate_hz)[0]) if mnt else 1.0 + 0j
        tones.append((k, f, a * complex(math.cos(ph), math.sin(ph)) * g))
    return rand_u, tones


def project(body, e):
    per, tones = body
    return Sig(e @ per, [(f, e[k] * c) for k, f, c in tones if e[k] != 0])


def first_order_lag_foh(p, fs, tau_s):
    """``tau db/dt = p(t) - b``, ``b(0) = 0``, for ``p`` linear between the fine samples
    (first-order hold): the exact solution of that piecewise-linear input, sample by sample,
    ``b[n] = alpha b[n-1] + w1 p[n] + w0 p[n-1]``, ``alpha = e^{-h/tau}``."""
    r = 1.0 / (fs * tau_s)
    alpha = math.exp(-r)
    one_minus = -math.expm1(-r)
    # w1 = 1 - (1 - alpha)/r, by its series when r is small (no cancellation)
    w1 = r / 2 - r * r / 6 + r**3 / 24 - r**4 / 120 if r < 1e-3 else 1.0 - one_minus / r
    w0 = one_minus - w1
    q = w1 * p[1:] + w0 * p[:-1]
    b = np.zeros_like(p)
    b[1:] = signal.lfilter([1.0], [1.0, -alpha], q)
    return b


def unit_effects(cfg, u, i, t, t_accel, m, j, body, box_u, a_unit, g_vec, effects):
    """Unit ``i`` with its path and output effects: the parts of its readings.

    Returns ``(lin_vib, nonlin, eff_read, v3_box, extra)``: the linear response to the
    vibration (exact boxcar), the (FP) rest averaged by the trapezoid rule, the output
    effects' part of the reading (their parts linear in the vibration by the exact
    boxcar, the rest and the clip by the trapezoid rule), the reading of the IA vibration
    the unit's (FP) sees, and fine-grid arrays for the tests.
    """
    p = u.passport
    fs = cfg.fine_rate_hz
    thr = cfg.vibrate_throughout
    aL3, aL1, aL2 = float(u.e_ia @ g_vec), float(u.e_oa @ g_vec), float(u.e_pa @ g_vec)
    v1s, v2s = project(body, u.e_oa), project(body, u.e_pa)
    ur = cfg.unit_response
    if ur is None:
        a3, a1, a2 = u.e_ia @ a_unit, u.e_oa @ a_unit, u.e_pa @ a_unit
        v3s = project(body, u.e_ia)
        v3_box = u.e_ia @ box_u
    else:
        b, a = ur.analog()
        lp = Lti(b, a, ur.natural_freq_hz, cfg.filter_method)
        prime_n = int(round(min(cfg.t_run, 0.2 + 3 * ur.settle_s()) * fs)) if thr else 0
        v3s = project(body, u.e_ia).through(lp, fs, prime_n)
        v3_box = v3s.boxcar(cfg, t_accel, m, j)
        a3 = aL3 + v3s.fine(t)
        a1, a2 = u.e_oa @ a_unit, u.e_pa @ a_unit
    lin_vib = p.k1 * p.lam * v3_box + (p.m1 * u.e_oa + p.m2 * u.e_pa) @ box_u
    nl = p.af(a3, a1, a2) - p.a0_g - (p.k1 * p.lam * a3 + p.m1 * a1 + p.m2 * a2)
    nonlin = boxcar_readings(nl, m)

    mine = [e for e in effects if e.acts_on(i)]
    eff_const = 0.0  # constant part (g)
    eff_lin_box = np.zeros(j)  # parts linear in the vibration: exact boxcar
    eff_lin_fine = np.zeros_like(t)
    eff_rest = np.zeros_like(t)  # the rest: trapezoid rule over the fine grid
    eff_sign_read = np.zeros(j)  # sign(a3) x a smooth signal: exact for the piecewise-linear signals
    eff_sign_fine = np.zeros_like(t)
    clips = []
    v3 = v3s.fine(t) if mine else None
    v1 = v1s.fine(t) if mine else None
    v2 = v2s.fine(t) if mine else None
    for e in mine:
        q = e.params
        if e.kind == "vibropendulous":
            # c HP[a3] a2 = c aL2 HP[v3] (linear) + c HP[v3] v2 (HP kills gravity)
            tau = q["tau_s"]
            hp = Lti([tau, 0.0], [tau, 1.0], 1.0 / (2 * math.pi * tau), "exact")
            h = v3s.through(hp, fs, causal_tau_s=None if thr else tau, t=t)
            hf = h.fine(t)
            c = q["c_rad_per_g"]
            eff_lin_box += c * aL2 * h.boxcar(cfg, t_accel, m, j)
            eff_lin_fine += c * aL2 * hf
            eff_rest += c * hf * v2
        elif e.kind == "anisoelastic":
            k = q["k_ae_per_g"]
            eff_const += k * aL1 * aL2
            eff_lin_box += k * (aL1 * v2s.boxcar(cfg, t_accel, m, j) + aL2 * v1s.boxcar(cfg, t_accel, m, j))
            eff_lin_fine += k * (aL1 * v2 + aL2 * v1)
            eff_rest += k * v1 * v2
        elif e.kind == "high_order_nonlinearity":
            k6, k7 = 1e-6 * q["k6_ppm_per_g5"], 1e-6 * q["k7_ppm_per_g6"]
            const = k6 * aL3**6 + k7 * aL3**7
            slope = 6 * k6 * aL3**5 + 7 * k7 * aL3**6
            eff_const += const
            eff_lin_box += slope * v3_box
            eff_lin_fine += slope * v3
            eff_rest += k6 * a3**6 + k7 * a3**7 - const - slope * v3
        elif e.kind == "heating":
            eff_rest += first_order_lag_foh(q["c_g_per_g2"] * v3 * v3, fs, q["tau_s"])
        elif e.kind == "scale_factor_frequency":
            # (L - 1)[a3] = (lambda_hf - 1) (s/wc)/(1 + s/wc) [v3]: a first-order high-pass
            tau = 1.0 / (2 * math.pi * q["corner_hz"])
            lam1 = q["lambda_hf"] - 1.0
            sh = Lti([lam1 * tau, 0.0], [tau, 1.0], q["corner_hz"], "exact")
            d = v3s.through(sh, fs, causal_tau_s=None if thr else tau, t=t)
            df = d.fine(t)
            eff_lin_box += p.k1 * d.boxcar(cfg, t_accel, m, j)
            eff_lin_fine += p.k1 * df
            eff_sign_read += sign_product_readings(a3, 0.5 * p.k1 * p.d1a * df, m)
            eff_sign_fine += 0.5 * p.k1 * p.d1a * np.sign(a3) * df
        elif e.kind == "saturation":
            clips.append(q["range_g"])
    if clips:
        y = p.af(a3, a1, a2) + eff_const + eff_lin_fine + eff_rest + eff_sign_fine
        yc = y
        for r in clips:
            yc = np.clip(yc, -r, r)
        eff_rest = eff_rest + (yc - y)
    eff_read = eff_const + eff_lin_box + boxcar_readings(eff_rest, m) + eff_sign_read if mine else np.zeros(j)
    extra = {"a_unit_axes_g": np.array([a1, a2, a3]) if mine or ur else None,
             "vib_unit_axes_readings_g": np.array([v1s.boxcar(cfg, t_accel, m, j) if ur else u.e_oa @ box_u,
                                                    v2s.boxcar(cfg, t_accel, m, j) if ur else u.e_pa @ box_u,
                                                    v3_box]),
             "effects_still_g": effects_at_rest(p, aL3, aL1, aL2, mine),
             "effect_linear_readings_g": eff_lin_box}
    return lin_vib, nonlin, eff_read, v3_box, extra


def sign_product_readings(a3, d, m):
    """Readings (mean over each interval of M fine samples) of ``sign(a3) d`` with ``a3`` and
    ``d`` linear between the samples: exact for those piecewise-linear signals, as the
    trapezoid rule is for the others. The trapezoid of the samples would miss the jump at
    each zero of ``a3`` inside a sample interval (an O(h) error: 10 % for a 400 Hz tone
    at 6.4 kHz); each such interval gets the exact integral, split at the zero."""
    s = np.sign(a3)
    out = boxcar_readings(s * d, m)
    n = np.nonzero(s[:-1] != s[1:])[0]
    if len(n):
        x = a3[n] / (a3[n] - a3[n + 1])  # where a3 crosses 0, fraction of the interval
        dx = d[n] + x * (d[n + 1] - d[n])
        exact = s[n] * 0.5 * (d[n] + dx) * x + s[n + 1] * 0.5 * (dx + d[n + 1]) * (1 - x)
        corr = exact - 0.5 * (s[n] * d[n] + s[n + 1] * d[n + 1])
        acc = np.zeros(len(out))
        keep = n // m < len(out)
        np.add.at(acc, n[keep] // m, corr[keep])
        out = out + acc / m
    return out


def effects_at_rest(p, aL3, aL1, aL2, effects):
    """What the output effects add to the reading of a still unit (no vibration)."""
    add = 0.0
    for e in effects:
        q = e.params
        if e.kind == "anisoelastic":
            add += q["k_ae_per_g"] * aL1 * aL2
        elif e.kind == "high_order_nonlinearity":
            add += 1e-6 * (q["k6_ppm_per_g5"] * aL3**6 + q["k7_ppm_per_g6"] * aL3**7)
    if not any(e.kind == "saturation" for e in effects):
        return add
    y0 = float(p.af(aL3, aL1, aL2))
    y = y0 + add
    for e in effects:
        if e.kind == "saturation":
            y = min(max(y, -e.params["range_g"]), e.params["range_g"])
    return y - y0


def windows(cfg):
    """Time windows [start, end] of the VE measurement and of the still segments."""
    if cfg.vibrate_throughout:
        return {"vibrating": [cfg.settle, cfg.t_run], "still_before": None, "still_after": None}
    return {
        "vibrating": [cfg.t_on + cfg.ramp_s + cfg.settle, cfg.t_off - cfg.ramp_s],
        "still_before": [0.0, cfg.t_on],
        "still_after": [cfg.t_off + cfg.settle, cfg.t_run],
    }


def reading_mask(cfg, t_accel, win):
    """Readings whose whole interval lies in ``win``."""
    ta = 1.0 / cfg.accel_rate_hz
    eps = 1e-9 * ta
    return (t_accel - ta >= win[0] - eps) & (t_accel <= win[1] + eps)


def effects_truth(cfg):
    """The hidden effects of docs/effects.md, with their parameters (truth.json ``effects``)."""
    out = []
    if cfg.resonance is not None:
        # the hidden mount (step 3, also under "resonance"), in docs/effects.md's names; its
        # "base" form is docs' transmissibility, the "plain" form is not a library effect
        out.append({"kind": "mount_resonance", "freq_hz": cfg.resonance.f0_hz, "q": cfg.resonance.q,
                    "form": cfg.resonance.form, "units": [0, 1, 2], "axes": ["OA", "PA", "IA"],
                    "hook": "at_unit_input", "model": "see resonance"})
    if cfg.unit_response is not None:
        ur = cfg.unit_response
        out.append({"kind": "unit_response", "natural_freq_hz": ur.natural_freq_hz,
                    "damping_ratio": ur.damping_ratio, "units": [0, 1, 2], "hook": "at_unit_input",
                    "model": "the IA component of the vibration at each unit (after the mount) through "
                    "wn^2/(s^2 + 2 zeta wn s + wn^2); OA, PA and gravity untouched; the whole (FP) and the output "
                    "effects see the filtered IA acceleration; sensed{u}_g of readings_truth.csv does not (it is "
                    "the acceleration at the unit)",
                    "discretisation": "exact: H(j w) on the run's DFT bins (flight-like runs: tones analytically)"
                    if cfg.filter_method == "exact" else "bilinear transform prewarped at natural_freq_hz"})
    for k, g in enumerate(cfg.sensor_gain_error):
        if g != 0:
            out.append({"kind": "sensor_error", "gain_error": g, "misalignment_oa_rad": 0.0,
                        "misalignment_pa_rad": 0.0, "units": [k], "hook": "at_sensor",
                        "model": f"vibration sensor VD{k + 1} reads (1 + gain_error) times the vibration along "
                        f"unit {k}'s IA (before its sensitivity, AC coupling and noise)"})
    for e in cfg.effects:
        out.append(e.to_dict())
    return out


def make_truth(res: RunResult):
    """The sidecar: conditions, passports, and the true VE per unit (for tests only)."""
    cfg, triad = res.cfg, res.triad
    win = windows(cfg)
    mv = reading_mask(cfg, res.t_accel, win["vibrating"])
    g_vec = cfg.gravity_g * np.asarray(cfg.orientation)
    fs = cfg.fine_rate_hz
    t = res.fine["t"]
    fm = (t >= win["vibrating"][0]) & (t <= win["vibrating"][1])
    amps = np.asarray(cfg.tone_amp_g)
    phases = np.asarray(cfg.tone_phase_rad)
    freqs = np.asarray(cfg.tone_hz)
    var_axis = cfg.random_psd_per_axis()

    units = []
    for i, u in enumerate(triad):
        p = u.passport
        aL3, aL1, aL2 = float(u.e_ia @ g_vec), float(u.e_oa @ g_vec), float(u.e_pa @ g_vec)
        af0 = float(p.af(aL3, aL1, aL2))
        # MODEL.md section 3: VE = the extra static error under vibration. The window
        # mean of the vibration itself, <v> (the table's velocity change over the window
        # divided by its length: zero on average, not in a finite window), moves the
        # mean reading by grad(FP)(aL) . <v>, to first order: that is input, not error,
        # and is reported apart: reading_shift = ve_time_domain + first_order_input_mean.
        nl0 = af0 - p.a0_g - p.k1 * p.lam * aL3 - p.m1 * aL1 - p.m2 * aL2
        d3 = (0.5 * p.k1 * p.lam * p.d1a * np.sign(aL3) + 2 * p.k2 * aL3 + 3 * p.k3 * aL3**2
              + 4 * p.k4 * aL3**3 + 5 * p.k5 * aL3**4 + p.m31 * aL1 + p.m32 * aL2)
        grad_nl = d3 * u.e_ia + p.m31 * aL3 * u.e_oa + p.m32 * aL3 * u.e_pa
        grad_lin = p.k1 * p.lam * u.e_ia + p.m1 * u.e_oa + p.m2 * u.e_pa
        ex = res.fine["unit_extra"][i]
        if cfg.unit_response is None:
            v_mean = res.fine["vib_unit_readings_g"][:, mv].mean(axis=1)  # body axes
            first = float((grad_lin + grad_nl) @ v_mean)
            ve_td = float(res.fine["nonlin_readings_g"][mv, i].mean() - nl0 - grad_nl @ v_mean)
        else:
            # the (FP) sees the IA vibration through the unit's response: unit axes OA, PA, IA
            vm = ex["vib_unit_axes_readings_g"][:, mv].mean(axis=1)
            g_u = np.array([p.m31 * aL3, p.m32 * aL3, d3])
            first = float((np.array([p.m1, p.m2, p.k1 * p.lam]) + g_u) @ vm)
            ve_td = float(res.fine["nonlin_readings_g"][mv, i].mean() - nl0 - g_u @ vm)
        shift = float(res.accel_clean_g[mv, i].mean() - af0)
        entry = {
            "name": u.name,
            "ia": u.ia,
            "oa": u.oa,
            "pa": u.pa,
            "aL3_g": aL3,
            "aL1_g": aL1,
            "aL2_g": aL2,
            "still_reading_g": af0,
            "still_reading_v": af0 * p.K1_v_per_g,
            "ve_time_domain_g": ve_td,
            "reading_shift_g": shift,
            "first_order_input_mean_g": first,
            "effects_mean_shift_g": float(res.fine["effect_readings_g"][mv, i].mean()),
            "effects_still_g": float(ex["effects_still_g"]) if ex else 0.0,
            "effects_linear_mean_g": float(ex["effect_linear_readings_g"][mv].mean()) if ex else 0.0,
        }
        entry["effects_ve_g"] = (entry["effects_mean_shift_g"] - entry["effects_still_g"]
                                 - entry["effects_linear_mean_g"])
        # section 8 [P2 (16)] from the recorded (noisy) outputs
        if not cfg.vibrate_throughout:
            m1 = reading_mask(cfg, res.t_accel, win["still_before"])
            m3 = reading_mask(cfg, res.t_accel, win["still_after"])
            u1, u2, u3 = (res.accel_v[mk, i].mean() for mk in (m1, mv, m3))
            entry["ve_section8_measured_g"] = float((u2 - 0.5 * (u1 + u3)) / p.K1_v_per_g)
            entry["section8_still_drift_g"] = float(abs(u1 - u3) / abs(p.K1_v_per_g))

        # closed forms: vibration at the unit (through the resonance) and at the base
        def axis_of(e):
            k = int(np.argmax(np.abs(e)))
            return k, float(np.sign(e[k]))

        (x3, s3), (x1, s1), (x2, s2) = axis_of(u.e_ia), axis_of(u.e_oa), axis_of(u.e_pa)
        for side in ("unit", "sensor"):
            rz = cfg.resonance if side == "unit" else None

            def tone_at(k, sgn):
                h = complex(rz.h(freqs[k])[0]) if rz else 1.0 + 0j
                return sgn * amps[k] * abs(h), phases[k] + math.atan2(h.imag, h.real)

            c3, p3 = tone_at(x3, s3)
            c1, p1 = tone_at(x1, s1)
            c2, p2 = tone_at(x2, s2)
            cr31 = 0.5 * c3 * c1 * math.cos(p3 - p1) if freqs[x3] == freqs[x1] else 0.0
            cr32 = 0.5 * c3 * c2 * math.cos(p3 - p2) if freqs[x3] == freqs[x2] else 0.0
            sig3 = math.sqrt(sigma2_through(cfg, x3, rz))
            entry[f"closed_form_{side}_side"] = {
                "aB3_g": abs(c3),
                "aB1_g": abs(c1),
                "aB2_g": abs(c2),
                "sigma3_g": sig3,
                "K31_g2": 0.0,
                "K32_g2": 0.0,
                "tone_cross31_g2": cr31,
                "tone_cross32_g2": cr32,
                "ve_published_g": ve_published(p, aL3, abs(c3), abs(c1), abs(c2), sig3),
                "ve_exact_g": ve_exact(p, aL3, aL1, aL2, c3, sig3, cr31, cr32),
            }
        # realised random vibration at the unit over the VE window
        r3 = s3 * res.fine["rand_unit"][x3, fm]
        r1 = s1 * res.fine["rand_unit"][x1, fm]
        r2 = s2 * res.fine["rand_unit"][x2, fm]
        sig_r = float(np.sqrt(np.mean(r3 * r3)))
        k31, k32 = float(np.mean(r3 * r1)), float(np.mean(r3 * r2))
        cu = entry["closed_form_unit_side"]
        c3u = math.copysign(cu["aB3_g"], s3)
        entry["realised_unit_side"] = {
            "sigma3_g": sig_r,
            "K31_g2": k31,
            "K32_g2": k32,
            "ve_exact_g": ve_exact(
                p, aL3, aL1, aL2, c3u, sig_r, cu["tone_cross31_g2"] + k31, cu["tone_cross32_g2"] + k32
            ),
        }
        units.append(entry)

    base_sig = np.sqrt(var_axis)
    truth = {
        "generator": "tests/python/rig_generator.py (independent of vibrocomp's simulator)",
        "note": "truth for tests only; never an input of vibrocomp",
        "orientation_name": cfg.orientation_name,
        "orientation": list(cfg.orientation),
        "gravity_g": cfg.gravity_g,
        "gravity_convention": "apparent acceleration of the still rig = gravity_g * orientation "
        "(the body direction pointing up); a unit with IA along it reads aL3 = +gravity_g",
        "triad": [u.to_dict() for u in triad],
        "lambda": "1 (the unit's frequency response is not modelled)" if cfg.unit_response is None
        else "1 in (FP); the unit's IA response is the hidden unit_response effect (see effects)",
        "effects": effects_truth(cfg),
        "tone": {
            "freq_hz": list(cfg.tone_hz),
            "amp_g": list(cfg.tone_amp_g),
            "phase_rad": list(cfg.tone_phase_rad),
            "model": "A_i sin(2 pi f_i t + phi_i) per body axis x, y, z, at the base",
        },
        "random": {
            "bands": [{"f_lo_hz": lo, "f_hi_hz": hi, "psd_g2_per_hz": list(s)} for lo, hi, s in cfg.random_bands],
            "rms_g": list(map(float, base_sig)),
            "model": "Gaussian, independent per axis, bins k/T_run in [f_lo, f_hi), a_k cos + b_k sin, "
            "a_k, b_k ~ N(0, S/T_run); at the base",
        },
        "resonance": None
        if cfg.resonance is None
        else {
            "f0_hz": cfg.resonance.f0_hz,
            "q": cfg.resonance.q,
            "zeta": cfg.resonance.zeta,
            "form": cfg.resonance.form,
            "transfer": "(w0^2 + 2 zeta w0 s)/(s^2 + 2 zeta w0 s + w0^2)"
            if cfg.resonance.form == "base"
            else "w0^2/(s^2 + 2 zeta w0 s + w0^2)",
            "gain_at_f0": float(abs(cfg.resonance.h(cfg.resonance.f0_hz)[0])),
            "discretisation": "exact: H(j w) applied on the run's DFT bins (periodic signals)"
            if cfg.filter_method == "exact"
            else "bilinear transform prewarped at f0, on the fine grid",
            "where": "between the shaker base and the units, per body axis; "
            "vibration sensors and reference on the base",
        },
        "rates": {
            "accel_hz": cfg.accel_rate_hz,
            "sensor_hz": cfg.sensor_rate_hz,
            "oversample": cfg.oversample,
            "fine_hz": fs,
            "fine_samples_per_reading": int(round(fs / cfg.accel_rate_hz)),
            "fine_samples_per_sensor_sample": cfg.sensor_stride,
            "fine_rule": "sensor_hz * oversample when accel_hz divides it, else lcm(sensor_hz, accel_hz) "
            "* oversample",
            "reading": "mean of U over (t - 1/accel_hz, t], latched at t: linear part of (FP) by the exact "
            "continuous boxcar of the band-limited vibration (FFT), the rest by the trapezoid rule "
            "over the fine samples",
        },
        "segments": {
            "vibrate_throughout": cfg.vibrate_throughout,
            "t_run_s": cfg.t_run,
            "vibration_on_s": cfg.t_on,
            "vibration_off_s": cfg.t_off,
            "ramp_s": 0.0 if cfg.vibrate_throughout else cfg.ramp_s,
            "settle_s": cfg.settle,
            "windows_s": win,
            "readings_in_ve_window": int(mv.sum()),
        },
        "vibration_sensor": {
            "sensitivity_v_per_g": cfg.vib_sens_v_per_g,
            "ac_coupling": f"first-order high-pass s/(s + 2 pi {cfg.vib_hp_hz}), "
            + ("exact (frequency domain)" if cfg.filter_method == "exact" else "bilinear prewarped at the corner")
            + ", in steady state for gravity (no DC output)",
            "hp_hz": cfg.vib_hp_hz,
            "axis": "each unit's IA (signed body axis), on the base",
            "noise_g_rms": cfg.vib_noise_g,
            "daq_delay_s": cfg.daq_delay_s,
            "daq_delay": "the sample stamped s holds the sensor's signal at s - daq_delay_s "
            "(exact: tone and envelope analytically, random vibration by e^{-j w D} on the run's DFT bins); "
            "the reference and the accelerometers are not delayed",
        },
        "reference": {"axes": "body x, y, z on the base, DC-coupled, g", "noise_g_rms": cfg.ref_noise_g}
        if cfg.ref_sens_v_per_g is None else
        {"axes": "body x, y, z on the base, AC-coupled, V", "noise_g_rms": cfg.ref_noise_g,
         "ref_chain": {"sensitivity_v_per_g": cfg.ref_sens_v_per_g, "ac_corner_hz": cfg.ref_hp_hz,
                       "delay_s": cfg.ref_delay_s}},
        "unit_noise_g_rms": cfg.unit_noise_g,
        "unit_drift": {
            "ug_per_s": cfg.unit_drift_ug_per_s,
            "rate_g_per_s": [float(x) for x in res.drift_g_per_s],
            "model": "each unit's reading carries r_u t (t from the run start), averaged over the reading's "
            "interval: r_u (t_j - 1/(2 accel_hz)); r_u = ug_per_s * 1e-6 * sign_u, signs from spawn_key "
            "[run_index, 2]; added like the white output noise (not in readings_truth.csv's error_g)",
        },
        "readings_truth": "readings_truth.csv: per reading, sensed{u}_g = mean over (t - 1/accel_hz, t] of "
        "e_IA . (gravity + the vibration at the unit) (exact boxcar), error{u}_g = noise-free, drift-free "
        "reading U/K1 minus sensed{u}_g",
        "seeds": {
            "seed": cfg.seed,
            "run_index": cfg.run_index,
            "repeat": cfg.repeat,
            "conditions_spawn_key": [cfg.run_index, 0],
            "random_spawn_keys": {
                "random_vibration": [cfg.run_index, 1, cfg.repeat, STREAM_RANDOM_VIB],
                "unit_noise": [cfg.run_index, 1, cfg.repeat, STREAM_UNIT_NOISE],
                "vib_noise": [cfg.run_index, 1, cfg.repeat, STREAM_VIB_NOISE],
                "ref_noise": [cfg.run_index, 1, cfg.repeat, STREAM_REF_NOISE],
            },
        },
        "ve_definitions": {
            "ve_time_domain_g": "MODEL.md section 3: mean noise-free reading (g) over the VE window minus "
            "the reading without vibration at the same gravity ((FP) of gravity), minus "
            "first_order_input_mean_g; computed from the nonlinear part of (FP) (all but a0 + k1 lambda a3 "
            "+ m1 a1 + m2 a2) averaged as the readings average it",
            "reading_shift_g": "mean noise-free reading (g) over the VE window minus (FP) of gravity "
            "= ve_time_domain_g + first_order_input_mean_g + effects_mean_shift_g",
            "effects_mean_shift_g": "mean over the VE window of what the hidden output effects add to the "
            "noise-free reading (including their static parts, e.g. k_ae aL1 aL2, and the clip); 0 without "
            "output effects. ve_time_domain_g is the (FP)'s own VE (with the IA vibration through the "
            "unit_response when there is one)",
            "effects_still_g": "what the output effects add to the reading of the still unit (static parts)",
            "effects_linear_mean_g": "the window mean of the output effects' parts linear in the vibration "
            "(c aL2 HP[v3], k_ae (aL1 v2 + aL2 v1), (6 k6 aL3^5 + 7 k7 aL3^6) v3, k1 (L - 1)[v3]): zero over whole "
            "periods, nonzero in a finite window, like first_order_input_mean_g",
            "effects_ve_g": "the vibration error the output effects add: effects_mean_shift_g - effects_still_g - "
            "effects_linear_mean_g (MODEL.md section 3's definition applied to them)",
            "first_order_input_mean_g": "grad (FP)(aL) . <v>: the response to the window mean <v> of the "
            "vibration at the unit (the table's velocity change over the window / its length; zero on "
            "average, nonzero in a finite window; the DC-coupled reference measures it at the base)",
            "ve_section8_measured_g": "MODEL.md section 8 [P2 (16)] from the recorded noisy outputs",
            "closed_form_*_side.ve_published_g": "MODEL.md section 5 (deterministic + random)",
            "closed_form_*_side.ve_exact_g": "MODEL.md section 6, exact mean over tone phase and Gaussian noise",
            "unit_side": "with the vibration the unit sees (through the resonance)",
            "sensor_side": "with the base vibration the sensors see",
            "realised_unit_side": "section 6 exact with the random vibration's realised sigma3/K31/K32 "
            "at the unit over the VE window",
        },
        "units": units,
    }
    return truth


# ---------------------------------------------------------------------------------------
# Writing


def _fmt_cols(cols, digits=None):
    if digits:
        f = ("{:.%dg}" % digits).format
        return [list(map(f, c)) for c in cols]
    return [list(map(repr, c)) for c in cols]


def write_csv(path, header_comment, names, t, data, digits=None):
    """``#`` comment lines, a header, one row per sample (docs/logs.md, ``log import``)."""
    cols = _fmt_cols([t.tolist()], None) + _fmt_cols(data.T.tolist(), digits)
    with open(path, "w", newline="\n") as f:
        for line in header_comment:
            f.write("# " + line + "\n")
        f.write(",".join(names) + "\n")
        f.write("\n".join(map(",".join, zip(*cols))))
        f.write("\n")


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def write_run(res: RunResult, folder, digits=None):
    """Write accel.csv, vib.csv, reference.csv, readings_truth.csv and truth.json into ``folder``."""
    os.makedirs(folder, exist_ok=True)
    cfg = res.cfg
    desc = (
        f"rig_generator: {len(res.triad)} x {res.triad[0].passport.id} on a shaker, orientation "
        f"{cfg.orientation_name} ({', '.join('%.6g' % v for v in cfg.orientation)}), seed {cfg.seed} "
        f"run {cfg.run_index} repeat {cfg.repeat}"
    )
    write_csv(
        os.path.join(folder, "accel.csv"),
        [desc, f"unit outputs U in V, mean over 1/{cfg.accel_rate_hz:g} s, time = end of the interval"],
        ["time_s", "u1_v", "u2_v", "u3_v"],
        res.t_accel,
        res.accel_v,
    )
    write_csv(
        os.path.join(folder, "vib.csv"),
        [desc, f"vibration sensors VD1..VD3 along each unit's IA, {cfg.vib_sens_v_per_g:g} V/g, "
         f"AC-coupled {cfg.vib_hp_hz:g} Hz, {cfg.sensor_rate_hz:g} Hz"],
        ["time_s", "vd1_v", "vd2_v", "vd3_v"],
        res.t_vib,
        res.vib_v,
        digits,
    )
    if cfg.ref_sens_v_per_g is None:
        ref_what, ref_cols = "DC-coupled, g", ["time_s", "ax_g", "ay_g", "az_g"]
    else:
        ref_what = (f"AC-coupled {cfg.ref_hp_hz:g} Hz, {cfg.ref_sens_v_per_g:g} V/g, delay "
                    f"{cfg.ref_delay_s:g} s, V")
        ref_cols = ["time_s", "ax_v", "ay_v", "az_v"]
    write_csv(
        os.path.join(folder, "reference.csv"),
        [desc, f"reference accelerometer on the base, body x y z, {ref_what}, {cfg.sensor_rate_hz:g} Hz"],
        ref_cols,
        res.t_vib,
        res.ref_g,
        digits,
    )
    if cfg.write_rig:
        write_rig(cfg, os.path.join(folder, "rig.toml"))
    write_csv(
        os.path.join(folder, "readings_truth.csv"),
        [desc, f"per reading (time = end of the 1/{cfg.accel_rate_hz:g} s interval, as accel.csv): "
         "sensed = interval mean of e_IA . (gravity + vibration at the unit), g; "
         "error = noise-free, drift-free reading U/K1 minus sensed, g (for tests only)"],
        ["time_s", "sensed1_g", "sensed2_g", "sensed3_g", "error1_g", "error2_g", "error3_g"],
        res.t_accel,
        np.concatenate([res.sensed_g, res.error_g], axis=1),
    )
    with open(os.path.join(folder, "truth.json"), "w") as f:
        json.dump(res.truth, f, indent=1, default=_json_default)
        f.write("\n")


def write_rig(cfg, path):
    """A rig file (docs/logs.md, "A rig's own data") stating what this run's rig knows:
    the vibration sensors' chain, the orientation over the whole run (a static
    reference's one segment) and, for an AC-coupled reference, its chain."""
    up = ", ".join(repr(float(v)) for v in cfg.orientation)
    lines = [
        'format = "vibrocomp-rig/1"',
        'triad = "default"',
        "",
        "[sensors]",
        f"sensitivity_v_per_g = {float(cfg.vib_sens_v_per_g)!r}",
        f"ac_corner_hz = {float(cfg.vib_hp_hz)!r}",
        f"delay_s = {float(cfg.daq_delay_s)!r}",
        "",
        "[reference]",
        'kind = "static"',
        f"gravity_g = {float(cfg.gravity_g)!r}",
        "[[reference.segment]]",
        "from_s = 0.0",
        f"to_s = {float(cfg.t_run)!r}",
        f"up = [{up}]",
    ]
    if cfg.ref_sens_v_per_g is not None:
        lines += [
            "[reference.chain]",
            f"sensitivity_v_per_g = {float(cfg.ref_sens_v_per_g)!r}",
            f"ac_corner_hz = {float(cfg.ref_hp_hz)!r}",
            f"delay_s = {float(cfg.ref_delay_s)!r}",
        ]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def run_repeats(cfg, triad, out, repeats=1, digits=None):
    """One condition, ``repeats`` draws of the random parts: ``out`` or ``out/repKK``."""
    results = []
    for k in range(repeats):
        c = copy.deepcopy(cfg)
        c.repeat = k
        res = simulate(c, triad)
        folder = out if repeats == 1 else os.path.join(out, f"rep{k:02d}")
        write_run(res, folder, digits)
        results.append((folder, res))
    return results


RUNS_CSV_COLUMNS = [
    "run_id", "repeat", "folder", "orientation", "gx", "gy", "gz", "tone_hz",
    "amp_x_g", "amp_y_g", "amp_z_g", "phase_x_rad", "phase_y_rad", "phase_z_rad",
    "random_rms_x_g", "random_rms_y_g", "random_rms_z_g", "resonance_f0_hz", "resonance_q",
]


def run_campaign(base_cfg, triad, out, orientations, tone_freqs, repeats=1, digits=None, log=None):
    """Orientations x tone frequencies, one subfolder per run, and ``runs.csv``.

    Run ids count orientation-major. Each run's tone amplitudes/phases, when not given,
    are drawn from ``(seed, run_id)`` and kept across repeats.
    """
    os.makedirs(out, exist_ok=True)
    rows = []
    rid = 0
    for oname in orientations:
        for f in tone_freqs:
            cfg = copy.deepcopy(base_cfg)
            cfg.orientation = tuple(orientation_vector(oname))
            cfg.orientation_name = oname
            cfg.tone_hz = (float(f),) * 3
            cfg.run_index = rid
            folder = os.path.join(out, f"run{rid:03d}")
            for folder_k, res in run_repeats(cfg, triad, folder, repeats, digits):
                c = res.cfg
                rows.append(
                    [rid, c.repeat, os.path.relpath(folder_k, out), oname, *c.orientation, f,
                     *c.tone_amp_g, *c.tone_phase_rad, *res.truth["random"]["rms_g"],
                     c.resonance.f0_hz if c.resonance else "", c.resonance.q if c.resonance else ""]
                )
                if log:
                    log(f"run {rid:3d} rep {c.repeat}: {oname:8s} {f:6g} Hz -> {folder_k}")
            rid += 1
    with open(os.path.join(out, "runs.csv"), "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(RUNS_CSV_COLUMNS)
        for r in rows:
            w.writerow([repr(v) if isinstance(v, float) else v for v in r])
    return rows


# ---------------------------------------------------------------------------------------
# Self-check of the discretisation


def selfcheck(log=print):
    """Print the discretisation figures (the tests check the same with tolerances)."""
    p_k2 = Passport(id="k2-only", a0_g=0, d1a=0, k2=105e-6, k3=0, k4=0, k5=0, m1=0, m2=0, m31=0, m32=0)
    base = dict(still_s=2.0, vib_s=4.0, unit_noise_g=0, vib_noise_g=0, ref_noise_g=0,
                sensor_rate_hz=6400.0, random_bands=[(20.0, 640.0, (0.0, 0.0, 0.0))])
    log("1. k2 only, pure tone 2 g along IA (AK3, +z up): VE vs k2 A^2/2 (MODEL.md section 5/6)")
    for f in (30.0, 47.3, 120.0):
        cfg = RunConfig(tone_hz=(f,) * 3, tone_amp_g=(0, 0, 2.0), tone_phase_rad=(0, 0, 0.3), **base)
        r = simulate(cfg, default_triad(p_k2))
        ve = r.truth["units"][2]["ve_time_domain_g"]
        cf = 105e-6 * 2.0**2 / 2
        log(f"   f = {f:6.1f} Hz: time domain {ve:.12e} g, closed form {cf:.12e} g, rel err {ve / cf - 1:+.2e}")
    log("2. asymmetry only (d1A = 15 ppm), tone 2 g along IA, aL3 = 1 g: VE vs section 6 exact")
    p_d = Passport(id="d1a-only", a0_g=0, d1a=15e-6, k2=0, k3=0, k4=0, k5=0, m1=0, m2=0, m31=0, m32=0)
    for f in (30.0, 47.3, 120.0):
        cfg = RunConfig(tone_hz=(f,) * 3, tone_amp_g=(0, 0, 2.0), tone_phase_rad=(0, 0, 0.3), **base)
        r = simulate(cfg, default_triad(p_d))
        u = r.truth["units"][2]
        ve, ex = u["ve_time_domain_g"], u["closed_form_unit_side"]["ve_exact_g"]
        log(f"   f = {f:6.1f} Hz: time domain {ve:.6e} g, exact {ex:.6e} g, rel err {ve / ex - 1:+.2e}")
    log("3. discretisation: fine rate 6.4 kHz / 25.6 kHz vs 102.4 kHz, same continuous signal")
    log("   (tone 120 Hz, 2 g per axis + random 20..640 Hz at 0.002 g^2/Hz; readings and VE)")
    for reso in (None, Resonance()):
        for method in (("exact", "bilinear") if reso else ("exact",)):
            runs = {}
            for ov in (1, 4, 16):
                cfg = RunConfig(still_s=1.0, vib_s=2.0, sensor_rate_hz=6400.0, oversample=ov,
                                tone_hz=(120.0,) * 3, tone_amp_g=(2.0, 2.0, 2.0), unit_noise_g=0,
                                resonance=reso, filter_method=method)
                runs[ov] = simulate(cfg)
            for ov in (1, 4):
                d = runs[ov].accel_clean_g - runs[16].accel_clean_g
                dve = max(abs(a["ve_time_domain_g"] - b["ve_time_domain_g"])
                          for a, b in zip(runs[ov].truth["units"], runs[16].truth["units"]))
                ve = max(abs(b["ve_time_domain_g"]) for b in runs[16].truth["units"])
                log(f"   mount {'150 Hz Q 2.5 ' + method if reso else 'none':22s} fs {6400 * ov:6d} Hz: "
                    f"reading error RMS {np.sqrt(np.mean(d**2)):.2e} g, max {np.abs(d).max():.2e} g; "
                    f"VE error {dve:.2e} g (VE up to {ve:.2e} g)")
    log("4. mount resonance with --filter-method bilinear (prewarped at f0; 150 Hz, Q 2.5, base form)")
    log("   vs H(j w) over 20..640 Hz (the exact method applies H(j w) itself)")
    res = Resonance()
    f = np.linspace(20, 640, 621)
    for fs in (6400.0, 25600.0):
        bz, az = res.digital(fs)
        hd = signal.freqz(bz, az, worN=f, fs=fs)[1]
        hc = res.h(f)
        err = np.abs(hd / hc - 1)
        log(f"   fs {fs:7.0f} Hz: max |Hd/H - 1| = {err.max():.2e} (at {f[err.argmax()]:.0f} Hz); "
            f"at f0 {abs(hd[np.argmin(abs(f - 150))] / hc[np.argmin(abs(f - 150))] - 1):.1e}")

    selfcheck_effects(log)


def _only(**coeffs):
    """A passport with every (FP) coefficient 0 but k1 = 1 (K1 as AL-15) and ``coeffs``."""
    base = dict(a0_g=0.0, d1a=0.0, k2=0.0, k3=0.0, k4=0.0, k5=0.0, m1=0.0, m2=0.0, m31=0.0, m32=0.0)
    base.update(coeffs)
    return Passport(id="selfcheck", **base)


def _effect_run(effects=(), amps=(0.0, 0.0, 2.0), f=60.0, orientation="+z", passport=None, fs=6400.0,
                phases=(0.0, 0.9, 2.0), **kw):
    """A quiet flight-like 2 s run with tones of ``amps`` at ``f`` on x, y, z and ``effects``."""
    args = dict(vibrate_throughout=True, duration_s=2.0, sensor_rate_hz=fs, orientation=orientation,
                orientation_name=str(orientation), tone_hz=(f,) * 3, tone_amp_g=amps, tone_phase_rad=phases,
                random_bands=[(20.0, 640.0, (0.0, 0.0, 0.0))], unit_noise_g=0.0, vib_noise_g=0.0, ref_noise_g=0.0,
                effects=[parse_effect(s) if isinstance(s, str) else s for s in effects])
    args.update(kw)
    return simulate(RunConfig(**args), default_triad(passport or _only()), keep_fine=True)


def closed_form_clip_of_tone(aL, amp, range_g):
    """``E[clip(aL + A sin) - (aL + A sin)]``, clip to +-r: ``-(up(r - aL) - up(r + aL))``,
    ``up(c) = E[(A sin - c)+] = (sqrt(A^2 - c^2) - c acos(c/A))/pi`` (docs/effects.md saturation)."""
    def up(c):
        return (math.sqrt(amp * amp - c * c) - c * math.acos(c / amp)) / math.pi if c < amp else 0.0
    return -up(range_g - aL) + up(range_g + aL)


def heating_window_mean(c, tau, amp, f, phase, t0, t1):
    """Mean over [t0, t1] of ``b``, ``tau b' = c v^2 - b``, ``b(0) = 0``, ``v = A sin(w t + phase)``:
    ``v^2 = P (1 - cos(2 w t + 2 phase))``, ``P = A^2/2``, each part's exact response, integrated
    in closed form."""
    p = amp * amp / 2
    big_w, psi = 4 * math.pi * f, 2 * phase
    k = 1.0 / (1 + 1j * big_w * tau)

    def integral(t):  # of b from 0 to t
        dc = c * p * (t - tau * (1 - math.exp(-t / tau)))
        rip = (np.exp(1j * psi) * (np.exp(1j * big_w * t) - 1) / (1j * big_w)
               - np.exp(1j * psi) * tau * (1 - math.exp(-t / tau)))
        return dc - c * p * (k * rip).real

    return (integral(t1) - integral(t0)) / (t1 - t0)


def selfcheck_effects(log=print):
    """The hidden effects against closed forms (docs/effects.md; the tests check the same)."""
    log("5. unit_response (1500 Hz, zeta 0.3), k2 only, 2 g IA tone at 1200 Hz: VE vs 0.5 k2 (|H| A)^2")
    ur = UnitResponse(1500.0, 0.3)
    h = abs(complex(ur.h(1200.0)[0]))
    for method in ("exact", "bilinear"):
        for fs in (6400.0, 25600.0):
            r = _effect_run(amps=(0.0, 0.0, 2.0), f=1200.0, passport=_only(k2=105e-6), unit_response=ur,
                            filter_method=method, fs=fs)
            cf = 0.5 * 105e-6 * (h * 2.0) ** 2
            log(f"   {method:8s} fs {fs:7.0f} Hz: VE {r.truth['units'][2]['ve_time_domain_g']:.9e} g, closed form "
                f"{cf:.9e} g, rel err {r.truth['units'][2]['ve_time_domain_g'] / cf - 1:+.2e}")
    log("   random 20..640 Hz, 0.002 g^2/Hz on z, through a 500 Hz, zeta 0.3 response: RMS at AK3 vs "
        "sqrt(int |H|^2 S df)")
    ur5 = UnitResponse(500.0, 0.3)
    r = _effect_run(amps=(0.0, 0.0, 0.0), unit_response=ur5, random_bands=[(20.0, 640.0, (0.0, 0.0, 0.002))],
                    duration_s=8.0)
    v3 = r.fine["unit_extra"][2]["a_unit_axes_g"][2] - 1.0
    f = np.linspace(20.0, 640.0, 62001)
    w = 0.002 * np.abs(ur5.h(f)) ** 2
    var = float(np.trapezoid(w, f))
    bins = 0.002 / 8.0 * np.abs(ur5.h(np.arange(160, 5120) / 8.0)) ** 2  # one bin's variance
    rel_sd = float(np.sqrt(np.sum(bins**2)) / np.sum(bins))
    got = float(np.mean(v3[:-1] ** 2))
    log(f"   RMS {math.sqrt(got):.6f} g, analytic {math.sqrt(var):.6f} g, variance ratio - 1 = "
        f"{got / var - 1:+.2e} (the draw's standard deviation {rel_sd:.1e}); without the response "
        f"{math.sqrt(0.002 * 620):.6f} g")
    log("6. sensor gain error 0.05 on VD2: its samples (noise-free) / the plain rig's = 1.05")
    a = _effect_run(amps=(1.0, 1.0, 1.0))
    b = _effect_run(amps=(1.0, 1.0, 1.0), sensor_gain_error=(0.0, 0.05, 0.0))
    ratio = b.vib_v[:, 1] / np.where(a.vib_v[:, 1] == 0, np.nan, a.vib_v[:, 1])
    log(f"   max |ratio - 1.05| = {np.nanmax(np.abs(ratio - 1.05)):.1e}; VD1, VD3 and readings unchanged: "
        f"{np.array_equal(a.vib_v[:, [0, 2]], b.vib_v[:, [0, 2]]) and np.array_equal(a.accel_v, b.accel_v)}")
    log("7. vibropendulous c 2e-4 rad/g, tau 2 ms, 60 Hz tones 1 / 1.5 / 2 g, oblique1: mean vs "
        "c 0.5 aB3 aB2 Re(HP e^{j(phi3 - phi2)})")
    amps, ph = (1.0, 1.5, 2.0), (0.0, 0.9, 2.0)
    w60 = 2 * math.pi * 60.0
    hp = 1j * w60 * 2e-3 / (1 + 1j * w60 * 2e-3)
    for thr in (True, False):
        extra = {} if thr else dict(vibrate_throughout=False, still_s=0.5, vib_s=1.0)
        r = _effect_run(["vibropendulous:c_rad_per_g=2e-4,tau_s=0.002"], amps=amps, orientation="oblique1",
                        **extra)
        errs = []
        for i, u in enumerate(r.triad):
            x3, x2 = int(np.argmax(np.abs(u.e_ia))), int(np.argmax(np.abs(u.e_pa)))
            cf = 2e-4 * 0.5 * u.e_ia[x3] * amps[x3] * u.e_pa[x2] * amps[x2] * (hp * np.exp(1j * (ph[x3] - ph[x2]))).real
            errs.append(r.truth["units"][i]["effects_mean_shift_g"] / cf - 1)
        log(f"   {'flight-like' if thr else 'shaker run '}: rel err per unit {', '.join(f'{e:+.1e}' for e in errs)}")
    log("8. anisoelastic k_ae 3e-5 /g, same tones: mean vs k_ae (aL1 aL2 + 0.5 aB1 aB2 cos(phi1 - phi2))")
    r = _effect_run(["anisoelastic:k_ae_per_g=3e-5"], amps=amps, orientation="oblique1")
    g = np.asarray(r.cfg.orientation)
    errs = []
    for i, u in enumerate(r.triad):
        x1, x2 = int(np.argmax(np.abs(u.e_oa))), int(np.argmax(np.abs(u.e_pa)))
        cf = 3e-5 * ((u.e_oa @ g) * (u.e_pa @ g) + 0.5 * u.e_oa[x1] * u.e_pa[x2] * amps[x1] * amps[x2]
                     * math.cos(ph[x1] - ph[x2]))
        errs.append(r.truth["units"][i]["effects_mean_shift_g"] / cf - 1)
    log(f"   rel err per unit {', '.join(f'{e:+.1e}' for e in errs)}")
    log("9. high_order_nonlinearity k6 0.05 ppm/g^5, k7 0.01 ppm/g^6, 3 g IA tone, aL3 = 1 g: vs "
        "k6 E[a3^6] + k7 E[a3^7] (binomial, E[sin^2,4,6] = 1/2, 3/8, 5/16)")
    mom = [1, 0, 0.5, 0, 3 / 8, 0, 5 / 16, 0]
    e6 = sum(math.comb(6, q) * 3.0**q * mom[q] for q in range(7))
    e7 = sum(math.comb(7, q) * 3.0**q * mom[q] for q in range(8))
    cf = 0.05e-6 * e6 + 0.01e-6 * e7
    r = _effect_run(["high_order_nonlinearity:k6_ppm_per_g5=0.05,k7_ppm_per_g6=0.01"], amps=(0.0, 0.0, 3.0))
    got = r.truth["units"][2]["effects_mean_shift_g"]
    log(f"   {got:.9e} g vs {cf:.9e} g, rel err {got / cf - 1:+.1e}")
    log("   random only (0.01 g^2/Hz, 20..640 Hz on z): the k6 term's mean vs k6 (E[a3^6] of the realised "
        "samples) and vs 1e-6 k6 (1 + 15 s^2 + 45 s^4 + 15 s^6) of the requested sigma")
    r = _effect_run(["high_order_nonlinearity:k6_ppm_per_g5=0.05"], amps=(0.0, 0.0, 0.0),
                    random_bands=[(20.0, 640.0, (0.0, 0.0, 0.01))], duration_s=4.0)
    win = windows(r.cfg)["vibrating"]
    t = r.fine["t"]
    a3 = r.fine["unit_extra"][2]["a_unit_axes_g"][2][(t >= win[0] - 1e-12) & (t <= win[1] + 1e-12)]
    e6 = float((np.sum(a3**6) - 0.5 * (a3[0] ** 6 + a3[-1] ** 6)) / (len(a3) - 1))  # trapezoid over the window
    s2 = 0.01 * 620
    got = r.truth["units"][2]["effects_mean_shift_g"]
    log(f"   {got:.9e} g vs realised {0.05e-6 * e6:.9e} g (rel err {got / (0.05e-6 * e6) - 1:+.1e}) vs expected "
        f"{0.05e-6 * (1 + 15 * s2 + 45 * s2**2 + 15 * s2**3):.6e} g (one draw of a heavy moment)")
    log("10. heating c 1e-5 g/g^2, tau 0.5 s, 2 g IA tone at 60 Hz from t = 0: window mean vs the exact "
        "response to v^2 = P (1 - cos 2 w t)")
    for fs in (6400.0, 25600.0):
        r = _effect_run(["heating:c_g_per_g2=1e-5,tau_s=0.5"], fs=fs)
        cf = heating_window_mean(1e-5, 0.5, 2.0, 60.0, 2.0, r.cfg.settle, r.cfg.t_run)
        got = r.truth["units"][2]["effects_mean_shift_g"]
        log(f"   fs {fs:7.0f} Hz: {got:.9e} g vs {cf:.9e} g, rel err {got / cf - 1:+.1e} (first-order hold)")
    log("11. saturation: k1 only, 4 g IA tone, aL3 = 1 g, range 3 g: mean of the clip vs the sinusoid's "
        "closed form")
    cf = closed_form_clip_of_tone(1.0, 4.0, 3.0)
    for fs in (6400.0, 25600.0):
        r = _effect_run(["saturation:range_g=3"], amps=(0.0, 0.0, 4.0), fs=fs)
        got = r.truth["units"][2]["effects_mean_shift_g"]
        log(f"   fs {fs:7.0f} Hz: {got:.9e} g vs {cf:.9e} g, rel err {got / cf - 1:+.1e} (kinks: O(h^2))")
    log("12. scale_factor_frequency corner 800 Hz, lambda_hf 1.5, d1A exaggerated to 0.1, 2 g IA tone at "
        "400 Hz, aL3 = 1 g: vs 0.5 k1 d1A A (Re L - 1) (2/pi) sqrt(1 - aL^2/A^2)")
    lf = (1 + 1.5j * 400.0 / 800.0) / (1 + 1j * 400.0 / 800.0)
    cf = 0.5 * 0.1 * 2.0 * (lf.real - 1) * (2 / math.pi) * math.sqrt(1 - 1 / 4.0)
    for fs in (6400.0, 25600.0):
        r = _effect_run(["scale_factor_frequency:corner_hz=800,lambda_hf=1.5"], f=400.0, fs=fs,
                        passport=_only(d1a=0.1))
        got = r.truth["units"][2]["effects_mean_shift_g"]
        log(f"   fs {fs:7.0f} Hz: {got:.9e} g vs {cf:.9e} g, rel err {got / cf - 1:+.1e} "
            "(sign(a3) split exactly at its zeros, the signals linear between samples)")


# ---------------------------------------------------------------------------------------
# CLI


def _floats(s, n=None):
    v = [float(x) for x in s.split(",")]
    if n and len(v) == 1:
        v = v * n
    if n and len(v) != n:
        raise argparse.ArgumentTypeError(f"want 1 or {n} comma-separated numbers: {s!r}")
    return tuple(v)


def _delay_s(s):
    try:
        d = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {s!r}") from None
    if not (0.0 <= d <= 1.0):
        raise argparse.ArgumentTypeError(f"{s}: the DAQ delay must be 0 <= D <= 1 s")
    return d


def _read_band_table(path):
    """A PSD band table: ``f_lo_hz,f_hi_hz,psd3_g2_per_hz`` (``#`` comments), all axes."""
    bands = []
    with open(path) as f:
        lines = [ln for ln in f if ln.strip() and not ln.lstrip().startswith("#")]
    for row in csv.DictReader(lines):
        s = float(row["psd3_g2_per_hz"])
        bands.append((float(row["f_lo_hz"]), float(row["f_hi_hz"]), (s, s, s)))
    return bands


def build_parser():
    ap = argparse.ArgumentParser(
        description="Independent shake-table rig generator (AL-15 triad, MODEL.md / RIG.md): "
        "writes accel.csv, vib.csv, reference.csv (vibrocomp log import format) and truth.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    sub = ap.add_subparsers(dest="cmd", required=True)

    def common(p):
        g = p.add_argument_group("rig and run")
        g.add_argument("--out", required=True, help="output folder")
        g.add_argument("--seed", type=int, default=30, help="seed of every random part")
        g.add_argument("--repeat", type=int, default=1, metavar="K",
                       help="K draws of the random parts (noise, random vibration) with the same conditions; "
                       "K > 1 writes repKK subfolders")
        g.add_argument("--tone-amp-g", type=lambda s: _floats(s, 3), default=None,
                       help="tone amplitude per body axis x,y,z (1 or 3 values); default drawn U(0.5, 2) from the seed")
        g.add_argument("--tone-phase-deg", type=lambda s: _floats(s, 3), default=None,
                       help="tone phase per axis; default drawn U(0, 360) from the seed")
        g.add_argument("--no-tone", action="store_true", help="no deterministic vibration")
        g.add_argument("--random-psd", type=lambda s: _floats(s, 3), default="0.002",
                       help="flat PSD of the random vibration, g^2/Hz, per axis (1 or 3 values); 0 = none")
        g.add_argument("--random-band-hz", type=lambda s: _floats(s, 2), default="20,640")
        g.add_argument("--random-psd-csv", default=None,
                       help="band table f_lo_hz,f_hi_hz,psd3_g2_per_hz (config/vibration/*.csv), all axes; "
                       "replaces --random-psd/--random-band-hz")
        g.add_argument("--resonance-f0-hz", type=float, default=None, help="hidden mount resonance (none by default)")
        g.add_argument("--resonance-q", type=float, default=2.5)
        g.add_argument("--resonance-form", choices=["base", "plain"], default="base",
                       help="base: (w0^2 + 2 zeta w0 s)/(..); plain: w0^2/(..)")
        g.add_argument("--filter-method", choices=["exact", "bilinear"], default="exact",
                       help="mount and AC coupling: exact frequency response on the run's DFT bins, or a "
                       "bilinear digital filter (prewarped at f0 / the AC corner) on the fine grid")
        g.add_argument("--accel-rate-hz", type=float, default=800.0)
        g.add_argument("--sensor-rate-hz", type=float, default=25600.0, help="vibration sensors and reference")
        g.add_argument("--oversample", type=int, default=1, help="fine rate = sensor rate x this")
        g.add_argument("--still-s", type=float, default=8.0)
        g.add_argument("--vib-s", type=float, default=8.0)
        g.add_argument("--vibrate-throughout", action="store_true", help="flight-like: vibration from start to end")
        g.add_argument("--duration-s", type=float, default=24.0, help="run length with --vibrate-throughout")
        g.add_argument("--ramp-s", type=float, default=0.1)
        g.add_argument("--settle-s", type=float, default=None, help="default max(0.1, 25/(zeta w0))")
        g.add_argument("--unit-noise-ug", type=float, default=10.0, help="white noise per reading, ug RMS")
        g.add_argument("--vib-noise-mg", type=float, default=1.0, help="vibration-sensor noise, mg RMS per sample")
        g.add_argument("--ref-noise-mg", type=float, default=1.0, help="reference noise, mg RMS per sample")
        g.add_argument("--vib-sens-v-per-g", type=float, default=0.1)
        g.add_argument("--vib-hp-hz", type=float, default=2.0)
        g.add_argument("--daq-delay-s", type=_delay_s, default=0.0, metavar="D",
                       help="vibration sensors' acquisition delay, 0 <= D <= 1 s: the sample stamped s in "
                       "vib.csv holds the signal at s - D (reference and accelerometers not delayed)")
        g.add_argument("--ref-sens-v-per-g", type=float, default=None, metavar="S",
                       help="record the reference AC-coupled in V at S V/g (columns ax_v..az_v; "
                       "default: DC-coupled in g)")
        g.add_argument("--ref-hp-hz", type=float, default=0.5, help="the AC-coupled reference's corner, Hz")
        g.add_argument("--ref-delay-s", type=_delay_s, default=0.0, metavar="D",
                       help="the AC-coupled reference's delay: its sample stamped s holds the base at s - D")
        g.add_argument("--write-rig", action="store_true",
                       help="write rig.toml per run: the chains and the orientation (write_rig)")
        g.add_argument("--unit-drift-ug-per-s", type=float, default=0.0, metavar="R",
                       help="each unit's readings drift by +-R ug/s from the run start (sign per unit from the seed)")
        h = p.add_argument_group("hidden effects (docs/effects.md; recorded in truth.json 'effects')")
        h.add_argument("--unit-response-hz", type=float, default=None, metavar="F",
                       help="the units' own IA response wn^2/(s^2 + 2 Z wn s + wn^2), natural frequency F "
                       "(with --unit-response-damping)")
        h.add_argument("--unit-response-damping", type=float, default=None, metavar="Z", help="its damping ratio")
        h.add_argument("--sensor-gain-error", type=lambda s: _floats(s, 3), default=None, metavar="G1,G2,G3",
                       help="vibration sensor k reads (1 + G_k) times the vibration on unit k's IA")
        h.add_argument("--effect", action="append", default=[], metavar="SPEC",
                       help="an output effect, kind:key=value,... (units=0|1|2 or 0+2 for some units only): "
                       + "; ".join(f"{k}: {', '.join(v)}" for k, v in OUTPUT_EFFECTS.items()))
        g.add_argument("--passport", default=None, help="passport TOML for all units (default built-in AL-15)")
        g.add_argument("--triad", default=None, help="triad TOML (default: AK1 +x/+y/+z, AK2 +y/+z/+x, AK3 +z/+x/+y)")
        g.add_argument("--passport-dir", default=None, help="where the triad's passport ids are looked up")
        g.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                       help="override a passport field (g units, e.g. k3=0, d1a=15e-6), any number")
        g.add_argument("--digits", type=int, default=None,
                       help="significant digits of vib/reference values (default: repr, exact)")

    p_run = sub.add_parser("run", help="one run", formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    common(p_run)
    p_run.add_argument("--orientation", default="+z",
                       help="up direction in body axes: " + ", ".join(ORIENTATIONS) + " or x,y,z")
    p_run.add_argument("--tone-hz", type=lambda s: _floats(s, 3), default="60",
                       help="tone frequency (1 value, or 3 per axis)")

    p_c = sub.add_parser("campaign", help="orientations x tone frequencies, runs.csv index",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    common(p_c)
    p_c.add_argument("--orientations", default=",".join(ORIENTATIONS), help="names, comma-separated")
    p_c.add_argument("--tone-freqs-hz", type=_floats, default="30,60,120")

    sub.add_parser("selfcheck", help="print the discretisation figures and the hidden effects' closed-form checks")
    return ap


def config_from_args(a):
    bands = (
        _read_band_table(a.random_psd_csv)
        if a.random_psd_csv
        else [(a.random_band_hz[0], a.random_band_hz[1], a.random_psd)]
    )
    passport = Passport.from_toml(a.passport) if a.passport else None
    if a.triad:
        triad = load_triad(a.triad, a.passport_dir, passport)
    else:
        triad = default_triad(passport)
    if a.set:
        for u in triad:
            u.passport = copy.deepcopy(u.passport)
        for item in a.set:
            name, _, value = item.partition("=")
            if name not in {f.name for f in dataclasses.fields(Passport)} or name == "id":
                raise SystemExit(f"--set: unknown passport field {name!r}")
            for u in triad:
                setattr(u.passport, name, float(value))
    if (a.unit_response_hz is None) != (a.unit_response_damping is None):
        raise SystemExit("--unit-response-hz and --unit-response-damping go together")
    try:
        effects = [parse_effect(s) for s in a.effect]
    except ValueError as e:
        raise SystemExit(str(e)) from None
    cfg = RunConfig(
        unit_response=None if a.unit_response_hz is None
        else UnitResponse(a.unit_response_hz, a.unit_response_damping),
        sensor_gain_error=a.sensor_gain_error or (0.0, 0.0, 0.0),
        effects=effects,
        tone_amp_g=(0.0, 0.0, 0.0) if a.no_tone else a.tone_amp_g,
        tone_phase_rad=None if a.tone_phase_deg is None else tuple(math.radians(x) for x in a.tone_phase_deg),
        random_bands=bands,
        resonance=Resonance(a.resonance_f0_hz, a.resonance_q, a.resonance_form) if a.resonance_f0_hz else None,
        filter_method=a.filter_method,
        accel_rate_hz=a.accel_rate_hz,
        sensor_rate_hz=a.sensor_rate_hz,
        oversample=a.oversample,
        still_s=a.still_s,
        vib_s=a.vib_s,
        vibrate_throughout=a.vibrate_throughout,
        duration_s=a.duration_s,
        ramp_s=a.ramp_s,
        settle_s=a.settle_s,
        unit_noise_g=a.unit_noise_ug * 1e-6,
        vib_noise_g=a.vib_noise_mg * 1e-3,
        ref_noise_g=a.ref_noise_mg * 1e-3,
        vib_sens_v_per_g=a.vib_sens_v_per_g,
        vib_hp_hz=a.vib_hp_hz,
        daq_delay_s=a.daq_delay_s,
        ref_sens_v_per_g=a.ref_sens_v_per_g,
        ref_hp_hz=a.ref_hp_hz,
        ref_delay_s=a.ref_delay_s,
        write_rig=a.write_rig,
        unit_drift_ug_per_s=a.unit_drift_ug_per_s,
        seed=a.seed,
    )
    return cfg, triad


def main(argv=None):
    a = build_parser().parse_args(argv)
    if a.cmd == "selfcheck":
        selfcheck()
        return 0
    cfg, triad = config_from_args(a)
    t0 = time.perf_counter()
    if a.cmd == "run":
        cfg.orientation = tuple(orientation_vector(a.orientation))
        cfg.orientation_name = a.orientation
        cfg.tone_hz = a.tone_hz
        results = run_repeats(cfg, triad, a.out, a.repeat, a.digits)
        for folder, res in results:
            ves = ", ".join(f"{u['name']} {u['ve_time_domain_g'] * 1e6:.2f} ug" for u in res.truth["units"])
            print(f"{folder}: VE {ves}")
    else:
        orients = [s.strip() for s in a.orientations.split(",") if s.strip()]
        for o in orients:
            orientation_vector(o)
        rows = run_campaign(cfg, triad, a.out, orients, a.tone_freqs_hz, a.repeat, a.digits,
                            log=lambda s: print(s, flush=True))
        print(f"{len(rows)} runs in {a.out} (index {os.path.join(a.out, 'runs.csv')})")
    print(f"done in {time.perf_counter() - t0:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
