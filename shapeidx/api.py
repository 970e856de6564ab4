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



from .distance.metrics import default_metric
from .signing.parameters import DEFAULT_POINTS, DEFAULT_SEED



def load(part, file_type: str | None = None, limits=None):
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
    """Every distance between two parts (or signatures), one per metric of the registry
    (:data:`shapeidx.distance.METRICS`: the paper's four, combined, combined-angle, all-angle).

    Returns
    -------
    dict
        Metric name -> float; 0 means identical histograms.
    """
    from .distance import compare as distances_between

    return distances_between(signature(a, points, seed), signature(b, points, seed))


def open_store(path, parts: bool = False):
    """Open a store to read and query it; keep it open to answer many queries quickly
    (``parts``: its sub-parts, for ``query(..., parts=True)``; a store built with ``build --parts``).

    Use it as a context manager, or close it. It is a :class:`~shapeidx.search.Searcher`:
    pass it to :func:`query`; ``paths``, ``column(name)``, ``counts(name, rows)``,
    ``signature(i)``, ``params`` and ``attrs`` read the store's entries
    (:class:`~shapeidx.store.StoreReader`). Held open, a store of at least 50,000 entries
    builds its block index on its second query (``warm()`` builds it at once), after which
    every query prunes in blocks (docs/performance.md, *A warm searcher*). A sharded store
    (``build --shards``) opens as a :class:`~shapeidx.search.sharded.ShardedSearcher`, which
    offers the query interface (:data:`shapeidx.search.searcher.QUERY_INTERFACE`) over every shard.
    """
    from .search.sharded import open_searcher

    return open_searcher(path, parts=parts)


def query(store, part=None, top: int = 10, metric: str = default_metric("query"), entry: str | None = None,
          file_type: str | None = None, where=(), exclude_self: bool = False, max_distance: float | None = None,
          scale: str = "invariant", parts: bool = False, same_part: bool = False) -> list:
    """The entries of ``store`` nearest to ``part`` (or to its entry ``entry``), nearest first.

    The same road as ``shapeidx query``, the web page and sheets (:mod:`shapeidx.search`):
    the same hits, distances and fields.

    Parameters
    ----------
    store : path of a store, or a store opened with :func:`open_store` (faster for many queries)
    part : anything :func:`load` takes, or a Signature made with the store's parameters
    top : int
        How many hits.
    metric : str
        A name of the metric registry, :data:`shapeidx.distance.METRICS` (one record
        each in :mod:`shapeidx.distance.metrics`); by default the query's
        (:func:`shapeidx.distance.default_metric`), the paper's Weighted.
    entry : str, optional
        Instead of ``part``, an entry of the store (its path relative to the root).
    file_type : str, optional
        As for :func:`load`.
    where : sequence of str
        Metadata conditions, all of which must hold (``"material=steel"``,
        ``"revision>=3"``, ``"path~Connector_*"``; :mod:`shapeidx.search.where`).
    exclude_self : bool
        Leave out the query's own entry.
    max_distance : float, optional
        Leave out hits farther than this.
    scale : str
        ``"invariant"`` (the paper's) or ``"sensitive"`` (parts of another size left out).
    parts : bool
        Rank the store's sub-parts (built with ``build --parts``, docs/assemblies.md) instead
        of its files (``store`` given as a path); each hit then also has ``parent`` (its file)
        and ``count`` (how many times the file holds it).
    same_part : bool
        Order the hits for "is this the same part?": the distance with the gap of the exact
        measures added (:mod:`shapeidx.search.same_part`); each hit then has ``shape_gap``.

    Returns
    -------
    list of dict
        ``{"rank", "distance", "path", "relative_path", "metadata"}`` per hit: ``path`` is
        absolute, ``relative_path`` the entry (what ``entry`` takes). Empty when nothing
        answers (filters that match no entry, every hit beyond ``max_distance``).

    Raises
    ------
    UsageError
        A ``where`` on a key the store does not have, or not of the form KEY OP VALUE.
    """
    from .search import Filters, Searcher, parse_where
    from .search.sharded import ShardedSearcher, open_searcher
    from .system import available_cores

    if (part is None) == (entry is None):
        raise ValueError("give a part or an entry, not both or neither")
    filters = Filters(exclude_self, max_distance, scale, parse_where(where), same_part)
    if parts and isinstance(store, (Searcher, ShardedSearcher)) and not store.parts:
        raise ValueError("parts=True ranks the sub-parts: give the store's path, or open_store(path, parts=True)")
    searcher = store if isinstance(store, (Searcher, ShardedSearcher)) else open_searcher(store, parts=parts)
    try:
        question = searcher.query_of_entry(entry) if entry is not None else searcher.query_of_part(
            part, file_type, threads=available_cores())
        return [hit.to_dict() for hit in searcher.search(question, top, metric, filters).hits]
    finally:
        if searcher is not store:
            searcher.close()
