"""Ranking a store straight from its files' memory-mapped ranking sections.

A one-off query needs, of a store of N entries, the histograms its metric reads, the class
fractions and means, and the paths of the few hits. :class:`RankedView` gives exactly that
from the ``rank/`` section of every file of the store (main file and journal segments,
:mod:`shapeidx.store.rank`) without assembling the full :class:`StoreReader` view: no path
is decoded but the hits', no column is read whole, no histogram copied.

Which rows are live (not superseded by a newer segment) is found by path key: a file's row
is dropped when a newer file holds an entry, or a removal, with the same BLAKE2b-128 key of
its path. Distances are those of :class:`~shapeidx.distance.HistogramBank` over the very
same counts, so they equal :func:`shapeidx.distance.compare` bit for bit.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from ..distance.bank import features_to_many
from ..distance.combined import ANGLE_METRICS, metric_values, require_angles
from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS, angle_probabilities
from ..signing.histogram import Histogram, Signature
from ..signing.parameters import CLASS_NAMES, HISTOGRAMS
from .layout import STATUS_OK
from .rank import path_keys

#: Threads that rank the blocks of one query (numpy releases the GIL; see docs/performance.md).
RANK_THREADS = 2


def ranked_view(reader, histograms=HISTOGRAMS):
    """A :class:`RankedView` of ``reader``, or None when a file of it has no ranking section
    (written before layout 3) holding ``histograms`` and the store's histograms in order."""
    for source in reader._sources:
        section = source.rank
        if section is None or section.histograms != tuple(HISTOGRAMS) or not set(histograms) <= set(section.histograms):
            return None
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

    @property
    def fractions(self) -> np.ndarray:
        return self._gather("fractions")

    @property
    def means(self) -> np.ndarray:
        """(N, H) mean pair distance of each histogram, in :data:`HISTOGRAMS` order."""
        return self._gather("means")

    @property
    def angles(self) -> np.ndarray:
        """(N, 4, ANGLE_BINS) normal-angle probabilities of each entry (NaN where unknown)."""
        counts = self._gather("angles")
        return angle_probabilities(counts.reshape(len(counts), len(ANGLE_HISTOGRAMS), ANGLE_BINS))

    def histogram_distances(self, h: str, query_p: np.ndarray, pool=None) -> np.ndarray:
        """``D`` of histogram ``h`` from ``query_p`` to every live entry."""
        outs, jobs = [], []
        for i, section in enumerate(self.sections):
            with self._checked(i):
                bank = section.bank(h)
            out = np.zeros(len(section))
            outs.append(out)
            for part in _halves(bank.groups, len(query_p)) if pool is not None else [bank.groups]:
                jobs.append((i, bank, out, part))
        if pool is None:
            for i, bank, out, part in jobs:
                with self._checked(i):
                    bank.distances_into(query_p, out, part, verify=True)
        else:
            futures = [(i, pool.submit(bank.distances_into, query_p, out, part, True)) for i, bank, out, part in jobs]
            for i, future in futures:
                with self._checked(i):
                    future.result()
        parts = [out[self.live[i]] if len(self.live[i]) != len(out) else out for i, out in enumerate(outs)]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def distances(self, signature: Signature, metric: str, threads: int = RANK_THREADS) -> np.ndarray:
        """Distance of every live entry to ``signature`` by ``metric``, equal to
        :meth:`shapeidx.ranking.SignatureTable.distances` bit for bit."""
        from ..distance.bank import METRIC_HISTOGRAMS

        needed = METRIC_HISTOGRAMS[metric]
        pool = ThreadPoolExecutor(threads) if threads > 1 else None
        try:
            d = {h: self.histogram_distances(h, signature.histograms[h].p, pool) for h in needed}
        finally:
            if pool is not None:
                pool.shutdown()
        with self._checked(None):
            fractions, means = self.fractions, self.means
            angles = self.angles if metric in ANGLE_METRICS else None
        if angles is not None:
            require_angles(angles, signature, metric)
        features = features_to_many(signature, None, fractions, means, needed, distances=d, angles=angles)
        return metric_values(features, (metric,))[metric]

    # -- the nearest entries, with exact distances only where a lower bound cannot rule them out
    def nearest(self, signature: Signature, metric: str, top: int, first: int | None = None,
                exclude: int | None = None, max_distance: float | None = None):
        """Positions and exact distances of a set of live entries that holds every entry a
        ``top``-nearest answer can contain: the ``top`` nearest (not ``exclude``, within
        ``max_distance``), every entry tied with the last of them, and ``first``.

        Each entry's distance is bounded from below by that of its coarse histograms
        (``rank/H/coarse``: by the triangle inequality, summing bins never increases an L1
        distance, and the paper's metrics grow with every ``D``); exact distances are computed
        for the entries of smallest bound, more of them until the ``top``-th exact distance is
        below every other entry's bound. The distances are those of :meth:`distances`, bit
        for bit. Returns None for a metric this does not bound (``combined``).
        """
        from ..distance.bank import METRIC_HISTOGRAMS
        from ..distance.paper import PAPER_METRICS

        if metric not in PAPER_METRICS:
            return None
        if top <= 0 or len(self) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        needed = METRIC_HISTOGRAMS[metric]
        with self._checked(None):
            fractions, means = self.fractions, self.means
            bounds = {h: self._lower_bounds(h, signature.histograms[h].p) for h in needed}
        features = features_to_many(signature, None, fractions, means, needed, distances=bounds)
        # room for rounding: the bound and the distance are sums of different float terms
        bound = metric_values(features, (metric,))[metric] * (1 - 1e-9) - 1e-15
        if exclude is not None:
            bound[exclude] = np.inf
        n = len(bound)
        count = min(n, max(256, 16 * top))
        while True:
            chosen = np.argpartition(bound, count - 1)[:count] if count < n else np.arange(n)
            if first is not None and first != exclude and first not in chosen:
                chosen = np.append(chosen, first)
            exact = self.exact_distances(signature, metric, chosen)
            valid = exact[(chosen != exclude) & (exact <= (np.inf if max_distance is None else max_distance))]
            reach = np.partition(valid, top - 1)[top - 1] if len(valid) >= top else np.inf
            if max_distance is not None:
                reach = min(reach, max_distance)
            outside = np.partition(bound, count)[count] if count < n else np.inf
            if count == n or reach < outside:
                return chosen, exact
            count = min(n, 4 * count)

    def _lower_bounds(self, h: str, query_p: np.ndarray) -> np.ndarray:
        """A lower bound of ``D`` of histogram ``h`` from ``query_p`` to every live entry."""
        from ..distance.bank import _padded_l1

        query_p = np.asarray(query_p, dtype=np.float64)
        parts = []
        for i, section in enumerate(self.sections):
            c = section.coarse
            padded = np.zeros(-(-len(query_p) // c) * c)
            padded[: len(query_p)] = query_p
            query_coarse = padded.reshape(-1, c).sum(axis=1)
            out = np.zeros(len(section))
            row = 0
            order = section.array(f"{h}/order")
            for bins, block, totals in section.blocks(h, "coarse"):
                n = len(block)
                width = max(bins, len(query_p))
                if width:
                    coarse_width = max(block.shape[1], len(query_coarse))
                    out[order[row : row + n]] = _padded_l1(block, totals, query_coarse, coarse_width, True) / width
                row += n
            parts.append(out[self.live[i]] if len(self.live[i]) != len(out) else out)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def exact_distances(self, signature: Signature, metric: str, positions: np.ndarray) -> np.ndarray:
        """The distance (as :meth:`distances`, bit for bit) of the live entries at ``positions`` only."""
        from ..distance.bank import METRIC_HISTOGRAMS, _padded_l1

        needed = METRIC_HISTOGRAMS[metric]
        positions = np.asarray(positions, dtype=np.int64)
        file_of = np.searchsorted(self.starts, positions, side="right") - 1
        d = {h: np.zeros(len(positions)) for h in needed}
        fractions = np.zeros((len(positions), 3))
        means = np.zeros((len(positions), len(HISTOGRAMS)))
        for i in np.unique(file_of).tolist():
            mine = np.flatnonzero(file_of == i)
            section = self.sections[i]
            rank_positions = self.live[i][positions[mine] - self.starts[i]]
            with self._checked(i):
                fractions[mine] = section.array("fractions")[rank_positions]
                means[mine] = section.array("means")[rank_positions]
                for h in needed:
                    query_p = np.asarray(signature.histograms[h].p, dtype=np.float64)
                    starts, slot = section.slots(h)
                    k = slot[rank_positions]
                    group = np.searchsorted(starts, k, side="right") - 1
                    blocks = section.blocks(h)
                    for j in np.unique(group).tolist():
                        sel = np.flatnonzero(group == j)
                        bins, block, totals = blocks[j]
                        width = max(bins, len(query_p))
                        at = k[sel] - starts[j]
                        if width:
                            d[h][mine[sel]] = _padded_l1(block[at], totals[at], query_p, width, True) / width
        features = features_to_many(signature, None, fractions, means, needed, distances=d)
        return metric_values(features, (metric,))[metric]

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
        return Signature(points=params.points, seed=params.seed, histograms=histograms, angles=angles)


def _halves(groups: list, query_bins: int) -> list:
    """``groups`` in two parts of about equal work (rows times width), for two threads."""
    work = np.array([len(rows) * max(bins, query_bins) for bins, rows, _, _ in groups], dtype=np.float64)
    if len(groups) < 2:
        return [groups]
    cut = int(np.searchsorted(np.cumsum(work), work.sum() / 2)) + 1
    cut = min(max(cut, 1), len(groups) - 1)
    return [groups[:cut], groups[cut:]]
