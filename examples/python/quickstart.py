"""The Python package in a minute: README, "From Python", as a script.

    cargo run --release -p vibrocomp -- demo       # writes vibrocomp-demo/session.mcap
    pip install ".[notebook]"
    python examples/python/quickstart.py [--demo-dir vibrocomp-demo] [--out DIR]

It computes the VE over an array of vibration amplitudes and compensates two readings
(`vibrocomp model ve`, `model compensate`), diagnoses a shake-table campaign and adds
the effects it finds (`lab diagnose`, `lab add`; the model is written to
`DIR/model.toml`, by default a new temporary folder), and reads the demo's
compensated stream into numpy and pandas. Type-checked with `mypy --strict`
(tests/python/package/test_typing.py runs it, and this script).
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np

import vibrocomp as vc

HERE = Path(__file__).resolve().parent
CAMPAIGN = HERE / "data" / "campaign-mount-k6.csv"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo-dir", type=Path, default=HERE.parent.parent / "vibrocomp-demo",
                        help="the folder `vibrocomp demo` wrote (default: vibrocomp-demo)")
    parser.add_argument("--out", type=Path, default=None,
                        help="where model.toml goes (default: a new temporary folder)")
    args = parser.parse_args()
    session = args.demo_dir / "session.mcap"
    if not session.is_file():
        parser.error(f"{session} is missing: run `vibrocomp demo` first, or give --demo-dir")
    out: Path = args.out or Path(tempfile.mkdtemp(prefix="vibrocomp-quickstart-"))

    # The model over arrays: a 40 Hz tone along IA of 0 .. 2 g, at 1 g of flight.
    ab3_g = np.linspace(0.0, 2.0, 5)
    v = vc.ve("AL-15", al3_g=1.0, ab3_g=ab3_g, freq_hz=40.0)
    for a, total in zip(ab3_g, v.total_g):
        print(f"aB3 = {a:.1f} g: VE = {total * 1e6:9.3f} ug")
    s = vc.compensate("AL-15", reading_g=[0.5, 1.0], ab3_g=0.42, freq_hz=40.0)
    print(f"a4_g = {s.a4_g.tolist()} (the readings with the VE removed, g)")

    # The lab: what the campaign shows beyond the passport, then those effects fitted.
    d = vc.lab.diagnose(CAMPAIGN)
    print(f"verdict: {d.verdict.verdict}; effects to add: {d.next_effects}")
    added = vc.lab.add(d.next_effects, CAMPAIGN)
    if added.fit is not None:  # None when the correction is the empirical one
        for p in added.fit.params:
            print(f"  {p.effect}.{p.name} = {p.value:.6g} +- {p.sigma:.2g}")
    model = added.model
    assert model is not None, "lab.add returns the extended model"
    model.save(out / "model.toml", overwrite=True)
    print(f"model: {out / 'model.toml'}")

    # A log, one stream: times in int64 ns, per-unit values (N, 3).
    comp = vc.Log(session).stream("/compensated")
    t_ns = comp.samples["t_ns"]
    a4_g = comp.samples["a4_g"]
    print(f"{comp.topic}: {len(t_ns)} samples over {(t_ns[-1] - t_ns[0]) / 1e9:.3f} s, "
          f"a4_g {a4_g.shape}")
    frame = comp.to_frame()
    print(f"AK1's mean a(4): {frame.a4_g_0.mean():.6f} g")


if __name__ == "__main__":
    main()
