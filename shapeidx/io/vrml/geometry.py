"""Geometry for the VRML reader: transforms, coordIndex to polygons, primitive shapes.

Polygons are (sizes, corners) pairs as in :class:`~shapeidx.io.base.PolygonMesh`:
polygon ``k`` has ``sizes[k]`` corners, listed in ``corners`` after those of ``k - 1``.

Primitive tessellation (fixed, so that the same file always gives the same polygons):

- Box / VRML 1.0 Cube: 6 quadrilaterals (exact).
- Cylinder: :data:`SEGMENTS` side quadrilaterals; top and bottom are one polygon of
  :data:`SEGMENTS` corners each. The polygon is inscribed in the circle.
- Cone: :data:`SEGMENTS` side triangles meeting at the apex; the bottom one polygon.
- Sphere: :data:`SEGMENTS` meridians by :data:`RINGS` bands of latitude; the bands
  touching a pole are triangles, the others quadrilaterals; vertices lie on the sphere.

All are centred on the origin with their axis along +y and wound counter-clockwise seen
from outside, as the VRML specifications define them.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

SEGMENTS = 32
RINGS = 16

Polygons = tuple[np.ndarray, np.ndarray, np.ndarray]  # vertices, sizes, corners


# -- transforms ---------------------------------------------------------------------------


def rotation_matrix(axis_angle) -> np.ndarray:
    """3x3 matrix of a VRML rotation ``x y z angle`` (radians, right-handed).

    A zero axis means no rotation, as browsers treat it.
    """
    x, y, z, angle = (float(v) for v in axis_angle)
    length = np.sqrt(x * x + y * y + z * z)
    if length == 0.0 or angle == 0.0:
        return np.eye(3)
    x, y, z = x / length, y / length, z / length
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    return np.array(
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ]
    )


def transform_matrix(translation, rotation, scale, scale_orientation, center) -> np.ndarray:
    """4x4 matrix (acting on column vectors) of a VRML Transform.

    The specification's order: ``T * C * R * SR * S * -SR * -C``.
    """
    linear = rotation_matrix(rotation)
    if np.any(np.asarray(scale) != 1.0):
        orient = rotation_matrix(scale_orientation)
        linear = linear @ orient @ np.diag(np.asarray(scale, dtype=float)) @ orient.T
    matrix = np.eye(4)
    matrix[:3, :3] = linear
    center = np.asarray(center, dtype=float)
    matrix[:3, 3] = np.asarray(translation, dtype=float) + center - linear @ center
    return matrix


class Placement:
    """Where a node's geometry goes: a 4x4 matrix (on column vectors), with what the
    walk asks of it per face set computed once per transform instead.

    Attributes
    ----------
    matrix : (4, 4) float64
    mirrored : bool
        Negative determinant: counter-clockwise polygons come out clockwise.
    key : bytes
        The matrix as bytes, to recognise the same placement of shared coordinates.
    """

    __slots__ = ("matrix", "mirrored", "key", "is_identity")

    def __init__(self, matrix: np.ndarray):
        self.matrix = matrix
        self.mirrored = bool(np.linalg.det(matrix[:3, :3]) < 0)
        self.key = matrix.tobytes()
        self.is_identity = self.key == _IDENTITY_BYTES

    def then(self, local: np.ndarray) -> "Placement":
        """This placement followed by a node's own transform ``local``."""
        return Placement(self.matrix @ local)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Points (n, 3) moved to their place."""
        if self.is_identity:
            return points
        return points @ self.matrix[:3, :3].T + self.matrix[:3, 3]


_IDENTITY_BYTES = np.eye(4).tobytes()


def translation_matrix(offset) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = offset
    return matrix


def linear_matrix(linear: np.ndarray) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = linear
    return matrix


# -- polygons from coordIndex ------------------------------------------------------------


def polygon_triangle_count(coord_index: np.ndarray) -> int:
    """Triangles the polygons of a coordIndex give at most (before index checks)."""
    index = np.asarray(coord_index)
    separators = index == -1
    sizes = np.bincount(np.cumsum(separators)[~separators])
    return int(np.maximum(sizes - 2, 0).sum())


#: The polygons of one coordIndex: ``(sizes, corners, triangles, notes)`` with sizes (k,)
#: int64, corners (sizes.sum(),) int64, triangles = sizes.sum() - 2 k (what they give),
#: notes what was dropped (for the warnings). A plain tuple: made by the thousand.
FaceSet = tuple[np.ndarray, np.ndarray, int, tuple[str, ...]]


def face_sets_from_coord_indices(coord_indices: list[np.ndarray], point_counts: list[int]) -> list[FaceSet | None]:
    """Split coordIndex arrays on -1 into polygons (the final -1 is optional), all at once.

    A CAD export may hold thousands of small face sets (KiCad writes one per CAD face):
    numpy's cost per call, not per number, would decide the time if each were split on
    its own, so the arrays are concatenated and split together. Each array's result is
    what splitting it alone gives.

    Indices outside ``[0, point_counts[j])`` (other than the -1 separators) are dropped,
    and polygons left with fewer than three corners are skipped. Integers too large for
    int64 count as out of range rather than wrapping around.

    Parameters
    ----------
    coord_indices : list of (n_j,) float64
        coordIndex values as read.
    point_counts : list of int
        The number of points each array indexes.

    Returns
    -------
    list of FaceSet or None
        ``(sizes, corners, triangles, notes)`` per array; None for an array holding
        numbers that are not integers (fractions, NaN).
    """
    count = len(coord_indices)
    if count == 0:
        return []
    lengths = np.fromiter(map(len, coord_indices), dtype=np.int64, count=count)
    values = np.concatenate(coord_indices).astype(np.float64, copy=False)
    segment = np.repeat(np.arange(count), lengths)  # which array each value is from
    with np.errstate(invalid="ignore"):  # NaN, infinity and huge values cast to garbage
        index = values.astype(np.int64)
        exact = index == values
        integral = np.ones(count, dtype=bool)
        if not exact.all():
            integral[segment[values != np.round(values)]] = False
            index = np.where(exact, index, np.clip(values, -(2**62), 2**62).astype(np.int64))
    out_of_range = (index < -1) | (index >= np.repeat(np.asarray(point_counts, dtype=np.int64), lengths))
    dropped = np.bincount(segment[out_of_range], minlength=count)
    index, segment = index[~out_of_range], segment[~out_of_range]
    separators = index == -1
    # Polygon numbers: a new polygon after each -1 and at the start of each array.
    polygon_of = (np.cumsum(separators) + segment)[~separators]
    corners, corner_segment = index[~separators], segment[~separators]
    sizes = np.bincount(polygon_of)  # empty polygons (-1 -1, or a trailing -1) count 0
    polygon_segment = np.zeros(len(sizes), dtype=np.int64)
    polygon_segment[polygon_of] = corner_segment
    keep = sizes >= 3
    short = np.bincount(polygon_segment[(sizes > 0) & ~keep], minlength=count)
    kept_corner = keep[polygon_of]
    corners, corner_segment = corners[kept_corner], corner_segment[kept_corner]
    sizes, polygon_segment = sizes[keep].astype(np.int64), polygon_segment[keep]
    corner_counts = np.bincount(corner_segment, minlength=count)
    polygon_counts = np.bincount(polygon_segment, minlength=count)
    corner_ends = np.cumsum(corner_counts).tolist()
    polygon_ends = np.cumsum(polygon_counts).tolist()
    triangles = (corner_counts - 2 * polygon_counts).tolist()
    # Each array's pieces, with tuples made by zip (in C): KiCad parts hold a thousand
    corner_starts, polygon_starts = [0, *corner_ends[:-1]], [0, *polygon_ends[:-1]]
    sizes_parts = [sizes[start:end] for start, end in zip(polygon_starts, polygon_ends)]
    corner_parts = [corners[start:end] for start, end in zip(corner_starts, corner_ends)]
    notes: list[tuple[str, ...]] = [()] * count
    for j in np.flatnonzero(dropped | short).tolist():
        notes[j] = _drop_notes(int(dropped[j]), int(short[j]))
    results: list[FaceSet | None] = list(zip(sizes_parts, corner_parts, triangles, notes))
    for j in np.flatnonzero(~integral).tolist():
        results[j] = None
    return results


def _drop_notes(dropped: int, short: int) -> tuple[str, ...]:
    notes = []
    if dropped:
        notes.append(f"{dropped} out-of-range coordIndex value(s) dropped")
    if short:
        notes.append(f"{short} polygon(s) with fewer than three corners skipped")
    return tuple(notes)


def reverse_winding(sizes: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Corners of every polygon in the opposite order, each keeping its first corner.

    ``a b c d`` becomes ``a d c b``: keeping the first corner keeps the quadrilateral
    split of Ip et al. (which looks from the first corner) on the same diagonal.
    """
    if len(corners) == 0:
        return corners
    starts = np.repeat(np.cumsum(sizes) - sizes, sizes)
    local = np.arange(len(corners)) - starts
    sizes_each = np.repeat(sizes, sizes)
    return corners[starts + (sizes_each - local) % sizes_each]


# -- primitives ----------------------------------------------------------------------------


def _flat(polygons: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    sizes = np.array([len(p) for p in polygons], dtype=np.int64)
    corners = np.array([i for p in polygons for i in p], dtype=np.int64)
    return sizes, corners


@lru_cache(maxsize=64)
def box(width: float, height: float, depth: float) -> Polygons:
    """Axis-aligned box centred on the origin: 8 vertices, 6 quadrilaterals."""
    x, y, z = width / 2, height / 2, depth / 2
    vertices = np.array(
        [[-x, -y, -z], [x, -y, -z], [x, y, -z], [-x, y, -z], [-x, -y, z], [x, -y, z], [x, y, z], [-x, y, z]]
    )
    faces = [[4, 5, 6, 7], [1, 0, 3, 2], [5, 1, 2, 6], [0, 4, 7, 3], [7, 6, 2, 3], [0, 1, 5, 4]]
    return (vertices, *_flat(faces))


def _circle(radius: float, y: float) -> np.ndarray:
    """SEGMENTS points on a circle around the y axis, counter-clockwise seen from +y."""
    angle = np.arange(SEGMENTS) * (2 * np.pi / SEGMENTS)
    return np.stack([radius * np.sin(angle), np.full(SEGMENTS, y), radius * np.cos(angle)], axis=1)


@lru_cache(maxsize=64)
def cylinder(radius: float, height: float, side: bool = True, top: bool = True, bottom: bool = True) -> Polygons:
    """Cylinder along y from ``-height/2`` to ``height/2``; parts as asked."""
    h = height / 2
    vertices = np.concatenate([_circle(radius, -h), _circle(radius, h)])
    n = SEGMENTS
    faces = []
    if side:
        faces += [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    if top:
        faces.append([n + i for i in range(n)])
    if bottom:
        faces.append([i for i in reversed(range(n))])
    return (vertices, *_flat(faces))


@lru_cache(maxsize=64)
def cone(bottom_radius: float, height: float, side: bool = True, bottom: bool = True) -> Polygons:
    """Cone along y, apex at ``height/2``, base circle at ``-height/2``; parts as asked."""
    h = height / 2
    vertices = np.concatenate([_circle(bottom_radius, -h), [[0.0, h, 0.0]]])
    n = SEGMENTS
    faces = []
    if side:
        faces += [[i, (i + 1) % n, n] for i in range(n)]
    if bottom:
        faces.append([i for i in reversed(range(n))])
    return (vertices, *_flat(faces))


@lru_cache(maxsize=64)
def sphere(radius: float) -> Polygons:
    """Sphere of SEGMENTS meridians and RINGS latitude bands, vertices on the sphere."""
    polar = np.arange(1, RINGS) * (np.pi / RINGS)  # inner rings, from the top down
    rings = [_circle(radius * np.sin(p), radius * np.cos(p)) for p in polar]
    vertices = np.concatenate([[[0.0, radius, 0.0]], *rings, [[0.0, -radius, 0.0]]])
    n = SEGMENTS
    south = len(vertices) - 1

    def ring(r, i):  # vertex number of corner i of inner ring r (0 = nearest the top)
        return 1 + r * n + i % n

    faces = [[0, ring(0, i), ring(0, i + 1)] for i in range(n)]
    for r in range(RINGS - 2):
        faces += [[ring(r, i), ring(r + 1, i), ring(r + 1, i + 1), ring(r, i + 1)] for i in range(n)]
    faces += [[ring(RINGS - 2, i), south, ring(RINGS - 2, i + 1)] for i in range(n)]
    return (vertices, *_flat(faces))


def primitive_triangle_count(polygons: Polygons) -> int:
    _, sizes, _ = polygons
    return int((sizes - 2).sum())
