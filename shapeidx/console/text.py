"""Text that goes into log lines: file names that cannot forge lines, reasons without byte reprs."""

from __future__ import annotations

import re
import time

_CONTROL = re.compile(r"[\x00-\x1f\x7f\x80-\x9f]")
_BYTES_REPR = re.compile(r"""\bb(['"])((?:\\.|(?!\1).)*)\1""")


def printable_name(name: str) -> str:
    """``name`` with control characters (newline, escape, ...) shown as ``\\n``, ``\\x1b``.

    A file name may hold any byte but ``/`` and NUL; printed raw, a newline in it would
    start a forged log line.
    """
    def escape(match: re.Match) -> str:
        char = match.group(0)
        return {"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(char, f"\\x{ord(char):02x}")

    return _CONTROL.sub(escape, str(name))


def plain_reason(text: str) -> str:
    """A failure reason as a user reads it: Python's ``b'...'`` reprs become ``'...'``,
    control characters are escaped, all on one line."""
    text = _BYTES_REPR.sub(lambda m: "'" + m.group(2) + "'", str(text))
    return printable_name(" ".join(text.split()))


def timestamp() -> str:
    """Local time with its UTC offset, to the second: ``2026-12-01T18:02:11+0000``."""
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
