"""Object File Format (OFF, COFF, NOFF...): counts, vertices, then polygons."""

from __future__ import annotations

import numpy as np

from ..errors import LoadError
from .base import Format, LoadLimits, PolygonMesh, head_of
from .formats import SUFFIXES
from .text import decode_text


def read_off(path, data: bytes, limits: LoadLimits | None = None) -> PolygonMesh:
    """Read OFF bytes. Colours and normals after the coordinates are ignored."""
    lines = []
    for number, raw in enumerate(decode_text(data).splitlines(), start=1):
        text = raw.split("#", 1)[0].split()
        if text:
            lines.append((number, text))
    if not lines or not lines[0][1][0].upper().endswith("OFF"):
        raise LoadError(path, "missing OFF header")
    header_line, header = lines[0]
    rest = lines[1:]
    counts = header[1:]
    if len(counts) < 2:
        if not rest:
            raise LoadError(path, "missing vertex and face counts", header_line)
        header_line, counts = rest[0]
        rest = rest[1:]
    try:
        n_vertices, n_faces = int(counts[0]), int(counts[1])
    except (ValueError, IndexError):
        raise LoadError(path, f"bad vertex/face counts {' '.join(counts)!r}", header_line) from None
    if n_vertices < 0 or n_faces < 0 or n_vertices + n_faces > len(rest):
        raise LoadError(
            path,
            f"announces {n_vertices:,} vertices and {n_faces:,} faces but has only {len(rest):,} data lines",
            header_line,
        )
    try:
        points = np.array([fields[:3] for _, fields in rest[:n_vertices]], dtype=np.float64)
    except ValueError:
        raise LoadError(path, "vertex line that is not three numbers", rest[0][0]) from None
    sizes, corners, skipped = [], [], 0
    for number, fields in rest[n_vertices : n_vertices + n_faces]:
        try:
            size = int(fields[0])
            refs = [int(x) for x in fields[1 : 1 + size]]
        except ValueError:
            raise LoadError(path, "face line that is not integers", number) from None
        if size < 3 or len(refs) != size or min(refs) < 0 or max(refs) >= n_vertices:
            skipped += 1
            continue
        sizes.append(size)
        corners.extend(refs)
    warnings = [f"{skipped} face(s) with fewer than three corners or out-of-range indices skipped"] if skipped else []
    return PolygonMesh(points.reshape(-1, 3), np.array(sizes, dtype=np.int64), np.array(corners, dtype=np.int64), "off", warnings)


def declared_off(data: bytes) -> tuple[int, int]:
    """Faces and vertices the OFF header announces (bounded by what the bytes can hold:
    a face line takes at least 8 bytes, a vertex line 6); (0, 0) when it cannot be read."""
    fields: list[bytes] = []
    for line in data[:4096].splitlines():
        fields += line.split(b"#", 1)[0].split()
        if len(fields) >= 3:
            break
    try:
        vertices, faces = int(fields[1]), int(fields[2])
    except (IndexError, ValueError):
        return 0, 0
    return max(0, min(faces, len(data) // 8)), max(0, min(vertices, len(data) // 6))


FORMATS = [Format("off", "OFF", SUFFIXES["off"], read_off, declared=declared_off, sniff=lambda data: head_of(data)[:3] == b"OFF" or head_of(data)[:4] in (b"COFF", b"NOFF"))]
