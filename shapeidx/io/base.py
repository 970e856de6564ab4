"""What every loader returns, the limits it honours, and reading (possibly gzipped) bytes."""

from __future__ import annotations

import gzip
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import LoadError
from .faceting import Faceting

GZIP_MAGIC = b"\x1f\x8b"


@dataclass(frozen=True)
class LoadLimits:
    """Bounds that protect a build from hostile or runaway input.

    Parameters
    ----------
    max_triangles : int
        Refuse a file whose polygons (after DEF/USE and Inline expansion) would give more
        triangles than this.
    max_uncompressed_bytes : int
        Refuse gzip data that would expand beyond this many bytes.
    max_inline_depth : int
        Deepest chain of VRML Inline nodes followed.
    root : Path or None
        Directory that Inline references must stay inside (the tree being indexed).
        ``None`` means the directory of the file being loaded.
    faceting : Faceting or None
        Tolerances for faceting solid models (STEP, IGES); None: the defaults.
        ``max_triangles`` applies to the faceted result too.
    """

    max_triangles: int = 50_000_000
    max_uncompressed_bytes: int = 1 << 30
    max_inline_depth: int = 8
    root: Path | None = None
    faceting: Faceting | None = None


@dataclass
class PolygonMesh:
    """A part as read from its file: vertices and polygons, before any cleaning.

    Polygons are stored flat, as VRML's coordIndex without the -1 separators:
    polygon ``k`` has ``face_sizes[k]`` corners, listed in ``face_indices`` right after
    those of polygon ``k - 1``. Winding is counter-clockwise seen from outside, as far as
    the file says so (loaders already flip ``ccw FALSE`` and mirrored transforms).

    Attributes
    ----------
    vertices : (n, 3) float64
    face_sizes : (k,) int64, every value >= 3
    face_indices : (face_sizes.sum(),) int64, each in [0, n)
    format : str
        Short name of what was read: ``stl``, ``obj``, ``off``, ``ply``, ``vrml1``, ``vrml2``.
    warnings : list of str
        Things the loader repaired or skipped, one sentence each.
    """

    vertices: np.ndarray
    face_sizes: np.ndarray
    face_indices: np.ndarray
    format: str
    warnings: list[str] = field(default_factory=list)

    @classmethod
    def from_triangles(cls, vertices, triangles, format: str, warnings=None) -> "PolygonMesh":
        """Wrap an (n, 3) vertex array and a (k, 3) triangle array."""
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        return cls(
            vertices=np.asarray(vertices, dtype=np.float64).reshape(-1, 3),
            face_sizes=np.full(len(triangles), 3, dtype=np.int64),
            face_indices=triangles.reshape(-1),
            format=format,
            warnings=list(warnings or []),
        )

    @property
    def polygon_count(self) -> int:
        return int(len(self.face_sizes))


def read_bytes(path: str | os.PathLike, limits: LoadLimits | None = None) -> tuple[bytes, bool]:
    """Read a file, transparently decompressing gzip (detected by its magic bytes).

    Returns
    -------
    data : bytes
    was_gzip : bool

    Raises
    ------
    LoadError
        Missing or unreadable file, corrupt gzip, or gzip that expands beyond
        ``limits.max_uncompressed_bytes``.
    """
    limits = limits or LoadLimits()
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(2)
            if head != GZIP_MAGIC:
                return head + f.read(), False
    except FileNotFoundError:
        raise LoadError(path, "no such file") from None
    except IsADirectoryError:
        raise LoadError(path, "is a directory, not a file") from None
    except PermissionError:
        raise LoadError(path, "permission denied") from None
    except OSError as exc:
        raise LoadError(path, f"cannot read: {exc.strerror or exc}") from None
    return _gunzip_bounded(path, limits.max_uncompressed_bytes), True


def _gunzip_bounded(path: Path, max_bytes: int) -> bytes:
    chunks = []
    total = 0
    try:
        with gzip.open(path, "rb") as f:
            while True:
                chunk = f.read(1 << 20)
                if not chunk:
                    break
                total += len(chunk)
                if total > max_bytes:
                    raise LoadError(
                        path,
                        f"gzip data expands beyond the limit of {max_bytes:,} bytes (refused as a possible bomb)",
                    )
                chunks.append(chunk)
    except LoadError:
        raise
    except (OSError, EOFError, zlib.error) as exc:
        raise LoadError(path, f"corrupt gzip data ({exc})") from None
    return b"".join(chunks)
