"""The registry of file formats and the entry points that use it: load, load_bytes, format_of."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import LoadError, OutOfMemory, exception_in_words
from . import obj, off, ply, step, stl, vrml
from .formats import FORMAT_NAMES
from .base import GZIP_MAGIC, Format, LoadLimits, PolygonMesh, gunzip_bounded, read_bytes, without_float_warnings

__all__ = [
    "FORMATS",
    "Format",
    "count_by_label",
    "entry_format",
    "LoadLimits",
    "PolygonMesh",
    "format_of",
    "load",
    "load_bytes",
    "read_bytes",
    "reader_revision",
    "register",
    "revisions",
    "suffixes",
]

#: Every format by name, in the order errors list them.
FORMATS: dict[str, Format] = {}
_BY_SUFFIX: dict[str, Format] = {}


def register(fmt: Format) -> None:
    """Make a format known to :func:`load`, :func:`format_of` and the build's walk."""
    FORMATS[fmt.name] = fmt
    for suffix in fmt.suffixes:
        _BY_SUFFIX[suffix] = fmt


for _module in (stl, obj, off, ply, vrml, step):
    for _format in _module.FORMATS:
        register(_format)
assert tuple(FORMATS) == FORMAT_NAMES, "every format of shapeidx.io.formats has its reader, in the same order"


def suffixes() -> list[str]:
    """File name endings of every known format (each may also end in ``.gz``)."""
    return sorted(_BY_SUFFIX)


def format_of(path: str | os.PathLike) -> str | None:
    """The format of ``path`` judged by its name (case-insensitive, ``.gz`` allowed), or None."""
    if isinstance(path, str) and "/" not in path:  # a bare file name (the build's walk): no Path to make
        name = path.lower()
    else:
        name = Path(path).name.lower()
    if name.endswith(".gz"):
        name = name[:-3]
    at = name.rfind(".")
    fmt = _BY_SUFFIX.get(name[at:]) if 0 < at < len(name) - 1 else None  # Path(name).suffix's rule: ".wrl" has none
    return fmt.name if fmt else None


def entry_format(path: str) -> str | None:
    """The format of a store entry's file, by its name (:func:`format_of`: a build reads a file
    by its name); a sub-entry ``FILE#n`` (``build --parts``) is its file's."""
    fmt = format_of(path)
    if fmt is None and "#" in path:
        fmt = format_of(path.rpartition("#")[0])
    return fmt


def reader_revision(path: str) -> int:
    """The revision (:attr:`Format.revision`) of the reader of an entry's file
    (:func:`entry_format`); 1 for a name no format owns."""
    fmt = entry_format(path)
    return FORMATS[fmt].revision if fmt else 1


def revisions() -> dict[str, int]:
    """Format name -> its reader's current revision."""
    return {name: fmt.revision for name, fmt in FORMATS.items()}


def count_by_label(names: list) -> dict[str, int]:
    """Format label -> how many of ``names`` (format names) are of it, in the registry's order."""
    return {fmt.label: names.count(name) for name, fmt in FORMATS.items() if name in names}


@without_float_warnings
def load(path: str | os.PathLike, limits: LoadLimits | None = None, file_type: str | None = None) -> PolygonMesh:
    """Read a part file into a :class:`PolygonMesh`.

    Parameters
    ----------
    path : path-like
    limits : LoadLimits, optional
    file_type : str, optional
        A format name of :data:`FORMATS`; by default the file's name decides, and a name
        without a known ending is sniffed from its first bytes.

    Raises
    ------
    LoadError
        Anything that keeps the file from being read, as one line naming the file.
    """
    limits = limits or LoadLimits()
    path = Path(path)
    _check_is_a_nonempty_file(path)
    data, _ = read_bytes(path, limits)
    return _read(data, path, file_type or format_of(path), limits)


@without_float_warnings
def load_bytes(
    data: bytes, path: str | os.PathLike, file_type: str | None = None, limits: LoadLimits | None = None
) -> PolygonMesh:
    """Read a part from its content (gzip allowed); ``path`` names it in errors.

    ``file_type`` as for :func:`load`; without it the content is sniffed.
    """
    limits = limits or LoadLimits()
    path = Path(path)
    if data[:2] == GZIP_MAGIC:
        data = gunzip_bounded(data, path, limits.max_uncompressed_bytes)
    return _read(data, path, file_type, limits)


def _read(data: bytes, path: Path, file_type: str | None, limits: LoadLimits) -> PolygonMesh:
    if file_type is not None and file_type not in FORMATS:
        raise LoadError(path, f"unknown file type {file_type!r} (known: {', '.join(FORMATS)})")
    fmt = None
    try:
        fmt = FORMATS[file_type] if file_type else _sniff(path, data)
        if fmt.declared is not None:  # refused from what the file declares, before it is read
            limits.check_memory(path, *fmt.declared(data))
        mesh = fmt.read(path, data, limits)
    except LoadError:
        raise
    except MemoryError:
        raise OutOfMemory(path, "out of memory while reading") from None
    except RecursionError:
        raise LoadError(path, "nesting too deep to read") from None
    except Exception as exc:  # a reader bug must still end as one line in words, never a traceback
        label = f"as {fmt.label}" if fmt else ""
        raise LoadError(path, f"cannot be read {label}: it holds {exception_in_words(exc)}") from None
    check_polygon_mesh(path, mesh, limits)
    if not mesh.metadata:
        from .metadata import file_metadata

        mesh.metadata = file_metadata(data, mesh.format if mesh.format.startswith("vrml") else fmt.name)
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


def _sniff(path: Path, data: bytes) -> Format:
    ordered = sorted((f for f in FORMATS.values() if f.sniff), key=lambda f: f.weak)
    for fmt in ordered:
        if fmt.sniff(data):
            return fmt
    labels = [f.label for f in FORMATS.values()]
    raise LoadError(path, f"unknown file type (expected {', '.join(labels[:-1])} or {labels[-1]})")
