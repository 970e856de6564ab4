"""The Python API: load a part, sign it, compare two, query a store.

Every function takes a *part* in whatever form the caller has it:

* a path (``str`` or :class:`os.PathLike`) of a file in any format of :mod:`shapeidx.io`
  (STL, OBJ, OFF, PLY, VRML 1.0 / 2.0, each possibly gzipped);
* a binary file object (``open(path, "rb")``, :class:`io.BytesIO`, a web upload), with
  ``file_type`` naming its format when its content does not say (OBJ has no magic number);
* a ``(vertices, faces)`` pair of arrays: (n, 3) coordinates and (k, 3) triangle indices;
* a :class:`trimesh.Trimesh` (anything with ``vertices`` and ``faces``);
* a :class:`~shapeidx.signing.solid.Solid`, as :func:`load` returns it.

Errors are the project's own: :class:`~shapeidx.errors.LoadError` for a part that cannot be
used (its ``str()`` is one line naming the file and the reason), and
:class:`~shapeidx.errors.StoreError` for a store that cannot be used as asked. Both derive
from :class:`~shapeidx.errors.ShapeidxError`.
"""

from __future__ import annotations



from .signing.parameters import DEFAULT_POINTS, DEFAULT_SEED



def load(part, file_type: str | None = None, limits=None):
    """Load a part and make it a clean, oriented triangle mesh (the paper's step 1).

    Polygons are triangulated, duplicate points merged, degenerate faces dropped, shells
    oriented outward and overlapping shells united (see ``docs/method.md``).

    Parameters
    ----------
    part : path, binary file object, (vertices, faces), trimesh.Trimesh or Solid
    file_type : str, optional
        Format name (``"stl"``, ``"obj"``, ``"off"``, ``"ply"``, ``"vrml"``, ``"step"``,
        ``"iges"``) for a path or file object whose name or content does not tell it.
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
    from .signing.part import load_part

    return load_part(part, file_type, limits)


def signature(part, points: int = DEFAULT_POINTS, seed: int = DEFAULT_SEED, file_type: str | None = None, threads: int | None = None):
    """The part's IN / OUT / MIXED D2 signature (Ip et al. 2002, section 3.2).

    Parameters
    ----------
    part : anything :func:`load` takes, or a Signature (returned as it is)
    points : int
        Surface samples (the paper's m; 1024 gives 523,776 pairs).
    seed : int
        Sampling seed: the same part and seed give the same signature on any machine.
    file_type : str, optional
        As for :func:`load`.
    threads : int, optional
        Threads for the ray queries (default: every core; the result does not depend on it).

    Returns
    -------
    Signature
        ``histograms`` (``"all"``, ``"in"``, ``"out"``, ``"mixed"`` -> Histogram with
        ``counts``, ``mean``, ``bin_width``, ``p``), ``fractions``, ``to_dict()``.
    """
    from .signing.histogram import Signature
    from .signing.pipeline import signature_of_solid
    from .system import available_cores

    if isinstance(part, Signature):
        return part
    if points < 2:
        raise ValueError(f"points must be at least 2, not {points}")
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, not {seed}")
    return signature_of_solid(load(part, file_type), points, seed, threads=threads or available_cores())


def compare(a, b, points: int = DEFAULT_POINTS, seed: int = DEFAULT_SEED) -> dict:
    """Every distance between two parts (or signatures): the paper's four and ``combined``.

    Returns
    -------
    dict
        ``{"all", "avg3", "avg4", "weighted", "combined"}`` -> float; 0 means identical
        histograms.
    """
    from .distance import compare as distances_between

    return distances_between(signature(a, points, seed), signature(b, points, seed))


def open_store(path):
    """Open a signature store for reading (main file and journal, as one consistent view).

    Use it as a context manager, or close it. See :class:`~shapeidx.store.StoreReader`
    for what it offers (``paths``, ``column(name)``, ``signature(i)``, ``params``).
    """
    from .store import open_store as open_reader

    return open_reader(path)


def query(store, part=None, top: int = 10, metric: str = "weighted", entry: str | None = None, file_type: str | None = None):
    """The entries of ``store`` nearest to ``part``, nearest first.

    Parameters
    ----------
    store : path of a store, or a store opened with :func:`open_store`
    part : anything :func:`load` takes, or a Signature made with the store's parameters
    top : int
        How many hits.
    metric : str
        ``"weighted"`` (the paper's, the default), ``"all"``, ``"avg3"``, ``"avg4"`` or
        ``"combined"``.
    entry : str, optional
        Instead of ``part``, a path of an entry of the store (relative to its root).
    file_type : str, optional
        As for :func:`load`.

    Returns
    -------
    list of dict
        ``{"rank", "path", "distance"}`` per hit; ``path`` is relative to the store's root.
    """
    from .ranking import query_store
    from .system import available_cores

    if (part is None) == (entry is None):
        raise ValueError("give a part or an entry, not both or neither")
    return query_store(store, part, entry=entry, top=top, metric=metric, threads=available_cores(), file_type=file_type)
