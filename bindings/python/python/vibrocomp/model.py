"""The vibration-error model of one accelerometer (MODEL.md sections 4 to 7, 10) over
numpy arrays of conditions: what `vibrocomp model ve`, `model compensate` and
`require` compute for one condition, here for every element of broadcast arrays.

Names follow the command line's flags in lower case: `al3_g` is `--aL3-g`, `ab3_g`
`--aB3-g`, `sigma3_g` `--sigma3-g`. Axes are the unit's own: 1 = OA, 2 = PA, 3 = IA.
Every value is checked against the rule a file's value obeys, all problems at once,
each as `name[index] = value: rule`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

import numpy as np

from . import _vibrocomp as _native
from ._arrays import array as _array
from ._arrays import column_bytes as _column_bytes

ArrayLike = Union[float, int, "np.ndarray", List[float]]

# The vibration's keyword arguments and their defaults (`model ve`'s flags); the
# sigmas default to "not given".
_VIBRATION_DEFAULTS = {
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


def _spec(passport: "PassportLike") -> str:
    if isinstance(passport, Passport):
        return passport.source
    return os.fspath(passport)


@dataclass(frozen=True)
class Passport:
    """A unit's passport: a shipped id (`AL-15`, `AL-1M`, `AKS-05`) or a TOML file.

    `fields` are the passport file's keys and values (ppm units, MODEL.md section 1).
    """

    source: str
    id: str
    fields: Dict[str, object] = field(repr=False)

    @classmethod
    def load(cls, spec: Union[str, "os.PathLike[str]"]) -> "Passport":
        """Reads a passport: a TOML file if `spec` names one, else a shipped id."""
        spec = os.fspath(spec)
        source = os.path.abspath(spec) if os.path.isfile(spec) else spec
        fields = json.loads(_native.passport(source))
        return cls(source=source, id=str(fields["id"]), fields=fields)


PassportLike = Union[Passport, str, "os.PathLike[str]"]


@dataclass(frozen=True)
class TriadUnit:
    """One unit of a triad: its name, its axes in the body frame (`+x`, `-z`), and
    its passport's fields."""

    name: str
    ia: str
    oa: str
    pa: str
    passport: Dict[str, object] = field(repr=False)


@dataclass(frozen=True)
class Triad:
    """A triad of units (config/triads): `default`, a shipped id or a TOML file."""

    id: str
    units: Tuple[TriadUnit, TriadUnit, TriadUnit]

    @classmethod
    def load(cls, spec: Union[str, "os.PathLike[str]"] = "default") -> "Triad":
        spec = os.fspath(spec)
        d = json.loads(_native.triad(spec))
        units = tuple(TriadUnit(**u) for u in d["units"])
        return cls(id=d["id"], units=units)  # type: ignore[arg-type]


def _columns(named: Dict[str, Optional[ArrayLike]]) -> Tuple[Dict[str, bytes], tuple]:
    """The given values broadcast together, flattened to float64 columns (as bytes for
    the native half), and their common shape."""
    given = {k: np.asarray(v, dtype=np.float64) for k, v in named.items() if v is not None}
    shape = np.broadcast_shapes(*(a.shape for a in given.values())) if given else ()
    cols = {k: _column_bytes(np.broadcast_to(a, shape).reshape(-1)) for k, a in given.items()}
    return cols, shape


def _shaped(values, shape: tuple):
    a = _array(values).reshape(shape)
    return float(a) if shape == () else a


def _model_arg(model) -> Optional[Tuple[str, str]]:
    if model is None:
        return None
    from .lab import Model

    m = model if isinstance(model, Model) else Model.load(model)
    return (m.text, m.name)


@dataclass(frozen=True)
class VeComponents:
    """The VE components of `vibrocomp model ve` (MODEL.md sections 5, 6), g; each an
    array of the conditions' shape (a float for scalar conditions)."""

    d01_g: np.ndarray
    d02_g: np.ndarray
    d03_g: np.ndarray
    delta1: np.ndarray
    delta2_per_g: np.ndarray
    delta3_per_g2: np.ndarray
    additive_g: np.ndarray
    multiplicative_g: np.ndarray
    total_g: np.ndarray


@dataclass(frozen=True)
class ExtendedVe:
    """An extended model's VE (`model ve --model`): the base model's, the factor the
    sensor effects scale the IA vibration by, each effect's change, and the total."""

    base_ve_g: np.ndarray
    sensor_rms_factor: np.ndarray
    effects: Dict[str, np.ndarray]
    ve_g: np.ndarray


def ve(
    passport: PassportLike,
    al3_g: ArrayLike,
    al1_g: ArrayLike = 0.0,
    al2_g: ArrayLike = 0.0,
    *,
    mode: str = "exact",
    model=None,
    psd: Optional[Union[str, "os.PathLike[str]"]] = None,
    **vibration: Optional[ArrayLike],
) -> Union[VeComponents, ExtendedVe]:
    """The VE of a unit for each condition (`vibrocomp model ve`).

    The flight acceleration `al1_g, al2_g, al3_g` and the vibration (`ab1_g .. ab3_g`,
    `freq_hz`, `phase31_deg`, `phase32_deg`, `sigma1_g .. sigma3_g`, `cov31_g2`,
    `cov32_g2`, `kurtosis3`) broadcast together. `mode`: `exact`, `paper` or
    `as-published`; `model`: an extended model (`vibrocomp.Model` or its file), whose
    mode wins; `psd`: a band PSD file for the random part instead of the sigmas.
    """
    named = _named(vibration, al1_g=al1_g, al2_g=al2_g, al3_g=al3_g)
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
class Stages:
    """The compensation stages of [P2 (17)-(20)] (`vibrocomp model compensate`), g:
    the first approximation a(1), the main error removed a(2), the deterministic VE
    removed a(3), the random VE removed a(4), and the three corrections."""

    a1_g: np.ndarray
    a2_g: np.ndarray
    a3_g: np.ndarray
    a4_g: np.ndarray
    main_g: np.ndarray
    det_g: np.ndarray
    rand_g: np.ndarray


@dataclass(frozen=True)
class ExtendedStages(Stages):
    """[`Stages`] under an extended model: the sensor factor, each effect's VE at a(1),
    and a(4) with the effects removed (the compensator service's output)."""

    sensor_rms_factor: np.ndarray = None  # type: ignore[assignment]
    effects: Dict[str, np.ndarray] = None  # type: ignore[assignment]
    a4_extended_g: np.ndarray = None  # type: ignore[assignment]


def compensate(
    passport: PassportLike,
    reading_g: ArrayLike,
    reading1_g: ArrayLike = 0.0,
    reading2_g: ArrayLike = 0.0,
    *,
    mode: str = "exact",
    model=None,
    psd: Optional[Union[str, "os.PathLike[str]"]] = None,
    **vibration: Optional[ArrayLike],
) -> Union[Stages, ExtendedStages]:
    """The compensation of mean readings (`vibrocomp model compensate`).

    `reading_g` is the unit's output over its nominal scale factor (U/K1, g);
    `reading1_g`, `reading2_g` the flight acceleration along OA and PA from the
    triad's other units. The vibration and `mode`, `model`, `psd` as for [`ve`].
    """
    named = _named(vibration, reading_g=reading_g, reading1_g=reading1_g, reading2_g=reading2_g)
    cols, shape = _columns(named)
    psd_arg = None if psd is None else os.fspath(psd)
    out = _native.compensate(_spec(passport), cols, mode, _model_arg(model), psd_arg)
    effects = {k: _shaped(v, shape) for k, v in out.pop("effects").items()}
    values = {k: _shaped(v, shape) for k, v in out.items()}
    if model is not None:
        return ExtendedStages(effects=effects, **values)
    return Stages(**values)


def _named(vibration: Dict[str, Optional[ArrayLike]], **flight) -> Dict[str, Optional[ArrayLike]]:
    unknown = sorted(set(vibration) - set(_VIBRATION_DEFAULTS))
    if unknown:
        raise TypeError(
            f"unknown vibration argument(s) {', '.join(unknown)}: "
            f"expected {', '.join(_VIBRATION_DEFAULTS)}"
        )
    named: Dict[str, Optional[ArrayLike]] = dict(_VIBRATION_DEFAULTS)
    named.update(vibration)
    named.update(flight)
    return named


@dataclass(frozen=True)
class Requirement:
    """One allowed modulus (MODEL.md section 10): the coefficient and term, its key in
    a passport file, its share of D*, its VE per unit coefficient (g), the allowed
    modulus in passport units (None: the term vanishes here) and that unit."""

    coefficient: str
    passport_key: str
    share: float
    ve_per_unit_g: float
    allowed: Optional[float]
    unit: str


@dataclass(frozen=True)
class Requirements:
    """`vibrocomp require --json`."""

    mode: str
    dstar_g: float
    requirements: List[Requirement]

    def to_dict(self) -> dict:
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
    mode: str = "paper",
) -> Requirements:
    """The allowed moduli of the passport coefficients for a VE budget `dstar_g`
    (`vibrocomp require`; `mode` `paper` or `exact`)."""
    d = json.loads(
        _native.require(float(dstar_g), float(al3_g), (float(ab1_g), float(ab2_g), float(ab3_g)),
                        float(sigma3_g), mode)
    )
    return Requirements(
        mode=d["mode"],
        dstar_g=d["dstar_g"],
        requirements=[Requirement(**r) for r in d["requirements"]],
    )
