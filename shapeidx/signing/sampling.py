"""Random points on a surface, uniform by area (Ip et al. 2002, section 3.2.1)."""

from __future__ import annotations

import numpy as np

from .mesh import triangle_areas
from .parameters import DEFAULT_SEED


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = DEFAULT_SEED):
    """Place ``count`` points uniformly at random on a triangle surface.

    As in Ip et al. (2002, section 3.2.1) and Osada et al. (2002): a triangle is chosen with
    probability proportional to its area, by binary search of a uniform number in the array
    of cumulative areas; the point inside it is

    .. math:: p = (1 - \\sqrt{r_1}) A + \\sqrt{r_1} (1 - r_2) B + \\sqrt{r_1} r_2 C.

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
    rng = np.random.Generator(np.random.PCG64(seed))
    cumulative = np.cumsum(triangle_areas(vertices, faces))
    pick = rng.random(count) * cumulative[-1]
    face_index = np.minimum(np.searchsorted(cumulative, pick, side="right"), len(faces) - 1)
    r1, r2 = rng.random((2, count))
    s = np.sqrt(r1)[:, None]
    a, b, c = (vertices[faces[face_index, k]] for k in range(3))
    points = (1 - s) * a + s * (1 - r2[:, None]) * b + s * r2[:, None] * c
    return points, face_index
