"""``shapeidx build``: bring a store up to date with a directory tree of part files.

    walk.py      walk the tree
    plan.py         --plan against the store--> tasks
    workers.py      --WorkerPool: one file per process--> outcomes
    commit.py       --Committer: a journal batch every interval--> merge into the main file
    progress.py  what the user sees meanwhile
"""

from __future__ import annotations

import os
import re
import signal
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..io.faceting import Faceting
from ..errors import ShapeidxError, StoreDamagedError, UsageError
from ..signing.parameters import BIN_DIVISOR, DEFAULT_POINTS, DEFAULT_SEED, SIGNATURE_VERSION
from ..store import StoreParams, StoreWriter, check_params, check_root, open_store
from ..system import available_cores
from .commit import DEFAULT_COMMIT_INTERVAL, MERGE_AFTER, Committer
from .plan import Plan, make_plan
from .walk import walk_parts
from .workers import DEFAULT_TIMEOUT, Outcome, Task, WorkerPool


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
    worker_memory: int | None = None  # bytes per worker; None: workers.default_memory_limit, 0: none
    #: Only plan: walk the tree and compare it with the store, change nothing.
    dry_run: bool = False
    #: With ``wait``: the longest wait for another build's lock, seconds (None: no limit).
    wait_timeout: float | None = None
    #: Drop the damaged entries of a damaged store first (their files are indexed again).
    repair: bool = False
    #: Also follow symbolic links that lead out of the tree.
    follow_outside_links: bool = False
    #: A dask.distributed scheduler's address: index the files on its cluster (see dask_pool.py).
    scheduler: str | None = None
    #: Where the cluster's workers see the tree, when not at the same path.
    worker_root: str | None = None
    #: A CSV of metadata (a path column and any others) joined to the entries (shapeidx.store.metadata).
    metadata: str | None = None
    #: (k, N): build only the files of shard k of N (by path key; shapeidx.store.shards) into the store.
    shard: tuple | None = None
    #: Also sign each file's sub-parts into the parts store ``STORE/parts`` (shapeidx.io.parts).
    parts: bool = False


@dataclass
class BuildSummary:
    """Counts of one build, and of the store after it."""

    found: int = 0
    #: Files the plan found new or changed (each is then indexed, failed, or found the same).
    planned: int = 0
    indexed: int = 0
    unchanged: int = 0
    removed: int = 0
    failed: int = 0
    seconds: float = 0.0
    store_ok: int = 0
    store_failed: int = 0
    store_bytes: int = 0
    failures: list = field(default_factory=list)  # (path, reason) of this build
    #: Rows of the metadata table this build read (None: no --metadata), and whether it changed.
    metadata_rows: int | None = None
    metadata_changed: bool = False
    #: With ``--parts``: sub-entries written by this build, and the parts store's ok sub-entries after it.
    parts_indexed: int | None = None
    parts_entries: int | None = None
    #: With ``--parts``: files whose sub-parts the build (or dry run) plans to make; and the
    #: sub-entries it removes (their files gone; without ``--parts``, also changed in content).
    parts_planned: int | None = None
    parts_removed: int | None = None
    #: Where the build's CPU went (:class:`BuildProfile`); None for a dry run.
    profile: "BuildProfile | None" = None
    #: Format label -> files planned only because an older revision of that format's reader
    #: signed their entries (:attr:`shapeidx.index.plan.Plan.older`; included in ``planned``),
    #: and files whose sub-entries (``--parts``) an older reader made.
    older: dict = field(default_factory=dict)
    older_parts: dict = field(default_factory=dict)
    #: The signature version of the store this build signed again whole (None: it was current).
    resigned_from: int | None = None

    def line(self) -> str:
        return f"{self.indexed} indexed, {self.unchanged} unchanged, {self.removed} removed, {self.failed} failed"

    def older_line(self) -> str:
        """``; signed again by a newer reader: 37 STEP`` ('' when no file was): why files whose
        size and time did not change were indexed (added after the store's counts)."""
        return ((f"; every entry signed again: the store held signature version {self.resigned_from}"
                 if self.resigned_from is not None else "")
                + (f"; signed again by a newer reader: {_counts(self.older)}" if self.older else "")
                + (f"; sub-parts made again by a newer reader: {_counts(self.older_parts)}" if self.older_parts else ""))

    root: str = ""

    def to_dict(self, store: Path, dry_run: bool = False) -> dict:
        """What ``shapeidx build --json`` prints."""
        return {
            "dry_run": dry_run,
            "found": self.found,
            "planned": self.planned,
            "indexed": self.indexed,
            "unchanged": self.unchanged,
            "removed": self.removed,
            "failed": self.failed,
            "resigned_from": self.resigned_from,
            "seconds": round(self.seconds, 3),
            "store": {"path": str(store), "root": self.root, "ok": self.store_ok, "failed": self.store_failed, "bytes": self.store_bytes},
            "failures": [{"path": path, "reason": reason} for path, reason in self.failures],
            "metadata": None if self.metadata_rows is None else {"rows": self.metadata_rows,
                                                                  "changed": self.metadata_changed},
            "parts": None if self.parts_indexed is None and self.parts_planned is None else {
                "indexed": self.parts_indexed or 0, "entries": self.parts_entries,
                "planned": self.parts_planned, "removed": self.parts_removed},
            "profile": None if self.profile is None else self.profile.to_dict(),
            "older_reader": dict(self.older),
            "older_reader_parts": dict(self.older_parts),
        }


def _counts(by_label: dict) -> str:
    """``37 STEP, 2 IGES``."""
    return ", ".join(f"{count} {label}" for label, count in by_label.items())


@dataclass
class BuildProfile:
    """CPU seconds of one build, by process and by stage (``build --json``'s ``profile``).

    The parent: ``start`` (the calling process's CPU before the build began: for the
    command line the interpreter and its imports; in a long-lived Python caller all it
    did before, so compare builds by the other stages there),
    ``setup`` (walk, plan, opening the store: before the first file is handed
    out), ``commit`` (entries written, journal merges), ``progress`` (log and progress
    lines), ``other`` (handing files to workers, waiting for them, the closing counts).
    The workers: what each file cost by stage, summed (:class:`~shapeidx.index.workers.StageClock`),
    and ``other``: the rest of the worker processes' CPU (imports at start, receiving tasks,
    sending results), local workers only (a Dask cluster's workers are not this machine's).
    """

    parent: dict = field(default_factory=dict)
    workers: dict = field(default_factory=dict)
    workers_total: float | None = None
    workers_started: int | None = None

    def charge(self, stages: dict | None) -> None:
        for stage, seconds in (stages or {}).items():
            self.workers[stage] = self.workers.get(stage, 0.0) + seconds

    def to_dict(self) -> dict:
        workers = {k: round(v, 3) for k, v in sorted(self.workers.items())}
        if self.workers_total is not None:
            workers["other"] = round(max(0.0, self.workers_total - sum(self.workers.values())) + self.workers.get("other", 0.0), 3)
        return {"cpu_seconds": {"parent": {k: round(v, 3) for k, v in self.parent.items()},
                                "parent_total": round(sum(self.parent.values()), 3),
                                "workers": workers,
                                "workers_total": None if self.workers_total is None else round(self.workers_total, 3)},
                "workers_started": self.workers_started}


def _cpu(who) -> float:
    import resource

    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


def resolve_params(store: Path, options: BuildOptions) -> StoreParams:
    """The build's parameters: those asked, else the existing store's, else the defaults."""
    from ..store.files import journal_dir, main_file

    existing = None
    if main_file(store).exists() or store.is_file():
        try:
            with open_store(store, skip_damaged=True) as reader:  # a damaged or missing segment is redone
                existing = reader.params
        except StoreDamagedError:
            if not options.repair:
                raise
            existing = _params_of_damaged(store)
    elif journal_dir(store).exists():  # its main file is missing: the segments still say the parameters
        existing = _params_of_damaged(store)
    # (a directory without either is new, or a first build is creating it: the writer decides under its lock)
    points = options.points or (existing.points if existing else DEFAULT_POINTS)
    seed = options.seed if options.seed is not None else (existing.seed if existing else DEFAULT_SEED)
    faceting = existing.faceting if existing else Faceting()
    linear = options.linear_deflection or faceting.linear_deflection
    angular = options.angular_deflection or faceting.angular_deflection
    return StoreParams(points=points, seed=seed, bin_divisor=BIN_DIVISOR, signature_version=SIGNATURE_VERSION,
                       linear_deflection=linear, angular_deflection=angular)


def resign_folder(store: Path) -> Path:
    """Where a store of an older signature version is signed again, beside it."""
    return store.with_name(store.name + ".resign")


def _older_signature(store: Path) -> int | None:
    """The signature version of ``store`` when it is older than this shapeidx's (else None)."""
    from ..store.files import main_file

    if not main_file(store).exists():
        return None
    try:
        with open_store(store, skip_damaged=True) as reader:
            version = reader.params.signature_version
    except ShapeidxError:
        return None  # damaged or unreadable: the build's own checks say so
    return version if version < SIGNATURE_VERSION else None


def _resign(root, store: Path, older: int, options: BuildOptions, reporter) -> "BuildSummary":
    """Sign every entry of a store of an older signature version again.

    Signatures of two versions are never mixed, and the old store cannot answer queries of the
    new version, so the build makes a whole new store beside it (:func:`resign_folder`, an
    ordinary store: a killed build goes on from what it committed) with the old store's
    parameters but the version, its metadata and thumbnails, and then puts it in the old one's
    place. Until then readers are refused with the command that finishes it.
    """
    import shutil

    from ..store.files import main_file

    side = resign_folder(store)
    with open_store(store, skip_damaged=True) as reader:
        old = reader.params
    reporter.warning(f"{store} holds signatures of version {older}; this shapeidx makes version {SIGNATURE_VERSION}:"
                     f" every entry is signed again (into {side}, which then replaces it)")
    side.mkdir(exist_ok=True)
    for name in ("metadata.h5", "thumbs"):  # what the files' content alone decides: still true
        source, target = store / name, side / name
        if source.exists() and not target.exists():
            (shutil.copytree if source.is_dir() else shutil.copy2)(source, target)
    if (store / "parts").exists() and not options.parts:
        reporter.warning(f"{store}/parts (sub-parts) is left out: 'build DIR --store {store} --parts' makes it again")
    same = replace(options, points=options.points or old.points, seed=old.seed if options.seed is None else options.seed,
                   linear_deflection=options.linear_deflection or old.faceting.linear_deflection,
                   angular_deflection=options.angular_deflection or old.faceting.angular_deflection)
    summary = run_build(root, side, same, reporter)
    if main_file(side).exists():
        _swap_in(store, side)
    summary.resigned_from = older
    return summary


def _swap_in(store: Path, side: Path) -> None:
    """Put the re-signed store ``side`` in the place of ``store`` (two renames; a build killed
    between them is completed by :func:`_finish_resign`)."""
    import shutil

    old = store.with_name(store.name + ".older")
    if old.exists():
        shutil.rmtree(old)
    os.replace(store, old)
    os.replace(side, store)
    shutil.rmtree(old, ignore_errors=True)


def _finish_resign(store: Path) -> None:
    """Complete a swap that a killed build left half done: the re-signed store is in its
    folder beside the store, and the store is gone (renamed aside)."""
    import shutil

    side, old = resign_folder(store), store.with_name(store.name + ".older")
    if not store.exists() and side.exists() and old.exists():
        os.replace(side, store)
    if store.exists() and old.exists():
        shutil.rmtree(old, ignore_errors=True)


def _params_of_damaged(store: Path) -> StoreParams | None:
    """The parameters a damaged store was built with, if the attributes of its main file or
    of one of its segments can still be read."""
    from ..store.files import batch_files, main_file
    from ..store.heaps import open_hdf5

    for path in [main_file(store)] + [p for _, p in reversed(batch_files(store))]:
        try:
            with open_hdf5(path) as f:
                return StoreParams.from_attrs(f.attrs)
        except (OSError, KeyError, ValueError):
            continue
    return None


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
    import resource

    started = time.monotonic()
    cpu_started, children_started = _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
    given = root
    root = Path(root).resolve()
    check_tree(given, root)
    store = Path(store)
    _refuse_parts_store(store)
    if not options.dry_run:
        from ..store.convert import convert_one_file_store

        if convert_one_file_store(store, options.wait, reporter.waiting, options.wait_timeout):
            reporter.warning(f"converted {store} from the one-file layout into a store directory (renames only)")
    if not options.dry_run:
        _finish_resign(store)
        older = _older_signature(store)
        if older is not None:
            return _resign(given, store, older, options, reporter)
    params = resolve_params(store, options)
    summary = BuildSummary(root=str(root))
    if options.worker_root and not options.scheduler:
        raise ShapeidxError("--worker-root is where a cluster's workers see the tree: it needs --scheduler")
    if options.parts and options.scheduler:
        raise ShapeidxError("--parts runs on local workers only (not with --scheduler)")
    if options.dry_run:
        return _dry_run(root, store, params, options, reporter, summary)
    walk = walk_parts(root, options.follow_outside_links)
    _refuse_empty(given, walk)
    table = _metadata_table(options, root, walk, reporter)  # a bad table is refused before the store changes
    walk = _shard_walk(walk, options)
    with _sigterm_as_interrupt(), StoreWriter(store, params, root, options.wait, reporter.waiting,
                                              options.wait_timeout, options.repair, reporter.warning) as writer:
        if options.wait:  # walk again: the tree may have changed while another build held the lock
            walk = _shard_walk(walk_parts(root, options.follow_outside_links), options)
        for warning in walk.warnings:
            reporter.warning(warning)
        if table is not None:
            summary.metadata_rows, summary.metadata_changed = len(table), _store_metadata(store, table, reporter)
        with open_store(store, skip_damaged=True) as reader:  # the writer dropped what is damaged
            plan = make_plan(walk, reader, options)
        summary.found, summary.unchanged = plan.found, plan.unchanged
        # with --parts: the files whose sub-parts alone are missing or stale are tasks too
        parts = (_parts_committer(store, params, root, options, reporter, plan, walk, summary) if options.parts
                 else _parts_pruner(store, params, root, options, reporter, plan, walk))
        # planned: the files to sign whole (not those only split into sub-parts), as a dry run counts them
        summary.planned = sum(getattr(task, "whole", True) for task in plan.tasks)
        summary.older, summary.older_parts = dict(plan.older), dict(plan.older_parts)
        reporter.planned(plan)
        committer = Committer(writer, options.commit_interval, options.merge_after, reporter)
        committer.remove(plan.removed)
        summary.removed = len(plan.removed)
        committers = [committer] + ([parts] if parts else [])
        pool = _pool(options, params, root)
        profile = summary.profile = BuildProfile()
        profile.parent = {"start": cpu_started, "setup": _cpu(resource.RUSAGE_SELF) - cpu_started, "commit": 0.0,
                          "progress": 0.0}
        clock = time.process_time
        try:
            for outcome in pool.run(plan.tasks):
                if outcome is not None:
                    _redact_outside(outcome, root)
                    _count(summary, outcome)
                    profile.charge(outcome.cpu)
                    at = clock()
                    for one in committers:
                        one.add(outcome)
                    committed = clock()
                    reporter.outcome(outcome)
                    profile.parent["progress"] += clock() - committed
                    profile.parent["commit"] += committed - at
                at = clock()
                for one in committers:
                    one.tick()
                profile.parent["commit"] += clock() - at
        except (KeyboardInterrupt, ShapeidxError):  # e.g. a lost Dask scheduler: keep what came back
            for one in committers:
                one.commit()
            if parts:
                parts.writer.close("interrupted")
            raise
        finally:
            pool.close()
        if isinstance(pool, WorkerPool):
            profile.workers_total = _cpu(resource.RUSAGE_CHILDREN) - children_started
            profile.workers_started = pool.started
        at = clock()
        for one in committers:
            one.finish()
        profile.parent["commit"] += clock() - at
        if parts:
            parts.writer.close("finished")
        writer.facts = {"indexed": summary.indexed, "failed": summary.failed, "removed": summary.removed,
                        "unchanged": summary.unchanged}
    summary.seconds = time.monotonic() - started
    _store_counts(store, summary)
    profile.parent["other"] = max(0.0, _cpu(resource.RUSAGE_SELF) - sum(profile.parent.values()))
    _parts_counts(store, options, parts, summary)
    return summary


def _parts_counts(store: Path, options: BuildOptions, parts, summary: BuildSummary) -> None:
    """The parts store's counts after a build with ``--parts``, or without it over a store that
    has sub-parts (what it removed: :func:`_parts_pruner`; a sharded build adds them up)."""
    from ..store.files import parts_store
    from ..store.known import known_files

    if not options.parts and not parts_store(store).is_dir():
        return
    try:
        with open_store(parts_store(store)) as reader:
            summary.parts_entries = known_files(reader).status_counts()[0]
    except ShapeidxError:
        if options.parts:
            raise
        return  # damaged or never committed: the build said so (_parts_pruner), its counts are not known
    summary.parts_indexed = summary.parts_indexed or 0
    if not options.parts:
        summary.parts_removed = parts.removed_count if parts is not None else 0


def _refuse_parts_store(store: Path) -> None:
    """A build into ``OWNER/parts`` itself would replace its sub-entries with whole files."""
    from ..store.files import build_command, owner_of_parts

    owner = owner_of_parts(store)
    if owner is not None:
        raise UsageError(f"{store} is the sub-parts store of {owner}, made by its builds with --parts:"
                         f" '{build_command(store)}' builds it")


def _shard_walk(walk, options: BuildOptions):
    """The walk narrowed to the files of ``options.shard`` (the whole walk without one)."""
    if options.shard is None:
        return walk
    from ..store.shards import shard_of_paths

    k, count = options.shard
    mine = shard_of_paths([f.path for f in walk.files], count) == k
    walk.files = [f for f, keep in zip(walk.files, mine.tolist()) if keep]
    if k:
        walk.warnings = []  # the first shard's build says them
    return walk


def _parts_committer(store: Path, params, root: Path, options: BuildOptions, reporter, plan, walk,
                     summary: BuildSummary):
    """The committer of the parts store (``STORE/parts``), its plan merged into ``plan`` and
    counted in ``summary``."""
    from ..store.files import parts_store
    from .commit import PartsCommitter
    from .plan import plan_parts

    path = parts_store(store)
    writer = StoreWriter(path, params, root, options.wait, reporter.waiting, options.wait_timeout, options.repair,
                         reporter.warning)
    try:
        with open_store(path, skip_damaged=True) as reader:
            removed = plan_parts(plan, walk, reader, options)
    except BaseException:
        writer.close()
        raise
    _count_parts_plan(plan, removed, summary)
    committer = PartsCommitter(writer, options.commit_interval, options.merge_after, reporter)
    committer.remove(removed)
    return committer


def _parts_pruner(store: Path, params, root: Path, options: BuildOptions, reporter, plan, walk):
    """A build without ``--parts`` over a store that has sub-parts: the committer that removes
    the sub-entries of the files it removes or signs again, and gives those whose times only
    changed their new times (:func:`~shapeidx.index.plan.prune_parts`), so that ``where-used``
    never names a file the store no longer holds, nor the sub-parts of its old content. None
    when there is nothing to do; a damaged or locked parts store is left as it is, with a warning."""
    from ..store.files import parts_store
    from ..store.reader import StoreBeingCreated
    from .commit import PartsCommitter
    from .plan import prune_parts

    path = parts_store(store)
    if not path.is_dir():
        return None
    try:
        with open_store(path) as reader, open_store(store, skip_damaged=True) as main:
            removed, touched = prune_parts(plan, walk, reader, main)
        if not removed and not touched and not any(getattr(task, "old_parts", ()) for task in plan.tasks):
            return None
        writer = StoreWriter(path, params, root, options.wait, reporter.waiting, options.wait_timeout,
                             on_warning=reporter.warning)
    except StoreBeingCreated:
        return None  # a first build with --parts was stopped before committing: nothing to remove
    except ShapeidxError as exc:
        reporter.warning(f"the sub-parts of the files removed or signed again are left in {path}: {exc}")
        return None
    committer = PartsCommitter(writer, options.commit_interval, options.merge_after, reporter)
    committer.remove(removed)
    committer.batch.touched.extend(touched)
    committer.removed_count = len(removed)
    return committer


def _metadata_table(options: BuildOptions, root: Path, walk, reporter):
    """The ``--metadata`` table read and checked (None without it), with a warning for rows
    that name no part file of the tree."""
    if not options.metadata:
        return None
    from ..store.metadata import read_csv_table

    table, warnings = read_csv_table(options.metadata, root)
    for warning in warnings:
        reporter.warning(warning)
    known = {f.path for f in walk.files}
    strays = [p for p in table.paths if p not in known]
    if strays and (options.shard is None or options.shard[0] == 0):  # a sharded build says it once
        reporter.warning(f"--metadata {options.metadata}: {len(strays)} of its {len(table)} rows name no part file of"
                         f" {root} (first: {strays[0]}); they are kept and match no entry")
    return table


def _store_metadata(store: Path, table, reporter=None) -> bool:
    """Write the table into the store (the lock is held) unless it holds the same; True if it changed.
    A damaged table in the store is replaced (it is what --metadata gives again)."""
    from ..store.metadata import load_table, write_table

    try:
        current = load_table(store)
    except StoreDamagedError as exc:
        if reporter is not None:
            reporter.warning(f"the store's metadata table was damaged; written again from --metadata ({exc})")
        current = None
    if current is not None and current.sha256 == table.sha256 and current.source == table.source:
        return False
    write_table(store, table)
    return True


def check_tree(given, root: Path) -> None:
    """Refuse, in one line, a tree that is missing, not a directory, or cannot be listed."""
    import os

    if not root.exists():
        raise ShapeidxError(f"{given}: no such directory")
    if not root.is_dir():
        raise ShapeidxError(f"{given}: not a directory (give the folder of the part files)")
    try:
        os.scandir(root).close()
    except OSError as exc:
        raise ShapeidxError(f"{given}: cannot list the directory: {exc.strerror or exc}") from None


def _refuse_empty(given, walk) -> None:
    """A tree without a single part file is a mistake (an unmounted share would empty the store)."""
    if not walk.files and not walk.unlisted:
        from ..io import suffixes

        raise ShapeidxError(
            f"{given}: no part files in this directory tree (looked for {' '.join(suffixes())}, also gzipped);"
            " nothing was indexed or changed"
        )
def _pool(options: BuildOptions, params: StoreParams, root: Path):
    """Local worker processes, or a Dask cluster's workers with ``--scheduler``."""
    if options.scheduler:
        from .dask_pool import DaskPool

        return DaskPool(options.scheduler, params, str(root), options.timeout, options.worker_root)
    return WorkerPool(options.workers or available_cores(), params, str(root), options.timeout, options.worker_memory)


def _dry_run(root: Path, store: Path, params: StoreParams, options, reporter, summary: BuildSummary) -> BuildSummary:
    """What a build would do, without the lock and without writing anything."""
    walk = walk_parts(root, options.follow_outside_links)
    table = _metadata_table(options, root, walk, reporter)
    walk = _shard_walk(walk, options)
    for warning in walk.warnings:
        reporter.warning(warning)
    if table is not None:
        summary.metadata_rows = len(table)
    if store.exists() or store.with_name(store.name + ".converting").exists():
        with open_store(store) as reader:
            check_params(reader, params)
            check_root(reader, root)
            plan = make_plan(walk, reader, options)
        _store_counts(store, summary)
    else:
        plan = Plan([Task(f.path, f.absolute) for f in walk.files], 0, [], len(walk.files))
    if options.parts:
        _plan_parts_dry(store, walk, plan, options, summary)
    summary.found, summary.unchanged = plan.found, plan.unchanged
    summary.planned = sum(getattr(task, "whole", True) for task in plan.tasks)
    summary.older = dict(plan.older)
    summary.older_parts = dict(plan.older_parts)
    summary.removed = len(plan.removed)
    reporter.planned(plan)
    return summary


def _plan_parts_dry(store: Path, walk, plan, options, summary: BuildSummary) -> None:
    """``build --parts --dry-run``: the parts store's plan merged into ``plan`` (as a build
    does), its counts into ``summary``; the parts store only read."""
    from ..store.files import parts_store
    from .plan import plan_parts

    path = parts_store(store)
    if path.exists():
        from ..store.known import known_files

        with open_store(path, skip_damaged=True) as reader:
            removed = plan_parts(plan, walk, reader, options)
            summary.parts_entries = known_files(reader).status_counts()[0]
    else:
        removed, summary.parts_entries = plan_parts(plan, walk, None, options), 0
    _count_parts_plan(plan, removed, summary)


def _count_parts_plan(plan, removed: list, summary: BuildSummary) -> None:
    summary.parts_planned = sum(bool(getattr(task, "parts", False)) for task in plan.tasks)
    summary.parts_removed = len(removed)


_QUOTED = re.compile(r"""'[^']*'|"[^"]*"|`[^`]*`""")


def _redact_outside(outcome: Outcome, root: Path) -> None:
    """A failure reason of a file outside the tree (--follow-outside-links) quotes none of its content.

    Reasons quote what they found ("unexpected 'root:x:0:0:...'"); the store and the log may
    be read by people who may not read the files a link points to.
    """
    if outcome.kind != "failed" or outcome.entry is None:
        return
    real = os.path.realpath(outcome.task.absolute)
    if real == str(root) or real.startswith(str(root).rstrip(os.sep) + os.sep):
        return
    outcome.entry.reason = _QUOTED.sub("'...'", outcome.entry.reason) + " (outside the indexed folder: quotes left out)"


def _count(summary: BuildSummary, outcome: Outcome) -> None:
    if outcome.parts is not None:
        summary.parts_indexed = (summary.parts_indexed or 0) + sum(e.status == 0 for e in outcome.parts)
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
    from ..store.known import known_files

    with open_store(store) as reader:  # by path key: no path decoded, whatever the journal holds
        summary.store_ok, summary.store_failed = known_files(reader).status_counts()
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
