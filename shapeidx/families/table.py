"""The ok entries of a store laid out for all-pairs work: histograms as ragged probability
rows, the class fractions and means, and the size and handedness columns.

:class:`~shapeidx.ranking.SignatureTable` answers "one part against every entry";
:class:`FamilyTable` answers "these pairs of entries", which is what classifying, clustering
and finding duplicates over a whole store need (a few neighbours per entry, never N x N).
:meth:`FamilyTable.pair_distances` gives for each pair what :func:`shapeidx.distance.compare`
gives for the two stored signatures (to rounding: sums run in another order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..distance import ANGLE_FEATURES, ANGLE_METRICS, FEATURES, METRIC_HISTOGRAMS, METRICS, SIZE_METRICS, metric_values
from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS, angle_probabilities
from ..distance.combined import ANGLE_KINDS, class_scales, size_features
from ..errors import StoreError
from ..ragged import offsets_of
from ..search.searcher import check_usable
from ..signing.parameters import HISTOGRAMS
from ..store import STATUS_OK, StoreReader
from ..store.layout import handedness_columns

#: Pair values handled per step of :meth:`FamilyTable.pair_distances` (bounds its memory).
PAIR_BLOCK_VALUES = 1 << 22
#: Most values of one histogram's dense copy (8 bytes each).
DENSE_VALUES = 1 << 27


@dataclass(eq=False)
class RaggedHistograms:
    """One histogram of every entry: probabilities end to end (``p[offsets[i]:offsets[i+1]]``)."""

    p: np.ndarray
    offsets: np.ndarray

    @property
    def lengths(self) -> np.ndarray:
        return np.diff(self.offsets)

    @classmethod
    def from_counts(cls, counts: np.ndarray, lengths: np.ndarray) -> "RaggedHistograms":
        offsets = offsets_of(np.asarray(lengths, dtype=np.int64))
        totals = np.zeros(len(lengths), dtype=np.float64)
        filled = lengths > 0
        if filled.any():
            totals[filled] = np.add.reduceat(counts, offsets[:-1][filled], dtype=np.int64)
        p = counts.astype(np.float64) / np.repeat(np.maximum(totals, 1), lengths)
        return cls(p, offsets)

    def dense(self) -> tuple[np.ndarray, int]:
        """The rows as a zero-padded (N, W) array, W the 99th percentile of the lengths (cached).

        Rows longer than W are left to the ragged road of :meth:`distances`.
        """
        if getattr(self, "_dense", None) is None:
            lengths = self.lengths
            n = len(lengths)
            width = int(np.quantile(lengths, 0.99)) if n else 0
            width = max(1, min(width, DENSE_VALUES // max(n, 1)))
            dense = np.zeros((n, width))
            short = lengths <= width
            rows = np.repeat(np.flatnonzero(short), lengths[short])
            starts = np.repeat(self.offsets[:-1][short], lengths[short])
            k = np.arange(len(rows)) - np.repeat(offsets_of(lengths[short])[:-1], lengths[short])
            dense[rows, k] = self.p[starts + k]
            self._dense = (dense, width)
        return self._dense

    def distances(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The paper's ``D`` (zero-padded L1 / bins) between rows ``a[k]`` and ``b[k]``."""
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        lengths = self.lengths
        dense, width = self.dense()
        bins = np.maximum(lengths[a], lengths[b])
        fits = bins <= width
        out = np.zeros(len(a))
        step = max(1, PAIR_BLOCK_VALUES // width)
        where = np.flatnonzero(fits & (bins > 0))
        for start in range(0, len(where), step):
            part = where[start : start + step]
            out[part] = np.abs(dense[a[part]] - dense[b[part]]).sum(axis=1) / bins[part]
        long = np.flatnonzero(~fits)
        if len(long):
            out[long] = self._ragged_distances(a[long], b[long])
        return out

    def _ragged_distances(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        lengths = self.lengths
        la, lb = lengths[a], lengths[b]
        width = np.maximum(la, lb)
        out = np.zeros(len(a))
        start = 0
        cumulative = np.cumsum(width)
        while start < len(a):
            base = cumulative[start - 1] if start else 0
            stop = max(start + 1, int(np.searchsorted(cumulative, base + PAIR_BLOCK_VALUES, side="right")))
            out[start:stop] = self._block(a[start:stop], b[start:stop], la[start:stop], lb[start:stop], width[start:stop])
            start = stop
        return out

    def _block(self, a, b, la, lb, width) -> np.ndarray:
        total = int(width.sum())
        if total == 0:
            return np.zeros(len(a))
        pair_offsets = offsets_of(width)
        k = np.arange(total) - np.repeat(pair_offsets[:-1], width)  # bin index within each pair
        va = _padded_values(self.p, self.offsets[a], la, k, width)
        vb = _padded_values(self.p, self.offsets[b], lb, k, width)
        sums = np.add.reduceat(np.abs(va - vb), pair_offsets[:-1][width > 0]) if total else np.zeros(0)
        out = np.zeros(len(a))
        out[width > 0] = sums / width[width > 0]
        return out


def _take_ragged(ragged: RaggedHistograms, rows: np.ndarray) -> RaggedHistograms:
    """Rows ``rows`` of a ragged table, as one."""
    lengths = ragged.lengths[rows]
    starts = np.repeat(ragged.offsets[:-1][rows] - offsets_of(lengths)[:-1], lengths)
    return RaggedHistograms(ragged.p[starts + np.arange(int(lengths.sum()))], offsets_of(lengths))


def _padded_values(p, starts, lengths, k, width) -> np.ndarray:
    starts_r = np.repeat(starts, width)
    inside = k < np.repeat(lengths, width)
    values = np.zeros(len(k))
    values[inside] = p[starts_r[inside] + k[inside]]
    return values


@dataclass
class FamilyTable:
    """The ok entries of a store, for pair work (see the module docstring).

    Attributes
    ----------
    paths : (N,) object
    rows : (N,) int64
        Position of each entry in the store reader.
    histograms : dict
        Name -> :class:`RaggedHistograms` (those loaded).
    fractions : (N, 3) float64
    means : (N, 4) float64
        Mean pair distance per histogram, in file units (``means[:, 0]``: the part's size).
    hashes : (N,) bytes
    extents : (N, 3) float64
        Principal radii, NaN for entries of a store that predates them.
    handedness : (N, 3) float64
        The pseudo-scalars h1, h2, h3 (shapeidx.signing.moments), NaN where undefined or unknown.
    bounds : (N, 6) float64
        Bounding box in file units: min x, y, z, max x, y, z.
    moments : (N, 4) float64
        Area / sum of squared principal radii, and |skewness| along each principal axis.
    missing_columns : list of str
        Columns the store's files lack (read as NaN).
    """

    paths: np.ndarray
    rows: np.ndarray
    histograms: dict
    fractions: np.ndarray
    means: np.ndarray
    hashes: np.ndarray
    extents: np.ndarray
    handedness: np.ndarray
    missing_columns: list
    bounds: np.ndarray | None = None
    moments: np.ndarray | None = None
    angles: np.ndarray | None = None  # (N, 4, ANGLE_BINS) normal-angle probabilities, NaN where unknown
    #: Histogram -> (N, 48) float32 rows of the candidate embedding the store keeps
    #: (:func:`shapeidx.store.candidates.stored_d2_basis`), for the histograms it was asked for.
    d2_basis: dict | None = None

    @classmethod
    def load(cls, reader: StoreReader, histograms=HISTOGRAMS, embedding=None) -> "FamilyTable":
        """The ok entries of ``reader``; refuses a store of another signature version.

        ``histograms``: the D2 histograms to load (a metric's, ``METRIC_HISTOGRAMS``; combined-angle
        needs none); ``embedding``: the histograms whose stored embedding rows to load
        (default: the same)."""
        check_usable(reader)
        rows = np.flatnonzero(reader.column("entries/status") == STATUS_OK)
        hists = {name: RaggedHistograms.from_counts(*reader.counts(name, rows)) for name in histograms}
        means = np.stack([reader.column(f"histograms/{name}/mean")[rows] for name in HISTOGRAMS], axis=1)
        from ..store.candidates import stored_d2_basis

        basis = stored_d2_basis(reader, rows, histograms if embedding is None else embedding)
        return cls(
            d2_basis=basis or None,
            paths=reader.paths[rows],
            rows=rows,
            histograms=hists,
            fractions=reader.column("entries/fractions")[rows],
            means=means,
            hashes=reader.column("entries/hash")[rows],
            extents=reader.column("entries/extents")[rows],
            handedness=handedness_columns(reader.column)[rows],
            missing_columns=reader.missing_columns,
            bounds=reader.column("entries/bounds")[rows],
            moments=reader.column("entries/moments")[rows],
            angles=angle_probabilities(reader.column("entries/angles")[rows].reshape(len(rows), len(ANGLE_HISTOGRAMS), ANGLE_BINS)),
        )

    @classmethod
    def load_store(cls, store, histograms=HISTOGRAMS, parts: bool = False) -> "FamilyTable":
        """The ok entries of the store at ``store``: an ordinary store (:meth:`load`), or every
        shard of a sharded one (``build --shards``) joined into one table sorted by path, as
        one store holding them all would give (``rows``: each entry's row in its own shard);
        ``parts``: the sub-entries (``build --parts``) instead."""
        from ..store import open_store
        from ..store.reader import member_stores

        tables = []
        for path in member_stores(store, parts):
            with open_store(path) as reader:
                tables.append(cls.load(reader, histograms))
        return tables[0] if len(tables) == 1 else cls.joined(tables)

    @classmethod
    def joined(cls, tables: list) -> "FamilyTable":
        """One table of the entries of ``tables`` (of stores with no path in common), sorted by path."""
        paths = np.concatenate([t.paths for t in tables])
        order = np.argsort(paths.astype(str), kind="stable")

        def join(values):
            return None if any(v is None for v in values) else np.concatenate(values)[order]

        histograms = {}
        for h in tables[0].histograms:
            ragged = [t.histograms[h] for t in tables]
            everything = RaggedHistograms(np.concatenate([r.p for r in ragged]),
                                          offsets_of(np.concatenate([r.lengths for r in ragged])))
            histograms[h] = _take_ragged(everything, order)
        basis = None
        if all(t.d2_basis for t in tables):
            basis = {h: np.concatenate([t.d2_basis[h] for t in tables])[order] for h in tables[0].d2_basis}
        return cls(
            paths=paths[order], rows=join([t.rows for t in tables]), histograms=histograms,
            fractions=join([t.fractions for t in tables]), means=join([t.means for t in tables]),
            hashes=join([t.hashes for t in tables]), extents=join([t.extents for t in tables]),
            handedness=join([t.handedness for t in tables]),
            missing_columns=sorted({c for t in tables for c in t.missing_columns}),
            bounds=join([t.bounds for t in tables]), moments=join([t.moments for t in tables]),
            angles=join([t.angles for t in tables]), d2_basis=basis,
        )

    def __len__(self) -> int:
        return len(self.paths)

    def subset(self, keep) -> "FamilyTable":
        """The entries ``keep`` selects (a boolean mask over the entries, or their indices), as a
        table of their own: what a ``--where`` filter's keep-mask makes of the store."""
        keep = np.asarray(keep)
        rows = np.flatnonzero(keep) if keep.dtype == bool else np.asarray(keep, dtype=np.int64)
        if keep.dtype == bool and len(keep) != len(self):
            raise ValueError(f"keep-mask of {len(keep)} values for a table of {len(self)} entries")

        def take(values):
            return None if values is None else values[rows]

        return FamilyTable(
            paths=self.paths[rows], rows=self.rows[rows],
            histograms={h: _take_ragged(r, rows) for h, r in self.histograms.items()},
            fractions=self.fractions[rows], means=self.means[rows], hashes=self.hashes[rows],
            extents=self.extents[rows], handedness=self.handedness[rows], missing_columns=self.missing_columns,
            bounds=take(self.bounds), moments=take(self.moments), angles=take(self.angles),
            d2_basis=None if self.d2_basis is None else {h: v[rows] for h, v in self.d2_basis.items()},
        )

    def with_signatures(self, rows, signatures) -> "FamilyTable":
        """This table with entries ``rows`` signed again: their D2 histograms, class fractions,
        means and normal-angle histograms taken from ``signatures`` (one
        :class:`~shapeidx.signing.histogram.Signature` per row, e.g. its points drawn with
        another seed), every exact column (hash, moments, extents, handedness, bounds) kept.
        For studies of the sampling: a copy of a part whose points land elsewhere than its
        original's, as a re-export's would. The stored embedding (``d2_basis``) is dropped, so
        the candidates come from the new histograms."""
        rows = np.asarray(rows, dtype=np.int64)
        signatures = list(signatures)
        if len(rows) != len(signatures):
            raise ValueError(f"{len(rows)} rows for {len(signatures)} signatures")
        new = dict(zip(rows.tolist(), signatures))
        histograms = {}
        for name, ragged in self.histograms.items():
            pieces = []
            for i in range(len(self)):
                if i in new:
                    counts = np.asarray(new[i].histograms[name].counts, dtype=np.float64)
                    pieces.append(counts / max(counts.sum(), 1.0))
                else:
                    pieces.append(ragged.p[ragged.offsets[i]:ragged.offsets[i + 1]])
            lengths = np.array([len(x) for x in pieces], dtype=np.int64)
            histograms[name] = RaggedHistograms(np.concatenate(pieces) if pieces else np.zeros(0), offsets_of(lengths))
        fractions, means = self.fractions.copy(), self.means.copy()
        angles = None if self.angles is None else self.angles.copy()
        for i, signature in new.items():
            shares = signature.fractions
            fractions[i] = [shares[c] for c in HISTOGRAMS[1:]]
            means[i] = [signature.histograms[h].mean for h in HISTOGRAMS]
            if angles is not None:
                angles[i] = np.nan if signature.angles is None else angle_probabilities(
                    np.asarray(signature.angles, dtype=np.float64).reshape(len(ANGLE_HISTOGRAMS), ANGLE_BINS))
        return FamilyTable(
            paths=self.paths, rows=self.rows, histograms=histograms, fractions=fractions, means=means,
            hashes=self.hashes, extents=self.extents, handedness=self.handedness, missing_columns=self.missing_columns,
            bounds=self.bounds, moments=self.moments, angles=angles, d2_basis=None,
        )

    def index_of(self, path: str) -> int | None:
        """Position of the entry with this relative path, or None."""
        i = int(np.searchsorted(self.paths, path))
        return i if i < len(self.paths) and self.paths[i] == path else None

    @property
    def sizes(self) -> np.ndarray:
        """Each part's size in file units: its mean pair distance (ALL)."""
        return self.means[:, 0]

    def _cached(self, name: str, make):
        """A per-entry array derived once (the tables are not changed after loading)."""
        cache = self.__dict__.setdefault("_derived", {})
        if name not in cache:
            cache[name] = make()
        return cache[name]

    def pair_features(self, a: np.ndarray, b: np.ndarray, histograms=HISTOGRAMS, angles=("l1", "hellinger"),
                      sizes: bool = False) -> dict:
        """The per-pair :data:`~shapeidx.distance.FEATURES` of entries ``a[k]``, ``b[k]``, the
        normal-angle histograms' distances named in ``angles`` (L1, Hellinger), and with ``sizes``
        the exact sizes' gaps (:data:`~shapeidx.distance.SIZE_FEATURES`)."""
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        features = {f"d_{h}": self.histograms[h].distances(a, b) if h in histograms else np.zeros(len(a)) for h in HISTOGRAMS}
        for i, c in enumerate(HISTOGRAMS[1:]):
            features[f"gap_{c}"] = np.abs(self.fractions[a, i] - self.fractions[b, i])
        scales = self._cached("scales", lambda: class_scales(self.means))
        gap = np.abs(scales[a] - scales[b])
        for i, c in enumerate(HISTOGRAMS[1:]):
            features[f"scale_{c}"] = gap[:, i]
        if self.angles is not None and angles:  # NaN for entries whose angles are unknown
            # angle_features' L1 and Hellinger distances, from square roots taken once per entry
            count = len(ANGLE_HISTOGRAMS)
            if "l1" in angles:
                l1 = np.abs(self.angles[a] - self.angles[b]).sum(axis=-1)
                features.update({name: l1[:, i] for i, name in enumerate(ANGLE_FEATURES[:count])})
            if "hellinger" in angles:
                roots = self._cached("angle_roots", lambda: np.sqrt(self.angles))
                hellinger = np.sqrt(((roots[a] - roots[b]) ** 2).sum(axis=-1) / 2)
                features.update({name: hellinger[:, i] for i, name in enumerate(ANGLE_FEATURES[count:])})
        if sizes:
            features.update(size_features(self.extents[a], self.extents[b]))
        assert set(FEATURES) <= set(features)
        return features

    def pair_distances(self, a: np.ndarray, b: np.ndarray, metric: str) -> np.ndarray:
        """Distance by ``metric`` between entries ``a[k]`` and ``b[k]``, for every k."""
        if metric not in METRICS:
            raise ValueError(f"unknown metric {metric!r}; expected one of {', '.join(METRICS)}")
        missing = set(METRIC_HISTOGRAMS[metric]) - set(self.histograms)
        if missing:
            raise ValueError(f"metric {metric} needs histograms not loaded: {', '.join(sorted(missing))}")
        known = self._cached("angles_known", lambda: self.angles is not None and bool(np.isfinite(self.angles).all()))
        if metric in ANGLE_METRICS and not known:
            raise StoreError(f"metric {metric} needs the normal-angle histograms, which entries of this store lack"
                             " (built before them): rebuild it with 'shapeidx build DIR --full'")
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        angles = ANGLE_KINDS[metric]
        out = np.empty(len(a))
        step = PAIR_BLOCK_VALUES // 64  # bounds the (pairs, 4, bins) copies of the angle road
        for lo in range(0, len(a), step):
            features = self.pair_features(a[lo : lo + step], b[lo : lo + step], METRIC_HISTOGRAMS[metric], angles,
                                          metric in SIZE_METRICS)
            out[lo : lo + step] = metric_values(features, (metric,))[metric]
        return out

    @property
    def radii(self) -> np.ndarray:
        """Each part's radius of gyration of its surface, ``sqrt(r1^2 + r2^2 + r3^2)``, in file
        units: exact (no sampling noise), NaN where the store predates the column."""
        return np.sqrt((self.extents**2).sum(axis=1))

    def size_ratios(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """How much larger b is than a: the ratio of the radii of gyration (exact) where both
        are known, else of the mean pair distances (a sample: within a few % of the truth)."""
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        radii = self.radii
        with np.errstate(divide="ignore", invalid="ignore"):
            exact = radii[b] / radii[a]
            sampled = self.sizes[b] / self.sizes[a]
        return np.where(np.isfinite(exact), exact, sampled)
