"""Shared fixtures of the Python package's tests (tests/python/package).

The package is the installed `vibrocomp` (`.ci/run` builds the wheel and installs it);
the command line it is compared with is `target/debug/vibrocomp`, the test build, or
`VIBROCOMP_BIN`.
"""

import json
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


def binary() -> Path:
    return Path(os.environ.get("VIBROCOMP_BIN", REPO / "target" / "debug" / "vibrocomp"))


@pytest.fixture(scope="session")
def cli():
    """Runs the command line; returns its parsed `--json` output (or the error object
    with `check=False`)."""
    exe = binary()
    if not exe.is_file():
        pytest.skip(f"{exe} is missing: build it with `cargo build --profile test -p vibrocomp` or set VIBROCOMP_BIN")

    def run(*args, check=True):
        p = subprocess.run([str(exe), *map(str, args), "--json"], capture_output=True, text=True, cwd=REPO)
        if check and p.returncode != 0:
            raise AssertionError(f"vibrocomp {' '.join(map(str, args))}: {p.stderr}")
        return json.loads(p.stdout)

    return run


@pytest.fixture(scope="session")
def demo_dir(tmp_path_factory):
    """`vibrocomp demo` run once into a temporary folder (about 2 s)."""
    exe = binary()
    if not exe.is_file():
        pytest.skip(f"{exe} is missing")
    out = tmp_path_factory.mktemp("demo") / "demo"
    p = subprocess.run([str(exe), "-q", "demo", "--out-dir", str(out)], capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 0, p.stderr
    return out
