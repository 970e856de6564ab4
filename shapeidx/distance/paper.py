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


# The four formulas, each over per-pair features (``d_H``: ``D`` of histogram H; ``gap_C``:
# ``|%A - %B|`` of class C). They work element-wise: numbers, or arrays with one value per pair.


def all_distance(f: dict):
    """**ALL** (plain D2): ``D(all_A, all_B)``."""
    return f["d_all"]


def avg3(f: dict):
    """**AvgOf3**: the mean ``D`` of IN, OUT and MIXED."""
    return sum(f[f"d_{c}"] for c in HISTOGRAMS[1:]) / 3.0


def avg4(f: dict):
    """**AvgOf4**: the mean ``D`` of ALL, IN, OUT and MIXED."""
    return sum(f[f"d_{h}"] for h in HISTOGRAMS) / 4.0


def weighted(f: dict):
    """**Weighted**: ``sum_c D(c_A, c_B) / (1 - |%c_A - %c_B|)``, the agreement floored at
    :data:`MIN_AGREEMENT`."""
    return sum(f[f"d_{c}"] / np.maximum(1.0 - f[f"gap_{c}"], MIN_AGREEMENT) for c in HISTOGRAMS[1:])
