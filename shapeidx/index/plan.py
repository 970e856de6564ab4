"""Planning a build: which walked files need work, judged against the store's entries.

Planning compares each file's size and modification time with its entry: equal means
unchanged, with no read at all. A file whose times changed but whose size did not is hashed
in a worker; the same content only updates the entry's times. Failed files are not retried
until they change (or ``retry_failed``, or a new shapeidx version).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .. import __version__
from ..store import STATUS_FAILED
from .walk import Walk
from .workers import Task


@dataclass
class Plan:
    """What a build has to do."""

    tasks: list
    unchanged: int
    removed: list
    found: int
    #: Paths of the tasks whose entries had failed (retried): failing again is not news.
    failed_before: set = field(default_factory=set)


def make_plan(walk: Walk, reader, options) -> Plan:
    """Compare the walked files with the store's entries: tasks, unchanged count, removed paths.

    ``options`` is a :class:`~shapeidx.index.build.BuildOptions` (``full``, ``rehash``,
    ``retry_failed`` are read).
    """
    paths = reader.paths
    index = {p: i for i, p in enumerate(paths)}
    size, mtime = reader.column("entries/size"), reader.column("entries/mtime_ns")
    hashes, status = reader.column("entries/hash"), reader.column("entries/status")
    retry = options.retry_failed or reader.attrs.get("shapeidx_version") != __version__
    tasks, unchanged, failed_before = [], 0, set()
    for f in walk.files:
        i = index.pop(f.path, None)
        if i is not None and status[i] == STATUS_FAILED and size[i] == f.size and mtime[i] == f.mtime_ns:
            failed_before.add(f.path)  # retried unchanged (--retry-failed, --full, a new version)
        if i is None or options.full:
            tasks.append(Task(f.path, f.absolute, in_store=i is not None))
            continue
        failed = status[i] == STATUS_FAILED
        same_stat = size[i] == f.size and mtime[i] == f.mtime_ns
        known = hashes[i].decode() or None
        if failed and retry:
            tasks.append(Task(f.path, f.absolute, in_store=True))
        elif same_stat and not options.rehash:
            unchanged += 1
        else:  # times changed (or --rehash): same size may still be the same content
            tasks.append(Task(f.path, f.absolute, known if size[i] == f.size else None, in_store=True))
    removed = [p for p in index if not _under_any(p, walk.unlisted)]
    return Plan(tasks, unchanged, sorted(removed), len(walk.files), failed_before)


def _under_any(path: str, folders: list) -> bool:
    return any(folder in ("", ".", path) or path.startswith(folder.rstrip("/") + "/") for folder in folders)
