"""Arrays from the native half: `(dtype, shape, bytearray)` viewed by numpy without a
copy (writable: the bytearray is the array's memory); columns to it as float64 bytes
(bindings/python/src/arrays.rs says why there is no numpy crate)."""

from typing import Any, Dict

import numpy as np
import numpy.typing as npt


def array(t: Any) -> npt.NDArray[Any]:
    """A native `(dtype, shape, bytearray)` as a numpy array; a list of strings (a log
    line's text) as an array of str."""
    if isinstance(t, tuple) and len(t) == 3:
        dtype, shape, buf = t
        return np.frombuffer(buf, dtype=dtype).reshape(shape)
    return np.asarray(t, dtype=np.str_)


def arrays(d: Dict[str, Any]) -> Dict[str, npt.NDArray[Any]]:
    """Every value of a native dict as [`array`]."""
    return {k: array(v) for k, v in d.items()}


def column_bytes(a: npt.ArrayLike) -> bytes:
    """An array's values as the native-endian float64 bytes the native half reads."""
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()
