"""What a search answers: hits with the same fields on every surface, and the answer around them.

A :class:`Hit` is what the command line prints (table, CSV, JSON), what ``shapeidx.query``
returns (as a dict), what ``/api/query`` sends and what a sheet draws: its rank, its distance,
its path (absolute, opens from anywhere) and relative path (the store's entry, what
``--id`` takes) and its metadata (the sidecar table's and the file's own). Surfaces add
presentation (the web page a thumbnail address, a sheet the similarity in words), never
other hits or other distances.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

#: Why an answer has no hit, in a word (:attr:`Answer.why`), in the order the search road
#: checks: the store has nothing to rank, ``--where`` matches nothing, the size band of
#: ``--scale sensitive`` keeps nothing, ``--exclude-self`` leaves nothing, the voters
#: (``among``) leave nothing, nothing within ``--max-distance``. A sharded store's merge
#: decides on these, not on the words (:mod:`shapeidx.search.sharded`).
NO_HIT = ("empty", "where", "scale", "exclude_self", "among", "max_distance")


@dataclass
class Hit:
    """One entry of an answer, nearest first.

    Attributes
    ----------
    rank : int
        1 for the nearest.
    distance : float
        By the answer's metric.
    path : str
        The part file, absolute.
    relative_path : str
        The entry: the path relative to the store's indexed folder.
    metadata : dict
        Key -> value of every metadata key with a value for this entry.
    parent : str or None
        A sub-entry's file (``query --parts``), relative to the indexed folder; ``path`` is then
        that file, absolute, and ``relative_path`` the sub-entry (``FILE#n``). None for a whole file.
    count : int or None
        How many times ``parent`` holds the sub-part (None for a whole file).
    shape_gap : float or None
        With the same-part order (``--same-part``): the gap of its exact measures to the
        query's (:func:`shapeidx.search.same_part.shape_gap`; 0: the same size, in some unit,
        and proportions), which ordered it with its distance. None otherwise.
    """

    rank: int
    distance: float
    path: str
    relative_path: str
    metadata: dict = field(default_factory=dict)
    parent: str | None = None
    count: int | None = None
    shape_gap: float | None = None

    def to_dict(self) -> dict:
        out = {"rank": self.rank, "distance": self.distance, "path": self.path,
               "relative_path": self.relative_path, "metadata": dict(self.metadata)}
        if self.parent is not None:  # a sub-entry: the fields of a whole file's hit stay as they were
            out.update(parent=self.parent, count=self.count)
        if self.shape_gap is not None:
            out["shape_gap"] = self.shape_gap
        return out


@dataclass
class Answer:
    """A query's answer.

    Attributes
    ----------
    query : str
        The query as given (a file name, ``-``, an entry).
    query_path : str or None
        The query file, absolute (None for standard input and entries).
    entry : str or None
        The query's own entry in the store, when it has one (``--id``, or a file of the tree).
    metric : str
    store, root : str
        The store and its indexed folder.
    hits : list of Hit
    considered : int
        Entries the filters left to rank (all of the store's ok entries without filters).
    entries : int
        The store's ok entries.
    reason : str or None
        Why there is no hit, in words (None when there are hits).
    why : str or None
        The same, in a word of :data:`NO_HIT` (None when there are hits).
    filters : list of str
        The filters that applied, as given.
    signature : Signature
        The query's signature (what sheets and the web page draw).
    """

    query: str
    query_path: str | None
    entry: str | None
    metric: str
    store: str
    root: str
    hits: list
    considered: int
    entries: int
    reason: str | None = None
    filters: list = field(default_factory=list)
    signature: object = None
    #: With ``--max-distance`` and no hit: the nearest distance there was (merging shards' answers).
    nearest: float | None = None
    #: With the same-part order: the query's smallest distances, which set the scale of the
    #: gaps (:mod:`shapeidx.search.same_part`; merging shards' answers).
    nearest_distances: list | None = None
    why: str | None = None

    def to_dict(self) -> dict:
        """The JSON object of one query (docs/cli.md documents every field)."""
        return {"query": self.query, "query_path": self.query_path, "entry": self.entry, "metric": self.metric,
                "store": self.store, "root": self.root, "filters": list(self.filters), "entries": self.entries,
                "considered": self.considered, "hits": [hit.to_dict() for hit in self.hits]}


def absolute(root: str | None, relative: str) -> str:
    return os.path.join(root, relative) if root else relative
