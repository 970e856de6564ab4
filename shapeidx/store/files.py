"""The files of a store and how they are written so that a kill at any moment loses nothing.

A store is one directory, the unit a user copies, moves, archives or deletes (``cp -a``,
``mv``, ``rsync -a``, ``tar``): everything shapeidx keeps about the indexed tree is inside.

    STORE/                   the store (any name; the examples use ``NAME.shapeidx``)
        main.h5              the main file: a snapshot, only ever replaced by rename
        journal/             segments committed since the main file was last written
            batch-0000000007.h5  same entry layout, plus /touched and /removed
        lock                 held (flock) by the one build that may write
        committed            the newest sequence number committed: a missing segment is noticed
        build.json           the last build: running, finished or stopped (shapeidx stats)
        verified             which main file a build last verified (shapeidx.store.verified)
        thumbs/              rendered thumbnails and the similarity calibration (a cache)
        parts/               the sub-parts of the files (``build --parts``): a store of its own,
                             same layout, entries ``FILE#n`` with their parent file

No file a reader may open is ever written in place: every file is written under a temporary
name, flushed to disk, and renamed into place (atomic on POSIX).
"""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path

import h5py

from .shards import owner_of_shard

_BATCH_NAME = re.compile(r"^batch-(\d{10})\.h5$")
#: The folder of a store that holds its sub-parts' store (``build --parts``).
PARTS = "parts"


def parts_store(store) -> Path:
    """The store of ``store``'s sub-parts (``STORE/parts``), which ``build --parts`` writes."""
    return Path(store) / PARTS


def owner_of_parts(store) -> Path | None:
    """The store whose sub-parts ``store`` is (``OWNER/parts``, which ``build OWNER --parts``
    writes), or None for any other store."""
    store = Path(store)
    owner = store.parent
    if store.name != PARTS or owner == store:
        return None
    return owner if any(p.exists() for p in (main_file(owner), lock_path(owner), committed_path(owner))) else None


def build_command(store, root: str | None = None) -> str:
    """The command that builds ``store``: a sub-parts store is built through its owner
    (``build OWNER --parts``): a build into ``OWNER/parts`` itself would fill it with whole files;
    a shard through its sharded store (a build into one shard would put every file in it)."""
    folder, owner = root or "DIR", owner_of_parts(store)
    if owner is not None:
        sharded = owner_of_shard(owner)  # a shard's sub-parts: through the sharded store too
        return f"shapeidx build {folder} --store {sharded if sharded is not None else owner} --parts"
    sharded = owner_of_shard(store)
    return f"shapeidx build {folder} --store {sharded if sharded is not None else store}"


def recovery_commands(store, root: str | None = None) -> tuple[str, str]:
    """(repair, check): the commands that repair and check ``store`` (a sub-parts store through
    its owner: ``build --parts --repair``, ``check --store OWNER``; see :func:`build_command`)."""
    owner = owner_of_parts(store)
    owner = owner_of_shard(store if owner is None else owner) or owner
    return f"{build_command(store, root)} --repair", f"shapeidx check --store {owner if owner is not None else store}"


#: Bytes reserved beyond a write's estimate (HDF5's metadata, chunk indexes).
RESERVE_MARGIN = 1 << 20


def write_atomically(final: Path, fill, estimate: int = 0) -> None:
    """Write an HDF5 file under a temporary name, flush it to disk, rename it to ``final``.

    ``fill(h5file)`` writes the content. A reader sees the old file or the new one, never
    a partial one, whenever this process is killed. ``estimate`` (bytes the file will take
    at most) is reserved on the disk first: a full disk, a quota or ``ulimit -f`` is then
    refused in one line before HDF5 writes anything (HDF5 copes badly with a write that
    fails half-way).
    """
    tmp = final.with_name(f"{final.name}.tmp-{os.getpid()}")
    reserve_space(final, estimate + RESERVE_MARGIN)
    try:
        with h5py.File(tmp, "w", libver="latest") as f:
            try:
                fill(f)
            except BaseException as exc:
                _release(exc, f)
                raise
        _fsync_path(tmp)
        os.replace(tmp, final)
    except BaseException as exc:
        _release(exc, None)
        _unlink_quietly(tmp)
        reason = _environment_reason(exc)
        if reason is not None:  # disk full, read-only, quota: the old files are untouched
            from ..errors import StoreError

            raise StoreError(f"cannot write {final}: {reason} (nothing was changed: the store is as it was)") from None
        raise
    _fsync_path(final.parent)


def reserve_space(final: Path, nbytes: int) -> None:
    """Make sure ``nbytes`` can be written next to ``final``: allocate them in a scratch file, free them.

    Raises
    ------
    StoreError
        The disk (or quota, or the file size limit) has no room: nothing was written.
    """
    scratch = final.with_name(f"{final.name}.reserve-{os.getpid()}")
    try:
        fd = os.open(scratch, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        try:
            os.posix_fallocate(fd, 0, int(nbytes))
        finally:
            os.close(fd)
    except OSError as exc:
        reason = _environment_reason(exc)
        if reason is None and exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
            raise
        if reason is not None:
            from ..errors import StoreError

            _unlink_quietly(scratch)
            raise StoreError(f"cannot write {final}: {reason} (needs about {nbytes / 1e6:.1f} MB;"
                             " nothing was changed: the store is as it was)") from None
    finally:
        _unlink_quietly(scratch)


def _release(exc: BaseException, f) -> None:
    """Let go of every HDF5 object of a write that failed (a full disk), now.

    The frames of the traceback keep datasets alive; released later, each would try to
    flush to the full disk again, print "Exception ignored" tracebacks and, at exit, crash
    HDF5. Clearing the frames and closing the file here ends the write cleanly.
    """
    import gc
    import traceback

    try:
        traceback.clear_frames(exc.__traceback__)
    except Exception:
        pass
    if f is not None:
        try:
            f.close()
        except Exception:
            pass
    gc.collect()


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


MAIN_FILE = "main.h5"


def main_file(store: Path) -> Path:
    """The main file of the store (directory) ``store``."""
    return Path(store) / MAIN_FILE


def journal_dir(store: Path) -> Path:
    return Path(store) / "journal"


def lock_path(store: Path) -> Path:
    return Path(store) / "lock"


def committed_path(store: Path) -> Path:
    return Path(store) / "committed"


def read_committed(store: Path) -> int:
    """The newest journal sequence number a build committed (``STORE/committed``; 0 when none)."""
    try:
        from ..io.base import read_regular

        return int(read_regular(committed_path(store), 4096).split()[0])  # a FIFO put there never blocks
    except (OSError, ValueError, IndexError):
        return 0


def write_committed(store: Path, seq: int) -> None:
    """Record ``seq`` as committed (atomically), after its segment or main file is in place:
    a reader that then finds no file holding ``seq`` knows that a file of the store is missing."""
    path = committed_path(store)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(f"{int(seq)}\n")
        os.replace(tmp, path)
    except OSError:  # a check only: without it a missing newest segment goes unnoticed, nothing breaks
        _unlink_quietly(tmp)


def build_state_path(store: Path) -> Path:
    return Path(store) / "build.json"


def thumbs_dir(store: Path) -> Path:
    return Path(store) / "thumbs"


def is_one_file_store(path: Path) -> bool:
    """Whether ``path`` is a store of the older layout: one HDF5 file (``STORE.journal/`` beside it)."""
    try:
        with open(path, "rb") as f:
            return Path(path).is_file() and f.read(8) == b"\x89HDF\r\n\x1a\n"
    except OSError:
        return False


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
