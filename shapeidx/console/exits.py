"""Exit statuses of the ``shapeidx`` command, one meaning each, and errors as one line.

docs/cli.md has the table for users; :data:`EXIT_STATUSES` is its source and
tests/test_cli_scripting.py checks that the two agree.
"""

from __future__ import annotations

import errno
import re

#: Success (also a build in which some files failed, without ``--strict``; also a closed
#: output pipe, as in ``shapeidx query ... | head -1``).
OK = 0
#: The command could not do what was asked: a bad input file, a missing or unusable store,
#: the environment (disk full, read-only file system). One line on stderr says which.
ERROR = 1
#: A usage error: an unknown option, a bad option value, a missing argument.
USAGE = 2
#: ``build --strict`` (or ``check``'s twin for builds): the store holds failed files.
FAILED_FILES = 3
#: Another build holds the store's lock (and ``--wait`` was not given or ran out of time).
LOCKED = 4
#: The store is damaged (checksums, offsets, structure; ``shapeidx check`` names what) or,
#: for ``check --files``, out of step with its files.
DAMAGED = 5
#: A bug in shapeidx: one line, the traceback with ``SHAPEIDX_DEBUG=1``. Please report it.
INTERNAL = 70
#: Interrupted (Ctrl-C, SIGTERM); a build commits the work done before it exits.
INTERRUPTED = 130

EXIT_STATUSES = {
    OK: "success (a build in which files failed is still a success without --strict; a closed output pipe too)",
    ERROR: "error: a bad input file, a missing or unusable store, the environment (disk full, read-only, no permission)",
    USAGE: "usage error: unknown option, bad option value, missing argument",
    FAILED_FILES: "build --strict: the store holds failed files",
    LOCKED: "another build holds the store's lock (without --wait, or --wait-timeout ran out)",
    DAMAGED: "the store is damaged (check names the problems; build refuses it without --repair), "
    "or check --files found entries whose files changed",
    INTERNAL: "internal error (a bug): run again with SHAPEIDX_DEBUG=1 for the traceback",
    INTERRUPTED: "interrupted (Ctrl-C or SIGTERM); a build commits its work first",
}

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


def status_of(exc: BaseException) -> int:
    """The exit status for an exception that reached the command line."""
    from ..errors import ShapeidxError, StoreDamagedError, StoreLockedError

    if isinstance(exc, StoreLockedError):
        return LOCKED
    if isinstance(exc, StoreDamagedError):
        return DAMAGED
    if isinstance(exc, ShapeidxError):
        return ERROR
    if isinstance(exc, KeyboardInterrupt):
        return INTERRUPTED
    if environment_reason(exc) is not None:
        return ERROR
    return INTERNAL
