"""The model lab (docs/lab.md): compare the VE model with a campaign, find which effect
of the library is missing, fit it and add it to an extended model.

    import vibrocomp as vc
    c = vc.lab.compare("campaign.csv")            # or a DataFrame, a dict of arrays,
    d = vc.lab.diagnose("campaign.csv")           # a manifest (.toml), a log (.mcap)
    a = vc.lab.add(d.next_effects, "campaign.csv")
    a.model.save("model.toml")
    vc.lab.compare("campaign.csv", model=a.model)

Inputs are fitted jointly, as on the command line: campaign tables (a CSV file, a
pandas DataFrame or a dict of equally long arrays with the table's columns),
shake-table manifests and MCAP logs with a reference. A log's options are the
command line's: `triad`, `estimator_config`, `batches`, `max_al_span_g`,
`pool_windows`. `progress=callable(done, of, what)` follows a long diagnosis.

The results are dataclasses with the content of the command line's `--json` (the
same keys, `to_dict()` gives it back); `lab add` does not write a file by itself:
`Added.model.save(path)` does.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import typing
from dataclasses import dataclass, fields, is_dataclass
from typing import Any, Callable, Dict, List, Optional, Sequence, Union

import numpy as np

from . import _vibrocomp as _native

PathLike = Union[str, "os.PathLike[str]"]

# ---------------------------------------------------------------------------------
# Typed results from the command line's JSON


class _Json:
    """A result read from the command line's JSON: every key a field (a key the class
    does not know is an error, so that the two cannot drift apart), and `to_dict()`
    giving the JSON back, keys absent from it left out."""

    _present: frozenset

    def to_dict(self) -> dict:
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self) if f.name in self._present}  # type: ignore[arg-type]


def _plain(v: Any) -> Any:
    if isinstance(v, _Json):
        return v.to_dict()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, list):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


def _convert(hint: Any, v: Any, where: str) -> Any:
    if v is None:
        return None
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is Union:
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], v, where) if len(inner) == 1 else v
    if origin in (list, List) and args:
        return [_convert(args[0], x, f"{where}[{i}]") for i, x in enumerate(v)]
    if isinstance(hint, type) and is_dataclass(hint) and issubclass(hint, _Json):
        return _build(hint, v, where)
    if hint is np.ndarray:
        return np.asarray([math.nan if x is None else x for x in v], dtype=np.float64)
    return v


def _build(cls, obj: dict, where: str = ""):
    hints = typing.get_type_hints(cls)
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(obj) - names)
    if unknown:
        raise TypeError(f"{cls.__name__}{where}: keys {unknown} not known to the Python package")
    values = {}
    for f in fields(cls):
        values[f.name] = _convert(hints[f.name], obj.get(f.name), f"{where}.{f.name}")
    out = cls(**values)
    object.__setattr__(out, "_present", frozenset(obj))
    return out


@dataclass(frozen=True)
class Row(_Json):
    """One condition: measured against predicted VE, g, and the residual in
    standard uncertainties (`z`); `line` is the table's line."""

    run_id: str
    line: Optional[int]
    measured_g: float
    uncertainty_g: float
    predicted_g: float
    residual_g: float
    z: float
    #: `waveform` (a log's window predicted as the compensator evaluates it, from the
    #: vibration samples) or `statistics` (from the estimate's statistics); `compare`
    #: only.
    path: Optional[str] = None
    #: A waveform row's window: the stage's VE and the interval means' part, g.
    window: Optional[dict] = None


@dataclass(frozen=True)
class Summary(_Json):
    n: int
    distinct_conditions: int
    rms_residual_g: float
    max_abs_residual_g: float
    rms_measured_g: float
    chi2: float
    dof: int
    chi2_per_dof: float
    p_value: float
    noise_floor_g: float


@dataclass(frozen=True)
class Group(_Json):
    label: str
    n: int
    mean_residual_g: float
    rms_residual_g: float
    chi2_per_dof: float


@dataclass(frozen=True)
class ByVariable(_Json):
    variable: str
    groups: List[Group]


@dataclass(frozen=True)
class Comparison(_Json):
    """`lab compare --json`: each condition, the summary, the residual grouped by each
    condition variable; a log's window groups' residual scales (`residual_scales`,
    docs/lab.md); `log`/`logs` the logs' summaries when inputs were logs."""

    table: str
    mode: str
    effects: List[str]
    rows: List[Row]
    summary: Summary
    by_variable: List[ByVariable]
    residual_scales: Optional[list] = None
    log: Optional[dict] = None
    logs: Optional[list] = None
    #: Rows per evaluation path, `{"waveform": n, "statistics": n}`.
    paths: Optional[dict] = None
    #: Per log, what the waveform path covered.
    waveform: Optional[Any] = None

    def to_frame(self):
        """The conditions as a pandas DataFrame."""
        import pandas as pd

        return pd.DataFrame([r.to_dict() for r in self.rows])


@dataclass(frozen=True)
class Param(_Json):
    """A fitted parameter: its value, standard uncertainty and profile intervals."""

    effect: str
    name: str
    value: float
    sigma: float
    sigma_minus: float
    sigma_plus: float
    three_sigma_minus: float
    three_sigma_plus: float


@dataclass(frozen=True)
class Fit(_Json):
    """A fit of effects to the residual (`EffectFit`)."""

    kind: str
    kinds: List[str]
    params: List[Param]
    correlation: List[List[float]]
    n: int
    k: int
    chi2_before: float
    chi2_after: float
    chi2_per_dof_after: float
    p_value_after: float
    bic_before: float
    bic_after: float
    delta_bic: float
    rms_residual_before_g: float
    rms_residual_after_g: float
    shift_g: np.ndarray
    residual_after_g: np.ndarray
    evaluations: int


@dataclass(frozen=True)
class Candidate(_Json):
    """One effect of the library against the residual."""

    kind: str
    physics: str
    signature: str
    fit: Optional[Fit]
    not_applicable: Optional[str]
    supported: bool
    explains: bool


@dataclass(frozen=True)
class Step(_Json):
    """One step of the stepwise search."""

    action: str
    effects: List[str]
    delta_bic: float
    bic: float
    chi2: float
    chi2_per_dof: float
    p_value: float
    rms_residual_g: float
    runners_up: list


@dataclass(frozen=True)
class Verdict(_Json):
    """What the data say: `verdict` is `noise`, `effect`, `confounded` or
    `unexplained`; the other fields are those of that verdict (None otherwise)."""

    verdict: str
    kind: Optional[str] = None
    kinds: Optional[List[str]] = None
    params: Optional[List[Param]] = None
    correlation: Any = None
    delta_bic: Optional[float] = None
    rms_residual_before_g: Optional[float] = None
    rms_residual_after_g: Optional[float] = None
    chi2_per_dof_after: Optional[float] = None
    physics: Optional[List[str]] = None
    p_value: Optional[float] = None
    chi2_per_dof: Optional[float] = None
    suggestions: Optional[list] = None
    found: Optional[List[str]] = None
    variables: Optional[List[str]] = None
    best: Optional[str] = None
    best_explained_fraction: Optional[float] = None
    found_explained_fraction: Optional[float] = None


@dataclass(frozen=True)
class Diagnosis(_Json):
    """`lab diagnose --json`: where the model fails and which effect is missing."""

    comparison: Comparison
    trends: list
    trends_after: list
    lack_of_fit: Optional[dict]
    candidates: List[Candidate]
    steps: List[Step]
    selected: Optional[Fit]
    not_applicable: list
    verdict: Verdict
    options: dict
    budget: dict
    empirical: Optional[dict]
    log: Optional[dict] = None
    logs: Optional[list] = None

    @property
    def next_effects(self) -> List[str]:
        """The effects `lab add --diagnosed` would add (none for "noise")."""
        if self.verdict.verdict == "noise" or self.selected is None:
            return []
        return list(self.selected.kinds)


@dataclass(frozen=True)
class Added(_Json):
    """`lab add --json` (without `out`: nothing is written until `model.save`)."""

    effects: List[str]
    fit: Optional[Fit] = None
    empirical: Optional[dict] = None
    log: Optional[dict] = None
    logs: Optional[list] = None
    model: Optional["Model"] = None

    def to_dict(self) -> dict:
        d = super().to_dict()
        d.pop("model", None)
        return d


# ---------------------------------------------------------------------------------
# The extended model


class Model:
    """An extended model (docs/lab.md, `MODEL.toml`): a base mode plus effects. Read
    with `Model.load`, made by `lab.add`, written with `save`."""

    def __init__(self, text: str, name: str = "<model>"):
        self.text = text
        self.name = name
        self.mode, self.effects = _native.model_effects(text, name)

    @classmethod
    def load(cls, path: PathLike) -> "Model":
        text, name = _native.read_model(os.fspath(path))
        return cls(text, name)

    def save(self, path: PathLike, overwrite: bool = False) -> None:
        """Writes the model file by the command line's rule (README, "Files"): an
        existing file only with `overwrite` (else `FileExistsError`); never through a
        symbolic link, into a FIFO or a device (`VibrocompError`, even with
        `overwrite`); the file appears only when complete."""
        _native.save_model(os.fspath(path), self.text, overwrite)

    def __repr__(self) -> str:
        return f"Model({self.name!r}, mode={self.mode!r}, effects={self.effects!r})"


# ---------------------------------------------------------------------------------
# Inputs


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, (float, np.floating)):
        return "" if math.isnan(v) else repr(float(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return str(v)


def _table_text(columns: Dict[str, Sequence[Any]]) -> str:
    names = list(columns)
    n = {len(columns[k]) for k in names}
    if len(n) > 1:
        raise ValueError(f"the table's columns differ in length: { {k: len(columns[k]) for k in names} }")
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(names)
    for i in range(n.pop() if n else 0):
        w.writerow([_cell(columns[k][i]) for k in names])
    return out.getvalue()


def _input(x: Any, i: int) -> tuple:
    if isinstance(x, (str, os.PathLike)):
        return ("path", os.fspath(x))
    if isinstance(x, dict):
        return ("table", _table_text(x), f"<table {i}>", os.getcwd())
    if hasattr(x, "to_dict") and hasattr(x, "columns"):  # a pandas DataFrame
        cols = {str(c): list(x[c]) for c in x.columns}
        return ("table", _table_text(cols), f"<DataFrame {i}>", os.getcwd())
    raise TypeError(
        f"input {i}: {type(x).__name__}: expected a file path, a pandas DataFrame or a dict of arrays"
    )


def _inputs(inputs: Sequence[Any]) -> list:
    if not inputs:
        raise TypeError("at least one input: a campaign table, a manifest or a log")
    return [_input(x, i) for i, x in enumerate(inputs)]


def _log_args(triad, estimator_config, batches, max_al_span_g, pool_windows) -> dict:
    return {
        "triad": os.fspath(triad),
        "estimator_config": None if estimator_config is None else os.fspath(estimator_config),
        "batches": int(batches),
        "max_al_span_g": float(max_al_span_g),
        "pool_windows": int(pool_windows),
    }


def _model(model) -> Optional[tuple]:
    if model is None:
        return None
    m = model if isinstance(model, Model) else Model.load(model)
    return (m.text, m.name)


Progress = Optional[Callable[[int, int, str], None]]


def table(
    *inputs: Any,
    model=None,
    mode: str = "exact",
    triad: PathLike = "default",
    estimator_config: Optional[PathLike] = None,
    batches: int = 8,
    max_al_span_g: float = 1.0,
    pool_windows: int = 0,
    progress: Progress = None,
):
    """The inputs as the lab's table (`--table-out`): a pandas DataFrame (a dict of
    columns without pandas). Refused for a table a CSV row cannot hold."""
    log = _log_args(triad, estimator_config, batches, max_al_span_g, pool_windows)
    text = _native.lab_table(_inputs(inputs), _model(model), mode, log, progress)
    try:
        import pandas as pd
    except ImportError:
        rows = list(csv.reader(line for line in io.StringIO(text) if not line.startswith("#")))
        return {name: [r[j] for r in rows[1:]] for j, name in enumerate(rows[0])}
    return pd.read_csv(io.StringIO(text), comment="#")


def compare(
    *inputs: Any,
    model=None,
    mode: str = "exact",
    triad: PathLike = "default",
    estimator_config: Optional[PathLike] = None,
    batches: int = 8,
    max_al_span_g: float = 1.0,
    pool_windows: int = 0,
    path: str = "waveform",
    progress: Progress = None,
) -> Comparison:
    """`vibrocomp lab compare`: measured against predicted VE per condition.

    `path`: ``"waveform"`` (default; also ``"windows"``, the command line's
    ``--path windows``) predicts a log's windows as the compensator evaluates the model,
    from the vibration samples (MODEL.md section 12); tables and logs without samples use
    the statistics path, as ``"statistics"`` does for all. The command line's default
    for logs, every reading fitted (``--path waveform``), is not in the package yet.
    """
    log = _log_args(triad, estimator_config, batches, max_al_span_g, pool_windows)
    text = _native.lab_compare(_inputs(inputs), _model(model), mode, log, path, progress)
    return _build(Comparison, json.loads(text))


def diagnose(
    *inputs: Any,
    model=None,
    mode: str = "exact",
    effects: Optional[Sequence[str]] = None,
    max_effects: int = 4,
    triad: PathLike = "default",
    estimator_config: Optional[PathLike] = None,
    batches: int = 8,
    max_al_span_g: float = 1.0,
    pool_windows: int = 0,
    progress: Progress = None,
) -> Diagnosis:
    """`vibrocomp lab diagnose`: where the model fails, and which effect is missing
    (`effects`: only these candidates)."""
    log = _log_args(triad, estimator_config, batches, max_al_span_g, pool_windows)
    text = _native.lab_diagnose(
        _inputs(inputs), _model(model), mode, log, list(effects or []), int(max_effects), progress
    )
    return _build(Diagnosis, json.loads(text))


def add(
    effects: Union[str, Sequence[str]],
    *inputs: Any,
    model=None,
    freeze: bool = False,
    triad: PathLike = "default",
    estimator_config: Optional[PathLike] = None,
    batches: int = 8,
    max_al_span_g: float = 1.0,
    pool_windows: int = 0,
    progress: Progress = None,
) -> Added:
    """`vibrocomp lab add`: fits `effects` (kinds, a comma-separated string, or
    `"diagnosed"` for those the diagnosis finds) to the inputs, jointly with the
    model's own effects unless `freeze`, and returns the extended model in
    `Added.model` (nothing is written)."""
    if isinstance(effects, str):
        kinds = [k for k in effects.split(",") if k]
    else:
        kinds = list(effects)
    diagnosed = kinds == ["diagnosed"]
    log = _log_args(triad, estimator_config, batches, max_al_span_g, pool_windows)
    text, toml = _native.lab_add(
        _inputs(inputs), _model(model), log, [] if diagnosed else kinds, diagnosed, bool(freeze), progress
    )
    added = _build(Added, json.loads(text))
    object.__setattr__(added, "model", Model(toml, "<added>"))
    return added
