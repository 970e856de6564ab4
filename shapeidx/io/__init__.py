"""Readers: one module per format family, one entry point, :func:`load`.

Every reader returns a :class:`PolygonMesh` (vertices and polygons, as the file says)
or raises :class:`~shapeidx.errors.LoadError` with a one-line reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import LoadError, OutOfMemory
from . import obj, off, ply, stl, vrml
from .base import LoadLimits, PolygonMesh, read_bytes, without_float_warnings

#: File name endings each reader handles (compared in lower case).
SUFFIX_FORMATS = {
    ".stl": "stl",
    ".obj": "obj",
    ".off": "off",
    ".ply": "ply",
    ".wrl": "vrml",
    ".wrz": "vrml",
    ".vrml": "vrml",
}

__all__ = ["LoadLimits", "PolygonMesh", "SUFFIX_FORMATS", "format_of", "load", "read_bytes"]


def format_of(path: str | os.PathLike) -> str | None:
    """The reader for ``path`` judged by its name (case-insensitive, ``.gz`` allowed), or None."""
    name = Path(path).name.lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return SUFFIX_FORMATS.get(Path(name).suffix)


@without_float_warnings
def load(path: str | os.PathLike, limits: LoadLimits | None = None) -> PolygonMesh:
    """Read a part file into a :class:`PolygonMesh`.

    The reader is chosen by the file name; a name without a known ending is sniffed from
    its first bytes. gzip compression is detected from the content for every format.

    Raises
    ------
    LoadError
        Anything that keeps the file from being read, as one line naming the file.
    """
    limits = limits or LoadLimits()
    path = Path(path)
    _check_is_a_nonempty_file(path)
    fmt = format_of(path)
    try:
        if fmt == "vrml":
            mesh = vrml.load_vrml(path, limits)
        else:
            data, _ = read_bytes(path, limits)
            fmt = fmt or _sniff(path, data)
            if fmt == "vrml":
                mesh = vrml.load_vrml(path, limits)
            else:
                mesh = _READERS[fmt](path, data)
    except LoadError:
        raise
    except MemoryError:
        raise OutOfMemory(path, "out of memory while reading") from None
    except RecursionError:
        raise LoadError(path, "nesting too deep to read") from None
    except Exception as exc:  # a reader bug must still end as one line, never a traceback
        raise LoadError(path, f"cannot read ({type(exc).__name__}: {exc})") from None
    check_polygon_mesh(path, mesh, limits)
    return mesh


def _check_is_a_nonempty_file(path: Path) -> None:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise LoadError(path, "no such file") from None
    except OSError as exc:
        raise LoadError(path, f"cannot read: {exc.strerror or exc}") from None
    if path.is_dir():
        raise LoadError(path, "is a directory, not a file")
    if size == 0:
        raise LoadError(path, "is empty (0 bytes)")


def check_polygon_mesh(path, mesh: PolygonMesh, limits: LoadLimits) -> None:
    """Refuse what no later stage can use: no polygons, non-finite or too many triangles."""
    if len(mesh.face_sizes) == 0:
        raise LoadError(path, "contains no polygons (empty or not a surface mesh)")
    triangles = int(np.sum(mesh.face_sizes) - 2 * len(mesh.face_sizes))
    if triangles > limits.max_triangles:
        raise LoadError(
            path,
            f"would give {triangles:,} triangles, more than the limit of {limits.max_triangles:,}",
        )
    limits.check_memory(path, triangles, len(mesh.vertices))
    largest = int(np.max(mesh.face_sizes))
    if largest > limits.max_polygon_corners:
        raise LoadError(
            path,
            f"has a polygon of {largest:,} corners, more than the limit of {limits.max_polygon_corners:,} "
            f"(refused: triangulating it would take too long)",
        )
    if not np.isfinite(mesh.vertices).all():
        raise LoadError(path, "has NaN or infinite vertex coordinates (as written, or overflowing when transformed)")


def _sniff(path: Path, data: bytes) -> str:
    head = data[:512].lstrip()
    if head.startswith(b"#VRML") or head.startswith(b"#Inventor"):
        return "vrml"
    if head[:3].lower() == b"ply":
        return "ply"
    if head[:3] == b"OFF" or head[:4] in (b"COFF", b"NOFF"):
        return "off"
    if head[:5].lower() == b"solid" or len(data) >= 84:
        return "stl"
    raise LoadError(path, "unknown file type (expected STL, OBJ, OFF, PLY or VRML)")


_READERS = {"stl": stl.read_stl, "obj": obj.read_obj, "off": off.read_off, "ply": ply.read_ply}
