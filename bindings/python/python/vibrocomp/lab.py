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
`pool_windows`. `progress=callable(done, of, what)` follows a long call (at least
every 0.5 s; by default a tqdm bar in a notebook, `progress=False` for none); Ctrl-C
or an exception from `progress` stops it (see `_progress_bar`).

The results are dataclasses with the content of the command line's `--json` (the
same keys, `to_dict()` gives it back); `lab add` does not write a file by itself:
`Added.model.save(path)` does. The keys are those of one schema,
docs/schema/lab-json.schema.json; a result that cannot be read raises
`LabResultError` with the whole JSON in `raw`. In a notebook a result's repr is a few
lines, Jupyter shows it as tables, and `Diagnosis.to_frame("candidates" | "steps")`
gives pandas DataFrames.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
import os
import sys
import typing
from dataclasses import dataclass, fields, is_dataclass
from typing import TYPE_CHECKING, Any, Callable, Dict, FrozenSet, List, Optional, Sequence, Tuple, Type, TypeVar, Union

import numpy as np

from . import _vibrocomp as _native

if TYPE_CHECKING:
    import pandas as pd

PathLike = Union[str, "os.PathLike[str]"]

# ---------------------------------------------------------------------------------
# Typed results from the command line's JSON
#
# One schema, docs/schema/lab-json.schema.json, names every key the lab's `--json` can
# emit: shared/vibro-lab/tests/json_schema.rs holds the Rust output to it, and
# tests/python/package/test_lab_schema.py holds these classes' fields to it. Objects
# the schema has that are not classes here (a log's summary, the options, the budget,
# the empirical correction...) are kept as the JSON's dicts.


class LabResultError(TypeError):
    """The lab's result could not be read into the package's classes (a key the
    package does not know, a value of an unexpected type).

    Attributes:
        raw: the command's whole JSON text, as the native call returned it: nothing
            computed is lost (``json.loads(e.raw)`` gives it as dicts).
    """

    def __init__(self, message: str, raw: str):
        """`message`: what failed; `raw`: the result's JSON text."""
        super().__init__(message)
        self.raw = raw


_T = TypeVar("_T")


def _parse(cls: Type[_T], text: str) -> _T:
    """`cls` built from the JSON `text`; a failure raises `LabResultError` with the
    text in `.raw`."""
    try:
        out: _T = _build(cls, json.loads(text))
        return out
    except (TypeError, ValueError, KeyError, AttributeError) as e:
        raise LabResultError(
            f"{e} (the result is kept whole in this error's `raw`: json.loads(e.raw))", text
        ) from e


class _Json:
    """A result read from the command line's JSON: every key a field (a key the class
    does not know is an error, so that the two cannot drift apart), and `to_dict()`
    giving the JSON back, keys absent from it left out."""

    _present: FrozenSet[str]

    def to_dict(self) -> Dict[str, Any]:
        """The result as the command line's JSON (a dict; keys absent there left out,
        NaN where the JSON has null for a float)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self) if f.name in self._present}  # type: ignore[arg-type]

    def __repr__(self) -> str:
        """A short form: scalars as they are, lists and arrays by their length."""
        parts = [f"{f.name}={_short(getattr(self, f.name))}" for f in fields(self) if f.name in self._present]  # type: ignore[arg-type]
        return _clip(f"{type(self).__name__}({', '.join(parts)})")


#: Longest repr of a result, characters.
_REPR_MAX = 600


def _clip(s: str, n: int = _REPR_MAX) -> str:
    return s if len(s) <= n else s[: n - 4] + " ..."


def _short(v: Any) -> str:
    if isinstance(v, _Json):
        return f"<{type(v).__name__}>"
    if isinstance(v, np.ndarray):
        return f"<{v.size} values>"
    if isinstance(v, (list, tuple)):
        if len(v) <= 4 and all(isinstance(x, (str, int, float)) for x in v):
            return _clip(repr(list(v)), 120)
        return f"[{len(v)} items]"
    if isinstance(v, dict):
        return f"{{{len(v)} keys}}"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, str):
        return repr(_clip(v, 80))
    return repr(v)


def _num(x: Any, fmt: str = ".4g") -> str:
    """A float for a repr or a table ("-" for None)."""
    if x is None:
        return "-"
    try:
        return format(float(x), fmt)
    except (TypeError, ValueError):
        return str(x)


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


def _build(cls: Any, obj: Any, where: str = "") -> Any:
    if not isinstance(obj, dict):
        raise TypeError(f"{cls.__name__}{where}: expected an object, got {type(obj).__name__}")
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


# HTML for Jupyter (`_repr_html_`): every text escaped.


def _h(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _html_table(header: Sequence[str], rows: Sequence[Sequence[Any]], caption: str = "") -> str:
    cap = f"<caption style='text-align:left'>{_h(caption)}</caption>" if caption else ""
    head = "".join(f"<th>{_h(c)}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{_h(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _html_pairs(title: str, pairs: Sequence[Tuple[str, Any]]) -> str:
    body = "".join(f"<tr><th style='text-align:left'>{_h(k)}</th><td>{_h(v)}</td></tr>" for k, v in pairs)
    return f"<table><caption style='text-align:left'><b>{_h(title)}</b></caption><tbody>{body}</tbody></table>"


def _frame(records: List[Dict[str, Any]]) -> "pd.DataFrame":
    """`records` as a pandas DataFrame."""
    import pandas as pd

    return pd.DataFrame.from_records(records)


@dataclass(frozen=True, repr=False)
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
    window: Optional[Dict[str, Any]] = None


@dataclass(frozen=True, repr=False)
class Summary(_Json):
    """The whole table compared: `n` rows (`distinct_conditions` distinct), the
    residual's RMS and largest magnitude and the measured VE's RMS (g), chi-square,
    its degrees of freedom, per degree of freedom and p-value, and the noise floor
    (RMS of the stated uncertainties, g)."""

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


@dataclass(frozen=True, repr=False)
class Group(_Json):
    """The residual over one group of conditions (`label`, the variable's value):
    `n` rows, their mean and RMS residual (g) and chi-square per degree of freedom."""

    label: str
    n: int
    mean_residual_g: float
    rms_residual_g: float
    chi2_per_dof: float


@dataclass(frozen=True, repr=False)
class ByVariable(_Json):
    """The residual grouped by one condition `variable` (a column of the table)."""

    variable: str
    groups: List[Group]


@dataclass(frozen=True, repr=False)
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
    residual_scales: Optional[List[Any]] = None
    log: Optional[Dict[str, Any]] = None
    logs: Optional[List[Any]] = None
    #: Rows per evaluation path, `{"waveform": n, "statistics": n}`.
    paths: Optional[Dict[str, Any]] = None
    #: Per log, what the waveform path covered.
    waveform: Optional[Any] = None
    #: Per shake-table manifest read: `{"manifest", "runs", "band_clipped",
    #: "runs_band_clipped"}` (the estimator's bands clipped to its reference's rate).
    manifests: Optional[List[Any]] = None

    def to_frame(self) -> "pd.DataFrame":
        """The conditions as a pandas DataFrame, one row per condition, the columns
        of `Row` (VE in g, `z` in standard uncertainties)."""
        return _frame([r.to_dict() for r in self.rows])

    def __repr__(self) -> str:
        """The table, the model and the summary in a few lines."""
        s = self.summary
        effects = " + ".join(self.effects) or "none"
        return _clip(
            f"Comparison({self.table!r}, mode {self.mode}, effects: {effects};\n"
            f"  {s.n} rows, chi2/dof {_num(s.chi2_per_dof)} (dof {s.dof}, p {_num(s.p_value, '.3g')}),\n"
            f"  residual rms {_num(s.rms_residual_g, '.3e')} g, max {_num(s.max_abs_residual_g, '.3e')} g, "
            f"noise floor {_num(s.noise_floor_g, '.3e')} g)"
        )

    def _repr_html_(self) -> str:
        """The summary and the ten largest residuals as HTML tables."""
        s = self.summary
        top = sorted(self.rows, key=lambda r: -abs(r.z) if r.z is not None and not math.isnan(r.z) else 0)[:10]
        return (
            _html_pairs(
                "Comparison",
                [
                    ("table", self.table),
                    ("mode", self.mode),
                    ("effects", ", ".join(self.effects) or "none"),
                    ("rows", s.n),
                    ("chi2/dof", f"{_num(s.chi2_per_dof)} (dof {s.dof}, p {_num(s.p_value, '.3g')})"),
                    ("residual rms, g", _num(s.rms_residual_g, ".3e")),
                    ("noise floor, g", _num(s.noise_floor_g, ".3e")),
                ],
            )
            + _html_table(
                ["run_id", "line", "measured_g", "predicted_g", "residual_g", "z"],
                [
                    [r.run_id, r.line, _num(r.measured_g, ".4e"), _num(r.predicted_g, ".4e"),
                     _num(r.residual_g, ".3e"), _num(r.z, ".3g")]
                    for r in top
                ],
                f"largest residuals ({len(top)} of {len(self.rows)})",
            )
        )


@dataclass(frozen=True, repr=False)
class Param(_Json):
    """A fitted parameter of `effect`: its value and standard uncertainty `sigma`
    (in the parameter's unit, named in `name`: `freq_hz`, `k_ppm`...), the 68 %
    profile interval's reach below and above (`sigma_minus`, `sigma_plus`) and the
    99.73 % interval's (`three_sigma_minus`, `three_sigma_plus`)."""

    effect: str
    name: str
    value: float
    sigma: float
    sigma_minus: float
    sigma_plus: float
    three_sigma_minus: float
    three_sigma_plus: float

    def __repr__(self) -> str:
        """`Param(effect.name = value ± sigma)`."""
        return f"Param({self.effect}.{self.name} = {_num(self.value, '.6g')} ± {_num(self.sigma, '.2g')})"


@dataclass(frozen=True, repr=False)
class Fit(_Json):
    """A fit of effects to the residual (`EffectFit`): `kinds` fitted jointly, their
    `params`, chi-square, BIC and residual RMS (g) before and after, each
    condition's VE change `shift_g` and residual after, g."""

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
    #: Rows some effect of the fit could not act on: `{"effect", "rows": [[line,
    #: run_id], ...], "reason"}` each (absent when none).
    not_applicable: Optional[List[Any]] = None

    def to_frame(self) -> "pd.DataFrame":
        """The parameters as a pandas DataFrame (one row per parameter, the columns
        of `Param`)."""
        return _frame([p.to_dict() for p in self.params])

    def __repr__(self) -> str:
        """The effects, the parameters' count and the fit's figures in a line or two."""
        return _clip(
            f"Fit({' + '.join(self.kinds)}: {len(self.params)} parameters, n {self.n},\n"
            f"  chi2/dof {_num(self.chi2_per_dof_after)} (p {_num(self.p_value_after, '.3g')}), "
            f"delta BIC {_num(self.delta_bic, '.1f')}, "
            f"rms {_num(self.rms_residual_before_g, '.3e')} -> {_num(self.rms_residual_after_g, '.3e')} g)"
        )

    def _repr_html_(self) -> str:
        """The figures and the parameters as HTML tables."""
        return _html_pairs(
            "Fit: " + " + ".join(self.kinds),
            [
                ("rows", self.n),
                ("chi2/dof after", f"{_num(self.chi2_per_dof_after)} (p {_num(self.p_value_after, '.3g')})"),
                ("delta BIC", _num(self.delta_bic, ".1f")),
                ("residual rms, g", f"{_num(self.rms_residual_before_g, '.3e')} -> {_num(self.rms_residual_after_g, '.3e')}"),
            ],
        ) + _params_html(self.params)


def _params_html(params: Sequence[Param]) -> str:
    return _html_table(
        ["effect", "parameter", "value", "sigma", "sigma_minus", "sigma_plus"],
        [[p.effect, p.name, _num(p.value, ".6g"), _num(p.sigma, ".3g"), _num(p.sigma_minus, ".3g"), _num(p.sigma_plus, ".3g")] for p in params],
        "parameters",
    )


@dataclass(frozen=True, repr=False)
class Candidate(_Json):
    """One effect of the library against the residual: its `fit` (None when it could
    not be fitted: `not_applicable` says why), whether the BIC supports it and
    whether it explains the residual."""

    kind: str
    physics: str
    signature: str
    fit: Optional[Fit]
    not_applicable: Optional[str]
    supported: bool
    explains: bool

    def __repr__(self) -> str:
        """The kind, its verdict and its fit's delta BIC."""
        f = self.fit
        what = f"delta BIC {_num(f.delta_bic, '.1f')}, chi2/dof {_num(f.chi2_per_dof_after)}" if f else f"not fitted: {self.not_applicable}"
        return _clip(f"Candidate({self.kind}: supported {self.supported}, explains {self.explains}, {what})", 300)


@dataclass(frozen=True, repr=False)
class Step(_Json):
    """One step of the stepwise search: the `action` (`model as is`, `add KIND`,
    `remove KIND`), the `effects` after it, the BIC change, chi-square and residual
    RMS (g) after it, and the other candidates of the round with their BIC change
    (`runners_up`, `[kind, delta_bic]` each)."""

    action: str
    effects: List[str]
    delta_bic: float
    bic: float
    chi2: float
    chi2_per_dof: float
    p_value: float
    rms_residual_g: float
    runners_up: List[Any]


@dataclass(frozen=True, repr=False)
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
    suggestions: Optional[List[Any]] = None
    found: Optional[List[str]] = None
    variables: Optional[List[str]] = None
    best: Optional[str] = None
    best_explained_fraction: Optional[float] = None
    found_explained_fraction: Optional[float] = None

    def summary(self) -> str:
        """The verdict in one line (`effect: a + b`, `noise (p 0.4)`...)."""
        v = self.verdict
        if v == "noise":
            return f"noise (p {_num(self.p_value, '.3g')}, chi2/dof {_num(self.chi2_per_dof)})"
        if v == "effect":
            return f"effect: {' + '.join(self.kinds or [])} (delta BIC {_num(self.delta_bic, '.1f')})"
        if v == "confounded":
            after = f", after {' + '.join(self.found)}" if self.found else ""
            return f"confounded: {' ~ '.join(self.kinds or [])} (correlation {_num(self.correlation, '.3f')}){after}"
        if v == "unexplained":
            after = f" after {' + '.join(self.found)}" if self.found else ""
            follows = f", follows {', '.join(self.variables)}" if self.variables else ""
            return f"unexplained (chi2/dof {_num(self.chi2_per_dof)}{after}{follows})"
        return v

    def __repr__(self) -> str:
        """`Verdict(...)` around `summary()`."""
        return _clip(f"Verdict({self.summary()})", 400)


@dataclass(frozen=True, repr=False)
class Diagnosis(_Json):
    """`lab diagnose --json`: where the model fails and which effect is missing.

    `repr` is a few lines (the verdict, the effects found, chi2/dof before and after);
    in Jupyter it shows as tables. `to_frame("candidates")` and `to_frame("steps")`
    (also `candidates_frame()`, `steps_frame()`) give the ranking and the stepwise
    search as pandas DataFrames."""

    comparison: Comparison
    trends: List[Any]
    trends_after: List[Any]
    lack_of_fit: Optional[Dict[str, Any]]
    candidates: List[Candidate]
    steps: List[Step]
    selected: Optional[Fit]
    not_applicable: List[Any]
    verdict: Verdict
    options: Dict[str, Any]
    budget: Dict[str, Any]
    empirical: Optional[Dict[str, Any]]
    #: Why no empirical correction is offered where the verdict is `unexplained`.
    empirical_none: Optional[str] = None
    log: Optional[Dict[str, Any]] = None
    logs: Optional[List[Any]] = None
    #: Per shake-table manifest read: `{"manifest", "runs", "band_clipped",
    #: "runs_band_clipped"}` (the estimator's bands clipped to its reference's rate).
    manifests: Optional[List[Any]] = None

    @property
    def next_effects(self) -> List[str]:
        """The effects `lab add --diagnosed` would add (none for "noise")."""
        if self.verdict.verdict == "noise" or self.selected is None:
            return []
        return list(self.selected.kinds)

    def _after(self) -> Tuple[Optional[float], Optional[float]]:
        """chi2/dof and residual RMS (g) after the effects found (the model's own
        when none was found)."""
        if self.selected is not None:
            return self.selected.chi2_per_dof_after, self.selected.rms_residual_after_g
        s = self.comparison.summary
        return s.chi2_per_dof, s.rms_residual_g

    def _empirical_line(self) -> str:
        if self.empirical:
            terms = [t.get("key", "?") for t in self.empirical.get("terms", [])]
            return f"empirical correction (not physical): {', '.join(terms)}"
        if self.empirical_none:
            return "no empirical correction: " + _clip(self.empirical_none, 120)
        return ""

    def __repr__(self) -> str:
        """The verdict, the effects found and chi2/dof before and after, in a few
        lines (the whole result: `to_dict()`)."""
        s = self.comparison.summary
        chi2_after, rms_after = self._after()
        supported = sum(1 for c in self.candidates if c.supported)
        found = " + ".join(self.next_effects) or "none"
        lines = [
            f"Diagnosis({self.verdict.summary()}",
            f"  effects found: {found}",
            f"  chi2/dof {_num(s.chi2_per_dof)} -> {_num(chi2_after)} (n {s.n}), "
            f"rms residual {_num(s.rms_residual_g, '.3e')} -> {_num(rms_after, '.3e')} g",
            f"  candidates {len(self.candidates)} ({supported} supported), steps {len(self.steps)}",
        ]
        e = self._empirical_line()
        if e:
            lines.append("  " + e)
        return _clip("\n".join(lines) + ")", 900)

    def _repr_html_(self) -> str:
        """The verdict, the effects found, the candidates and the steps as HTML
        tables (every text escaped)."""
        s = self.comparison.summary
        chi2_after, rms_after = self._after()
        pairs = [
            ("verdict", self.verdict.summary()),
            ("effects found", ", ".join(self.next_effects) or "none"),
            ("rows", s.n),
            ("chi2/dof", f"{_num(s.chi2_per_dof)} -> {_num(chi2_after)}"),
            ("residual rms, g", f"{_num(s.rms_residual_g, '.3e')} -> {_num(rms_after, '.3e')}"),
        ]
        e = self._empirical_line()
        if e:
            pairs.append(("empirical", e))
        out = _html_pairs("Diagnosis", pairs)
        if self.selected is not None:
            out += _params_html(self.selected.params)
        out += _html_table(
            ["kind", "supported", "explains", "delta BIC", "chi2/dof after", "rms after, g"],
            [
                [c.kind, c.supported, c.explains]
                + ([_num(c.fit.delta_bic, ".1f"), _num(c.fit.chi2_per_dof_after), _num(c.fit.rms_residual_after_g, ".3e")]
                   if c.fit else [f"not fitted: {c.not_applicable}", "", ""])
                for c in self.candidates
            ],
            "candidates",
        )
        out += _html_table(
            ["action", "effects", "delta BIC", "chi2/dof", "rms, g"],
            [[st.action, " + ".join(st.effects), _num(st.delta_bic, ".1f"), _num(st.chi2_per_dof), _num(st.rms_residual_g, ".3e")] for st in self.steps],
            "steps",
        )
        return out

    def candidates_frame(self) -> "pd.DataFrame":
        """The candidates as a pandas DataFrame, best first: one row per candidate,
        the columns `kind`, `physics`, `signature`, `supported`, `explains`,
        `not_applicable` and the fit's scalars (`delta_bic`, `chi2_after`,
        `chi2_per_dof_after`, `p_value_after`, `bic_before`, `bic_after`,
        `rms_residual_before_g`, `rms_residual_after_g` (g), `n`, `k`, `evaluations`;
        NaN where not fitted) and `params` (`{name: value}` of the fit), each the
        value of the `--json`'s `candidates`."""
        keys = ["delta_bic", "chi2_before", "chi2_after", "chi2_per_dof_after", "p_value_after", "bic_before",
                "bic_after", "rms_residual_before_g", "rms_residual_after_g", "n", "k", "evaluations"]
        records = []
        for c in self.candidates:
            r = {"kind": c.kind, "physics": c.physics, "signature": c.signature, "supported": c.supported,
                 "explains": c.explains, "not_applicable": c.not_applicable}
            for k in keys:
                v = None if c.fit is None else getattr(c.fit, k)
                r[k] = math.nan if v is None else v
            r["params"] = {} if c.fit is None else {f"{p.effect}.{p.name}": p.value for p in c.fit.params}
            records.append(r)
        return _frame(records)

    def steps_frame(self) -> "pd.DataFrame":
        """The stepwise search as a pandas DataFrame: one row per step, the columns of
        `Step` (`effects` a list, `runners_up` a list of `[kind, delta_bic]`; RMS in
        g), each the value of the `--json`'s `steps`."""
        return _frame([st.to_dict() for st in self.steps])

    def to_frame(self, what: str = "candidates") -> "pd.DataFrame":
        """A pandas DataFrame of `what`: ``"candidates"`` (`candidates_frame()`),
        ``"steps"`` (`steps_frame()`) or ``"rows"`` (the comparison's conditions,
        `Comparison.to_frame()`)."""
        if what == "candidates":
            return self.candidates_frame()
        if what == "steps":
            return self.steps_frame()
        if what == "rows":
            return self.comparison.to_frame()
        raise ValueError(f"what = {what!r}: must be \"candidates\", \"steps\" or \"rows\"")


@dataclass(frozen=True, repr=False)
class Added(_Json):
    """`lab add --json` (without `out`: nothing is written until `model.save`)."""

    effects: List[str]
    fit: Optional[Fit] = None
    empirical: Optional[Dict[str, Any]] = None
    log: Optional[Dict[str, Any]] = None
    logs: Optional[List[Any]] = None
    #: Where the command line wrote the model (`lab add --out`); never set by the
    #: package, which writes nothing.
    out: Optional[str] = None
    #: Per shake-table manifest read: `{"manifest", "runs", "band_clipped",
    #: "runs_band_clipped"}` (the estimator's bands clipped to its reference's rate).
    manifests: Optional[List[Any]] = None
    model: Optional["Model"] = None

    def to_dict(self) -> Dict[str, Any]:
        """The result as the command line's JSON (`model` left out: `model.text`)."""
        d = super().to_dict()
        d.pop("model", None)
        return d

    def __repr__(self) -> str:
        """The effects of the extended model and the fit's figures in a few lines."""
        lines = [f"Added(effects: {', '.join(self.effects) or 'none'}"]
        if self.fit is not None:
            f = self.fit
            lines.append(
                f"  fit: {' + '.join(f.kinds)}, chi2/dof {_num(f.chi2_per_dof_after)}, "
                f"rms {_num(f.rms_residual_before_g, '.3e')} -> {_num(f.rms_residual_after_g, '.3e')} g"
            )
        if self.empirical:
            terms = [t.get("key", "?") for t in self.empirical.get("terms", [])]
            lines.append(f"  empirical correction (not physical): {', '.join(terms)}")
        if self.model is not None:
            lines.append(f"  model: {self.model!r}")
        return _clip("\n".join(lines) + ")")

    def _repr_html_(self) -> str:
        """The effects and the fit's parameters as HTML tables."""
        out = _html_pairs("Added", [("effects", ", ".join(self.effects) or "none")])
        if self.fit is not None:
            out += self.fit._repr_html_()
        return out


# ---------------------------------------------------------------------------------
# The extended model


class Model:
    """An extended model (docs/lab.md, `MODEL.toml`): a base mode plus effects. Read
    with `Model.load`, made by `lab.add`, written with `save`."""

    def __init__(self, text: str, name: str = "<model>"):
        """`text`: the model file's TOML (checked); `name`: what errors call it (its
        path, or `<added>`)."""
        self.text = text
        self.name = name
        self.mode, self.effects = _native.model_effects(text, name)

    @classmethod
    def load(cls, path: PathLike) -> "Model":
        """The extended model file at `path` (a `lab add --out` TOML), checked."""
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


Progress = Union[None, bool, Callable[[int, int, str], None]]


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
    with _progress_bar(progress) as callback:
        text = _native.lab_table(_inputs(inputs), _model(model), mode, log, callback)
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
    with _progress_bar(progress) as callback:
        text = _native.lab_compare(_inputs(inputs), _model(model), mode, log, path, callback)
    return _parse(Comparison, text)


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
    with _progress_bar(progress) as callback:
        text = _native.lab_diagnose(
            _inputs(inputs), _model(model), mode, log, list(effects or []), int(max_effects), callback
        )
    return _parse(Diagnosis, text)


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
    with _progress_bar(progress) as callback:
        text, toml = _native.lab_add(
            _inputs(inputs), _model(model), log, [] if diagnosed else kinds, diagnosed, bool(freeze), callback
        )
    added = _parse(Added, text)
    object.__setattr__(added, "model", Model(toml, "<added>"))
    return added


# ---------------------------------------------------------------------------------
# Progress of a long call


def _in_notebook() -> bool:
    """Whether this is a Jupyter (IPython kernel) session; IPython is not imported
    when it is not already."""
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    try:
        shell = ipython.get_ipython()
    except Exception:  # an IPython too old or half imported: not a notebook
        return False
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


class _TqdmProgress:
    """`progress(done, of, what)` drawn as a tqdm bar: `of` its total (0: not known
    yet), `what` its description (the candidate being fitted, "run measured")."""

    def __init__(self, tqdm):
        self.bar = tqdm(total=None, unit="step", leave=False, dynamic_ncols=True)

    def __call__(self, done: int, of: int, what: str) -> None:
        if of and self.bar.total != of:
            self.bar.reset(total=of)
        self.bar.n = done
        self.bar.set_description_str(what, refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


class _progress_bar:
    """The `progress` argument of the lab's calls, as the callable the native call
    takes (a context manager that closes the bar it made).

    - a callable: called as `progress(done, of, what)` when the count moves and at
      least every 0.25 s while the call runs, `(0, 0, "starting")` before the first
      count; an exception it raises stops the call and is raised from it;
    - None (the default): a tqdm bar in a notebook when tqdm is installed (the
      `vibrocomp[notebook]` extra), else nothing;
    - True: a tqdm bar wherever it runs (ImportError without tqdm); False: nothing.

    Ctrl-C stops a call within about 0.1 s (`KeyboardInterrupt`), whatever `progress`.
    """

    def __init__(self, progress: Progress):
        self.bar: Optional[_TqdmProgress] = None
        if progress is True or (progress is None and _in_notebook()):
            try:
                from tqdm.auto import tqdm
            except ImportError:
                if progress is True:
                    raise ImportError(
                        "progress=True draws a tqdm bar: pip install tqdm (or vibrocomp[notebook])"
                    ) from None
            else:
                self.bar = _TqdmProgress(tqdm)
            self.callback = self.bar
        elif progress is None:
            self.callback = None
        elif progress is False:
            self.callback = None
        elif callable(progress):
            self.callback = progress
        else:
            raise TypeError(
                f"progress = {progress!r}: must be a callable(done, of, what), True, False or None"
            )

    def __enter__(self):
        return self.callback

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()
