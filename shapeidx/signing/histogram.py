"""The Signature value: four D2 histograms and the class fractions (Ip et al. 2002, 3.2.4)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .occlusion import compiled_pairs
from .parameters import BIN_DIVISOR, CLASS_NAMES


@dataclass(frozen=True)
class Histogram:
    """A D2 histogram whose bins are ``mean / BIN_DIVISOR`` wide, starting at distance 0.

    Attributes
    ----------
    counts : (bins,) int64
        Pairs per bin. Empty when the set has no pairs (a class absent from the part).
    mean : float
        Mean distance of the set (0 when empty), in the part's units.
    bin_width : float
        ``mean / BIN_DIVISOR`` (0 when empty).
    """

    counts: np.ndarray
    mean: float
    bin_width: float

    @classmethod
    def of(cls, distances: np.ndarray, divisor: int = BIN_DIVISOR) -> "Histogram":
        """Histogram of a set of distances, bin width its mean over ``divisor``."""
        if len(distances) == 0:
            return cls(np.zeros(0, dtype=np.int64), 0.0, 0.0)
        mean = float(distances.mean())
        if mean <= 0:  # every pair at distance 0: one bin holds them all
            return cls(np.array([len(distances)], dtype=np.int64), 0.0, 0.0)
        width = mean / divisor
        return cls(np.bincount((distances / width).astype(np.int64)), mean, width)

    @property
    def total(self) -> int:
        return int(self.counts.sum())

    @property
    def p(self) -> np.ndarray:
        """Probabilities per bin, summing to 1 (empty for an empty histogram)."""
        total = self.total
        return self.counts / total if total else np.zeros(0)


@dataclass(frozen=True)
class Signature:
    """A part's enhanced D2 signature.

    Attributes
    ----------
    points : int
        Surface samples used (pairs = points * (points - 1) / 2).
    seed : int
        Seed of the sampling.
    histograms : dict
        ``"all"``, ``"in"``, ``"out"``, ``"mixed"`` -> :class:`Histogram`.
    angles : (4, ANGLE_BINS) int64 or None
        Pair counts of the normal-angle histograms (:mod:`shapeidx.signing.angles`), rows in
        ``ANGLE_HISTOGRAMS`` order; None where unknown (an entry of a store built before them).
    radii : (3,) float64 or None
        The principal radii of the surface, largest first, integrated exactly from the surface
        (:func:`shapeidx.signing.moments.shape_facts`: no sampling noise, in file units; the
        store's ``entries/extents``), read by the size-aware metric; None where unknown.
    """

    points: int
    seed: int
    histograms: dict
    angles: np.ndarray | None = field(default=None, compare=False, repr=False)
    radii: np.ndarray | None = field(default=None, compare=False, repr=False)

    @classmethod
    def from_pairs(cls, distances: np.ndarray, classes: np.ndarray, points: int, seed: int, divisor: int = BIN_DIVISOR,
                   angles: np.ndarray | None = None, radii: np.ndarray | None = None):
        """Build the four histograms from classified pair distances.

        The three class histograms come from one pass: each pair's bin in its own class's
        scale, offset by class, counted by a single ``bincount``.
        """
        native = compiled_pairs()
        mean_all = float(distances.mean()) if len(distances) else 0.0  # numpy's pairwise sum, as Histogram.of's
        if native is not None and mean_all > 0:
            histograms = _histograms_compiled(native, distances, classes, mean_all, divisor)
            return cls(points=points, seed=seed, histograms=histograms, angles=angles, radii=radii)
        histograms = {"all": Histogram.of(distances, divisor)}
        n_classes = len(CLASS_NAMES)
        codes = classes.astype(np.intp)  # once: bincount and take would each convert uint8 again
        sizes = np.bincount(codes, minlength=n_classes)
        means = np.bincount(codes, weights=distances, minlength=n_classes) / np.maximum(sizes, 1)
        widths = means / divisor
        key = (distances / np.take(np.where(widths > 0, widths, 1.0), codes)).astype(np.int64)
        stride = int(key.max()) + 1 if len(key) else 1
        codes *= stride
        key += codes  # each pair's bin, offset by its class
        table = np.bincount(key, minlength=n_classes * stride).reshape(n_classes, stride)
        histograms.update(_class_histograms(table, means, widths))
        return cls(points=points, seed=seed, histograms=histograms, angles=angles, radii=radii)

    @property
    def fractions(self) -> dict:
        """Share of the pairs in each class: ``{"in": ..., "out": ..., "mixed": ...}``, summing to 1."""
        total = self.histograms["all"].total
        return {name: self.histograms[name].total / total for name in CLASS_NAMES}

    def to_dict(self) -> dict:
        """Plain JSON-ready form (probabilities, not counts)."""
        return {
            "points": self.points,
            "seed": self.seed,
            "pairs": self.histograms["all"].total,
            "fractions": self.fractions,
            "radii": None if self.radii is None else self.radii.tolist(),
            "histograms": {
                name: {"bin_width": h.bin_width, "mean": h.mean, "pairs": h.total, "p": h.p.tolist()}
                for name, h in self.histograms.items()
            },
        }


def known_radii(extents) -> np.ndarray | None:
    """Principal radii (``entries/extents``, :func:`shapeidx.signing.moments.shape_facts`) as a
    signature's :attr:`Signature.radii`: None unless all three are known and positive."""
    radii = np.asarray(extents, dtype=np.float64)
    return radii.copy() if radii.shape == (3,) and np.isfinite(radii).all() and (radii > 0).all() else None


def _class_histograms(table: np.ndarray, means: np.ndarray, widths: np.ndarray) -> dict:
    """The IN / OUT / MIXED histograms from a (3, bins) table of counts, each cut after its
    last filled bin (an empty class: no bins)."""
    histograms = {}
    for code, name in enumerate(CLASS_NAMES):
        used = np.flatnonzero(table[code])
        counts = table[code, : used[-1] + 1] if len(used) else np.zeros(0, dtype=np.int64)
        histograms[name] = Histogram(counts, float(means[code]), float(widths[code]))
    return histograms


def _histograms_compiled(native, distances: np.ndarray, classes: np.ndarray, mean_all: float, divisor: int) -> dict:
    """:meth:`Signature.from_pairs`' histograms by two compiled passes over the pairs
    (shapeidx/signing/_pairs.c): the same sums in the same order, the same bins."""
    distances = np.ascontiguousarray(distances, dtype=np.float64)
    classes = np.ascontiguousarray(classes, dtype=np.uint8)
    sums, sizes = np.zeros(len(CLASS_NAMES)), np.zeros(len(CLASS_NAMES), dtype=np.int64)
    largest = np.zeros(len(CLASS_NAMES))
    native.class_sums(distances, classes, sums, sizes, largest)
    means = sums / np.maximum(sizes, 1)
    widths = means / divisor
    width_all = mean_all / divisor
    # d / w grows with d, so a histogram's largest distance falls in its last bin (each
    # class by its own largest: a class of a few short pairs has a narrow bin width)
    bins_all = int(largest.max() / width_all) + 1
    bins = max(int(top / (w if w > 0 else 1.0)) for top, w in zip(largest, widths)) + 1
    counts_all = np.zeros(bins_all, dtype=np.int64)
    per_class = np.zeros((len(CLASS_NAMES), bins), dtype=np.int64)
    native.bin_counts(distances, classes, width_all, widths, counts_all, per_class)
    return {"all": Histogram(counts_all, mean_all, width_all), **_class_histograms(per_class, means, widths)}
