"""What every loader returns, the limits it honours, and reading (possibly gzipped) bytes."""

from __future__ import annotations

import functools
import gzip
import io
import os
import zlib
from collections.abc import Callable
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
        Refuse gzip data that would expand beyond this many bytes (default 256 MiB: the
        decompressed text is held in memory, and parsing it takes several times as much).
    max_inline_depth : int
        Deepest chain of VRML Inline nodes followed.
    root : Path or None
        Directory that Inline references must stay inside (the tree being indexed).
        ``None`` means the directory of the file being loaded.
    faceting : Faceting or None
        Tolerances for faceting solid models (STEP, IGES); None: the defaults.
        ``max_triangles`` applies to the faceted result too.
    max_polygon_corners : int
        Refuse a polygon of more corners than this: triangulating a concave polygon takes
        time that grows as the square of its corners (10,000 take half a second, 100,000
        two minutes). Real files stay far below (the most in the shared data: 936).
    max_bytes : int
        Refuse a part whose reading and cleaning would need more memory than this, as
        estimated from its triangle and vertex counts (:meth:`estimated_bytes`) before the
        arrays are built: for VRML after DEF/USE and Inline expansion is counted, for the
        other formats once the file is read. The default, 4 GiB, admits some 5 million
        triangles. What no count foresees (Python objects of a huge text file) is bounded
        by the build workers' memory limit instead (:mod:`shapeidx.index.workers`).
        Also the memory limit of the child process OpenCASCADE reads STEP and IGES in
        (:mod:`shapeidx.io.contained`), beyond what that process holds when it starts.
    max_seconds : float or None
        Seconds OpenCASCADE may take to read and facet one STEP or IGES file in its child
        process (:mod:`shapeidx.io.contained`) before it is stopped and the file refused;
        None for no limit. Inside a build's workers the build's ``--timeout`` applies instead.
    """

    max_triangles: int = 50_000_000
    max_uncompressed_bytes: int = 256 << 20
    max_inline_depth: int = 8
    root: Path | None = None
    faceting: Faceting | None = None
    max_bytes: int = 4 << 30
    max_polygon_corners: int = 20_000
    max_seconds: float | None = 120.0

    def estimated_bytes(self, triangles: int, vertices: int = 0) -> int:
        """Peak memory of cleaning a part of ``triangles`` triangles over ``vertices`` points.

        Measured with scripts/fuzz.py's bombs and by peak RSS on icospheres of 0.3 and 1.3
        million triangles written as binary STL (three points per triangle): about 750
        bytes per triangle from reading to the clean solid; the signature adds little.
        """
        return BYTES_PER_TRIANGLE * int(triangles) + BYTES_PER_VERTEX * int(vertices)

    def check_memory(self, path, triangles: int, vertices: int = 0) -> None:
        """Raise LoadError when a part of this size would need more than ``max_bytes``."""
        need = self.estimated_bytes(triangles, vertices)
        if need > self.max_bytes:
            counts = f"{int(triangles):,} triangles" + (f", {int(vertices):,} vertices" if vertices else "")
            raise LoadError(
                path,
                f"would need about {_binary_size(need)} of memory ({counts}), more than the limit of "
                f"{_binary_size(self.max_bytes)} (refused as a possible bomb)",
            )


    def check_reading(self, path, need: int, what: str) -> None:
        """Raise LoadError when reading a file would take ``need`` bytes, more than
        ``max_bytes``; ``what`` says for what ("to split its 75,000,000 coordIndex values")."""
        if need > self.max_bytes:
            raise LoadError(
                path,
                f"would need about {_binary_size(need)} of memory {what}, more than the limit of "
                f"{_binary_size(self.max_bytes)} (refused as a possible bomb)",
            )


class NotRegularFile(OSError):
    """A name that is a FIFO, socket or device, not a file: ``str()`` says which."""

    def __str__(self) -> str:
        return self.strerror


def open_regular(path: str | os.PathLike):
    """Open a file for reading in binary, refusing anything but a regular file.

    The file is opened with ``O_NONBLOCK`` and checked on its descriptor (``fstat``), so a
    FIFO, socket or device under the name (put there after a build, say) is refused at once
    instead of blocking the reading thread forever (a FIFO without a writer blocks ``open``);
    the check and the read are of the same file. Raises :class:`IsADirectoryError` for a
    directory, :class:`NotRegularFile` for the rest, as ``open`` raises for a missing file.
    """
    import errno
    import stat

    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "is a directory, not a file", os.fspath(path))
        if not stat.S_ISREG(mode):
            kind = ("a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
                    else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a special file")
            raise NotRegularFile(errno.EINVAL, f"is {kind}, not a regular file", os.fspath(path))
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(path: str | os.PathLike, limit: int | None = None) -> bytes:
    """A small file's bytes through :func:`open_regular` (never blocks on a FIFO); more than
    ``limit`` bytes raise :class:`OSError` (a record of a few bytes grown to gigabytes)."""
    import errno

    with open_regular(path) as f:
        data = f.read(-1 if limit is None else limit + 1)
    if limit is not None and len(data) > limit:
        raise OSError(errno.EFBIG, f"larger than {limit:,} bytes", os.fspath(path))
    return data


def file_hash(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, as 64 hex digits (what a store entry records)."""
    import hashlib

    digest = hashlib.sha256()
    with open_regular(path) as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def _binary_size(n: int) -> str:
    return f"{n / (1 << 30):.1f} GiB" if n >= 1 << 30 else f"{n / (1 << 20):.1f} MiB"


#: Memory estimate of :meth:`LoadLimits.estimated_bytes`, per triangle and per vertex.
BYTES_PER_TRIANGLE = 800
BYTES_PER_VERTEX = 48


def head_of(data: bytes) -> bytes:
    """The first 512 bytes with leading white space removed: what magic numbers are read from."""
    return data[:512].lstrip()


@dataclass(frozen=True)
class Format:
    """A file format a reader module handles; every reader module declares one as ``FORMAT``.

    Attributes
    ----------
    name : str
        What ``file_type`` arguments and ``--type`` options call it (``"stl"``).
    label : str
        Its name for people (``"STL"``).
    suffixes : tuple of str
        File name endings, lower case, without ``.gz`` (compression is detected anyway).
    read : callable
        ``read(path, data, limits) -> PolygonMesh``: ``data`` is the file's content, already
        decompressed; ``path`` names the file in errors (and locates VRML Inline files).
        Raises :class:`~shapeidx.errors.LoadError`.
    sniff : callable or None
        ``sniff(data) -> bool``: whether this content is in this format (judged by its
        first bytes, :func:`head_of`, for most formats).
    weak : bool
        The sniff test is a last resort (binary STL has no magic number): tried after
        every other format's.
    declared : callable or None
        ``declared(data) -> (triangles, vertices)``: at least how many triangles and
        vertices the file says it holds (header counts, ``f`` lines, ``endfacet``), found
        without reading it (a header, or a count of bytes in C), and never more than its
        bytes can hold. :func:`shapeidx.io.load` checks the memory they need
        (:meth:`LoadLimits.check_memory`) before the reader spends it.
    revision : int
        The reader's revision: raised whenever this reader could give another mesh for the
        same file (and limits), so that a build signs again the files an older revision
        read (each store entry records the revision that signed it, ``entries/revision``;
        :func:`shapeidx.index.plan.make_plan`) while the other formats' entries stay.
        This is :data:`~shapeidx.signing.parameters.SIGNATURE_VERSION` for one format:
        a change to what every format shares (cleaning, sampling, classification) raises
        that instead. Each raise, and what it was for, is noted where the format is declared:

        * STEP and IGES 2 (shapeidx.io.step): faces going round their surface more than once
          (a cylinder wall wound two or three turns) meshed as one turn, not as a sliver.
    """

    name: str
    label: str
    suffixes: tuple
    read: Callable
    sniff: Callable | None = None
    weak: bool = False
    declared: Callable | None = None
    revision: int = 1


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
    metadata : dict
        What the file says about itself (:mod:`shapeidx.io.metadata`: ``title``, ``product_id``).
    """

    vertices: np.ndarray
    face_sizes: np.ndarray
    face_indices: np.ndarray
    format: str
    warnings: list[str] = field(default_factory=list)
    metadata: dict = field(default_factory=dict)

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
        with open_regular(path) as f:
            head = f.read(2)
            if head != GZIP_MAGIC:
                return head + f.read(), False
            f.seek(0)
            return gunzip_bounded(f, path, limits.max_uncompressed_bytes), True
    except LoadError:
        raise
    except FileNotFoundError:
        raise LoadError(path, "no such file") from None
    except IsADirectoryError:
        raise LoadError(path, "is a directory, not a file") from None
    except NotRegularFile as exc:
        raise LoadError(path, str(exc)) from None
    except PermissionError:
        raise LoadError(path, "permission denied") from None
    except OSError as exc:
        raise LoadError(path, f"cannot read: {exc.strerror or exc}") from None


def gunzip_bounded(source, path: Path, max_bytes: int) -> bytes:
    """Decompress gzip data from ``source`` (a path, an open file or the compressed bytes), refusing to
    expand beyond ``max_bytes``; ``path`` names the file in errors."""
    declared = _gzip_declared_size(source)
    if declared is not None and declared > max_bytes:
        raise LoadError(
            path,
            f"gzip data expands beyond the limit of {max_bytes:,} bytes (it declares {declared:,}: a bomb,"
            f" or its last bytes are damaged; refused)",
        )
    if isinstance(source, (bytes, bytearray, memoryview)):
        source = io.BytesIO(source)
    chunks = []
    total = 0
    try:
        with gzip.open(source, "rb") as f:
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
        raise LoadError(path, f"corrupt gzip data ({_gzip_problem(exc)})") from None
    return b"".join(chunks)


def _gzip_problem(exc: BaseException) -> str:
    """What a gzip or zlib exception says about the data, in words (zlib's own text reads
    "Error -3 while decompressing data: invalid distance too far back")."""
    if isinstance(exc, EOFError):
        return "it is cut short before the end of its compressed stream"
    text = str(exc)
    if isinstance(exc, zlib.error):
        detail = text.split(":", 1)[1].strip() if ":" in text else ""
        return "its compressed stream is damaged" + (f": {detail}" if detail else "")
    if text.startswith("Not a gzipped file"):
        return "not gzip after its first bytes"
    if text.startswith("CRC check failed"):
        return "its checksum does not match its content"
    if text.startswith("Incorrect length"):
        return "its declared length does not match its content"
    return getattr(exc, "strerror", None) or "unreadable"


def _gzip_declared_size(source) -> int | None:
    """The uncompressed size a gzip stream's last member declares (ISIZE, its last four
    bytes: the size modulo 2^32), or None when it cannot be read. A lie can only make the
    streaming limit the one that refuses."""
    try:
        if isinstance(source, (bytes, bytearray, memoryview)):
            tail = bytes(source[-4:]) if len(source) >= 18 else b""
        elif hasattr(source, "seek"):  # an open file: read its end, then go back
            at = source.tell()
            try:
                source.seek(0, os.SEEK_END)
                if source.tell() < 18:
                    return None
                source.seek(-4, os.SEEK_END)
                tail = source.read(4)
            finally:
                source.seek(at)
        else:
            return None
    except (OSError, ValueError):
        return None
    return int.from_bytes(tail, "little") if len(tail) == 4 else None


#: Largest coordinate magnitude, and largest extent, that cleaning computes with: areas grow
#: as the square and volumes as the cube of the extent, and must stay finite in float64
#: (whose largest value is 1.8e308). Real parts are some 1e-6 to 1e4 in any unit.
MAX_COORDINATE = 1e100
#: Smallest extent: below it areas and volumes underflow to zero.
MIN_EXTENT = 1e-100


def column_min(points: np.ndarray) -> np.ndarray:
    """``points.min(axis=0)`` of an (n, d) array, the very values, a column at a time: numpy's
    reduction over the rows of a narrow array walks them d values at a time, ten times slower
    than a reduction along one column. Where a column's least value is zero or not finite (the
    sign of a zero, or which NaN, may depend on the order of comparisons) numpy's own
    reduction answers, so the result is bit for bit ``points.min(axis=0)``."""
    return _by_column(points, np.min)


def column_max(points: np.ndarray) -> np.ndarray:
    """``points.max(axis=0)``, as :func:`column_min`."""
    return _by_column(points, np.max)


def _by_column(points: np.ndarray, reduce) -> np.ndarray:
    points = np.asarray(points)
    if points.ndim != 2 or len(points) == 0 or points.dtype.kind != "f":
        return reduce(points, axis=0)
    out = np.array([reduce(points[:, k]) for k in range(points.shape[1])], dtype=points.dtype)
    if not (np.isfinite(out).all() and (out != 0).all()):
        return reduce(points, axis=0)
    return out


def check_coordinate_range(path, points: np.ndarray) -> None:
    """Refuse coordinates that areas and volumes cannot be computed with (LoadError).

    ``points`` are the vertices the faces use. Non-finite ones are refused by the loader.
    """
    if len(points) == 0:
        return
    largest = float(np.max(np.abs(points)))
    if not largest <= MAX_COORDINATE:
        raise LoadError(
            path,
            f"has coordinates too large to compute with (up to {largest:.3g}; areas and volumes would "
            f"overflow beyond {MAX_COORDINATE:.0e})",
        )
    extent = float(np.max(column_max(points) - column_min(points)))
    if 0 < extent < MIN_EXTENT:
        raise LoadError(
            path, f"is too small to compute with (extent {extent:.3g}; areas and volumes would underflow to zero)"
        )


def without_float_warnings(function):
    """Run ``function`` with numpy's floating-point warnings off.

    Overflow, invalid values (NaN, signalling NaN) and division by zero in hostile input
    would print RuntimeWarnings beside the one-line error; the readers and cleaning check
    their results instead (non-finite coordinates, coordinate range, zero area) and say
    what is wrong in that line.
    """

    @functools.wraps(function)
    def quiet(*args, **kwargs):
        with np.errstate(all="ignore"):
            return function(*args, **kwargs)

    return quiet
