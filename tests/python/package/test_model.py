"""The model from Python against the command line, bit for bit: the VE (exact, paper,
as published; tones, random vibration given as RMS or as a band PSD; an extended
model), the compensation stages of [P2 (17)-(20)], the requirements; passports and
triads against their files read with Python's own TOML reader; values refused by the
files' rules, every problem at once."""

import json
import math
import sys

import numpy as np
import pytest

import vibrocomp as vc
from conftest import REPO

VE_KEYS = ("d01_g", "d02_g", "d03_g", "delta1", "delta2_per_g", "delta3_per_g2",
           "additive_g", "multiplicative_g", "total_g")
STAGE_KEYS = ("a1_g", "a2_g", "a3_g", "a4_g", "main_g", "det_g", "rand_g")
FLAGS = {
    "al1_g": "--aL1-g", "al2_g": "--aL2-g", "al3_g": "--aL3-g",
    "ab1_g": "--aB1-g", "ab2_g": "--aB2-g", "ab3_g": "--aB3-g", "freq_hz": "--freq-hz",
    "phase31_deg": "--phase31-deg", "phase32_deg": "--phase32-deg",
    "sigma1_g": "--sigma1-g", "sigma2_g": "--sigma2-g", "sigma3_g": "--sigma3-g",
    "cov31_g2": "--cov31-g2", "cov32_g2": "--cov32-g2", "kurtosis3": "--kurtosis3",
    "reading_g": "--reading-g", "reading1_g": "--reading1-g", "reading2_g": "--reading2-g",
}


def conditions(seed, n, random_part=True, tones=True):
    """`n` conditions drawn over the model's whole range: flight along all axes, tones
    with cross-axis amplitudes and phases, random vibration with covariances and
    kurtosis."""
    rng = np.random.default_rng(seed)
    c = {
        "al1_g": rng.uniform(-3, 3, n), "al2_g": rng.uniform(-3, 3, n), "al3_g": rng.uniform(-8, 8, n),
    }
    if tones:
        c.update(ab1_g=rng.uniform(0, 1.5, n), ab2_g=rng.uniform(0, 1.5, n), ab3_g=rng.uniform(0, 3, n),
                 freq_hz=rng.choice([0.0, 40.0, 120.0, 300.0], n),
                 phase31_deg=rng.uniform(-180, 180, n), phase32_deg=rng.uniform(-180, 180, n))
    if random_part:
        s = rng.uniform(0.1, 2.0, (3, n))
        c.update(sigma1_g=s[0], sigma2_g=s[1], sigma3_g=s[2],
                 cov31_g2=rng.uniform(-0.5, 0.5, n) * s[0] * s[2],
                 cov32_g2=rng.uniform(-0.5, 0.5, n) * s[1] * s[2],
                 kurtosis3=rng.uniform(2.0, 5.0, n))
    return c


def flags(c, i):
    return [f"{FLAGS[k]}={float(v[i])!r}" for k, v in c.items()]


def same(a, b):
    """Equal bit for bit (NaN equal to NaN, -0.0 apart from 0.0)."""
    a, b = float(a), float(b)
    return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))


@pytest.mark.parametrize("passport,mode,seed", [
    ("AL-15", "exact", 1), ("AL-15", "paper", 2), ("AL-1M", "as-published", 3), ("AKS-05", "exact", 4),
])
def test_the_ve_of_every_condition_is_the_command_lines_bit_for_bit(cli, passport, mode, seed):
    c = conditions(seed, 6)
    v = vc.ve(passport, mode=mode, **c)
    for i in range(6):
        want = cli("model", "ve", "--passport", passport, "--mode", mode, *flags(c, i))
        assert want["mode"] == mode and want["passport"] == passport
        for k in VE_KEYS:
            assert same(getattr(v, k)[i], want[k]), (k, i, getattr(v, k)[i], want[k])


def test_tones_alone_random_alone_and_a_band_psd_are_the_command_lines(cli):
    psd = REPO / "config" / "vibration" / "p1-table3.csv"
    tones = conditions(5, 3, random_part=False)
    rand = conditions(6, 3, tones=False)
    for c, extra in ((tones, {}), (rand, {})):
        v = vc.ve("AL-15", **c, **extra)
        for i in range(3):
            want = cli("model", "ve", "--passport", "AL-15", *flags(c, i))
            assert all(same(getattr(v, k)[i], want[k]) for k in VE_KEYS)
    al3 = np.array([0.0, 2.5, -4.0])
    v = vc.ve("AL-15", al3_g=al3, psd=psd)
    for i, a in enumerate(al3):
        want = cli("model", "ve", "--passport", "AL-15", f"--aL3-g={float(a)!r}", "--psd", psd)
        assert all(same(getattr(v, k)[i], want[k]) for k in VE_KEYS)


def test_arrays_broadcast_and_scalars_give_floats():
    v = vc.ve("AL-15", al3_g=np.array([[0.0], [1.0]]), ab3_g=np.array([0.2, 0.4, 0.8]), freq_hz=40.0)
    assert v.total_g.shape == (2, 3)
    one = vc.ve("AL-15", al3_g=1.0, ab3_g=0.4, freq_hz=40.0)
    assert isinstance(one.total_g, float) and one.total_g == v.total_g[1, 1]


@pytest.mark.parametrize("mode", ["exact", "paper", "as-published"])
def test_the_compensation_stages_are_the_command_lines_bit_for_bit(cli, mode):
    rng = np.random.default_rng(11)
    c = conditions(12, 5)
    c.pop("al1_g"), c.pop("al2_g"), c.pop("al3_g")
    c.update(reading_g=rng.uniform(-6, 6, 5), reading1_g=rng.uniform(-2, 2, 5), reading2_g=rng.uniform(-2, 2, 5))
    s = vc.compensate("AL-15", mode=mode, **c)
    for i in range(5):
        want = cli("model", "compensate", "--passport", "AL-15", "--mode", mode, *flags(c, i))
        for k in STAGE_KEYS:
            assert same(getattr(s, k)[i], want[k]), (k, i)


def test_an_extended_model_gives_the_command_lines_ve_and_stages(cli, tmp_path):
    campaign = REPO / "examples" / "python" / "data" / "campaign-mount-k6.csv"
    path = tmp_path / "model.toml"
    cli("lab", "add", "mount_resonance,high_order_nonlinearity", "--from", campaign, "--out", path)
    model = vc.Model.load(path)
    assert model.effects == ["mount_resonance", "high_order_nonlinearity"]
    c = conditions(21, 4, random_part=False)
    v = vc.ve("AL-15", model=path, **c)
    for i in range(4):
        want = cli("model", "ve", "--passport", "AL-15", "--model", path, *flags(c, i))
        assert same(v.ve_g[i], want["ve_g"]) and same(v.base_ve_g[i], want["base_ve_g"])
        assert same(v.sensor_rms_factor[i], want["sensor_rms_factor"])
        assert [e["kind"] for e in want["effects"]] == list(v.effects)
        assert all(same(v.effects[e["kind"]][i], e["ve_g"]) for e in want["effects"])
    readings = np.array([0.5, 3.0])
    s = vc.compensate("AL-15", readings, model=model, ab3_g=1.2, freq_hz=48.0)
    for i, r in enumerate(readings):
        want = cli("model", "compensate", "--passport", "AL-15", "--model", path,
                   f"--reading-g={float(r)!r}", "--aB3-g=1.2", "--freq-hz=48.0")
        assert same(s.a4_extended_g[i], want["a4_extended_g"])
        assert all(same(getattr(s, k)[i], want[k]) for k in STAGE_KEYS)
        assert all(same(s.effects[e["kind"]][i], e["ve_g"]) for e in want["effects"])


@pytest.mark.parametrize("mode", ["paper", "exact"])
def test_the_requirements_are_the_command_lines(cli, mode):
    r = vc.require(1e-4, 2.0, ab1_g=0.3, ab3_g=0.42, sigma3_g=0.5, mode=mode)
    want = cli("require", "--dstar-g=0.0001", "--aL3-g=2.0", "--aB1-g=0.3", "--aB3-g=0.42",
               "--sigma3-g=0.5", "--mode", mode)
    assert r.to_dict() == want


@pytest.mark.skipif(sys.version_info < (3, 11), reason="tomllib")
def test_passports_and_triads_are_their_files():
    import tomllib

    for pid, name in (("AL-15", "al-15"), ("AL-1M", "al-1m"), ("AKS-05", "aks-05")):
        path = REPO / "config" / "accelerometers" / f"{name}.toml"
        want = tomllib.loads(path.read_text())
        by_id, by_file = vc.Passport.load(pid), vc.Passport.load(path)
        assert by_id.id == pid and by_file.source == str(path)
        for k, x in want.items():
            assert by_id.fields[k] == x and by_file.fields[k] == x, k
    triad = tomllib.loads((REPO / "config" / "triads" / "default.toml").read_text())
    t = vc.Triad.load("default")
    assert [u.name for u in t.units] == [u["name"] for u in triad["unit"]]
    for u, w in zip(t.units, triad["unit"]):
        assert (u.ia, u.oa, u.pa) == tuple(("+" + w[k]).replace("+-", "-").replace("++", "+") for k in ("ia", "oa", "pa"))


def test_values_outside_the_rules_are_refused_all_at_once():
    with pytest.raises(vc.VibrocompError) as e:
        vc.ve("AL-15", al3_g=[0.0, 2000.0], ab3_g=[0.1, -1.0], kurtosis3=40.0, sigma3_g=1.0)
    msg = str(e.value)
    assert "al3_g[1] = 2000: must be finite and within +-1000 g" in msg
    assert "ab3_g[1] = -1: must be finite and 0 <= aB <= 1000 g" in msg
    assert "kurtosis3[0] = 40: must be finite and 1 <= kurtosis <= 30" in msg
    assert e.value.file is None
    with pytest.raises(vc.VibrocompError, match="neither a readable file nor a known passport id"):
        vc.Passport.load("AL-99")
    with pytest.raises(vc.VibrocompError, match="mode"):
        vc.ve("AL-15", al3_g=1.0, mode="approximate")
    with pytest.raises(TypeError, match="unknown vibration argument"):
        vc.ve("AL-15", al3_g=1.0, sigma4_g=1.0)
    with pytest.raises(ValueError):
        vc.ve("AL-15", al3_g=[1.0, 2.0], ab3_g=[0.1, 0.2, 0.3])
