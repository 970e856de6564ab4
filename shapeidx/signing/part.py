"""A part in whatever form the caller has it -> a clean, oriented triangle mesh (:class:`Solid`).

The one place that knows the forms a part comes in (every command, the Python API, the web
page's uploads and the search road take parts through it):

* a path (``str`` or :class:`os.PathLike`) of a file in any format of :mod:`shapeidx.io`;
* a binary file object (``open(path, "rb")``, :class:`io.BytesIO`, a web upload), with
  ``file_type`` naming its format when its content does not say (OBJ has no magic number);
* a ``(vertices, faces)`` pair of arrays: (n, 3) coordinates and (k, 3) triangle indices;
* a :class:`trimesh.Trimesh` (anything with ``vertices`` and ``faces``);
* a :class:`~shapeidx.signing.solid.Solid`, returned as it is.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import LoadError

#: Name given in errors to a file object that has no ``name``.
STREAM_NAME = "<stream>"


def load_part(part, file_type: str | None = None, limits=None):
    """Load a part and make it a clean, oriented triangle mesh (the paper's step 1).

    Polygons are triangulated, duplicate points merged, degenerate faces dropped, shells
    oriented outward and overlapping shells united (see ``docs/method.md``).

    Parameters
    ----------
    part : path, binary file object, (vertices, faces), trimesh.Trimesh or Solid
    file_type : str, optional
        Format name (one of ``shapeidx.io.formats.FORMAT_NAMES``: ``"stl"``, ``"step"``, ...)
        for a path or file object whose name or content does not tell it.
    limits : shapeidx.io.LoadLimits, optional
        Bounds on what a hostile file may make the reader do.

    Returns
    -------
    Solid
        ``vertices`` (n, 3), ``faces`` (k, 3), ``watertight``, ``volume``, ``area``,
        ``bounds``, ``warnings`` and ``describe()`` (what ``shapeidx inspect`` prints).

    Raises
    ------
    LoadError
        The part cannot be read or has no usable surface.
    """
    from .. import io
    from .solid import Solid, make_solid

    if isinstance(part, Solid):
        return part
    if isinstance(part, (str, os.PathLike)):
        return make_solid(io.load(part, limits, file_type), part)
    if hasattr(part, "read"):
        name = getattr(part, "name", None)
        name = os.fspath(name) if isinstance(name, (str, os.PathLike)) else STREAM_NAME
        data = part.read()
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise LoadError(name, "the file object is not binary (open it with 'rb')")
        if len(data) == 0:
            raise LoadError(name, "is empty (0 bytes)")
        limits = limits or io.LoadLimits()
        if name == STREAM_NAME and limits.root is None:
            # a stream has no folder: its VRML Inline references must not reach the working directory
            with tempfile.TemporaryDirectory() as nowhere:
                return make_solid(io.load_bytes(bytes(data), name, file_type, replace(limits, root=Path(nowhere))), name)
        return make_solid(io.load_bytes(bytes(data), name, file_type, limits), name)
    vertices, faces, label = _arrays_of(part)
    mesh = io.PolygonMesh.from_triangles(vertices, faces, format=label)
    io.check_polygon_mesh(label, mesh, limits or io.LoadLimits())
    if len(mesh.face_indices) and (mesh.face_indices.min() < 0 or mesh.face_indices.max() >= len(mesh.vertices)):
        raise LoadError(f"<{label}>", "face indices outside the vertex array")
    return make_solid(mesh, f"<{label}>")


def _arrays_of(part):
    """(vertices, faces, what it was) of a mesh object or a (vertices, faces) pair."""
    if hasattr(part, "vertices") and hasattr(part, "faces"):
        return np.asarray(part.vertices), np.asarray(part.faces), type(part).__name__.lower()
    if isinstance(part, (tuple, list)) and len(part) == 2:
        vertices, faces = (np.asarray(a) for a in part)
        if vertices.ndim == 2 and vertices.shape[1] == 3 and faces.ndim == 2 and faces.shape[1] == 3:
            return vertices, faces, "arrays"
        raise LoadError("<arrays>", f"expected (n, 3) vertices and (k, 3) faces, got {vertices.shape} and {faces.shape}")
    raise TypeError(
        f"cannot load a part from {type(part).__name__}: give a path, a binary file object, "
        "(vertices, faces) arrays or a mesh with vertices and faces"
    )
