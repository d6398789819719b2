"""Types of the native half `vibrocomp._vibrocomp` (bindings/python/src): what the
Python half calls. Arrays come out as `(dtype, shape, bytearray)` (`_arrays.array`
views them), columns go in as float64 bytes; results the Python half parses are the
command line's JSON text. Checked against the built module by `mypy.stubtest`
(tests/python/package/test_typing.py)."""

import os
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union, final


_Path = Union[str, "os.PathLike[str]"]
# An extended model's TOML text and the name it is known by (its path).
_ModelText = Tuple[str, str]
# A lab input: `("path", path)` or `("table", csv_text, name, dir)`.
_Input = Union[Tuple[str, _Path], Tuple[str, str, str, _Path]]
# Called as `progress(done, of, what)` while the lab works.
_Progress = Callable[[int, int, str], object]

__all__ = [
    "__version__",
    "passport",
    "triad",
    "ve",
    "compensate",
    "require",
    "read_model",
    "save_model",
    "model_effects",
    "lab_table",
    "lab_compare",
    "lab_diagnose",
    "lab_add",
    "LogFile",
    "Archive",
    "archive_job",
    "archive_failed",
]

__version__: str

# The model (src/model.rs).

def passport(spec: str) -> str: ...
def triad(spec: str) -> str: ...
def ve(
    passport: str,
    columns: Mapping[str, bytes],
    mode: str,
    model: Optional[_ModelText] = None,
    psd: Optional[str] = None,
) -> Dict[str, Any]: ...
def compensate(
    passport: str,
    columns: Mapping[str, bytes],
    mode: str,
    model: Optional[_ModelText] = None,
    psd: Optional[str] = None,
) -> Dict[str, Any]: ...
def require(
    dstar_g: float,
    al3_g: float,
    ab_g: Sequence[float],
    sigma3_g: float,
    mode: str,
) -> str: ...

# The lab (src/lab.rs).

def read_model(path: _Path) -> Tuple[str, str]: ...
def save_model(path: _Path, text: str, overwrite: bool) -> None: ...
def model_effects(text: str, name: str) -> Tuple[str, List[str]]: ...
def lab_table(
    inputs: Sequence[_Input],
    model: Optional[_ModelText],
    mode: str,
    log: Mapping[str, Any],
    progress: Optional[_Progress] = None,
) -> str: ...
def lab_compare(
    inputs: Sequence[_Input],
    model: Optional[_ModelText],
    mode: str,
    log: Mapping[str, Any],
    path: str = "waveform",
    progress: Optional[_Progress] = None,
) -> str: ...
def lab_diagnose(
    inputs: Sequence[_Input],
    model: Optional[_ModelText],
    mode: str,
    log: Mapping[str, Any],
    effects: Sequence[str],
    max_effects: int,
    progress: Optional[_Progress] = None,
) -> str: ...
def lab_add(
    inputs: Sequence[_Input],
    model: Optional[_ModelText],
    log: Mapping[str, Any],
    effects: Sequence[str],
    diagnosed: bool,
    freeze: bool,
    progress: Optional[_Progress] = None,
) -> Tuple[str, str]: ...

# The logs (src/logs.rs).

@final
class LogFile:
    def __new__(cls, path: _Path) -> "LogFile": ...
    def info(self) -> str: ...
    def topics(self) -> List[Tuple[str, str]]: ...
    def metadata(self) -> List[Tuple[str, Dict[str, str]]]: ...
    def attachments(self) -> List[Tuple[str, str, bytes]]: ...
    @staticmethod
    def toml_to_json(text: str, name: str) -> str: ...
    def read(self, topic: str) -> Tuple[str, Optional[Dict[str, Any]], Dict[str, Any]]: ...

# Archives (src/archive.rs).

@final
class Archive:
    def __new__(cls, manifest: _Path, out: _Path, restart: bool = False) -> "Archive": ...
    def total(self) -> int: ...
    def pending(self) -> List[str]: ...
    def record(self, result: str) -> bool: ...
    def finish(self) -> str: ...

def archive_job(job: str) -> str: ...
def archive_failed(job: str, problem: str, worker: str) -> str: ...
