"""The vibration-error model of one accelerometer (MODEL.md sections 4 to 7, 10) over
numpy arrays of conditions: what `vibrocomp model ve`, `model compensate` and
`require` compute for one condition, here for every element of broadcast arrays.

Names follow the command line's flags in lower case: `al3_g` is `--aL3-g`, `ab3_g`
`--aB3-g`, `sigma3_g` `--sigma3-g`. Axes are the unit's own: 1 = OA, 2 = PA, 3 = IA.
Every value is checked against the rule a file's value obeys, all problems at once,
each as `name[index] = value: rule`.

Types: a result holds a `float` per value when every condition is a scalar, else a
float64 array of the conditions' broadcast shape (`VeComponents[float]`,
`VeComponents[FloatArray]`; the overloads of `ve` and `compensate` say which).
"""

from __future__ import annotations

import functools
import inspect
import json
import os
from dataclasses import dataclass, field
from typing import (
    TYPE_CHECKING,
    Any,
    Callable,
    Dict,
    Generic,
    List,
    Literal,
    Optional,
    Protocol,
    Sequence,
    Tuple,
    TypeVar,
    Union,
    cast,
    overload,
)

import numpy as np
import numpy.typing as npt

from . import _vibrocomp as _native
from ._arrays import array as _array
from ._arrays import column_bytes as _column_bytes

if TYPE_CHECKING:
    from .lab import Model

Mode = Literal["exact", "paper", "as-published"]
"""The base model's mode (`--mode`)."""

FloatArray = npt.NDArray[np.float64]
"""A float64 array: the values of array conditions."""


class SupportsArray(Protocol):
    """What numpy makes an array of (`__array__`): an array, a pandas Series."""

    def __array__(self) -> npt.NDArray[Any]:
        """The values as a numpy array."""
        ...


Values = Union[float, Sequence[float], SupportsArray]
"""A condition: a scalar, a list or an array (a DataFrame's column), broadcast with
the others."""

V = TypeVar("V", float, FloatArray)
"""What a result holds per value: `float` (scalar conditions) or `FloatArray`."""

PathLike = Union[str, "os.PathLike[str]"]
"""A file's path."""

ModelLike = Union["Model", str, "os.PathLike[str]"]
"""An extended model: a `vibrocomp.Model` or its file."""

# The vibration's keyword arguments and their defaults (`model ve`'s flags); the
# sigmas default to "not given".
_VIBRATION_DEFAULTS: Dict[str, Optional[float]] = {
    "ab1_g": 0.0,
    "ab2_g": 0.0,
    "ab3_g": 0.0,
    "freq_hz": 0.0,
    "phase31_deg": 0.0,
    "phase32_deg": 0.0,
    "sigma1_g": None,
    "sigma2_g": None,
    "sigma3_g": None,
    "cov31_g2": 0.0,
    "cov32_g2": 0.0,
    "kurtosis3": 3.0,
}


def _spec(passport: PassportLike) -> str:
    if isinstance(passport, Passport):
        return passport.source
    return os.fspath(passport)


@dataclass(frozen=True)
class Passport:
    """A unit's passport: a shipped id (`AL-15`, `AL-1M`, `AKS-05`) or a TOML file.

    `source` is the id or the file's absolute path, `id` the passport's id, and `fields`
    the passport file's keys and values (ppm units, MODEL.md section 1).
    """

    source: str
    id: str
    fields: Dict[str, Any] = field(repr=False)

    @classmethod
    def load(cls, spec: PathLike) -> "Passport":
        """Reads a passport: a TOML file if `spec` names one, else a shipped id
        (`--passport`). Raises `VibrocompError` naming the file, line and key of a
        bad value, or for an unknown id."""
        spec = os.fspath(spec)
        source = os.path.abspath(spec) if os.path.isfile(spec) else spec
        fields = json.loads(_native.passport(source))
        return cls(source=source, id=str(fields["id"]), fields=fields)


PassportLike = Union[Passport, str, "os.PathLike[str]"]
"""A passport: a `Passport`, a shipped id or a TOML file."""


@dataclass(frozen=True)
class TriadUnit:
    """One unit of a triad: its `name`, its axes in the body frame (`ia`, `oa`, `pa`,
    each as `+x` .. `-z`), and its passport's fields (`passport`, ppm units)."""

    name: str
    ia: str
    oa: str
    pa: str
    passport: Dict[str, Any] = field(repr=False)


@dataclass(frozen=True)
class Triad:
    """A triad of units (config/triads): its `id` and its three `units`."""

    id: str
    units: Tuple[TriadUnit, TriadUnit, TriadUnit]

    @classmethod
    def load(cls, spec: PathLike = "default") -> "Triad":
        """Reads a triad (`--triad`): `default`, a shipped id or a TOML file."""
        spec = os.fspath(spec)
        d = json.loads(_native.triad(spec))
        u = [TriadUnit(**unit) for unit in d["units"]]
        return cls(id=d["id"], units=(u[0], u[1], u[2]))


def _columns(named: Dict[str, Optional[Values]]) -> Tuple[Dict[str, bytes], Tuple[int, ...]]:
    """The given values broadcast together, flattened to float64 columns (as bytes for
    the native half), and their common shape."""
    given = {k: np.asarray(v, dtype=np.float64) for k, v in named.items() if v is not None}
    shape = np.broadcast_shapes(*(a.shape for a in given.values())) if given else ()
    cols = {k: _column_bytes(np.broadcast_to(a, shape).reshape(-1)) for k, a in given.items()}
    return cols, shape


def _shaped(values: Any, shape: Tuple[int, ...]) -> Any:
    a = _array(values).reshape(shape)
    return float(a) if shape == () else a


def _model_arg(model: Optional[ModelLike]) -> Optional[Tuple[str, str]]:
    if model is None:
        return None
    from .lab import Model

    m = model if isinstance(model, Model) else Model.load(model)
    return (m.text, m.name)


_F = TypeVar("_F", bound=Callable[..., Any])


def _known_arguments(f: _F) -> _F:
    """`f`, refusing an unknown keyword argument with the list of the vibration's (the
    message of the package before its arguments were spelled out). The signature stays
    `f`'s (`functools.wraps`: `help()`, `inspect.signature`, IDEs)."""
    known = set(inspect.signature(f).parameters)

    @functools.wraps(f)
    def checked(*args: Any, **kwargs: Any) -> Any:
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise TypeError(
                f"{f.__name__}(): unknown vibration argument(s) {', '.join(unknown)}: "
                f"expected {', '.join(_VIBRATION_DEFAULTS)}"
            )
        return f(*args, **kwargs)

    return cast(_F, checked)


@dataclass(frozen=True)
class VeComponents(Generic[V]):
    """The VE components of `vibrocomp model ve` (MODEL.md sections 5, 6); each a
    float for scalar conditions, else an array of the conditions' shape.

    - `d01_g`, `d02_g`, `d03_g`: the additive VE terms D01, D02, D03, g.
    - `delta1` (dimensionless), `delta2_per_g` (1/g), `delta3_per_g2` (1/g^2): the
      multiplicative terms.
    - `additive_g`, `multiplicative_g`: the additive VE and the multiplicative one at
      the flight acceleration, g.
    - `total_g`: the VE, their sum, g.
    """

    d01_g: V
    d02_g: V
    d03_g: V
    delta1: V
    delta2_per_g: V
    delta3_per_g2: V
    additive_g: V
    multiplicative_g: V
    total_g: V


@dataclass(frozen=True)
class ExtendedVe(Generic[V]):
    """An extended model's VE (`model ve --model`): the base model's `base_ve_g` (g),
    the factor `sensor_rms_factor` the sensor effects scale the IA vibration by
    (dimensionless), each effect's change of the VE by kind (`effects`, g), and the
    total `ve_g` (g)."""

    base_ve_g: V
    sensor_rms_factor: V
    effects: Dict[str, V]
    ve_g: V


@overload
def ve(  # type: ignore[overload-overlap]
    passport: PassportLike,
    al3_g: float,
    al1_g: float = ...,
    al2_g: float = ...,
    *,
    ab1_g: float = ...,
    ab2_g: float = ...,
    ab3_g: float = ...,
    freq_hz: float = ...,
    phase31_deg: float = ...,
    phase32_deg: float = ...,
    sigma1_g: Optional[float] = ...,
    sigma2_g: Optional[float] = ...,
    sigma3_g: Optional[float] = ...,
    cov31_g2: float = ...,
    cov32_g2: float = ...,
    kurtosis3: float = ...,
    mode: Mode = ...,
    model: None = ...,
    psd: Optional[PathLike] = ...,
) -> VeComponents[float]: ...


@overload
def ve(
    passport: PassportLike,
    al3_g: Values,
    al1_g: Values = ...,
    al2_g: Values = ...,
    *,
    ab1_g: Values = ...,
    ab2_g: Values = ...,
    ab3_g: Values = ...,
    freq_hz: Values = ...,
    phase31_deg: Values = ...,
    phase32_deg: Values = ...,
    sigma1_g: Optional[Values] = ...,
    sigma2_g: Optional[Values] = ...,
    sigma3_g: Optional[Values] = ...,
    cov31_g2: Values = ...,
    cov32_g2: Values = ...,
    kurtosis3: Values = ...,
    mode: Mode = ...,
    model: None = ...,
    psd: Optional[PathLike] = ...,
) -> VeComponents[FloatArray]: ...


@overload
def ve(  # type: ignore[overload-overlap]
    passport: PassportLike,
    al3_g: float,
    al1_g: float = ...,
    al2_g: float = ...,
    *,
    ab1_g: float = ...,
    ab2_g: float = ...,
    ab3_g: float = ...,
    freq_hz: float = ...,
    phase31_deg: float = ...,
    phase32_deg: float = ...,
    sigma1_g: Optional[float] = ...,
    sigma2_g: Optional[float] = ...,
    sigma3_g: Optional[float] = ...,
    cov31_g2: float = ...,
    cov32_g2: float = ...,
    kurtosis3: float = ...,
    mode: Mode = ...,
    model: ModelLike,
    psd: Optional[PathLike] = ...,
) -> ExtendedVe[float]: ...


@overload
def ve(
    passport: PassportLike,
    al3_g: Values,
    al1_g: Values = ...,
    al2_g: Values = ...,
    *,
    ab1_g: Values = ...,
    ab2_g: Values = ...,
    ab3_g: Values = ...,
    freq_hz: Values = ...,
    phase31_deg: Values = ...,
    phase32_deg: Values = ...,
    sigma1_g: Optional[Values] = ...,
    sigma2_g: Optional[Values] = ...,
    sigma3_g: Optional[Values] = ...,
    cov31_g2: Values = ...,
    cov32_g2: Values = ...,
    kurtosis3: Values = ...,
    mode: Mode = ...,
    model: ModelLike,
    psd: Optional[PathLike] = ...,
) -> ExtendedVe[FloatArray]: ...


@_known_arguments
def ve(
    passport: PassportLike,
    al3_g: Values,
    al1_g: Values = 0.0,
    al2_g: Values = 0.0,
    *,
    ab1_g: Values = 0.0,
    ab2_g: Values = 0.0,
    ab3_g: Values = 0.0,
    freq_hz: Values = 0.0,
    phase31_deg: Values = 0.0,
    phase32_deg: Values = 0.0,
    sigma1_g: Optional[Values] = None,
    sigma2_g: Optional[Values] = None,
    sigma3_g: Optional[Values] = None,
    cov31_g2: Values = 0.0,
    cov32_g2: Values = 0.0,
    kurtosis3: Values = 3.0,
    mode: Mode = "exact",
    model: Optional[ModelLike] = None,
    psd: Optional[PathLike] = None,
) -> Union[VeComponents[Any], ExtendedVe[Any]]:
    """The VE of a unit for each condition (`vibrocomp model ve`).

    - `passport`: the unit's passport (a `Passport`, a shipped id or a TOML file).
    - `al3_g`, `al1_g`, `al2_g`: the flight acceleration along IA, OA and PA, g (the
      last two default 0).

    The vibration (keyword arguments, each a scalar or an array, broadcast with the
    flight acceleration; `model ve`'s flags):

    - `ab1_g`, `ab2_g`, `ab3_g`: the deterministic (tone) vibration's amplitude along
      OA, PA and IA, g (default 0; all 0: no tone).
    - `freq_hz`: its frequency, Hz (selects lambda(f) from the passport; 0: lambda = 1).
    - `phase31_deg`, `phase32_deg`: the phase of the IA vibration relative to OA and PA,
      phi3 - phi1 and phi3 - phi2, degrees (default 0, as the papers).
    - `sigma1_g`, `sigma2_g`, `sigma3_g`: the RMS of the broadband random vibration
      along OA, PA and IA, g (default None: not given; `psd`'s bands replace them).
    - `cov31_g2`, `cov32_g2`: the covariances K_31(0) and K_32(0) of the random
      vibration along IA and OA, IA and PA, g^2 (default 0).
    - `kurtosis3`: the kurtosis of the random vibration along IA (default 3, Gaussian).

    - `mode`: `"exact"` (default), `"paper"` or `"as-published"` (MODEL.md section 7).
    - `model`: an extended model (`vibrocomp.Model` or its file), whose mode wins.
    - `psd`: a band PSD file (CSV: `f_lo_hz, f_hi_hz, psd3_g2_per_hz [, psd1.., psd2..]`,
      e.g. config/vibration/p1-table3.csv) for the random part instead of the sigmas.

    Raises `VibrocompError` listing every value outside its rule (`name[index] = value:
    rule`), `ValueError` for arrays that do not broadcast, and `TypeError` for an
    unknown keyword argument.

    Returns `VeComponents` (without `model`) or `ExtendedVe` (with it): floats for
    scalar conditions, else arrays of the conditions' broadcast shape.
    """
    named = {
        "al1_g": al1_g, "al2_g": al2_g, "al3_g": al3_g,
        "ab1_g": ab1_g, "ab2_g": ab2_g, "ab3_g": ab3_g, "freq_hz": freq_hz,
        "phase31_deg": phase31_deg, "phase32_deg": phase32_deg,
        "sigma1_g": sigma1_g, "sigma2_g": sigma2_g, "sigma3_g": sigma3_g,
        "cov31_g2": cov31_g2, "cov32_g2": cov32_g2, "kurtosis3": kurtosis3,
    }  # fmt: skip
    cols, shape = _columns(named)
    psd_arg = None if psd is None else os.fspath(psd)
    out = _native.ve(_spec(passport), cols, mode, _model_arg(model), psd_arg)
    effects = {k: _shaped(v, shape) for k, v in out.pop("effects").items()}
    if model is not None:
        return ExtendedVe(
            base_ve_g=_shaped(out["base_ve_g"], shape),
            sensor_rms_factor=_shaped(out["sensor_rms_factor"], shape),
            effects=effects,
            ve_g=_shaped(out["ve_g"], shape),
        )
    return VeComponents(**{k: _shaped(v, shape) for k, v in out.items()})


@dataclass(frozen=True)
class Stages(Generic[V]):
    """The compensation stages of [P2 (17)-(20)] (`vibrocomp model compensate`), g:
    the first approximation `a1_g` a(1), the main error removed `a2_g` a(2), the
    deterministic VE removed `a3_g` a(3), the random VE removed `a4_g` a(4), and the
    three corrections `main_g`, `det_g`, `rand_g`."""

    a1_g: V
    a2_g: V
    a3_g: V
    a4_g: V
    main_g: V
    det_g: V
    rand_g: V


@dataclass(frozen=True)
class ExtendedStages(Stages[V]):
    """[`Stages`] under an extended model: the factor `sensor_rms_factor` the sensor
    effects scale the IA vibration by (dimensionless), each effect's VE at a(1) by kind
    (`effects`, g), and a(4) with the effects removed (`a4_extended_g`, g: the
    compensator service's output)."""

    # Defaults only because a dataclass's fields with defaults follow those without
    # (`compensate` always gives them).
    sensor_rms_factor: V = None  # type: ignore[assignment]
    effects: Dict[str, V] = None  # type: ignore[assignment]
    a4_extended_g: V = None  # type: ignore[assignment]


@overload
def compensate(  # type: ignore[overload-overlap]
    passport: PassportLike,
    reading_g: float,
    reading1_g: float = ...,
    reading2_g: float = ...,
    *,
    ab1_g: float = ...,
    ab2_g: float = ...,
    ab3_g: float = ...,
    freq_hz: float = ...,
    phase31_deg: float = ...,
    phase32_deg: float = ...,
    sigma1_g: Optional[float] = ...,
    sigma2_g: Optional[float] = ...,
    sigma3_g: Optional[float] = ...,
    cov31_g2: float = ...,
    cov32_g2: float = ...,
    kurtosis3: float = ...,
    mode: Mode = ...,
    model: None = ...,
    psd: Optional[PathLike] = ...,
) -> Stages[float]: ...


@overload
def compensate(
    passport: PassportLike,
    reading_g: Values,
    reading1_g: Values = ...,
    reading2_g: Values = ...,
    *,
    ab1_g: Values = ...,
    ab2_g: Values = ...,
    ab3_g: Values = ...,
    freq_hz: Values = ...,
    phase31_deg: Values = ...,
    phase32_deg: Values = ...,
    sigma1_g: Optional[Values] = ...,
    sigma2_g: Optional[Values] = ...,
    sigma3_g: Optional[Values] = ...,
    cov31_g2: Values = ...,
    cov32_g2: Values = ...,
    kurtosis3: Values = ...,
    mode: Mode = ...,
    model: None = ...,
    psd: Optional[PathLike] = ...,
) -> Stages[FloatArray]: ...


@overload
def compensate(  # type: ignore[overload-overlap]
    passport: PassportLike,
    reading_g: float,
    reading1_g: float = ...,
    reading2_g: float = ...,
    *,
    ab1_g: float = ...,
    ab2_g: float = ...,
    ab3_g: float = ...,
    freq_hz: float = ...,
    phase31_deg: float = ...,
    phase32_deg: float = ...,
    sigma1_g: Optional[float] = ...,
    sigma2_g: Optional[float] = ...,
    sigma3_g: Optional[float] = ...,
    cov31_g2: float = ...,
    cov32_g2: float = ...,
    kurtosis3: float = ...,
    mode: Mode = ...,
    model: ModelLike,
    psd: Optional[PathLike] = ...,
) -> ExtendedStages[float]: ...


@overload
def compensate(
    passport: PassportLike,
    reading_g: Values,
    reading1_g: Values = ...,
    reading2_g: Values = ...,
    *,
    ab1_g: Values = ...,
    ab2_g: Values = ...,
    ab3_g: Values = ...,
    freq_hz: Values = ...,
    phase31_deg: Values = ...,
    phase32_deg: Values = ...,
    sigma1_g: Optional[Values] = ...,
    sigma2_g: Optional[Values] = ...,
    sigma3_g: Optional[Values] = ...,
    cov31_g2: Values = ...,
    cov32_g2: Values = ...,
    kurtosis3: Values = ...,
    mode: Mode = ...,
    model: ModelLike,
    psd: Optional[PathLike] = ...,
) -> ExtendedStages[FloatArray]: ...


@_known_arguments
def compensate(
    passport: PassportLike,
    reading_g: Values,
    reading1_g: Values = 0.0,
    reading2_g: Values = 0.0,
    *,
    ab1_g: Values = 0.0,
    ab2_g: Values = 0.0,
    ab3_g: Values = 0.0,
    freq_hz: Values = 0.0,
    phase31_deg: Values = 0.0,
    phase32_deg: Values = 0.0,
    sigma1_g: Optional[Values] = None,
    sigma2_g: Optional[Values] = None,
    sigma3_g: Optional[Values] = None,
    cov31_g2: Values = 0.0,
    cov32_g2: Values = 0.0,
    kurtosis3: Values = 3.0,
    mode: Mode = "exact",
    model: Optional[ModelLike] = None,
    psd: Optional[PathLike] = None,
) -> Union[Stages[Any], ExtendedStages[Any]]:
    """The compensation of mean readings (`vibrocomp model compensate`).

    - `passport`: the unit's passport (a `Passport`, a shipped id or a TOML file).
    - `reading_g`: the unit's output over its nominal scale factor (U/K1), g.
    - `reading1_g`, `reading2_g`: the flight acceleration along OA and PA from the
      triad's other units, g (default 0).

    The vibration (keyword arguments, each a scalar or an array, broadcast with the
    flight acceleration; `model ve`'s flags):

    - `ab1_g`, `ab2_g`, `ab3_g`: the deterministic (tone) vibration's amplitude along
      OA, PA and IA, g (default 0; all 0: no tone).
    - `freq_hz`: its frequency, Hz (selects lambda(f) from the passport; 0: lambda = 1).
    - `phase31_deg`, `phase32_deg`: the phase of the IA vibration relative to OA and PA,
      phi3 - phi1 and phi3 - phi2, degrees (default 0, as the papers).
    - `sigma1_g`, `sigma2_g`, `sigma3_g`: the RMS of the broadband random vibration
      along OA, PA and IA, g (default None: not given; `psd`'s bands replace them).
    - `cov31_g2`, `cov32_g2`: the covariances K_31(0) and K_32(0) of the random
      vibration along IA and OA, IA and PA, g^2 (default 0).
    - `kurtosis3`: the kurtosis of the random vibration along IA (default 3, Gaussian).

    - `mode`: `"exact"` (default), `"paper"` or `"as-published"` (MODEL.md section 7).
    - `model`: an extended model (`vibrocomp.Model` or its file), whose mode wins.
    - `psd`: a band PSD file (CSV: `f_lo_hz, f_hi_hz, psd3_g2_per_hz [, psd1.., psd2..]`,
      e.g. config/vibration/p1-table3.csv) for the random part instead of the sigmas.

    Raises `VibrocompError` listing every value outside its rule (`name[index] = value:
    rule`), `ValueError` for arrays that do not broadcast, and `TypeError` for an
    unknown keyword argument.

    Returns `Stages` (without `model`) or `ExtendedStages` (with it): floats for
    scalar readings, else arrays of the broadcast shape.
    """
    named = {
        "reading_g": reading_g, "reading1_g": reading1_g, "reading2_g": reading2_g,
        "ab1_g": ab1_g, "ab2_g": ab2_g, "ab3_g": ab3_g, "freq_hz": freq_hz,
        "phase31_deg": phase31_deg, "phase32_deg": phase32_deg,
        "sigma1_g": sigma1_g, "sigma2_g": sigma2_g, "sigma3_g": sigma3_g,
        "cov31_g2": cov31_g2, "cov32_g2": cov32_g2, "kurtosis3": kurtosis3,
    }  # fmt: skip
    cols, shape = _columns(named)
    psd_arg = None if psd is None else os.fspath(psd)
    out = _native.compensate(_spec(passport), cols, mode, _model_arg(model), psd_arg)
    effects = {k: _shaped(v, shape) for k, v in out.pop("effects").items()}
    values = {k: _shaped(v, shape) for k, v in out.items()}
    if model is not None:
        return ExtendedStages(effects=effects, **values)
    return Stages(**values)


@dataclass(frozen=True)
class Requirement:
    """One allowed modulus (MODEL.md section 10): the `coefficient` and its term, its
    key in a passport file (`passport_key`), its `share` of D* (dimensionless), its VE
    per unit coefficient (`ve_per_unit_g`, g per passport unit), the `allowed` modulus
    in passport units (None: the term vanishes here) and that `unit`."""

    coefficient: str
    passport_key: str
    share: float
    ve_per_unit_g: float
    allowed: Optional[float]
    unit: str


@dataclass(frozen=True)
class Requirements:
    """`vibrocomp require --json`: the `mode`, the VE budget `dstar_g` (g) and one
    `Requirement` per coefficient."""

    mode: str
    dstar_g: float
    requirements: List[Requirement]

    def to_dict(self) -> Dict[str, Any]:
        """The command line's JSON (`require --json`) as a dict."""
        return {
            "mode": self.mode,
            "dstar_g": self.dstar_g,
            "requirements": [r.__dict__.copy() for r in self.requirements],
        }


def require(
    dstar_g: float,
    al3_g: float,
    *,
    ab1_g: float = 0.0,
    ab2_g: float = 0.0,
    ab3_g: float = 0.0,
    sigma3_g: float = 0.0,
    mode: Literal["paper", "exact"] = "paper",
) -> Requirements:
    """The allowed moduli of the passport coefficients for a VE budget (`vibrocomp
    require`, MODEL.md section 10).

    - `dstar_g`: the VE budget D*, g.
    - `al3_g`: the flight acceleration along IA, g.
    - `ab1_g`, `ab2_g`, `ab3_g`: the tone's amplitude along OA, PA and IA, g.
    - `sigma3_g`: the RMS of the random vibration along IA, g.
    - `mode`: `"paper"` (default) or `"exact"`.
    """
    d = json.loads(
        _native.require(float(dstar_g), float(al3_g), (float(ab1_g), float(ab2_g), float(ab3_g)),
                        float(sigma3_g), mode)
    )
    return Requirements(
        mode=d["mode"],
        dstar_g=d["dstar_g"],
        requirements=[Requirement(**r) for r in d["requirements"]],
    )
