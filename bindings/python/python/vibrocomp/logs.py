"""A vibrocomp MCAP log (docs/logs.md), read one stream at a time into numpy arrays.

    log = vibrocomp.Log("vibrocomp-demo/session.mcap")
    log.topics                       # {"/accel": "vibrocomp.v1.AccelBlock", ...}
    accel = log.stream("/accel")     # reads that channel only
    accel.samples["t_ns"], accel.samples["output_v"]      # (N,) int64, (N, 3) float64
    accel.to_frame()                 # a pandas DataFrame, one row per sample
    accel.to_frame().output_v_0      # its columns are identifiers

Block streams (`/accel`, `/vib`, `/truth` the reference, `/compensated` the stages)
give one row per sample on the data timeline (`t_ns = t0_ns + i * sample_period_ns`)
in `samples`, with the row of its block in `samples["block"]`, and one row per block
in `rows`. The others (`/estimate`, heartbeats, log lines, the view channels
`/view/...`) give one row per message in `rows` (and no `samples`: an empty dict).
Every row carries the message's MCAP `log_time_ns` (the data time),
`publish_time_ns` (the receive time) and `sequence`. Array slots beyond a message's
count (an estimate's tones and bands) are NaN. A stream is read when asked for, and
only its channel's messages are decoded.

Integers are int64, so that the difference of two times (ns since the log's epoch) or
two counters is negative where it should be; the `flags` bit fields are uint32, as
sent. A value an int64 cannot hold (past 2^63 - 1 ns, 292 years after the epoch) is
refused with a `VibrocompError` naming the message, the field and the value.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Union

import numpy as np
import numpy.typing as npt

from . import _vibrocomp as _native
from ._arrays import arrays as _arrays

if TYPE_CHECKING:
    import pandas as pd

Column = npt.NDArray[Any]
"""A stream's column: an array with one row per sample or message (float64, int64,
uint32 for the `flags` bit fields, bool, or str: a log line's text)."""


@dataclass(frozen=True)
class Stream:
    """One stream of a log: its `topic`, its message type (`kind`, the schema name),
    its `samples` (block streams: one row per sample; empty for the others) and its
    `rows` (one per block or message), each a dict of columns by name (module
    docstring; docs/python.md, "Logs")."""

    topic: str
    kind: str
    samples: Dict[str, Column] = field(repr=False)
    rows: Dict[str, Column] = field(repr=False)

    def __len__(self) -> int:
        """The number of rows (blocks or messages)."""
        return _length(self.rows)

    def to_frame(self, what: str = "samples") -> "pd.DataFrame":
        """A pandas DataFrame of the samples (`what="samples"`, block streams) or of the
        rows (`what="rows"`). An (N, 3) column becomes three columns `name_0`,
        `name_1`, `name_2`, an (N, k, 3) one `name_j_u`: every column name is an
        identifier (`frame.a4_g_2`)."""
        import pandas as pd

        if what not in ("samples", "rows"):
            raise ValueError(f'what = {what!r}: must be "samples" or "rows"')
        table = self.samples if what == "samples" and self.samples else self.rows
        columns: Dict[str, Any] = {}
        for name, values in table.items():
            a = np.asarray(values)
            if a.ndim == 1:
                columns[name] = a
            else:
                flat = a.reshape(a.shape[0], -1)
                for j, index in enumerate(np.ndindex(*a.shape[1:])):
                    columns[name + "".join(f"_{i}" for i in index)] = flat[:, j]
        return pd.DataFrame(columns)


def _length(table: Dict[str, Column]) -> int:
    for v in table.values():
        return len(v)
    return 0


@dataclass(frozen=True)
class Attachment:
    """A file the log carries (a passport, a service's configuration, a scenario, a
    rig's CSV header): its `name`, its `media_type` and its bytes (`data`)."""

    name: str
    media_type: str
    data: bytes = field(repr=False)

    @property
    def text(self) -> str:
        """The attachment as UTF-8 text."""
        return self.data.decode("utf-8")

    def toml(self) -> Dict[str, Any]:
        """A TOML attachment as a dict (`VibrocompError` if it is not TOML)."""
        table: Dict[str, Any] = json.loads(_native.LogFile.toml_to_json(self.text, self.name))
        return table


class Log:
    """A vibrocomp MCAP log. Opening it reads and checks its summary only; each
    stream is read when asked for (`stream`), attachments when read."""

    def __init__(self, path: Union[str, "os.PathLike[str]"]) -> None:
        """Opens the log at `path` and checks its summary (`VibrocompError` for a file
        that is not a finished MCAP log)."""
        self.path: str = os.fspath(path)
        self._native = _native.LogFile(self.path)
        self._info: Optional[Dict[str, Any]] = None

    def __repr__(self) -> str:
        return f"Log({self.path!r})"

    @property
    def info(self) -> Dict[str, Any]:
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
        """The stream on `topic` (`"/accel"`), read now: only its channel's messages are
        decoded. `VibrocompError` for a topic the log has no channel on, or a message
        that cannot be read."""
        kind, samples, rows = self._native.read(topic)
        return Stream(
            topic=topic,
            kind=kind,
            samples={} if samples is None else _arrays(samples),
            rows=_arrays(rows),
        )

    def streams(self) -> List[str]:
        """The topics, in the log's order."""
        return list(self.topics)
