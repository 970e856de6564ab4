"""What a store file holds: its schema, the per-entry columns, and how entries become columns.

The README's "The store" section is the reader's guide to this layout; keep the two in step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone

import h5py
import numpy as np

from ..errors import StoreError
from ..io.faceting import DEFAULT_ANGULAR_DEFLECTION, DEFAULT_LINEAR_DEFLECTION, Faceting
from ..io.metadata import FILE_KEYS
from ..ragged import offsets_of
from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS
from ..signing.histogram import Histogram, Signature
from ..signing.parameters import HISTOGRAMS

#: Layout version of the files; a store with a newer one is refused. 2 added the size and
#: handedness columns (:data:`SHAPE_COLUMNS`); files of layout 1 still open, those columns NaN.
#: 3 added the memory-mapped ranking section ``rank/`` (shapeidx.store.rank) and journal
#: segments that stay until a size-tiered merge (shapeidx.store.writer); files of layout 1
#: and 2 still open and get the section when they are next rewritten (or by ``check --repair``).
#: 4: the store is a directory (shapeidx.store.files) and each file has the text columns of
#: what a part file says about itself (:data:`TEXT_COLUMNS`; read as "" from older files).
SCHEMA_VERSION = 4
STATUS_OK, STATUS_FAILED = 0, 1
#: Class fractions are stored as (N, 3) in this order.
FRACTION_CLASSES = HISTOGRAMS[1:]
#: Where the default store lives, relative to the working directory.
DEFAULT_STORE = "index.shapeidx"
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
#: Added in layout 2 (shapeidx.signing.moments.shape_facts): bounding box (min xyz, max
#: xyz) and principal radii in file units, the two handedness pseudo-scalars and four
#: scale-free surface moments (area / sum r^2, |skewness| per axis); later the third
#: handedness pseudo-scalar (:data:`HANDEDNESS_COLUMNS`). Absent from older files: read as
#: NaN (``StoreReader.missing_columns`` names them).
SHAPE_COLUMNS = {"entries/bounds": 6, "entries/extents": 3, "entries/handedness": 2, "entries/moments": 4,
                 "entries/axial_handedness": 1}
#: The columns of the three handedness pseudo-scalars of :func:`shapeidx.signing.moments.shape_facts`,
#: in its order: ``h1, h2`` (layout 2) and ``h3``, the handedness about the one defined axis,
#: added later in the same layout (absent from older files: NaN, the mirror unknown there).
HANDEDNESS_COLUMNS = ("entries/handedness", "entries/axial_handedness")
#: Later, in the same layout: the pair counts of the normal-angle histograms
#: (shapeidx.signing.angles; rows all, in, out, mixed, laid end to end). Absent from older
#: files, read as NaN like the columns above: the metrics that use them then refuse the store.
ANGLE_COLUMNS = {"entries/angles": len(ANGLE_HISTOGRAMS) * ANGLE_BINS}
#: Numeric columns a file may lack (read as NaN): name -> width.
OPTIONAL_COLUMNS = {**SHAPE_COLUMNS, **ANGLE_COLUMNS}
ENTRY_COLUMNS.update({name: (np.float64, np.float64) for name in OPTIONAL_COLUMNS})
#: Layout 4: what the file says about itself (shapeidx.io.metadata: the STEP product's name and
#: id, a VRML WorldInfo title), one string column per key; absent from older files (read as "").
TEXT_COLUMNS = tuple(f"entries/{key}" for key in FILE_KEYS)
ENTRY_COLUMNS.update({name: (object, _STR) for name in TEXT_COLUMNS})
#: Sub-entries (``build --parts``, :mod:`shapeidx.io.parts`), in the same layout: the file an
#: entry is a sub-part of ("" for a whole file) and how many times that file holds it (1 for a
#: whole file). Absent from older files: read as "" and 1.
PARENT_COLUMN, COUNT_COLUMN = "entries/parent", "entries/count"
ENTRY_COLUMNS[PARENT_COLUMN] = (object, _STR)
ENTRY_COLUMNS[COUNT_COLUMN] = (np.int64, np.int64)
#: The revision of the reader that signed the entry (:attr:`shapeidx.io.base.Format.revision`,
#: of the format its file's name says; a failed entry's too): a build signs again an entry whose
#: reader has been revised since (:mod:`shapeidx.index.plan`). Absent from older files: read as
#: :data:`FIRST_REVISION`, what every reader was before revisions were recorded.
REVISION_COLUMN = "entries/revision"
FIRST_REVISION = 1
ENTRY_COLUMNS[REVISION_COLUMN] = (np.int64, np.int64)
#: Every column a file may lack.
MAY_BE_ABSENT = (frozenset(OPTIONAL_COLUMNS) | frozenset(TEXT_COLUMNS)
                 | {PARENT_COLUMN, COUNT_COLUMN, REVISION_COLUMN})
for _name in HISTOGRAMS:
    ENTRY_COLUMNS[f"histograms/{_name}/mean"] = (np.float64, np.float64)
    ENTRY_COLUMNS[f"histograms/{_name}/bin_width"] = (np.float64, np.float64)
#: Histogram counts are stored as uint32: at most 8192 points give 33,550,336 pairs.
COUNT_DTYPE = np.uint32
#: Catalog rows copied per step of a merge: bounds its memory whatever the store's size.
MERGE_ROWS = 65_536
#: Every dataset is written in chunks, each with HDF5's Fletcher-32 checksum, so that a flipped
#: byte is found when it is read; a damaged chunk costs only the entries it holds (--repair).
CHUNK_ROWS = 1024
CHUNK_COUNTS = 16_384
#: Attribute of every variable-length string dataset: SHA-256 of its values, each followed by
#: NUL (HDF5 filters no variable-length data, so these datasets have no Fletcher-32).
CONTENT_HASH = "content_sha256"


def checked(shape, counts: bool = False) -> dict:
    """``create_dataset`` options for a checksummed (Fletcher-32) dataset of ``shape``."""
    shape = tuple(int(n) for n in shape)
    if not shape or shape[0] == 0:
        return {}  # nothing to protect; HDF5 cannot chunk an empty fixed-size dataset
    rows = min(shape[0], CHUNK_COUNTS if counts else CHUNK_ROWS)
    return {"chunks": (rows,) + shape[1:], "fletcher32": True}


def strings_hash(values) -> str:
    """The :data:`CONTENT_HASH` of a string column."""
    import hashlib

    digest = hashlib.sha256()
    for value in values:
        digest.update(str(value).encode("utf-8", "surrogatepass") + b"\0")
    return digest.hexdigest()


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
            seed_policy=as_text(attrs["seed_policy"]),
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


def as_text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


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
    bounds: tuple = (float("nan"),) * 6
    extents: tuple = (float("nan"),) * 3
    handedness: tuple = (float("nan"),) * 2
    moments: tuple = (float("nan"),) * 4
    axial_handedness: tuple = (float("nan"),)
    angles: tuple = (float("nan"),) * (len(ANGLE_HISTOGRAMS) * ANGLE_BINS)
    title: str = ""
    product_id: str = ""
    #: A sub-entry's file (its path relative to the root), "" for a whole file.
    parent: str = ""
    #: How many times ``parent`` holds this sub-part.
    count: int = 1
    #: The revision of the reader that read the file (:data:`REVISION_COLUMN`); None: the
    #: current one of its format (:func:`shapeidx.io.registry.reader_revision`), found when the
    #: entry is written. A build's workers set it (a Dask worker's reader may be another's).
    revision: int | None = None

    @classmethod
    def indexed(cls, path, hash, size, mtime_ns, signature: Signature, facts: dict, shape: dict | None = None) -> "Entry":
        """An ok entry: a signature, the mesh facts of :meth:`shapeidx.signing.solid.Solid.describe`
        and the size and handedness of :func:`shapeidx.signing.moments.shape_facts` (``shape``)."""
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
            **{k: tuple(float(v) for v in shape[k]) for k in ("bounds", "extents", "moments") if k in (shape or {})},
            **({} if "handedness" not in (shape or {}) else
               {"handedness": tuple(float(v) for v in shape["handedness"][:2]),
                "axial_handedness": tuple(float(v) for v in shape["handedness"][2:3]) or (float("nan"),)}),
            **({} if signature.angles is None else {"angles": tuple(float(v) for v in np.ravel(signature.angles))}),
            **{key: str(value) for key, value in facts.get("metadata", {}).items() if key in FILE_KEYS},
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
        "entries/path": object_array([e.path for e in entries]),
        "entries/hash": np.array([e.hash.encode() for e in entries], dtype=_HASH),
        "entries/size": np.array([e.size for e in entries], dtype=np.int64),
        "entries/mtime_ns": np.array([e.mtime_ns for e in entries], dtype=np.int64),
        "entries/status": np.array([e.status for e in entries], dtype=np.uint8),
        "entries/reason": object_array([e.reason for e in entries]),
        "entries/triangles": np.array([e.triangles for e in entries], dtype=np.int64),
        "entries/area": np.array([e.area for e in entries], dtype=np.float64),
        "entries/watertight": np.array([e.watertight for e in entries], dtype=np.bool_),
        "entries/fractions": np.array([e.fractions for e in entries], dtype=np.float64).reshape(n, 3),
    }
    for name, width in OPTIONAL_COLUMNS.items():
        key = name.split("/")[1]
        columns[name] = np.array([getattr(e, key) for e in entries], dtype=np.float64).reshape(n, width)
    for name in TEXT_COLUMNS:
        columns[name] = object_array([getattr(e, name.split("/")[1]) for e in entries])
    columns[PARENT_COLUMN] = object_array([e.parent for e in entries])
    columns[COUNT_COLUMN] = np.array([e.count for e in entries], dtype=np.int64)
    columns[REVISION_COLUMN] = np.array([_revision_of(e) for e in entries], dtype=np.int64)
    counts = {}
    for name in HISTOGRAMS:
        hists = [e.histograms.get(name, empty) for e in entries]
        columns[f"histograms/{name}/mean"] = np.array([h.mean for h in hists], dtype=np.float64)
        columns[f"histograms/{name}/bin_width"] = np.array([h.bin_width for h in hists], dtype=np.float64)
        lengths = np.array([len(h.counts) for h in hists], dtype=np.int64)
        flat = np.concatenate([h.counts for h in hists]) if n else np.zeros(0)
        counts[name] = (_as_counts(flat), lengths)
    return columns, counts


def _revision_of(entry: Entry) -> int:
    if entry.revision is not None:
        return int(entry.revision)
    from ..io.registry import reader_revision

    return reader_revision(entry.parent or entry.path)


def object_array(values) -> np.ndarray:
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


def _as_counts(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values)
    if len(values) and values.max() > np.iinfo(COUNT_DTYPE).max:
        raise StoreError("a histogram bin holds more pairs than the store's uint32 counts allow")
    return values.astype(COUNT_DTYPE)


def write_columns(f: h5py.File, columns: dict) -> None:
    """Write every per-entry column (dataset name -> array) with its file dtype."""
    for name, (_, file_dtype) in ENTRY_COLUMNS.items():
        data = columns[name] if name in columns or name not in MAY_BE_ABSENT else missing_column(name, _rows(columns))
        # HDF5 filters no variable-length data: strings are covered by their content hash
        options = {} if file_dtype is _STR else checked(np.shape(data))
        dataset = f.create_dataset(name, data=data, dtype=file_dtype, **options)
        if file_dtype is _STR:
            dataset.attrs[CONTENT_HASH] = strings_hash(data)
        if name in TEXT_COLUMNS:  # whether any entry has a value: what a CSV answer's columns are
            dataset.attrs[TEXT_PRESENT] = bool(len(data) and any(v != "" for v in data))


#: Attribute of a text column (:data:`TEXT_COLUMNS`): whether any of its values is not empty.
TEXT_PRESENT = "any_value"


def handedness_columns(column) -> np.ndarray:
    """``(N, 3)``: the handedness pseudo-scalars ``h1, h2, h3`` (:data:`HANDEDNESS_COLUMNS`),
    ``column(name)`` giving each column (a reader's ``column``, a dict's ``__getitem__``)."""
    return np.hstack([np.asarray(column(name), dtype=np.float64).reshape(-1, SHAPE_COLUMNS[name])
                      for name in HANDEDNESS_COLUMNS])


def missing_column(name: str, rows: int) -> np.ndarray:
    """A column an older file lacks: NaN (rows, width), or "" for a text column."""
    if name in TEXT_COLUMNS or name == PARENT_COLUMN:
        return object_array([""] * rows)
    if name == COUNT_COLUMN:
        return np.ones(rows, dtype=np.int64)
    if name == REVISION_COLUMN:
        return np.full(rows, FIRST_REVISION, dtype=np.int64)
    return np.full((rows, OPTIONAL_COLUMNS[name]), np.nan)


def _rows(columns: dict) -> int:
    return len(columns["entries/path"])


def write_counts(f: h5py.File, name: str, counts: np.ndarray, lengths: np.ndarray) -> None:
    """Write one histogram's counts as CSR: ``counts`` and ``offsets``."""
    offsets = offsets_of(lengths)
    f.create_dataset(f"histograms/{name}/offsets", data=offsets, **checked(offsets.shape))
    counts = _as_counts(counts)
    f.create_dataset(f"histograms/{name}/counts", data=counts, dtype=COUNT_DTYPE, **checked(counts.shape, counts=True))


def write_paths(f: h5py.File, name: str, paths) -> None:
    values = object_array(list(paths))
    dataset = f.create_dataset(name, data=values, dtype=_STR)
    dataset.attrs[CONTENT_HASH] = strings_hash(values)


def write_int64(f: h5py.File, name: str, values) -> None:
    values = np.asarray(values, dtype=np.int64)
    f.create_dataset(name, data=values, **checked(values.shape))
