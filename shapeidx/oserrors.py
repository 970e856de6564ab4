"""Operating-system errors that are the environment's (a full disk, a read-only mount), not bugs.

The store's writer turns them into one-line :class:`~shapeidx.errors.StoreError`; the command
line prints any that reach it as one line with status 1 (see :mod:`shapeidx.console.exits`).
"""

from __future__ import annotations

import errno
import re

#: errno values that say "the environment", not "a bug": one clean line, status ERROR.
ENVIRONMENT_ERRNOS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EIO: "input/output error",
    errno.EFBIG: "file too large for the file system (or ulimit -f)",
    errno.ENAMETOOLONG: "file name too long",
    errno.EMFILE: "too many open files",
}
_ERRNO_IN_TEXT = re.compile(r"errno\s*=\s*(\d+)")


def os_error_errno(exc: BaseException) -> int | None:
    """The errno of an OSError, also of h5py's, which keeps it only in its message text."""
    if not isinstance(exc, OSError):
        return None
    if exc.errno:
        return exc.errno
    match = _ERRNO_IN_TEXT.search(str(exc))
    return int(match.group(1)) if match else None


def environment_reason(exc: BaseException) -> str | None:
    """``"no space left on the device"`` etc. when ``exc`` is an environment error, else None."""
    number = os_error_errno(exc)
    if number in ENVIRONMENT_ERRNOS:
        return ENVIRONMENT_ERRNOS[number]
    if isinstance(exc, OSError) and number is None:
        text = str(exc).lower()
        for known in ("no space left", "read-only file system", "quota exceeded", "permission denied"):
            if known in text:
                return known.replace("no space left", "no space left on the device")
    return None
