"""One query against a whole store: the distances to every entry in one vectorised pass.

:class:`HistogramBank` holds many histograms of differing bin counts; :func:`distances_to_many`
gives, for every entry, the same value :func:`~shapeidx.distance.compare` gives for that pair,
bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..ragged import offsets_of
from ..signing.histogram import Signature
from ..signing.parameters import HISTOGRAMS
from ..signing.angles import angle_probabilities
from .combined import angle_features, class_scales, metric_values, signature_means, size_features
from .metrics import ANGLE_METRICS, PAPER_METRICS, REGISTRY, SIZE_METRICS


#: Histograms each metric reads (its registry record's): ranking skips the others.
METRIC_HISTOGRAMS = {name: m.histograms for name, m in REGISTRY.items()}
#: Values per working block of :meth:`HistogramBank.distances`: small enough to stay in the
#: CPU cache, so each stored probability is read from memory once per query.
BLOCK_VALUES = 1 << 15


class HistogramBank:
    """Many probability histograms of differing bin counts, ready for one-to-many ``D``.

    Rows are grouped by bin count, each group a dense ``(rows, bins)`` array of the stored
    counts (uint32: half the memory of probabilities, and no pass to compute them at load)
    with each row's total. A query costs a few numpy operations per *distinct* bin count
    (hundreds at most), never a Python loop per row, and no row is padded to the widest
    histogram of the bank (a single freak histogram of 10,000 bins would otherwise make every
    row that wide).

    :meth:`distances` gives, bit for bit, what :func:`histogram_distance` gives for each
    pair: probabilities are ``count / total`` in float64 as :attr:`Histogram.p` computes
    them, and it sums the same values in the same order (numpy sums each row of a
    C-contiguous block exactly as it sums that row alone), so :func:`compare` and a store
    ranking agree.
    """

    def __init__(self, size: int, groups: list):
        self.size = size
        #: ``(bins, rows, counts, totals)`` per distinct bin count: rows index the bank.
        self.groups = groups

    def __len__(self) -> int:
        return self.size

    @classmethod
    def from_counts(cls, counts: np.ndarray, lengths: np.ndarray) -> "HistogramBank":
        """Build from histograms laid end to end: row ``i`` is the next ``lengths[i]`` counts."""
        lengths = np.asarray(lengths, dtype=np.int64)
        offsets = offsets_of(lengths)
        totals = np.zeros(len(lengths), dtype=np.int64)
        filled = lengths > 0
        if filled.any():  # empty rows between filled ones add nothing to a filled row's sum
            totals[filled] = np.add.reduceat(counts, offsets[:-1][filled], dtype=np.int64)
        order = np.argsort(lengths, kind="stable")
        sorted_lengths = lengths[order]
        starts = np.concatenate([[0], np.flatnonzero(np.diff(sorted_lengths)) + 1, [len(order)]])
        # every window of consecutive counts, as a view: taking rows of it copies each
        # histogram as one contiguous run (several times faster than an index per value)
        windows = {}
        groups = []
        for lo, hi in zip(starts[:-1], starts[1:]):
            if lo < hi:
                rows = order[lo:hi]
                bins = int(sorted_lengths[lo])
                if bins == 0:
                    block = np.zeros((len(rows), 0), dtype=counts.dtype)
                else:
                    window = windows.setdefault(bins, np.lib.stride_tricks.sliding_window_view(counts, bins))
                    block = window[offsets[rows]]
                groups.append((bins, rows, block, np.maximum(totals[rows], 1)))
        return cls(len(lengths), groups)

    def distances(self, query_p: np.ndarray) -> np.ndarray:
        """``D(query, row)`` for every row (see :func:`histogram_distance`).

        Parameters
        ----------
        query_p : (nq,) float
            The query's probabilities.

        Returns
        -------
        (len(self),) float64
        """
        out = np.zeros(self.size)
        self.distances_into(query_p, out, self.groups)
        return out

    def distances_into(self, query_p: np.ndarray, out: np.ndarray, groups, verify: bool = False) -> None:
        """:meth:`distances` of the rows of ``groups`` (some of :attr:`groups`) into ``out``:
        disjoint groups can be ranked by several threads (numpy releases the GIL).

        ``verify``: also check, block by block while it is in the cache, that each row's
        counts add up to its total (raises ValueError otherwise): counts mapped from a file
        without a filter checksum cannot change a bit unnoticed.
        """
        query_p = np.asarray(query_p, dtype=np.float64)
        for bins, rows, counts, totals in groups:
            width = max(bins, len(query_p))
            if width:
                out[rows] = padded_l1(counts, totals, query_p, width, verify) / width
            elif verify and np.any(totals != 1):
                raise ValueError("histogram counts disagree with their totals")


def padded_l1(counts: np.ndarray, totals: np.ndarray, query_p: np.ndarray, width: int, verify: bool = False) -> np.ndarray:
    """Row sums of ``|counts / total - query|`` over ``width`` bins, both zero-padded, in
    blocks small enough to stay in the CPU cache (``verify``: see :meth:`HistogramBank.distances_into`)."""
    bins = counts.shape[1]
    query = np.zeros(width)
    query[: len(query_p)] = query_p
    step = max(1, BLOCK_VALUES // width)
    work = np.empty((min(step, len(counts)), width))
    work[:, bins:] = query[bins:]  # bins only the query has: |0 - q| = q, left as they are
    sums = np.empty(len(counts))
    for start in range(0, len(counts), step):
        part = slice(start, start + step)
        n = len(counts[part])
        if verify and not np.array_equal(np.maximum(counts[part].sum(axis=1, dtype=np.int64), 1), totals[part]):
            raise ValueError("histogram counts disagree with their totals")
        diff = work[:n, :bins]
        np.divide(counts[part], totals[part, None], out=diff)  # the probabilities, as Histogram.p
        np.subtract(diff, query[:bins], out=diff)
        np.abs(diff, out=diff)
        sums[start : start + n] = work[:n].sum(axis=1)
    return sums


def features_to_many(query: Signature, banks: dict, fractions: np.ndarray, means: np.ndarray | None = None, histograms=HISTOGRAMS,
                     distances: dict | None = None, angles: np.ndarray | None = None, radii: np.ndarray | None = None) -> dict:
    """The per-pair features (:data:`FEATURES`) from one signature to every row of a table.

    Parameters
    ----------
    query : Signature
    banks : dict
        Histogram name -> :class:`HistogramBank`, all of the same rows; those in
        ``histograms`` must be present (the ``D`` of the others are left at 0).
    fractions : (N, 3) float64
        Each row's IN, OUT and MIXED fractions, in that order.
    means : (N, 4) float64, optional
        Each row's histogram means in :data:`HISTOGRAMS` order; without them the scale
        features are left out.
    distances : dict, optional
        Histogram name -> the ``D`` already computed for every row (then ``banks`` is not used).
    angles : (N, 4, ANGLE_BINS) float64, optional
        Each row's normal-angle probabilities (:func:`angle_probabilities`); with them and a
        query that has its own, the angle features are added (NaN for rows whose angles are
        unknown).
    radii : (N, 3) float64, optional
        Each row's principal radii (NaN: unknown); with them the size features
        (:data:`~shapeidx.distance.combined.SIZE_FEATURES`) are added (0 where a size is unknown).
    """
    if distances is not None:
        features = {f"d_{h}": distances[h] if h in histograms else 0.0 for h in HISTOGRAMS}
    else:
        features = {f"d_{h}": banks[h].distances(query.histograms[h].p) if h in histograms else 0.0 for h in HISTOGRAMS}
    query_fractions = query.fractions
    for i, c in enumerate(HISTOGRAMS[1:]):
        features[f"gap_{c}"] = np.abs(fractions[:, i] - query_fractions[c])
    if means is not None:
        scale_gap = np.abs(class_scales(means) - class_scales(signature_means(query)))
        for i, c in enumerate(HISTOGRAMS[1:]):
            features[f"scale_{c}"] = scale_gap[:, i]
    if angles is not None and query.angles is not None:
        features.update(angle_features(angle_probabilities(query.angles)[None], angles))
    if radii is not None:
        features.update(size_features(None if query.radii is None else query.radii[None], radii))
    return features


def distances_to_many(query: Signature, banks: dict, fractions: np.ndarray, means: np.ndarray | None = None, metrics=PAPER_METRICS,
                      angles: np.ndarray | None = None, radii: np.ndarray | None = None) -> dict:
    """Distances from one signature to every row of a table, vectorised.

    Parameters are those of :func:`features_to_many`; ``means`` is needed for ``combined``,
    ``angles`` (and the query's own) for ``combined-angle``, ``radii`` (and the query's own) for ``combined-size``.

    Returns
    -------
    dict
        Metric name -> (N,) float64, each equal to :func:`compare` for that pair.
    """
    needed = {h for m in metrics for h in METRIC_HISTOGRAMS[m]}
    features = features_to_many(query, banks, fractions, means, needed,
                                angles=angles if set(metrics) & set(ANGLE_METRICS) else None,
                                radii=radii if set(metrics) & set(SIZE_METRICS) else None)
    return metric_values(features, metrics)
