"""Polygon meshes as the part splitters need them: fanned into triangles, areas, rows by label.

Shared by :mod:`shapeidx.io.parts` (a file's connected bodies) and :mod:`shapeidx.io.vrml.groups`
(a VRML file's groups), which need only connectivity and areas, not the signature's clean mesh.
"""

from __future__ import annotations

import numpy as np

from .base import PolygonMesh


def members_of(labels: np.ndarray) -> list[np.ndarray]:
    """The indices holding each label, label by label (one sort: a mesh of a million separate
    triangles has a million labels)."""
    labels = np.asarray(labels)
    if len(labels) == 0:
        return []
    order = np.argsort(labels, kind="stable")
    cuts = np.flatnonzero(np.diff(labels[order])) + 1
    return np.split(order, cuts)


def fan_triangles(mesh: PolygonMesh) -> np.ndarray:
    """Polygons fanned into triangles (the split needs only connectivity and areas)."""
    sizes = np.asarray(mesh.face_sizes, dtype=np.int64)
    corners = np.asarray(mesh.face_indices, dtype=np.int64)
    if len(sizes) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    fans = sizes - 2
    first = np.repeat(starts, fans)
    step = np.arange(int(fans.sum())) - np.repeat(np.cumsum(fans) - fans, fans)
    return np.stack([corners[first], corners[first + step + 1], corners[first + step + 2]], axis=1)


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The area of each triangle (rows of vertex indices)."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
