"""vibrocomp from Python: the vibration-error model, the model lab and the logs.

    import vibrocomp as vc
    p = vc.Passport.load("AL-15")
    v = vc.ve(p, al3_g=[0.0, 1.0, 2.0], ab3_g=0.42, freq_hz=40.0)   # arrays in and out
    d = vc.lab.diagnose("campaign.csv")                            # the lab, typed results
    log = vc.Log("vibrocomp-demo/session.mcap")                    # a log, stream by stream
    accel = log.stream("/accel").samples                           # numpy arrays
    s = vc.archive.run("archive.toml", "results")                  # a whole archive, Parquet

The numbers are the command line's (the same libraries). The package is typed
(PEP 561: `py.typed`, the native module's stubs): results are dataclasses of floats
and numpy arrays that `mypy --strict` and pyright check, and `ve` and `compensate`
name each argument with its unit. Errors are `vibrocomp.VibrocompError` with the
command line's message, file, line and key, its subclasses also `FileNotFoundError`,
`PermissionError`, `OSError` or `ValueError` (`vibrocomp.errors`).
"""

from typing import TYPE_CHECKING, Any

from ._vibrocomp import __version__
from . import errors
from .errors import (
    ConfigError,
    FilePermissionError,
    FileSystemError,
    InvalidInputError,
    LogFormatError,
    MissingFileError,
    VibrocompError,
)
from .model import (
    ExtendedStages,
    ExtendedVe,
    Passport,
    Requirement,
    Requirements,
    Stages,
    Triad,
    TriadUnit,
    VeComponents,
    compensate,
    require,
    ve,
)
from . import lab
from .lab import Model
from .logs import Log, Stream


if TYPE_CHECKING:
    from . import archive
else:
    # `vibrocomp.archive` is imported on first use, not here: `python -m
    # vibrocomp.archive` (what `vibrocomp archive run --dask` runs) would otherwise
    # find it imported already and warn that it runs a second copy. Type checkers see
    # the import above instead: a module `__getattr__` would make every misspelt
    # `vibrocomp.name` an `Any` to them.
    def __getattr__(name: str) -> Any:
        if name == "archive":
            import importlib

            return importlib.import_module(".archive", __name__)
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "__version__",
    "Passport",
    "Triad",
    "TriadUnit",
    "VeComponents",
    "ExtendedVe",
    "Stages",
    "ExtendedStages",
    "Requirement",
    "Requirements",
    "ve",
    "compensate",
    "require",
    "lab",
    "archive",
    "Model",
    "Log",
    "Stream",
]
# The exception classes, as `vibrocomp.errors` lists them.
__all__ += errors.__all__
