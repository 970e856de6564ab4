"""Exceptions that carry a one-line, user-facing message."""

from __future__ import annotations

import os


class ShapeidxError(Exception):
    """Base class of every error shapeidx reports to its user as one line."""


class LoadError(ShapeidxError):
    """A file that cannot be turned into a part: names the file, the reason, and the line if known.

    ``str(err)`` is the one-line message, e.g. ``parts/a.wrl:12: unexpected '}'``.
    """

    def __init__(self, path: str | os.PathLike | None, reason: str, line: int | None = None):
        self.path = None if path is None else os.fspath(path)
        self.reason = reason
        self.line = line
        super().__init__(str(self))

    def __str__(self) -> str:
        where = self.path if self.path is not None else "<input>"
        if self.line is not None:
            where = f"{where}:{self.line}"
        return f"{where}: {self.reason}"


class StoreError(ShapeidxError):
    """The signature store cannot be used as asked (missing, locked, other parameters, ...)."""


class StoreLockedError(StoreError):
    """Another build holds the store's lock (and ``--wait`` was not given, or ran out)."""


class StoreDamagedError(StoreError):
    """The store's files fail their checks (checksums, offsets, structure): see ``shapeidx check``."""
