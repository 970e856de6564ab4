"""``shapeidx classify``: a part's category from its nearest labelled neighbours.

Each of the ``k`` nearest labelled entries votes for its label with weight
``1 - d / d_(k+1)`` (Dudani's distance-weighted rule: the nearest counts most, the k-th
little, and the scale of the distance does not matter), with a small floor so that ``k``
neighbours at one distance still vote. The label with the largest total wins; its
*confidence* is its share of the total weight (1: every voter agrees). Defaults (k, metric)
are the ones measured best by leave-one-out on kicad6 (docs/results.md).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from ..distance.metrics import default_metric
from ..errors import ShapeidxError

#: Voters (measured by leave-one-out on kicad6, docs/results.md).
DEFAULT_K = 3
DEFAULT_METRIC = default_metric("classify")
#: Smallest weight a voter gets (share of the nearest voter's).
WEIGHT_FLOOR = 0.05


def vote_weights(distances: np.ndarray, next_distance: float) -> np.ndarray:
    """Dudani weights of sorted voter distances, given the distance of the first non-voter."""
    distances = np.asarray(distances, dtype=np.float64)
    if len(distances) == 0:
        return distances
    far, near = (next_distance if np.isfinite(next_distance) else distances[-1]), distances[0]
    if far <= near:
        return np.ones(len(distances))
    return np.maximum((far - distances) / (far - near), WEIGHT_FLOOR)


def vote(distances: np.ndarray, labels: np.ndarray, k: int = DEFAULT_K) -> dict:
    """The k-NN vote among labelled voters.

    Parameters
    ----------
    distances : (m,) float
        Distance of the query to every voter (inf: not a voter).
    labels : (m,) object
        The voters' labels.
    k : int

    Returns
    -------
    dict
        ``label`` (None if no voter), ``confidence`` in [0, 1], ``voters``: indices of the
        voters, nearest first, and ``weights``.
    """
    finite = np.flatnonzero(np.isfinite(distances))
    if len(finite) == 0:
        return {"label": None, "confidence": 0.0, "voters": np.zeros(0, np.int64), "weights": np.zeros(0)}
    order = finite[np.argsort(distances[finite], kind="stable")]
    voters = order[:k]
    next_distance = float(distances[order[k]]) if len(order) > k else float("inf")
    weights = vote_weights(distances[voters], next_distance)
    totals = defaultdict(float)
    for label, w in zip(labels[voters], weights):
        totals[label] += w
    # ties: the label of the nearer voter wins
    best = max(totals, key=lambda lab: (totals[lab], -next(i for i, v in enumerate(voters) if labels[v] == lab)))
    return {"label": best, "confidence": float(totals[best] / weights.sum()), "voters": voters, "weights": weights}


def leave_one_out(matrix: np.ndarray, labels: np.ndarray, k: int = DEFAULT_K) -> dict:
    """Leave-one-out classification of every labelled model by the others' vote.

    Parameters
    ----------
    matrix : (n, n) float
        Distances between the models.
    labels : (n,) object

    Returns
    -------
    dict
        ``accuracy`` (share of models whose vote gives their own label), ``predicted`` (n,)
        and ``confidence`` (n,).
    """
    n = len(labels)
    predicted = np.empty(n, dtype=object)
    confidence = np.zeros(n)
    for i in range(n):
        d = np.array(matrix[i], dtype=np.float64)
        d[i] = np.inf
        result = vote(d, labels, k)
        predicted[i], confidence[i] = result["label"], result["confidence"]
    correct = predicted == labels
    return {"accuracy": float(correct.mean()) if n else float("nan"), "predicted": predicted, "confidence": confidence}


def classify_parts(searcher, parts, labels: dict, k: int = DEFAULT_K, metric: str = DEFAULT_METRIC,
                   filters=None, threads: int = 1) -> list[dict]:
    """Classify each part (a file, or an entry path of the store) by the store's labelled entries.

    The voters are found by the one search road (a searcher of
    :func:`~shapeidx.search.open_searcher`: one store or a sharded one, of its files or of its
    sub-parts): the ``k + 1`` nearest labelled entries that ``filters`` keep (``--where``,
    ``--scale``), the part's own entry left out; a file of the tree asked of the sub-parts
    (``classify --parts``) leaves out its own sub-parts (``FILE#n``) instead.

    Parameters
    ----------
    searcher : an open searcher (:data:`~shapeidx.search.searcher.QUERY_INTERFACE`)
    parts : list of str
        Files to sign (with the store's parameters), or relative paths of store entries. A
        part that is itself in the store does not vote for itself.
    labels : dict
        The label of each entry path (None or absent: not a voter).
    k, metric : see :func:`vote`
    filters : :class:`~shapeidx.search.Filters`, optional

    Returns
    -------
    list of dict
        Per part, in the order given: ``path``, ``label``, ``confidence``, ``neighbours``
        (``path``, ``label``, ``distance``, ``weight`` of each voter).
    """
    import os
    from dataclasses import replace

    from ..search import Filters

    voters = frozenset(path for path, label in labels.items() if label is not None)
    if not voters:
        raise ShapeidxError(
            f"store {searcher.store} has no labelled entries (no part lies in a folder deep enough for the labels);"
            " give --labels FILE or a smaller --label-depth"
        )
    filters = replace(filters or Filters(), exclude_self=True)
    entries = set(searcher.entry_paths())
    results = []
    for part in parts:
        if part in entries:  # a path of the store
            query = searcher.query_of_entry(part)
        elif os.path.exists(part):  # a file, perhaps inside the indexed folder
            query = searcher.query_of_part(part, threads=threads)
        else:
            raise ShapeidxError(f"{part}: no such file, and no entry of that path in {searcher.store}")
        among = voters
        if getattr(searcher, "parts", False) and query.own is None and query.entry is None:
            # a file's own sub-parts are not its entry in the search's eyes: leave them out here
            own = searcher.entry_path_of(part)
            if own is not None:
                among = frozenset(p for p in voters if p.rpartition("#")[0] != own)
        answer = searcher.search(query, k + 1, metric, filters, among=among,
                                 among_reason="no labelled entry is left to vote")
        hits = answer.hits
        distances = np.array([hit.distance for hit in hits], dtype=np.float64)
        voter_labels = np.array([labels[hit.relative_path] for hit in hits], dtype=object)
        result = vote(distances, voter_labels, k)
        results.append({
            "path": part,
            "label": result["label"],
            "confidence": result["confidence"],
            "neighbours": [
                {"path": hits[i].relative_path, "label": voter_labels[i], "distance": float(distances[i]), "weight": float(w)}
                for i, w in zip(result["voters"], result["weights"])
            ],
        })
    return results
