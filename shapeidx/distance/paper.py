"""The distances of Ip et al. (2002, section 3.2.5) between two signatures.

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
"""

from __future__ import annotations

import numpy as np

from ..signing.parameters import HISTOGRAMS

#: The distances Ip et al. (2002) define.
PAPER_METRICS = ("all", "avg3", "avg4", "weighted")
#: Floor of ``1 - Diff`` in the Weighted distance (weights are at most its inverse).
MIN_AGREEMENT = 1e-3


def histogram_distance(p: np.ndarray, q: np.ndarray) -> float:
    """``D(p, q)``: L1 after zero-padding the shorter histogram, divided by the bin count."""
    n = max(len(p), len(q))
    if n == 0:
        return 0.0
    padded = np.zeros((2, n))
    padded[0, : len(p)] = p
    padded[1, : len(q)] = q
    return float(np.abs(padded[0] - padded[1]).sum() / n)


def paper_distances(d: dict, fraction_gap: dict) -> dict:
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
