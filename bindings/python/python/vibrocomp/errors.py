"""Errors of the package: every failure of the native code is a `VibrocompError`.

It carries what the command line's `--json` error object carries (README,
"Conventions"): the whole message, each cause on its own (`chain`), and where a file
is concerned its `file`, and where known the `line` (1-based), `column` and `key`
(dotted path) of the problem; those are None when the error has none.

Its subclasses also derive from the built-in exception a caller would catch for the
same failure, so that ``except FileNotFoundError`` works as with `open()`:

- `MissingFileError` (`FileNotFoundError`): an input that does not exist;
- `FilePermissionError` (`PermissionError`): one that may not be read or written;
- `FileSystemError` (`OSError`): any other failure of the file system;
- `InvalidInputError` (`ValueError`): a value, a table row, a request the rules refuse;
  - `ConfigError`: a configuration, passport or model file's problem (its `key`);
  - `LogFormatError`: what is not an MCAP log, or a damaged one.

A failure that is none of these (a computation the model cannot make) is a plain
`VibrocompError`. `str(e)` is the command line's message in every case.
"""

from __future__ import annotations

import errno as _errno
from typing import List, Optional, Sequence

__all__ = [
    "VibrocompError",
    "MissingFileError",
    "FilePermissionError",
    "FileSystemError",
    "InvalidInputError",
    "ConfigError",
    "LogFormatError",
]


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
        """`message`: the whole message; `chain`: each cause, outermost first; `file`,
        `line` (1-based), `column` (1-based, in characters), `key` (dotted path): where
        the problem is, None where not known."""
        super().__init__(message)
        self.message: str = message
        self.chain: List[str] = list(chain)
        self.file = file
        self.line = line
        self.column = column
        self.key = key

    def __str__(self) -> str:
        # `OSError.__str__` would put "[Errno 2]" and the file name in front.
        return self.message

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


class _OSFailure(VibrocompError):
    """A `VibrocompError` that is also an `OSError`: `errno`, `strerror` and `filename`
    set as `open()` sets them (`filename` is `file`)."""

    _errno: Optional[int] = None

    def __init__(self, message: str, chain: Sequence[str] = (), file: Optional[str] = None,
                 line: Optional[int] = None, column: Optional[int] = None, key: Optional[str] = None):
        """As `VibrocompError`'s; `errno`, `strerror` (the last cause) and `filename`
        (`file`) set too."""
        super().__init__(message, chain, file, line, column, key)
        self.errno = self._errno
        self.strerror = self.chain[-1] if self.chain else message
        self.filename = file


class MissingFileError(_OSFailure, FileNotFoundError):
    """An input file (or folder) that does not exist."""

    _errno = _errno.ENOENT


class FilePermissionError(_OSFailure, PermissionError):
    """A file the process may not read or write."""

    _errno = _errno.EACCES


class FileSystemError(_OSFailure, OSError):
    """Another failure of the file system (an I/O error, a folder where a file was
    expected)."""


class InvalidInputError(VibrocompError, ValueError):
    """A value, a table's row or cell, or a request that the rules refuse."""


class ConfigError(InvalidInputError):
    """A configuration, passport or model file (or text) with a problem: an unknown
    key, a value outside its rule; `file`, `line` and `key` say where."""


class LogFormatError(InvalidInputError):
    """A file that is not an MCAP log, or a damaged one (the message says whether
    `vibrocomp log recover` can rewrite it)."""

