"""Planning a build: which walked files need work, judged against the store's entries.

Planning compares each file's size and modification time with its entry: equal means
unchanged, with no read at all. A file whose times changed but whose size did not is hashed
in a worker; the same content only updates the entry's times. Failed files are not retried
until they change (or ``retry_failed``, or a new shapeidx version).

An entry signed by an older revision of its format's reader (each entry records it,
``entries/revision``; :attr:`shapeidx.io.base.Format.revision`) is work too, whatever its
size and time, ok or failed: its file is read and signed again, without the same-content
shortcut (its content is the same, its signature is not what the reader now makes). The
other formats' entries stay. The plan counts these files by format (:attr:`Plan.older`), for
the build to say why they are indexed again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import __version__
from ..store import STATUS_FAILED
from ..store.known import known_files
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
    #: Format label -> files of the tasks that are work only because an older revision of that
    #: format's reader signed their entries (``{"STEP": 37}``).
    older: dict = field(default_factory=dict)
    #: The same for ``build --parts``: files whose sub-entries an older reader made.
    older_parts: dict = field(default_factory=dict)


def _format_of(found) -> str | None:
    """A walked file's format: the walk's, else (a listing made by hand) by its name."""
    if found.format:
        return found.format
    from ..io.registry import entry_format

    return entry_format(found.path)


def older_words(older: dict, verb: str = "signed") -> str:
    """``37 signed by an older STEP reader, 2 by an older IGES reader`` ('' for none)."""
    parts = [f"{count} {verb + ' ' if k == 0 else ''}by an older {label} reader"
             for k, (label, count) in enumerate(older.items())]
    return ", ".join(parts)


def make_plan(walk: Walk, reader, options) -> Plan:
    """Compare the walked files with the store's entries: tasks, unchanged count, removed paths.

    ``options`` is a :class:`~shapeidx.index.build.BuildOptions` (``full``, ``rehash``,
    ``retry_failed`` are read). The entries are looked up by path key
    (:func:`~shapeidx.store.known.known_files`): no stored path is decoded but the removed
    entries', no content hash read but the changed files'. An entry older than its reader
    (:attr:`Plan.older`) is found by its revision column against the revision of the format
    the walk found for its file (a dictionary lookup a file; no path is parsed again).
    """
    from ..io.registry import count_by_label, revisions

    known = known_files(reader)
    files = walk.files
    at = known.lookup([f.path for f in files])
    found = at >= 0
    entry = np.where(found, at, 0)
    size = np.array([f.size for f in files], dtype=np.int64)
    mtime = np.array([f.mtime_ns for f in files], dtype=np.int64)
    failed = found & (known.status[entry] == STATUS_FAILED) if len(known) else np.zeros(len(files), dtype=bool)
    same_size = found & (known.size[entry] == size) if len(known) else failed
    same_stat = same_size & (known.mtime_ns[entry] == mtime) if len(known) else failed
    retry = options.retry_failed or reader.attrs.get("shapeidx_version") != __version__
    # an entry of an older reader revision than its format's now: signed again, ok or failed
    stale = np.zeros(len(files), dtype=bool)
    if len(known) and found.any():
        by_format = revisions()
        newest = max(by_format.values())
        maybe = np.flatnonzero(found & (known.revision[entry] < newest))  # older than some reader
        if len(maybe):
            current = np.array([by_format.get(_format_of(files[k]), 1)
                                for k in maybe.tolist()], dtype=np.int64)
            stale[maybe] = known.revision[entry[maybe]] < current
    # failed entries retried unchanged (--retry-failed, --full, a new version): failing again is not news
    # a file that could not be read at all (permission, I/O error) is recorded without size or time
    # (index.workers): it is tried again at every build, but its failing again is not news either
    never_read = failed & (known.size[entry] == 0) & (known.mtime_ns[entry] == 0) if len(known) else failed
    failed_before = {files[k].path for k in np.flatnonzero(failed & (same_stat | never_read)).tolist()}
    work = ~found | (failed & bool(retry)) | ~same_stat | stale
    # work only for the reader's revision (not changed, not retried anyway): what the build says
    older = stale & same_stat & ~(failed & bool(retry)) if not options.full else np.zeros(len(files), dtype=bool)
    if options.full or options.rehash:
        work[:] = True
    unchanged = int(np.sum(~work))
    # times changed (or --rehash): same size may still be the same content, known by its hash
    # (not for an older reader's entry: the same content is to be signed again)
    hashed = (np.flatnonzero(work & same_size & ~(failed & bool(retry)) & ~stale) if not options.full
              else np.zeros(0, dtype=np.int64))
    known_hash = dict(zip(hashed.tolist(), known.hashes(at[hashed]))) if len(hashed) else {}
    tasks = [Task(files[k].path, files[k].absolute, known_hash.get(k) or None, in_store=bool(found[k]))
             for k in np.flatnonzero(work).tolist()]
    gone = np.ones(len(known), dtype=bool)
    gone[at[found]] = False
    removed = [p for p in known.paths(np.flatnonzero(gone)) if not _under_any(p, walk.unlisted)]
    older_names = [_format_of(files[k]) for k in np.flatnonzero(older).tolist()] if older.any() else []
    return Plan(tasks, unchanged, sorted(removed), len(files), failed_before, count_by_label(older_names))


def _under_any(path: str, folders: list) -> bool:
    return any(folder in ("", ".", path) or path.startswith(folder.rstrip("/") + "/") for folder in folders)


def plan_parts(plan: Plan, walk: Walk, reader, options) -> list:
    """``build --parts``: mark the plan's tasks to also sign their files' sub-parts, add a task
    for every file whose sub-entries are missing or stale though its own entry is up to date,
    and return the sub-entries whose files are gone.

    ``reader`` is the parts store's view (None: it has no entry yet). A file's sub-entries
    (``FILE#n``, or one failed ``FILE``) carry its size, time and content hash: the same size
    and time mean they are up to date, as for the whole-file entries, unless an older revision
    of the file's reader made them (:func:`make_plan`): then they are made again, the same
    content notwithstanding, and counted in ``plan.older_parts``.
    """
    import dataclasses

    from ..io.registry import count_by_label, revisions

    by_format = revisions()
    known = _known_parts(reader)
    index = {task.path: k for k, task in enumerate(plan.tasks)}
    older = []
    for f in walk.files:
        record = known.get(f.path)
        old = tuple(record[0]) if record else ()
        stale = record is not None and record[4] < by_format.get(_format_of(f), 1)
        stored_hash = None if record is None or options.full or stale else _text(record[3])
        if f.path in index:
            k = index[f.path]
            plan.tasks[k] = dataclasses.replace(plan.tasks[k], parts=True, parts_hash=stored_hash, old_parts=old)
        elif options.full or options.rehash or record is None or (record[1], record[2]) != (f.size, f.mtime_ns) or stale:
            plan.tasks.append(Task(f.path, f.absolute, whole=False, parts=True, parts_hash=stored_hash, old_parts=old,
                                   in_store=True))
        if stale and not options.full and (record[1], record[2]) == (f.size, f.mtime_ns):
            older.append(_format_of(f))
    plan.older_parts = count_by_label(older)
    return _gone_parts(known, walk)


def _known_parts(reader) -> dict:
    """The parts store's sub-entries by file: parent -> [paths, size, mtime_ns, hash, oldest revision]."""
    from ..store.layout import REVISION_COLUMN

    known: dict = {}
    if reader is not None and len(reader):
        paths, parents = reader.paths, reader.column("entries/parent")
        size, mtime, hashes = reader.column("entries/size"), reader.column("entries/mtime_ns"), reader.column("entries/hash")
        revision = reader.column(REVISION_COLUMN)
        for i in range(len(paths)):
            record = known.setdefault(str(parents[i]) or str(paths[i]),
                                      [[], int(size[i]), int(mtime[i]), hashes[i], int(revision[i])])
            record[0].append(str(paths[i]))
            record[4] = min(record[4], int(revision[i]))
    return known


def _gone_parts(known: dict, walk: Walk) -> list:
    """The sub-entries whose files the walk no longer finds (not those under an unlisted folder)."""
    walked = {f.path for f in walk.files}
    return sorted(p for parent, record in known.items() if parent not in walked and not _under_any(parent, walk.unlisted)
                  for p in record[0])


def prune_parts(plan: Plan, walk: Walk, reader, main=None) -> tuple[list, list]:
    """A build without ``--parts`` over a store that has sub-parts: the sub-entries it must not
    leave behind. Each task of a file with sub-entries carries them (``old_parts``, not
    ``parts``) and their content hash (``parts_hash``): they are removed when the file's
    content changed (they describe content that is gone; ``build --parts`` makes them again),
    and get its new times when it did not (times changed, ``--full``, a newer reader:
    :class:`~shapeidx.index.commit.PartsCommitter`).

    A file without a task whose sub-entries are of other times than it is one whose own
    entry an earlier build without ``--parts`` committed before it was killed: its sub-entries
    are judged now, against its entry's hash in ``main`` (the store's view).

    Returns (removed, touched): the sub-entries of the files that are gone (as
    :func:`plan_parts` does) or changed, and (path, size, mtime_ns) of those that only get times.
    """
    import dataclasses

    known = _known_parts(reader)
    plan.tasks = [dataclasses.replace(task, old_parts=tuple(known[task.path][0]), parts_hash=_text(known[task.path][3]))
                  if task.path in known else task for task in plan.tasks]
    removed, touched = _gone_parts(known, walk), []
    tasked = {task.path for task in plan.tasks}
    behind = [f for f in walk.files if f.path not in tasked and f.path in known
              and (known[f.path][1], known[f.path][2]) != (f.size, f.mtime_ns)]
    if behind and main is not None:
        entries = known_files(main)
        at = entries.lookup([f.path for f in behind])
        hashes = entries.hashes(at[at >= 0]) if (at >= 0).any() else []
        now = dict(zip([f.path for f, k in zip(behind, at.tolist()) if k >= 0], hashes))
        for f in behind:
            record = known[f.path]
            if now.get(f.path) and now[f.path] == _text(record[3]):
                touched.extend((p, f.size, f.mtime_ns) for p in record[0])
            else:
                removed.extend(record[0])
    return sorted(removed), touched


def _text(value) -> str | None:
    """A stored hash as text (None when empty)."""
    return (value.decode() if isinstance(value, bytes) else str(value)) or None
