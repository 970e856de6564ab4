"""Agreement of a clustering with known classes: normalised mutual information and the
adjusted Rand index (Hubert & Arabie 1985), as scikit-learn defines them (NMI with the
arithmetic mean of the two entropies)."""

from __future__ import annotations

import numpy as np


def _contingency(a, b) -> np.ndarray:
    _, ia = np.unique(np.asarray(a, dtype=str), return_inverse=True)
    _, ib = np.unique(np.asarray(b, dtype=str), return_inverse=True)
    table = np.zeros((ia.max() + 1 if len(ia) else 0, ib.max() + 1 if len(ib) else 0), dtype=np.int64)
    np.add.at(table, (ia, ib), 1)
    return table


def _entropy(counts: np.ndarray) -> float:
    p = counts[counts > 0] / counts.sum()
    return float(-(p * np.log(p)).sum())


def nmi(classes, clusters) -> float:
    """Normalised mutual information: I(A; B) / mean(H(A), H(B)); 1 for identical partitions."""
    table = _contingency(classes, clusters)
    n = table.sum()
    if n == 0:
        return float("nan")
    ha, hb = _entropy(table.sum(axis=1)), _entropy(table.sum(axis=0))
    if ha == 0 and hb == 0:
        return 1.0
    nz = table > 0
    pij = table[nz] / n
    outer = np.outer(table.sum(axis=1), table.sum(axis=0))[nz] / n**2
    mi = float((pij * np.log(pij / outer)).sum())
    return max(0.0, mi / ((ha + hb) / 2))


def ari(classes, clusters) -> float:
    """Adjusted Rand index: 1 for identical partitions, about 0 for independent ones."""
    table = _contingency(classes, clusters)
    n = int(table.sum())

    def pairs(x):
        x = np.asarray(x, dtype=np.float64)
        return (x * (x - 1) / 2).sum()

    total = n * (n - 1) / 2
    index, rows, cols = pairs(table), pairs(table.sum(axis=1)), pairs(table.sum(axis=0))
    expected = rows * cols / total if total else 0.0
    best = (rows + cols) / 2
    if best == expected:
        return 1.0
    return float((index - expected) / (best - expected))
