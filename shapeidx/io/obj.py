"""Wavefront OBJ: ``v`` and ``f`` records; polygons kept as written."""

from __future__ import annotations

import numpy as np

from ..errors import LoadError
from .base import Format, LoadLimits, PolygonMesh
from .formats import SUFFIXES
from .text import decode_text


def read_obj(path, data: bytes, limits: LoadLimits | None = None) -> PolygonMesh:
    """Read OBJ bytes. Face corners ``v``, ``v/t``, ``v//n`` and ``v/t/n`` are accepted;
    negative indices count back from the latest vertex, as the format says."""
    vertices: list[tuple[list[str], int]] = []  # coordinates as text, line number
    sizes: list[int] = []
    corners: list[int] = []
    warnings: list[str] = []
    skipped = 0
    for number, line in enumerate(decode_text(data).splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        tag = fields[0]
        if tag == "v":
            if len(fields) < 4:
                raise LoadError(path, "vertex with fewer than three coordinates", number)
            vertices.append((fields[1:4], number))
        elif tag == "f":
            try:
                refs = [int(f.split("/", 1)[0]) for f in fields[1:]]
            except ValueError:
                raise LoadError(path, f"face corner is not an index: {line.strip()[:60]!r}", number) from None
            count = len(vertices)
            refs = [r - 1 if r > 0 else count + r for r in refs]
            if len(refs) < 3 or min(refs) < 0 or max(refs) >= count:
                skipped += 1
                continue
            sizes.append(len(refs))
            corners.extend(refs)
    if skipped:
        warnings.append(f"{skipped} face(s) with fewer than three corners or out-of-range indices skipped")
    try:
        points = np.array([v for v, _ in vertices], dtype=np.float64).reshape(-1, 3)
    except ValueError:
        fields, number = next((v, n) for v, n in vertices if not _all_numbers(v))
        raise LoadError(path, f"vertex coordinate is not a number: {' '.join(fields)!r}", number) from None
    return PolygonMesh(points, np.array(sizes, dtype=np.int64), np.array(corners, dtype=np.int64), "obj", warnings)


def _all_numbers(fields: list[str]) -> bool:
    try:
        [float(f) for f in fields]
    except ValueError:
        return False
    return True


def declared_obj(data: bytes) -> tuple[int, int]:
    """Faces (``f`` records: each gives a triangle at least) and vertices (``v`` records),
    counted in C over the bytes."""
    head = data[:2]
    faces = data.count(b"\nf ") + data.count(b"\nf\t") + (head in (b"f ", b"f\t"))
    vertices = data.count(b"\nv ") + data.count(b"\nv\t") + (head in (b"v ", b"v\t"))
    return faces, vertices


FORMATS = [Format("obj", "OBJ", SUFFIXES["obj"], read_obj, declared=declared_obj)]
