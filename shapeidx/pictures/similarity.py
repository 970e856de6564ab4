"""Distances in words, calibrated on the store they come from.

A distance by itself says little (Weighted distances of kicad6 parts are around 0.002 to
0.02; the paper's own numbers are on another scale). What a user can judge is how a hit
compares with the other pairs of parts in the same store, so the words come from the
distribution of the distances between entries of that store:

* up to 32 entries, drawn with a fixed seed, are each ranked against every entry (itself
  left out); at 100,000 entries, 20 draws (two million pairs) are enough for the quantiles;
  the sample is kept in the store's thumbnail folder (``STORE/thumbs/``), keyed by the
  store files' sizes and times, so it is drawn once per build, not once per sheet;
* a hit's **share** is the fraction of those pairs that are at most as far apart as the hit;
* the words follow the share (:data:`WORDS`): "very similar" means closer than 99% of the
  pairs in the store, and so on. An exact 0 is "identical signature".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
    #: Where the pairs were drawn: the store, or one shard of a sharded store.
    within: str = "the store"

    @classmethod
    def of_store(cls, searcher, metric: str, seed: int = 0) -> "SimilarityScale":
        """Calibrate on the entries of an open :class:`~shapeidx.search.Searcher`."""
        from ..search.distances import distances as distances_to

        n = len(searcher)
        if n < 2:
            return cls(metric, np.zeros(0), 0, 0)
        draws = int(np.clip(TARGET_PAIRS // n, MIN_DRAWS, MAX_DRAWS))
        draws = min(draws, n)
        picked = np.sort(np.random.default_rng(seed).choice(n, size=draws, replace=False))
        found = []
        for i in picked.tolist():
            d = distances_to(searcher.view, searcher.signature_at(i), metric)
            found.append(np.delete(d, i))
        distances = np.sort(np.concatenate(found))
        pairs = len(distances)
        if pairs > KEPT:  # evenly spaced order statistics keep the quantiles
            distances = distances[np.linspace(0, pairs - 1, KEPT).astype(np.int64)]
        return cls(metric, distances, pairs, draws)

    @classmethod
    def cached(cls, searcher, metric: str, folder) -> "SimilarityScale":
        """:meth:`of_store`, kept in ``folder`` for the same store files and metric."""
        import os
        import tempfile
        from pathlib import Path

        folder = Path(folder)
        try:
            stats = [os.stat(source.path) for source in searcher.reader._sources]
            key = f"{stats[0].st_size}-{stats[0].st_mtime_ns}-{sum(s.st_mtime_ns for s in stats) % 10**12}-{len(searcher)}"
        except OSError:
            return cls.of_store(searcher, metric)
        target = folder / f"calibration-{metric}-d{MAX_DRAWS}-{key}.npz"
        try:
            from ..io.base import open_regular

            with open_regular(target) as f, np.load(f) as data:  # a FIFO in the cache is a miss, never a hang
                return cls(metric, data["distances"], int(data["pairs"]), int(data["draws"]))
        except (OSError, KeyError, ValueError, EOFError):
            pass
        scale = cls.of_store(searcher, metric)
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
        return f"{self.words(distance)}: {closer_than(share)}"

    def describe(self) -> str:
        """One sentence on how the words were calibrated."""
        if not self.pairs:
            return "No calibration: the store has fewer than two entries."
        q = {p: np.quantile(self.distances, p) for p in (0.01, 0.05, 0.5)}
        return (
            f"Words calibrated on {self.pairs:,} {self.metric} distances between {self.draws} entries drawn at random"
            f" and every other entry of {self.within}: 1% of pairs are closer than {q[0.01]:.3g}, 5% closer than"
            f" {q[0.05]:.3g}, half closer than {q[0.5]:.3g}. " + "; ".join(
                f"{w}: closer than {100 * (1 - limit):.1f}% of pairs" if limit < 1 else f"{w}: the rest"
                for limit, w in WORDS
            ) + "."
        )


def closer_than(share: float) -> str:
    """``"closer than 97.2% of the store's pairs"``; never "100.0%": the share is measured on a
    sample of the store's pairs, so a hit closer than every pair sampled is "among the store's
    closest pairs", and one rounded up to 100.0 reads "99.9%"."""
    if share <= 0:
        return "among the store's closest pairs (closer than every pair sampled)"
    text = f"{100 * (1 - share):.1f}"
    if text == "100.0":
        text = "99.9"
    return f"closer than {text}% of the store's pairs"


def shard_scale(path: str, metric: str, shard: int, shards: int) -> SimilarityScale:
    """The scale of a sharded store, calibrated on one of its shards (run where the shard is,
    kept in the shard's own thumbnail folder). Shards hold the entries of their path keys, a
    uniform draw of the store, so the pairs of one shard are distributed as the store's are."""
    from ..search.sharded import held_searcher
    from .thumbcache import cache_dir_of_store

    scale = SimilarityScale.cached(held_searcher(path), metric, cache_dir_of_store(path))
    scale.within = f"shard {shard} of the {shards} (a uniform draw of the store's entries by path key)"
    return scale
