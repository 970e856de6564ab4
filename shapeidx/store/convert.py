"""Converting a store of the older one-file layout into a store directory, by renames only.

Before shapeidx 0.2 a store was a main file ``STORE`` with its journal, lock, verification
record and thumbnails beside it (``STORE.journal/``, ``STORE.lock``, ``STORE.verified``,
``STORE.thumbs/``): five things to copy, and copying the one that looked like the store gave
an empty one. The first build that meets such a store moves them into the directory
``STORE/`` (:mod:`shapeidx.store.files`): the same HDF5 files, so no part is signed again.

The conversion holds the old layout's lock (no build of an older shapeidx runs meanwhile)
and is resumable: everything is first moved into ``STORE.converting/``, which is then
renamed to ``STORE``; a conversion killed half-way is finished by the next build.
"""

from __future__ import annotations

import os
from pathlib import Path

from .files import is_one_file_store, journal_dir, main_file, thumbs_dir
from .lock import StoreLock

#: The old layout's files beside ``STORE``: suffix -> where it goes in the directory (None: dropped).
_SIBLINGS = ((".journal", journal_dir), (".thumbs", thumbs_dir), (".verified", None))


def convert_one_file_store(store: Path, wait: bool = False, on_wait=None, timeout: float | None = None) -> bool:
    """Convert ``store`` if it is a one-file store (or a conversion was interrupted); True if it did."""
    store = Path(store)
    staging = store.with_name(store.name + ".converting")
    if not is_one_file_store(store) and not staging.is_dir():
        return False
    old_lock_file = store.with_name(store.name + ".lock")
    lock = StoreLock(store, old_lock_file)
    lock.acquire(wait, on_wait, timeout)
    try:
        if is_one_file_store(store):
            staging.mkdir(exist_ok=True)
            os.replace(store, main_file(staging))
        if not staging.is_dir():
            return False  # another process converted it while we waited for the lock
        for suffix, place in _SIBLINGS:
            old = store.with_name(store.name + suffix)
            if old.is_dir() or old.is_file():
                if place is None:
                    old.unlink()
                else:
                    os.replace(old, place(staging))
        os.replace(staging, store)
    finally:
        lock.release()
    old_lock_file.unlink(missing_ok=True)
    return True
