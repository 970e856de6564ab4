"""Distances in words, calibrated on the store they come from.

A distance by itself says little (Weighted distances of kicad6 parts are around 0.002 to
0.02; the paper's own numbers are on another scale). What a user can judge is how a hit
compares with the other pairs of parts in the same store, so the words come from the
distribution of the distances between entries of that store:

* up to 32 entries, drawn with a fixed seed, are each ranked against every entry (itself
  left out); at 100,000 entries, 20 draws (two million pairs) are enough for the quantiles;
  the sample is kept in the store's thumbnail folder (``STORE.thumbs/``), keyed by the
  store file's size and time, so it is drawn once per build, not once per sheet;
* a hit's **share** is the fraction of those pairs that are at most as far apart as the hit;
* the words follow the share (:data:`WORDS`): "very similar" means closer than 99% of the
  pairs in the store, and so on. An exact 0 is "identical signature".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..signing.histogram import Histogram, Signature
from ..signing.parameters import HISTOGRAMS

#: (largest share of the store's pairs, words), checked in order.
WORDS = (
    (0.001, "nearly identical"),
    (0.01, "very similar"),
    (0.05, "similar"),
    (0.20, "somewhat similar"),
    (0.50, "weakly similar"),
    (1.01, "not similar"),
)
#: Pairs the calibration aims at, and its bounds on the number of sampled entries.
TARGET_PAIRS = 2_000_000
MIN_DRAWS, MAX_DRAWS = 8, 32
#: Distances kept for the quantiles (a sorted subsample when there are more).
KEPT = 200_000


def signatures_of(reader, rows) -> list[Signature]:
    """Stored signatures of store rows ``rows``, reading each column once (not once per entry)."""
    rows = np.asarray(rows, dtype=np.int64)
    per_histogram = {}
    for name in HISTOGRAMS:
        flat, lengths = reader.counts(name, rows)
        offsets = np.concatenate([[0], np.cumsum(lengths)])
        means = reader.column(f"histograms/{name}/mean")[rows]
        widths = reader.column(f"histograms/{name}/bin_width")[rows]
        per_histogram[name] = (flat, offsets, means, widths)
    out = []
    for k in range(len(rows)):
        histograms = {}
        for name, (flat, offsets, means, widths) in per_histogram.items():
            counts = flat[offsets[k] : offsets[k + 1]].astype(np.int64)
            histograms[name] = Histogram(counts, float(means[k]), float(widths[k]))
        out.append(Signature(points=reader.params.points, seed=reader.params.seed, histograms=histograms))
    return out


@dataclass
class SimilarityScale:
    """The distribution of one metric's distances between a store's entries.

    Attributes
    ----------
    metric : str
    distances : (k,) float64
        Sorted sample of pairwise distances.
    pairs : int
        Pairs the sample was drawn from.
    draws : int
        Entries ranked against the whole store.
    """

    metric: str
    distances: np.ndarray
    pairs: int
    draws: int

    @classmethod
    def of_table(cls, reader, table, metric: str, seed: int = 0) -> "SimilarityScale":
        """Calibrate on a loaded :class:`~shapeidx.ranking.SignatureTable` of ``reader``."""
        n = len(table)
        if n < 2:
            return cls(metric, np.zeros(0), 0, 0)
        draws = int(np.clip(TARGET_PAIRS // n, MIN_DRAWS, MAX_DRAWS))
        draws = min(draws, n)
        picked = np.sort(np.random.default_rng(seed).choice(n, size=draws, replace=False))
        found = []
        for i, signature in zip(picked, signatures_of(reader, table.rows[picked])):
            d = table.distances(signature, metric)
            found.append(np.delete(d, i))
        distances = np.sort(np.concatenate(found))
        pairs = len(distances)
        if pairs > KEPT:  # evenly spaced order statistics keep the quantiles
            distances = distances[np.linspace(0, pairs - 1, KEPT).astype(np.int64)]
        return cls(metric, distances, pairs, draws)

    @classmethod
    def cached(cls, reader, table, metric: str, folder) -> "SimilarityScale":
        """:meth:`of_table`, kept in ``folder`` for the same store file and metric."""
        import os
        import tempfile
        from pathlib import Path

        folder = Path(folder)
        try:
            stat = os.stat(reader.path)
            key = f"{stat.st_size}-{stat.st_mtime_ns}-{reader.journal}-{len(table)}"
        except OSError:
            return cls.of_table(reader, table, metric)
        target = folder / f"calibration-{metric}-d{MAX_DRAWS}-{key}.npz"
        try:
            with np.load(target) as data:
                return cls(metric, data["distances"], int(data["pairs"]), int(data["draws"]))
        except (OSError, KeyError, ValueError):
            pass
        scale = cls.of_table(reader, table, metric)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for old in folder.glob(f"calibration-{metric}-*.npz"):  # of an older build
                old.unlink(missing_ok=True)
            fd, temporary = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=folder)
            with os.fdopen(fd, "wb") as f:
                np.savez(f, distances=scale.distances, pairs=scale.pairs, draws=scale.draws)
            os.replace(temporary, target)
        except OSError:
            pass  # a cache that cannot be written only costs time
        return scale

    def share(self, distance: float) -> float | None:
        """Fraction of the store's pairs at most ``distance`` apart (None without calibration)."""
        if len(self.distances) == 0:
            return None
        return float(np.searchsorted(self.distances, distance, side="right")) / len(self.distances)

    def words(self, distance: float) -> str:
        """The similarity in words, e.g. ``"very similar"``."""
        if distance <= 0:
            return "identical signature"
        share = self.share(distance)
        if share is None:
            return ""
        return next(words for limit, words in WORDS if share <= limit)

    def explain(self, distance: float) -> str:
        """Words and the share behind them: ``"similar: closer than 97.2% of the store's pairs"``."""
        share = self.share(distance)
        if share is None:
            return ""
        if distance <= 0:
            return "identical signature"
        return f"{self.words(distance)}: closer than {100 * (1 - share):.1f}% of the store's pairs"

    def describe(self) -> str:
        """One sentence on how the words were calibrated."""
        if not self.pairs:
            return "No calibration: the store has fewer than two entries."
        q = {p: np.quantile(self.distances, p) for p in (0.01, 0.05, 0.5)}
        return (
            f"Words calibrated on {self.pairs:,} {self.metric} distances between {self.draws} entries drawn at random"
            f" and every other entry of the store: 1% of pairs are closer than {q[0.01]:.3g}, 5% closer than"
            f" {q[0.05]:.3g}, half closer than {q[0.5]:.3g}. " + "; ".join(
                f"{w}: closer than {100 * (1 - limit):.1f}% of pairs" if limit < 1 else f"{w}: the rest"
                for limit, w in WORDS
            ) + "."
        )
