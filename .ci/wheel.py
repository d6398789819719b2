"""CI's wheel of the Python package, from the native module of the test build.

`pip install .` builds the wheel with maturin (pyproject.toml). CI does not: maturin
runs `cargo rustc -p vibrocomp-python` with its own profile, so cargo resolves the
package's graph alone (other features than the whole workspace's) under another profile,
and compiles about 40 of the libraries `cargo test --workspace` had just compiled again
(three minutes of CI's 2 cores; `cargo rustc --profile test` would build a test harness,
not the module). This script builds the module within the test build itself: the same
profile, the same selection of packages and targets as `cargo test --workspace` (hence
the same features) plus the package's library, so that only pyo3 and the module
compile. It then lays the wheel out as maturin does (`[tool.maturin]`'s
`python-source` and `module-name`, `[project]`'s metadata, an abi3 tag), so that the
tests install and import a wheel like a user's. The module links what the workspace
links (iceoryx2 among them); a user's does not (tests/integration/packaging.rs).

    python3 .ci/wheel.py OUT_DIR   # prints the wheel's path

Run it in the test build's environment: `CARGO_INCREMENTAL=0`, as .ci/run exports it
(cargo builds the workspace's crates again when the setting differs).
"""

from __future__ import annotations

import base64
import hashlib
import json
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# pyo3's `abi3-py39` (Cargo.toml): one wheel for CPython 3.9 and later.
TAG = "cp39-abi3-linux_x86_64"


def native_name() -> str:
    """The native module's name (`_vibrocomp`), which is its library's name."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return pyproject["tool"]["maturin"]["module-name"].rpartition(".")[2]


def native_module() -> Path:
    """Builds the module within the test build, and returns the library's path."""
    # `cargo test --workspace`'s selection (libraries, binaries, tests, examples, with
    # the dev-dependencies): everything but the package's library is already built.
    build = subprocess.run(
        ["cargo", "build", "--profile", "test", "--workspace", "--lib", "--bins",
         "--tests", "--examples", "--message-format=json-render-diagnostics"],
        cwd=ROOT, stdout=subprocess.PIPE, text=True, check=True)
    for line in build.stdout.splitlines():
        message = json.loads(line)
        if (message.get("reason") == "compiler-artifact"
                and message["target"]["name"] == native_name()
                and "cdylib" in message["target"]["crate_types"]):
            return Path(message["filenames"][0])
    sys.exit("cargo built no cdylib for vibrocomp-python")


def _metadata(project: dict, version: str) -> str:
    lines = [
        "Metadata-Version: 2.4",
        f"Name: {project['name']}",
        f"Version: {version}",
        f"Summary: {project['description']}",
        f"Requires-Python: {project['requires-python']}",
        f"Keywords: {','.join(project.get('keywords', []))}",
        f"License: {project['license']['text']}",
    ]
    lines += [f"Classifier: {c}" for c in project.get("classifiers", [])]
    lines += [f"Requires-Dist: {d}" for d in project.get("dependencies", [])]
    for extra, deps in sorted(project.get("optional-dependencies", {}).items()):
        lines.append(f"Provides-Extra: {extra}")
        lines += [f"Requires-Dist: {d} ; extra == '{extra}'" for d in deps]
    readme = ROOT / project["readme"]
    lines.append("Description-Content-Type: text/markdown; charset=UTF-8; variant=GFM")
    return "\n".join(lines) + "\n\n" + readme.read_text(encoding="utf-8")


def _record_hash(data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=")
    return f"sha256={digest.decode()},{len(data)}"


def build(module: Path, out_dir: Path) -> Path:
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    project, maturin = pyproject["project"], pyproject["tool"]["maturin"]
    cargo = tomllib.loads((ROOT / "Cargo.toml").read_text(encoding="utf-8"))
    version = cargo["workspace"]["package"]["version"]
    package, _, native = maturin["module-name"].rpartition(".")
    source = ROOT / maturin["python-source"] / package
    if not (source / "__init__.py").is_file():
        sys.exit(f"{source}: no __init__.py; pyproject.toml's [tool.maturin] has moved")
    files: dict[str, bytes] = {}
    for path in sorted(source.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            files[path.relative_to(source.parent).as_posix()] = path.read_bytes()
    files[f"{package}/{native}.abi3.so"] = module.read_bytes()
    dist = f"{project['name']}-{version}.dist-info"
    files[f"{dist}/METADATA"] = _metadata(project, version).encode()
    files[f"{dist}/WHEEL"] = (
        f"Wheel-Version: 1.0\nGenerator: vibrocomp .ci/wheel.py\n"
        f"Root-Is-Purelib: false\nTag: {TAG}\n"
    ).encode()
    record = "".join(f"{name},{_record_hash(data)}\n" for name, data in files.items())
    files[f"{dist}/RECORD"] = (record + f"{dist}/RECORD,,\n").encode()
    out_dir.mkdir(parents=True, exist_ok=True)
    wheel = out_dir / f"{project['name']}-{version}-{TAG}.whl"
    with zipfile.ZipFile(wheel, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for name, data in files.items():
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = (0o755 if name.endswith(".so") else 0o644) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, data)
    return wheel


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    print(build(native_module(), Path(sys.argv[1])))
