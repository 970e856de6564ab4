"""``shapeidx cluster``: the whole store in families of similar parts.

Two roads, by the store's size:

* up to :data:`MATRIX_LIMIT` entries, the exact distance matrix (every pair, by
  :meth:`FamilyTable.pair_distances`) and scipy's hierarchical clustering with Ward's
  criterion on it (measured against average and complete linkage on kicad6:
  docs/results.md);
* above, a graph of each entry's :data:`GRAPH_NEIGHBOURS` nearest neighbours (candidates of
  :mod:`.candidates`, confirmed with the exact distance) and single linkage on it: its
  minimum spanning forest, cut at the threshold or into ``clusters`` trees by dropping the
  longest edges. Memory and time grow as N k, not N^2.

``--scale sensitive`` adds a size term to the matrix (:data:`SIZE_PENALTY`) and keeps pairs
outside the size band out of the graph. Either way ``--threshold D`` cuts the tree at distance D and ``--clusters K`` into K
clusters; without either, :data:`DEFAULT_CLUSTERS_PER_ENTRY` sets K (one cluster per ten
parts, kicad6's ratio of parts to folders). Each entry gets its cluster (numbered from 1 by
size, largest first) and its distance to the cluster's most central member (the medoid:
least total distance to the other members; on the graph road, among the members'
neighbours).
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeidxError
from ..store.candidates import candidate_pairs
from ..distance.scale import check_scale, ratio_within_band

#: Largest store clustered from the full distance matrix (N^2 / 2 exact distances).
MATRIX_LIMIT = 4000
#: Neighbours per entry in the graph road.
GRAPH_NEIGHBOURS = 15
#: Default K = N / this (kicad6: 520 parts in 52 folders).
DEFAULT_CLUSTERS_PER_ENTRY = 10
DEFAULT_METRIC = "combined"
#: Finite stand-in for "apart" (pairs outside the size band under --scale sensitive).
APART = 1e6
#: ``--scale sensitive`` in the matrix road: a pair's distance grows by this share of the
#: median nearest-neighbour distance per factor e of size ratio. Infinite distances (the
#: band of ``query`` and ``classify``) break Ward's criterion; this was the best of 0.25,
#: 0.5 and 1 on kicad6 (docs/results.md).
SIZE_PENALTY = 0.5
#: The exact moments' share (:func:`moment_gap`, times the median nearest-neighbour
#: distance): the best of 0, 0.1, 0.25, 0.5, 1 on kicad6 for Ward's agreement with the
#: classes (docs/results.md); a part's proportions are what D2 at 1024 points blurs.
MOMENT_WEIGHT = 0.1


def distance_matrix(table, metric: str = DEFAULT_METRIC, scale: str = "invariant", band: bool = False,
                    moments: bool = True, base: np.ndarray | None = None) -> np.ndarray:
    """(N, N) exact distances between every two entries, plus (``moments``) the exact-moment
    term of :data:`MOMENT_WEIGHT`.

    ``base``: the metric's own (N, N) matrix, when already computed.
    ``scale="sensitive"`` adds the size term of :data:`SIZE_PENALTY` (``band``: instead, pairs
    outside the size band are :data:`APART`, as ``classify`` and ``query`` keep them apart).
    """
    n = len(table)
    i, j = np.triu_indices(n, 1)
    if base is not None:  # the metric's matrix, already computed
        d = np.asarray(base)[i, j]
    else:
        d = table.pair_distances(i, j, metric) if len(i) else np.zeros(0)
    matrix = np.zeros((n, n))
    matrix[i, j] = d
    matrix[j, i] = d
    if len(d) and (moments or check_scale(scale) == "sensitive"):
        np.fill_diagonal(matrix, np.inf)
        typical = float(np.median(matrix.min(axis=1)))
        np.fill_diagonal(matrix, 0.0)
    if moments and len(d) and MOMENT_WEIGHT:
        d = d + MOMENT_WEIGHT * typical * moment_gap(table, i, j)
        matrix[i, j] = d
        matrix[j, i] = d
    if check_scale(scale) == "sensitive" and len(d):
        ratios = table.size_ratios(i, j)
        if band:
            d = np.where(ratio_within_band(ratios), d, APART)
        else:
            d = d + SIZE_PENALTY * typical * np.nan_to_num(np.abs(np.log(ratios)))
        matrix[i, j] = d
        matrix[j, i] = d
    return matrix


def moment_gap(table, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sum of the ``|ln|`` gaps of the proportions r2/r1, r3/r1 and of area / sum r^2 (unknown: 0)."""
    def features(rows):
        e = table.extents[rows]
        area = table.moments[rows, 0] if table.moments is not None else np.full(len(rows), np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack([np.log(e[:, 1] / e[:, 0]), np.log(e[:, 2] / e[:, 0]), np.log(area)], axis=1)

    return np.nan_to_num(np.abs(features(a) - features(b))).sum(axis=1)


def _numbered_by_size(labels: np.ndarray) -> np.ndarray:
    """Cluster numbers 1..K, 1 the largest (ties: the one whose first member comes first)."""
    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    first = np.full(len(counts), len(labels))
    np.minimum.at(first, inverse, np.arange(len(labels)))
    order = np.lexsort((first, -counts))
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(1, len(order) + 1)
    return rank[inverse]


def cluster_matrix(matrix: np.ndarray, clusters: int | None = None, threshold: float | None = None,
                   method: str = "ward", tree: np.ndarray | None = None) -> np.ndarray:
    """Hierarchical clustering of a distance matrix: cluster numbers (1 = largest).

    ``tree``: scipy's linkage of ``matrix`` by ``method``, when already made.
    """
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import squareform

    n = len(matrix)
    if n == 1:
        return np.ones(1, dtype=np.int64)
    tree = linkage(squareform(matrix, checks=False), method) if tree is None else tree
    if threshold is not None:
        labels = fcluster(tree, threshold, "distance")
    else:
        labels = fcluster(tree, min(clusters, n), "maxclust")
    return _numbered_by_size(labels)


def medoid_distances(matrix: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Each entry's distance to its cluster's medoid."""
    out = np.zeros(len(labels))
    for c in np.unique(labels):
        members = np.flatnonzero(labels == c)
        sub = matrix[np.ix_(members, members)]
        out[members] = sub[:, int(np.argmin(sub.sum(axis=1)))]
    return out


def cluster_graph(table, metric: str, clusters: int | None, threshold: float | None, scale: str,
                  k: int = GRAPH_NEIGHBOURS, method: str = "auto", threads: int | None = None):
    """Single linkage on the nearest-neighbour graph: (cluster numbers, distance to the medoid)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    n = len(table)
    a, b, d, _, _ = candidate_pairs(table, metric, min(k, n - 1), method, threads)
    if check_scale(scale) == "sensitive":
        keep = ratio_within_band(table.size_ratios(a, b))
        a, b, d = a[keep], b[keep], d[keep]
    # a zero weight is "no edge" to scipy's sparse graphs: identical entries get a tiny one
    weights = np.maximum(d, 1e-300)
    forest = minimum_spanning_tree(coo_matrix((weights, (a, b)), shape=(n, n)).tocsr()).tocoo()
    fa, fb, fw = forest.row, forest.col, forest.data
    if threshold is not None:
        keep = fw <= threshold
    else:
        parts_now, _ = connected_components(coo_matrix((fw, (fa, fb)), shape=(n, n)), directed=False)
        cut = max(0, min(clusters, n) - parts_now)
        keep = np.ones(len(fw), dtype=bool)
        if cut:
            keep[np.argsort(-fw, kind="stable")[:cut]] = False
    _, labels = connected_components(coo_matrix((fw[keep], (fa[keep], fb[keep])), shape=(n, n)), directed=False)
    labels = _numbered_by_size(labels)
    # medoid among each cluster's graph edges: the member with the least mean distance to its
    # neighbours in the cluster; every member's distance to it is then computed exactly
    same = labels[a] == labels[b]
    total = np.bincount(a[same], d[same], n) + np.bincount(b[same], d[same], n)
    count = np.bincount(a[same], minlength=n) + np.bincount(b[same], minlength=n)
    mean = np.where(count > 0, total / np.maximum(count, 1), np.inf)
    order = np.lexsort((mean, labels))
    first = np.concatenate([[True], labels[order][1:] != labels[order][:-1]])
    medoid_of = np.zeros(labels.max() + 1, dtype=np.int64)
    medoid_of[labels[order][first]] = order[first]
    medoids = medoid_of[labels]
    distances = table.pair_distances(np.arange(n), medoids, metric)
    distances[medoids == np.arange(n)] = 0.0
    return labels, distances


def cluster_store(table, metric: str = DEFAULT_METRIC, clusters: int | None = None, threshold: float | None = None,
                  scale: str = "invariant", road: str = "auto", threads: int | None = None) -> dict:
    """Cluster a :class:`~shapeidx.families.table.FamilyTable`.

    Parameters
    ----------
    clusters, threshold : int or float, optional
        At most one; neither: N / :data:`DEFAULT_CLUSTERS_PER_ENTRY` clusters.
    road : "auto", "matrix" or "graph"
        See the module docstring; "auto" takes the matrix up to :data:`MATRIX_LIMIT` entries.

    Returns
    -------
    dict
        ``paths``, ``clusters`` (numbers, 1 the largest), ``distances`` (to the medoid),
        ``road``, ``count`` (clusters made); on the matrix road of more than one entry also
        ``tree`` (scipy's Ward linkage, for :func:`shapeidx.families.cluster_plot.plot_clusters`).
    """
    n = len(table)
    if n == 0:
        raise ShapeidxError("the store has no indexed entries to cluster")
    if clusters is not None and threshold is not None:
        raise ShapeidxError("give --clusters or --threshold, not both")
    if clusters is None and threshold is None:
        clusters = max(1, round(n / DEFAULT_CLUSTERS_PER_ENTRY))
    road = ("matrix" if n <= MATRIX_LIMIT else "graph") if road == "auto" else road
    if n == 1:
        labels, distances = np.ones(1, dtype=np.int64), np.zeros(1)
    elif road == "matrix":
        from scipy.cluster.hierarchy import linkage
        from scipy.spatial.distance import squareform

        matrix = distance_matrix(table, metric, scale)
        tree = linkage(squareform(matrix, checks=False), "ward")
        labels = cluster_matrix(matrix, clusters, threshold, tree=tree)
        distances = medoid_distances(matrix, labels)
    else:
        labels, distances = cluster_graph(table, metric, clusters, threshold, scale, threads=threads)
    result = {"paths": table.paths, "clusters": labels, "distances": distances, "road": road, "count": int(labels.max())}
    if road == "matrix" and n > 1:
        result["tree"] = tree  # scipy's linkage: the dendrogram of ``cluster --plot``
    return result
