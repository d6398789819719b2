"""A study, run by hand (not a test): how the shake-table VE measurement's stated
uncertainty [P2 (16)] (MODEL.md section 8, batch means as `vibrocomp identify measure`
computes them) compares with its scatter over repeats with other random draws, on the
independent generator's campaign (8 orientations x 3 tones, 4 repeats; tones 0.5..2 g
and random 20..640 Hz at 0.002 g^2/Hz per body axis):

- batch means of the raw vibrating record (what `identify measure` does);
- the same after removing the linear response (k1 a3 + m1 a1 + m2 a2, through K1)
  measured by the DC-coupled reference accelerometer, averaged over each reading's
  interval by the trapezoid rule over the reference's samples;
- batches of whole tone periods of the raw record.

    python3 tests/python/measure_study.py nofit /tmp/camp6400 6400

(`fit` instead of `nofit`: the linear response's gain fitted on the vibrating record.)
Figures of 2026-11-27 in issue 30's note: 14.3x, 1.11x and 4.96x stated/scatter at
6.4 kHz.
"""
import json, subprocess, sys, numpy as np, os
G = "/work/main/tests/python/rig_generator.py"
out = sys.argv[2] if len(sys.argv) > 2 else "/tmp/ana/camp"
RATE = sys.argv[3] if len(sys.argv) > 3 else "3200"
if not os.path.exists(out + "/runs.csv"):
    subprocess.run([sys.executable, G, "campaign", "--out", out, "--sensor-rate-hz", RATE, "--repeat", "4"], check=True, stdout=subprocess.DEVNULL)
import csv
runs = list(csv.DictReader(open(out + "/runs.csv")))
def batch_se_periods(x, period_readings, nb=20):
    # batches of whole tone periods (as near as the readings allow), as many as fit
    per = max(1, int(len(x) / nb / period_readings))
    L = int(round(per * period_readings))
    k = len(x) // L
    m = np.array([x[b*L:(b+1)*L].mean() for b in range(k)])
    return m.std(ddof=1) / np.sqrt(k)
def batch_se(x, nb=20):
    n = len(x); m = np.array([x[b*n//nb:(b+1)*n//nb].mean() for b in range(nb)])
    return m.std(ddof=1) / np.sqrt(nb)
def load(p):
    with open(p) as f:
        lines = [l for l in f if not l.startswith("#")]
    return np.loadtxt(lines[1:], delimiter=",")
FIT = len(sys.argv) > 1 and sys.argv[1] == "fit"
res = {}  # (run, unit) -> list of (ve_raw, se_raw, ve_ref, se_ref, truth)
for r in runs:
    d = os.path.join(out, r["folder"])
    t = json.load(open(d + "/truth.json"))
    acc = load(d + "/accel.csv")
    ref = load(d + "/reference.csv")
    w = t["segments"]["windows_s"]
    fs = t["rates"]["sensor_hz"]; fa = t["rates"]["accel_hz"]; m = int(round(fs / fa))
    ta = acc[:, 0]; idx = np.round(ta * fs).astype(int)
    # trapezoid over the m+1 samples spanning the reading's interval [t - 1/fa, t]
    kern = np.ones(m + 1) / m; kern[0] = kern[-1] = 0.5 / m
    refm = np.stack([np.convolve(ref[:, 1 + k], kern, mode="full")[:len(ref)] for k in range(3)], axis=1)
    ok = (idx < len(ref)) & (idx - m >= 0)
    for u, unit in enumerate(t["triad"]):
        p = unit["passport"]; K1 = p["K1_v_per_g"]
        axis = {"x": 0, "y": 1, "z": 2}
        def comp(s): return (1 if s[0] == "+" else -1), axis[s[1]]
        (sI, bI), (sO, bO), (sP, bP) = comp(unit["ia"]), comp(unit["oa"]), comp(unit["pa"])
        U = acc[:, 1 + u]
        a = refm[np.clip(idx, 0, len(ref) - 1)]
        lin = K1 * (p["k1"] * sI * a[:, bI] + p["m1"] * sO * a[:, bO] + p["m2"] * sP * a[:, bP])
        def seg(lo, hi): return ok & (ta > lo) & (ta <= hi)
        s1, v, s2 = seg(*w["still_before"]), seg(*w["vibrating"]), seg(*w["still_after"])
        ve = lambda x: (x[v].mean() - 0.5 * (x[s1].mean() + x[s2].mean())) / K1
        se = lambda x: np.sqrt(batch_se(x[v])**2 + 0.25 * (batch_se(x[s1])**2 + batch_se(x[s2])**2)) / abs(K1)
        # the gain of the linear response fitted on the vibrating record (the unit's
        # sensitivity at the vibration's frequencies against the reference's: a mount
        # between them, the readings' boxcar against the samples' trapezoid)
        uc = U[v] - U[v].mean(); lc = lin[v] - lin[v].mean()
        gain = (uc @ lc) / (lc @ lc)
        r2 = U - (gain if FIT else 1.0) * lin
        key = (r["run_id"], u)
        pr = fa / float(r["tone_hz"])
        sep = np.sqrt(batch_se_periods(U[v], pr)**2 + 0.25 * (batch_se(U[s1])**2 + batch_se(U[s2])**2)) / abs(K1)
        res.setdefault(key, []).append((ve(U), se(U), ve(r2), se(r2), t["units"][u]["ve_time_domain_g"], sep))
def report(i_ve, i_se, name):
    ratios = []; pulls = []
    for k, rows in res.items():
        a = np.array(rows)
        scatter = a[:, i_ve].std(ddof=1)
        ratios.append((a[:, i_se].mean(), scatter))
        pulls.extend((a[:, i_ve] - a[:, 4]) / a[:, i_se])
    st = np.array(ratios)
    pooled_scatter = np.sqrt((st[:, 1]**2).mean()); pooled_stated = np.sqrt((st[:, 0]**2).mean())
    pulls = np.array(pulls)
    print(f"{name}: {len(res)} unit-conditions x {len(rows)} repeats: stated {pooled_stated:.3e} g, scatter {pooled_scatter:.3e} g, stated/scatter {pooled_stated/pooled_scatter:.2f}; pulls vs truth rms {np.sqrt((pulls**2).mean()):.2f}, max |pull| {np.abs(pulls).max():.1f}")
print("runs", len(runs))
report(0, 1, "P2 (16), batch means of the raw records")
report(2, 3, "P2 (16) less the linear response through the reference")
report(0, 5, "P2 (16), batches of whole tone periods")
