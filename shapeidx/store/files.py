"""The files of a store and how they are written so that a kill at any moment loses nothing.

    STORE                    the main file: a complete snapshot, only ever replaced by rename
    STORE.journal/           batches committed since the main file was last written
        batch-0000000007.h5    same entry layout, plus /touched and /removed
    STORE.lock               held (flock) by the one build that may write

No file a reader may open is ever written in place: every file is written under a temporary
name, flushed to disk, and renamed into place (atomic on POSIX).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import h5py

_BATCH_NAME = re.compile(r"^batch-(\d{10})\.h5$")


def write_atomically(final: Path, fill) -> None:
    """Write an HDF5 file under a temporary name, flush it to disk, rename it to ``final``.

    ``fill(h5file)`` writes the content. A reader sees the old file or the new one, never
    a partial one, whenever this process is killed.
    """
    tmp = final.with_name(f"{final.name}.tmp-{os.getpid()}")
    try:
        with h5py.File(tmp, "w", libver="latest") as f:
            fill(f)
        _fsync_path(tmp)
        os.replace(tmp, final)
    except BaseException as exc:
        _unlink_quietly(tmp)
        reason = _environment_reason(exc)
        if reason is not None:  # disk full, read-only, quota: the old files are untouched
            from ..errors import StoreError

            raise StoreError(f"cannot write {final}: {reason} (nothing was changed: the store is as it was)") from None
        raise
    _fsync_path(final.parent)


def _unlink_quietly(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def _environment_reason(exc: BaseException) -> str | None:
    from ..oserrors import environment_reason

    return environment_reason(exc)


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def journal_dir(store: Path) -> Path:
    return store.with_name(store.name + ".journal")


def lock_path(store: Path) -> Path:
    return store.with_name(store.name + ".lock")


def batch_files(store: Path) -> list[tuple[int, Path]]:
    """Committed batches of the journal as (seq, path), oldest first."""
    folder = journal_dir(store)
    if not folder.is_dir():
        return []
    found = []
    for child in folder.iterdir():
        match = _BATCH_NAME.match(child.name)
        if match:
            found.append((int(match.group(1)), child))
    return sorted(found)


def remove_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass


def glob_escape(name: str) -> str:
    """``name`` with glob's special characters quoted."""
    return re.sub(r"([*?\[])", r"[\1]", name)
