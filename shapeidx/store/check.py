"""Verifying a store (``shapeidx check``) and repairing a damaged one (``build --repair``).

A check reads every file of the store (the main file and the journal batches it does not
hold yet) dataset by dataset, chunk by chunk, so that a damaged chunk is pinned to the
entries it holds:

* structure: every dataset is there, every column has one row per entry, paths are sorted
  and unique, statuses are ``ok`` or ``failed``;
* checksums: the Fletcher-32 of every chunk (stores written before checksums have none and
  are reported as such, not as damaged), the content hash of every string column;
* offsets: histogram offsets start at 0, never decrease and end at the counts' length;
* totals: an ok entry's ALL histogram holds ``points * (points - 1) / 2`` pairs, its IN, OUT
  and MIXED histograms as many together, and its class fractions are theirs;
* with ``files``: every entry's file still exists and hashes to the stored SHA-256.

A repair keeps every entry that passes and drops the others, so that the build that runs
the repair indexes their files again: a damaged journal batch is deleted (losing at most
its work), a main file damaged in some rows is rewritten without them, and a main file
that cannot be read at all is set aside (renamed ``STORE/main.h5.damaged-TIME``) and the store is
built again from its files.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from ..errors import StoreError
from ..io.base import file_hash
from .heaps import open_hdf5
from ..signing.parameters import HISTOGRAMS
from .files import PARTS, batch_files, main_file, owner_of_parts, parts_store, recovery_commands, write_atomically
from .layout import (
    CONTENT_HASH,
    COUNT_DTYPE,
    ENTRY_COLUMNS,
    MAY_BE_ABSENT,
    FRACTION_CLASSES,
    STATUS_FAILED,
    STATUS_OK,
    as_text,
    checked,
    object_array,
    strings_hash,
    write_columns,
    write_counts,
)
from .lock import StoreLock
from .metadata import METADATA_FILE, load_table
from .reader import StoreBeingCreated, check_store_directory, damaged, open_store, resolve_store_path
from .shards import is_sharded, shard_paths


@dataclass
class Problem:
    """One thing wrong: in which ``file`` of the store, which dataset or entry (``what``), and how."""

    file: str
    what: str
    problem: str

    def line(self) -> str:
        return f"{self.file}: {self.what}: {self.problem}"

    def to_dict(self) -> dict:
        return {"file": self.file, "what": self.what, "problem": self.problem}


@dataclass
class FileScan:
    """What a check found in one file of the store."""

    path: Path
    seq: int
    entries: int = 0
    problems: list = field(default_factory=list)
    #: Rows that fail a check (their entries are dropped by a repair).
    bad_rows: set = field(default_factory=set)
    #: The file cannot be used at all (unreadable, paths lost, structure broken).
    unusable: bool = False
    checksummed: bool = True
    columns: dict = field(default_factory=dict)
    #: How many entry columns the file holds (an older file lacks some optional ones): the
    #: ranking arrays are compared with the entries only when every one of them was read.
    columns_held: int = 0
    counts: dict = field(default_factory=dict)  # name -> (flat counts, offsets), bad chunks zeroed
    #: The ranking section (derived data) is damaged / absent (a file of layout 2 or older).
    rank_damaged: bool = False
    rank_missing: bool = False

    @property
    def only_ranking(self) -> bool:
        """Whether every problem is in the ranking section (rebuilt from the sound entries)."""
        return bool(self.problems) and all(p.what == "rank" for p in self.problems)

    def problem(self, what: str, text: str, rows=None, fatal: bool = False) -> None:
        self.problems.append(Problem(self.path.name, what, text))
        if rows is not None:
            self.bad_rows.update(int(r) for r in rows)
        if fatal:
            self.unusable = True


@dataclass
class CheckReport:
    """What ``shapeidx check`` found in a store."""

    store: Path
    entries: int = 0
    files: int = 0
    checksummed: bool = True
    files_hashed: int = 0
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    #: The check of the store's sub-parts (``STORE/parts``, ``build --parts``); None: it has none.
    parts: "CheckReport | None" = None
    #: A sharded store's: each shard's check, in shard order; None: not a sharded store.
    shards: "list | None" = None

    def summary(self) -> str:
        if self.shards is not None:
            where = f"{self.files} file(s) of {len(self.shards)} shards"
            if self.problems:
                # damaged sub-parts of a shard are rebuilt by the owner's build with --parts
                parts = next((s.parts.store for s in self.shards if s.parts is not None and s.parts.problems), None)
                repair, _ = recovery_commands(parts or self.store)
                return (f"{self.store}: DAMAGED: {len(self.problems)} problem(s) in {where};"
                        f" '{repair}' rebuilds the damaged entries")
            sums = "checksums verified" if self.checksummed else "some files have no checksums"
            hashed = f", {self.files_hashed} files hash as stored" if self.files_hashed else ""
            return f"{self.store}: ok: {self.entries} entries in {where}, {sums}{hashed}"
        if self.problems:
            repair, _ = recovery_commands(self.parts.store if self.parts and self.parts.problems else self.store)
            return (f"{self.store}: DAMAGED: {len(self.problems)} problem(s) in {self.files} file(s);"
                    f" '{repair}' rebuilds the damaged entries")
        sums = "checksums verified" if self.checksummed else "no checksums (written by an older shapeidx)"
        hashed = f", {self.files_hashed} files hash as stored" if self.files_hashed else ""
        parts = f"; sub-parts ok: {self.parts.entries} entries in {self.parts.files} file(s)" if self.parts else ""
        return f"{self.store}: ok: {self.entries} entries in {self.files} file(s), {sums}{hashed}{parts}"

    def to_dict(self) -> dict:
        return {
            "store": str(self.store),
            "ok": not self.problems,
            "entries": self.entries,
            "files": self.files,
            "checksummed": self.checksummed,
            "files_hashed": self.files_hashed,
            "problems": [p.to_dict() for p in self.problems],
            "notes": self.notes,
            "parts": None if self.parts is None else self.parts.to_dict(),
            "shards": None if self.shards is None else [shard.to_dict() for shard in self.shards],
        }


def usable_store_path(store) -> Path:
    """The store path of the command line (``--store``, ``$SHAPEIDX_STORE``, the default)."""
    return resolve_store_path(store)


def scan_file(path: Path, seq: int, points: int | None, derived: bool = True) -> FileScan:
    """Read and check every dataset of one store file; see the module docstring. ``derived``:
    also rebuild the ranking arrays in memory and compare (else only their checksums)."""
    scan = FileScan(path, seq)
    try:
        f = open_hdf5(path)
    except OSError as exc:
        scan.problem("file", f"not readable as HDF5 ({_first_line(exc)})", fatal=True)
        return scan
    with f:
        try:
            n = int(f["entries/size"].shape[0])
        except (KeyError, OSError, RuntimeError, ValueError) as exc:
            scan.problem("entries/size", f"missing or unreadable ({_first_line(exc)})", fatal=True)
            return scan
        scan.entries = n
        expected = [name for name in ENTRY_COLUMNS if name not in MAY_BE_ABSENT or _present(f, name)]  # older files lack some
        scan.columns_held = len(expected)
        for name, (dtype, _) in ENTRY_COLUMNS.items():
            if name not in expected:
                continue
            values = _scan_dataset(scan, f, name, dtype, n)
            if values is not None:
                scan.columns[name] = values
        if "entries/path" not in scan.columns:
            scan.unusable = True  # without its paths no entry of the file can be trusted
            return scan
        paths = scan.columns["entries/path"]
        if len(paths) > 1 and not np.all(paths[1:] > paths[:-1]):
            scan.problem("entries/path", "paths are not sorted and unique", fatal=True)
        if "entries/status" in scan.columns:
            status = scan.columns["entries/status"]
            odd = np.flatnonzero((status != STATUS_OK) & (status != STATUS_FAILED))
            if len(odd):
                scan.problem("entries/status", f"{len(odd)} status value(s) are neither ok nor failed", odd)
        for name in HISTOGRAMS:
            _scan_histogram(scan, f, name, n)
        if len(scan.columns) < len(expected) or len(scan.counts) < len(HISTOGRAMS):
            scan.unusable = True  # a whole column lost: rebuild rather than guess
        _check_totals(scan, points)
        for group in ("touched", "removed"):
            if group in f:
                _scan_dataset(scan, f, f"{group}/path", object, None, whole_file=True)
        if "touched" in f:
            for name in ("touched/size", "touched/mtime_ns"):
                _scan_dataset(scan, f, name, np.int64, None, whole_file=True)
        _scan_ranking(scan, f, derived)
    return scan


def _scan_ranking(scan: FileScan, f: h5py.File, derived: bool = True) -> None:
    """The ``rank/`` section: its checksums, and that it is what the checked canonical data make."""
    from .rank import RANK, RankSection, expected_rank

    version = int(f.attrs.get("schema_version", 0))
    if RANK not in f:
        if version >= 3:
            scan.problem(RANK, "missing (the ranking arrays: 'shapeidx check --repair' rebuilds them)")
            scan.rank_damaged = True
        else:
            scan.rank_missing = True
        return
    try:
        section = RankSection(f, scan.path)
        wrong = section.verify()
    except (KeyError, OSError, RuntimeError, ValueError) as exc:
        wrong = [f"{RANK} cannot be used ({_first_line(exc)})"]
    if derived and not wrong and not scan.problems and len(scan.counts) == len(HISTOGRAMS) and len(scan.columns) == scan.columns_held:
        counts = {name: (flat, np.diff(offsets)) for name, (flat, offsets) in scan.counts.items()}
        for name, values in expected_rank(scan.columns, counts, section.histograms):
            if not np.array_equal(section.array(name), values, equal_nan=True):  # NaN: unknown angles
                wrong.append(f"{RANK}/{name} disagrees with the entries it is made from")
    for text in wrong:
        scan.problem(RANK, f"{text} ('shapeidx check --repair' rebuilds the ranking arrays)")
        scan.rank_damaged = True


def _present(f: h5py.File, name: str) -> bool:
    """Whether ``f`` has ``name``; a lookup the damage makes fail counts as present (its scan reports it)."""
    try:
        return name in f
    except (KeyError, OSError, RuntimeError, ValueError):
        return True


def _scan_dataset(scan: FileScan, f: h5py.File, name: str, dtype, n: int | None, whole_file: bool = False):
    """A dataset's values, read chunk by chunk; damaged chunks are problems (their rows bad)."""
    try:
        dataset = f[name]
    except (KeyError, OSError, RuntimeError, ValueError) as exc:
        scan.problem(name, f"missing or unreadable ({_first_line(exc)})", range(n or 0), fatal=whole_file)
        return None
    if n is not None and (not dataset.shape or dataset.shape[0] != n):
        scan.problem(name, f"{dataset.shape[0] if dataset.shape else 0} rows, not {n}", range(n), fatal=True)
        return None
    if dtype is object:
        try:
            values = dataset.asstr()[()] if dataset.shape[0] else object_array([])
        except (OSError, RuntimeError, ValueError, UnicodeDecodeError) as exc:
            scan.problem(name, f"cannot be read ({_first_line(exc)})", range(n or 0), fatal=name.endswith("path"))
            return None
        if CONTENT_HASH in dataset.attrs:
            if strings_hash(values) != as_text(dataset.attrs[CONTENT_HASH]):
                fatal = name.endswith("/path")
                scan.problem(name, "fails its content checksum", range(n or 0), fatal=fatal or whole_file)
                return None
        elif dataset.shape[0]:
            scan.checksummed = False
        return values
    return _read_chunks(scan, dataset, name, n if n is not None else dataset.shape[0], whole_file)


def _read_chunks(scan: FileScan, dataset: h5py.Dataset, name: str, n: int, whole_file: bool):
    total = dataset.shape[0]
    if total == 0:
        return dataset[()]
    if dataset.fletcher32 is False:
        scan.checksummed = False
    step = dataset.chunks[0] if dataset.chunks else total
    out = np.zeros(dataset.shape, dtype=dataset.dtype)
    for lo in range(0, total, step):
        hi = min(lo + step, total)
        try:
            out[lo:hi] = dataset[lo:hi]
        except (OSError, RuntimeError, ValueError) as exc:
            rows = range(lo, min(hi, n)) if n else ()
            scan.problem(name, f"values {lo}..{hi - 1} fail their checksum ({_first_line(exc)})", rows,
                         fatal=whole_file)
    return out


def _scan_histogram(scan: FileScan, f: h5py.File, name: str, n: int) -> None:
    key = f"histograms/{name}/offsets"
    offsets = _scan_dataset(scan, f, key, np.int64, None)
    if offsets is None:
        scan.bad_rows.update(range(n))
        return
    counts_key = f"histograms/{name}/counts"
    try:
        counts_dataset = f[counts_key]
    except (KeyError, OSError, RuntimeError, ValueError) as exc:
        scan.problem(counts_key, f"missing or unreadable ({_first_line(exc)})", range(n))
        return
    total = counts_dataset.shape[0]
    if offsets.shape != (n + 1,) or offsets[0] != 0 or np.any(np.diff(offsets) < 0) or offsets[-1] != total:
        scan.problem(key, f"out of bounds ({len(offsets)} offsets for {n} entries and {total} counts)", range(n))
        return
    marker = len(scan.problems)
    flat = _read_chunks(scan, counts_dataset, counts_key, 0, False)
    starts, ends = offsets[:-1], offsets[1:]
    for problem in scan.problems[marker:]:  # a damaged chunk of counts: the entries it overlaps
        # "values LO..HI fail their checksum"
        lo, last = (int(v) for v in problem.problem.split(" ")[1].split(".."))
        scan.bad_rows.update(int(i) for i in np.flatnonzero((starts <= last) & (ends > lo) & (ends > starts)))
    scan.counts[name] = (flat.astype(COUNT_DTYPE, copy=False), offsets)


def _check_totals(scan: FileScan, points: int | None) -> None:
    """Pair totals and fractions of ok entries agree with the store's point count."""
    if points is None or "entries/status" not in scan.columns or len(scan.counts) != len(HISTOGRAMS):
        return
    ok = np.flatnonzero(scan.columns["entries/status"] == STATUS_OK)
    ok = ok[~np.isin(ok, np.fromiter(scan.bad_rows, dtype=np.int64, count=len(scan.bad_rows)))]  # already known bad
    if len(ok) == 0:
        return
    sums = {}
    for name, (flat, offsets) in scan.counts.items():
        cumulative = np.concatenate([[0], np.cumsum(flat, dtype=np.int64)])
        sums[name] = cumulative[offsets[ok + 1]] - cumulative[offsets[ok]]
    pairs = points * (points - 1) // 2
    wrong = ok[(sums["all"] != pairs) | (sums["in"] + sums["out"] + sums["mixed"] != pairs)]
    if len(wrong):
        scan.problem("histograms", f"{len(wrong)} ok entr(y/ies) whose histograms do not hold {pairs} pairs"
                     f" (first: {scan.columns['entries/path'][wrong[0]]})", wrong)
    if "entries/fractions" in scan.columns:
        shares = np.stack([sums[c] for c in FRACTION_CLASSES], axis=1) / pairs
        off = ok[~np.all(np.abs(scan.columns["entries/fractions"][ok] - shares) <= 1e-9, axis=1)]
        if len(off):
            scan.problem("entries/fractions", f"{len(off)} ok entr(y/ies) whose class fractions disagree with"
                         f" their histograms (first: {scan.columns['entries/path'][off[0]]})", off)


def _store_files(store: Path) -> tuple[list, int | None, dict]:
    """(seq, path) of the main file and the batches it does not hold, its points, its attributes."""
    attrs = {}
    try:
        with open_hdf5(main_file(store)) as f:
            attrs = {k: (as_text(v) if isinstance(v, (bytes, str)) else v) for k, v in f.attrs.items()}
    except (OSError, KeyError, RuntimeError, ValueError):  # h5py says KeyError for a damaged object header
        pass  # the main file's own scan reports it
    merged = int(attrs.get("journal_seq", 0))
    points = int(attrs["points"]) if "points" in attrs else None
    return [(0, main_file(store))] + [(seq, p) for seq, p in batch_files(store) if seq > merged], points, attrs


def check_store(store, files: bool = False) -> CheckReport:
    """Check a store (see the module docstring); ``files``: also hash every entry's file."""
    store = Path(store)
    check_store_directory(store)
    if is_sharded(store):
        return _check_sharded(store, files)
    if not main_file(store).exists():
        open_store(store).close()  # the reader's one line: not a store, being created, or damaged (5)
    report = CheckReport(store)
    sources, points, attrs = _store_files(store)
    if attrs and ("schema_version" not in attrs or "points" not in attrs):
        raise StoreError(f"{store} is not a shapeidx store")
    scans = [scan_file(path, seq, points) for seq, path in sources]
    # a batch that a running build's merge deleted meanwhile is not damage
    scans = [scan for scan in scans if scan.seq == 0 or scan.path.exists() or not scan.problems]
    report.files = len(scans)
    for scan in scans:
        report.problems.extend(scan.problems)
        report.entries += scan.entries
        report.checksummed &= scan.checksummed
    if any(scan.rank_missing for scan in scans):
        report.notes.append("some files have no ranking arrays (written before layout 3): queries read them"
                            " the slow way until 'shapeidx check --repair' adds them")
    if not report.checksummed:
        report.notes.append("some datasets have no checksums (written by an older shapeidx): a build's next"
                            " merge that rewrites the main file adds them (build --full does)")
    if not report.problems:  # every file sound: is one missing? (a gap in the journal)
        from ..errors import StoreDamagedError

        try:
            open_store(store).close()
        except StoreDamagedError as exc:
            text = str(exc)
            what = text[text.index("damaged (") + 9 : text.rindex("): ")] if "damaged (" in text and "): " in text else text
            report.problems.append(Problem(store.name, "journal", what))
    _check_metadata(store, report)
    if files and not report.problems:
        _check_files(store, attrs.get("root"), report)
    _check_parts(store, report)
    return report


def _check_sharded(store: Path, files: bool) -> CheckReport:
    """A sharded store: every shard checked as a store of its own (its sub-parts too), its
    problems named ``shards/K/FILE``, its notes ``shards/K: ...``."""
    report = CheckReport(store, shards=[])
    for path in shard_paths(store):
        name = f"shards/{path.name}"
        if not path.exists():  # shards are made as the sharded build reaches them: a killed first build
            report.notes.append(f"{name}: holds nothing yet (no build has reached it; the next build fills it)")
            report.shards.append(CheckReport(path))
            continue
        try:
            shard = check_store(path, files=files)
        except StoreBeingCreated:
            report.notes.append(f"{name}: its first build has committed nothing yet")
            continue
        except StoreError as exc:
            shard = CheckReport(path, problems=[Problem(name, "store", str(exc))])
            report.problems.extend(shard.problems)
        else:
            report.problems.extend(Problem(f"{name}/{p.file}", p.what, p.problem) for p in shard.problems)
        report.shards.append(shard)
        report.entries += shard.entries
        report.files += shard.files
        report.files_hashed += shard.files_hashed
        report.checksummed &= shard.checksummed
        report.notes.extend(f"{name}: {note}" for note in shard.notes)
    return report


def _check_parts(store: Path, report: CheckReport) -> None:
    """The sub-parts store (``STORE/parts``) checked as a store of its own, its problems
    named ``parts/FILE`` in ``report`` (its entries ``FILE#n`` have no file of their own to hash)."""
    sub = parts_store(store)
    if not sub.is_dir() or owner_of_parts(store) is not None:
        return
    try:
        report.parts = check_store(sub)
    except StoreBeingCreated:
        report.notes.append(f"{PARTS}: the first build with --parts has committed nothing yet")
        return
    except StoreError as exc:
        report.parts = CheckReport(sub, problems=[Problem(PARTS, "store", str(exc))])
    report.problems.extend(Problem(f"{PARTS}/{p.file}", p.what, p.problem) for p in report.parts.problems)
    report.notes.extend(f"{PARTS}: {note}" for note in report.parts.notes)


def _check_metadata(store: Path, report: CheckReport) -> None:
    """The --metadata table (STORE/metadata.h5), read as every command reads it."""
    from ..errors import StoreDamagedError

    try:
        load_table(store)
    except StoreDamagedError as exc:
        text = str(exc)
        what = text[text.index("damaged (") + 9 : text.rindex("): ")] if "damaged (" in text and "): " in text else text
        report.problems.append(Problem(METADATA_FILE, "table", what + "; 'shapeidx build DIR --metadata TABLE.csv'"
                                                                      " writes it again"))


def _check_files(store: Path, root: str | None, report: CheckReport) -> None:
    """Every entry's file (of the merged view) still exists and hashes as stored."""
    with open_store(store) as reader:
        hashes = reader.column("entries/hash")
        for path, digest in zip(reader.paths, hashes):
            expected = digest.decode()
            if not expected:
                continue  # could not be read when indexed: nothing to compare
            absolute = os.path.join(root or "", str(path))
            try:
                actual = file_hash(absolute)
            except OSError as exc:
                report.problems.append(Problem(store.name, str(path), f"the file cannot be read ({exc.strerror or exc})"))
                continue
            report.files_hashed += 1
            if actual != expected:
                report.problems.append(Problem(store.name, str(path), "the file changed since it was indexed"
                                               " (a build signs it again)"))


def refuse_damaged(store: Path) -> None:
    """Raise the one-line :class:`StoreDamagedError` if the store's main file fails a check.

    ``build`` calls this before it changes anything (journal batches are verified whenever a
    store is opened). It reads the whole main file (about a second per 100 MB) unless that
    very file passed before or was written by the store's own merge (``STORE/verified``,
    :mod:`shapeidx.store.verified`); the caller holds the lock.
    """
    from .verified import identity, is_verified, mark_verified

    store = Path(store)
    if not main_file(store).exists() or is_verified(store):
        return
    before = identity(store)
    _, points, attrs = _store_files(store)
    scan = scan_file(main_file(store), 0, points, derived=False)  # every checksum; the full comparison is check's
    if scan.problems:
        first = scan.problems[0]
        more = f" and {len(scan.problems) - 1} more" if len(scan.problems) > 1 else ""
        raise damaged(store, f"{first.what}: {first.problem}{more}", attrs.get("root"))
    mark_verified(store, before)


def repair_store(store: Path) -> list[str]:
    """Make a damaged store usable again by dropping what is damaged; returns what was done.

    The caller holds the store's lock (``build --repair`` runs this before it plans, so the
    dropped entries' files are indexed again by the same build).
    """
    store = Path(store)
    if not main_file(store).exists():
        return []
    sources, points, attrs = _store_files(store)
    done = []
    for seq, path in sources[1:]:
        scan = scan_file(path, seq, points)
        if scan.only_ranking:
            done.extend(rebuild_ranking(store, [scan]))
        elif scan.problems:
            path.unlink(missing_ok=True)
            done.append(f"repair: dropped the damaged journal batch {path.name} ({scan.problems[0].problem});"
                        " its files are indexed again")
    main = scan_file(main_file(store), 0, points)
    if main.only_ranking:
        return done + rebuild_ranking(store, [main])
    if not main.problems:
        return done
    if main.unusable or not attrs:
        aside = store / f"{main_file(store).name}.damaged-{time.strftime('%Y%m%dT%H%M%S')}"
        os.replace(main_file(store), aside)
        for _, path in sources[1:]:
            path.unlink(missing_ok=True)  # batches apply to the main file they followed
        done.append(f"repair: the main file could not be used ({main.problems[0].line()}); it was moved to"
                    f" {aside.name} and every file is indexed again")
        return done
    keep = np.setdiff1d(np.arange(main.entries), np.fromiter(main.bad_rows, dtype=np.int64, count=len(main.bad_rows)))
    _rewrite_main(store, main, keep, attrs)
    done.append(f"repair: {main.entries - len(keep)} damaged entr(y/ies) of the main file dropped"
                f" ({main.problems[0].line()}); their files are indexed again")
    return done


def rebuild_ranking(store: Path, scans: list | None = None) -> list[str]:
    """Rewrite every file of the store whose ranking section is damaged or missing (layout 2
    or older) with a fresh one made from its checked entries; returns what was done.

    The caller holds the store's lock (``check --repair``, ``build --repair``). A file whose
    entries themselves fail a check is left alone (``build --repair`` drops those entries).
    """
    store = Path(store)
    if scans is None:
        sources, points, _ = _store_files(store)
        scans = [scan_file(path, seq, points) for seq, path in sources]
    done = []
    for scan in scans:
        if not (scan.rank_missing or (scan.rank_damaged and scan.only_ranking)) or not scan.path.exists():
            continue
        _rewrite_ranking(scan)
        why = "none: written before layout 3" if scan.rank_missing else scan.problems[0].problem
        done.append(f"repair: rebuilt the ranking arrays of {scan.path.name} ({why})")
    return done


def repair_ranking(store: Path) -> list[str]:
    """``check --repair``: :func:`rebuild_ranking` of the store and of its sub-parts store
    (``STORE/parts``), each under its own lock; returns what was done."""
    done = []
    sub = parts_store(store)
    for target in (Path(store), sub) if sub.is_dir() and main_file(sub).exists() else (Path(store),):
        lock = StoreLock(target)
        lock.acquire()
        try:
            done += [line if target == Path(store) else f"{PARTS}: {line}" for line in rebuild_ranking(target)]
        finally:
            lock.release()
    return done


def _rewrite_ranking(scan: FileScan) -> None:
    """``scan.path`` again, atomically: every group but ``rank/`` copied as it is, a new ``rank/``."""
    from .rank import RANK, write_rank

    counts = {name: (flat, np.diff(offsets)) for name, (flat, offsets) in scan.counts.items()}

    def fill(f):
        with open_hdf5(scan.path) as old:
            f.attrs.update(dict(old.attrs))
            for name in old:
                if name != RANK:
                    old.copy(old[name], f, name=name)
        write_rank(f, scan.columns, counts, HISTOGRAMS)

    write_atomically(scan.path, fill, 3 * scan.path.stat().st_size)


def _rewrite_main(store: Path, scan: FileScan, keep: np.ndarray, attrs: dict) -> None:
    """The main file again with only the rows ``keep`` (all of them checked), atomically."""
    from .layout import utc_now
    from .rank import write_rank

    columns = {name: scan.columns[name][keep] for name in ENTRY_COLUMNS if name in scan.columns}
    counts = {}
    for name in HISTOGRAMS:
        flat, offsets = scan.counts[name]
        lengths = (offsets[1:] - offsets[:-1])[keep]
        pieces = [flat[offsets[i] : offsets[i + 1]] for i in keep]
        counts[name] = (np.concatenate(pieces) if pieces else np.zeros(0, dtype=COUNT_DTYPE), lengths)

    def fill(f):
        f.attrs.update({**attrs, "updated": utc_now()})
        write_columns(f, columns)
        for name, (values, lengths) in counts.items():
            write_counts(f, name, values, lengths)
        write_rank(f, columns, counts, HISTOGRAMS)

    write_atomically(main_file(store), fill, 2 * main_file(store).stat().st_size)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__


__all__ = ["CheckReport", "Problem", "check_store", "rebuild_ranking", "repair_store", "scan_file", "usable_store_path",
           "checked"]
