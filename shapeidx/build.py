"""``shapeidx build``: bring a store up to date with a directory tree of part files.

    walk the tree --plan against the store--> tasks --WorkerPool--> outcomes
         --Committer: a journal batch every interval--> merge into the main file

* Walking follows symbolic links but enters each real directory once (no loops, no file
  indexed twice through two links), skips hidden folders and files, and keeps the files
  :func:`shapeidx.io.format_of` knows (also gzipped).
* Planning compares each file's size and modification time with its entry: equal means
  unchanged, with no read at all. A file whose times changed but whose size did not is
  hashed in a worker; the same content only updates the entry's times. Failed files are
  not retried until they change (or ``retry_failed``, or a new shapeidx version).
* Every outcome goes to the :class:`Committer`, which writes a journal batch at least every
  ``commit_interval`` seconds, so a killed build that is run again redoes at most that much.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ShapeidxError
from .io import format_of
from .io.faceting import Faceting
from .pipeline import DEFAULT_POINTS, SIGNATURE_VERSION
from .sampling import DEFAULT_SEED
from .signature import BIN_DIVISOR
from .store import STATUS_FAILED, STATUS_OK, Batch, StoreParams, StoreWriter, open_store
from .workers import DEFAULT_TIMEOUT, Outcome, Task, WorkerPool

#: Seconds between commits of a running build (the work a kill can lose).
DEFAULT_COMMIT_INTERVAL = 60.0
#: Entries a batch holds at most (bounds the builder's memory, whatever the tree's size).
BATCH_ENTRIES = 500
#: Journal batches that trigger a merge into the main file before the build ends.
MERGE_AFTER = 64


@dataclass(frozen=True)
class FoundFile:
    path: str  # relative to the root, '/'-separated
    absolute: str
    size: int
    mtime_ns: int


@dataclass
class Walk:
    """What :func:`walk_parts` found: part files, and what it could not look at."""

    files: list = field(default_factory=list)
    #: Relative folders that could not be listed: their entries must not be taken as removed.
    unlisted: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


def walk_parts(root: Path) -> Walk:
    """Every part file under ``root`` (see the module docstring for the rules), sorted by path.

    Real folders are walked before symbolically linked ones, so that a file reachable both
    ways is indexed under its real path; each real folder is entered once.
    """
    found = Walk()
    seen: set = set()
    folders, linked = [Path(root)], []
    while folders or linked:
        folder = folders.pop() if folders else linked.pop(0)
        try:
            stat = folder.stat()
            if (stat.st_dev, stat.st_ino) in seen:
                continue  # a loop, or a second way to a folder already walked
            seen.add((stat.st_dev, stat.st_ino))
            children = sorted(os.scandir(folder), key=lambda e: e.name)
        except OSError as exc:
            rel = folder.relative_to(root).as_posix()
            found.unlisted.append(rel)
            found.warnings.append(f"cannot list {rel}: {exc.strerror or exc}")
            continue
        for child in children:
            if child.name.startswith("."):
                continue
            if _is_folder(child):
                (linked if child.is_symlink() else folders).append(Path(child.path))
            elif format_of(child.name) is not None:
                _add_file(found, root, Path(child.path))
    found.files.sort(key=lambda f: f.path)
    return found


def _is_folder(entry: os.DirEntry) -> bool:
    try:
        return entry.is_dir()
    except OSError:
        return False


def _add_file(found: Walk, root: Path, absolute: Path) -> None:
    rel = absolute.relative_to(root).as_posix()
    try:
        rel.encode("utf-8")
    except UnicodeEncodeError:
        found.warnings.append(f"skipped {rel!r}: its name is not valid UTF-8")
        return
    try:
        stat = absolute.stat()
    except OSError as exc:
        found.warnings.append(f"skipped {rel}: {exc.strerror or exc} (a broken link?)")
        return
    if not absolute.is_file():
        return
    found.files.append(FoundFile(rel, str(absolute), stat.st_size, stat.st_mtime_ns))


@dataclass
class Plan:
    """What a build has to do."""

    tasks: list
    unchanged: int
    removed: list
    found: int


@dataclass(frozen=True)
class BuildOptions:
    """How to build; the CLI's options. ``points``/``seed``/deflections None: the store's, else the defaults."""

    points: int | None = None
    seed: int | None = None
    linear_deflection: float | None = None  # faceting of STEP/IGES, see shapeidx.io.faceting
    angular_deflection: float | None = None
    workers: int = 0  # 0: one per core
    full: bool = False
    rehash: bool = False
    retry_failed: bool = False
    timeout: float | None = DEFAULT_TIMEOUT
    wait: bool = False
    commit_interval: float = DEFAULT_COMMIT_INTERVAL
    merge_after: int = MERGE_AFTER


def make_plan(walk: Walk, reader, options: BuildOptions) -> Plan:
    """Compare the walked files with the store's entries: tasks, unchanged count, removed paths."""
    paths = reader.paths
    index = {p: i for i, p in enumerate(paths)}
    size, mtime = reader.column("entries/size"), reader.column("entries/mtime_ns")
    hashes, status = reader.column("entries/hash"), reader.column("entries/status")
    retry = options.retry_failed or reader.attrs.get("shapeidx_version") != __version__
    tasks, unchanged = [], 0
    for f in walk.files:
        i = index.pop(f.path, None)
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
    return Plan(tasks, unchanged, sorted(removed), len(walk.files))


def _under_any(path: str, folders: list) -> bool:
    return any(folder in ("", ".") or path.startswith(folder.rstrip("/") + "/") for folder in folders)


@dataclass
class BuildSummary:
    """Counts of one build, and of the store after it."""

    found: int = 0
    indexed: int = 0
    unchanged: int = 0
    removed: int = 0
    failed: int = 0
    seconds: float = 0.0
    store_ok: int = 0
    store_failed: int = 0
    store_bytes: int = 0
    failures: list = field(default_factory=list)  # (path, reason) of this build

    def line(self) -> str:
        return f"{self.indexed} indexed, {self.unchanged} unchanged, {self.removed} removed, {self.failed} failed"


class Committer:
    """Collects outcomes into batches and commits them to the journal on time.

    A batch is committed when it holds :data:`BATCH_ENTRIES` records or when
    ``interval`` seconds passed since the last commit; the journal is merged into the main
    file once it holds ``merge_after`` batches, and by :meth:`finish`.
    """

    def __init__(self, writer: StoreWriter, interval: float, merge_after: int, reporter):
        self.writer = writer
        self.interval = interval
        self.merge_after = merge_after
        self.reporter = reporter
        self.batch = Batch()
        self.last = time.monotonic()

    def add(self, outcome: Outcome) -> None:
        if outcome.kind in ("indexed", "failed"):
            self.batch.entries.append(outcome.entry)
        elif outcome.kind == "same":
            self.batch.touched.append((outcome.task.path, outcome.size, outcome.mtime_ns))
        elif outcome.kind == "missing" and outcome.task.in_store:
            self.batch.removed.append(outcome.task.path)

    def remove(self, paths: list) -> None:
        self.batch.removed.extend(paths)

    def tick(self) -> None:
        """Commit if the batch is full or old; merge if the journal is long."""
        due = time.monotonic() - self.last >= self.interval
        if len(self.batch) >= BATCH_ENTRIES or (due and len(self.batch)):
            self.commit()
            if self.writer.pending_batches >= self.merge_after:
                self.writer.merge()
                self.reporter.merged()

    def commit(self) -> None:
        if len(self.batch):
            seq = self.writer.commit(self.batch)
            self.reporter.committed(seq, len(self.batch))
            self.batch = Batch()
        self.last = time.monotonic()

    def finish(self) -> None:
        self.commit()
        if self.writer.pending_batches:
            self.writer.merge()
            self.reporter.merged()


def resolve_params(store: Path, options: BuildOptions) -> StoreParams:
    """The build's parameters: those asked, else the existing store's, else the defaults."""
    existing = None
    if store.exists():
        with open_store(store) as reader:
            existing = reader.params
    points = options.points or (existing.points if existing else DEFAULT_POINTS)
    seed = options.seed if options.seed is not None else (existing.seed if existing else DEFAULT_SEED)
    faceting = existing.faceting if existing else Faceting()
    linear = options.linear_deflection or faceting.linear_deflection
    angular = options.angular_deflection or faceting.angular_deflection
    return StoreParams(points=points, seed=seed, bin_divisor=BIN_DIVISOR, signature_version=SIGNATURE_VERSION,
                       linear_deflection=linear, angular_deflection=angular)


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def run_build(root, store, options: BuildOptions, reporter) -> BuildSummary:
    """Index ``root`` into ``store``; see the module docstring. Returns the summary.

    Raises
    ------
    ShapeidxError
        The build itself cannot run (no such directory, store locked or of other
        parameters or another root). Bad part files never raise: they are recorded.
    KeyboardInterrupt
        On Ctrl-C or SIGTERM, after committing what was done.
    """
    started = time.monotonic()
    root = Path(root).resolve()
    if not root.is_dir():
        raise ShapeidxError(f"{root}: no such directory")
    store = Path(store)
    params = resolve_params(store, options)
    summary = BuildSummary()
    with _sigterm_as_interrupt(), StoreWriter(store, params, root, options.wait, reporter.waiting) as writer:
        walk = walk_parts(root)
        for warning in walk.warnings:
            reporter.warning(warning)
        with open_store(store) as reader:
            plan = make_plan(walk, reader, options)
        summary.found, summary.unchanged = plan.found, plan.unchanged
        reporter.planned(plan)
        committer = Committer(writer, options.commit_interval, options.merge_after, reporter)
        committer.remove(plan.removed)
        summary.removed = len(plan.removed)
        pool = WorkerPool(options.workers or default_workers(), params, str(root), options.timeout)
        try:
            for outcome in pool.run(plan.tasks):
                if outcome is not None:
                    _count(summary, outcome)
                    committer.add(outcome)
                    reporter.outcome(outcome)
                committer.tick()
        except KeyboardInterrupt:
            committer.commit()
            raise
        finally:
            pool.close()
        committer.finish()
    summary.seconds = time.monotonic() - started
    _store_counts(store, summary)
    return summary


def _count(summary: BuildSummary, outcome: Outcome) -> None:
    if outcome.kind == "indexed":
        summary.indexed += 1
    elif outcome.kind == "failed":
        summary.failed += 1
        summary.failures.append((outcome.task.path, outcome.entry.reason))
    elif outcome.kind == "same":
        summary.unchanged += 1
    elif outcome.kind == "missing" and outcome.task.in_store:
        summary.removed += 1


def _store_counts(store: Path, summary: BuildSummary) -> None:
    with open_store(store) as reader:
        status = reader.column("entries/status")
        summary.store_ok = int(np.sum(status == STATUS_OK))
        summary.store_failed = int(np.sum(status == STATUS_FAILED))
        summary.store_bytes = reader.size_on_disk()


class _sigterm_as_interrupt:
    """SIGTERM (a cron timeout, a shutdown) stops a build like Ctrl-C: what is done is committed."""

    def __enter__(self):
        self.previous = None
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGTERM, _raise_interrupt)
        return self

    def __exit__(self, *exc):
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt
