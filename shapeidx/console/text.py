"""Text that goes into log lines: reasons without byte reprs, times (names: errors.printable)."""

from __future__ import annotations

import re
import time

from ..errors import printable

_BYTES_REPR = re.compile(r"""\bb(['"])((?:\\.|(?!\1).)*)\1""")


def plain_reason(text: str) -> str:
    """A failure reason as a user reads it: Python's ``b'...'`` reprs become ``'...'``,
    control characters are escaped, all on one line."""
    text = _BYTES_REPR.sub(lambda m: "'" + m.group(2) + "'", str(text))
    return printable(" ".join(text.split()))


def timestamp() -> str:
    """Local time with its UTC offset, to the second: ``2026-12-01T18:02:11+0000``."""
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
