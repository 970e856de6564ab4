"""The live ok entries of a store, straight from its files' memory-mapped ranking sections.

A query needs, of a store of N entries, the histograms its metric reads, the class
fractions and means, and the paths of the few hits. :class:`RankedView` gives exactly that
from the ``rank/`` section of every file of the store (main file and journal segments,
:mod:`shapeidx.store.rank`) without assembling the full :class:`StoreReader` view: no path
is decoded but the hits', no column is read whole, no histogram copied. It holds arrays
only; the distances are computed by :mod:`shapeidx.search.distances`.

Which rows are live (not superseded by a newer segment) is found by path key: a file's row
is dropped when a newer file holds an entry, or a removal, with the same BLAKE2b-128 key of
its path.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS, angle_probabilities
from ..signing.histogram import Histogram, Signature, known_radii
from ..signing.parameters import CLASS_NAMES, HISTOGRAMS
from .layout import STATUS_OK
from .rank import path_keys

def ranked_view(reader) -> "RankedView":
    """The :class:`RankedView` of ``reader``; a store with a file that has no ranking section
    (written before layout 3) is refused in one line: ``check --repair`` or a build adds it."""
    from ..errors import StoreError

    for source in reader._sources:
        section = source.rank
        if section is None or section.histograms != tuple(HISTOGRAMS):
            raise StoreError(f"store {reader.path} has a file without ranking arrays ({source.path.name}, written"
                             f" before layout 3): 'shapeidx check --repair --store {reader.path}' adds them")
    return RankedView(reader)


class RankedView:
    """The live ok entries of a store, in file order (main file first, then each segment).

    Attributes
    ----------
    live : list of (M_i,) int64
        Per file, the rank positions (into its ``rank/rows``) of its live ok entries.
    starts : (files + 1,) int64
        Where each file's live entries begin in the concatenated order.
    """

    def __init__(self, reader):
        self.reader = reader
        self.sources = reader._sources
        self.sections = [source.rank for source in self.sources]
        self.removed = [set(source.paths_of("removed").tolist()) if i else set() for i, source in enumerate(self.sources)]
        with self._checked(0 if len(self.sources) == 1 else None):
            self.live = self._live_positions()
        self.starts = np.concatenate([[0], np.cumsum([len(p) for p in self.live])]).astype(np.int64)
        self._gathered: dict = {}

    @contextmanager
    def _checked(self, i: int | None):
        """Damage found in the ranking arrays of file ``i`` (None: some file) as the store's one-line error."""
        try:
            yield
        except ValueError as exc:
            source = self.sources[i or 0]
            raise source.damaged(f"its ranking arrays: {exc}; 'shapeidx check --repair' rebuilds them") from None

    def _live_positions(self) -> list:
        """Per file, its ok rows that no newer file supersedes (an entry or a removal of the same path)."""
        live = [None] * len(self.sources)
        newer = np.zeros((0, 2), dtype=np.uint64)
        for i in range(len(self.sources) - 1, -1, -1):
            section = self.sections[i]
            positions = np.arange(len(section), dtype=np.int64)
            if len(newer):
                keys = section.array("path_key")[section.rows]
                order = np.lexsort((newer[:, 1], newer[:, 0]))
                first, second = newer[order, 0], newer[order, 1]
                at = np.searchsorted(first, keys[:, 0])
                maybe = np.flatnonzero(first[np.minimum(at, len(first) - 1)] == keys[:, 0])
                # the rare rows whose first 64 bits match a newer key: all 128 bits decide
                newer_set = set(zip(first.tolist(), second.tolist()))
                gone = [p for p in maybe.tolist() if (int(keys[p, 0]), int(keys[p, 1])) in newer_set]
                positions = np.delete(positions, gone)
            live[i] = positions
            if i:
                removed = path_keys(sorted(self.removed[i])) if self.removed[i] else np.zeros((0, 2), dtype=np.uint64)
                newer = np.concatenate([newer, np.asarray(section.array("path_key")), removed])
        return live

    def __len__(self) -> int:
        return int(self.starts[-1])

    # -- per-entry arrays of the live ok entries, concatenated
    def _gather(self, name: str) -> np.ndarray:
        parts = [self.sections[i].array(name)[self.live[i]] if len(self.live[i]) != len(self.sections[i])
                 else self.sections[i].array(name) for i in range(len(self.sources))]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def gather(self, name: str, positions: np.ndarray | None = None) -> np.ndarray:
        """The per-entry ranking array ``name`` (``fractions``, ``means``, ``angles``) of the live
        entries at ``positions`` (default: all, kept for later calls)."""
        if positions is None:
            if name not in self._gathered:
                with self._checked(None):
                    self._gathered[name] = self._gather(name)
            return self._gathered[name]
        positions = np.asarray(positions, dtype=np.int64)
        out = None
        for i, mine, rank_positions in self.by_file(positions):
            with self._checked(i):
                values = self.sections[i].array(name)[rank_positions]
            if out is None:
                out = np.empty((len(positions),) + values.shape[1:], dtype=values.dtype)
            out[mine] = values
        if out is None:
            width = {"fractions": 3, "means": len(HISTOGRAMS), "angles": len(ANGLE_HISTOGRAMS) * ANGLE_BINS}[name]
            out = np.zeros((0, width))
        return out

    def angle_probabilities(self, positions: np.ndarray | None = None) -> np.ndarray:
        """(n, 4, ANGLE_BINS) normal-angle probabilities of the live entries at ``positions``
        (default all, kept); NaN where unknown (entries of a store built before them)."""
        if "angle_p" in self._gathered:  # kept: each row is its own counts over their total, as below
            kept = self._gathered["angle_p"]
            return kept if positions is None else kept[np.asarray(positions, dtype=np.int64)]
        counts = self.gather("angles", positions)
        p = angle_probabilities(counts.reshape(len(counts), len(ANGLE_HISTOGRAMS), ANGLE_BINS))
        if positions is None:
            self._gathered["angle_p"] = p
        return p

    def numbers(self, name: str, width: int, positions: np.ndarray | None = None) -> np.ndarray:
        """(n, width) float64: the numeric per-entry column ``name`` of the store's entries
        (``entries/extents``, ``entries/moments``, ...) for the live entries at ``positions``
        (default all, kept for later calls); NaN where a file has none."""
        if positions is None and name in self._gathered:
            return self._gathered[name]
        at = np.arange(len(self)) if positions is None else np.asarray(positions, dtype=np.int64)
        out = np.full((len(at), width), np.nan)
        for i, mine, rows in self.rows_of(at):
            out[mine] = self.sources[i].column(name)[rows]
        if positions is None:
            self._gathered[name] = out
        return out

    def by_file(self, positions: np.ndarray):
        """``(file, indices into positions, rank positions in that file)`` of the live entries at
        ``positions``, file by file."""
        positions = np.asarray(positions, dtype=np.int64)
        file_of = np.searchsorted(self.starts, positions, side="right") - 1
        for i in np.unique(file_of).tolist():
            mine = np.flatnonzero(file_of == i)
            yield i, mine, self.live[i][positions[mine] - self.starts[i]]

    def rows_of(self, positions: np.ndarray) -> list:
        """``(file, rows of that file)`` of the live entries at ``positions``, with where each goes."""
        return [(i, mine, self.sections[i].rows[rank_positions]) for i, mine, rank_positions in self.by_file(positions)]

    def checked(self, i: int | None):
        """Damage found in the ranking arrays of file ``i`` as the store's one-line error (a context)."""
        return self._checked(i)

    # -- single entries, read alone
    def locate(self, position: int) -> tuple[int, int]:
        """(file, row) of the live entry at ``position``."""
        i = int(np.searchsorted(self.starts, position, side="right")) - 1
        return i, int(self.sections[i].rows[self.live[i][position - self.starts[i]]])

    def path_at(self, position: int) -> str:
        """The path of one live entry, read alone and checked against its (CRC-checked) key."""
        i, row = self.locate(position)
        path = self.sources[i].path_at(row)
        with self._checked(i):
            key = self.sections[i].array("path_key")[row]
        if not np.array_equal(path_keys([path])[0], key):
            raise self.sources[i].damaged("entries/path disagrees with its ranking key")
        return path

    def find(self, path: str) -> tuple[int, int] | None:
        """(file, row) of the newest entry with ``path`` (ok or failed), or None."""
        for i in range(len(self.sources) - 1, -1, -1):
            row = self.sources[i].find(path)
            if row is not None:
                return i, row
            if path in self.removed[i]:
                return None
        return None

    def position_of(self, found: tuple[int, int]) -> int | None:
        """The position of the entry (file, row) among the live ok entries, or None (a failed entry)."""
        i, row = found
        rows = self.sections[i].rows
        p = int(np.searchsorted(rows, row))
        if p >= len(rows) or rows[p] != row:
            return None
        k = int(np.searchsorted(self.live[i], p))
        return int(self.starts[i]) + k if k < len(self.live[i]) and self.live[i][k] == p else None

    def status_of(self, found: tuple[int, int]) -> tuple[int, str]:
        i, row = found
        source = self.sources[i]
        status = int(source.value_at("entries/status", row))
        reason = "" if status == STATUS_OK else str(source._read("entries/reason", object)[row])
        return status, reason

    def signature(self, found: tuple[int, int], params) -> Signature:
        """The stored signature of the entry (file, row), read from its canonical (checksummed) data."""
        i, row = found
        source = self.sources[i]
        histograms = {}
        for name in HISTOGRAMS:
            lo, hi = (int(v) for v in source._read(f"histograms/{name}/offsets", np.int64, np.s_[row : row + 2]))
            counts = source._read(f"histograms/{name}/counts", np.uint32, np.s_[lo:hi]) if hi > lo else np.zeros(0)
            mean = float(source.value_at(f"histograms/{name}/mean", row))
            width = float(source.value_at(f"histograms/{name}/bin_width", row))
            if not 0 <= lo <= hi <= source.dataset(f"histograms/{name}/counts").shape[0]:
                raise source.damaged(f"histograms/{name}/offsets are out of bounds")
            histograms[name] = Histogram(np.asarray(counts).astype(np.int64), mean, width)
        # what check verifies for every entry, for this one: its histograms hold all the pairs
        pairs = params.points * (params.points - 1) // 2
        classes = sum(int(histograms[c].counts.sum()) for c in CLASS_NAMES)
        if int(histograms["all"].counts.sum()) != pairs or classes != pairs:
            raise source.damaged(f"histograms of {source.path_at(row)} do not hold {pairs} pairs")
        angles = np.asarray(source.value_at("entries/angles", row), dtype=np.float64)
        angles = angles.reshape(len(ANGLE_HISTOGRAMS), ANGLE_BINS).astype(np.int64) if np.isfinite(angles).all() else None
        return Signature(points=params.points, seed=params.seed, histograms=histograms, angles=angles,
                         radii=known_radii(source.column("entries/extents")[row]))
