"""Helpers shared by the VRML tests (no tests here).

Measures follow what ``shapeidx inspect --json`` reports: the file's polygons as read,
triangulated by :func:`shapeidx.signing.mesh.triangulate_polygons`, before any cleaning.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shapeidx.io import LoadLimits
from shapeidx.io.vrml import load_vrml
from shapeidx.signing.mesh import signed_volumes, triangle_areas, triangulate_polygons

FIXTURES = Path(__file__).parent / "data" / "vrml"

#: The unit cube [0,1]^3 as six counter-clockwise quadrilaterals (area 6, volume 1).
CUBE_POINTS = "0 0 0, 1 0 0, 1 1 0, 0 1 0, 0 0 1, 1 0 1, 1 1 1, 0 1 1"
CUBE_INDEX = "0 3 2 1 -1, 4 5 6 7 -1, 0 1 5 4 -1, 3 7 6 2 -1, 0 4 7 3 -1, 1 2 6 5 -1"
#: The same faces listed clockwise seen from outside (each polygon reversed).
CUBE_INDEX_CLOCKWISE = "0 1 2 3 -1, 7 6 5 4 -1, 4 5 1 0 -1, 2 6 7 3 -1, 3 7 4 0 -1, 5 6 2 1 -1"
CUBE_SHAPE = (
    f"Shape {{ geometry IndexedFaceSet {{ coord Coordinate {{ point [ {CUBE_POINTS} ] }} "
    f"coordIndex [ {CUBE_INDEX} ] }} }}"
)


def vrml2(body: str) -> str:
    return "#VRML V2.0 utf8\n" + body + "\n"


def vrml1(body: str) -> str:
    return "#VRML V1.0 ascii\n" + body + "\n"


def write(tmp_path: Path, text: str | bytes, name: str = "part.wrl") -> Path:
    """Write ``text`` to ``tmp_path/name`` (folders made as needed)."""
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def read(tmp_path: Path, text: str | bytes, name: str = "part.wrl", limits: LoadLimits | None = None):
    """Write ``text`` to ``tmp_path/name`` and load it with the VRML reader."""
    return load_vrml(write(tmp_path, text, name), limits or LoadLimits())


def measure(mesh) -> tuple[int, float, float]:
    """(triangles, area, signed volume) of a loaded mesh, polygons as read.

    The signed volume is positive when the polygons are wound counter-clockwise seen
    from outside (for a closed surface).
    """
    triangles = triangulate_polygons(mesh.vertices, mesh.face_sizes, mesh.face_indices)
    if len(triangles) == 0:
        return 0, 0.0, 0.0
    area = float(triangle_areas(mesh.vertices, triangles).sum())
    volume = float(signed_volumes(mesh.vertices, triangles).sum())
    return len(triangles), area, volume


def bounds(mesh) -> np.ndarray:
    """(2, 3): the lowest and the highest corner of the vertices."""
    return np.stack([mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)])
