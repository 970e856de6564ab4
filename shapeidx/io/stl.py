"""STL, binary and ASCII (several solids allowed)."""

from __future__ import annotations

import re

import numpy as np

from ..errors import LoadError
from .base import Format, LoadLimits, PolygonMesh, head_of
from .formats import SUFFIXES

_BINARY_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_ASCII_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)", re.IGNORECASE)  # some exporters write VERTEX


def read_stl(path, data: bytes, limits: LoadLimits | None = None) -> PolygonMesh:
    """Read STL bytes; binary is recognised by its exact length, whatever the header says."""
    if len(data) >= 84:
        count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        if len(data) == 84 + 50 * count:
            records = np.frombuffer(data, dtype=_BINARY_RECORD, count=count, offset=84)
            return _from_corners(path, records["corners"].astype(np.float64), "stl")
    if data.lstrip()[:5].lower() == b"solid":
        return _read_ascii(path, data)
    if len(data) < 84:
        raise LoadError(path, f"too short for an STL file ({len(data)} bytes)")
    count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
    raise LoadError(
        path, f"binary STL header announces {count:,} triangles but the file holds {(len(data) - 84) / 50:,.1f}"
    )


def _read_ascii(path, data: bytes) -> PolygonMesh:
    found = _ASCII_VERTEX.findall(data)
    if len(found) % 3:
        raise LoadError(path, f"ASCII STL has {len(found)} vertices, not a multiple of three")
    try:
        corners = np.array(found, dtype=np.float64).reshape(-1, 3, 3)
    except ValueError:
        bad = next(f for v in found for f in v if not _is_number(f))
        from ..errors import quoted_bytes

        raise LoadError(path, f"ASCII STL has a vertex coordinate that is not a number: {quoted_bytes(bad[:40])}") from None
    return _from_corners(path, corners, "stl")


def _is_number(text: bytes) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _from_corners(path, corners: np.ndarray, fmt: str) -> PolygonMesh:
    if len(corners) == 0:
        raise LoadError(path, "STL file contains no triangles")
    vertices = corners.reshape(-1, 3)
    return PolygonMesh.from_triangles(vertices, np.arange(len(vertices)).reshape(-1, 3), fmt)


def declared_stl(data: bytes) -> tuple[int, int]:
    """Triangles: the binary header's count when the length agrees with it, else ASCII
    ``endfacet`` records (counted in C); three vertices each."""
    if len(data) >= 84:
        count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        if len(data) == 84 + 50 * count:
            return count, 3 * count
    count = data.count(b"endfacet") + data.count(b"ENDFACET")
    return count, 3 * count


FORMATS = [Format("stl", "STL", SUFFIXES["stl"], read_stl, declared=declared_stl, sniff=lambda data: head_of(data)[:5].lower() == b"solid" or len(data) >= 84, weak=True)]
