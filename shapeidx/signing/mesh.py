"""Mesh operations on the way from polygons as read to a clean surface.

:func:`shapeidx.signing.solid.make_solid` applies them in this order:

1. :func:`triangulate_polygons`: triangles as they are, quadrilaterals split by the
   rule of Ip et al. (2002, section 3.2.1), larger polygons triangulated in their plane
   (correct for concave ones).
2. :func:`merge_vertices` and :func:`remove_bad_faces`: duplicate points merged,
   degenerate and duplicate triangles dropped, and walls between touching bodies (a face
   each body writes, one on the other) dropped whole (:func:`shared_walls`).
3. :func:`orient_shells`: the triangles split into shells (connected through edges that
   have exactly two triangles) and each shell's winding made consistent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..ragged import offsets_of
from ..io.base import column_max, column_min


# ----------------------------------------------------------------------------------
# geometry helpers


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of two (k, 3) float64 arrays, by the same products and differences in
    the same order (so bit for bit the same), without np.cross's copies of both arguments."""
    if not (a.ndim == b.ndim == 2 and a.shape == b.shape and a.shape[1] == 3 and a.dtype == b.dtype == np.float64):
        return np.cross(a, b)
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    out = np.empty(a.shape)
    cp0, cp1, cp2 = out[:, 0], out[:, 1], out[:, 2]
    np.multiply(a1, b2, out=cp0)
    cp0 -= a2 * b1
    tmp = a0 * b2
    np.multiply(a2, b0, out=cp1)
    cp1 -= tmp
    np.multiply(a0, b1, out=cp2)
    np.multiply(a1, b0, out=tmp)
    cp2 -= tmp
    return out


def triangle_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Cross products (b - a) x (c - a): normal direction times twice the area, (k, 3)."""
    a = vertices[faces[:, 0]]
    return cross3(vertices[faces[:, 1]] - a, vertices[faces[:, 2]] - a)


def unit_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normal of each triangle by its winding; zero for a degenerate triangle."""
    n = triangle_cross(vertices, faces)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def flip_faces(faces: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A copy of ``faces`` with the triangles where ``mask`` is true wound the other way."""
    out = faces.copy()
    out[mask] = out[mask][:, ::-1]
    return out


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of every triangle, (k,)."""
    if len(faces) == 0:
        return np.zeros(0)
    return 0.5 * np.linalg.norm(triangle_cross(vertices, faces), axis=1)


def signed_volumes(vertices: np.ndarray, faces: np.ndarray, origin=None) -> np.ndarray:
    """Signed volume of the tetrahedron (origin, a, b, c) of every triangle, (k,).

    Summed over a closed, outward-wound shell this is the enclosed volume. ``origin`` is one
    point, or one point per triangle, (k, 3).
    """
    origin = np.zeros(3) if origin is None else np.asarray(origin)
    a = vertices[faces[:, 0]] - origin
    b = vertices[faces[:, 1]] - origin
    c = vertices[faces[:, 2]] - origin
    return np.einsum("ij,ij->i", a, cross3(b, c)) / 6.0


def unique_indices(indices: np.ndarray, return_inverse: bool = False):
    """``np.unique`` of non-negative integer indices (vertex numbers), by a mask, not a sort.

    Returns the sorted distinct values (int64) and, with ``return_inverse``, each index's
    position among them (flat): exactly what ``np.unique`` gives, in time linear in the
    indices and the largest of them.
    """
    flat = np.asarray(indices).reshape(-1)
    if len(flat) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return (empty, empty) if return_inverse else empty
    if flat.min() < 0:  # not vertex numbers: the general road
        return np.unique(flat, return_inverse=return_inverse)
    seen = np.zeros(int(flat.max()) + 1, dtype=bool)
    seen[flat] = True
    used = np.flatnonzero(seen)
    if not return_inverse:
        return used
    rank = np.cumsum(seen) - 1
    return used, rank[flat]


# ----------------------------------------------------------------------------------
# 1. triangulation


def polygon_starts(face_sizes: np.ndarray) -> np.ndarray:
    """Offset of each polygon's first corner in the flat index array."""
    return offsets_of(face_sizes)[:-1]


def split_quads(vertices: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split quadrilaterals into two triangles each, by the rule of Ip et al. (2002).

    Section 3.2.1: from the first corner ``a``, take the vectors to the other three corners
    ``b, c, d``; the widest of the three angles between them is between the two that are not
    the diagonal, and the remaining vector is the one to split along. For a convex
    quadrilateral the widest angle is always ``b-a-d``, and the split is along ``a-c``.

    The rule assumes ``a`` is not a reflex corner: there every angle is measured on the
    wrong side and it would name an edge. So the rule's diagonal is kept whenever it splits
    the quadrilateral into two triangles wound like the quadrilateral (its Newell normal);
    otherwise the other diagonal is used, which for a concave quadrilateral is the one
    through its reflex corner, the only one inside it.

    Parameters
    ----------
    vertices : (n, 3) float
    quads : (q, 4) int
        Corner indices ``a, b, c, d`` in winding order.

    Returns
    -------
    (2q, 3) int
        Triangles with the quadrilateral's winding; those of quad ``i`` are rows ``2i`` and
        ``2i + 1``.
    """
    a, b, c, d = (vertices[quads[:, k]] for k in range(4))

    def unit(v):
        n = np.linalg.norm(v, axis=1, keepdims=True)
        return v / np.where(n > 0, n, 1.0)

    def faces_along(n, p, q, r):
        return np.einsum("ij,ij->i", np.cross(q - p, r - p), n) > 0

    ab, ac, ad = unit(b - a), unit(c - a), unit(d - a)
    cos_bd = np.einsum("ij,ij->i", ab, ad)
    cos_bc = np.einsum("ij,ij->i", ab, ac)
    cos_cd = np.einsum("ij,ij->i", ac, ad)
    rule_says_ac = cos_bd <= np.minimum(cos_bc, cos_cd)  # widest angle: smallest cosine

    normal = np.cross(a, b) + np.cross(b, c) + np.cross(c, d) + np.cross(d, a)  # Newell
    ac_ok = faces_along(normal, a, b, c) & faces_along(normal, a, c, d)
    bd_ok = faces_along(normal, a, b, d) & faces_along(normal, b, c, d)
    along_ac = np.where(rule_says_ac, ac_ok | ~bd_ok, ac_ok & ~bd_ok)

    qa, qb, qc, qd = quads.T
    first = np.where(along_ac[:, None], np.stack([qa, qb, qc], 1), np.stack([qa, qb, qd], 1))
    second = np.where(along_ac[:, None], np.stack([qa, qc, qd], 1), np.stack([qb, qc, qd], 1))
    return np.stack([first, second], axis=1).reshape(-1, 3).astype(np.int64)


def _polygon_frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newell normal and an in-plane basis (e1, e2, normal right-handed) per polygon.

    ``points`` is (k, s, 3); polygons are seen counter-clockwise in (e1, e2) coordinates.
    """
    nxt = np.roll(points, -1, axis=1)
    normal = np.cross(points, nxt).sum(axis=1)  # Newell's method: robust for non-planar
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(length > 0, normal / np.where(length > 0, length, 1), [0.0, 0.0, 1.0])
    # any vector not parallel to the normal
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normal, e1)
    return normal, e1, e2


def _triangulate_ngons(vertices: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Triangulate (k, s) polygons of one size s >= 5; returns (k, s - 2, 3) corner indices.

    Convex, simple polygons (checked in their own plane) are fanned; the others go through
    an ear-clipping triangulator (manifold3d), which handles concave polygons.
    """
    import manifold3d

    k, s = corners.shape
    pts = vertices[corners]
    centre = pts.mean(axis=1, keepdims=True)
    _, e1, e2 = _polygon_frames(pts - centre)
    rel = pts - centre
    uv = np.stack([np.einsum("ksj,kj->ks", rel, e1), np.einsum("ksj,kj->ks", rel, e2)], axis=2)

    edge = np.roll(uv, -1, axis=1) - uv
    nxt = np.roll(edge, -1, axis=1)
    turn = np.arctan2(edge[..., 0] * nxt[..., 1] - edge[..., 1] * nxt[..., 0], np.einsum("ksj,ksj->ks", edge, nxt))
    convex = (turn >= -1e-12).all(axis=1) & (np.abs(turn.sum(axis=1) - 2 * np.pi) < 1e-6)

    fan = np.stack(
        [np.zeros(s - 2, dtype=np.int64), np.arange(1, s - 1), np.arange(2, s)], axis=1
    )  # (s-2, 3) local corner numbers
    local = np.broadcast_to(fan, (k, s - 2, 3)).copy()
    for row in np.flatnonzero(~convex):
        try:
            tri = np.asarray(manifold3d.triangulate([uv[row]]), dtype=np.int64)
        except Exception:
            continue  # keep the fan: degenerate polygon, nothing better to do
        if tri.shape == (s - 2, 3):
            local[row] = tri
    return np.take_along_axis(corners[:, None, :], local.reshape(k, -1)[:, None, :], axis=2).reshape(k, s - 2, 3)


def triangulate_polygons(vertices: np.ndarray, face_sizes: np.ndarray, face_indices: np.ndarray) -> np.ndarray:
    """Triangulate polygons given as sizes and flat corner indices.

    Every polygon of ``s`` corners gives ``s - 2`` triangles (some may be degenerate), in
    polygon order and with the polygon's winding. Quadrilaterals follow :func:`split_quads`;
    larger polygons are triangulated in their best-fit plane, correctly when concave.

    Returns
    -------
    (sum(face_sizes - 2), 3) int64
    """
    face_sizes = np.asarray(face_sizes, dtype=np.int64)
    face_indices = np.asarray(face_indices, dtype=np.int64)
    starts = polygon_starts(face_sizes)
    per_polygon = face_sizes - 2
    out_start = polygon_starts(per_polygon)
    out = np.empty((int(per_polygon.sum()), 3), dtype=np.int64)

    for size in np.unique(face_sizes):
        which = np.flatnonzero(face_sizes == size)
        corners = face_indices[starts[which, None] + np.arange(size)]
        if size == 3:
            out[out_start[which]] = corners
        elif size == 4:
            tri = split_quads(vertices, corners).reshape(-1, 2, 3)
            out[out_start[which]] = tri[:, 0]
            out[out_start[which] + 1] = tri[:, 1]
        else:
            tri = _triangulate_ngons(vertices, corners)
            rows = out_start[which, None] + np.arange(size - 2)
            out[rows.reshape(-1)] = tri.reshape(-1, 3)
    return out


# ----------------------------------------------------------------------------------
# 2. merging and dropping


def merge_vertices(vertices: np.ndarray, faces: np.ndarray, relative_tolerance: float = 1e-9):
    """Merge points that coincide up to ``relative_tolerance`` times the bounding-box diagonal.

    Returns
    -------
    vertices : (n', 3) float64
        The distinct points still used by a face.
    faces : (k, 3) int64
        Re-indexed.
    """
    used, inverse = unique_indices(faces, return_inverse=True)
    points = vertices[used]
    lo, hi = column_min(points), column_max(points)
    step = max(float(np.linalg.norm(hi - lo)), 1e-300) * relative_tolerance
    keys = np.round((points - lo) / step).astype(np.int64)
    first, group = group_rows(keys)
    return points[first], group[inverse].reshape(-1, 3)


#: A part whose typical triangle is smaller than this fraction of its extent is looked at for
#: far pieces (:func:`far_pieces`); real parts' typical triangles are 1e-3 to 1e-1 of it.
FAR_CHECK = 1e-4
#: Pieces this many times the body's size away from it (and beyond) are near it.
NEAR_GAP = 10.0
#: Far pieces are left out when they make the extent this many times the body's.
FAR_EXTENT = 100.0


def far_pieces(vertices: np.ndarray, triangles: np.ndarray):
    """Triangles of pieces far from the part's body: a stray triangle written far away.

    The merging of points (:func:`merge_vertices`) and every tolerance after it follow the
    part's extent; one stray triangle 10^12 away from a 1 mm part would make them 10^3 and
    collapse every real face. So the body is found first, by the local size of the faces:

    * pieces: triangles joined by shared points (exactly equal coordinates);
    * the body: the piece of most triangles, grown by every piece less than
      :data:`NEAR_GAP` times its size away (repeated while it grows);
    * what is left is far, and is left out when it makes the extent more than
      :data:`FAR_EXTENT` times the body's (otherwise it is part of the part, kept).

    Only run when the typical (median) triangle is below :data:`FAR_CHECK` of the extent.

    Returns
    -------
    far : (k,) bool or None
        The triangles to leave out, or None when none are.
    distance : float
        How far the farthest left-out point is from the body's box.
    size : float
        The body's size (largest side of its box).
    """
    if len(triangles) < 2:
        return None, 0.0, 0.0
    corners = vertices[triangles]  # (k, 3, 3)
    # each triangle's box (corner by corner, as numpy's reduction over the corners compares them)
    lo = np.minimum(np.minimum(corners[:, 0], corners[:, 1]), corners[:, 2])
    hi = np.maximum(np.maximum(corners[:, 0], corners[:, 1]), corners[:, 2])
    extent = float(np.max(column_max(hi) - column_min(lo)))
    local = np.max(hi - lo, axis=1)
    if not extent > 0 or float(np.median(local)) >= FAR_CHECK * extent:
        return None, 0.0, 0.0
    used, inverse = unique_indices(triangles, return_inverse=True)
    _, point_group = group_rows(np.ascontiguousarray(vertices[used]).view(np.int64).reshape(len(used), 3))
    corner_group = point_group[inverse].reshape(-1, 3)
    count = int(point_group.max()) + 1
    rows = np.concatenate([corner_group[:, 0], corner_group[:, 1]])
    cols = np.concatenate([corner_group[:, 1], corner_group[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(count, count))
    pieces, label = connected_components(graph, directed=False)
    if pieces < 2:
        return _far_corners(vertices, triangles, used, inverse)
    piece = label[corner_group[:, 0]]
    piece_lo = np.full((pieces, 3), np.inf)
    piece_hi = np.full((pieces, 3), -np.inf)
    np.minimum.at(piece_lo, piece, lo)
    np.maximum.at(piece_hi, piece, hi)
    body = np.zeros(pieces, dtype=bool)
    body[np.argmax(np.bincount(piece, minlength=pieces))] = True
    while True:
        body_lo, body_hi = piece_lo[body].min(axis=0), piece_hi[body].max(axis=0)
        size = float(np.max(body_hi - body_lo))
        gap = np.max(np.maximum(body_lo - piece_hi, piece_lo - body_hi), axis=1)
        near = ~body & (gap <= NEAR_GAP * size)
        if not near.any():
            break
        body |= near
    if body.all() or extent <= FAR_EXTENT * size:
        return _far_corners(vertices, triangles, used, inverse)
    return ~body[piece], float(gap[~body].max()), size


def _far_corners(vertices, triangles, used, inverse):
    """Triangles with a corner far from all other points (a spike: one coordinate written
    1e20 in one triangle of a part): :func:`far_pieces` for one connected piece.

    Along each axis the used points are sorted; where the largest gap between neighbours
    leaves at most ``max(3, 1 %)`` of the points on one side, and is more than
    :data:`FAR_EXTENT` times the extent of the points on the other, those few are far.
    Repeated while it finds some (stray points on several sides).
    """
    points = vertices[used]
    far = np.zeros(len(points), dtype=bool)
    found = True
    while found:
        found = False
        for axis in range(3):
            keep = np.flatnonzero(~far)
            if len(keep) < 5:  # a far point and at least a tetrahedron
                break
            order = keep[np.argsort(points[keep, axis], kind="stable")]
            coords = points[order, axis]
            k = int(np.argmax(np.diff(coords)))
            gap = float(coords[k + 1] - coords[k])
            few, rest = (order[: k + 1], order[k + 1:]) if k + 1 <= len(order) // 2 else (order[k + 1:], order[: k + 1])
            if len(few) > max(3, len(order) // 100):
                continue
            rest_size = float(np.max(points[rest].max(axis=0) - points[rest].min(axis=0)))
            if gap > FAR_EXTENT * rest_size:
                far[few] = True
                found = True
    if not far.any():
        return None, 0.0, 0.0
    body = points[~far]
    lo, hi = body.min(axis=0), body.max(axis=0)
    distance = float(np.max(np.maximum(lo - points[far], points[far] - hi)))
    return far[inverse].reshape(-1, 3).any(axis=1), distance, float(np.max(hi - lo))


def group_rows(rows: np.ndarray):
    """Group equal rows of a 2-D integer array (``np.unique(axis=0)``, several times faster).

    Returns
    -------
    first : (g,) int
        Index of the first row of each group, groups ordered by row value.
    group : (n,) int
        Group of each row.
    """
    if len(rows) == 0:  # the code below would index the first of no rows
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.lexsort(rows.T[::-1])
    ordered = rows[order]
    starts = np.concatenate([[True], np.any(ordered[1:] != ordered[:-1], axis=1)])
    group_sorted = np.cumsum(starts) - 1
    group = np.empty(len(rows), dtype=np.int64)
    group[order] = group_sorted
    first = order[np.flatnonzero(starts)]
    return first, group


def remove_bad_faces(vertices: np.ndarray, faces: np.ndarray, relative_area: float = 1e-14):
    """Drop degenerate triangles (a repeated corner), duplicates (the same three corners) and
    walls between touching bodies (:func:`shared_walls`).

    Of duplicated triangles the first is kept, whatever its winding, unless they are a wall.
    A triangle with three distinct corners but no area (a sliver whose corners lie on one
    line) is kept: exporters write them to close T-junctions, and dropping one would open
    the surface. It gets no sample point (sampling is by area) and Embree never reports a
    hit on it.

    Returns
    -------
    faces : (k', 3) int64
    degenerate : int
        Triangles dropped for a repeated corner.
    duplicate : int
        Triangles dropped as copies of one that is kept.
    flat : int
        Zero-area triangles kept.
    wall : int
        Triangles dropped as walls between touching bodies, every copy counted.
    """
    if len(faces) == 0:
        return faces, 0, 0, 0, 0
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    faces = faces[~repeated]
    if len(faces) == 0:  # every triangle had a repeated corner
        return faces, int(repeated.sum()), 0, 0, 0
    faces = same_quad_diagonals(vertices, faces)
    first, group = group_rows(np.sort(faces, axis=1))
    copies = np.bincount(group, minlength=len(first))
    walls = shared_walls(faces[first], copies)
    wall = int(copies[walls].sum())
    duplicate = len(faces) - len(first) - (wall - int(walls.sum()))
    faces = faces[np.sort(first[~walls])]
    diag2 = float(np.sum((column_max(vertices) - column_min(vertices)) ** 2))
    flat = int(np.sum(triangle_areas(vertices, faces) <= relative_area * diag2))
    return faces, int(repeated.sum()), int(duplicate), flat, int(wall)


def same_quad_diagonals(vertices: np.ndarray, faces: np.ndarray, tolerance: float = 1e-9) -> np.ndarray:
    """Split every planar quadrilateral written more than once along one diagonal.

    Where two separately written bodies touch, each writes the face between them, often as
    a quadrilateral split along its other diagonal. The two copies then share no triangle,
    and :func:`shared_walls` could not see that they are one face written twice. A pair of
    triangles is taken as a written quadrilateral when they share an edge no other triangle
    has, lie in one plane and make a convex quadrilateral, and neither has another such
    partner; quadrilaterals with the same four corners are then all split as the first is.
    The surface is unchanged: both splits cover the same convex planar region, with the
    same outline.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (k, 3) int
        Triangles without a repeated corner.

    Returns
    -------
    (k, 3) int
        ``faces``, with the triangles of repeated quadrilaterals replaced.
    """
    if len(faces) < 4:
        return faces
    h1, h2 = _two_face_edges(faces)
    t1, t2 = h1 // 3, h2 // 3
    slot1, slot2 = h1 % 3, h2 % 3
    u = faces[t1, slot1]
    v = faces[t1, (slot1 + 1) % 3]
    a = faces[t1, (slot1 + 2) % 3]  # t1's corner off the shared edge
    b = faces[t2, (slot2 + 2) % 3]  # t2's
    # only a pair whose four corners another pair also has can be a repeated quadrilateral:
    # the geometry is needed for those and for every pair sharing a triangle with them (has
    # the triangle one partner?); the others are groups of one, which nothing changes
    repeats = _shared_corner_sets(u, v, a, b)
    if not repeats.any():
        return faces
    involved = np.zeros(len(faces), dtype=bool)
    involved[t1[repeats]] = involved[t2[repeats]] = True
    near = involved[t1] | involved[t2]
    t1, t2, u, v, a, b, repeats = t1[near], t2[near], u[near], v[near], a[near], b[near], repeats[near]
    pu, pv, pa, pb = vertices[u], vertices[v], vertices[a], vertices[b]
    scale2 = np.einsum("ij,ij->i", pv - pu, pv - pu)
    n1 = cross3(pv - pu, pa - pu)
    n2 = cross3(pv - pu, pb - pu)
    # one plane: b lies on a's plane; convex: a and b on opposite sides of u-v, u and v of a-b
    height = np.abs(np.einsum("ij,ij->i", n1, pb - pu)) / np.maximum(np.linalg.norm(n1, axis=1), 1e-300)
    flat = height <= tolerance * np.sqrt(scale2)
    opposite_ab = np.einsum("ij,ij->i", n1, n2) < 0
    m1 = cross3(pb - pa, pu - pa)
    m2 = cross3(pb - pa, pv - pa)
    opposite_uv = np.einsum("ij,ij->i", m1, m2) < 0
    quad = flat & opposite_ab & opposite_uv & (a != b)
    t1, t2, u, v, a, b, repeats = t1[quad], t2[quad], u[quad], v[quad], a[quad], b[quad], repeats[quad]
    partners = np.bincount(np.concatenate([t1, t2]), minlength=len(faces))  # exact for the involved triangles
    alone = (partners[t1] == 1) & (partners[t2] == 1) & repeats
    t1, t2, u, v, a, b = t1[alone], t2[alone], u[alone], v[alone], a[alone], b[alone]
    if len(t1) < 2:
        return faces
    corners = np.sort(np.stack([u, v, a, b], axis=1), axis=1)
    first, group = group_rows(corners)
    repeated = np.bincount(group)[group] >= 2
    if not repeated.any():
        return faces
    faces = faces.copy()
    lead = first[group]  # the first quadrilateral written with these corners
    change = repeated & (lead != np.arange(len(t1)))
    faces[t1[change]] = faces[t1[lead[change]]]
    faces[t2[change]] = faces[t2[lead[change]]]
    return faces


def _shared_corner_sets(*corners: np.ndarray) -> np.ndarray:
    """Which rows of the corners (one array per corner) may have the same set of corners as
    another row: a hash of each row's set, the same whatever the order of its corners (a sum
    of one mixing of each), shared with another row. Rows with equal sets are always marked;
    a false mark only costs the full test."""
    mixed = np.zeros(len(corners[0]), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for c in corners:
            x = c.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
            mixed += x ^ (x >> np.uint64(29))
    order = np.argsort(mixed, kind="stable")
    same = mixed[order[1:]] == mixed[order[:-1]]
    marked = np.zeros(len(mixed), dtype=bool)
    marked[order[1:][same]] = marked[order[:-1][same]] = True
    return marked


def shared_walls(faces: np.ndarray, copies: np.ndarray) -> np.ndarray:
    """Which distinct triangles are walls between two touching bodies, to be dropped whole.

    Exporters that write every body (or every face) of a part separately, as KiCad's older
    libraries do, write the face where two bodies touch twice, once for each body: a
    capacitor's end cap against its body. Kept once, that face is a wall inside the united
    solid: three triangles meet at each of its edges, the shells it joins stop being
    closed, and every segment through it counts as crossing the surface (MIXED, when it lies
    in the material). Both copies are the inside of the union and are dropped, when

    * the triangle was written an even number of times (pairs cancel, as two bodies' faces
      do in their union), and
    * its connected patch of such triangles is attached to the rest of the surface, every
      edge of the patch keeping an even number of triangles: two where it was three (the
      two bodies' side faces), none inside the patch.

    So a face written twice inside one closed body (dropping it would open a hole), a
    zero-thickness sheet written once per side and a whole body written twice (nothing
    would remain of it) keep one copy, as before.

    Parameters
    ----------
    faces : (k, 3) int
        Distinct triangles (each written at least once).
    copies : (k,) int
        How many times each was written.

    Returns
    -------
    (k,) bool
        True for the triangles to drop.
    """
    drop = (copies >= 2) & (copies % 2 == 0)
    if not drop.any():
        return drop
    _, _, face, key = _edge_table(faces)
    edge_ids, edge = np.unique(key, return_inverse=True)
    edges = len(edge_ids)
    on_edge = np.bincount(edge, minlength=edges)
    while drop.any():
        dropped = drop[face]
        left = on_edge - np.bincount(edge[dropped], minlength=edges)
        # the patches: dropped triangles joined through edges where nothing else is left
        inner = dropped & (left[edge] == 0)
        rows, cols = face[inner], edge[inner]
        graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols + len(faces))),
                           shape=(len(faces) + edges,) * 2)
        _, label = connected_components(graph, directed=False)
        patch = label[: len(faces)]
        odd = dropped & (left[edge] % 2 == 1)
        attached = dropped & (left[edge] >= 2)
        bad = np.zeros(label.max() + 1, dtype=bool)
        bad[patch[face[odd]]] = True
        has_attachment = np.zeros(label.max() + 1, dtype=bool)
        has_attachment[patch[face[attached]]] = True
        reject = drop & (bad[patch] | ~has_attachment[patch])
        if not reject.any():
            break
        drop &= ~reject
    return drop


# ----------------------------------------------------------------------------------
# 3. shells and consistent winding


@dataclass
class Shells:
    """Faces grouped into shells, with consistent winding inside each shell."""

    faces: np.ndarray  # (k, 3) re-wound
    shell: np.ndarray  # (k,) shell number of each face, 0..count-1
    count: int
    closed: np.ndarray  # (count,) bool: no boundary (every edge traversed equally both ways)
    orientable: np.ndarray  # (count,) bool
    kept_file_winding: np.ndarray  # (count,) fraction of faces whose winding was not changed


def _edge_table(faces: np.ndarray):
    """Half-edges (u -> v) of every face, with an integer key for the undirected edge."""
    k = len(faces)
    u = faces.reshape(-1)
    v = faces[:, [1, 2, 0]].reshape(-1)
    face = np.repeat(np.arange(k), 3)
    lo, hi = np.minimum(u, v), np.maximum(u, v)
    n = int(faces.max()) + 1 if k else 1
    key = lo * n + hi
    return u, v, face, key


def _two_face_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges that exactly two triangles share, as their two half-edges (indices into
    :func:`_edge_table`'s arrays: half-edge ``h`` is side ``h % 3`` of face ``h // 3``)."""
    _, _, _, key = _edge_table(faces)
    order = np.argsort(key, kind="stable")
    skey = key[order]
    start = np.flatnonzero(np.concatenate([[True], skey[1:] != skey[:-1]]))
    size = np.diff(np.concatenate([start, [len(skey)]]))
    two = start[size == 2]
    return order[two], order[two + 1]


def orient_shells(faces: np.ndarray) -> Shells:
    """Split faces into shells and make the winding consistent within each.

    Two faces are neighbours when they share an edge that has exactly two faces in the whole
    mesh (non-manifold edges do not join shells). Neighbours are consistently wound when
    they traverse the shared edge in opposite directions. Finding which faces to flip is a
    two-colouring of a signed graph, solved for all shells at once as connected components
    of the doubled graph whose nodes are (face, flipped?): node ``f`` is face ``f`` as read,
    node ``f + k`` the same face flipped.
    """
    k = len(faces)
    u, _, face, _ = _edge_table(faces)
    h1, h2 = _two_face_edges(faces)
    f1, f2 = face[h1], face[h2]
    must_flip_one = u[h1] == u[h2]  # both traverse the shared edge the same way

    partner = f2 + k * must_flip_one
    rows = np.concatenate([f1, f1 + k])
    cols = np.concatenate([partner, (partner + k) % (2 * k)])
    doubled = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(2 * k, 2 * k))
    _, label = connected_components(doubled, directed=False)
    as_read, flipped = label[:k], label[k:]
    orientable_face = as_read != flipped
    flip = orientable_face & (as_read > flipped)  # canonical choice: the smaller label is kept

    new_faces = flip_faces(faces, flip)

    plain = coo_matrix((np.ones(len(f1), dtype=np.int8), (f1, f2)), shape=(k, k))
    count, shell = connected_components(plain, directed=False)

    orientable = np.bincount(shell, weights=~orientable_face, minlength=count) == 0  # no face that is not
    kept = np.bincount(shell, weights=(~flip).astype(float), minlength=count) / np.bincount(shell, minlength=count)
    closed = _closed_shells(new_faces, shell, count) & orientable
    return Shells(new_faces, shell, count, closed, orientable, kept)


def _closed_shells(faces: np.ndarray, shell: np.ndarray, count: int) -> np.ndarray:
    """Per shell: is it closed, i.e. is every edge traversed as often in one direction as in
    the other by the shell's faces? Then the shell has no boundary and encloses a volume
    (its winding number is a whole number everywhere), also where two parts of it touch
    along an edge that four faces share."""
    u, v, face, key = _edge_table(faces)
    owner = shell[face]
    order = np.lexsort((key, owner))
    skey, sowner = key[order], owner[order]
    forward = (u < v)[order].astype(np.int64)
    new_group = np.concatenate([[True], (skey[1:] != skey[:-1]) | (sowner[1:] != sowner[:-1])])
    start = np.flatnonzero(new_group)
    size = np.diff(np.concatenate([start, [len(skey)]]))
    n_forward = np.add.reduceat(forward, start)
    good_edge = 2 * n_forward == size
    return np.bincount(sowner[start], weights=~good_edge, minlength=count) == 0  # no bad edge
