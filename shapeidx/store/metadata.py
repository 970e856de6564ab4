"""The metadata table a user joins to the shapes: ``build DIR --metadata parts.csv``.

A CSV file with a header: one column names the part file (``path``, ``file`` or
``filename``: relative to the indexed folder, or absolute inside it), every other column is
a metadata key (part number, material, project, revision, ...). The build copies it into the
store as ``STORE/metadata.h5``, written whole and atomically under the store's lock, apart
from the signatures: metadata that changes is read again by the next build given the
table, and no part is signed again for it. A build without ``--metadata`` keeps the table
the store has.

    metadata.h5
        path            (R,) UTF-8    the table's paths, relative to the indexed folder, sorted
        path_key        (R, 2) uint64 BLAKE2b-128 of each path (the ranking arrays' key)
        columns/K       (R,) UTF-8    one dataset per metadata key (attribute ``key``: its name)
        attributes      source (the CSV given), sha256 (of its bytes), rows, updated

Queries join the table to the store's entries by path key (:meth:`MetadataTable.rows_of`);
a row whose file is not (yet) in the store is kept and simply matches no entry.
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from ..errors import ShapeidxError, printable
from .files import write_atomically
from .layout import CONTENT_HASH, as_text, checked, object_array, strings_hash, utc_now
from .rank import path_keys
from .reader import damaged

METADATA_FILE = "metadata.h5"
#: Names the path column may have (case-insensitive), first found wins.
PATH_COLUMNS = ("path", "file", "filename")
#: Keys that cannot be metadata columns: ``path`` is the entry's own path.
RESERVED = ("path",)
#: Largest table accepted (bytes): far beyond any real parts list, short of filling memory.
MAX_TABLE_BYTES = 1 << 30


def metadata_path(store: Path) -> Path:
    return Path(store) / METADATA_FILE


@dataclass
class MetadataTable:
    """A metadata table: sorted paths, their keys, and one column of strings per key."""

    paths: np.ndarray
    keys: np.ndarray
    columns: dict
    source: str = ""
    sha256: str = ""

    def __len__(self) -> int:
        return len(self.paths)

    def rows_of(self, keys: np.ndarray) -> np.ndarray:
        """The table row of each path key of ``keys`` ((n, 2) uint64), -1 where none."""
        keys = np.asarray(keys, dtype=np.uint64).reshape(-1, 2)
        out = np.full(len(keys), -1, dtype=np.int64)
        if len(self) == 0 or len(keys) == 0:
            return out
        order = np.lexsort((self.keys[:, 1], self.keys[:, 0]))
        first = self.keys[order, 0]
        at = np.minimum(np.searchsorted(first, keys[:, 0]), len(first) - 1)
        # the first 64 bits find the row; all 128 decide (a neighbour with the same first half is checked too)
        for shift in (0, 1, -1):
            candidate = np.clip(at + shift, 0, len(first) - 1)
            rows = order[candidate]
            hit = (self.keys[rows, 0] == keys[:, 0]) & (self.keys[rows, 1] == keys[:, 1]) & (out < 0)
            out[hit] = rows[hit]
        return out

    def column(self, key: str, rows: np.ndarray) -> np.ndarray:
        """The values of ``key`` at table ``rows`` ("" where a row is -1)."""
        values = self.columns[key]
        rows = np.asarray(rows, dtype=np.int64)
        out = object_array([""] * len(rows))
        found = rows >= 0
        out[found] = values[rows[found]]
        return out


def read_csv_table(csv_file: str | os.PathLike, root: Path) -> tuple[MetadataTable, list[str]]:
    """The table of ``csv_file`` with paths made relative to ``root``; and warnings (one line each).

    Raises
    ------
    ShapeidxError
        The file cannot be read, has no header or no path column, or a path outside ``root``.
    """
    name = printable(os.fspath(csv_file))
    try:
        data = Path(csv_file).read_bytes()
    except OSError as exc:
        raise ShapeidxError(f"--metadata {name}: cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_TABLE_BYTES:
        raise ShapeidxError(f"--metadata {name}: {len(data):,} bytes is more than a metadata table may hold")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ShapeidxError(f"--metadata {name}: not UTF-8 text (byte {exc.start})") from None
    try:
        dialect = csv.Sniffer().sniff(text[:65536], delimiters=",;\t") if text.strip() else csv.excel
    except csv.Error:
        dialect = csv.excel
    rows = list(csv.reader(io.StringIO(text), dialect))
    if not rows or not any(cell.strip() for cell in rows[0]):
        raise ShapeidxError(f"--metadata {name}: no header row (the first row names the columns)")
    header = [cell.strip() for cell in rows[0]]
    lowered = [h.lower() for h in header]
    path_at = next((lowered.index(p) for p in PATH_COLUMNS if p in lowered), None)
    if path_at is None:
        raise ShapeidxError(f"--metadata {name}: no path column (name one of {', '.join(PATH_COLUMNS)};"
                            f" the header is {', '.join(header)})")
    keys = [h for i, h in enumerate(header) if i != path_at]
    for problem in (k for k in keys if not k or k.lower() in RESERVED or k in header[:header.index(k)]):
        raise ShapeidxError(f"--metadata {name}: column {problem!r} is empty, reserved or repeated")
    warnings, table = [], {}
    resolved_root = Path(root).resolve()
    for number, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            warnings.append(f"--metadata {name}:{number}: {len(row)} cells for {len(header)} columns; row left out")
            continue
        raw = row[path_at].strip()
        relative = _relative(raw, resolved_root)
        if relative is None:
            raise ShapeidxError(f"--metadata {name}:{number}: {printable(raw)} is outside the indexed folder {resolved_root}")
        if relative in table:
            warnings.append(f"--metadata {name}:{number}: {printable(relative)} given again; the later row wins")
        table[relative] = [" ".join(cell.split()) for i, cell in enumerate(row) if i != path_at]
    paths = object_array(sorted(table))
    columns = {key: object_array([table[p][k] for p in paths]) for k, key in enumerate(keys)}
    return MetadataTable(paths, path_keys(paths), columns, os.fspath(Path(csv_file).resolve()),
                         hashlib.sha256(data).hexdigest()), warnings


def _relative(raw: str, root: Path) -> str | None:
    """``raw`` as a path relative to ``root``, ``/``-separated (None: outside it)."""
    path = Path(raw)
    if path.is_absolute():
        try:
            return Path(os.path.normpath(path)).relative_to(root).as_posix()
        except ValueError:
            try:
                return path.resolve().relative_to(root).as_posix()
            except (ValueError, OSError):
                return None
    normal = os.path.normpath(raw).replace(os.sep, "/")
    return None if normal == ".." or normal.startswith("../") else normal


def write_table(store: Path, table: MetadataTable) -> None:
    """Write ``STORE/metadata.h5`` (atomically; the caller holds the store's lock)."""

    def fill(f: h5py.File) -> None:
        f.attrs.update({"source": table.source, "sha256": table.sha256, "rows": len(table), "updated": utc_now()})
        _strings(f, "path", table.paths)
        f.create_dataset("path_key", data=table.keys, **checked(table.keys.shape))
        group = f.create_group("columns")
        for index, (key, values) in enumerate(table.columns.items()):
            dataset = _strings(group, str(index), values)
            dataset.attrs["key"] = key

    size = sum(len(str(v)) + 16 for values in [table.paths, *table.columns.values()] for v in values)
    write_atomically(metadata_path(store), fill, 2 * size + 32 * len(table))


def _strings(group, name: str, values) -> h5py.Dataset:
    values = object_array(list(values))
    dataset = group.create_dataset(name, data=values, dtype=h5py.string_dtype("utf-8"))
    dataset.attrs[CONTENT_HASH] = strings_hash(values)
    return dataset


def load_table(store: Path) -> MetadataTable | None:
    """The store's metadata table, or None when it has none.

    Raises
    ------
    StoreDamagedError
        The file fails its checks.
    """
    path = metadata_path(store)
    if not path.exists():
        return None
    try:
        from .heaps import open_hdf5

        with open_hdf5(path) as f:
            paths = _read_strings(f["path"])
            keys = np.asarray(f["path_key"][()], dtype=np.uint64).reshape(-1, 2)
            columns = {}
            for name in sorted(f["columns"], key=int):
                dataset = f["columns"][name]
                columns[as_text(dataset.attrs["key"])] = _read_strings(dataset)
            source, sha = as_text(f.attrs.get("source", "")), as_text(f.attrs.get("sha256", ""))
    except (OSError, KeyError, ValueError, RuntimeError) as exc:
        raise damaged(Path(store), f"{METADATA_FILE} cannot be read: {str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__}") from None
    if len(keys) != len(paths) or any(len(v) != len(paths) for v in columns.values()):
        raise damaged(Path(store), f"{METADATA_FILE} has columns of unequal length")
    return MetadataTable(paths, keys, columns, source, sha)


def _read_strings(dataset) -> np.ndarray:
    values = dataset.asstr()[()] if dataset.shape[0] else object_array([])
    values = object_array(list(values))
    if strings_hash(values) != as_text(dataset.attrs.get(CONTENT_HASH, "")):
        raise ValueError(f"{dataset.name} fails its content checksum")
    return values
