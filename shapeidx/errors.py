"""Exceptions that carry a one-line, user-facing message."""

from __future__ import annotations

import os
import re

# C0 and C1 control characters, DEL, Unicode line and paragraph separators, the bidirectional
# controls (U+202E in "evil\u202elrw.wrl" shows "evilwrl.wrl": a name that lies about itself),
# and the lone surrogates by which Python stands for bytes of a file name that are not UTF-8.
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069\u2028\u2029\ud800-\udfff]")
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(match: re.Match) -> str:
    char = match.group()
    if char in _NAMED:
        return _NAMED[char]
    code = ord(char)
    if 0xDC80 <= code <= 0xDCFF:  # surrogateescape: the raw byte of a non-UTF-8 name
        return f"\\x{code - 0xDC00:02x}"
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def printable(text: object) -> str:
    """``text`` safe to print as (part of) one log line.

    Control characters (a newline or a carriage return in a file name could forge a line
    of its own, an escape sequence could rewrite the terminal) become ``\\n``, ``\\r``,
    ``\\t``, ``\\xNN`` or ``\\uNNNN`` (so do the bidirectional controls, which would show
    a name reordered); bytes of a file name that are not UTF-8 become
    ``\\xNN`` (printing them raw would fail with UnicodeEncodeError). Backslashes are left
    alone: a Windows path stays readable. Other text is returned unchanged.
    """
    text = str(text)
    return _UNPRINTABLE.sub(_escape, text) if _UNPRINTABLE.search(text) else text


def quoted_bytes(data: bytes) -> str:
    """Bytes of a file quoted in a message: UTF-8 text as it is, every byte that is not UTF-8 as
    ``\\xNN`` (never U+FFFD, which hides what the byte was): ``b"1 0 \\xe9"`` -> ``'1 0 \\xe9'``."""
    return "'" + printable(data.decode("utf-8", errors="backslashreplace")) + "'"


_BYTES_REPR = re.compile(r"""\bb(['"])((?:\\.|(?!\1).)*)\1""")


def plain_reason(text: str) -> str:
    """A failure reason as a user reads it: Python's ``b'...'`` reprs become ``'...'``,
    control characters are escaped, all on one line."""
    text = _BYTES_REPR.sub(lambda m: "'" + m.group(2) + "'", str(text))
    return printable(" ".join(text.split()))


#: What a reason says when a reader met something its own checks did not foresee (an internal
#: exception, said in words): the tests and scripts/fuzz.py count such reasons as gaps to close.
UNFORESEEN = "which shapeidx's checks did not foresee"

_EXCEPTION_WORDS = (
    (OverflowError, "a number too large to compute with"),
    (ZeroDivisionError, "values that lead to a division by zero"),
    (ArithmeticError, "values that lead to a numeric failure"),
    (UnicodeError, "text that is not in the expected encoding"),
    (LookupError, "a reference to an element that does not exist"),
    (ValueError, "a value of the wrong form or out of range"),
    (TypeError, "a value of the wrong kind"),
)


def exception_in_words(exc: BaseException) -> str:
    """What an unforeseen exception says about the input, in words without its class name or
    message (``OverflowError: Python int too large to convert to C long`` becomes "a number too
    large to compute with"); always ends with :data:`UNFORESEEN` and a request to report it."""
    words = next((w for kind, w in _EXCEPTION_WORDS if isinstance(exc, kind)), "something")
    return f"{words}, {UNFORESEEN} (please report the file)"


def timestamp() -> str:
    """Local time with its UTC offset, to the second: ``2026-12-01T18:02:11+0000``."""
    import time

    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


class ShapeidxError(Exception):
    """Base class of every error shapeidx reports to its user as one line.

    ``str(err)`` passes the message through :func:`printable`, so that a file name or a
    reason holding a newline or another control character still prints as one line.
    """

    def __str__(self) -> str:
        return printable(super().__str__())


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
        where = printable(self.path) if self.path is not None else "<input>"
        if self.line is not None:
            where = f"{where}:{self.line}"
        return f"{where}: {printable(self.reason)}"


class OutOfMemory(LoadError):
    """A file whose reading or cleaning ran out of memory (a MemoryError, often at the
    worker's memory limit). The process that saw it should not be trusted with another file:
    a native library may have been left half-way through an allocation."""


class StoreError(ShapeidxError):
    """The signature store cannot be used as asked (missing, locked, other parameters, ...)."""


class StoreLockedError(StoreError):
    """Another build holds the store's lock (and ``--wait`` was not given, or ran out)."""


class StoreDamagedError(StoreError):
    """The store's files fail their checks (checksums, offsets, structure): see ``shapeidx check``."""


class UsageError(ShapeidxError):
    """A request that cannot be meant as given (a ``--where`` on a key the store does not
    have, a format that does not exist): the command line exits with its usage status, 2."""


class NoAnswer(ShapeidxError):
    """A sound question that nothing answers: filters that match no entry, hits all beyond
    ``--max-distance``, a store with no entry yet. ``str()`` says which; the command line
    exits with status 6 (docs/cli.md), so a script tells an empty answer from a failure."""
