"""The package's types and docs, as a type checker and a reader see them: the wheel
carries `py.typed` and the native module's stubs; the stubs match the built module
(`mypy.stubtest`); the notebook's code and examples/python/quickstart.py pass
`mypy --strict` against the installed package, whose types are the real ones (not
`Any`: `reveal_type` says what each call returns, and a misspelt argument is an
error); `ve` and `compensate` spell out their arguments; every public name has a
docstring. The quickstart runs, and its model file is the command line's.

mypy (pinned in tests/python/requirements.txt) runs in this interpreter, with its
cache under pytest's temporary folder.
"""

import dataclasses
import importlib
import inspect
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import vibrocomp as vc
from conftest import REPO, binary

EXAMPLES = REPO / "examples" / "python"
PACKAGE = Path(vc.__file__).resolve().parent
VIBRATION = {
    "ab1_g": 0.0, "ab2_g": 0.0, "ab3_g": 0.0, "freq_hz": 0.0, "phase31_deg": 0.0,
    "phase32_deg": 0.0, "sigma1_g": None, "sigma2_g": None, "sigma3_g": None,
    "cov31_g2": 0.0, "cov32_g2": 0.0, "kurtosis3": 3.0,
}  # the command line's defaults (`vibrocomp model ve --help`)
# What each argument's docstring line must say it is in.
UNITS = {"_g": ", g", "_hz": "Hz", "_deg": "degrees", "_g2": "g^2", "kurtosis3": "kurtosis"}


def require_mypy():
    try:
        import mypy  # noqa: F401
    except ImportError:
        pytest.fail("mypy is missing: pip install -r tests/python/requirements.txt")


def mypy(tmp_path, *args):
    """`mypy --strict` on `args` in a subprocess of this interpreter: (exit code, output)."""
    require_mypy()
    p = subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--cache-dir", str(tmp_path / "mypy-cache"),
         "--no-error-summary", "--hide-error-context", *map(str, args)],
        capture_output=True, text=True, cwd=tmp_path,
    )
    return p.returncode, p.stdout + p.stderr


def test_the_wheel_carries_the_marker_and_the_stubs():
    """Installed, the package is typed (PEP 561): without `py.typed` mypy and pyright
    see `Any` ("missing library stubs or py.typed marker")."""
    assert (PACKAGE / "py.typed").is_file()
    assert (PACKAGE / "_vibrocomp.pyi").is_file()


def test_the_stubs_match_the_native_module(tmp_path):
    require_mypy()
    p = subprocess.run([sys.executable, "-m", "mypy.stubtest", "vibrocomp._vibrocomp",
                        "--mypy-config-file", str(tmp_path / "none.ini")],
                       capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr


def test_the_notebook_passes_mypy_strict(tmp_path):
    """The notebook's code cells, in order, as one script."""
    nb = json.loads((EXAMPLES / "vibrocomp.ipynb").read_text(encoding="utf-8"))
    cells = ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]
    assert len(cells) >= 5
    notebook = tmp_path / "vibrocomp_notebook.py"
    notebook.write_text("\n\n".join(cells) + "\n", encoding="utf-8")
    code, out = mypy(tmp_path, notebook)
    assert code == 0, out


def test_the_quickstart_passes_mypy_strict(tmp_path):
    code, out = mypy(tmp_path, EXAMPLES / "quickstart.py")
    assert code == 0, out


def test_the_model_and_the_logs_pass_mypy_strict(tmp_path):
    """The installed modules of the model, the logs and the arrays (the others' errors,
    if any, are not theirs: imports are followed silently)."""
    code, out = mypy(tmp_path, "--follow-imports=silent", "-m", "vibrocomp", "-m", "vibrocomp.model",
                     "-m", "vibrocomp.logs", "-m", "vibrocomp._arrays")
    assert code == 0, out


def test_the_types_are_the_real_ones_not_any(tmp_path):
    """What mypy infers for the calls a notebook makes, and a misspelt argument, a
    unit mixed up and a scalar result indexed as an array refused."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import numpy as np\n"
        "import vibrocomp as vc\n"
        'reveal_type(vc.ve("AL-15", al3_g=1.0, ab3_g=0.4, freq_hz=40.0))\n'
        'reveal_type(vc.ve("AL-15", al3_g=1.0, ab3_g=np.linspace(0, 2, 5)).total_g)\n'
        'reveal_type(vc.ve("AL-15", 1.0, model="model.toml"))\n'
        'reveal_type(vc.compensate("AL-15", reading_g=[0.5, 1.0]).a4_g)\n'
        'reveal_type(vc.Log("session.mcap").stream("/accel").samples["t_ns"])\n'
        'reveal_type(vc.Log("session.mcap").stream("/accel").to_frame())\n'
        'reveal_type(vc.Passport.load("AL-15").fields)\n'
        'vc.ve("AL-15", al3_g=1.0, ab3=0.4)\n'
        'vc.ve("AL-15", al3_g=1.0, mode="aproximate")\n'
        'vc.ve("AL-15", al3_g=1.0).total_g[0]\n'
        'vc.ve("AL-15", al3_g="1.0")\n',
        encoding="utf-8",
    )
    code, out = mypy(tmp_path, probe)
    revealed = re.findall(r"probe\.py:(\d+): note: Revealed type is \"(.*)\"", out)
    errors = {int(line): text for line, text in re.findall(r"probe\.py:(\d+): error: (.*)", out)}
    got = {int(line): t.replace("builtins.", "") for line, t in revealed}
    assert got[3] == "vibrocomp.model.VeComponents[float]", out
    assert got[4].startswith("numpy.ndarray[") and "float64" in got[4], out
    assert got[5] == "vibrocomp.model.ExtendedVe[float]", out
    assert got[6].startswith("numpy.ndarray[") and "float64" in got[6], out
    assert got[7].startswith("numpy.ndarray["), out
    assert got[8].startswith("pandas.core.frame.DataFrame"), out
    assert got[9] == "dict[str, Any]", out
    assert "ab3" in errors.get(10, "") or "No overload variant" in errors.get(10, ""), out
    assert "No overload variant" in errors.get(11, ""), out
    assert "not indexable" in errors.get(12, ""), out
    assert 'incompatible type "str"' in errors.get(13, ""), out
    assert set(errors) == {10, 11, 12, 13}, out


@pytest.mark.parametrize("function,flight", [
    (vc.ve, ("passport", "al3_g", "al1_g", "al2_g")),
    (vc.compensate, ("passport", "reading_g", "reading1_g", "reading2_g")),
])
def test_ve_and_compensate_spell_out_their_arguments_with_units(function, flight):
    """What `help()` and an IDE show: the real names, the command line's defaults, and
    a docstring line with each argument's unit; no `**vibration`."""
    params = inspect.signature(function).parameters
    assert tuple(params)[:4] == flight
    assert not any(p.kind is p.VAR_KEYWORD for p in params.values())
    for name, default in VIBRATION.items():
        assert params[name].kind is params[name].KEYWORD_ONLY and params[name].default == default, name
    assert [params[k].default for k in ("mode", "model", "psd")] == ["exact", None, None]
    doc = inspect.getdoc(function)
    for name in [*flight[1:], *VIBRATION]:
        line = next((ln for ln in doc.splitlines() if f"`{name}`" in ln), None)
        assert line is not None, f"{name} is not in the docstring"
        suffix = next(s for s in UNITS if name.endswith(s))
        # the unit is on the argument's line or the next (a wrapped line)
        at = doc.index(line)
        assert UNITS[suffix] in doc[at:at + 2 * len(line) + 90], (name, line)


def test_unknown_and_missing_arguments_keep_their_messages():
    with pytest.raises(TypeError, match="unknown vibration argument.*sigma4_g: expected ab1_g, ab2_g"):
        vc.ve("AL-15", al3_g=1.0, sigma4_g=1.0)
    with pytest.raises(TypeError, match="unknown vibration argument.*freq: expected"):
        vc.compensate("AL-15", reading_g=1.0, freq=40.0)
    with pytest.raises(TypeError, match="al3_g"):
        vc.ve("AL-15", ab3_g=1.0)
    with pytest.raises(TypeError, match="reading_g"):
        vc.compensate("AL-15")


def public_names():
    """Every public module of the package, and every public function, class, method
    and property defined in it (not imported, not inherited): `(qualified name,
    object)`."""
    out = []
    modules = [vc] + [importlib.import_module(f"vibrocomp.{m}")
                      for m in ("model", "lab", "logs", "archive", "errors")]
    for module in modules:
        out.append((module.__name__, module))
        for name, obj in vars(module).items():
            if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
                continue
            if not (inspect.isclass(obj) or inspect.isfunction(obj)):
                continue
            out.append((f"{module.__name__}.{name}", obj))
            if inspect.isclass(obj):
                for attr, member in vars(obj).items():
                    if attr.startswith("_") and attr != "__init__":
                        continue
                    # A dataclass's `__init__` is made from its fields, which its
                    # docstring names; a protocol's is not called.
                    if attr == "__init__" and (dataclasses.is_dataclass(obj) or getattr(obj, "_is_protocol", False)):
                        continue
                    if isinstance(member, (classmethod, staticmethod)):
                        member = member.__func__
                    if inspect.isfunction(member) or isinstance(member, property):
                        out.append((f"{module.__name__}.{name}.{attr}", member))
    return out


def test_every_public_name_has_a_docstring():
    names = public_names()
    assert len(names) > 60, len(names)
    # A dataclass without a docstring gets its signature as one: not a docstring.
    missing = [n for n, obj in names
               if not (obj.__doc__ or "").strip()
               or (inspect.isclass(obj) and obj.__doc__.startswith(f"{obj.__name__}("))]
    assert missing == [], f"{len(missing)} of {len(names)} public names without a docstring: {missing}"


def test_the_quickstart_runs_and_writes_the_command_lines_model(demo_dir, tmp_path, cli):
    p = subprocess.run([sys.executable, str(EXAMPLES / "quickstart.py"), "--demo-dir", str(demo_dir),
                        "--out", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    want = tmp_path / "cli-model.toml"
    c = subprocess.run([str(binary()), "-q", "lab", "add", "--diagnosed", "--from",
                        str(EXAMPLES / "data" / "campaign-mount-k6.csv"), "--out", str(want)],
                       capture_output=True, text=True)
    assert c.returncode == 0, c.stderr
    assert (tmp_path / "model.toml").read_text() == want.read_text()
    # The VE it prints at aB3 = 2 g is `model ve`'s.
    ve = cli("model", "ve", "--passport", "AL-15", "--aL3-g=1", "--aB3-g=2", "--freq-hz=40")
    assert f"aB3 = 2.0 g: VE = {ve['total_g'] * 1e6:9.3f} ug" in p.stdout, p.stdout
    assert re.search(r"/compensated: \d+ samples over \d+\.\d+ s, a4_g \(\d+, 3\)", p.stdout), p.stdout
