"""Checks of the independent rig generator (tests/python/rig_generator.py).

Run: ``python3 -m pytest tests/python/test_rig_generator.py -q``.

Every expected value here is computed in this file from MODEL.md's formulas (the
conversion function and the closed-form vibration errors), not taken from the
generator's truth, except where a test checks the truth itself.
"""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)

import rig_generator as rg  # noqa: E402

FAST = dict(sensor_rate_hz=6400.0, still_s=1.0, vib_s=3.0)
QUIET = dict(unit_noise_g=0.0, vib_noise_g=0.0, ref_noise_g=0.0)
NO_RANDOM = [(20.0, 640.0, (0.0, 0.0, 0.0))]


def only(**coeffs):
    """A passport with every coefficient 0 but K1 = -1.6698, k1 = 1 and ``coeffs``."""
    base = dict(a0_g=0.0, d1a=0.0, k2=0.0, k3=0.0, k4=0.0, k5=0.0, m1=0.0, m2=0.0, m31=0.0, m32=0.0)
    base.update(coeffs)
    return rg.Passport(id="test", **base)


def fp_independent(p, a3, a1, a2):
    """(FP) of MODEL.md section 2 written out again, term by term, for scalars."""
    s = 1.0 if a3 > 0 else (-1.0 if a3 < 0 else 0.0)
    return (
        p.a0_g
        + p.k1 * p.lam * (1 + 0.5 * p.d1a * s) * a3
        + p.k2 * a3**2 + p.k3 * a3**3 + p.k4 * a3**4 + p.k5 * a3**5
        + p.m1 * a1 + p.m2 * a2 + p.m31 * a3 * a1 + p.m32 * a3 * a2
    )


def ve_of(res, unit):
    return res.truth["units"][unit]["ve_time_domain_g"]


# --------------------------------------------------------------------------------------
# passports and triad are the shipped ones


def same_passport(a, b):
    """Equal values; ppm / 1e6 and the literal may differ in the last bit."""
    a, b = a.to_dict(), b.to_dict()
    return a.keys() == b.keys() and all(
        a[k] == b[k] if isinstance(a[k], str) else math.isclose(a[k], b[k], rel_tol=1e-15) for k in a)


def test_builtin_passport_and_triad_match_config():
    shipped = rg.Passport.from_toml(os.path.join(ROOT, "config", "accelerometers", "al-15.toml"))
    assert same_passport(shipped, rg.Passport())
    triad = rg.load_triad(os.path.join(ROOT, "config", "triads", "default.toml"),
                          os.path.join(ROOT, "config", "accelerometers"))
    for u, v in zip(triad, rg.default_triad(), strict=True):
        assert (u.name, u.ia, u.oa, u.pa) == (v.name, v.ia, v.oa, v.pa)
        assert same_passport(u.passport, v.passport)


# --------------------------------------------------------------------------------------
# without vibration: (FP) of gravity, to 1e-12 relative


@pytest.mark.parametrize("orientation", list(rg.ORIENTATIONS))
def test_still_readings_are_fp_of_gravity(orientation):
    cfg = rg.RunConfig(orientation=orientation, orientation_name=orientation, tone_amp_g=(0, 0, 0),
                       random_bands=NO_RANDOM, resonance=rg.Resonance(), **FAST, **QUIET)
    res = rg.simulate(cfg)
    g = rg.orientation_vector(orientation)
    for i, u in enumerate(res.triad):
        expect = u.passport.K1_v_per_g * fp_independent(u.passport, u.e_ia @ g, u.e_oa @ g, u.e_pa @ g)
        got = res.accel_v[:, i]
        assert np.max(np.abs(got / expect - 1)) < 1e-12
        assert abs(got.mean() / expect - 1) < 1e-12


def test_still_segments_of_a_vibrating_run():
    """Before and after the vibration the readings are (FP) of gravity (1e-9 g: the exact
    boxcar's band-limited interpolation leaks at most ~1e-10 g next to the ramp)."""
    cfg = rg.RunConfig(orientation="oblique2", resonance=rg.Resonance(), **FAST, **QUIET)
    res = rg.simulate(cfg)
    win = rg.windows(res.cfg)
    for key in ("still_before", "still_after"):
        m = rg.reading_mask(res.cfg, res.t_accel, win[key])
        for i, u in enumerate(res.truth["units"]):
            assert np.max(np.abs(res.accel_clean_g[m, i] - u["still_reading_g"])) < 1e-9


# --------------------------------------------------------------------------------------
# pure tone: closed forms of MODEL.md sections 5-6


@pytest.mark.parametrize("freq,tol", [(30.0, 1e-10), (120.0, 1e-10), (47.3, 1 / (2 * math.pi * 47.3 * 2.7))])
def test_k2_tone_ve_is_k2_a2_over_2(freq, tol):
    """d0(1) = 0.5 k2 aB3^2 [P1 (15)]; whole tone periods in the window (2.7 s) give it to
    rounding; 47.3 Hz leaves a fraction of a period: |<cos 2 theta>| <= 1/(2 pi f T)."""
    k2, amp = 105e-6, 2.0
    cfg = rg.RunConfig(tone_hz=(freq,) * 3, tone_amp_g=(0.0, 0.0, amp), tone_phase_rad=(0, 0, 0.7),
                       random_bands=NO_RANDOM, **FAST, **QUIET)
    res = rg.simulate(cfg, rg.default_triad(only(k2=k2)))
    assert abs(ve_of(res, 2) / (0.5 * k2 * amp**2) - 1) < tol
    assert abs(ve_of(res, 0)) < 1e-18 and abs(ve_of(res, 1)) < 1e-18  # no tone on their IA


def test_k2_tone_through_the_resonance():
    """The unit sees |H(j w)| A: VE = 0.5 k2 (|H| A)^2, the sensors' A would say 0.5 k2 A^2."""
    k2, amp, f = 105e-6, 1.0, 120.0
    reso = rg.Resonance(150.0, 2.5, "base")
    cfg = rg.RunConfig(tone_hz=(f,) * 3, tone_amp_g=(0.0, 0.0, amp), tone_phase_rad=(0, 0, 0.2),
                       random_bands=NO_RANDOM, resonance=reso, settle_s=0.1, **FAST, **QUIET)
    res = rg.simulate(cfg, rg.default_triad(only(k2=k2)))  # settle 0.1 s: 19 time constants, whole periods
    w0, zeta, w = 2 * math.pi * 150.0, 0.2, 2 * math.pi * f
    h = abs((w0**2 + 2j * zeta * w0 * w) / (-(w**2) + 2j * zeta * w0 * w + w0**2))
    assert abs(ve_of(res, 2) / (0.5 * k2 * (h * amp) ** 2) - 1) < 1e-9
    u = res.truth["units"][2]
    assert abs(u["closed_form_unit_side"]["ve_exact_g"] / ve_of(res, 2) - 1) < 1e-9
    assert abs(u["closed_form_sensor_side"]["ve_exact_g"] / (0.5 * k2 * amp**2) - 1) < 1e-10  # 1 g - 1 g cancels


def test_k3_tone_ve_is_delta1_times_aL3():
    """delta(1) aL3 = 1.5 k3 aB3^2 aL3 [P1 (16)], exact for one sinusoid (MODEL.md 6)."""
    k3, amp = 87e-6, 1.5
    cfg = rg.RunConfig(orientation="oblique2", tone_hz=(60.0,) * 3, tone_amp_g=(amp, amp, amp),
                       tone_phase_rad=(0.1, 0.2, 0.3), random_bands=NO_RANDOM, **FAST, **QUIET)
    res = rg.simulate(cfg, rg.default_triad(only(k3=k3)))
    g = rg.ORIENTATIONS["oblique2"]
    for i in range(3):  # unit i has IA along body axis i
        assert abs(ve_of(res, i) / (1.5 * k3 * amp**2 * g[i]) - 1) < 1e-9


def test_m31_m32_tone_ve_with_phase():
    """d0(2) + d0(3) = 0.5 m31 aB3 aB1 cos(phi3 - phi1) + 0.5 m32 aB3 aB2 cos(phi3 - phi2)
    (MODEL.md section 6; the papers' [P1 (15)] is the case cos = 1)."""
    m31, m32 = 11.6e-6, 20e-6
    amps, ph = (1.0, 1.5, 2.0), (0.0, 0.9, 2.0)
    cfg = rg.RunConfig(orientation="oblique1", tone_hz=(50.0,) * 3, tone_amp_g=amps, tone_phase_rad=ph,
                       random_bands=NO_RANDOM, **FAST, **QUIET)
    res = rg.simulate(cfg, rg.default_triad(only(m31=m31, m32=m32)))
    for i, u in enumerate(res.triad):
        x3, x1, x2 = (int(np.argmax(np.abs(e))) for e in (u.e_ia, u.e_oa, u.e_pa))
        expect = 0.5 * m31 * amps[x3] * amps[x1] * math.cos(ph[x3] - ph[x1]) + 0.5 * m32 * amps[x3] * amps[
            x2] * math.cos(ph[x3] - ph[x2])
        assert abs(ve_of(res, i) / expect - 1) < 1e-9
    # same frequency, in phase: the papers' published form
    cfg.tone_phase_rad = (0.4, 0.4, 0.4)
    res = rg.simulate(cfg, rg.default_triad(only(m31=m31, m32=0.0)))
    u = res.truth["units"][0]
    assert abs(ve_of(res, 0) / u["closed_form_unit_side"]["ve_published_g"] - 1) < 1e-9


def test_asymmetry_under_a_tone_matches_the_exact_mean():
    """0.5 k1 d1A E|aL + aB sin| (MODEL.md 6): 2 g tone, aL3 = 1 g; |.| is not band-limited,
    so the sampled mean carries a small aliasing error (stated: 2e-4 relative at 6.4 kHz)."""
    d1a, amp, aL = 15e-6, 2.0, 1.0
    cfg = rg.RunConfig(tone_hz=(30.0,) * 3, tone_amp_g=(0, 0, amp), tone_phase_rad=(0, 0, 0.3),
                       random_bands=NO_RANDOM, **FAST, **QUIET)
    res = rg.simulate(cfg, rg.default_triad(only(d1a=d1a)))
    e_abs = (2 / math.pi) * (aL * math.asin(aL / amp) + math.sqrt(amp**2 - aL**2))
    assert abs(ve_of(res, 2) / (0.5 * d1a * (e_abs - aL)) - 1) < 2e-4
    # a tone smaller than aL3: the exact asymmetry term vanishes (0.637 of the papers does not)
    cfg.tone_amp_g = (0, 0, 0.5)
    res = rg.simulate(cfg, rg.default_triad(only(d1a=d1a)))
    assert abs(ve_of(res, 2)) < 1e-15


def test_full_passport_tone_matches_section6_exact():
    """All of (FP) at once, three tones: to 1e-5 (the asymmetry's sampled |.| aliases)."""
    cfg = rg.RunConfig(orientation="oblique1", tone_hz=(40.0,) * 3, tone_amp_g=(1.2, 0.8, 2.0),
                       tone_phase_rad=(0.0, 1.0, 2.5), random_bands=NO_RANDOM, **FAST, **QUIET)
    res = rg.simulate(cfg)
    for i, u in enumerate(res.truth["units"]):
        assert abs(ve_of(res, i) / u["closed_form_unit_side"]["ve_exact_g"] - 1) < 1e-5


def test_flight_like_run_tone():
    """Vibrating throughout (steady state from t = 0), through a resonance: the same VE."""
    k2, amp, f = 105e-6, 1.0, 47.0
    for method in ("exact", "bilinear"):
        cfg = rg.RunConfig(vibrate_throughout=True, duration_s=3.0, tone_hz=(f,) * 3, tone_amp_g=(0, 0, amp),
                           tone_phase_rad=(0, 0, 0.4), random_bands=NO_RANDOM, resonance=rg.Resonance(),
                           filter_method=method, sensor_rate_hz=6400.0, **QUIET)
        res = rg.simulate(cfg, rg.default_triad(only(k2=k2)))
        h = abs(complex(rg.mount(res.cfg).h_effective(f, 6400.0)[0]))
        t_w = 3.0 - res.cfg.settle  # 47 Hz: not a whole number of periods
        assert abs(ve_of(res, 2) / (0.5 * k2 * (h * amp) ** 2) - 1) < 1 / (2 * math.pi * f * t_w)


# --------------------------------------------------------------------------------------
# random vibration


def band_variance_welch(x, fs, lo=20.0, hi=640.0):
    f, p = signal.welch(x, fs=fs, nperseg=int(fs), axis=0)  # Hann, 1 Hz bins
    df = f[1] - f[0]
    # integrate a little wider than the band: Hann leaks about 2 bins; the noise floor is tiny
    m = (f >= lo - 3) & (f <= hi + 3)
    return p[m].sum(axis=0) * df


def test_random_rms_matches_the_requested_psd():
    """Band RMS^2 from Welch on the reference (base) equals S (f_hi - f_lo) within its
    statistical uncertainty 1/sqrt(B T) (relative, of a variance over a window T)."""
    s = (0.002, 0.004, 0.001)
    cfg = rg.RunConfig(tone_amp_g=(0, 0, 0), random_bands=[(20.0, 640.0, s)], sensor_rate_hz=6400.0,
                       still_s=1.0, vib_s=8.0)
    res = rg.simulate(cfg)
    win = rg.windows(res.cfg)["vibrating"]
    m = (res.t_vib >= win[0]) & (res.t_vib <= win[1])
    var = band_variance_welch(res.ref_g[m], 6400.0)
    t_w = win[1] - win[0]
    rel_sd = 1 / math.sqrt(620.0 * t_w)
    expect = np.array(s) * 620.0
    assert np.all(np.abs(var / expect - 1) < 4 * rel_sd), (var / expect - 1, rel_sd)
    # the PSD is flat at S inside the band
    f, p = signal.welch(res.ref_g[m], fs=6400.0, nperseg=1600, axis=0)
    inband = (f >= 40) & (f <= 600)
    assert np.all(np.abs(p[inband].mean(axis=0) / np.array(s) - 1) < 0.05)
    assert np.all(p[(f > 700) & (f < 3000)].mean(axis=0) < 1e-3 * np.array(s))


def test_random_rms_over_repeats_and_its_scatter():
    """Over K repeats the mean variance converges and the scatter is 1/sqrt(B T)."""
    k, s = 12, 0.002
    vars_ = []
    for rep in range(k):
        cfg = rg.RunConfig(tone_amp_g=(0, 0, 0), random_bands=[(20.0, 640.0, (s, s, s))], sensor_rate_hz=6400.0,
                           still_s=1.0, vib_s=4.0, repeat=rep, ref_noise_g=0.0)
        res = rg.simulate(cfg)
        win = rg.windows(res.cfg)["vibrating"]
        m = (res.t_vib >= win[0]) & (res.t_vib <= win[1])
        v = res.ref_g[m] - res.ref_g[m].mean(axis=0)
        vars_.append(np.mean(v**2, axis=0) / (s * 620.0))
    vars_ = np.concatenate(vars_)  # 3 axes x K repeats, independent
    rel_sd = 1 / math.sqrt(620.0 * (win[1] - win[0]))
    assert abs(vars_.mean() - 1) < 4 * rel_sd / math.sqrt(len(vars_))
    assert 0.5 * rel_sd < vars_.std(ddof=1) < 1.6 * rel_sd


def test_k2_random_ve_is_k2_sigma2():
    """d0(1) = k2 sigma3^2 [P1 (14)]: to the realised sigma at the unit, and to the
    requested sigma within the statistical uncertainty of the variance."""
    k2, s = 105e-6, 0.002
    cfg = rg.RunConfig(tone_amp_g=(0, 0, 0), random_bands=[(20.0, 640.0, (s, s, s))], **FAST, **QUIET)
    res = rg.simulate(cfg, rg.default_triad(only(k2=k2)))
    rel_sd = 1 / math.sqrt(620.0 * 2.8)
    for i, u in enumerate(res.truth["units"]):
        real = u["realised_unit_side"]["sigma3_g"] ** 2
        assert abs(ve_of(res, i) / (k2 * real) - 1) < 2e-3
        assert abs(ve_of(res, i) / (k2 * s * 620.0) - 1) < 4 * rel_sd


# --------------------------------------------------------------------------------------
# the hidden resonance, from a swept tone


def tone_gain_from_readings(res, unit, f, amp):
    """Least-squares amplitude of the tone in the readings over the VE window, divided by
    the boxcar's response and the tone amplitude (the unit's passport is linear)."""
    cfg = res.cfg
    m = rg.reading_mask(cfg, res.t_accel, rg.windows(cfg)["vibrating"])
    t = res.t_accel[m]
    y = res.accel_clean_g[m, unit]
    a = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t)])
    c = np.linalg.lstsq(a, y, rcond=None)[0]
    return math.hypot(c[0], c[1]) / abs(rg.boxcar_response(f, 1 / cfg.accel_rate_hz)) / amp


@pytest.mark.parametrize("form,method", [("plain", "exact"), ("base", "exact"), ("plain", "bilinear"),
                                         ("base", "bilinear")])
def test_resonance_gain_at_f0(form, method):
    f0, q = 150.0, 2.5
    reso = rg.Resonance(f0, q, form)
    expect_f0 = q if form == "plain" else q * math.sqrt(1 + 1 / q**2)
    gains = {}
    for f in (120.0, 135.0, 145.0, 150.0, 155.0, 165.0, 180.0):
        cfg = rg.RunConfig(tone_hz=(f,) * 3, tone_amp_g=(1.0, 0, 0), tone_phase_rad=(0.3, 0, 0),
                           random_bands=NO_RANDOM, resonance=reso, filter_method=method, **FAST, **QUIET)
        res = rg.simulate(cfg, rg.default_triad(only()))
        gains[f] = tone_gain_from_readings(res, 0, f, 1.0)
        expect = abs(complex(rg.mount(res.cfg).h_effective(f, 6400.0)[0]))
        assert abs(gains[f] / expect - 1) < 1e-6
    assert abs(gains[150.0] / expect_f0 - 1) < 1e-6
    # the sweep peaks near f0 (plain form: at f0 sqrt(1 - 2 zeta^2) = 145.4 Hz)
    assert max(gains, key=gains.get) in (145.0, 150.0)


# --------------------------------------------------------------------------------------
# vibration sensors


def test_vibration_sensor_ac_coupled_0p1_v_per_g():
    amp, f = 1.5, 30.0
    cfg = rg.RunConfig(orientation="oblique1", tone_hz=(f,) * 3, tone_amp_g=(amp, 0.5 * amp, 0.0),
                       tone_phase_rad=(0.2, 1.0, 0.0), random_bands=NO_RANDOM, **FAST)
    for method in ("exact", "bilinear"):
        cfg.filter_method = method
        res = rg.simulate(cfg)
        n_sd = 0.1 * cfg.vib_noise_g
        still = res.t_vib < res.cfg.t_on
        # gravity (0.577 g on every IA) does not reach the output: mean ~ 0 within the noise
        assert np.all(np.abs(res.vib_v[still].mean(axis=0)) < 5 * n_sd / math.sqrt(still.sum()))
        win = rg.windows(res.cfg)["vibrating"]
        m = (res.t_vib >= win[0]) & (res.t_vib <= win[1])
        assert np.all(np.abs(res.vib_v[m].mean(axis=0)) < 1e-4)
        t = res.t_vib[m]
        hp = abs(1j * f / (1j * f + cfg.vib_hp_hz))  # first-order AC coupling at 2 Hz
        for unit, a in ((0, amp), (1, 0.5 * amp), (2, 0.0)):
            x = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t)])
            c = np.linalg.lstsq(x, res.vib_v[m, unit], rcond=None)[0]
            got = math.hypot(c[0], c[1])
            assert abs(got - 0.1 * a * hp) < 5 * n_sd * math.sqrt(2 / m.sum()) + 1e-9
            assert abs(got - 0.1 * a) <= 0.1 * a * 0.003 + 1e-5  # 0.22 % below 0.1 V/g at 30 Hz


def test_vibration_sensor_sign_follows_ia():
    """A sensor along -x sees the x tone with the opposite sign."""
    triad = [rg.Unit("AK1", rg.Passport(), "-x", "+y", "-z"), rg.Unit("AK2", rg.Passport(), "+y", "+z", "+x"),
             rg.Unit("AK3", rg.Passport(), "+z", "+x", "+y")]
    cfg = rg.RunConfig(tone_hz=(60.0,) * 3, tone_amp_g=(1.0, 0, 0), tone_phase_rad=(0, 0, 0),
                       random_bands=NO_RANDOM, **FAST, **QUIET)
    res = rg.simulate(cfg, triad)
    ref_hp = rg.simulate(cfg).vib_v[:, 0]
    assert np.allclose(res.vib_v[:, 0], -ref_hp, atol=1e-15)
    assert res.truth["units"][0]["aL3_g"] == -0.0 or res.truth["units"][0]["aL3_g"] == 0.0


# --------------------------------------------------------------------------------------
# CLI: files, --repeat, campaign, determinism

CLI_FAST = ["--sensor-rate-hz", "6400", "--still-s", "1", "--vib-s", "2"]


def run_cli(*args):
    subprocess.run([sys.executable, os.path.join(HERE, "rig_generator.py"), *args], check=True,
                   capture_output=True, text=True)


def read_rows(path):
    with open(path) as f:
        lines = [ln.rstrip("\n") for ln in f if ln.strip() and not ln.startswith("#")]
    return lines[0].split(","), [[float(c) for c in ln.split(",")] for ln in lines[1:]], lines[1:]


def test_cli_files_follow_the_log_import_format(tmp_path):
    out = tmp_path / "run"
    run_cli("run", "--out", str(out), "--orientation=-y", "--resonance-f0-hz", "150", *CLI_FAST)
    for name, cols, rate in (("accel.csv", ["time_s", "u1_v", "u2_v", "u3_v"], 800.0),
                             ("vib.csv", ["time_s", "vd1_v", "vd2_v", "vd3_v"], 6400.0),
                             ("reference.csv", ["time_s", "ax_g", "ay_g", "az_g"], 6400.0)):
        header, rows, raw = read_rows(out / name)
        assert header == cols
        a = np.array(rows)
        assert a.shape == (int(4 * rate), 4) and np.all(np.isfinite(a))
        n0 = 1 if name == "accel.csv" else 0  # readings are latched at the end of their interval
        assert np.all(np.abs(a[:, 0] - (np.arange(len(a)) + n0) / rate) < 1e-12)
        assert np.all(np.diff(a[:, 0]) > 0)
        # written with repr: the text is the shortest repr of the parsed value
        assert all(repr(float(c)) == c for c in raw[100].split(","))
    truth = json.loads((out / "truth.json").read_text())
    assert truth["orientation"] == [0.0, -1.0, 0.0]
    assert truth["resonance"]["f0_hz"] == 150.0
    _, rows, _ = read_rows(out / "accel.csv")
    u2 = np.array(rows)[:100, 2]  # AK2, IA +y, still: aL3 = -1 g
    assert abs(u2.mean() / truth["units"][1]["still_reading_v"] - 1) < 1e-4


def test_repeat_redraws_only_the_random_parts(tmp_path):
    out = tmp_path / "rep"
    run_cli("run", "--out", str(out), "--repeat", "2", "--seed", "7", *CLI_FAST)
    t0 = json.loads((out / "rep00" / "truth.json").read_text())
    t1 = json.loads((out / "rep01" / "truth.json").read_text())
    for key in ("orientation", "tone", "random", "resonance", "rates", "segments", "triad"):
        assert t0[key] == t1[key], key
    for u0, u1 in zip(t0["units"], t1["units"]):
        assert u0["closed_form_unit_side"] == u1["closed_form_unit_side"]
        assert u0["still_reading_g"] == u1["still_reading_g"]
        assert u0["ve_time_domain_g"] != u1["ve_time_domain_g"]
    assert t0["seeds"]["repeat"] == 0 and t1["seeds"]["repeat"] == 1
    for name in ("accel.csv", "vib.csv", "reference.csv"):
        a0 = np.array(read_rows(out / "rep00" / name)[1])
        a1 = np.array(read_rows(out / "rep01" / name)[1])
        assert np.array_equal(a0[:, 0], a1[:, 0])
        assert not np.array_equal(a0[:, 1:], a1[:, 1:])
    # same seed, same repeat: identical files
    again = tmp_path / "again"
    run_cli("run", "--out", str(again), "--repeat", "2", "--seed", "7", *CLI_FAST)
    for name in ("accel.csv", "vib.csv", "reference.csv", "truth.json"):
        assert (again / "rep01" / name).read_bytes() == (out / "rep01" / name).read_bytes()
    # another seed: other conditions (tone amplitudes drawn from it)
    other = tmp_path / "other"
    run_cli("run", "--out", str(other), "--seed", "8", *CLI_FAST)
    assert json.loads((other / "truth.json").read_text())["tone"] != t0["tone"]


def test_repeat_keeps_the_tone_part_of_the_data():
    """Without noise and random vibration, two repeats are the same data."""
    cfg = rg.RunConfig(random_bands=NO_RANDOM, **FAST, **QUIET)
    a = rg.simulate(cfg)
    cfg.repeat = 3
    b = rg.simulate(cfg)
    assert np.array_equal(a.accel_v, b.accel_v) and np.array_equal(a.vib_v, b.vib_v)


def test_campaign_index(tmp_path):
    out = tmp_path / "camp"
    run_cli("campaign", "--out", str(out), "--orientations", "+z,oblique1", "--tone-freqs-hz", "30,120",
            *CLI_FAST)
    with open(out / "runs.csv") as f:
        lines = f.read().splitlines()
    assert lines[0].split(",") == rg.RUNS_CSV_COLUMNS
    rows = [ln.split(",") for ln in lines[1:]]
    assert len(rows) == 4
    for r in rows:
        truth = json.loads((out / r[2] / "truth.json").read_text())
        assert truth["orientation_name"] == r[3]
        assert truth["tone"]["freq_hz"] == [float(r[7])] * 3
        assert truth["tone"]["amp_g"] == [float(x) for x in r[8:11]]
        assert all(0.5 <= float(x) <= 2.0 for x in r[8:11])
        assert abs(float(r[14]) - math.sqrt(0.002 * 620)) < 1e-12


# --------------------------------------------------------------------------------------
# vibration sensors' acquisition delay, unit drift, rates that do not divide,
# per-reading truth (readings_truth.csv)

FLIGHT = dict(vibrate_throughout=True, duration_s=2.0, sensor_rate_hz=6400.0)


def tone_phase(x, fs, f):
    """Phase (rad) of ``sin(2 pi f t + phase)`` in samples ``x`` at ``t = k / fs``, least
    squares over whole periods (the run holds a whole number of periods of f)."""
    t = np.arange(len(x)) / fs
    basis = np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)], axis=1)
    (c_sin, c_cos), *_ = np.linalg.lstsq(basis, x, rcond=None)
    return math.atan2(c_cos, c_sin)


@pytest.mark.parametrize("method", ["exact", "bilinear"])
def test_daq_delay_shifts_the_tone_phase_by_w_d(method):
    """vib.csv with delay D lags the D = 0 run by exactly D: the tone's phase moves by
    -2 pi f D (to 1e-9 relative); readings and reference do not move."""
    d, f = 1.56e-3, 60.0
    cfg = rg.RunConfig(tone_hz=(f,) * 3, random_bands=NO_RANDOM, filter_method=method, **FLIGHT, **QUIET)
    a = rg.simulate(cfg)
    b = rg.simulate(rg.RunConfig(**{**cfg.__dict__, "daq_delay_s": d}))
    assert np.array_equal(a.accel_v, b.accel_v) and np.array_equal(a.ref_g, b.ref_g)
    assert b.truth["vibration_sensor"]["daq_delay_s"] == d
    want = -2 * math.pi * f * d
    for k in range(3):
        dp = tone_phase(b.vib_v[:, k], 6400.0, f) - tone_phase(a.vib_v[:, k], 6400.0, f)
        dp = (dp + math.pi) % (2 * math.pi) - math.pi
        assert abs(dp / want - 1) < 1e-9, (k, dp, want)


def test_daq_delay_of_the_random_vibration_is_a_pure_delay():
    """With random vibration: vib.csv(D) equals vib.csv(0) delayed by e^{-j w D} on its DFT
    (the signal is periodic over the run and band-limited), to 1e-12 of its RMS."""
    d = 0.37e-3  # not a whole number of samples
    cfg = rg.RunConfig(tone_hz=(50.0,) * 3, **FLIGHT, **QUIET)
    a = rg.simulate(cfg)
    b = rg.simulate(rg.RunConfig(**{**cfg.__dict__, "daq_delay_s": d}))
    x = a.vib_v
    spec = np.fft.rfft(x, axis=0) * np.exp(-2j * np.pi * np.fft.rfftfreq(len(x), 1 / 6400.0) * d)[:, None]
    shifted = np.fft.irfft(spec, n=len(x), axis=0)
    assert np.max(np.abs(shifted - b.vib_v)) < 1e-12 * np.sqrt(np.mean(x**2))
    # a shaker run (still / vibrating / still): the delayed data start D later
    cfg = rg.RunConfig(**FAST, **QUIET)
    a = rg.simulate(cfg)
    b = rg.simulate(rg.RunConfig(**{**cfg.__dict__, "daq_delay_s": 0.25}))
    lag = np.argmax(np.abs(b.vib_v[:, 2]) > 1e-9) - np.argmax(np.abs(a.vib_v[:, 2]) > 1e-9)
    assert abs(lag / 6400.0 - 0.25) <= 2 / 6400.0
    assert np.array_equal(a.accel_v, b.accel_v)


def test_daq_delay_is_checked(tmp_path):
    for bad in ("-0.1", "1.5", "abc"):
        r = subprocess.run([sys.executable, os.path.join(HERE, "rig_generator.py"), "run", "--out",
                            str(tmp_path / "x"), "--daq-delay-s", bad], capture_output=True, text=True)
        assert r.returncode == 2 and "--daq-delay-s" in r.stderr, r.stderr
    with pytest.raises(ValueError, match="still_s"):
        rg.simulate(rg.RunConfig(still_s=0.5, vib_s=3.0, daq_delay_s=0.8, **QUIET))


def test_unit_drift_is_a_ramp_per_unit():
    """Readings with drift R minus the same run without: r_u (t - T_a/2), |r_u| = R."""
    r_ug = 5.0
    cfg = rg.RunConfig(**FLIGHT)  # noise on: the same noise draws in both runs
    a = rg.simulate(cfg)
    b = rg.simulate(rg.RunConfig(**{**cfg.__dict__, "unit_drift_ug_per_s": r_ug}))
    rates = np.array(b.truth["unit_drift"]["rate_g_per_s"])
    assert np.allclose(np.abs(rates), r_ug * 1e-6, rtol=0, atol=0)
    k1 = np.array([u.passport.K1_v_per_g for u in b.triad])
    ramp = (b.accel_v - a.accel_v) / k1
    want = rates[None, :] * (a.t_accel - 0.5 / 800.0)[:, None]
    assert np.max(np.abs(ramp - want)) < 1e-14
    assert np.array_equal(a.vib_v, b.vib_v) and np.array_equal(a.ref_g, b.ref_g)
    assert np.array_equal(a.error_g, b.error_g)  # readings_truth: drift-free
    # the signs come from their own stream: other seeds give other signs
    signs = {tuple(np.sign(rg.drift_rates_g_per_s(rg.RunConfig(seed=s, unit_drift_ug_per_s=1.0))))
             for s in range(8)}
    assert len(signs) > 1


@pytest.mark.parametrize("sensor_hz,fine_hz", [(5000.0, 20000.0), (6400.0, 6400.0), (10000.0, 20000.0)])
def test_sensor_rates_that_do_not_divide_the_reading_rate(sensor_hz, fine_hz):
    cfg = rg.RunConfig(**{**FLIGHT, "sensor_rate_hz": sensor_hz}, **QUIET)
    res = rg.simulate(cfg)
    assert res.truth["rates"]["fine_hz"] == fine_hz
    assert res.vib_v.shape == (int(2 * sensor_hz), 3) and res.ref_g.shape == (int(2 * sensor_hz), 3)
    assert res.accel_v.shape == (1600, 3)
    assert np.all(np.abs(res.t_vib - np.arange(len(res.t_vib)) / sensor_hz) < 1e-12)
    assert np.all(np.abs(res.t_accel - np.arange(1, 1601) / 800.0) < 1e-12)
    # the same continuous signal at any rate: sensed_g equal to the 6.4 kHz run's
    ref = rg.simulate(rg.RunConfig(**FLIGHT, **QUIET))
    assert np.max(np.abs(res.sensed_g - ref.sensed_g)) < 1e-12
    # vib.csv samples at times common to both rates agree (1/200 s for 5 kHz and 6.4 kHz)
    step_a, step_b = int(sensor_hz / 200), 32
    assert np.max(np.abs(res.vib_v[::step_a] - ref.vib_v[::step_b])) < 1e-12
    # over the whole flight-like run the vibration's mean is 0: sensed averages to gravity
    g_ia = np.array([u.e_ia @ np.asarray(res.cfg.orientation) for u in res.triad])
    assert np.max(np.abs(res.sensed_g.mean(axis=0) - g_ia)) < 1e-12


def test_sensor_rate_that_does_not_divide_in_a_shaker_run():
    """5 kHz sensors, still / vibrating / still, random vibration only: sensed_g over the VE
    window averages to gravity's projection within the window mean of the random
    vibration (bound: sqrt(2 S int df / (2 pi f W)^2), times 5)."""
    cfg = rg.RunConfig(sensor_rate_hz=5000.0, still_s=1.0, vib_s=3.0, tone_amp_g=(0, 0, 0), **QUIET)
    res = rg.simulate(cfg)
    win = res.truth["segments"]["windows_s"]["vibrating"]
    w = win[1] - win[0]
    bound = 5 * math.sqrt(2 * 0.002 / (2 * math.pi * w) ** 2 * (1 / 20 - 1 / 640))
    mv = rg.reading_mask(res.cfg, res.t_accel, win)
    g_ia = np.array([u.e_ia @ np.asarray(res.cfg.orientation) for u in res.triad])
    dev = res.sensed_g[mv].mean(axis=0) - g_ia
    assert np.all(np.abs(dev) < bound), (dev, bound)
    assert np.all(np.abs(res.sensed_g[~mv][:400] - g_ia) < 1e-12)  # still before


def test_readings_truth_error_is_the_section6_exact_ve_for_tones():
    """Tones only, no mount, flight-like, whole periods of 30 / 50 / 120 Hz on x / y / z:
    the error averaged over the run is (FP)(g) - aL3 plus MODEL.md section 6's exact VE
    (written out here: binomial moments of aL3 + c sin, tone amplitudes below |aL3| so the
    asymmetry term is exact; the tones are at different frequencies, so no cross terms)."""
    amps = (0.5, 0.3, 0.55)
    cfg = rg.RunConfig(orientation="oblique1", tone_hz=(30.0, 50.0, 120.0), tone_amp_g=amps,
                       random_bands=NO_RANDOM, **FLIGHT, **QUIET)
    res = rg.simulate(cfg)
    g = np.asarray(res.cfg.orientation)
    for i, u in enumerate(res.triad):
        p = u.passport
        aL3, aL1, aL2 = u.e_ia @ g, u.e_oa @ g, u.e_pa @ g
        c = amps[int(np.argmax(np.abs(u.e_ia)))]
        s2, s4 = c**2 / 2, 3 * c**4 / 8
        ve = (p.k2 * s2 + p.k3 * 3 * aL3 * s2 + p.k4 * (6 * aL3**2 * s2 + s4)
              + p.k5 * (10 * aL3**3 * s2 + 5 * aL3 * s4))
        want = fp_independent(p, aL3, aL1, aL2) - aL3 + ve
        got = res.error_g[:, i].mean()
        assert abs(got - want) < 1e-12 * abs(want) + 1e-15, (i, got, want)
        assert abs(res.sensed_g[:, i].mean() - aL3) < 1e-13


def test_readings_truth_csv_against_truth_json(tmp_path):
    """readings_truth.csv: accel.csv's times; over the VE window its error averages to
    reading_shift_g + still_reading_g - <sensed> (the same readings), and to
    ve_time_domain_g + still_reading_g - aL3 within the first-order response to the
    window mean of the vibration."""
    out = tmp_path / "run"
    run_cli("run", "--out", str(out), "--orientation=oblique2", "--resonance-f0-hz", "150", *CLI_FAST)
    header, rows, raw = read_rows(out / "readings_truth.csv")
    assert header == ["time_s", "sensed1_g", "sensed2_g", "sensed3_g", "error1_g", "error2_g", "error3_g"]
    _, _, raw_accel = read_rows(out / "accel.csv")
    assert [r.split(",")[0] for r in raw] == [r.split(",")[0] for r in raw_accel]
    assert all(repr(float(c)) == c for c in raw[100].split(","))
    truth = json.loads((out / "truth.json").read_text())
    a = np.array(rows)
    cfg = rg.RunConfig(still_s=1.0, vib_s=2.0, sensor_rate_hz=6400.0, resonance=rg.Resonance())
    mv = rg.reading_mask(cfg, a[:, 0], truth["segments"]["windows_s"]["vibrating"])
    assert mv.sum() == truth["segments"]["readings_in_ve_window"]
    sensed, err = a[mv, 1:4].mean(axis=0), a[mv, 4:7].mean(axis=0)
    v_axis = np.max(np.abs(sensed - [u["aL3_g"] for u in truth["units"]]))
    for i, u in enumerate(truth["units"]):
        assert abs(err[i] - (u["reading_shift_g"] + u["still_reading_g"] - sensed[i])) < 1e-14
        want = u["ve_time_domain_g"] + u["still_reading_g"] - u["aL3_g"]
        assert abs(err[i] - want) < 3e-3 * v_axis + 1e-14, (i, err[i], want, v_axis)
    # still: error = (FP)(g) - aL3 exactly, sensed = aL3
    for i, u in enumerate(truth["units"]):
        assert np.all(np.abs(a[:400, 1 + i] - u["aL3_g"]) < 1e-12)
        assert np.all(np.abs(a[:400, 4 + i] - (u["still_reading_g"] - u["aL3_g"])) < 1e-12)


def test_every_tone_on_the_mount_resonance(tmp_path):
    """--tone-hz 150,150,150 --resonance-f0-hz 150: runs, and the tone at the units is
    |H(j w0)| = Q sqrt(1 + 1/Q^2) times the base's."""
    out = tmp_path / "res"
    run_cli("run", "--out", str(out), "--tone-hz", "150,150,150", "--resonance-f0-hz", "150",
            "--vibrate-throughout", "--duration-s", "2", "--sensor-rate-hz", "6400", "--no-tone")
    run_cli("run", "--out", str(out), "--tone-hz", "150,150,150", "--resonance-f0-hz", "150",
            "--vibrate-throughout", "--duration-s", "2", "--sensor-rate-hz", "6400")
    assert np.all(np.isfinite(np.array(read_rows(out / "readings_truth.csv")[1])))
    cfg = rg.RunConfig(tone_hz=(150.0,) * 3, tone_amp_g=(0, 0, 1.0), tone_phase_rad=(0, 0, 0),
                       random_bands=NO_RANDOM, resonance=rg.Resonance(), **FLIGHT, **QUIET)
    res = rg.simulate(cfg)
    q = 2.5
    box = abs(complex(rg.boxcar_response(150.0, 1 / 800.0)))
    amp = np.sqrt(2 * np.mean((res.sensed_g[:, 2] - 1.0) ** 2))
    assert abs(amp / (q * math.sqrt(1 + 1 / q**2) * box) - 1) < 1e-9


# --------------------------------------------------------------------------------------
# waveform_errors.py: matching compensated readings to readings_truth.csv, windows


def test_waveform_errors_matching_and_windows():
    import waveform_errors as we

    n, per = 64, 16  # 4 windows of 16 readings at 800 Hz (window 0.02 s)
    t_s = np.arange(1, n + 1) / 800.0
    sensed = np.tile([1.0, 0.0, -0.5], (n, 1))
    error = np.full((n, 3), 3e-3)
    off = np.array([1e-6, -2e-6, 0.0])

    def block(first, count, flags, t_shift_ns=0):
        t0 = int(round(t_s[first] * 1e9)) + t_shift_ns
        return (first, t0, 1_250_000, flags, sensed[first:first + count] + off)

    # window 0: main-only; 1: waveform; 2: a fallback block; 3: one reading missing
    blocks = [block(0, 16, we.MAIN_ONLY), block(16, 16, we.WAVEFORM), block(32, 8, we.WAVEFORM),
              block(40, 8, we.WAVEFORM_FALLBACK), block(48, 15, we.WAVEFORM)]
    r = we.measure(blocks, t_s, sensed, error, window_s=per / 800.0)
    assert r["window_readings"] == per and r["windows_left_out"] == 1
    assert r["sample_index_minus_row"] == [0] and r["max_time_diff_s"] < 1e-12
    assert (r["all"]["windows"], r["compensated"]["windows"], r["waveform"]["windows"],
            r["fallback"]["windows"]) == (3, 2, 1, 1)
    for u in range(3):
        assert abs(r["all"]["units"][u]["rms_g"] - abs(off[u])) < 1e-15
    assert abs(r["uncompensated"]["all_units_rms_g"] - 3e-3) < 1e-15
    assert r["blocks_per_flag"] == {"MAIN_ONLY": 1, "WAVEFORM": 3, "WAVEFORM_FALLBACK": 1}
    # a reading 2 % of a period off its row: refused, loudly
    with pytest.raises(ValueError, match="of a period"):
        we.measure([block(0, 16, 0, t_shift_ns=25_000)], t_s, sensed, error, window_s=0.02)
    # half a period (the start of the interval instead of its end): refused
    with pytest.raises(ValueError, match="time conventions"):
        we.measure([block(1, 8, 0, t_shift_ns=-625_000)], t_s, sensed, error, window_s=0.02)
    assert we.truth_only(t_s, error, 0.02)["uncompensated"]["windows"] == 4


# --------------------------------------------------------------------------------------
# hidden effects (docs/effects.md): each against a closed form written out here

EFF_AMPS, EFF_PHASES = (1.0, 1.5, 2.0), (0.0, 0.9, 2.0)


def effect_run(effects=(), amps=(0.0, 0.0, 2.0), f=60.0, orientation="+z", passport=None, **kw):
    """Quiet, flight-like 2 s at 6.4 kHz, tones ``amps`` at ``f`` on x, y, z, and ``effects``."""
    args = dict(orientation=orientation, orientation_name=orientation, tone_hz=(f,) * 3, tone_amp_g=amps,
                tone_phase_rad=EFF_PHASES, random_bands=NO_RANDOM,
                effects=[rg.parse_effect(s) for s in effects], **FLIGHT, **QUIET)
    args.update(kw)
    return rg.simulate(rg.RunConfig(**args), rg.default_triad(passport or only()), keep_fine=True)


def shift_of(res, unit):
    return res.truth["units"][unit]["effects_mean_shift_g"]


def axis_sign(e):
    k = int(np.argmax(np.abs(e)))
    return k, float(e[k])


EFFECT_CLI = ["--sensor-rate-hz", "3200", "--accel-rate-hz", "400", "--still-s", "0.5", "--vib-s", "1",
              "--tone-hz", "40,40,40"]
DATA_FILES = ("accel.csv", "vib.csv", "reference.csv", "readings_truth.csv")


def test_effects_at_zero_strength_are_bit_identical(tmp_path):
    run_cli("run", "--out", str(tmp_path / "plain"), *EFFECT_CLI)
    run_cli("run", "--out", str(tmp_path / "zero"), *EFFECT_CLI, "--sensor-gain-error", "0,0,0",
            "--effect", "vibropendulous:c_rad_per_g=0,tau_s=0.002", "--effect", "anisoelastic:k_ae_per_g=0",
            "--effect", "high_order_nonlinearity:k6_ppm_per_g5=0,k7_ppm_per_g6=0",
            "--effect", "heating:c_g_per_g2=0,tau_s=2", "--effect", "scale_factor_frequency:corner_hz=800,lambda_hf=1")
    for name in DATA_FILES:
        assert (tmp_path / "plain" / name).read_bytes() == (tmp_path / "zero" / name).read_bytes(), name
    truth = json.loads((tmp_path / "zero" / "truth.json").read_text())
    assert [e["kind"] for e in truth["effects"]] == ["vibropendulous", "anisoelastic", "high_order_nonlinearity",
                                                     "heating", "scale_factor_frequency"]
    assert all(e["zero_strength"] for e in truth["effects"])
    assert json.loads((tmp_path / "plain" / "truth.json").read_text())["effects"] == []


def test_truth_records_every_effect_and_its_parameters(tmp_path):
    out = tmp_path / "eff"
    run_cli("run", "--out", str(out), *EFFECT_CLI, "--unit-response-hz", "1200", "--unit-response-damping", "0.4",
            "--sensor-gain-error", "0,0.05,0", "--effect", "anisoelastic:k_ae_per_g=2e-5,units=1",
            "--effect", "saturation:range_g=15")
    eff = json.loads((out / "truth.json").read_text())["effects"]
    by = {e["kind"]: e for e in eff}
    assert by["unit_response"]["natural_freq_hz"] == 1200.0 and by["unit_response"]["damping_ratio"] == 0.4
    assert by["sensor_error"]["gain_error"] == 0.05 and by["sensor_error"]["units"] == [1]
    assert by["anisoelastic"]["k_ae_per_g"] == 2e-5 and by["anisoelastic"]["units"] == [1]
    assert by["saturation"]["range_g"] == 15.0 and by["saturation"]["units"] == [0, 1, 2]


def test_effect_specs_are_checked():
    with pytest.raises(ValueError, match=r"unknown kind 'nope'"):
        rg.parse_effect("nope:x=1")
    with pytest.raises(ValueError) as e:
        rg.parse_effect("vibropendulous:c_rad_per_g=0.5,foo=1,units=3")
    msg = str(e.value)  # every problem at once, with the value and the rule
    assert "c_rad_per_g = 0.5: must be finite and |c| <= 0.1 rad/g" in msg
    assert "foo: unknown key" in msg and "tau_s: required" in msg and "units = '3'" in msg
    assert rg.parse_effect("heating:c_g_per_g2=1e-6,tau_s=3,units=0+2").units == (0, 2)
    with pytest.raises(ValueError, match="at least one of"):
        rg.parse_effect("high_order_nonlinearity:units=1")


def test_unit_response_filters_the_ia_vibration_only():
    """k2 only, 2 g tone at 1200 Hz on z through a 1500 Hz, zeta 0.3 response: VE = 0.5 k2 (|H| A)^2
    with H = wn^2/(wn^2 - w^2 + 2j zeta wn w); a tone on x (AK3's OA) goes through untouched
    (m31 a3 a1 with the IA tone off: no change), and sensed/readings_truth's sensed is the
    acceleration at the unit (without its response)."""
    k2, amp, f, fn, z = 105e-6, 2.0, 1200.0, 1500.0, 0.3
    wn, w = 2 * math.pi * fn, 2 * math.pi * f
    h = abs(wn**2 / (wn**2 - w**2 + 2j * z * wn * w))
    ur = rg.UnitResponse(fn, z)
    for thr in (True, False):
        extra = {} if thr else dict(vibrate_throughout=False, still_s=0.5, vib_s=1.0)
        res = effect_run(amps=(0.0, 0.0, amp), f=f, passport=only(k2=k2), unit_response=ur, **extra)
        assert abs(ve_of(res, 2) / (0.5 * k2 * (h * amp) ** 2) - 1) < 1e-9
        plain = effect_run(amps=(0.0, 0.0, amp), f=f, passport=only(k2=k2), **extra)
        assert np.array_equal(res.sensed_g, plain.sensed_g)
    # OA untouched: m31 a3 a1 with a tone on OA (x) only and aL3 = 1 g: 0 VE, equal readings
    res = effect_run(amps=(amp, 0.0, 0.0), f=f, passport=only(m31=11.6e-6), unit_response=ur)
    plain = effect_run(amps=(amp, 0.0, 0.0), f=f, passport=only(m31=11.6e-6))
    assert np.max(np.abs(res.accel_clean_g[:, 2] - plain.accel_clean_g[:, 2])) < 1e-15


def test_sensor_gain_error_scales_one_sensor():
    a = effect_run(amps=(1.0, 1.0, 1.0))
    b = effect_run(amps=(1.0, 1.0, 1.0), sensor_gain_error=(0.0, -0.04, 0.0))
    assert np.allclose(b.vib_v[:, 1], 0.96 * a.vib_v[:, 1], rtol=1e-14, atol=1e-18)
    assert np.array_equal(a.vib_v[:, [0, 2]], b.vib_v[:, [0, 2]]) and np.array_equal(a.accel_v, b.accel_v)


@pytest.mark.parametrize("flight", [True, False])
def test_vibropendulous_mean_with_phase(flight):
    """c 0.5 aB3 aB2 Re(HP(jw) e^{j(phi3 - phi2)}), HP = jw tau/(1 + jw tau), with signed axes."""
    c, tau, f = 2e-4, 2e-3, 60.0
    extra = {} if flight else dict(vibrate_throughout=False, still_s=0.5, vib_s=1.0)
    res = effect_run([f"vibropendulous:c_rad_per_g={c},tau_s={tau}"], amps=EFF_AMPS, f=f,
                     orientation="oblique1", **extra)
    w = 2 * math.pi * f
    hp = 1j * w * tau / (1 + 1j * w * tau)
    for i, u in enumerate(res.triad):
        (x3, s3), (x2, s2) = axis_sign(u.e_ia), axis_sign(u.e_pa)
        want = c * 0.5 * s3 * EFF_AMPS[x3] * s2 * EFF_AMPS[x2] * (hp * np.exp(
            1j * (EFF_PHASES[x3] - EFF_PHASES[x2]))).real
        assert abs(shift_of(res, i) / want - 1) < 1e-9, (i, shift_of(res, i), want)
    # error_g (readings_truth) carries it: error with the effect minus without = the effect
    plain = effect_run(amps=EFF_AMPS, f=f, orientation="oblique1", **extra)
    d = res.error_g - plain.error_g
    assert np.allclose(d, res.fine["effect_readings_g"], rtol=0, atol=1e-15)


def test_anisoelastic_mean_and_unit_selection():
    k = 3e-5
    res = effect_run([f"anisoelastic:k_ae_per_g={k},units=2"], amps=EFF_AMPS, orientation="oblique1")
    plain = effect_run(amps=EFF_AMPS, orientation="oblique1")
    g = np.asarray(res.cfg.orientation)
    u = res.triad[2]
    (x1, s1), (x2, s2) = axis_sign(u.e_oa), axis_sign(u.e_pa)
    want = k * ((u.e_oa @ g) * (u.e_pa @ g)
                + 0.5 * s1 * s2 * EFF_AMPS[x1] * EFF_AMPS[x2] * math.cos(EFF_PHASES[x1] - EFF_PHASES[x2]))
    assert abs(shift_of(res, 2) / want - 1) < 1e-9
    assert abs(res.truth["units"][2]["effects_still_g"] / (k * (u.e_oa @ g) * (u.e_pa @ g)) - 1) < 1e-12
    assert np.array_equal(res.accel_v[:, :2], plain.accel_v[:, :2])  # units 0 and 1 untouched


def test_high_order_nonlinearity_tone_and_random():
    """Tone: k6 E[(1 + A sin)^6] + k7 E[(1 + A sin)^7] by the binomial rule; random only: the
    k6 term's mean is k6 E[a3^6] of the samples the unit saw (trapezoid over the window)."""
    mom = [1, 0, 0.5, 0, 3 / 8, 0, 5 / 16, 0]
    amp = 3.0
    want = (0.05e-6 * sum(math.comb(6, q) * amp**q * mom[q] for q in range(7))
            + 0.01e-6 * sum(math.comb(7, q) * amp**q * mom[q] for q in range(8)))
    res = effect_run(["high_order_nonlinearity:k6_ppm_per_g5=0.05,k7_ppm_per_g6=0.01"], amps=(0.0, 0.0, amp))
    assert abs(shift_of(res, 2) / want - 1) < 1e-12
    res = effect_run(["high_order_nonlinearity:k6_ppm_per_g5=0.05"], amps=(0.0, 0.0, 0.0),
                     random_bands=[(20.0, 640.0, (0.0, 0.0, 0.01))])
    win = rg.windows(res.cfg)["vibrating"]
    t = res.fine["t"]
    a3 = res.fine["a_unit"][2][(t >= win[0] - 1e-12) & (t <= win[1] + 1e-12)]
    e6 = (np.sum(a3**6) - 0.5 * (a3[0] ** 6 + a3[-1] ** 6)) / (len(a3) - 1)
    assert abs(shift_of(res, 2) / (0.05e-6 * e6) - 1) < 1e-7  # linear part: exact boxcar, not trapezoid


def test_heating_warm_up():
    """tau b' = c v^2 - b from b(0) = 0, v = A sin(w t + phi): window mean of the exact solution
    (DC part and 2w ripple) against the first-order-hold recursion: 1e-6 at 6.4 kHz."""
    c, tau, amp, f = 1e-5, 0.5, 2.0, 60.0
    res = effect_run([f"heating:c_g_per_g2={c},tau_s={tau}"], amps=(0.0, 0.0, amp), f=f)
    want = rg.heating_window_mean(c, tau, amp, f, EFF_PHASES[2], res.cfg.settle, res.cfg.t_run)
    assert abs(shift_of(res, 2) / want - 1) < 1e-6
    # the bias grows through the run: the last readings carry more than the first
    e = res.fine["effect_readings_g"][:, 2]
    assert e[-80:].mean() > 2 * e[80:160].mean() > 0
    # and the closed form itself against a quadrature of the exact b(t)
    from scipy import integrate
    w2, psi = 4 * math.pi * f, 2 * EFF_PHASES[2]

    def b(tt):
        return c * amp**2 / 2 * ((1 - math.exp(-tt / tau)) - ((np.exp(1j * (w2 * tt + psi)) - np.exp(1j * psi)
                                  * math.exp(-tt / tau)) / (1 + 1j * w2 * tau)).real)

    q = integrate.quad(b, 0.3, 1.7, limit=500)[0] / 1.4
    assert abs(rg.heating_window_mean(c, tau, amp, f, EFF_PHASES[2], 0.3, 1.7) / q - 1) < 1e-9


def test_saturation_clips_a_sine():
    """k1 only, aL3 = 1 g + 4 g tone, range 3 g: E[clip - identity] = -up(r - 1) + up(r + 1),
    up(c) = (sqrt(A^2 - c^2) - c acos(c/A))/pi; the trapezoid over the kinks: O(h^2), 2e-5."""
    amp, r = 4.0, 3.0

    def up(cc):
        return (math.sqrt(amp**2 - cc**2) - cc * math.acos(cc / amp)) / math.pi if cc < amp else 0.0

    res = effect_run([f"saturation:range_g={r}"], amps=(0.0, 0.0, amp))
    want = -up(r - 1.0) + up(r + 1.0)
    assert want < 0 and abs(shift_of(res, 2) / want - 1) < 3e-5
    # a clipped reading: the exact boxcar of the linear part plus the trapezoid of the clip's
    # correction, so it passes the range by O((w h)^2 A) (1.2e-3 g here), 16x less at 4x the rate
    assert np.max(np.abs(res.accel_clean_g)) < r + 2e-3
    fine = effect_run([f"saturation:range_g={r}"], amps=(0.0, 0.0, amp), oversample=4)
    assert np.max(np.abs(fine.accel_clean_g)) < r + 1e-4
    assert abs(shift_of(fine, 2) / want - 1) < 2e-6


def test_scale_factor_frequency_sign_term():
    """0.5 k1 d1A A (Re L - 1) (2/pi) sqrt(1 - aL^2/A^2) (docs/effects.md), d1A exaggerated
    to 0.1; the k1 (L - 1) a3 part averages out over whole periods; 1.8e-2 at 6.4 kHz."""
    fc, lam, amp, f = 800.0, 1.5, 2.0, 400.0
    lf = (1 + lam * 1j * f / fc) / (1 + 1j * f / fc)
    want = 0.5 * 0.1 * amp * (lf.real - 1) * (2 / math.pi) * math.sqrt(1 - 1 / amp**2)
    res = effect_run([f"scale_factor_frequency:corner_hz={fc},lambda_hf={lam}"], amps=(0.0, 0.0, amp), f=f,
                     passport=only(d1a=0.1))
    assert abs(shift_of(res, 2) / want - 1) < 2e-2
    # per reading the linear part k1 (L - 1) v3 is there: |L - 1| A times the reading's boxcar
    f = 130.0  # (d1A = 0: the linear part alone; 13/80 of the reading rate, whole cycles)
    lf = (1 + lam * 1j * f / fc) / (1 + 1j * f / fc)
    res = effect_run([f"scale_factor_frequency:corner_hz={fc},lambda_hf={lam}"], amps=(0.0, 0.0, amp), f=f)
    plain = effect_run(amps=(0.0, 0.0, amp), f=f)
    d = res.accel_clean_g[:, 2] - plain.accel_clean_g[:, 2]
    box = abs(complex(rg.boxcar_response(f, 1 / 800.0)))
    assert abs(np.sqrt(2 * np.mean(d**2)) / (abs(lf - 1) * amp * box) - 1) < 1e-9


# --------------------------------------------------------------------------------------
# waveform_battery.py: the members' generator options, and the scoring (hand-made JSON)


def test_waveform_battery_members_make_valid_rigs():
    """Every member's generator options parse and validate (no generation), and hide
    exactly the member's kinds, with the lab's parameter names mapped."""
    import waveform_battery as wb

    assert len(wb.SINGLES) == 9 and sum("+" in m for m in wb.MEMBERS) == 4 and "nothing" in wb.MEMBERS
    for name, m in wb.MEMBERS.items():
        for i in range(wb.SIZES["full"]["runs"]):
            args = ["run", "--out", "unused", "--vibrate-throughout", "--duration-s", "4",
                    "--sensor-rate-hz", "6400", "--oversample", "4", *m["design"](i), *wb.generator_args(m["effects"])]
            a = rg.build_parser().parse_args(args)
            cfg, _ = rg.config_from_args(a)
            cfg.tone_hz = a.tone_hz
            rg.resolve_conditions(cfg).validate()
        truth = rg.effects_truth(cfg)
        assert {e["kind"] for e in truth} == set(wb.member_truth(name)["kinds"]), name
        for kind, k in wb.member_truth(name)["kinds"].items():
            rec = next(e for e in truth if e["kind"] == kind)
            for pname in k["hidden"]:
                assert rec[pname] == k["params"][pname], (name, kind, pname)
            if kind == "sensor_error":
                assert rec["units"] == [k["unit"]]


def _diag(found, params, verdict="effect", path="waveform"):
    return {"path": path, "verdict": verdict, "found": found, "params": params, "chi2_per_dof": 1.02,
            "elapsed_s": 3.5}


def test_waveform_battery_scoring():
    import waveform_battery as wb

    t = wb.member_truth("vibropendulous")
    good = [{"kind": "vibropendulous", "name": "c_rad_per_g", "value": 2.1e-4, "sigma": 0.05e-4},
            {"kind": "vibropendulous", "name": "tau_s", "value": 0.0019, "sigma": 0.0001}]
    s = wb.score(t, _diag(["vibropendulous"], good))
    assert s["pass"] and [round(r["pull"], 6) for r in s["params"]] == [2.0, -1.0]
    # a pull beyond 3 sigma, a missing parameter, a spurious effect, the wrong verdict or path
    bad = [dict(good[0], value=2.2e-4), good[1]]
    assert not wb.score(t, _diag(["vibropendulous"], bad))["pass"]
    assert "tau_s not reported" in " ".join(wb.score(t, _diag(["vibropendulous"], good[:1]))["reasons"])
    s = wb.score(t, _diag(["vibropendulous", "heating"], good))
    assert not s["pass"] and "spurious heating" in s["reasons"]
    assert not wb.score(t, _diag(["vibropendulous"], good, verdict="confounded"))["pass"]
    assert not wb.score(t, _diag(["vibropendulous"], good, path="statistics"))["pass"]
    assert not wb.score(t, _diag(["vibropendulous"], [dict(good[0], sigma=0.0), good[1]]))["pass"]
    # nothing: verdict noise
    n = wb.member_truth("nothing")
    assert wb.score(n, _diag([], [], verdict="noise"))["pass"]
    assert not wb.score(n, _diag(["heating"], [], verdict="effect"))["pass"]
    # a pair; the sensor error's unit when the JSON carries it; k7 = 0 left out of a member
    # is scored when reported; the chain's delay against 0
    p = wb.member_truth("mount_resonance+sensor_error")
    params = [{"kind": "mount_resonance", "name": "freq_hz", "value": 150.3, "sigma": 0.2},
              {"kind": "mount_resonance", "name": "q", "value": 2.45, "sigma": 0.05},
              {"kind": "sensor_error", "name": "gain_error", "value": 0.0, "sigma": 0.001, "unit": 0},
              {"kind": "sensor_error", "name": "gain_error", "value": 0.041, "sigma": 0.002, "unit": 2},
              {"kind": "sensor_chain", "name": "delay_s", "value": 2e-6, "sigma": 1e-6}]
    s = wb.score(p, _diag(["sensor_error", "mount_resonance"], params))
    assert s["pass"], s["reasons"]
    params[-1]["value"] = 5e-6
    assert "delay_s" in " ".join(wb.score(p, _diag(["sensor_error", "mount_resonance"], params))["reasons"])
    h = wb.member_truth("heating")
    assert set(h["kinds"]["heating"]["params"]) == {"c_g_per_g2", "tau_s"}
    assert wb.member_truth("high_order_nonlinearity")["kinds"]["high_order_nonlinearity"]["hidden"] == [
        "k6_ppm_per_g5", "k7_ppm_per_g6"]
    assert "PASS" in wb.format_row("vibropendulous", wb.score(t, _diag(["vibropendulous"], good)))


@pytest.mark.skipif(not os.path.exists(os.path.join(ROOT, "target", "debug", "vibrocomp")),
                    reason="needs target/debug/vibrocomp (cargo build -p vibrocomp)")
def test_waveform_battery_generates_and_imports(tmp_path):
    """One member at CI size, generated and imported (no diagnosis): the logs exist and the
    runs' truth records the hidden effect."""
    import waveform_battery as wb

    made = wb.make_member(os.path.join(ROOT, "target", "debug", "vibrocomp"), str(tmp_path), "heating", "ci",
                          seed=5, jobs=2, fit_delay=False)
    assert len(made["logs"]) == 2 and all(os.path.getsize(p) > 100_000 for p in made["logs"])
    truth = json.loads(open(os.path.join(made["runs"][1], "truth.json")).read())
    assert truth["effects"][0]["kind"] == "heating" and truth["effects"][0]["tau_s"] == 2.0
    # heating runs on the shaker: still 2 s, vibrating 4 s, still 2 s.
    assert truth["orientation_name"] == "oblique1" and truth["segments"]["t_run_s"] == 8.0
    assert "delay_s = 0.0" in open(os.path.join(made["runs"][0], "rig.toml")).read()


def test_waveform_battery_reads_the_statistics_paths_json():
    """Today's `lab diagnose --json` (statistics path) maps onto the battery's interface."""
    import waveform_battery as wb

    today = {"comparison": {"paths": {"waveform": 0, "statistics": 12}}, "elapsed_s": 0.9,
             "verdict": {"verdict": "effect", "kind": "vibropendulous", "kinds": ["vibropendulous"],
                         "chi2_per_dof_after": 0.21,
                         "params": [{"effect": "vibropendulous", "name": "c_rad_per_g", "value": 2.15e-4,
                                     "sigma": 2.6e-5},
                                    {"effect": "vibropendulous", "name": "tau_s", "value": 1.87e-3, "sigma": 3.3e-4}]}}
    n = wb.normalize(today)
    assert (n["path"], n["verdict"], n["found"], n["chi2_per_dof"]) == (
        "statistics", "effect", ["vibropendulous"], 0.21)
    t = wb.member_truth("vibropendulous")
    assert not wb.score(t, today)["pass"]  # not the waveform path
    s = wb.score(t, today, require_path="any")
    assert s["pass"] and abs(s["params"][0]["pull"] - 0.15e-4 / 2.6e-5) < 1e-12
