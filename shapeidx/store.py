"""The signature store: one HDF5 file of entries, plus a journal of committed batches.

Layout (the README's "The store" section is the reader's guide; keep the two in step)::

    STORE                    the main file: a complete snapshot, only ever replaced by rename
    STORE.journal/           batches committed since the main file was last written
        batch-0000000007.h5    same entry layout, plus /touched and /removed
    STORE.lock               held (flock) by the one build that may write

Crash safety comes from never writing a file that a reader may open. Every file is written
under a temporary name, flushed to disk, and renamed into place (atomic on POSIX). A build
commits its progress as a new batch file in the journal; a merge writes a fresh main file
holding the main and every batch, renames it over the old one, and only then deletes the
batches. The main file records the last batch it holds (``journal_seq``), so batches that
outlive a kill between that rename and their deletion are ignored, never applied twice.

A reader opens the main file, then the batches newer than its ``journal_seq``, and
applies them in order. If a batch disappears in between (a merge finished), it starts over.
"""

from __future__ import annotations

import fcntl
import os
import re
import socket
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from .errors import StoreError
from .io.faceting import DEFAULT_ANGULAR_DEFLECTION, DEFAULT_LINEAR_DEFLECTION, Faceting
from .signature import HISTOGRAMS, Histogram, Signature

#: Layout version of the files; a store with a newer one is refused.
SCHEMA_VERSION = 1
STATUS_OK, STATUS_FAILED = 0, 1
STATUS_NAMES = ("ok", "failed")
#: Class fractions are stored as (N, 3) in this order.
FRACTION_CLASSES = HISTOGRAMS[1:]
#: Where the default store lives, relative to the working directory.
DEFAULT_STORE = "shapeidx.h5"
STORE_ENV = "SHAPEIDX_STORE"

_STR = h5py.string_dtype("utf-8")
_STATUS = h5py.enum_dtype({"ok": STATUS_OK, "failed": STATUS_FAILED}, basetype="u1")
_HASH = "S64"
#: Per-entry columns: HDF5 dataset name -> (dtype in memory, dtype in the file).
ENTRY_COLUMNS = {
    "entries/path": (object, _STR),
    "entries/hash": (_HASH, _HASH),
    "entries/size": (np.int64, np.int64),
    "entries/mtime_ns": (np.int64, np.int64),
    "entries/status": (np.uint8, _STATUS),
    "entries/reason": (object, _STR),
    "entries/triangles": (np.int64, np.int64),
    "entries/area": (np.float64, np.float64),
    "entries/watertight": (np.bool_, np.bool_),
    "entries/fractions": (np.float64, np.float64),
}
for _name in HISTOGRAMS:
    ENTRY_COLUMNS[f"histograms/{_name}/mean"] = (np.float64, np.float64)
    ENTRY_COLUMNS[f"histograms/{_name}/bin_width"] = (np.float64, np.float64)
#: Histogram counts are stored as uint32: at most 8192 points give 33,550,336 pairs.
COUNT_DTYPE = np.uint32
_BATCH_NAME = re.compile(r"^batch-(\d{10})\.h5$")
#: Catalog rows copied per step of a merge: bounds its memory whatever the store's size.
MERGE_ROWS = 65_536


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class StoreParams:
    """What makes two signatures comparable; a store never mixes two sets of these."""

    points: int
    seed: int
    bin_divisor: int
    signature_version: int
    seed_policy: str = "fixed"
    #: Faceting of solid models (STEP, IGES): see shapeidx.io.faceting.
    linear_deflection: float = DEFAULT_LINEAR_DEFLECTION
    angular_deflection: float = DEFAULT_ANGULAR_DEFLECTION

    def as_attrs(self) -> dict:
        return {
            "points": self.points,
            "seed": self.seed,
            "bin_divisor": self.bin_divisor,
            "signature_version": self.signature_version,
            "seed_policy": self.seed_policy,
            "linear_deflection": self.linear_deflection,
            "angular_deflection": self.angular_deflection,
        }

    @classmethod
    def from_attrs(cls, attrs) -> "StoreParams":
        return cls(
            points=int(attrs["points"]),
            seed=int(attrs["seed"]),
            bin_divisor=int(attrs["bin_divisor"]),
            signature_version=int(attrs["signature_version"]),
            seed_policy=_text(attrs["seed_policy"]),
            # stores written before STEP support used the faceting defaults (they held no solid model)
            linear_deflection=float(attrs.get("linear_deflection", DEFAULT_LINEAR_DEFLECTION)),
            angular_deflection=float(attrs.get("angular_deflection", DEFAULT_ANGULAR_DEFLECTION)),
        )

    @property
    def faceting(self) -> Faceting:
        """The faceting of solid models these parameters ask for."""
        return Faceting(self.linear_deflection, self.angular_deflection)

    def differences(self, other: "StoreParams") -> list[str]:
        """``name=mine (asked: theirs)`` for every parameter that differs."""
        mine, theirs = self.as_attrs(), other.as_attrs()
        return [f"{k}={mine[k]} (asked: {theirs[k]})" for k in mine if mine[k] != theirs[k]]


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


# --------------------------------------------------------------------------- entries


@dataclass
class Entry:
    """One file of the indexed tree, as the store keeps it.

    Failed entries have no histograms, ``triangles`` -1, NaN area and fractions, and the
    one-line ``reason`` (empty for ok entries).
    """

    path: str
    hash: str
    size: int
    mtime_ns: int
    status: int = STATUS_OK
    reason: str = ""
    triangles: int = -1
    area: float = float("nan")
    watertight: bool = False
    fractions: tuple = (float("nan"),) * 3
    histograms: dict = field(default_factory=dict)

    @classmethod
    def indexed(cls, path, hash, size, mtime_ns, signature: Signature, facts: dict) -> "Entry":
        """An ok entry: a signature and the mesh facts of :meth:`shapeidx.solid.Solid.describe`."""
        return cls(
            path=path,
            hash=hash,
            size=size,
            mtime_ns=mtime_ns,
            triangles=int(facts["triangles"]),
            area=float(facts["area"]),
            watertight=bool(facts["watertight"]),
            fractions=tuple(signature.fractions[c] for c in FRACTION_CLASSES),
            histograms=dict(signature.histograms),
        )

    @classmethod
    def failed(cls, path, hash, size, mtime_ns, reason: str) -> "Entry":
        return cls(path=path, hash=hash, size=size, mtime_ns=mtime_ns, status=STATUS_FAILED, reason=reason)


def entries_to_columns(entries: list[Entry]) -> tuple[dict, dict]:
    """Columns (dataset name -> array) and counts (name -> (flat, lengths)), sorted by path."""
    entries = sorted(entries, key=lambda e: e.path)
    n = len(entries)
    empty = Histogram(np.zeros(0, dtype=np.int64), 0.0, 0.0)
    columns = {
        "entries/path": _object_array([e.path for e in entries]),
        "entries/hash": np.array([e.hash.encode() for e in entries], dtype=_HASH),
        "entries/size": np.array([e.size for e in entries], dtype=np.int64),
        "entries/mtime_ns": np.array([e.mtime_ns for e in entries], dtype=np.int64),
        "entries/status": np.array([e.status for e in entries], dtype=np.uint8),
        "entries/reason": _object_array([e.reason for e in entries]),
        "entries/triangles": np.array([e.triangles for e in entries], dtype=np.int64),
        "entries/area": np.array([e.area for e in entries], dtype=np.float64),
        "entries/watertight": np.array([e.watertight for e in entries], dtype=np.bool_),
        "entries/fractions": np.array([e.fractions for e in entries], dtype=np.float64).reshape(n, 3),
    }
    counts = {}
    for name in HISTOGRAMS:
        hists = [e.histograms.get(name, empty) for e in entries]
        columns[f"histograms/{name}/mean"] = np.array([h.mean for h in hists], dtype=np.float64)
        columns[f"histograms/{name}/bin_width"] = np.array([h.bin_width for h in hists], dtype=np.float64)
        lengths = np.array([len(h.counts) for h in hists], dtype=np.int64)
        flat = np.concatenate([h.counts for h in hists]) if n else np.zeros(0)
        counts[name] = (_as_counts(flat), lengths)
    return columns, counts


def _object_array(values) -> np.ndarray:
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


def _as_counts(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values)
    if len(values) and values.max() > np.iinfo(COUNT_DTYPE).max:
        raise StoreError("a histogram bin holds more pairs than the store's uint32 counts allow")
    return values.astype(COUNT_DTYPE)


def offsets_of(lengths: np.ndarray) -> np.ndarray:
    """CSR offsets (n + 1,) of rows with these lengths."""
    offsets = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    return offsets


def take_ragged(flat: np.ndarray, offsets: np.ndarray, rows: np.ndarray, base: int = 0):
    """Rows ``rows`` of a CSR array whose values ``flat`` start at offset ``base``.

    Returns
    -------
    values : the rows' values laid end to end
    lengths : (len(rows),) int64
    """
    starts = offsets[rows] - base
    lengths = offsets[rows + 1] - offsets[rows]
    total = int(lengths.sum())
    if len(rows) and starts[0] == 0 and total == len(flat):
        return flat, lengths  # the rows cover the values (rows left out are empty): no copy
    # position of each output value in ``flat``: its row's start plus its place in the row
    shift = np.repeat(starts - offsets_of(lengths)[:-1], lengths)
    return flat[shift + np.arange(total)], lengths


# --------------------------------------------------------------------------- writing files


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
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_path(final.parent)


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_columns(f: h5py.File, columns: dict) -> None:
    """Write every per-entry column (dataset name -> array) with its file dtype."""
    for name, (_, file_dtype) in ENTRY_COLUMNS.items():
        data = columns[name]
        f.create_dataset(name, data=data, dtype=file_dtype)


def write_counts(f: h5py.File, name: str, counts: np.ndarray, lengths: np.ndarray) -> None:
    """Write one histogram's counts as CSR: ``counts`` and ``offsets``."""
    f.create_dataset(f"histograms/{name}/offsets", data=offsets_of(lengths))
    f.create_dataset(f"histograms/{name}/counts", data=_as_counts(counts), dtype=COUNT_DTYPE)


def _write_paths(f: h5py.File, name: str, paths) -> None:
    f.create_dataset(name, data=_object_array(list(paths)), dtype=_STR)


# --------------------------------------------------------------------------- reading files


class _SourceFile:
    """One store file (main or batch) opened for reading, columns read on demand."""

    def __init__(self, path: Path, seq: int):
        self.path = path
        self.seq = seq
        self.file = h5py.File(path, "r")
        self._columns: dict = {}
        self._offsets: dict = {}

    def __len__(self) -> int:
        return int(self.file["entries/size"].shape[0])

    def column(self, name: str) -> np.ndarray:
        if name not in self._columns:
            self._columns[name] = _read(self.file[name], ENTRY_COLUMNS[name][0])
        return self._columns[name]

    def offsets(self, name: str) -> np.ndarray:
        if name not in self._offsets:
            self._offsets[name] = self.file[f"histograms/{name}/offsets"][()]
        return self._offsets[name]

    def counts_of(self, name: str, rows: np.ndarray):
        """(flat counts, lengths) of ``rows`` (sorted, increasing), reading one span of the file."""
        offsets = self.offsets(name)
        if len(rows) == 0:
            return np.zeros(0, dtype=COUNT_DTYPE), np.zeros(0, dtype=np.int64)
        lo, hi = int(offsets[rows[0]]), int(offsets[rows[-1] + 1])
        span = self.file[f"histograms/{name}/counts"][lo:hi]
        return take_ragged(span, offsets, rows, base=lo)

    def paths_of(self, group: str) -> np.ndarray:
        if group not in self.file:
            return _object_array([])
        return _read(self.file[f"{group}/path"], object)

    def close(self) -> None:
        self.file.close()


def _read(dataset: h5py.Dataset, dtype) -> np.ndarray:
    if dtype is object:
        return dataset.asstr()[()] if dataset.shape[0] else _object_array([])
    return dataset[()]


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
    """

    def __init__(self, path: Path, main: _SourceFile, batches: list[_SourceFile]):
        self.path = path
        self.attrs = {k: (_text(v) if isinstance(v, (bytes, str)) else v) for k, v in main.file.attrs.items()}
        self.params = StoreParams.from_attrs(self.attrs)
        self.journal = len(batches)
        self._sources = [main] + batches
        self._assemble()

    # -- assembly: which row of which file holds each live entry
    def _assemble(self) -> None:
        main = self._sources[0]
        if len(self._sources) == 1:
            self.source = np.zeros(len(main), dtype=np.int64)
            self.row = np.arange(len(main), dtype=np.int64)
            self._overrides = {}
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
        self._overrides = touched

    def _merge_order(self, main_paths, alive, latest) -> None:
        kept = np.flatnonzero(alive)
        new_paths = _object_array(sorted(latest))
        insert_at = np.searchsorted(main_paths[kept], new_paths) + np.arange(len(new_paths))
        n = len(kept) + len(new_paths)
        self.source = np.zeros(n, dtype=np.int64)
        self.row = np.zeros(n, dtype=np.int64)
        from_main = np.ones(n, dtype=bool)
        from_main[insert_at] = False
        self.row[from_main] = kept
        refs = np.array([latest[p] for p in new_paths], dtype=np.int64).reshape(-1, 2)
        self.source[insert_at], self.row[insert_at] = refs[:, 0], refs[:, 1]

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
        return Signature(points=self.params.points, seed=self.params.seed, histograms=histograms)

    def size_on_disk(self) -> int:
        """Bytes of the main file and the journal."""
        return sum(s.path.stat().st_size for s in self._sources if s.path.exists())

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


def open_store(path: str | os.PathLike, attempts: int = 20) -> StoreReader:
    """Open a store for reading: the main file and the journal batches it does not hold yet.

    Raises
    ------
    StoreError
        No store there, a file that is not a store, or one of a newer layout.
    """
    path = Path(path)
    for _ in range(attempts):
        try:
            main = _SourceFile(path, 0)
        except FileNotFoundError:
            raise StoreError(f"no store at {path} (run 'shapeidx build DIR' first, or give --store)") from None
        except OSError as exc:
            raise StoreError(f"{path}: cannot open the store ({exc})") from None
        batches = []
        try:
            _check_schema(path, main.file.attrs)
            merged = int(main.file.attrs["journal_seq"])
            for seq, batch in batch_files(path):
                if seq > merged:
                    batches.append(_SourceFile(batch, seq))
            if _same_file(path, main):  # no merge replaced the main file while the batches were listed
                return StoreReader(path, main, batches)
        except FileNotFoundError:  # a batch went: a merge finished meanwhile
            pass
        except BaseException:
            _close_all([main, *batches])
            raise
        _close_all([main, *batches])
        time.sleep(0.02)
    raise StoreError(f"{path}: the store kept changing while being opened; try again")


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
        raise StoreError(
            f"store {reader.path} was built with other signature parameters: {', '.join(differences)}; "
            "use another --store, or delete this one to rebuild it"
        )


# --------------------------------------------------------------------------- writing the store


class StoreLock:
    """The single-writer lock: an exclusive ``flock`` on ``STORE.lock``.

    The kernel drops it when its holder dies, even by kill -9, so a crash never leaves a
    stale lock. Readers take no lock.
    """

    def __init__(self, store: Path):
        self.path = lock_path(store)
        self.fd: int | None = None

    def acquire(self, wait: bool = False, on_wait=None) -> None:
        """Take the lock, or raise :class:`StoreError` naming the holder (``wait``: block)."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            if not wait:
                os.close(fd)
                raise StoreError(
                    f"another build is writing {self.path.name[: -len('.lock')]} ({holder}); "
                    "try again later, or pass --wait"
                ) from None
            if on_wait:
                on_wait(holder)
            fcntl.flock(fd, fcntl.LOCK_EX)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}, since {_now()}\n".encode(), 0)
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.ftruncate(self.fd, 0)
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def _holder(fd: int, patience: float = 0.5) -> str:
    """Who holds the lock, as its holder wrote it (it writes right after taking the lock)."""
    deadline = time.monotonic() + patience
    while True:
        text = os.pread(fd, 500, 0).decode(errors="replace").strip()
        if text or time.monotonic() > deadline:
            return text or "a process that did not say who it is"
        time.sleep(0.01)


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

    def __init__(self, path: Path, params: StoreParams, root: Path, wait: bool = False, on_wait=None):
        self.path = Path(path)
        self.params = params
        self.root = str(root)
        if not self.path.parent.is_dir():
            raise StoreError(f"cannot create the store {self.path}: no directory {self.path.parent}")
        self.lock = StoreLock(self.path)
        self.lock.acquire(wait, on_wait)
        try:
            self._prepare()
        except BaseException:
            self.lock.release()
            raise

    def _prepare(self) -> None:
        self._remove_leftovers()
        if not self.path.exists():
            self._create_empty()
        with open_store(self.path) as reader:
            check_params(reader, self.params)
            if reader.attrs.get("root") != self.root:
                raise StoreError(
                    f"store {self.path} indexes {reader.attrs.get('root')}, not {self.root}; "
                    "use another --store for this directory"
                )
            self.merged_seq = int(reader.attrs["journal_seq"])
        self.next_seq = max([self.merged_seq] + [seq for seq, _ in batch_files(self.path)]) + 1

    def _remove_leftovers(self) -> None:
        """Temporary files of killed writers, and batches already in the main file."""
        for tmp in self.path.parent.glob(f"{glob_escape(self.path.name)}.tmp-*"):
            tmp.unlink(missing_ok=True)
        folder = journal_dir(self.path)
        if folder.is_dir():
            for tmp in folder.glob("*.tmp-*"):
                tmp.unlink(missing_ok=True)
        if self.path.exists():
            with h5py.File(self.path, "r") as f:
                merged = int(f.attrs["journal_seq"]) if "journal_seq" in f.attrs else 0
            for seq, batch in batch_files(self.path):
                if seq <= merged:
                    batch.unlink(missing_ok=True)

    def _main_attrs(self, journal_seq: int, extra: dict | None = None) -> dict:
        attrs = {
            "schema_version": SCHEMA_VERSION,
            "shapeidx_version": __version__,
            **self.params.as_attrs(),
            "histograms": " ".join(HISTOGRAMS),
            "root": self.root,
            "journal_seq": journal_seq,
            "updated": _now(),
        }
        attrs.update(extra or {})
        return attrs

    def _create_empty(self) -> None:
        columns, counts = entries_to_columns([])
        attrs = self._main_attrs(0, {"created": _now()})

        def fill(f):
            f.attrs.update(attrs)
            write_columns(f, columns)
            for name, (flat, lengths) in counts.items():
                write_counts(f, name, flat, lengths)

        write_atomically(self.path, fill)

    @property
    def pending_batches(self) -> int:
        return self.next_seq - 1 - self.merged_seq

    def commit(self, batch: Batch) -> int:
        """Write ``batch`` to the journal (atomically); return its sequence number."""
        folder = journal_dir(self.path)
        folder.mkdir(exist_ok=True)
        seq = self.next_seq
        columns, counts = entries_to_columns(batch.entries)
        touched = sorted(batch.touched)

        def fill(f):
            f.attrs.update({"seq": seq, "schema_version": SCHEMA_VERSION, **self.params.as_attrs()})
            write_columns(f, columns)
            for name, (flat, lengths) in counts.items():
                write_counts(f, name, flat, lengths)
            _write_paths(f, "touched/path", [t[0] for t in touched])
            f.create_dataset("touched/size", data=np.array([t[1] for t in touched], dtype=np.int64))
            f.create_dataset("touched/mtime_ns", data=np.array([t[2] for t in touched], dtype=np.int64))
            _write_paths(f, "removed/path", sorted(batch.removed))

        write_atomically(folder / f"batch-{seq:010d}.h5", fill)
        self.next_seq += 1
        return seq

    def merge(self) -> None:
        """Write a fresh main file holding every entry, rename it into place, drop the journal.

        Nothing is written when the journal is empty: a build that changed nothing costs
        no rewrite of a large store.
        """
        with open_store(self.path) as reader:
            if reader.journal == 0:
                return
            through = max(source.seq for source in reader._sources)
            attrs = self._main_attrs(through, {"created": reader.attrs.get("created", _now())})
            write_atomically(self.path, lambda f: _write_snapshot(f, reader, attrs))
        self.merged_seq = through
        for seq, batch in batch_files(self.path):
            if seq <= through:
                batch.unlink(missing_ok=True)
        _remove_if_empty(journal_dir(self.path))

    def close(self) -> None:
        self.lock.release()

    def __enter__(self) -> "StoreWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _write_snapshot(f: h5py.File, reader: StoreReader, attrs: dict) -> None:
    """Every live entry of ``reader`` into ``f``; histogram counts copied in bounded steps."""
    f.attrs.update(attrs)
    write_columns(f, {name: reader.column(name) for name in ENTRY_COLUMNS})
    for name in HISTOGRAMS:
        lengths = np.zeros(len(reader), dtype=np.int64)
        for source_index, source in enumerate(reader._sources):
            mine = reader.source == source_index
            lengths[mine] = np.diff(source.offsets(name))[reader.row[mine]]
        offsets = offsets_of(lengths)
        f.create_dataset(f"histograms/{name}/offsets", data=offsets)
        counts = f.create_dataset(f"histograms/{name}/counts", shape=(int(offsets[-1]),), dtype=COUNT_DTYPE)
        for start in range(0, len(reader), MERGE_ROWS):
            rows = np.arange(start, min(start + MERGE_ROWS, len(reader)))
            flat, _ = reader.counts(name, rows)
            counts[offsets[rows[0]] : offsets[rows[-1] + 1]] = flat


def _remove_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass


def glob_escape(name: str) -> str:
    """``name`` with glob's special characters quoted."""
    return re.sub(r"([*?\[])", r"[\1]", name)


def describe_store(reader: StoreReader) -> dict:
    """What ``shapeidx stats`` shows: counts by status, parameters, versions, size on disk."""
    status = reader.column("entries/status")
    reasons = reader.column("entries/reason")[status == STATUS_FAILED]
    common, counts = np.unique(reasons.astype(str), return_counts=True) if len(reasons) else ([], [])
    by_count = sorted(zip(counts, common), key=lambda pair: (-pair[0], pair[1]))
    return {
        "store": str(reader.path),
        "entries": int(len(status)),
        "ok": int(np.sum(status == STATUS_OK)),
        "failed": int(np.sum(status == STATUS_FAILED)),
        "parameters": reader.params.as_attrs(),
        "schema_version": int(reader.attrs["schema_version"]),
        "shapeidx_version": reader.attrs.get("shapeidx_version"),
        "root": reader.attrs.get("root"),
        "created": reader.attrs.get("created"),
        "updated": reader.attrs.get("updated"),
        "journal_batches": reader.journal,
        "bytes": reader.size_on_disk(),
        "failure_reasons": [{"reason": str(r), "count": int(c)} for c, r in by_count],
    }
