"""The distances of Ip et al. (2002, section 3.2.5), one-to-one and one-to-many.

``D(h1, h2)`` is the L1 norm between two probability histograms after the shorter one is
padded with empty bins, divided by the number of bins. From it:

* **ALL** (plain D2): ``D(all_A, all_B)``;
* **AvgOf3**: the mean of ``D`` over IN, OUT and MIXED;
* **AvgOf4**: the mean of ``D`` over ALL, IN, OUT and MIXED;
* **Weighted**: ``sum over c in (IN, OUT, MIXED) of D(c_A, c_B) / (1 - |%c_A - %c_B|)``.

Edge cases, decided so that no distance is ever NaN or infinite:

* a class with no pairs has an empty histogram. Two empty histograms are at distance 0
  (the parts agree: neither has that class). An empty histogram against one with ``n`` bins
  is at ``1 / n``, which is exactly what zero padding gives (L1 = 1);
* the Weighted weight ``1 / (1 - Diff)`` tends to infinity as ``Diff`` tends to 1 (one part all
  in a class, the other not at all). ``1 - Diff`` is floored at :data:`MIN_AGREEMENT`, so a
  weight is at most 1000.

Beyond the paper, **combined** is a learned, non-negative weighted sum of ten per-pair
features (:data:`FEATURES`): the four ``D`` values, the three ``|%A - %B|`` and, per class,
how much the two parts differ in the ratio of that class's mean distance to the ALL mean
(``|ln(mA_c / mA_all) - ln(mB_c / mB_all)|``). The paper's per-histogram normalisation by its
own mean discards that scale information; the store keeps the means, so it costs nothing.
The weights come from ``shapeidx/combined_metric.json``, written by
``scripts/learn_metric.py`` (neighbourhood component analysis on a labelled collection,
with class-wise cross-validation figures recorded beside the weights).
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources

import numpy as np

from .signature import HISTOGRAMS, Signature

#: The distances Ip et al. (2002) define.
PAPER_METRICS = ("all", "avg3", "avg4", "weighted")
METRICS = PAPER_METRICS + ("combined",)
#: Floor of ``1 - Diff`` in the Weighted distance (weights are at most its inverse).
MIN_AGREEMENT = 1e-3
#: The per-pair quantities all metrics are made of, in the order of the combined weights.
FEATURES = tuple(f"d_{h}" for h in HISTOGRAMS) + tuple(f"gap_{c}" for c in HISTOGRAMS[1:]) + tuple(
    f"scale_{c}" for c in HISTOGRAMS[1:]
)
#: A class with no pairs counts, in the scale features, as a mean this share of the ALL mean.
EMPTY_CLASS_SCALE = 1e-3


def histogram_distance(p: np.ndarray, q: np.ndarray) -> float:
    """``D(p, q)``: L1 after zero-padding the shorter histogram, divided by the bin count."""
    n = max(len(p), len(q))
    if n == 0:
        return 0.0
    padded = np.zeros((2, n))
    padded[0, : len(p)] = p
    padded[1, : len(q)] = q
    return float(np.abs(padded[0] - padded[1]).sum() / n)


def combine(d: dict, fraction_gap: dict) -> dict:
    """The four distances from per-histogram ``D`` values and per-class ``|%A - %B|``.

    Works element-wise, so the values may be numbers or numpy arrays (one per store entry).
    """
    classes = HISTOGRAMS[1:]
    weighted = sum(d[c] / np.maximum(1.0 - fraction_gap[c], MIN_AGREEMENT) for c in classes)
    return {
        "all": d["all"],
        "avg3": sum(d[c] for c in classes) / 3.0,
        "avg4": sum(d[h] for h in HISTOGRAMS) / 4.0,
        "weighted": weighted,
    }


def class_scales(means: np.ndarray) -> np.ndarray:
    """``ln(class mean / ALL mean)`` for IN, OUT, MIXED from means in :data:`HISTOGRAMS` order.

    ``means`` is (4,) or (N, 4); a class with no pairs (mean 0) counts as
    :data:`EMPTY_CLASS_SCALE` of the ALL mean.
    """
    means = np.asarray(means, dtype=np.float64)
    overall = np.maximum(means[..., :1], np.finfo(float).tiny)
    return np.log(np.maximum(means[..., 1:], EMPTY_CLASS_SCALE * overall) / overall)


def signature_means(signature: Signature) -> np.ndarray:
    """The four histograms' mean distances, in :data:`HISTOGRAMS` order."""
    return np.array([signature.histograms[h].mean for h in HISTOGRAMS])


def metric_values(features: dict, metrics=METRICS) -> dict:
    """Metrics from per-pair features (numbers, or arrays with one value per pair)."""
    d = {h: features[f"d_{h}"] for h in HISTOGRAMS}
    gap = {c: features[f"gap_{c}"] for c in HISTOGRAMS[1:]}
    values = combine(d, gap)
    if "combined" in metrics:
        weights = combined_weights()["weights"]
        values["combined"] = sum(weights[name] * features[name] for name in FEATURES)
    return {m: values[m] for m in metrics}


@lru_cache(maxsize=1)
def combined_weights() -> dict:
    """The learned weights of the combined metric and how they were obtained."""
    data = json.loads(resources.files("shapeidx").joinpath("combined_metric.json").read_text())
    if set(data["weights"]) != set(FEATURES):
        raise ValueError("combined_metric.json does not match shapeidx.distance.FEATURES")
    return data


def features_between(a: Signature, b: Signature) -> dict:
    """The per-pair features (:data:`FEATURES`) of two signatures."""
    features = {f"d_{h}": histogram_distance(a.histograms[h].p, b.histograms[h].p) for h in HISTOGRAMS}
    fa, fb = a.fractions, b.fractions
    features.update({f"gap_{c}": abs(fa[c] - fb[c]) for c in HISTOGRAMS[1:]})
    scale_gap = np.abs(class_scales(signature_means(a)) - class_scales(signature_means(b)))
    features.update({f"scale_{c}": float(v) for c, v in zip(HISTOGRAMS[1:], scale_gap)})
    return features


def compare(a: Signature, b: Signature) -> dict:
    """Every metric between two signatures: ``{"all", "avg3", "avg4", "weighted", "combined"}``."""
    return {name: float(value) for name, value in metric_values(features_between(a, b)).items()}


def one_to_many(query_p: np.ndarray, table: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``D(query, row)`` for every row of a zero-padded table of histograms, vectorised.

    Parameters
    ----------
    query_p : (nq,) float
    table : (N, B) float
        Histograms padded with zeros to a common width B.
    lengths : (N,) int
        True bin count of each row.

    Returns
    -------
    (N,) float64
    """
    width = max(table.shape[1], len(query_p))
    q = np.zeros(width, dtype=table.dtype)
    q[: len(query_p)] = query_p
    l1 = np.abs(table - q[: table.shape[1]]).sum(axis=1, dtype=np.float64)
    if len(query_p) > table.shape[1]:
        l1 += q[table.shape[1] :].sum()
    n = np.maximum(lengths, len(query_p)).astype(np.float64)
    return np.divide(l1, n, out=np.zeros_like(l1), where=n > 0)


#: Histograms each metric reads: ranking skips the others (Weighted never needs ALL).
METRIC_HISTOGRAMS = {
    "all": ("all",),
    "avg3": HISTOGRAMS[1:],
    "avg4": HISTOGRAMS,
    "weighted": HISTOGRAMS[1:],
    "combined": HISTOGRAMS,
}
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
        offsets = np.zeros(len(lengths) + 1, dtype=np.int64)
        np.cumsum(lengths, out=offsets[1:])
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
        query_p = np.asarray(query_p, dtype=np.float64)
        out = np.zeros(self.size)
        for bins, rows, counts, totals in self.groups:
            width = max(bins, len(query_p))
            if width:
                out[rows] = _padded_l1(counts, totals, query_p, width) / width
        return out


def _padded_l1(counts: np.ndarray, totals: np.ndarray, query_p: np.ndarray, width: int) -> np.ndarray:
    """Row sums of ``|counts / total - query|`` over ``width`` bins, both zero-padded, in
    blocks small enough to stay in the CPU cache."""
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
        diff = work[:n, :bins]
        np.divide(counts[part], totals[part, None], out=diff)  # the probabilities, as Histogram.p
        np.subtract(diff, query[:bins], out=diff)
        np.abs(diff, out=diff)
        sums[start : start + n] = work[:n].sum(axis=1)
    return sums


def rank_features(query: Signature, banks: dict, fractions: np.ndarray, means: np.ndarray | None = None, histograms=HISTOGRAMS) -> dict:
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
    """
    features = {f"d_{h}": banks[h].distances(query.histograms[h].p) if h in histograms else 0.0 for h in HISTOGRAMS}
    query_fractions = query.fractions
    for i, c in enumerate(HISTOGRAMS[1:]):
        features[f"gap_{c}"] = np.abs(fractions[:, i] - query_fractions[c])
    if means is not None:
        scale_gap = np.abs(class_scales(means) - class_scales(signature_means(query)))
        for i, c in enumerate(HISTOGRAMS[1:]):
            features[f"scale_{c}"] = scale_gap[:, i]
    return features


def rank_distances(query: Signature, banks: dict, fractions: np.ndarray, means: np.ndarray | None = None, metrics=PAPER_METRICS) -> dict:
    """Distances from one signature to every row of a table, vectorised.

    Parameters are those of :func:`rank_features`; ``means`` is needed for ``combined``.

    Returns
    -------
    dict
        Metric name -> (N,) float64, each equal to :func:`compare` for that pair.
    """
    needed = {h for m in metrics for h in METRIC_HISTOGRAMS[m]}
    features = rank_features(query, banks, fractions, means, needed)
    return metric_values(features, metrics)
