"""IN / OUT / MIXED classification of every pair of surface points (Ip et al. 2002, 3.2.3).

The solid is a closed set. A segment between two surface points is

* IN when every point of it lies in the solid (segments lying on a face are IN),
* OUT when no point of its open interior lies in the solid,
* MIXED otherwise.

How it is decided, without a Python loop over pairs:

1. At each end, the segment either enters the material or leaves it; the face normal
   there says which (``cos = direction . normal``). A segment that runs along its face
   (``|cos|`` below :data:`TANGENT`) is taken as entering: it lies on the surface, which
   belongs to the solid.
2. Ends that disagree (one enters, the other leaves) make the segment MIXED: it must cross
   the surface in between. No ray is needed.
3. Ends that agree: the segment is IN (or OUT) unless the surface is crossed in between.
   One Embree occlusion query answers that, on the segment moved off the surface by
   :data:`OFFSET` (times the bounding-box diagonal) to the side it runs on: inward for IN
   candidates, outward for OUT ones. The shift keeps the query clear of the segment's own
   faces (no self-hits at the ends, also for tangent segments) and well above float32
   rounding. A segment on a face that then passes over a hole becomes a shifted segment
   that crosses the hole's wall: MIXED, as it should be.

All of this needs normals that point away from the material, which
:func:`shapeidx.signing.solid.make_solid` gives every closed solid. For a surface that is not
watertight, each sample's normal is turned by generalized winding numbers instead (toward
the side with the lower winding number), then the same logic applies. Testing the winding
number at the midpoint of every uncrossed segment as well was measured on the open meshes
of mesh-wild: it changed the class of under 0.1% of pairs on real parts, at 5 to 20 times
the cost, and only disagreed on zero-volume sheets (where IN, the closed-set answer, holds).

Geometry is moved to the origin and scaled to a unit diagonal before it reaches Embree, so
float32 precision is the same for a 1 mm chip and a 10 m frame far from the origin.

Steps 1 to 3 run in one compiled loop per row of pairs (``_pairs.c``, through
:class:`~shapeidx.signing.occlusion.NativeScene`), with the numpy code below as its twin
where the extension is missing: the same float32 and float64 operations in the same order,
so the same classes bit for bit (tests/test_compiled_pairs.py).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial.distance import pdist

from ..io.base import column_max, column_min
from .mesh import unit_normals
from .occlusion import NativeScene, OcclusionScene, thread_pool, native_pairs
from .sampling import z_order
from .parameters import CLASS_NAMES, IN, MIXED, OUT  # noqa: F401 (re-exported: the class codes)

assert (IN, OUT) == (0, 1)  # classify_pairs writes an agreeing pair's "leaves the material" flag as its class

#: Shift of query segments off the surface, relative to the bounding-box diagonal.
OFFSET = 1e-5
#: A segment whose direction makes |cos| < TANGENT with its face normal runs along the face.
TANGENT = 1e-3
#: Probe distance for the winding-number side test on open surfaces (relative to diagonal).
PROBE = 1e-4


@lru_cache(maxsize=4)
def pair_flat_indices(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat positions of the pairs ``i < j`` in a (count, count) matrix: ``i * count + j``
    and the transposed ``j * count + i`` (read-only arrays)."""
    first, second = pair_indices(count)
    upper = first.astype(np.int64) * count + second
    lower = second.astype(np.int64) * count + first
    upper.flags.writeable = False
    lower.flags.writeable = False
    return upper, lower


@lru_cache(maxsize=4)
def pair_indices(count: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``count * (count - 1) / 2`` pairs ``i < j``, row by row (read-only arrays)."""
    i, j = np.triu_indices(count, k=1)
    i, j = i.astype(np.int32), j.astype(np.int32)
    i.flags.writeable = False
    j.flags.writeable = False
    return i, j


#: Rows of the pair matrix handled at once by :func:`pair_blocks`' users: a block of
#: 64 x 1024 float64 values (512 KiB) stays in a core's cache between the passes over it.
BLOCK_ROWS = 64


@lru_cache(maxsize=4)
def pair_blocks(count: int, rows: int = BLOCK_ROWS) -> tuple:
    """The pairs ``i < j`` in blocks of rows, for pair-matrix work that stays in cache.

    Returns a tuple of ``(first, stop_row, local, start, stop)``: the pairs ``start:stop``
    (in :func:`pair_indices` order) are those with ``first <= i < stop_row``, and ``local``
    is where each lies in the flattened ``(stop_row - first, count - first)`` block of rows
    ``first..stop_row - 1`` and columns ``first..count - 1`` (read-only).
    """
    blocks = []
    start = 0
    for first in range(0, count, rows):
        stop_row = min(count, first + rows)
        width = count - first
        local = np.concatenate([(i - first) * width + np.arange(i + 1 - first, width) for i in range(first, stop_row)])
        local.flags.writeable = False
        blocks.append((first, stop_row, local, start, start + len(local)))
        start += len(local)
    return tuple(blocks)


def normalise(vertices: np.ndarray, points: np.ndarray):
    """Centre on the bounding box and scale to a unit diagonal; returns (vertices, points, scale)."""
    lo, hi = column_min(vertices), column_max(vertices)
    centre = (lo + hi) / 2
    diagonal = float(np.linalg.norm(hi - lo))
    scale = 1.0 / diagonal if diagonal > 0 else 1.0
    return (vertices - centre) * scale, (points - centre) * scale, scale


def classify_pairs(
    vertices: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    face_index: np.ndarray,
    watertight: bool,
    scene: OcclusionScene | None = None,
    threads: int = 1,
    normals_out: list | None = None,
):
    """Distance and class of every pair of sample points.

    Parameters
    ----------
    vertices, faces
        The solid's surface, wound so that normals point away from the material.
    points : (m, 3) float
        Surface samples, from :func:`shapeidx.signing.sampling.sample_surface`.
    face_index : (m,) int
        The triangle of each sample.
    watertight : bool
        False orients each sample's normal by generalized winding numbers.
    scene : OcclusionScene, optional
        Built from the normalised surface when not given (pass one to reuse it).
    threads : int
        Threads for the Embree queries (1 in build workers, which already use every core).
    normals_out : list, optional
        Receives the samples' outward unit normals ((m, 3) float64), which the normal-angle
        histograms (:mod:`shapeidx.signing.angles`) need.

    Returns
    -------
    distances : (m(m-1)/2,) float64
        In the part's own units, pairs in :func:`pair_indices` order.
    classes : (m(m-1)/2,) uint8
        :data:`IN`, :data:`OUT` or :data:`MIXED`.
    """
    vertices, points, scale = normalise(np.asarray(vertices, float), np.asarray(points, float))
    normals = unit_normals(vertices, faces[face_index])
    if scene is None:
        scene = NativeScene(vertices, faces) if native_pairs() is not None else OcclusionScene(vertices, faces)

    if not watertight:
        normals = _orient_by_winding(points, normals, vertices, faces)
    if normals_out is not None:
        normals_out.append(normals)
    if isinstance(scene, NativeScene):
        return _classify_compiled(scene, points, normals, scale, threads)

    m = len(points)
    first, second = pair_indices(m)
    distance = pdist(points)  # float64, in pair_indices order

    # rise[a, b] = (p_a - p_b) . n_b: how far p_a lies above the plane of b's face. Three
    # small outer products serve every pair; float32 is ample for a sign test against
    # TANGENT. (BLAS is no faster for an inner dimension of 3 and wakes threads.) A pair
    # (i, j) needs rise[i, j] and rise[j, i]: both are computed by blocks of rows i (the
    # second as its transpose, products commute: the same numbers), so that each block's
    # values are compared while still in cache and only the upper triangle is computed.
    # the segment leaves the material at its end j when p_i lies above j's plane with
    # cos >= TANGENT (and at i when p_j lies above i's); coincident points stay IN
    p32, n32, own, shifted = _float32_ends(points, normals)
    threshold = (TANGENT * distance).astype(np.float32)
    leaves_second = np.empty(len(distance), dtype=bool)
    leaves_first = np.empty(len(distance), dtype=bool)
    for row, stop_row, local, start, stop in pair_blocks(m):
        p_i, n_i, p_j, n_j = p32[row:stop_row], n32[row:stop_row], p32[row:], n32[row:]
        rise = np.multiply.outer(p_i[:, 0], n_j[:, 0])  # rise[i, j]
        rise += np.multiply.outer(p_i[:, 1], n_j[:, 1])
        rise += np.multiply.outer(p_i[:, 2], n_j[:, 2])
        rise -= own[None, row:]
        rise_back = np.multiply.outer(n_i[:, 0], p_j[:, 0])  # rise[j, i]
        rise_back += np.multiply.outer(n_i[:, 1], p_j[:, 1])
        rise_back += np.multiply.outer(n_i[:, 2], p_j[:, 2])
        rise_back -= own[row:stop_row, None]
        np.greater(rise.ravel()[local], threshold[start:stop], out=leaves_second[start:stop])
        np.greater(rise_back.ravel()[local], threshold[start:stop], out=leaves_first[start:stop])

    agree = np.flatnonzero(leaves_first == leaves_second)
    outward = leaves_first[agree]
    row_shift = np.where(outward, np.int32(m), np.int32(0))
    clear = ~scene.blocked_between(shifted, first[agree] + row_shift, second[agree] + row_shift, threads)

    # IN is 0 and OUT 1: an agreeing pair's class is its "outward", unless the surface is crossed
    classes = np.full(len(distance), MIXED, dtype=np.uint8)
    classes[agree] = np.where(clear, outward.view(np.uint8), np.uint8(MIXED))
    return distance / scale, classes


def _float32_ends(points: np.ndarray, normals: np.ndarray):
    """What both roads of the end tests read, made once so that they read the same numbers:
    points and normals as float32, each point's ``p . n`` (float32), and the points moved
    off the surface, inward (rows 0..m-1) and outward (rows m..2m-1), as float32."""
    p32, n32 = points.astype(np.float32), normals.astype(np.float32)
    own = np.einsum("ij,ij->i", p32, n32)
    shifted = np.concatenate([points - OFFSET * normals, points + OFFSET * normals]).astype(np.float32)
    return p32, n32, own, shifted


def spatial_order(points: np.ndarray) -> np.ndarray:
    """The points' indices in Morton (Z-curve) order (:func:`~shapeidx.signing.sampling.z_order`):
    points near each other come near each other, so rays to them run side by side."""
    return z_order(points).astype(np.int32)


def _classify_compiled(scene, points, normals, scale, threads: int, packets: bool = True):
    """:func:`classify_pairs`' pair pass in one compiled loop (shapeidx/signing/_pairs.c):
    the same tests in the same float32 and float64 steps, so the same classes and distances.

    Embree gets the agreeing pairs' rays in packets of 16 from one origin, each row's pairs
    taken in :func:`spatial_order` so that a packet's rays run side by side (on 40 library
    parts: 0.79 of the time of one ray at a time in row order; ``packets=False`` sends them
    one at a time, for the tests).
    """
    m = len(points)
    if m < 2:
        return np.zeros(0), np.zeros(0, dtype=np.uint8)
    points = np.ascontiguousarray(points, dtype=np.float64)
    p32, n32, own, shifted = _float32_ends(points, normals)
    distance = np.empty(m * (m - 1) // 2)
    classes = np.empty(len(distance), dtype=np.uint8)
    order = spatial_order(points)

    def rows(first, stop):
        scene.classify(points, p32, n32, own, shifted, order, TANGENT, scale, first, stop, distance, classes, packets)

    if threads <= 1 or m < 200:
        rows(0, m)
    else:  # row i holds m - 1 - i pairs: cut the rows where the pair count is shared evenly
        done = np.cumsum(np.arange(m - 1, -1, -1))
        cuts = [0, *np.searchsorted(done, [len(distance) * k / threads for k in range(1, threads)]).tolist(), m]
        list(thread_pool(threads).map(rows, cuts[:-1], cuts[1:]))
    return distance, classes


def _orient_by_winding(points, normals, vertices, faces):
    """Point each sample's normal to the side with the lower winding number (outside)."""
    from .solid import winding_numbers

    probes = np.concatenate([points + PROBE * normals, points - PROBE * normals])
    w_front, w_back = np.split(winding_numbers(vertices, faces, probes), 2)
    return np.where((w_front > w_back)[:, None], -normals, normals)
