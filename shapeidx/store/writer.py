"""The one writer of a store: its commits (journal batches) and its merges.

A build commits its progress as a new batch file in the journal. The journal's files are
*segments*, oldest first, each applied on top of the ones before it (and of the main file); a
merge combines the newest ones, size-tiered like an LSM tree, so that a commit and its merge
cost what changed, not the size of the store:

* the newest segments are merged into one as long as the one before them holds at most
  :data:`GROWTH` times as many rows as they do together: segments grow geometrically from
  the newest to the oldest, there are O(log N) of them, and each entry is rewritten
  O(log N) times over its life;
* a merge of batches a..b writes the segment ``batch-b`` (attribute ``first_seq`` = a),
  renames it over the old ``batch-b``, and only then deletes a..b-1; a reader that still
  sees them gets the same view (the new segment supersedes everything they hold), and
  :func:`~shapeidx.store.reader.open_store` leaves them out;
* when the cascade reaches the main file (or the journal holds :data:`MAX_SEGMENTS`
  segments) a fresh main file holding everything is written and renamed over the old one,
  and only then are the segments deleted. The main file records the last batch it holds
  (``journal_seq``), so segments that outlive a kill between that rename and their deletion
  are ignored, never applied twice.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from ..errors import StoreError
from ..ragged import offsets_of
from ..signing.parameters import HISTOGRAMS
from .files import (batch_files, journal_dir, main_file, remove_if_empty, write_atomically,
                    write_committed)
from .layout import (
    COUNT_DTYPE,
    ENTRY_COLUMNS,
    MERGE_ROWS,
    SCHEMA_VERSION,
    StoreParams,
    utc_now,
    entries_to_columns,
    write_columns,
    write_counts,
    write_paths,
    write_int64,
    checked,
)
from .rank import write_rank, write_rank_entries, write_rank_histogram
from .lock import StoreLock, record_build
from .reader import StoreReader, check_params, check_root, damaged, open_store
from .heaps import open_hdf5

from .verified import mark_verified
from .check import refuse_damaged, repair_store
from .convert import convert_one_file_store

#: A run of the newest segments is merged into the segment before it while that one holds at
#: most GROWTH times their rows (see the module docstring).
GROWTH = 2
#: Segments the journal holds at most: beyond, everything is merged into the main file.
MAX_SEGMENTS = 32
#: A finishing build folds the journal into the main file when the journal holds at least
#: this share of the main file's rows (:meth:`StoreWriter.checkpoint`).
FOLD_SHARE = 0.25


def _make_store_directory(store: Path) -> None:
    """Create the store's directory, or accept an existing one that is a store (or empty).

    A directory that holds other files is refused: ``--store`` naming a folder of parts by
    mistake must not put a store inside it.
    """
    if store.is_dir():
        ours = {"main.h5", "journal", "lock", "build.json", "verified", "thumbs", "committed", "metadata.h5", "parts"}
        others = [p.name for p in store.iterdir() if p.name not in ours and ".tmp-" not in p.name
                  and not p.name.startswith("main.h5.")]
        if others and not main_file(store).exists():
            raise StoreError(f"{store} is a directory that is not a shapeidx store (it holds {others[0]!r});"
                             " give --store a new name (the build creates the store's directory)")
        return
    if store.exists():
        raise StoreError(f"{store} is not a shapeidx store (a store is a directory; this is a file)")
    if not store.parent.is_dir():
        raise StoreError(f"cannot create the store {store}: no directory {store.parent}")
    try:
        store.mkdir(exist_ok=True)
    except OSError as exc:
        raise StoreError(f"cannot create the store {store}: {exc.strerror or exc}") from None


@dataclass
class Batch:
    """What one commit adds to the store: new or changed entries, touched and removed paths."""

    entries: list = field(default_factory=list)
    #: (path, size, mtime_ns): same content, new file times; the signature is kept.
    touched: list = field(default_factory=list)
    removed: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.entries) + len(self.touched) + len(self.removed)


class StoreWriter:
    """The one writer of a store (holds its lock): commits batches, merges the journal.

    Parameters
    ----------
    path : Path
    params : StoreParams
        The build's parameters; an existing store with others is refused.
    root : Path
        The indexed directory; an existing store of another directory is refused.
    wait : bool
        Wait for another build's lock instead of refusing at once.
    """

    def __init__(self, path: Path, params: StoreParams, root: Path, wait: bool = False, on_wait=None,
                 wait_timeout: float | None = None, repair: bool = False, on_warning=None):
        self.path = Path(path)
        self.params = params
        self.root = str(root)
        self.on_warning = on_warning or (lambda text: None)

        if convert_one_file_store(self.path, wait, on_wait, wait_timeout):
            self.on_warning(f"converted {self.path} from the one-file layout into a store directory (renames only)")
        _make_store_directory(self.path)
        self.lock = StoreLock(self.path)
        self.lock.acquire(wait, on_wait, wait_timeout)
        try:
            if repair:
                for line in repair_store(self.path):
                    self.on_warning(line)
            refuse_damaged(self.path)  # with the lock held: no merge can change it meanwhile
            self._prepare(repair)
            record_build(self.path, "running")
        except BaseException:
            self.lock.release()
            raise

    def _prepare(self, repair: bool = False) -> None:
        from .files import committed_path

        self._remove_leftovers()
        if not main_file(self.path).exists():
            if not repair and (journal_dir(self.path).exists() or committed_path(self.path).exists()):
                raise damaged(self.path, f"its main file {main_file(self.path).name} is missing")
            self._create_empty()
        with open_store(self.path, skip_damaged=True) as reader:
            check_params(reader, self.params)
            check_root(reader, self.root)
            self.merged_seq = int(reader.attrs["journal_seq"])
            skipped = reader.skipped
            missing = reader.missing
        for batch, reason in skipped:  # its work is redone: its files differ from their entries
            self.on_warning(f"dropped the damaged journal batch {batch.name} ({reason}); its files are indexed again")
            batch.unlink(missing_ok=True)
        if missing:
            self.on_warning(f"{missing}: the files it held are indexed again")
        # a gap in the journal (a segment dropped or lost) is closed by folding it into the main file
        self.must_fold = bool(skipped or missing)
        self.next_seq = max([self.merged_seq] + [seq for seq, _ in batch_files(self.path)]) + 1
        self.uncompacted = len(batch_files(self.path))  # a killed build's batches are merged at the next finish

    def _remove_leftovers(self) -> None:
        """Temporary files of killed writers, and batches already in the main file."""
        for folder in (self.path, journal_dir(self.path)):  # main.h5, verified, build.json, segments
            if folder.is_dir():
                for tmp in folder.glob("*.tmp-*"):
                    tmp.unlink(missing_ok=True)
        if main_file(self.path).exists():
            try:
                with open_hdf5(main_file(self.path)) as f:
                    merged = int(f.attrs["journal_seq"]) if "journal_seq" in f.attrs else 0
            except (OSError, KeyError, RuntimeError, ValueError):  # KeyError: h5py's word for a damaged header
                return  # a damaged main file: open_store says so next, in one line
            for seq, batch in batch_files(self.path):
                if seq <= merged:
                    batch.unlink(missing_ok=True)
            _remove_covered(self.path)

    def _main_attrs(self, journal_seq: int, extra: dict | None = None) -> dict:
        attrs = {
            "schema_version": SCHEMA_VERSION,
            "shapeidx_version": __version__,
            **self.params.as_attrs(),
            "histograms": " ".join(HISTOGRAMS),
            "root": self.root,
            "journal_seq": journal_seq,
            "updated": utc_now(),
        }
        attrs.update(extra or {})
        return attrs

    def _create_empty(self) -> None:
        columns, counts = entries_to_columns([])
        attrs = self._main_attrs(0, {"created": utc_now()})

        def fill(f):
            f.attrs.update(attrs)
            write_columns(f, columns)
            for name, (flat, lengths) in counts.items():
                write_counts(f, name, flat, lengths)
            write_rank(f, columns, counts, HISTOGRAMS)

        write_atomically(main_file(self.path), fill)

    @property
    def pending_batches(self) -> int:
        """Batches committed since the last merge (the journal also holds older, merged segments)."""
        return self.uncompacted

    def commit(self, batch: Batch) -> int:
        """Write ``batch`` to the journal (atomically); return its sequence number."""
        folder = journal_dir(self.path)
        try:
            folder.mkdir(exist_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot create the journal folder {folder}: {exc.strerror or exc}"
                             " (nothing was changed: the store is as it was)") from None
        seq = self.next_seq
        columns, counts = entries_to_columns(batch.entries)
        touched = sorted(batch.touched)

        def fill(f):
            f.attrs.update({"seq": seq, "schema_version": SCHEMA_VERSION, **self.params.as_attrs()})
            write_columns(f, columns)
            for name, (flat, lengths) in counts.items():
                write_counts(f, name, flat, lengths)
            write_rank(f, columns, counts, HISTOGRAMS)
            write_paths(f, "touched/path", [t[0] for t in touched])
            write_int64(f, "touched/size", [t[1] for t in touched])
            write_int64(f, "touched/mtime_ns", [t[2] for t in touched])
            write_paths(f, "removed/path", sorted(batch.removed))

        write_atomically(folder / f"batch-{seq:010d}.h5", fill, 2 * _bytes_of(columns, counts, batch))
        write_committed(self.path, seq)
        self.next_seq += 1
        self.uncompacted += 1
        return seq

    def merge(self) -> None:
        """Merge every segment into a fresh main file, rename it into place, drop the journal.

        Nothing is written when the journal is empty (and the main file has its ranking
        arrays): a build that changed nothing costs no rewrite of a large store.
        """
        self.compact(full=True)

    def compact(self, full: bool = False, fold: bool = False) -> str | None:
        """Merge the newest journal segments, size-tiered (see the module docstring); ``full``:
        everything into the main file, as :meth:`merge`; ``fold``: everything into the main
        file when the journal holds at least :data:`FOLD_SHARE` of its rows (what a build
        does when it finishes: see :meth:`checkpoint`).

        Nothing is written when no run of segments is due: a build that changed nothing
        costs no rewrite, and one that changed 100 files rewrites about 100 entries.

        Returns what was merged: ``"main"`` (everything into the main file), ``"segments"``
        (the newest segments into one), or None (nothing was due).
        """
        with open_store(self.path, skip_damaged=True) as reader:  # a gap is folded away, not refused
            segments = reader._sources[1:]
            if not segments and not (full and reader._sources[0].rank is None):
                self.uncompacted = 0
                return None  # a main file of layout 2 or older is rewritten by a full merge: it gains rank/
            sizes = [_rows_of(source) for source in reader._sources]
            journal_rows = sum(sizes[1:])
            # a file of layout 2 or older has no ranking arrays: the first merge rewrites everything, once
            if full or any(source.rank is None for source in reader._sources):
                first = 0
            elif fold and journal_rows >= FOLD_SHARE * len(reader._sources[0]):
                first = 0
            else:
                first = _merge_from(sizes)
            if first is None:
                self.uncompacted = 0
                return None
            if first == 0:
                self._merge_all(reader)
            else:
                self._merge_segments(reader, first)
        self.uncompacted = 0
        return "main" if first == 0 else "segments"

    def checkpoint(self) -> str | None:
        """What a build does when it finishes: the journal's newest segments merged, and the
        whole journal folded into the main file once it holds :data:`FOLD_SHARE` of the main
        file's rows, so that the main file alone holds a store built once (the README's h5py
        example reads it), while a build that changes 100 files of 10^6 rewrites about 100
        entries. Folding at that share costs each entry O(1) rewrites over its life (the
        main file is rewritten only after it has grown by a fixed fraction)."""
        if getattr(self, "must_fold", False):
            self.must_fold = False
            return self.compact(full=True)
        return self.compact(fold=True)

    def _merge_all(self, reader: StoreReader) -> None:
        """A fresh main file holding every entry, renamed into place; then the journal goes."""
        through = max(source.seq for source in reader._sources)
        attrs = self._main_attrs(through, {"created": reader.attrs.get("created", utc_now())})
        # the merged file holds no more than the files it merges, their checksums and ranking arrays
        estimate = int(reader.files_size() * 2.2)
        write_atomically(main_file(self.path), lambda f: _write_snapshot(f, reader, attrs), estimate)
        mark_verified(self.path)  # written from checked reads: the next build need not read it again
        write_committed(self.path, through)
        self.merged_seq = through
        for seq, batch in batch_files(self.path):
            if seq <= through:
                batch.unlink(missing_ok=True)
        remove_if_empty(journal_dir(self.path))

    def _merge_segments(self, reader: StoreReader, first: int) -> None:
        """Segments ``reader._sources[first:]`` (a..b) into one ``batch-b``; then a..b-1 go."""
        run = reader._sources[first:]
        view = StoreReader(self.path, run[0], run[1:])  # the run's entries, applied in order
        view.attrs = dict(reader.attrs)
        removed, touched = _run_removed_and_touched(run, set(view.paths))
        seq, first_seq = run[-1].seq, run[0].first_seq
        attrs = {"seq": seq, "first_seq": first_seq, "schema_version": SCHEMA_VERSION, **self.params.as_attrs()}
        estimate = int(sum(_size_of(source.path) for source in run) * 2.2)

        def fill(f):
            _write_snapshot(f, view, attrs)
            write_paths(f, "touched/path", [t[0] for t in touched])
            write_int64(f, "touched/size", [t[1] for t in touched])
            write_int64(f, "touched/mtime_ns", [t[2] for t in touched])
            write_paths(f, "removed/path", removed)

        write_atomically(journal_dir(self.path) / f"batch-{seq:010d}.h5", fill, estimate)
        for old_seq, batch in batch_files(self.path):
            if first_seq <= old_seq < seq:
                batch.unlink(missing_ok=True)

    def close(self, state: str = "stopped", facts: dict | None = None) -> None:
        """Release the lock, recording how the build ended (``finished``, ``interrupted``, ``stopped``)."""
        if self.lock.fd is not None:
            record_build(self.path, state, facts)
        self.lock.release()

    def __enter__(self) -> "StoreWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            state = "finished"
        else:
            state = "interrupted" if issubclass(exc_type, KeyboardInterrupt) else "stopped"
        self.close(state, getattr(self, "facts", None))


def _bytes_of(columns: dict, counts: dict, batch: Batch) -> int:
    """A generous estimate of a batch file's size."""
    total = sum(len(str(v)) + 16 for name in ("entries/path", "entries/reason") for v in columns[name])
    total += sum(a.nbytes for name, a in columns.items() if a.dtype != object)
    total += sum(flat.nbytes + 8 * (len(lengths) + 1) for flat, lengths in counts.values())
    total += sum(len(t[0]) + 40 for t in batch.touched) + sum(len(p) + 24 for p in batch.removed)
    return 2 * total


def _remove_covered(store: Path) -> None:
    """Delete the batches a merged segment holds (left by a merge killed before deleting them)."""
    ranges = []
    for seq, batch in batch_files(store):
        try:
            with open_hdf5(batch) as f:
                ranges.append((int(f.attrs.get("first_seq", seq)), seq))
        except (OSError, KeyError, ValueError):
            continue  # a damaged batch: open_store reports it, repair drops it
    for seq, batch in batch_files(store):
        if any(lo <= seq < hi for lo, hi in ranges):
            batch.unlink(missing_ok=True)


def _rows_of(source) -> int:
    """What merging a file costs: its entries, touched and removed paths (at least 1)."""
    extra = sum(int(source.file[g].shape[0]) for g in ("touched/path", "removed/path") if g in source.file)
    return max(1, len(source) + extra)


def _size_of(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def _merge_from(sizes: list) -> int | None:
    """Where the run of segments to merge starts (0: the main file too), or None: nothing is due.

    ``sizes``: rows of the main file and of each segment, oldest first. The newest segments
    are taken while the one before them holds at most :data:`GROWTH` times their rows.
    """
    if len(sizes) - 1 >= MAX_SEGMENTS:
        return 0
    first, run = len(sizes) - 1, sizes[-1]
    while first > 0 and sizes[first - 1] <= GROWTH * run:
        first -= 1
        run += sizes[first]
    return None if first == len(sizes) - 1 else first


def _run_removed_and_touched(run: list, kept: set) -> tuple[list, list]:
    """The removed paths and the touched (path, size, mtime_ns) a merged run of segments keeps:
    those that still apply to the files below it (see :class:`Batch`)."""
    removed: set = set()
    touched: dict = {}
    for source in run:
        gone = source.paths_of("removed")
        removed.update(gone)
        for p in gone:
            touched.pop(p, None)
        for p in source.column("entries/path"):
            touched.pop(p, None)  # an entry of the run supersedes the touch of the one below
        if "touched" in source.file:
            size, mtime = source.file["touched/size"][()], source.file["touched/mtime_ns"][()]
            for p, s, m in zip(source.paths_of("touched"), size, mtime):
                if p not in kept:  # the run's own entries already carry their new times
                    touched[p] = (p, int(s), int(m))
    return sorted(removed - kept), [touched[p] for p in sorted(touched)]


def _write_snapshot(f: h5py.File, reader: StoreReader, attrs: dict) -> None:
    """Every live entry of ``reader`` into ``f``; histogram counts copied in bounded steps,
    then the ranking section (one histogram at a time)."""
    f.attrs.update(attrs)
    columns = {name: reader.column(name) for name in ENTRY_COLUMNS}
    write_columns(f, columns)
    ok = write_rank_entries(f, columns, HISTOGRAMS)
    del columns
    for name in HISTOGRAMS:
        lengths = np.zeros(len(reader), dtype=np.int64)
        for source_index, source in enumerate(reader._sources):
            mine = reader.source == source_index
            lengths[mine] = np.diff(source.offsets(name))[reader.row[mine]]
        offsets = offsets_of(lengths)
        f.create_dataset(f"histograms/{name}/offsets", data=offsets, **checked(offsets.shape))
        total = (int(offsets[-1]),)
        counts = f.create_dataset(f"histograms/{name}/counts", shape=total, dtype=COUNT_DTYPE, **checked(total, counts=True))
        for start in range(0, len(reader), MERGE_ROWS):
            rows = np.arange(start, min(start + MERGE_ROWS, len(reader)))
            flat, _ = reader.counts(name, rows)
            counts[offsets[rows[0]] : offsets[rows[-1] + 1]] = flat
        flat, _ = reader.counts(name, np.arange(len(reader)))
        write_rank_histogram(f, name, flat, lengths, ok)
        del flat
