"""Exit statuses of the ``shapeidx`` command, one meaning each, and errors as one line.

docs/cli.md has the table for users; :data:`EXIT_STATUSES` is its source and
tests/test_cli_scripting.py checks that the two agree.
"""

from __future__ import annotations

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
#: No answer: the question was sound but nothing answers it (a query's filters or
#: ``--max-distance`` leave no hit, a store with no entry yet). One line on stderr says why.
#: Not 1 (grep's "no match"): 1 already means "could not run" in every command, and a
#: script must be able to tell an empty answer from a failure.
NO_ANSWER = 6
#: ``check-new``: a new part is already in the store (a duplicate of tier identical, same or
#: converted). Distinct from 1 (could not check) and 6 (no answer), so a gate can tell them apart.
DUPLICATES = 7
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
    NO_ANSWER: "no answer: the query's filters or --max-distance leave no hit, or the store has no entry yet"
    " (stderr says which)",
    DUPLICATES: "check-new: a new part is already in the store (a duplicate of tier identical, same or converted)",
    INTERNAL: "internal error (a bug): run again with SHAPEIDX_DEBUG=1 for the traceback",
    INTERRUPTED: "interrupted (Ctrl-C or SIGTERM); a build commits its work first",
}

from ..oserrors import environment_reason  # noqa: F401 (re-exported for the command line)


def status_of(exc: BaseException) -> int:
    """The exit status for an exception that reached the command line."""
    from ..errors import NoAnswer, ShapeidxError, StoreDamagedError, StoreLockedError, UsageError

    if isinstance(exc, UsageError):
        return USAGE
    if isinstance(exc, NoAnswer):
        return NO_ANSWER
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
