"""Retrieval quality of a labelled collection: NN, first and second tier, E-measure, DCG.

Definitions follow the Princeton Shape Benchmark (Shilane et al. 2004) as written in
``shared/reference/retrieval-metrics.md``: every model is the query once, against all the
others (itself left out); ``C`` is the size of its class, so there are ``C - 1`` relevant
models; every figure is the mean over all queries.
"""

from __future__ import annotations

import numpy as np

SCORES = ("nn", "ft", "st", "e", "dcg")
#: Results the E-measure looks at.
E_DEPTH = 32


def rank_lists(distances: np.ndarray) -> np.ndarray:
    """Per query (row), the other models from nearest to farthest.

    Ties are broken by model index, so the ranking is deterministic. The query itself is
    left out: the result has one column fewer than ``distances``.
    """
    n = len(distances)
    d = np.array(distances, dtype=np.float64)
    np.fill_diagonal(d, np.inf)
    order = np.argsort(d, axis=1, kind="stable")
    return order[:, : n - 1]


def retrieval_scores(distances: np.ndarray, labels, per_query: bool = False) -> dict:
    """NN, FT, ST, E and DCG of a square distance matrix over labelled models.

    Parameters
    ----------
    distances : (n, n) float
        ``distances[q, k]`` is the distance from query ``q`` to model ``k``.
    labels : sequence of length n
        Class of each model. Models alone in their class (no relevant answer) are skipped
        as queries but still appear in the other queries' lists.
    per_query : bool
        Also return the five scores of every query (``"queries"``: dict of arrays).

    Returns
    -------
    dict
        ``{"nn", "ft", "st", "e", "dcg"}`` means over the queries, and ``"queries"`` (count).
    """
    labels = np.asarray(labels)
    _, class_of = np.unique(labels, return_inverse=True)
    class_size = np.bincount(class_of)[class_of]
    queries = np.flatnonzero(class_size > 1)
    if len(queries) == 0:  # no model has a relevant answer: nothing to score
        result = {name: float("nan") for name in SCORES} | {"queries": 0}
        return result | ({"per_query": {"index": queries} | {s: np.zeros(0) for s in SCORES}} if per_query else {})
    ranked = rank_lists(distances)[queries]
    relevant = class_of[ranked] == class_of[queries][:, None]  # (q, n - 1) bool
    wanted = class_size[queries] - 1  # C - 1 per query
    hits = np.cumsum(relevant, axis=1)

    def hits_within(depth):
        return hits[np.arange(len(queries)), np.minimum(depth, hits.shape[1]) - 1]

    nn = relevant[:, 0].astype(float)
    ft = hits_within(wanted) / wanted
    st = hits_within(2 * wanted) / wanted
    found = hits_within(np.full(len(queries), E_DEPTH))
    precision, recall = found / min(E_DEPTH, hits.shape[1]), found / wanted
    e = np.divide(2 * precision * recall, precision + recall, out=np.zeros(len(queries)), where=found > 0)
    # DCG_1 = G_1, DCG_i = DCG_(i-1) + G_i / log2(i): discount 1 for i = 1, 1 / log2(i) after
    discount = np.ones(hits.shape[1])
    discount[1:] = 1.0 / np.log2(np.arange(2, hits.shape[1] + 1))
    dcg = relevant @ discount
    ideal = np.cumsum(discount)[wanted - 1]
    dcg = dcg / ideal

    per = {"nn": nn, "ft": ft, "st": st, "e": e, "dcg": dcg}
    result = {name: float(values.mean()) if len(queries) else float("nan") for name, values in per.items()}
    result["queries"] = int(len(queries))
    if per_query:
        result["per_query"] = {"index": queries, **per}
    return result
