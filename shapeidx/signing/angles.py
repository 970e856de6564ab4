"""The normal-angle shape function: the angle between two sample points' surface normals.

D2 sees only how far apart two points are. Whether their faces are parallel (two sides of a
plate, the top and bottom of a chip), square to each other (a box's walls) or anything in
between (a curved can) is what tells many electronic parts apart, and D2 does not see it.
Ohbuchi et al. (2003, "Shape-similarity search of three-dimensional models using
parameterized statistics") histogram that angle over random pairs; here it is histogrammed
over the same pairs as D2 and split by the same IN / OUT / MIXED classes, so it costs no ray
query: the classification already has every sample's outward normal.

For each histogram of :data:`ANGLE_HISTOGRAMS` the angle ``theta = arccos(n_i . n_j)`` in
``[0, pi]`` falls into one of :data:`ANGLE_BINS` equal bins. The normals are oriented away
from the material (by winding numbers where the mesh is not closed), so ``theta`` near
``pi`` means facing surfaces, near 0 parallel ones facing the same way. The angle is unchanged
by rotation, translation, uniform scaling and mirroring.

Analytic forms the tests check: on a sphere ``cos theta`` is uniform on ``[-1, 1]`` (the
normals are the points' directions), so bin ``k`` holds ``(cos(k pi / B) - cos((k + 1) pi / B)) / 2``
of the pairs; on a cube a pair lies on the same face (``theta = 0``) with probability 1/6, on
opposite faces (``pi``) 1/6 and on adjacent faces (``pi / 2``) 4/6.
"""

from __future__ import annotations

import numpy as np

from .classify import pair_blocks
from .occlusion import compiled_pairs
from .parameters import CLASS_NAMES

#: Bins of each angle histogram over ``[0, pi]``. Odd, and 17 rather than 15, so that no bin
#: edge falls on an angle CAD parts are full of (90, 45, 30, 60, 120, 135 degrees): with an
#: edge at 90 degrees, rounding alone would throw a box's perpendicular faces into one bin or
#: its neighbour depending on the part's pose (16 bins: L1 0.23 between a block and its rotated copy).
ANGLE_BINS = 17
#: The angle histograms: over all pairs, then per class (the order of their rows).
ANGLE_HISTOGRAMS = ("all",) + CLASS_NAMES


def angle_histograms(normals: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """Pair counts per angle bin, for all pairs and per class.

    Parameters
    ----------
    normals : (m, 3) float
        Unit outward normals of the sample points.
    classes : (m(m-1)/2,) uint8
        Class code of each pair, pairs in :func:`shapeidx.signing.classify.pair_indices` order
        (row ``1 + code`` of the result).

    Returns
    -------
    (len(ANGLE_HISTOGRAMS), ANGLE_BINS) int64
    """
    n = np.ascontiguousarray(normals, dtype=np.float64)
    native = compiled_pairs()
    if native is not None and len(n) > 1:
        return _angle_histograms_compiled(native, n, np.ascontiguousarray(classes, dtype=np.uint8))
    # the cosines by three outer products (a BLAS product with an inner dimension of 3
    # costs several times more), by blocks of rows that stay in cache, upper triangle only
    cos = np.empty(len(n) * (len(n) - 1) // 2)
    for row, stop_row, local, start, stop in pair_blocks(len(n)):
        n_i, n_j = n[row:stop_row], n[row:]
        block = np.multiply.outer(n_i[:, 0], n_j[:, 0])
        block += np.multiply.outer(n_i[:, 1], n_j[:, 1])
        block += np.multiply.outer(n_i[:, 2], n_j[:, 2])
        np.take(block.ravel(), local, out=cos[start:stop])
    bins = angle_bins(cos)
    per_class = np.bincount(np.asarray(classes, dtype=np.int64) * ANGLE_BINS + bins, minlength=len(CLASS_NAMES) * ANGLE_BINS)
    per_class = per_class[: len(CLASS_NAMES) * ANGLE_BINS].reshape(len(CLASS_NAMES), ANGLE_BINS)
    return np.vstack([per_class.sum(axis=0), per_class]).astype(np.int64)


def _angle_histograms_compiled(native, normals: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """:func:`angle_histograms` by one compiled pass (shapeidx/signing/_pairs.c): the same
    cosines, binned by the same table; the pairs near a bin edge come back to be binned here
    by the definition."""
    per_class = np.zeros((len(CLASS_NAMES), ANGLE_BINS), dtype=np.int64)
    near_cos, near_class = np.empty(len(classes)), np.empty(len(classes), dtype=np.uint8)
    near = native.angle_counts(normals, classes, _CELL_BINS, per_class, near_cos, near_class)
    if near:
        keys = near_class[:near].astype(np.int64) * ANGLE_BINS + angle_bins_exact(near_cos[:near])
        per_class += np.bincount(keys, minlength=per_class.size).reshape(per_class.shape)
    return np.vstack([per_class.sum(axis=0), per_class])


def angle_bins_exact(cos: np.ndarray) -> np.ndarray:
    """The bin of each angle ``arccos(cos)``: the definition (:func:`angle_bins` is the fast road)."""
    cos = np.clip(cos, -1.0, 1.0)
    return np.minimum((np.arccos(cos) * (ANGLE_BINS / np.pi)).astype(np.int64), ANGLE_BINS - 1)


#: Cells of equal width in ``cos`` over [-1, 1] for :func:`angle_bins`' table.
_CELLS = 4096


def _cell_bins() -> np.ndarray:
    """The angle bin of every value in each cosine cell, or -1 where a bin edge falls
    inside the cell (widened by far more than the rounding of the cell number).

    The bin falls as the cosine grows (arccos is monotone), so a cell whose two widened
    ends have the same bin holds only that bin.
    """
    edges = np.linspace(-1.0, 1.0, _CELLS + 1)
    margin = 1e-9
    low = angle_bins_exact(np.maximum(edges[:-1] - margin, -1.0))
    high = angle_bins_exact(np.minimum(edges[1:] + margin, 1.0))
    table = np.where(low == high, low, -1).astype(np.int64)
    table.flags.writeable = False
    return table


_CELL_BINS = _cell_bins()


def angle_bins(cos: np.ndarray) -> np.ndarray:
    """:func:`angle_bins_exact`, without an arccos for most values.

    Each cosine's cell in a table over [-1, 1] gives its bin; only the values in the few
    cells that a bin edge crosses (about 1 in 250) are binned by the definition. The result
    is the definition's, value for value (tests/test_angles.py checks it at every edge).
    """
    cell = ((cos + 1.0) * (_CELLS / 2)).astype(np.intp)  # a power of two: exact scaling
    np.clip(cell, 0, _CELLS - 1, out=cell)  # cosines just beyond +-1 (rounding) and NaN
    bins = _CELL_BINS[cell]
    near_edge = np.flatnonzero(bins < 0)
    if len(near_edge):
        bins[near_edge] = angle_bins_exact(cos[near_edge])
    return bins


def angle_probabilities(counts: np.ndarray) -> np.ndarray:
    """Each row of ``counts`` (..., bins) divided by its total (an empty row stays 0, an
    unknown one, NaN, stays NaN)."""
    counts = np.asarray(counts, dtype=np.float64)
    totals = counts.sum(axis=-1, keepdims=True)
    p = np.divide(counts, totals, out=np.zeros_like(counts), where=totals > 0)
    return np.where(np.isnan(totals), np.nan, p)
