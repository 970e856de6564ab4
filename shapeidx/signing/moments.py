"""A part's absolute size, proportions and handedness: what D2 cannot see, from exact surface moments.

D2 histograms are made of point-pair distances, which a mirror image keeps; the paper's
normalisation by the mean distance also throws away the part's size. Both matter when a
data manager asks "is this the same part?": a left and a right bracket are different
parts, and so are a part and its drawing at 25.4 times the size. :func:`shape_facts`
computes, once per part at build time, the quantities the store keeps for that:

* ``bounds``: the axis-aligned bounding box in file units (min x, y, z, max x, y, z);
* ``extents``: the principal radii, ``sqrt`` of the eigenvalues of the area-weighted
  covariance of the surface, largest first: the part's size along its own axes, the same
  in every orientation;
* ``handedness``: two pseudo-scalars made of third-order surface moments in the
  principal-axes frame; each is unchanged by any rotation (and translation and uniform
  scaling) and changes sign under a mirroring;
* ``moments``: a fingerprint unchanged by rotation, mirroring and scaling: the area over
  ``r1^2 + r2^2 + r3^2``, and the absolute skewnesses ``|T_111|, |T_222|, |T_333|`` (NaN
  where the axes are undefined). With the proportions ``r2/r1, r3/r1`` it tells apart parts
  whose D2 signatures are within sampling noise of each other (docs/duplicates.md).

Handedness. Let ``e1, e2, e3`` be the principal axes and ``T_ijk`` the third central
moments of the surface along them, divided by ``sigma_i sigma_j sigma_k`` (so they do not
depend on size). An eigenvector is only defined up to its sign; flipping ``e_k`` flips
every ``T`` with an odd number of indices ``k`` and flips ``det[e1 e2 e3]``. Hence

    h1 = det(E) * T_111 * T_222 * T_333     (the product of the three axial skewnesses)
    h2 = det(E) * T_123                     (the fully mixed moment)

do not depend on the sign choices, so they are invariant under rotations. A mirroring
keeps the axes' moments (up to those signs) but reverses the frame's orientation, so both
change sign. A part with a mirror plane through its centroid has both equal to zero. The
moments are integrated exactly (a 7-point quadrature rule, exact for cubic polynomials on
a triangle), not from random samples, so a rotated copy gives the same values to rounding
and a re-faceted one nearly the same.

Where the axes are not defined (two principal radii within :data:`AXIS_GAP` of each
other: a square pin, a cylinder) the frame can turn freely in their plane and the values
mean nothing: ``h1`` and ``h2`` are NaN. One axis ``u`` is still defined when the third
radius stands apart (a long pin header of nearly square section: ``u`` along its row), and
so is a third pseudo-scalar that needs no other axis (:func:`axial_handedness`): in the
whitened frame (``x -> Sigma^(-1/2) x``, unique even where two radii coincide) let
``v_i = T_ijj``; then

    h3 = u . (v x T(., u, v))

is even in the sign of ``u``, unchanged by any rotation, and changes sign under a mirroring
(a triple product of three vectors). It is defined exactly where ``h1, h2`` are not and one
axis is, and it is far smaller than they are (a long SMD pin header's is 2e-4 to 4e-3), hence its
own threshold (:data:`shapeidx.signing.chirality.AXIAL_CHIRAL_MIN`). Where no axis is
defined, or the surface is flat, all three are NaN and the part counts as of unknown
handedness (:mod:`shapeidx.signing.chirality` never calls it mirrored).
"""

from __future__ import annotations

import numpy as np

#: Two principal variances closer than this share of the largest make the axes undefined.
AXIS_GAP = 0.02
#: The facts :func:`shape_facts` returns for a part it cannot measure.
UNKNOWN = {"bounds": (np.nan,) * 6, "extents": (np.nan,) * 3, "handedness": (np.nan,) * 3, "moments": (np.nan,) * 4}

# Degree-3 rule on a triangle: vertices 3/60, edge midpoints 8/60, centroid 27/60.
_BARY = np.array(
    [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5], [1 / 3, 1 / 3, 1 / 3]]
)
_WEIGHTS = np.array([3, 3, 3, 8, 8, 8, 27]) / 60.0


def surface_moments(vertices: np.ndarray, faces: np.ndarray):
    """Area, centroid, covariance and third central moments of a triangle surface, exactly.

    Returns
    -------
    area : float
    centroid : (3,) float64
    covariance : (3, 3) float64
        Second central moments divided by the area.
    third : (3, 3, 3) float64
        Third central moments divided by the area.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    tri = vertices[np.asarray(faces, dtype=np.int64)]  # (k, 3, 3)
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area = float(areas.sum())
    if not area > 0:
        raise ValueError("the surface has no area")
    # the quadrature points as columns, one row per axis, and each distinct moment a sum of
    # products of contiguous rows: an einsum of four operands loops over every index
    # combination (some 15 times slower on a KiCad part), and BLAS would start threads
    # that only spin beside a build worker, which already has its core.
    points = np.einsum("qv,dvk->dqk", _BARY, tri.transpose(2, 1, 0)).reshape(3, -1)  # (3, 7 k)
    weights = (_WEIGHTS[:, None] * areas[None, :] / area).reshape(-1)  # (7 k,), sums to 1
    centroid = np.einsum("dn,n->d", points, weights)
    x = points - centroid[:, None]
    weighted = x * weights
    covariance = np.empty((3, 3))
    third = np.empty((3, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            pair = weighted[i] * x[j]
            covariance[i, j] = covariance[j, i] = pair.sum()
            for k in range(j, 3):
                value = (pair * x[k]).sum()
                for a, b, c in {(i, j, k), (i, k, j), (j, i, k), (j, k, i), (k, i, j), (k, j, i)}:
                    third[a, b, c] = value
    return area, centroid, covariance, third


def _principal_frame(covariance: np.ndarray):
    """``(variances, axes, close, flat)``: the principal variances largest first and their axes
    (columns), which neighbouring pairs are within :data:`AXIS_GAP` of each other (2,), and
    whether the surface is flat (its smallest variance nothing beside the largest)."""
    variances, axes = np.linalg.eigh(covariance)
    variances, axes = variances[::-1], axes[:, ::-1]
    top = max(float(variances[0]), np.finfo(float).tiny)
    return variances, axes, -np.diff(variances) / top < AXIS_GAP, bool(variances[2] <= 1e-12 * top)


def handedness_of(covariance: np.ndarray, third: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal radii (largest first) and the two pseudo-scalars ``(h1, h2)`` (module docstring).

    ``h`` is NaN when two principal variances are within :data:`AXIS_GAP` of each other.
    """
    variances, axes, close, flat = _principal_frame(covariance)
    radii = np.sqrt(np.maximum(variances, 0.0))
    if close.any() or flat:
        return radii, np.full(2, np.nan)
    t = np.einsum("ijk,ia,jb,kc->abc", third, axes, axes, axes) / np.einsum("a,b,c->abc", radii, radii, radii)
    det = float(np.sign(np.linalg.det(axes)))
    return radii, np.array([det * t[0, 0, 0] * t[1, 1, 1] * t[2, 2, 2], det * t[0, 1, 2]])


def axial_handedness(covariance: np.ndarray, third: np.ndarray) -> float:
    """``h3`` (module docstring): the handedness about the one defined principal axis, where
    exactly two principal variances are within :data:`AXIS_GAP` of each other (NaN otherwise:
    ``h1, h2`` are defined, or no axis is, or the surface is flat)."""
    variances, axes, close, flat = _principal_frame(covariance)
    if close.all() or not close.any() or flat:
        return float("nan")
    u = axes[:, 2] if close[0] else axes[:, 0]  # the radius that stands apart
    whiten = (axes / np.sqrt(variances)) @ axes.T  # Sigma^(-1/2)
    t = np.einsum("ijk,ia,jb,kc->abc", third, whiten, whiten, whiten)
    v = np.einsum("ijj->i", t)
    return float(u @ np.cross(v, np.einsum("ijk,j,k->i", t, u, v)))


def shape_facts(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """``bounds`` (6,), ``extents`` (3,), ``handedness`` (3,: ``h1, h2, h3``) and ``moments``
    (4,) of a surface.

    A surface that cannot be measured (no area) gives :data:`UNKNOWN` (NaN everywhere).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if len(faces) == 0 or len(vertices) == 0:
        return dict(UNKNOWN)
    from ..io.base import column_max, column_min
    from .mesh import unique_indices  # here: this module is imported without scipy

    used = vertices[unique_indices(faces)]
    bounds = tuple(np.concatenate([column_min(used), column_max(used)]).tolist())
    try:
        _, _, covariance, third = surface_moments(vertices, faces)
    except ValueError:
        return dict(UNKNOWN, bounds=bounds)
    radii, handedness = handedness_of(covariance, third)
    area = float(np.asarray(_areas(vertices, faces)).sum())
    spread = float((radii**2).sum())
    skew = np.full(3, np.nan)
    if np.isfinite(handedness).all():
        axes = _principal_frame(covariance)[1]
        t = np.einsum("ijk,ia,ja,ka->a", third, axes, axes, axes) / radii**3
        skew = np.abs(t)
    moments = (area / spread if spread > 0 else np.nan, *skew.tolist())
    handedness = (*handedness.tolist(), axial_handedness(covariance, third))
    return {"bounds": bounds, "extents": tuple(radii.tolist()), "handedness": handedness,
            "moments": tuple(float(m) for m in moments)}


def _areas(vertices, faces):
    tri = vertices[np.asarray(faces, dtype=np.int64)]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
