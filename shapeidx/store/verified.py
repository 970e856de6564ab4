"""Which main file a build has already verified: ``STORE/verified``.

A build refuses a damaged store before it changes anything, and so used to read and check
every chunk of the main file at its start: 40-54 s at 10^6 entries, whatever the change.
The main file is never written in place (a merge or a repair writes a new one and renames
it over the old), so once its checksums have passed, the same file, unchanged, need not be
read again. ``STORE/verified`` records the main file's identity as ``os.stat`` gives it
(device, inode, size, modification and change times, in ns) when it was last verified, or
when this store's own merge wrote it (from checked reads: HDF5 computes every chunk's
Fletcher-32 as it writes). A build whose main file still has that identity skips the full
read; any write to the file (even one byte through the file system), a copy, a restore or
a rename of another file into place changes the identity, and the next build verifies the
whole file again.

What this gives up: damage that reaches the disk without passing through the file system
(a silently failing disk) is no longer found when a build starts but when the damaged
bytes are read (every read checks its Fletcher-32 or CRC-32: a query, a merge, ``check``);
so is a write that keeps the size and lands within the file system's timestamp tick of the
recording (a few milliseconds on ext4), which only a process writing into the store's main
file behind shapeidx's back could make.

The record is only ever a shortcut: a missing, stale or unreadable one means "verify".
It is written under the store's lock, atomically (a temporary file renamed into place).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .files import main_file

_FIELDS = ("st_dev", "st_ino", "st_size", "st_mtime_ns", "st_ctime_ns")


def verified_path(store: Path) -> Path:
    return Path(store) / "verified"


def identity(store: Path) -> dict | None:
    """The main file's identity as ``os.stat`` gives it (None: it cannot be stat'ed)."""
    try:
        stat = os.stat(main_file(store))
    except OSError:
        return None
    return {name: int(getattr(stat, name)) for name in _FIELDS}


def is_verified(store: Path) -> bool:
    """Whether the main file is the very file last recorded as verified."""
    try:
        from ..io.base import read_regular

        recorded = json.loads(read_regular(verified_path(store), 4096))
    except (OSError, ValueError, RecursionError):
        return False
    now = identity(store)
    return now is not None and isinstance(recorded, dict) and all(recorded.get(k) == now[k] for k in _FIELDS)


def mark_verified(store: Path, before: dict | None = None) -> None:
    """Record the main file as verified (the caller holds the lock and checked it).

    ``before``: its identity when the check began; nothing is recorded if it changed since.
    """
    now = identity(store)
    if now is None or (before is not None and before != now):
        return
    record = verified_path(store)
    tmp = record.with_name(f"{record.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(json.dumps(now) + "\n")
        os.replace(tmp, record)
    except OSError:  # a shortcut only: without it, the next build verifies again
        try:
            tmp.unlink()
        except OSError:
            pass


def forget_verified(store: Path) -> None:
    """Drop the record (the main file is being set aside or rewritten outside a merge)."""
    try:
        verified_path(store).unlink()
    except OSError:
        pass
