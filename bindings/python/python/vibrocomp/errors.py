"""Errors of the package: every failure of the native code is a `VibrocompError`.

It carries what the command line's `--json` error object carries (README,
"Conventions"): the whole message, each cause on its own (`chain`), and where a file
is concerned its `file`, and where known the `line` (1-based), `column` and `key`
(dotted path) of the problem; those are None when the error has none.
"""

from __future__ import annotations

from typing import List, Optional, Sequence


class VibrocompError(Exception):
    """A failure of vibrocomp: bad input (a file, a value, a rule) or a computation
    the model cannot make. `str(e)` is the command line's message."""

    def __init__(
        self,
        message: str,
        chain: Sequence[str] = (),
        file: Optional[str] = None,
        line: Optional[int] = None,
        column: Optional[int] = None,
        key: Optional[str] = None,
    ):
        super().__init__(message)
        self.message: str = message
        self.chain: List[str] = list(chain)
        self.file = file
        self.line = line
        self.column = column
        self.key = key

    def to_dict(self) -> dict:
        """The command line's JSON error object (without its `exit_code`)."""
        d = {"message": self.message, "chain": list(self.chain)}
        for name in ("file", "line", "column", "key"):
            value = getattr(self, name)
            if value is not None:
                d[name] = value
        return d

    def __reduce__(self):
        return (
            type(self),
            (self.message, self.chain, self.file, self.line, self.column, self.key),
        )
