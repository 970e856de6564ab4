"""Where is a part used? The files that hold a sub-part like it, nearest first.

    with open_searcher("library.shapeidx", parts=True) as searcher:   # built with --parts
        query = searcher.query_of_part("pin.step")            # or question_of_entry("a.step#3")
        answer = searcher.where_used(query, top=10, metric="weighted")
        for use in answer.uses:
            print(use.rank, use.distance, use.path, use.count, use.part)

Every sub-entry of the store (``FILE#n``, :mod:`shapeidx.io.parts`; a file that is one part
is its own ``FILE#1``) is ranked by its distance to the query on the road of ``query``
(:meth:`shapeidx.search.searcher.Searcher.rank`: the same distances, and the block index of a
warm store), as many as it takes to find ``top`` files; the files are then ranked by their
nearest sub-part. A file's ``count`` is how many times it holds that nearest sub-part; with
``max_distance`` it is how many times it holds any sub-part within that distance, and
``parts`` lists them.

Where-used is a method of every searcher (:data:`~shapeidx.search.searcher.QUERY_INTERFACE`):
:meth:`Searcher.where_used <shapeidx.search.searcher.Searcher.where_used>` answers one store
by :func:`uses_in_store`; a sharded store's asks it of every shard and merges the files
(:meth:`shapeidx.search.sharded.ShardedSearcher.where_used`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..distance.metrics import default_metric
from .distances import RANK_THREADS
from .hits import absolute

#: where-used's metric: plain D2 with the normal angles ranked the files holding a KiCad pin
#: or body first best (docs/assemblies.md: R-precision 1.00 against 0.86 for ``weighted``).
DEFAULT_METRIC = default_metric("where-used")
#: With ``scale="sensitive"``: the largest relative difference of principal radii between the
#: query and a sub-part it can be (measured on KiCad: 0.02 loses 8 % of the files that hold
#: the part, 0.05 none, and keeps the precision at 0.96).
SAME_SIZE = 0.05
#: Why no file answers, in a word (:attr:`WhereUsed.why`), in the order where-used checks: the
#: store has nothing to rank, no sub-part is in the size band of ``--scale sensitive``, none has
#: the query's principal radii (``same_size``), none within ``max_distance`` (or none ranked).
#: A sharded store's merge decides on these, not on the words.
NO_USE = ("empty", "scale", "same_size", "max_distance")


@dataclass
class Use:
    """One file that holds a sub-part like the query.

    Attributes
    ----------
    rank : int
    distance : float
        Of its nearest sub-part.
    path : str
        The file, absolute.
    relative_path : str
        The file, relative to the indexed folder (its whole-file entry).
    part : str
        Its nearest sub-part's entry (``FILE#n``, what ``--id`` takes).
    title : str
        That sub-part's name in the file ("" when it has none).
    count : int
        How many times the file holds the nearest sub-part (with ``max_distance``: any
        sub-part within it).
    parts : list of str
        With ``max_distance``: every sub-part of the file within it; else the nearest alone.
    """

    rank: int
    distance: float
    path: str
    relative_path: str
    part: str
    title: str
    count: int
    parts: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"rank": self.rank, "distance": self.distance, "path": self.path, "relative_path": self.relative_path,
                "part": self.part, "title": self.title, "count": self.count, "parts": list(self.parts)}


@dataclass
class WhereUsed:
    """The answer of where-used (:func:`uses_in_store`): the files, nearest first, and what was
    asked; with none, why (``reason``, in words; ``why``, its kind of :data:`NO_USE`)."""

    query: str
    entry: str | None
    metric: str
    store: str
    root: str
    sub_entries: int
    files: int
    uses: list
    max_distance: float | None = None
    reason: str | None = None
    #: With no use within ``max_distance``: the distance of the nearest sub-part (None: none ranked).
    nearest: float | None = None
    #: With no use: why, in a word of :data:`NO_USE` (what a sharded store's merge decides on).
    why: str | None = None

    def to_dict(self) -> dict:
        return {"query": self.query, "entry": self.entry, "metric": self.metric, "store": self.store,
                "root": self.root, "sub_entries": self.sub_entries, "files": self.files,
                "max_distance": self.max_distance, "uses": [use.to_dict() for use in self.uses]}


def where_used(searcher, query, top: int = 10, metric: str = DEFAULT_METRIC, max_distance: float | None = None,
               scale: str = "sensitive", same_size: float | None = SAME_SIZE, threads: int = RANK_THREADS) -> WhereUsed:
    """``searcher.where_used(query, ...)``: the method of every searcher opened with
    ``parts=True`` (:func:`uses_in_store` for one store)."""
    return searcher.where_used(query, top, metric, max_distance, scale, same_size, threads)


def check_question(top: int, metric: str) -> None:
    """Refuse ``top`` below 1 and an unknown metric (ValueError naming the known ones)."""
    from ..distance.metrics import metric as metric_record

    metric_record(metric)
    if top < 1:
        raise ValueError(f"top must be at least 1, not {top}")


def uses_in_store(searcher, query, top: int, metric: str, filters, same_size: float | None,
                  threads: int = RANK_THREADS) -> WhereUsed:
    """The ``top`` files of one store holding a sub-part nearest to ``query`` (see the module
    docstring): the work of :meth:`Searcher.where_used <shapeidx.search.searcher.Searcher.where_used>`.

    ``searcher`` is a :class:`~shapeidx.search.searcher.Searcher` of the store's sub-parts
    (opened with ``parts=True``, or on ``STORE/parts`` itself, as a shard's is); ``query``
    one of its :class:`~shapeidx.search.searcher.Query`; ``filters`` a
    :class:`~shapeidx.search.searcher.Filters` of ``max_distance`` and ``scale`` (made by the
    method: this module does not import the searcher's). ``scale``: ``"sensitive"``
    (the default) keeps only sub-parts of the query's size: a part used in an assembly has its
    size there, and D2 alone, which is scale-invariant, would take a small pin for any
    elongated box. That is ``query --scale sensitive``'s band (a factor 2), and with
    ``same_size`` principal radii (the exact surface moments the store keeps,
    ``entries/extents``) within that share of the query's (default :data:`SAME_SIZE`; None:
    the band only). ``"invariant"``: any size.
    """
    check_question(top, metric)
    max_distance, scale = filters.max_distance, filters.scale
    n = len(searcher.view)
    answer = WhereUsed(query.label, query.entry, metric, str(searcher.store.resolve()), searcher.root, n, 0, [],
                       max_distance)
    if n == 0:
        answer.why, answer.reason = "empty", searcher.empty_reason()
        return answer
    parents, counts = searcher.parents()
    parents = np.array([p or searcher.view.path_at(i) for i, p in enumerate(parents)], dtype=object) if (
        parents == "").any() else parents
    answer.files = len(set(parents.tolist()))
    keep, why = searcher.keep(query, filters)
    if why is not None:
        answer.why, answer.reason = why
        return answer
    if scale == "sensitive" and same_size is not None:
        close = _same_size(searcher, query, same_size)
        keep = close if keep is None else keep & close
        if not keep.any():
            answer.why, answer.reason = "same_size", f"no sub-part has the query's size within {same_size:g}"
            return answer
    searcher.asked()
    # the nearest sub-entries on the search's road, more of them until `top` files are among those
    # surely complete (up to the wanted-th distance: the rank's contract); every one within max_distance
    wanted = n if max_distance is not None else min(n, max(64, 4 * top))
    while True:
        positions, distances = searcher.rank(query.signature, metric, wanted, keep, query.own, max_distance, threads)
        valid = np.isfinite(distances)
        positions, distances = positions[valid], distances[valid]
        order = np.lexsort((positions, distances))
        positions, distances = positions[order], distances[order]
        if wanted >= n or len(distances) < wanted:
            break  # every ranked sub-entry is here
        complete = distances <= distances[wanted - 1]
        if len(set(parents[positions[complete]].tolist())) >= top:
            positions, distances = positions[complete], distances[complete]
            break
        wanted = min(n, 4 * wanted)
    uses: dict = {}
    for position, distance in zip(positions.tolist(), distances.tolist()):
        parent = parents[position]
        within = max_distance is not None and distance <= max_distance
        use = uses.get(parent)
        if use is None:
            if max_distance is not None and not within:
                continue
            if len(uses) >= top:
                if max_distance is None:
                    break
                continue
            part = searcher.view.path_at(position)
            title = searcher.metadata_at(position).get("title", "")
            uses[parent] = Use(0, float(distance), absolute(searcher.root, parent), parent, part, title,
                               int(counts[position]), [part])
        elif within:
            use.count += int(counts[position])
            use.parts.append(searcher.view.path_at(position))
    answer.uses = sorted(uses.values(), key=lambda u: (u.distance, u.relative_path))
    for rank, use in enumerate(answer.uses, start=1):
        use.rank = rank
    if not answer.uses:
        nearest_at = float(distances[0]) if len(distances) else float("nan")
        answer.nearest = nearest_at if np.isfinite(nearest_at) else None
        answer.why, answer.reason = "max_distance", no_use_reason(max_distance, answer.nearest)
    return answer


def no_use_reason(max_distance: float | None, nearest: float | None) -> str:
    """Why no file answers: none within ``max_distance`` (the nearest sub-part at ``nearest``)."""
    if max_distance is not None and nearest is not None:
        return f"no sub-part within --max-distance {max_distance:g} (the nearest is at {nearest:.6g})"
    return "no sub-part could be ranked"


def question_of_entry(parts, entry, files=None):
    """``parts.question_of_entry(entry, files)``: where-used's question for an entry of the
    store (:meth:`shapeidx.search.searcher.Searcher.question_of_entry`)."""
    return parts.question_of_entry(entry, files)


def query_radii(searcher, query) -> np.ndarray | None:
    """The query's principal radii, from its exact measures (``searcher.query_measures``:
    given, of its loaded part, or its own entry's; None: unknown)."""
    from .same_part import radii_of_measures

    measures = searcher.query_measures(query)
    return None if measures is None else radii_of_measures(measures)


def _same_size(searcher, query, tolerance: float) -> np.ndarray:
    """Which ranked sub-entries have principal radii within ``tolerance`` (relative) of the query's."""
    mine = query_radii(searcher, query)
    if mine is None:
        return np.ones(len(searcher.view), dtype=bool)
    extents = searcher.entry_numbers("entries/extents", 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        gap = np.abs(np.log(extents / mine)).max(axis=1)
    return ~(gap > np.log1p(tolerance))  # unknown radii (NaN) are kept
