"""What a build needs to know of a store's live entries, found by path key, no path decoded.

A build's plan compares every walked file's size and modification time with its entry. At
10^6 entries, decoding every stored path (and checking the SHA-256 of them all) to look the
files up costs seconds, and grows with the store. :func:`known_files` instead takes each
file's ``rank/path_key`` (the BLAKE2b-128 of its paths, CRC-32-checked as it is mapped) and
its ``size``, ``mtime_ns``, ``status`` and ``revision`` columns (Fletcher-32, 25 bytes an entry), applies
the journal segments by key (an entry or a removal of a newer file supersedes; a newer
file's ``touched`` times apply), and looks the walked files up by their keys. Paths and
content hashes are read only for the rows that need them: the changed files' hashes, the
removed entries' paths.

Files written before layout 3 have no path keys: their paths are decoded and keyed (the
cost of the old way, once per build, until their next merge gives them the section).
"""

from __future__ import annotations

import numpy as np

from .layout import FIRST_REVISION, REVISION_COLUMN, STATUS_OK
from .rank import path_keys

#: Above this share of a file's rows, reading its whole path column beats single reads.
WHOLE_COLUMN_SHARE = 1 / 64


def _keys_of(source) -> np.ndarray:
    """(n, 2) uint64 path keys of every row of one store file, their CRC-32 checked.

    Only ``rank/path_key`` is read (16 bytes an entry), not the whole section: opening a
    :class:`~shapeidx.store.rank.RankSection` checks the CRCs of every per-entry array.
    """
    from .rank import CHECKSUM, RANK, bytes_crc32

    name = f"{RANK}/path_key"
    if name not in source.file:  # a file written before layout 3
        return path_keys(source.column("entries/path"))
    dataset = source.dataset(name)
    try:
        keys = dataset[()]
    except (OSError, RuntimeError, ValueError) as exc:
        raise source.damaged(f"{name} cannot be read: {exc}") from None
    expected = dataset.attrs.get(CHECKSUM)
    if keys.shape != (len(source), 2) or expected is None or bytes_crc32(keys) != int(expected):
        raise source.damaged(f"{name} fails its checksum; 'shapeidx check --repair' rebuilds the ranking arrays")
    return keys


class _KeyIndex:
    """128-bit keys sorted by their first 64 bits, looked up exactly (both halves compared)."""

    def __init__(self, keys: np.ndarray):
        keys = np.asarray(keys, dtype=np.uint64).reshape(-1, 2)
        self.order = np.argsort(keys[:, 0], kind="stable")
        self.first, self.second = keys[self.order, 0], keys[self.order, 1]

    def find(self, keys: np.ndarray) -> np.ndarray:
        """Position (into the keys given at construction) of each of ``keys``, or -1."""
        keys = np.asarray(keys, dtype=np.uint64).reshape(-1, 2)
        out = np.full(len(keys), -1, dtype=np.int64)
        if len(self.first) == 0 or len(keys) == 0:
            return out
        at = np.searchsorted(self.first, keys[:, 0])
        inside = np.minimum(at, len(self.first) - 1)
        hit = (self.first[inside] == keys[:, 0]) & (at < len(self.first))
        exact = hit & (self.second[inside] == keys[:, 1])
        out[exact] = self.order[inside[exact]]
        # the rare keys whose first 64 bits equal another's: the run of equal first halves decides
        for q in np.flatnonzero(hit & ~exact).tolist():
            j = int(at[q])
            while j < len(self.first) and self.first[j] == keys[q, 0]:
                if self.second[j] == keys[q, 1]:
                    out[q] = self.order[j]
                    break
                j += 1
        return out

    def contains(self, keys: np.ndarray) -> np.ndarray:
        return self.find(keys) >= 0


class KnownFiles:
    """The live entries of a store as a build's plan sees them (in no particular order).

    Attributes
    ----------
    source, row : (n,) int64
        The file (index into ``reader._sources``) and row of each live entry.
    size, mtime_ns : (n,) int64
        Its file's size and modification time, as the store last recorded them.
    status : (n,) uint8
    revision : (n,) int64
        The revision of the reader that signed it (:data:`~shapeidx.store.layout.REVISION_COLUMN`;
        1 in a file written before the column).
    """

    def __init__(self, reader, keys, source, row, size, mtime_ns, status, revision=None):
        self.reader = reader
        self.source, self.row = source, row
        self.size, self.mtime_ns, self.status = size, mtime_ns, status
        self.revision = np.full(len(row), FIRST_REVISION, dtype=np.int64) if revision is None else revision
        self._index = _KeyIndex(keys)

    def __len__(self) -> int:
        return len(self.row)

    def lookup(self, paths) -> np.ndarray:
        """The live entry (index) of each path, or -1."""
        return self._index.find(path_keys(paths))

    def _per_source(self, indices, read_one, read_all) -> list:
        indices = np.asarray(indices, dtype=np.int64)
        out = [None] * len(indices)
        for i, source in enumerate(self.reader._sources):
            mine = np.flatnonzero(self.source[indices] == i)
            if len(mine) == 0:
                continue
            rows = self.row[indices[mine]]
            if len(rows) > WHOLE_COLUMN_SHARE * len(source):
                column = read_all(source)
                values = [column[r] for r in rows.tolist()]
            else:
                values = [read_one(source, r) for r in rows.tolist()]
            for k, value in zip(mine.tolist(), values):
                out[k] = value
        return out

    def paths(self, indices) -> list[str]:
        """The paths of the live entries ``indices`` (only their rows are read, when few)."""
        return self._per_source(indices, lambda s, r: s.path_at(r), lambda s: s.column("entries/path"))

    def hashes(self, indices) -> list[str]:
        """The content hashes (SHA-256 hex, '' if none) of the live entries ``indices``."""
        values = self._per_source(indices, lambda s, r: s.value_at("entries/hash", r), lambda s: s.column("entries/hash"))
        return [bytes(v).decode() for v in values]

    def status_counts(self) -> tuple[int, int]:
        """(ok, failed) live entries."""
        ok = int(np.sum(self.status == STATUS_OK))
        return ok, len(self) - ok


def known_files(reader) -> KnownFiles:
    """The live entries of ``reader``'s store (see the module docstring).

    Mirrors :meth:`StoreReader._assemble`: a file's row is live unless a newer file holds an
    entry or a removal of its path; the newest ``touched`` times of a path apply to its entry
    when they are no older than the file that holds it.
    """
    sources = reader._sources
    parts = []  # (file, live rows, their keys), newest file first
    newer = np.zeros((0, 2), dtype=np.uint64)
    touches: dict = {}  # key -> (size, mtime_ns, file), the newest touch of each path
    for i in range(len(sources) - 1, -1, -1):
        source = sources[i]
        keys = _keys_of(source)
        rows = np.arange(len(keys), dtype=np.int64)
        if len(newer):
            rows = rows[~_KeyIndex(newer).contains(keys)]
        parts.append((i, rows, keys[rows]))
        if i:
            removed = source.paths_of("removed")
            extra = [keys]
            if len(removed):
                extra.append(path_keys(removed))
            if "touched" in source.file:
                size, mtime = source.file["touched/size"][()], source.file["touched/mtime_ns"][()]
                touched = source.paths_of("touched")
                for key, s, m in zip(map(tuple, path_keys(touched).tolist()), size.tolist(), mtime.tolist()):
                    touches.setdefault(key, (int(s), int(m), i))
            newer = np.concatenate([newer, *extra])
    file_of = np.concatenate([np.full(len(rows), i, dtype=np.int64) for i, rows, _ in parts])
    row = np.concatenate([rows for _, rows, _ in parts])
    keys = np.concatenate([k for _, _, k in parts]).reshape(-1, 2)

    def column(name, dtype):
        return np.concatenate([np.asarray(sources[i].column(name), dtype=dtype)[rows] for i, rows, _ in parts])

    size, mtime, status = column("entries/size", np.int64), column("entries/mtime_ns", np.int64), column("entries/status", np.uint8)
    revision = column(REVISION_COLUMN, np.int64)  # a file written before the column: all 1
    known = KnownFiles(reader, keys, file_of, row, size, mtime, status, revision)
    if touches:
        touched_keys = np.array(list(touches), dtype=np.uint64).reshape(-1, 2)
        at = known._index.find(touched_keys)
        for (s, m, i), k in zip(touches.values(), at.tolist()):
            if k >= 0 and i >= file_of[k]:  # a newer entry of the path supersedes the touch
                size[k], mtime[k] = s, m
    return known
