"""A vibrocomp MCAP log (docs/logs.md), read one stream at a time into numpy arrays.

    log = vibrocomp.Log("vibrocomp-demo/session.mcap")
    log.topics                       # {"/accel": "vibrocomp.v1.AccelBlock", ...}
    accel = log.stream("/accel")     # reads that channel only
    accel.samples["t_ns"], accel.samples["output_v"]      # (N,), (N, 3)
    accel.to_frame()                 # a pandas DataFrame, one row per sample

Block streams (`/accel`, `/vib`, `/truth` the reference, `/compensated` the stages)
give one row per sample on the data timeline (`t_ns = t0_ns + i * sample_period_ns`)
in `samples`, with the row of its block in `samples["block"]`, and one row per block
in `rows`. The others (`/estimate`, heartbeats, log lines, the view channels
`/view/...`) give one row per message in `rows`. Every row carries the message's
MCAP `log_time_ns` (the data time), `publish_time_ns` (the receive time) and
`sequence`. Array slots beyond a message's count (an estimate's tones and bands) are
NaN. A stream is read when asked for, and only its channel's messages are decoded.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Union

import numpy as np

from . import _vibrocomp as _native
from ._arrays import arrays as _arrays


@dataclass(frozen=True)
class Stream:
    """One stream of a log: its topic, its message type (schema name), its samples
    (block streams) and its rows (blocks or messages), each a dict of arrays."""

    topic: str
    kind: str
    samples: Optional[Dict[str, np.ndarray]] = field(repr=False)
    rows: Dict[str, np.ndarray] = field(repr=False)

    def __len__(self) -> int:
        return _length(self.rows)

    def to_frame(self, what: str = "samples"):
        """A pandas DataFrame of the samples (`what="samples"`, block streams) or of the
        rows (`what="rows"`); an (N, 3) column becomes three columns `name[0..2]`, an
        (N, k, 3) one `name[j][u]`."""
        import pandas as pd

        table = self.samples if what == "samples" and self.samples is not None else self.rows
        columns: Dict[str, object] = {}
        for name, values in table.items():
            if isinstance(values, list):
                columns[name] = values
                continue
            a = np.asarray(values)
            if a.ndim == 1:
                columns[name] = a
            else:
                flat = a.reshape(a.shape[0], -1)
                for j, index in enumerate(np.ndindex(*a.shape[1:])):
                    columns[name + "".join(f"[{i}]" for i in index)] = flat[:, j]
        return pd.DataFrame(columns)


def _length(table: Dict[str, object]) -> int:
    for v in table.values():
        return len(v)  # type: ignore[arg-type]
    return 0


@dataclass(frozen=True)
class Attachment:
    """A file the log carries (a passport, a service's configuration, a scenario, a
    rig's CSV header)."""

    name: str
    media_type: str
    data: bytes = field(repr=False)

    @property
    def text(self) -> str:
        return self.data.decode("utf-8")

    def toml(self) -> dict:
        """A TOML attachment as a dict."""
        return json.loads(_native.LogFile.toml_to_json(self.text, self.name))


class Log:
    """A vibrocomp MCAP log. Opening it reads and checks its summary only; each
    stream is read when asked for (`stream`), attachments when read."""

    def __init__(self, path: Union[str, "os.PathLike[str]"]):
        self.path = os.fspath(path)
        self._native = _native.LogFile(self.path)
        self._info: Optional[dict] = None

    def __repr__(self) -> str:
        return f"Log({self.path!r})"

    @property
    def info(self) -> dict:
        """`vibrocomp log info --json`: channels, counts, time span, losses, metadata
        and attachments."""
        if self._info is None:
            self._info = json.loads(self._native.info())
        return self._info

    @property
    def topics(self) -> Dict[str, str]:
        """Every channel's topic and message type (from the summary: no chunk read)."""
        return dict(self._native.topics())

    @property
    def metadata(self) -> Dict[str, Dict[str, str]]:
        """The metadata records by name (a later record of the same name wins)."""
        return {name: dict(entries) for name, entries in self._native.metadata()}

    @property
    def rig(self) -> Dict[str, str]:
        """The rig's description: an imported log's `rig` metadata (the rig file, its
        reference, the sensor settings), a simulated one's `scenario`; {} if neither."""
        meta = self.metadata
        return meta.get("rig") or meta.get("scenario") or {}

    @property
    def attachments(self) -> Dict[str, Attachment]:
        """The attachments by name, with their bytes (read now)."""
        return {
            name: Attachment(name, media_type, bytes(data))
            for name, media_type, data in self._native.attachments()
        }

    def stream(self, topic: str) -> Stream:
        """The stream on `topic`, read now (only its channel's messages are decoded)."""
        kind, samples, rows = self._native.read(topic)
        return Stream(
            topic=topic,
            kind=kind,
            samples=None if samples is None else _arrays(samples),
            rows=_arrays(rows),
        )

    def streams(self) -> List[str]:
        """The topics, in the log's order."""
        return list(self.topics)
