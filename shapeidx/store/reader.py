"""Reading a store: the main file and the journal batches it does not hold yet, as one view.

A reader opens the main file, then the batches newer than its ``journal_seq``, and applies
them in order (drop ``removed``, replace or add the batch's entries, update the times of
``touched``). If a batch disappears in between (a merge finished), it starts over. Readers
take no lock and keep working during a build.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import h5py
import numpy as np

from ..errors import NoAnswer, StoreDamagedError, StoreError
from ..ragged import offsets_of, take_ragged
from ..signing.histogram import Histogram, Signature, known_radii
from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS
from ..signing.parameters import HISTOGRAMS
from .files import batch_files, is_one_file_store, main_file, recovery_commands
from .layout import (
    CONTENT_HASH,
    COUNT_DTYPE,
    DEFAULT_STORE,
    ENTRY_COLUMNS,
    SCHEMA_VERSION,
    MAY_BE_ABSENT,
    SHAPE_COLUMNS,
    STORE_ENV,
    StoreParams,
    as_text,
    missing_column,
    object_array,
    strings_hash,
)
from .lock import lock_held


#: Journal files of at most this many entries (a build's batches) are read whole and verified
#: when a store is opened, so a damaged one is left out; larger ones (segments merged from
#: batches) are checked as the main file is: shapes at opening, checksums as they are read.
VERIFY_ROWS = 4096


#: A main file at least this large, which a build verified whole (STORE/verified), is opened
#: without walking its global heaps again (one pass over its bytes; some 0.2 s per 45 MB): below
#: it the walk is cheap and also covers a forged STORE/verified.
TRUST_VERIFIED_ABOVE = 256 << 20


def _large(path: Path) -> bool:
    try:
        return os.stat(path).st_size >= TRUST_VERIFIED_ABOVE
    except OSError:
        return False


class StoreBeingCreated(StoreError, NoAnswer):
    """A store whose first build has begun but committed nothing: no answer exists yet (the
    command line exits 6, "no answer", not 1: nothing is wrong, it is only too early)."""


def damaged(store: Path, what: str, root: str | None = None) -> StoreDamagedError:
    """The one-line error of a damaged store: what is wrong, and how to recover."""
    from .shards import owner_of_shard

    repair, check = recovery_commands(store, root)
    owner = owner_of_shard(store)  # a shard is named as part of the store the user gave
    named = f"{owner} (its shard {Path(store).name})" if owner is not None else str(store)
    return StoreDamagedError(
        f"the store {named} is damaged ({what}): '{repair}' rebuilds the"
        f" damaged entries (or delete the store and build again); '{check}' lists every problem"
    )


class _SourceFile:
    """One store file (main or batch) opened for reading, columns read on demand.

    Every read is checked: a dataset whose checksum (Fletcher-32, or the content hash of a
    string column) fails, offsets out of bounds, columns of unequal length all raise
    :class:`StoreDamagedError` before any of it is used.
    """

    def __init__(self, path: Path, seq: int, store: Path | None = None):
        from .heaps import open_hdf5
        from .verified import is_verified

        self.path = path
        self.seq = seq
        self.store = store or path
        # global heaps checked first (a hang otherwise), but for a large main file a build verified whole
        trusted = seq == 0 and store is not None and _large(path) and is_verified(store)
        self.file = open_hdf5(path, trusted=trusted)
        self._columns: dict = {}
        self._offsets: dict = {}

    def damaged(self, what: str) -> StoreDamagedError:
        where = "" if self.seq == 0 else f" of {self.path.name}"
        root = self.file.attrs.get("root") if self.seq == 0 else None
        return damaged(self.store, what + where, as_text(root) if root is not None else None)

    def dataset(self, name: str) -> h5py.Dataset:
        try:
            return self.file[name]
        except KeyError:
            raise self.damaged(f"{name} is missing") from None
        except (OSError, RuntimeError, ValueError) as exc:
            raise self.damaged(f"{name} cannot be opened: {_first_line(exc)}") from None

    def _read(self, name: str, dtype, selection=()):
        dataset = self.dataset(name)
        try:
            if dtype is object:
                values = dataset.asstr()[()] if dataset.shape[0] else object_array([])
                if CONTENT_HASH in dataset.attrs and strings_hash(values) != as_text(dataset.attrs[CONTENT_HASH]):
                    raise self.damaged(f"{name} fails its content checksum")
                return values
            return dataset[selection] if selection != () else dataset[()]
        except StoreDamagedError:
            raise
        except (OSError, RuntimeError, ValueError, UnicodeDecodeError) as exc:
            raise self.damaged(f"{name} cannot be read: {_first_line(exc)}") from None

    def __len__(self) -> int:
        return int(self.dataset("entries/size").shape[0])

    def check_shapes(self) -> None:
        """Every column holds one row per entry (cheap: shapes only)."""
        n = len(self)
        for name in ENTRY_COLUMNS:
            if name in MAY_BE_ABSENT and name not in self.file:
                continue  # a file of layout 1: these columns read as NaN
            shape = self.dataset(name).shape
            if not shape or shape[0] != n:
                raise self.damaged(f"{name} has {shape[0] if shape else 0} rows, not {n}")
        for name in HISTOGRAMS:
            shape = self.dataset(f"histograms/{name}/offsets").shape
            if shape != (n + 1,):
                raise self.damaged(f"histograms/{name}/offsets has {shape[0] if shape else 0} values, not {n + 1}")

    def verify_all(self) -> None:
        """Read and check every dataset (a journal batch is small: done when it is opened)."""
        self.check_shapes()
        for name in ENTRY_COLUMNS:
            self.column(name)
        for name in HISTOGRAMS:
            self.counts_of(name, np.arange(len(self)))
        for group in ("touched", "removed"):
            self.paths_of(group)
        if "touched" in self.file:
            for name in ("touched/size", "touched/mtime_ns"):
                self._read(name, np.int64)

    def column(self, name: str) -> np.ndarray:
        if name not in self._columns:
            if name in MAY_BE_ABSENT and name not in self.file:  # a file of layout 1
                self._columns[name] = missing_column(name, len(self))
            else:
                self._columns[name] = self._read(name, ENTRY_COLUMNS[name][0])
        return self._columns[name]

    def offsets(self, name: str) -> np.ndarray:
        if name not in self._offsets:
            key = f"histograms/{name}/offsets"
            offsets = self._read(key, np.int64)
            total = self.dataset(f"histograms/{name}/counts").shape[0]
            if (offsets.shape != (len(self) + 1,) or (len(offsets) and offsets[0] != 0)
                    or np.any(np.diff(offsets) < 0) or (len(offsets) and offsets[-1] != total)):
                raise self.damaged(f"{key} are out of bounds (the counts hold {total} values)")
            self._offsets[name] = offsets
        return self._offsets[name]

    def counts_of(self, name: str, rows: np.ndarray):
        """(flat counts, lengths) of ``rows`` (sorted, increasing), reading one span of the file."""
        offsets = self.offsets(name)
        if len(rows) == 0:
            return np.zeros(0, dtype=COUNT_DTYPE), np.zeros(0, dtype=np.int64)
        if rows[0] < 0 or rows[-1] + 1 >= len(offsets):
            raise IndexError(f"rows {rows[0]}..{rows[-1]} of a file of {len(offsets) - 1} entries")
        lo, hi = int(offsets[rows[0]]), int(offsets[rows[-1] + 1])
        span = self._read(f"histograms/{name}/counts", COUNT_DTYPE, np.s_[lo:hi])
        return take_ragged(span, offsets, rows, base=lo)

    def paths_of(self, group: str) -> np.ndarray:
        if group not in self.file:
            return object_array([])
        return self._read(f"{group}/path", object)

    @property
    def first_seq(self) -> int:
        """The oldest journal batch this file holds (a segment merged from batches first_seq..seq)."""
        return int(self.file.attrs.get("first_seq", self.seq))

    @property
    def rank(self):
        """The file's memory-mapped ranking section (:class:`~shapeidx.store.rank.RankSection`), or None
        for a file written before layout 3."""
        if not hasattr(self, "_rank"):
            from .rank import RANK, RankSection

            self._rank = None
            if RANK in self.file:
                try:
                    self._rank = RankSection(self.file, self.path)
                except (KeyError, OSError, RuntimeError, ValueError) as exc:
                    raise self.damaged(f"its ranking arrays cannot be used: {_first_line(exc)}") from None
        return self._rank

    def path_at(self, row: int) -> str:
        """The path of one row, read alone (no other path is decoded)."""
        try:
            value = self.dataset("entries/path")[int(row)]
            return value.decode("utf-8", "surrogatepass") if isinstance(value, bytes) else str(value)
        except (OSError, RuntimeError, ValueError, UnicodeDecodeError) as exc:
            raise self.damaged(f"entries/path cannot be read: {_first_line(exc)}") from None

    def find(self, path: str) -> int | None:
        """The row holding ``path`` (paths are sorted), by binary search over single reads."""
        lo, hi = 0, len(self)
        while lo < hi:
            mid = (lo + hi) // 2
            if self.path_at(mid) < path:
                lo = mid + 1
            else:
                hi = mid
        return lo if lo < len(self) and self.path_at(lo) == path else None

    def value_at(self, name: str, row: int):
        """One row of a numeric column, read alone."""
        if name in MAY_BE_ABSENT and name not in self.file:
            return missing_column(name, 1)[0]
        return self._read(name, ENTRY_COLUMNS[name][0], np.s_[int(row)])

    def text_at(self, name: str, row: int) -> str:
        """One row of a text column (:data:`~shapeidx.store.layout.TEXT_COLUMNS`), read alone, for
        showing (its content hash covers the whole column: a filter reads the column whole)."""
        if name not in self.file:
            return ""
        try:
            value = self.dataset(name)[int(row)]
        except (OSError, RuntimeError, ValueError, IndexError) as exc:
            raise self.damaged(f"{name} cannot be read: {_first_line(exc)}") from None
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)

    def text_present(self, name: str) -> bool:
        """Whether any entry of this file has a value in text column ``name`` (written with it;
        read from the column for a file written before)."""
        if name not in self.file:
            return False
        flag = self.dataset(name).attrs.get("any_value")
        return bool(flag) if flag is not None else bool((self.column(name) != "").any())

    def close(self) -> None:
        if getattr(self, "_rank", None) is not None:
            self._rank.close()
        self.file.close()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__


class StoreReader:
    """A consistent view of a store: its entries (main file plus journal), sorted by path.

    Open with :func:`open_store`; use as a context manager. The view holds its files open,
    so it stays readable while a build merges and deletes them.

    Attributes
    ----------
    path : Path
    attrs : dict
        The main file's attributes (parameters, versions, root, times).
    params : StoreParams
    journal : int
        Batches applied on top of the main file.
    skipped : list of (Path, str)
        Damaged journal segments left out of the view, with why: only a view opened for a
        build (``open_store(..., skip_damaged=True)``), which drops them and redoes their
        work; every other reader refuses a damaged segment (an answer over fewer entries
        than the store holds is never given).
    """

    def __init__(self, path: Path, main: _SourceFile, batches: list[_SourceFile], skipped=()):
        self.path = path
        self.skipped = list(skipped)
        self.attrs = {k: (as_text(v) if isinstance(v, (bytes, str)) else v) for k, v in main.file.attrs.items()}
        self.params = StoreParams.from_attrs(self.attrs)
        self.journal = len(batches)
        self._sources = [main] + batches
        self.missing = None  # what is missing from the journal (only a build's view may have a gap)
        self._assembled = False

    # -- assembly: which row of which file holds each live entry; done on first use, so that a
    # query that ranks the files' own arrays (shapeidx.store.ranked) never decodes every path
    @property
    def source(self) -> np.ndarray:
        """The file (index into the main file and batches) of each live entry."""
        self._assemble()
        return self._source

    @property
    def row(self) -> np.ndarray:
        """The row within its file of each live entry."""
        self._assemble()
        return self._row

    @property
    def _overrides(self) -> dict:
        self._assemble()
        return self._touched

    def _assemble(self) -> None:
        if self._assembled:
            return
        self._assembled = True
        main = self._sources[0]
        if len(self._sources) == 1:
            self._source = np.zeros(len(main), dtype=np.int64)
            self._row = np.arange(len(main), dtype=np.int64)
            self._touched = {}
            return
        main_paths = main.column("entries/path")
        alive = np.ones(len(main), dtype=bool)
        latest: dict = {}  # path -> (source, row), for entries written by batches
        touched: dict = {}  # path -> (size, mtime_ns)

        def supersede(paths):
            for p in paths:
                latest.pop(p, None)
                touched.pop(p, None)
            if len(main_paths) and len(paths):
                at = np.minimum(np.searchsorted(main_paths, paths), len(main_paths) - 1)
                alive[at[main_paths[at] == paths]] = False

        for index, batch in enumerate(self._sources[1:], start=1):
            supersede(batch.paths_of("removed"))
            paths = batch.column("entries/path")
            supersede(paths)
            latest.update((p, (index, r)) for r, p in enumerate(paths))
            if "touched" in batch.file:
                size, mtime = batch.file["touched/size"][()], batch.file["touched/mtime_ns"][()]
                touched.update((p, (int(s), int(m))) for p, s, m in zip(batch.paths_of("touched"), size, mtime))
        self._merge_order(main_paths, alive, latest)
        self._touched = touched

    def _merge_order(self, main_paths, alive, latest) -> None:
        kept = np.flatnonzero(alive)
        new_paths = object_array(sorted(latest))
        insert_at = np.searchsorted(main_paths[kept], new_paths) + np.arange(len(new_paths))
        n = len(kept) + len(new_paths)
        self._source = np.zeros(n, dtype=np.int64)
        self._row = np.zeros(n, dtype=np.int64)
        from_main = np.ones(n, dtype=bool)
        from_main[insert_at] = False
        self._row[from_main] = kept
        refs = np.array([latest[p] for p in new_paths], dtype=np.int64).reshape(-1, 2)
        self._source[insert_at], self._row[insert_at] = refs[:, 0], refs[:, 1]

    # -- columns
    def __len__(self) -> int:
        return len(self.row)

    def column(self, name: str) -> np.ndarray:
        """One per-entry column (e.g. ``"entries/path"``) for every live entry, in path order."""
        dtype = ENTRY_COLUMNS[name][0]
        sample = self._sources[0].column(name)
        out = np.empty((len(self),) + sample.shape[1:], dtype=dtype if dtype is not object else object)
        for index, source in enumerate(self._sources):
            mine = self.source == index
            if mine.any():
                out[mine] = source.column(name)[self.row[mine]]
        if self._overrides and name in ("entries/size", "entries/mtime_ns"):
            self._apply_touched(name, out)
        return out

    def _apply_touched(self, name, out) -> None:
        paths = self.paths
        field_index = 0 if name == "entries/size" else 1
        for p, values in self._overrides.items():
            i = self.index_of(p, paths)
            if i is not None:
                out[i] = values[field_index]

    @property
    def missing_columns(self) -> list[str]:
        """Layout-2 columns (size, handedness) some live entry lacks: its file predates them (NaN)."""
        return [n for n in SHAPE_COLUMNS if any(n not in s.file and (self.source == i).any() for i, s in enumerate(self._sources))]

    @property
    def paths(self) -> np.ndarray:
        if not hasattr(self, "_paths"):
            self._paths = self.column("entries/path")
        return self._paths

    def index_of(self, path: str, paths=None) -> int | None:
        """Position of the entry with this relative path, or None."""
        paths = self.paths if paths is None else paths
        i = int(np.searchsorted(paths, path))
        return i if i < len(paths) and paths[i] == path else None

    def counts(self, name: str, rows: np.ndarray | None = None):
        """Histogram ``name`` of the entries ``rows`` (default all): (flat counts, lengths)."""
        rows = np.arange(len(self)) if rows is None else np.asarray(rows, dtype=np.int64)
        pieces = []  # (positions in ``rows``, their counts laid end to end, their lengths)
        for index, source in enumerate(self._sources):
            positions = np.flatnonzero(self.source[rows] == index)
            if len(positions) == 0:
                continue
            source_rows = self.row[rows[positions]]
            by_row = np.argsort(source_rows, kind="stable")  # one increasing span per file
            flat, got = source.counts_of(name, source_rows[by_row])
            pieces.append((positions[by_row], flat, got))
        if len(pieces) == 1 and np.array_equal(pieces[0][0], np.arange(len(rows))):
            return pieces[0][1], pieces[0][2]
        lengths = np.zeros(len(rows), dtype=np.int64)
        for positions, _, got in pieces:
            lengths[positions] = got
        offsets = offsets_of(lengths)
        out = np.empty(int(offsets[-1]), dtype=COUNT_DTYPE)
        for positions, flat, got in pieces:
            out[np.repeat(offsets[positions] - offsets_of(got)[:-1], got) + np.arange(len(flat))] = flat
        return out, lengths

    def signature(self, index: int) -> Signature:
        """The stored signature of entry ``index`` (an ok entry)."""
        histograms = {}
        for name in HISTOGRAMS:
            counts, _ = self.counts(name, np.array([index]))
            mean = float(self.column(f"histograms/{name}/mean")[index])
            width = float(self.column(f"histograms/{name}/bin_width")[index])
            histograms[name] = Histogram(counts.astype(np.int64), mean, width)
        angles = self.column("entries/angles")[index]
        angles = angles.reshape(len(ANGLE_HISTOGRAMS), ANGLE_BINS).astype(np.int64) if np.isfinite(angles).all() else None
        return Signature(points=self.params.points, seed=self.params.seed, histograms=histograms, angles=angles,
                         radii=known_radii(self.column("entries/extents")[index]))

    def size_on_disk(self) -> int:
        """Bytes of the store: every file of its directory (main file, journal, metadata,
        thumbnails), what a copy of it takes."""
        total = 0
        for folder, _, names in os.walk(self.path):
            for name in names:
                try:
                    total += os.lstat(os.path.join(folder, name)).st_size
                except FileNotFoundError:  # a segment a merge removed meanwhile
                    pass
        return total

    def files_size(self) -> int:
        """Bytes of the HDF5 files of this view (main file and segments): what a merge rewrites."""
        total = 0
        for source in self._sources:
            try:
                total += source.path.stat().st_size
            except FileNotFoundError:  # a batch a merge removed meanwhile
                pass
        return total

    def close(self) -> None:
        for source in self._sources:
            source.close()

    def __enter__(self) -> "StoreReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def resolve_store_path(path: str | os.PathLike | None) -> Path:
    """The store to use: ``path``, else ``$SHAPEIDX_STORE``, else ``./shapeidx.h5``."""
    return Path(path or os.environ.get(STORE_ENV) or DEFAULT_STORE)


def member_stores(store: str | os.PathLike, parts: bool = False) -> list[Path]:
    """The ordinary stores that hold ``store``'s entries: the store itself, or every shard of a
    sharded store (``build --shards``), in shard order; ``parts``: their sub-parts stores
    (``build --parts``), a StoreError naming the build that makes them when there are none."""
    from .files import parts_store
    from .shards import is_sharded, shard_paths

    store = Path(store)
    members = shard_paths(store) if is_sharded(store) else [store]
    if not parts:
        return members
    found = [parts_store(member) for member in members]
    if not all(p.is_dir() for p in found):
        if len(members) == 1:
            open_store(store).close()  # no store at all: that error first
        raise StoreError(f"the store {store} has no sub-parts: build it with 'shapeidx build DIR --store {store}"
                         " --parts' (docs/assemblies.md)")
    return found


def open_store(path: str | os.PathLike, attempts: int = 20, skip_damaged: bool = False) -> StoreReader:
    """Open a store for reading: the main file and the journal segments it does not hold yet.

    ``skip_damaged``: leave a damaged segment out of the view (:attr:`StoreReader.skipped`)
    instead of refusing the store; only a build asks for that (it redoes their work).

    Raises
    ------
    StoreError
        No store there, a file that is not a store, or one of a newer layout.
    StoreDamagedError
        A file of the store fails its checks (a damaged segment included, unless ``skip_damaged``).
    """
    from .files import read_committed

    path = Path(path)
    for _ in range(attempts):
        # read before the segments are listed: a segment is in place before its number is
        # recorded, so every number read here names a file the listing can see (or merged away)
        committed = read_committed(path)
        main = _open_main(path)
        batches, skipped = [], []
        try:
            _check_schema(path, main.file.attrs)
            main.check_shapes()
            merged = int(main.file.attrs["journal_seq"])
            for seq, batch in batch_files(path):
                if seq > merged:
                    opened, reason = _open_batch(path, batch, seq)
                    if opened is not None:
                        batches.append(opened)
                    elif reason is not None and skip_damaged:
                        skipped.append((batch, reason))
                    elif reason is not None:
                        raise damaged(path, f"journal segment {batch.name}: {reason}", as_text(main.file.attrs.get("root", "")) or None)
                    else:
                        raise FileNotFoundError(batch)  # it vanished: a merge finished meanwhile
            if _same_file(main.path, main):  # no merge replaced the main file while the batches were listed
                batches = _drop_covered(batches)
                missing = _missing_segments(merged, batches, skipped, committed)
                if missing and not skip_damaged:
                    raise damaged(path, missing, as_text(main.file.attrs.get("root", "")) or None)
                reader = StoreReader(path, main, batches, skipped)
                reader.missing = missing
                return reader
        except FileNotFoundError:  # a batch went: a merge finished meanwhile
            pass
        except (OSError, RuntimeError, KeyError, ValueError) as exc:  # HDF5 metadata that cannot be read
            _close_all([main, *batches])
            raise damaged(path, f"the main file's metadata cannot be read: {_first_line(exc)}") from None
        except BaseException:
            _close_all([main, *batches])
            raise
        _close_all([main, *batches])
        time.sleep(0.02)
    raise StoreError(f"{path}: the store kept changing while being opened; try again")


def _open_main(path: Path) -> _SourceFile:
    check_store_directory(path)
    main = main_file(path)
    try:
        return _SourceFile(main, 0, path)
    except FileNotFoundError:
        from .files import build_state_path, committed_path, journal_dir, lock_path

        if any(p.exists() for p in (journal_dir(path), committed_path(path))) or (
                build_state_path(path).exists() and not lock_path(path).exists()):
            raise damaged(path, f"its main file {main.name} is missing") from None
        if lock_path(path).exists():
            from .files import build_command

            if not lock_held(path):  # its first build was killed before it committed anything
                raise StoreBeingCreated(f"the store {path} holds nothing yet: its first build stopped before committing"
                                        f" anything; '{build_command(path)}' builds it") from None
            raise StoreBeingCreated(f"the store {path} is being created: a first build has just begun and committed"
                                    " nothing yet; try again in a moment") from None
        if (path / "shards.json").is_file():
            raise StoreError(f"{path} is a sharded store: build, query, where-used, classify, duplicates, cluster,"
                             " check-new, plot, serve, check and stats take it whole;"
                             f" a store reader opens one shard ({path}/shards/K)") from None
        raise StoreError(f"{path} is not a shapeidx store (it holds no {main.name})") from None
    except PermissionError:
        raise StoreError(f"{path}: cannot open the store: permission denied") from None
    except OSError as exc:
        if not main.exists():
            raise StoreError(f"{path} is not a shapeidx store (it holds no {main.name})") from None
        if main.stat().st_size == 0 or _signature_missing(main):
            raise damaged(path, f"{main.name} is not an HDF5 file") from None
        raise damaged(path, f"the main file cannot be opened: {_first_line(exc)}") from None


def check_store_directory(path: Path) -> None:
    """Refuse, in one line, a path that is not a store directory: nothing there, a file of
    the older one-file layout (a build converts it), or any other file."""
    if path.is_dir():
        return
    if not path.exists():
        from .files import build_command

        raise StoreError(f"no store at {path} (run '{build_command(path)}' first, or give --store)")
    if is_one_file_store(path):
        raise StoreError(f"{path} is a store of the older one-file layout: 'shapeidx build DIR --store {path}' converts"
                         " it into the store directory (renames only: no part is signed again)")
    raise StoreError(f"{path} is not a shapeidx store (a store is a directory; this is a file)")


def _signature_missing(path: Path) -> bool:
    """Whether the file lacks HDF5's signature at offset 0 (another kind of file, not a damaged store)."""
    try:
        from ..io.base import open_regular

        with open_regular(path) as f:
            return f.read(8) != b"\x89HDF\r\n\x1a\n"
    except OSError:
        return False


def _open_batch(store: Path, batch: Path, seq: int):
    """(source, None) for a sound batch; (None, reason) for a damaged one; (None, None) if it vanished.

    h5py reports a file that vanished between listing and opening as a plain OSError, not
    FileNotFoundError: whether it still exists tells a race with a merge from damage.
    """
    try:
        source = _SourceFile(batch, seq, store)
    except OSError as exc:
        if not batch.exists():
            return None, None
        return None, f"cannot be opened: {_first_line(exc)}"
    try:
        if len(source) <= VERIFY_ROWS:
            source.verify_all()
        else:  # a merged segment: checked like the main file (shapes now, checksums as it is read)
            source.check_shapes()
    except StoreDamagedError as exc:
        source.close()
        if not batch.exists():
            return None, None
        text = str(exc)
        return None, text[text.index("(") + 1 : text.index(" of batch-")] if " of batch-" in text else "damaged"
    return source, None


def _missing_segments(merged: int, batches: list, skipped: list, committed: int) -> str | None:
    """What is missing from the journal, in words (None: nothing). The segments after the
    main file's ``journal_seq`` must follow one another without a gap (a merged segment
    covers ``first_seq``..seq), up to the newest sequence number committed
    (``STORE/committed``, read before the segments were listed)."""
    if skipped:
        return None  # a build that drops damaged segments redoes their work and folds the journal
    expected = merged + 1
    for batch in sorted(batches, key=lambda b: b.seq):
        if batch.first_seq > expected:
            gap = batch.first_seq - 1
            return (f"journal segment {gap} is missing" if gap == expected
                    else f"journal segments {expected}..{gap} are missing")
        expected = max(expected, batch.seq + 1)
    if committed >= expected:
        return f"journal segment {committed} (the newest committed) is missing" if committed == expected else (
            f"journal segments {expected}..{committed} (the newest committed) are missing")
    return None


def _drop_covered(batches: list) -> list:
    """Leave out (and close) batches that a later merged segment holds: a merge of batches
    a..b writes ``batch-b`` (attribute ``first_seq`` = a) and then deletes a..b-1; killed in
    between, those are still there, and applying them too would give the same view, only slower."""
    ranges = [(batch.first_seq, batch.seq) for batch in batches]
    kept = []
    for batch in batches:
        if any(lo <= batch.seq < hi for lo, hi in ranges):
            batch.close()
        else:
            kept.append(batch)
    return kept


def _same_file(path: Path, source: _SourceFile) -> bool:
    """Whether ``path`` still names the file ``source`` has open.

    A merge renames its new main file into place before deleting the batches it holds. A
    reader that opened the old main file and then found the batches gone would miss their
    entries; seeing the main file unchanged after listing the batches rules that out.
    """
    try:
        now = os.stat(path)
    except FileNotFoundError:
        return False
    opened = os.fstat(source.file.id.get_vfd_handle())
    return (now.st_dev, now.st_ino) == (opened.st_dev, opened.st_ino)


def _close_all(sources) -> None:
    for source in sources:
        source.close()


def _check_schema(path: Path, attrs) -> None:
    if "schema_version" not in attrs or "points" not in attrs:
        raise StoreError(f"{path} is not a shapeidx store")
    version = int(attrs["schema_version"])
    if version > SCHEMA_VERSION:
        raise StoreError(f"{path} was written by a newer shapeidx (layout {version}; this one reads {SCHEMA_VERSION})")


def check_params(reader: StoreReader, wanted: StoreParams) -> None:
    """Refuse a store built with other signature parameters (never mix signatures)."""
    differences = reader.params.differences(wanted)
    if differences:
        from .files import build_command, owner_of_parts

        owner = owner_of_parts(reader.path)
        if owner is not None:  # another --store is no way out: the sub-parts follow their store's parameters
            raise StoreError(
                f"the sub-parts store {reader.path} was built with other signature parameters than its store"
                f" {owner}: {', '.join(differences)}; delete {reader.path} and"
                f" '{build_command(reader.path, as_text(reader.attrs.get('root', '')) or None)}'"
                " makes it again with the store's"
            )
        raise StoreError(
            f"store {reader.path} was built with other signature parameters: {', '.join(differences)}; "
            "use another --store, or delete this one to rebuild it"
        )


def check_root(reader: StoreReader, root) -> None:
    """Refuse a store that indexes another directory (its paths are relative to its root)."""
    if reader.attrs.get("root") != str(root):
        raise StoreError(
            f"store {reader.path} indexes {reader.attrs.get('root')}, not {root}; use another --store for this directory"
        )
