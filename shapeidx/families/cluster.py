"""``shapeidx cluster``: the whole store in families of similar parts.

Two roads, by the store's size:

* up to :data:`MATRIX_LIMIT` entries, the exact distance matrix (every pair, by
  :meth:`FamilyTable.pair_distances`) and scipy's hierarchical clustering with Ward's
  criterion on it (measured against average and complete linkage on kicad6:
  docs/results.md);
* above, the graph road: each entry's :data:`GRAPH_NEIGHBOURS` nearest neighbours
  (candidates of :mod:`shapeidx.store.candidates`, confirmed with the exact distance), the
  edges weighted by local scaling; its communities by Leiden (constant Potts model, the
  resolution found by bisection) are the *families*, about one per :data:`BLOCK_MEAN`
  entries or one per cluster asked for, whichever is fewer; exact Ward inside each family
  (a matrix of its members only, at most :data:`BLOCK_LIMIT` of them) splits the families
  further, the highest Ward merges of the whole forest undone first, until there are as many
  clusters as asked for. Time and memory grow as N k plus the sum of the families' squared
  sizes (at most N times :data:`BLOCK_LIMIT`), not N^2.

Why: single linkage on the same graph (this road until issue 22) chains: on Debian's whole
KiCad 6 library (6,227 parts) it put 5,836 parts in one of 150 clusters. Leiden's CPM
communities must each be denser than the resolution, so none grows along a chain; and the
library measurement (docs/families.md: average and complete linkage on the sparse graph,
Ward on the embedding, HDBSCAN, Leiden alone and with Ward inside its communities, against
exact Ward on the full matrix) put this road first at 90 and 150 clusters and level with
exact Ward at 623.

``--scale sensitive`` adds a size term to the matrices (:data:`SIZE_PENALTY`) and keeps
pairs outside the size band out of the graph. ``--threshold D`` cuts Ward's trees at height
D (on the graph road: inside the families, never joining two) and ``--clusters K`` makes K
clusters; without either, :data:`DEFAULT_CLUSTERS_PER_ENTRY` sets K (one cluster per ten
parts, kicad6's ratio of parts to folders). Each entry gets its cluster (numbered from 1 by
size, largest first) and its distance to the cluster's most central member (the medoid:
least total distance to the other members).
"""

from __future__ import annotations

import numpy as np

from ..distance.metrics import default_metric
from ..errors import ShapeidxError
from ..store.candidates import candidate_pairs
from ..distance.scale import check_scale, ratio_within_band

#: Largest store clustered from the full distance matrix (N^2 / 2 exact distances).
MATRIX_LIMIT = 4000
#: Neighbours per entry in the graph road (10 agreed better with the folders than 15 or 30 on
#: the library and on kicad6: docs/families.md).
GRAPH_NEIGHBOURS = 10
#: The graph road's families hold this many entries on average (at least): above that many
#: clusters, exact Ward splits Leiden's communities (docs/families.md measures 1, 2, 3, 4).
BLOCK_MEAN = 40
#: Largest family given an exact matrix; a larger Leiden community is split again first.
BLOCK_LIMIT = 4000
#: Leiden's CPM resolution is searched between these (the edge weights lie in (0, 1]).
LEIDEN_RESOLUTION = (1e-7, 1.0)
#: Bisection steps at most, and the share of the wanted communities that ends the search
#: (Ward makes up the rest).
LEIDEN_STEPS = 40
LEIDEN_TOLERANCE = 0.98
#: The search also ends when the resolution's bracket is this narrow (hi / lo): where the count
#: of communities jumps over the wanted window (synthetic stores of 16 near copies per part at
#: 10^5 entries) the bisection otherwise ran all 40 steps, 96 of 212 s (docs/performance-families.md);
#: on the whole library the window is reached in 4 to 8 steps, before the bracket is this narrow.
LEIDEN_BRACKET = 1.01
#: Leiden's iterations per run, and its seed (the same seed, the same communities).
LEIDEN_ITERATIONS = 2
LEIDEN_SEED = 22
#: Default K = N / this (kicad6: 520 parts in 52 folders).
DEFAULT_CLUSTERS_PER_ENTRY = 10
DEFAULT_METRIC = default_metric("cluster")
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
                    moments: bool = True, base: np.ndarray | None = None, typical: float | None = None) -> np.ndarray:
    """(N, N) exact distances between every two entries, plus (``moments``) the exact-moment
    term of :data:`MOMENT_WEIGHT`.

    ``base``: the metric's own (N, N) matrix, when already computed. ``typical``: the unit of
    the moment and size terms (default: the median nearest-neighbour distance of this matrix;
    the graph road passes the whole store's, so that every block has the same terms).
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
    if len(d) and (moments or check_scale(scale) == "sensitive") and typical is None:
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


def neighbour_graph(table, metric: str, scale: str = "invariant", k: int = GRAPH_NEIGHBOURS, method: str = "auto",
                    threads: int | None = None):
    """Each entry's ``k`` nearest neighbours (candidates confirmed exactly) as weighted edges.

    Returns
    -------
    a, b : (E,) int64
        Every edge once, ``a < b``.
    weights : (E,) float64
        ``exp(-d^2 / (sigma_a sigma_b))``, sigma an entry's distance to its k-th neighbour
        (Zelnik-Manor & Perona's local scaling: a dense family and a sparse one weigh their
        own neighbours alike; measured against unit and 1/d weights in docs/families.md).
    typical : float
        The median distance of an entry to its nearest neighbour (the unit of the moment and
        size terms of :func:`distance_matrix`).
    """
    n = len(table)
    k = min(k, n - 1)
    _, _, _, neighbours, distances = candidate_pairs(table, metric, k, method, threads)
    rows = np.repeat(np.arange(n), k)
    cols, d = neighbours.ravel(), distances.ravel()
    valid = (cols >= 0) & np.isfinite(d)
    rows, cols, d = rows[valid], cols[valid], d[valid]
    if check_scale(scale) == "sensitive":
        keep = ratio_within_band(table.size_ratios(rows, cols))
        rows, cols, d = rows[keep], cols[keep], d[keep]
    finite = np.where(np.isfinite(distances), distances, np.nan)
    with np.errstate(all="ignore"):
        sigma = np.nanmax(finite, axis=1) if k else np.ones(n)
        typical = float(np.nanmedian(finite[:, 0])) if k else 1.0
    fallback = float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else 1.0
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, fallback if fallback > 0 else 1.0)
    weights = np.exp(-(d**2) / (sigma[rows] * sigma[cols]))
    a, b = np.minimum(rows, cols), np.maximum(rows, cols)
    # each edge once, with its larger weight (a pair in both lists has one distance)
    order = np.lexsort((-weights, a * n + b))
    first = np.concatenate([[True], np.diff((a * n + b)[order]) != 0]) if len(order) else np.zeros(0, bool)
    keep = order[first]
    if not np.isfinite(typical) or typical <= 0:
        typical = 1.0
    return a[keep], b[keep], weights[keep], typical


def leiden_communities(n: int, a: np.ndarray, b: np.ndarray, weights: np.ndarray, target: int,
                       seed: int | None = None) -> np.ndarray:
    """About ``target`` communities of the weighted graph (never more, unless its separate
    parts are more): Leiden (Traag et al. 2019, igraph's) with the constant Potts model, its
    resolution found by bisection. Returns each node's community, 0..C-1.

    CPM asks each community to be denser than the resolution, so unlike modularity it has
    no resolution limit and does not grow one community across a whole chain of neighbours.
    The same seed gives the same communities.
    """
    import random

    import igraph

    graph = igraph.Graph(n=n, edges=np.stack([a, b], axis=1).tolist(), directed=False)
    target = max(1, min(target, n))
    lo, hi = LEIDEN_RESOLUTION
    best = None  # (count, membership): the most communities not above target, else the fewest
    rng = random.Random(LEIDEN_SEED if seed is None else seed)
    try:
        for _ in range(LEIDEN_STEPS):
            resolution = float(np.sqrt(lo * hi))
            igraph.set_random_number_generator(random.Random(rng.random()))
            membership = np.asarray(graph.community_leiden(
                objective_function="CPM", weights=weights, resolution=resolution, n_iterations=LEIDEN_ITERATIONS
            ).membership, dtype=np.int64)
            count = int(membership.max()) + 1
            if best is None or (count <= target and (best[0] > target or count > best[0])) or (
                    count > target and best[0] > target and count < best[0]):
                best = (count, membership)
            if LEIDEN_TOLERANCE * target <= count <= target:
                break
            if count < target:
                lo = resolution
            else:
                hi = resolution
            if hi / lo < LEIDEN_BRACKET:
                break
    finally:
        igraph.set_random_number_generator(random)
    return best[1]


def ward_forest(table, blocks: np.ndarray, metric: str, scale: str, typical: float, clusters: int | None,
                threshold: float | None):
    """Exact Ward inside each block, one cut for the whole forest: (labels, medoid distances).

    ``clusters``: the forest's highest merges are undone, across blocks, until there are that
    many clusters (never fewer than the blocks); ``threshold``: every merge above that height.
    """
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import squareform

    n = len(table)
    members_of = _members(blocks)
    trees, heights, owner = {}, [], []
    matrices = {}
    for block, members in enumerate(members_of):
        if len(members) < 2:
            continue
        matrix = distance_matrix(table.subset(members), metric, scale, typical=typical)
        matrices[block] = matrix
        trees[block] = linkage(squareform(matrix, checks=False), "ward")
        heights.append(trees[block][:, 2])
        owner.append(np.full(len(members) - 1, block))
    undo = {}
    if clusters is not None and heights:
        extra = max(0, min(clusters, n) - len(members_of))
        all_heights, all_owner = np.concatenate(heights), np.concatenate(owner)
        highest = np.argsort(-all_heights, kind="stable")[:extra]
        undo = dict(zip(*np.unique(all_owner[highest], return_counts=True)))
    labels = np.zeros(n, dtype=np.int64)
    distances = np.zeros(n)
    next_label = 0
    for block, members in enumerate(members_of):
        if block not in trees:
            local = np.ones(len(members), dtype=np.int64)
        elif threshold is not None:
            local = fcluster(trees[block], threshold, "distance")
        else:
            local = fcluster(trees[block], int(undo.get(block, 0)) + 1, "maxclust")
        _, local = np.unique(local, return_inverse=True)
        labels[members] = local + next_label
        next_label += int(local.max()) + 1
        if block in matrices:
            distances[members] = medoid_distances(matrices[block], local)
    return labels, distances


def _members(labels: np.ndarray) -> list:
    """Indices of each label 0..L-1, in order."""
    order = np.argsort(labels, kind="stable")
    bounds = np.flatnonzero(np.diff(np.concatenate([[-1], labels[order], [labels.max() + 1 if len(labels) else 0]])))
    return [order[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:])]


def split_large(n, a, b, weights, blocks: np.ndarray, limit: int) -> np.ndarray:
    """Blocks of more than ``limit`` entries split again by Leiden on their own edges (so that
    no exact matrix is larger than ``limit`` squared)."""
    blocks = blocks.copy()
    for _ in range(8):
        sizes = np.bincount(blocks)
        large = np.flatnonzero(sizes > limit)
        if not len(large):
            break
        for block in large:
            members = np.flatnonzero(blocks == block)
            local = np.full(n, -1, dtype=np.int64)
            local[members] = np.arange(len(members))
            inside = (local[a] >= 0) & (local[b] >= 0)
            parts = leiden_communities(len(members), local[a[inside]], local[b[inside]], weights[inside],
                                       2 * -(-len(members) // limit))
            if parts.max() == 0:  # no split possible along the edges: cut it in order
                parts = np.arange(len(members)) * (2 * -(-len(members) // limit)) // len(members)
            blocks[members] = np.where(parts == 0, block, parts + blocks.max())
        _, blocks = np.unique(blocks, return_inverse=True)
    return blocks


def cluster_graph(table, metric: str, clusters: int | None, threshold: float | None, scale: str,
                  k: int = GRAPH_NEIGHBOURS, method: str = "auto", threads: int | None = None):
    """The graph road: (cluster numbers, distance to the medoid, blocks made).

    The store's families are Leiden's communities of the nearest-neighbour graph; where more
    clusters are asked for than there are families of :data:`BLOCK_MEAN` entries, exact Ward
    splits each family further (see the module docstring).
    """
    n = len(table)
    a, b, weights, typical = neighbour_graph(table, metric, scale, k, method, threads)
    blocks_wanted = max(1, round(n / BLOCK_MEAN))
    if clusters is not None:
        blocks_wanted = min(blocks_wanted, clusters)
    blocks = leiden_communities(n, a, b, weights, blocks_wanted)
    blocks = split_large(n, a, b, weights, blocks, BLOCK_LIMIT)
    labels, distances = ward_forest(table, blocks, metric, scale, typical, clusters, threshold)
    return _numbered_by_size(labels), distances, int(blocks.max()) + 1


def cluster_store(table, metric: str = DEFAULT_METRIC, clusters: int | None = None, threshold: float | None = None,
                  scale: str = "invariant", road: str = "auto", threads: int | None = None, keep=None) -> dict:
    """Cluster a :class:`~shapeidx.families.table.FamilyTable`.

    Parameters
    ----------
    clusters, threshold : int or float, optional
        At most one; neither: N / :data:`DEFAULT_CLUSTERS_PER_ENTRY` clusters.
    road : "auto", "matrix" or "graph"
        See the module docstring; "auto" takes the matrix up to :data:`MATRIX_LIMIT` entries.
    keep : (N,) bool, optional
        Only these entries (a ``--where`` filter's keep-mask over the table's entries).

    Returns
    -------
    dict
        ``paths``, ``clusters`` (numbers, 1 the largest), ``distances`` (to the medoid),
        ``road``, ``count`` (clusters made); on the matrix road of more than one entry also
        ``tree`` (scipy's Ward linkage, for :func:`shapeidx.families.cluster_plot.plot_clusters`);
        on the graph road ``families`` (Leiden's communities that Ward split).
    """
    if keep is not None:
        table = table.subset(keep)
    n = len(table)
    if n == 0:
        raise ShapeidxError("the store has no indexed entries to cluster")
    if clusters is not None and threshold is not None:
        raise ShapeidxError("give --clusters or --threshold, not both")
    if clusters is None and threshold is None:
        clusters = max(1, round(n / DEFAULT_CLUSTERS_PER_ENTRY))
    road = ("matrix" if n <= MATRIX_LIMIT else "graph") if road == "auto" else road
    families = None
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
        labels, distances, families = cluster_graph(table, metric, clusters, threshold, scale, threads=threads)
    result = {"paths": table.paths, "clusters": labels, "distances": distances, "road": road, "count": int(labels.max())}
    if road == "matrix" and n > 1:
        result["tree"] = tree  # scipy's linkage: the dendrogram of ``cluster --plot``
    if families is not None:
        result["families"] = families
    return result
