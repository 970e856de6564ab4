"""The compiled fast path of the VRML reader, for flat VRML 2.0 files.

KiCad's library (and most CAD exporters) write a VRML 2.0 file as a few hundred
top-level ``Shape { geometry IndexedFaceSet { coordIndex [...] coord Coordinate {
point [...] } } appearance ... }``: the Python reader's cost there is per node and per
array, not per byte. ``_scan.c`` reads such a file in one pass and gives the finished
mesh; for anything else (other node structures, strings, PROTOs, comments inside
brackets, any warning or error) it gives None and :mod:`.reader` reads the file the
Python way. Its results are the Python reader's, bit for bit (tests/test_vrml_fast.py).

When the extension is not built, :data:`available` is False and every file is read in
Python. Setting the environment variable ``SHAPEIDX_VRML_PYTHON=1`` does the same, as does
``SHAPEIDX_NATIVE=0``, which switches off every compiled pass of shapeidx.
"""

from __future__ import annotations

import os

import numpy as np

from ..base import LoadLimits, PolygonMesh

try:
    from . import _scan
except ImportError:  # not compiled (a source checkout without a build): Python only
    _scan = None

#: Is the compiled path used? (Tests switch it off to compare the two paths.)
available = (_scan is not None and os.environ.get("SHAPEIDX_VRML_PYTHON", "") in ("", "0")
             and os.environ.get("SHAPEIDX_NATIVE", "1") != "0")


def load_flat(path, data: bytes, limits: LoadLimits, check_expansion) -> PolygonMesh | None:
    """The mesh of a flat VRML 2.0 file, or None when the Python reader must read it.

    Parameters
    ----------
    path : path-like
        For messages.
    data : bytes
        The whole file, decompressed.
    limits : LoadLimits
    check_expansion : callable(triangles, visits)
        The reader's own limit check (raises LoadError), which it raises here; files over
        the compiled scanner's own limits (``max_triangles``) are left to the Python
        reader, which refuses them before it splits their polygons.

    Returns
    -------
    PolygonMesh or None
    """
    if not available or data.__class__ is not bytes:
        return None
    from .scene import MAX_NODE_VISITS

    found = _scan.scan(data, limits.max_triangles, MAX_NODE_VISITS)
    if found is None:
        return None
    vertices, sizes, corners, triangles, visits, _ = found
    # the counts are the Python reader's (the same file, read the same way): a refusal is
    # final, and is not read again in Python (which would spend what the refusal spares)
    check_expansion(triangles, visits)
    if not sizes:  # as MeshBuilder.arrays() makes an empty mesh
        return PolygonMesh(np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), "vrml2", [])
    # frombuffer over a bytearray: writeable, C-contiguous, no copy
    return PolygonMesh(
        np.frombuffer(vertices, dtype=np.float64).reshape(-1, 3),
        np.frombuffer(sizes, dtype=np.int64),
        np.frombuffer(corners, dtype=np.int64),
        "vrml2",
        [],
    )
