"""Arrays from the native half: `(dtype, shape, bytearray)` viewed by numpy without a
copy (writable: the bytearray is the array's memory); columns to it as float64 bytes
(bindings/python/src/arrays.rs says why there is no numpy crate)."""

from typing import Any

import numpy as np


def array(t: Any) -> Any:
    """A native `(dtype, shape, bytearray)` as a numpy array; anything else as it is
    (a list of strings)."""
    if isinstance(t, tuple) and len(t) == 3:
        dtype, shape, buf = t
        return np.frombuffer(buf, dtype=dtype).reshape(shape)
    return t


def arrays(d: dict) -> dict:
    return {k: array(v) for k, v in d.items()}


def column_bytes(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()
