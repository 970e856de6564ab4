"""Points on a surface, uniform by area (Ip et al. 2002, section 3.2.1), drawn stratified.

The paper places m points independently at random. Independent draws leave clumps and gaps
on the surface, and the histograms of two drawings of one part differ by that alone: with
1,024 independent points an exact copy of a kicad6 part, its points drawn with another seed,
was its own nearest part only 79-91 % of the time (docs/sampling.md). Here the same
distribution is sampled with far less of that noise, by two classic variance reductions:

* **systematic sampling by area along a space-filling curve**: the triangles are taken in the
  Z-order (Morton order) of their centroids, and the m points sit at ``(k + u) / m`` of the
  cumulative area in that order (one uniform ``u`` for all). A triangle of area ``A_t`` out of
  ``A`` receives ``m A_t / A`` points rounded up or down, never a clump of five where one was
  due, and so does every stretch of the curve, a region of the surface: the points spread
  over the part. The order is the geometry's, not the file's, so two files of one part that
  list their triangles otherwise are stratified alike;
* **a low-discrepancy pattern inside the triangles**: the k-th point's two barycentric
  numbers are the k-th point of the R2 sequence (Roberts 2018, additive recurrence on the
  plastic number) shifted by a uniform random offset (Cranley-Patterson rotation), so the
  points one large triangle receives spread evenly over it.

Each point is still uniform on the surface, by area, for its own random draw (``u`` and the
offsets are uniform), so the expected histograms are the paper's; only the spread between
drawings shrinks. The seed fixes every draw: the same file gives the same points.
"""

from __future__ import annotations

import numpy as np

from ..io.base import column_max, column_min
from .mesh import triangle_areas
from .parameters import DEFAULT_SEED

#: The plastic number: the R2 sequence steps by (1 / g, 1 / g^2) modulo 1.
_PLASTIC = 1.324717957244746025960908854478
_R2_STEP = np.array([1 / _PLASTIC, 1 / _PLASTIC**2])


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = DEFAULT_SEED):
    """Place ``count`` points on a triangle surface, each uniform by area, stratified.

    Systematic sampling of the cumulative areas, the triangles in :func:`curve_order`, chooses
    the triangles (one uniform offset ``u``: point k at ``(k + u) / count`` of the total area,
    found by binary search); the
    point inside its triangle is, as in Osada et al. (2002),

    .. math:: p = (1 - \\sqrt{r_1}) A + \\sqrt{r_1} (1 - r_2) B + \\sqrt{r_1} r_2 C

    with ``(r_1, r_2)`` the k-th point of the R2 low-discrepancy sequence, rotated by a uniform
    offset. Every point is uniform on the surface by area; the module docstring says why the
    points are not independent.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (k, 3) int
    count : int
    seed : int
        Seeds numpy's PCG64, whose stream is the same on every platform.

    Returns
    -------
    points : (count, 3) float64
    face_index : (count,) int64
        The triangle each point lies on.
    """
    faces = np.asarray(faces)
    order = curve_order(vertices, faces)
    cumulative = np.cumsum(triangle_areas(vertices, faces[order]))
    start, *offset = random_offsets(seed)
    step = np.arange(count)
    pick = (step + start) * (cumulative[-1] / count)
    face_index = order[np.minimum(np.searchsorted(cumulative, pick, side="right"), len(faces) - 1)]
    r1, r2 = (np.multiply.outer(_R2_STEP, step) + np.asarray(offset)[:, None]) % 1.0
    s = np.sqrt(r1)[:, None]
    a, b, c = (vertices[faces[face_index, k]] for k in range(3))
    points = (1 - s) * a + s * (1 - r2[:, None]) * b + s * r2[:, None] * c
    return points, face_index


def random_offsets(seed: int) -> np.ndarray:
    """The three uniform numbers a drawing takes from ``seed``: the systematic start ``u`` and
    the two Cranley-Patterson offsets. Two drawings of one surface are as near as these are (on
    the unit torus): a query seed whose start falls near the store's draws nearly the store's
    points, so a benchmark's seeds are read with their offsets (scripts/same_part_study.py)."""
    return np.random.Generator(np.random.PCG64(seed)).random(3)


def curve_order(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The triangles' indices in the Z-order (:func:`z_order`) of their centroids in the
    surface's own frame (:func:`own_frame`): a rotated or moved copy of a part is ordered as
    the part is (ties, triangles of one cell, in file order)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    centroids = (vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]) / 3
    return z_order(own_frame(centroids, triangle_areas(vertices, faces)))


def own_frame(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``points`` in the frame of their weighted principal axes, each axis pointing to the
    side of its larger third moment: unchanged by rotation and translation, up to rounding,
    where the axes are distinct (a part as round as a cylinder about an axis keeps some turn)."""
    total = weights.sum()
    if not total > 0 or len(points) < 2:
        return points
    centred = points - (weights @ points) / total
    _, axes = np.linalg.eigh((centred * weights[:, None]).T @ centred / total)
    local = centred @ axes
    skew = weights @ local**3
    return local * np.where(skew < 0, -1.0, 1.0)


#: Cells per axis of :func:`z_order`'s grid (2^10: a code fits 30 bits).
_CURVE_BITS = 10


def z_order(points: np.ndarray) -> np.ndarray:
    """The points' indices in Morton (Z-curve) order of a 1024^3 grid over their bounds:
    points near each other come near each other (ties in given order)."""
    lo, hi = column_min(points), column_max(points)
    cell = ((points - lo) / np.maximum(hi - lo, 1e-300) * ((1 << _CURVE_BITS) - 1)).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(_CURVE_BITS):
        for axis in range(3):
            code |= ((cell[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")
