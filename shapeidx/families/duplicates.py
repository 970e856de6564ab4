"""``shapeidx duplicates``: groups of store entries that are the same part.

Every pair found is put in one tier:

* ``identical``: the same file content (SHA-256);
* ``same``: the same geometry: the shape distance is within the noise of signing one part
  with other random points (``thresholds.json``, measured per metric by
  ``scripts/duplicates_study.py --noise``, see docs/duplicates.md) and the exact surface
  moments agree (:func:`fingerprint_gap` within :data:`FINGERPRINT_SAME`). The second test
  is needed: on kicad6 the sampling noise of D2 at 1024 points is larger than the distance
  between many pairs of different parts of one family;
* ``near``: a near duplicate: distance within the looser ``near`` threshold and moments
  within :data:`FINGERPRINT_NEAR`.

Each pair also says ``size_ratio`` (size of ``b`` over size of ``a``; sizes are mean pair
distances in file units, so a copy saved in inches shows 1/25.4) and ``mirrored`` (one is the
mirror image of the other, by :func:`shapeidx.families.chirality.mirror_relation`; always
false for parts that are their own mirror image). With ``scale="sensitive"`` a pair whose
sizes differ by more than :data:`~shapeidx.distance.scale.SIZE_BAND` is no duplicate.

Candidates come from :func:`shapeidx.store.candidates.candidate_pairs`, twice: each
entry's nearest neighbours in the D2 embedding, and in the space of its exact moments
(:func:`fingerprint_vectors`); all are confirmed with the exact distance, so the work grows
as N k, not N^2. Groups are the connected components of the pairs found; a group of up to
:data:`ALL_PAIRS_GROUP` members lists every pair found among them, a larger one the pairs of
a minimum spanning tree (best tier first, then least distance), which link it. Nothing is ever
deleted or moved.
"""

from __future__ import annotations


import numpy as np

from ..errors import ShapeidxError
from ..store.candidates import OVERFETCH as OVERFETCH_MOMENTS, candidate_pairs
from .chirality import mirror_relation
from ..distance.scale import check_scale, ratio_within_band

TIERS = ("identical", "same", "near")
DEFAULT_METRIC = "combined"
#: Candidate neighbours per entry.
DEFAULT_NEIGHBOURS = 20
#: Largest :func:`fingerprint_gap` for ``same`` and for ``near`` (docs/duplicates.md).
FINGERPRINT_SAME = 0.02
FINGERPRINT_NEAR = 0.06


def thresholds(metric: str) -> dict:
    """``{"same": d, "near": d}`` for ``metric`` (its registry record's, see the module docstring)."""
    from ..distance.metrics import REGISTRY, duplicate_metrics

    found = REGISTRY[metric].duplicate_thresholds if metric in REGISTRY else None
    if found is None:
        raise ShapeidxError(f"no duplicate thresholds measured for metric {metric!r} (have: {', '.join(duplicate_metrics())})")
    return found


def aspect_gap(extents_a: np.ndarray, extents_b: np.ndarray) -> np.ndarray:
    """Largest ``|ln|`` difference of the proportions r2/r1 and r3/r1 (NaN: unknown)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pa = np.log(extents_a[:, 1:] / extents_a[:, :1])
        pb = np.log(extents_b[:, 1:] / extents_b[:, :1])
        return np.abs(pa - pb).max(axis=1)


def fingerprint_gap(table, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """How far apart two parts' exact, scale-free surface moments are (NaN: unknown).

    The largest of: the proportions' ``|ln|`` gaps (:func:`aspect_gap`), the ``|ln|`` gap of
    area / sum r^2, and the gaps of the absolute skewnesses along the principal axes. These
    are integrals of the surface, not samples: a rotated, mirrored, rescaled or re-saved copy
    has the same values to rounding, where D2 distances carry the sampling noise.
    """
    gaps = [aspect_gap(table.extents[a], table.extents[b])]
    if table.moments is not None:
        ma, mb = table.moments[a], table.moments[b]
        with np.errstate(divide="ignore", invalid="ignore"):
            gaps.append(np.abs(np.log(ma[:, 0] / mb[:, 0])))
        gaps.append(np.abs(ma[:, 1:] - mb[:, 1:]).max(axis=1) if len(a) else np.zeros(0))
    stacked = np.stack(gaps, axis=1)
    out = np.full(len(a), np.nan)
    known = ~np.isnan(stacked).all(axis=1)
    out[known] = np.nanmax(stacked[known], axis=1)
    return out


def fingerprint_vectors(table) -> np.ndarray | None:
    """The moments of :func:`fingerprint_gap` as vectors (NaN as 0), or None if all unknown."""
    if table.moments is None:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        proportions = np.log(table.extents[:, 1:] / table.extents[:, :1])
        vectors = np.concatenate([proportions, np.log(table.moments[:, :1]), table.moments[:, 1:]], axis=1)
    if np.isnan(vectors).all():
        return None
    return np.nan_to_num(vectors, nan=0.0, posinf=0.0, neginf=0.0)


#: Entries sharing one exact fingerprint (copies of one surface) are all paired with each
#: other up to this many; a larger set pairs each member with the first and its neighbours.
ALL_PAIRS_LIMIT = 200


def _candidates(table, metric, k, method, threads):
    """Candidate pairs by the D2 embedding and by the exact moments, confirmed, each once.

    Copies of one surface share their moments exactly, so they would fill each other's
    nearest-moment lists; the moment search therefore runs over the distinct fingerprints
    (each once), pairs the first entry of each with the first of its neighbours, and pairs
    the entries of one fingerprint among themselves.
    """
    from ..store.candidates import CandidateIndex

    a, b, _, _, _ = candidate_pairs(table, metric, k, method, threads)
    pieces_a, pieces_b = [a], [b]
    vectors = fingerprint_vectors(table)
    if vectors is not None:
        unique, first, inverse = np.unique(vectors, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
        if len(unique) > 1:
            index = CandidateIndex(unique, method, threads)
            _, found = index.search(unique, min(OVERFETCH_MOMENTS * k, len(unique) - 1) + 1)
            rows = np.repeat(first, found.shape[1])
            cols = found.ravel()
            keep = cols >= 0
            pieces_a.append(rows[keep])
            pieces_b.append(first[cols[keep]])
        order = np.argsort(inverse, kind="stable")
        bounds = np.flatnonzero(np.diff(np.concatenate([[-1], inverse[order], [-2]])))
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            members = order[lo:hi]
            if len(members) < 2:
                continue
            if len(members) <= ALL_PAIRS_LIMIT:
                i, j = np.triu_indices(len(members), 1)
                pieces_a.append(members[i])
                pieces_b.append(members[j])
            else:
                pieces_a.append(np.full(len(members) - 1, members[0]))
                pieces_b.append(members[1:])
    a, b = np.concatenate(pieces_a), np.concatenate(pieces_b)
    a, b = np.minimum(a, b), np.maximum(a, b)
    keep = a != b
    a, b = a[keep], b[keep]
    _, once = np.unique(a * len(table) + b, return_index=True)
    a, b = a[once], b[once]
    return a, b, table.pair_distances(a, b, metric)


#: Groups up to this size list every pair found among their members; larger ones list the
#: pairs of a minimum spanning tree (tier first, then distance): enough to link them.
ALL_PAIRS_GROUP = 12


def _linking_pairs(n, pa, pb, tier, dist):
    """The pairs a group lists: all of a small group's, a spanning tree's in a large one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    a, b = np.minimum(pa, pb), np.maximum(pa, pb)
    order = np.lexsort((dist, tier))  # per pair of entries, its best tier, then distance
    key = a[order] * n + b[order]
    _, first = np.unique(key, return_index=True)
    keep = order[first]
    a, b, tier, dist = a[keep], b[keep], tier[keep], dist[keep]
    _, component = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    size = np.bincount(component, minlength=n)
    small = size[component[a]] <= ALL_PAIRS_GROUP
    # spanning tree of the large groups: weight orders by tier, then by distance
    span = np.flatnonzero(~small)
    chosen = np.flatnonzero(small)
    if len(span):
        scale = float(dist[span].max()) + 1.0
        weight = tier[span] * scale + dist[span] + 1e-9
        tree = minimum_spanning_tree(coo_matrix((weight, (a[span], b[span])), shape=(n, n)).tocsr()).tocoo()
        span_keys = a[span] * n + b[span]  # increasing: the pairs came out of np.unique sorted by key
        tree_keys = np.minimum(tree.row, tree.col).astype(np.int64) * n + np.maximum(tree.row, tree.col)
        chosen = np.concatenate([chosen, span[np.searchsorted(span_keys, tree_keys)]]).astype(np.int64)
    return a[chosen], b[chosen], tier[chosen], dist[chosen]


class _UnionFind:
    def __init__(self, n: int):
        self.parent = np.arange(n)

    def find(self, i: int) -> int:
        root = i
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[i] != root:
            self.parent[i], i = root, self.parent[i]
        return root

    def union(self, a: int, b: int) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[max(ra, rb)] = min(ra, rb)


def _geometry_tiers(table, a, b, d, limits: dict, scale: str):
    """(same, near) masks of pairs ``a``-``b`` at distances ``d`` (different files)."""
    gap = fingerprint_gap(table, a, b)
    unknown = np.isnan(gap)
    same = (d <= limits["same"]) & (unknown | (gap <= FINGERPRINT_SAME))
    near = ~same & (d <= limits["near"]) & (unknown | (gap <= FINGERPRINT_NEAR))
    if scale == "sensitive":
        band = ratio_within_band(table.size_ratios(a, b))
        same, near = same & band, near & band
    return same, near


def pair_tiers(table, a: np.ndarray, b: np.ndarray, metric: str = DEFAULT_METRIC, scale: str = "invariant",
               limits: dict | None = None) -> dict:
    """The tier :func:`find_duplicates` gives the pairs ``a``-``b`` (rows of ``table``), asked directly.

    Returns
    -------
    dict
        Arrays aligned with the pairs: ``tier`` ("identical", "same", "near" or "" for
        none), ``distance``, ``size_ratio`` (b over a), ``mirrored``.
    """
    check_scale(scale)
    limits = limits or thresholds(metric)
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    d = table.pair_distances(a, b, metric) if len(a) else np.zeros(0)
    hashes = table.hashes
    identical = (hashes[a] == hashes[b]) & np.array([len(h) > 0 for h in hashes[a]], dtype=bool)
    same, near = _geometry_tiers(table, a, b, d, limits, scale)
    tier = np.where(identical, "identical", np.where(same, "same", np.where(near, "near", "")))
    return {"tier": tier, "distance": np.where(identical, 0.0, d), "size_ratio": table.size_ratios(a, b),
            "mirrored": mirror_relation(table.handedness[a], table.handedness[b])}


def find_duplicates(table, metric: str = DEFAULT_METRIC, scale: str = "invariant", k: int = DEFAULT_NEIGHBOURS,
                    method: str = "auto", threads: int | None = None, limits: dict | None = None) -> list[dict]:
    """Duplicate groups of a :class:`~shapeidx.families.table.FamilyTable`.

    Returns
    -------
    list of dict
        Groups, largest first: ``members`` (paths, sorted) and ``pairs`` (``a``, ``b``,
        ``tier``, ``distance``, ``size_ratio``, ``mirrored``).
    """
    check_scale(scale)
    limits = limits or thresholds(metric)
    n = len(table)
    if n == 0:
        return []
    pairs_a, pairs_b, tiers, dists = [], [], [], []
    # identical files: every member to the first of its hash
    hashes = table.hashes
    order = np.argsort(hashes, kind="stable")
    sorted_hashes = hashes[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_hashes[1:] != sorted_hashes[:-1]]))
    ends = np.concatenate([starts[1:], [n]])
    for lo, hi in zip(starts, ends):
        if hi - lo > 1 and sorted_hashes[lo] not in (b"", ""):
            members = np.sort(order[lo:hi])
            pairs_a += [members[0]] * (len(members) - 1)
            pairs_b += list(members[1:])
            tiers += ["identical"] * (len(members) - 1)
            dists += [0.0] * (len(members) - 1)
    if n > 1:
        a, b, d = _candidates(table, metric, min(k, n - 1), method, threads)
        keep = (d <= limits["near"]) & (hashes[a] != hashes[b])
        a, b, d = a[keep], b[keep], d[keep]
        same, near = _geometry_tiers(table, a, b, d, limits, scale)
        take = same | near
        pairs_a += list(a[take])
        pairs_b += list(b[take])
        tiers += ["same" if s else "near" for s in same[take]]
        dists += list(d[take])
    if not pairs_a:
        return []
    pa, pb = np.array(pairs_a, dtype=np.int64), np.array(pairs_b, dtype=np.int64)
    tier_code = np.array([TIERS.index(t) for t in tiers], dtype=np.int64)
    dists = np.asarray(dists, dtype=np.float64)
    pa, pb, tier_code, dists = _linking_pairs(n, pa, pb, tier_code, dists)
    ratios = table.size_ratios(pa, pb)
    mirrored = mirror_relation(table.handedness[pa], table.handedness[pb])
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, component = connected_components(coo_matrix((np.ones(len(pa)), (pa, pb)), shape=(n, n)), directed=False)
    by_group: dict = {}
    for i in np.lexsort((table.paths[pb], table.paths[pa], tier_code)):
        by_group.setdefault(int(component[pa[i]]), []).append(int(i))
    out = []
    for pair_indices in by_group.values():
        members = sorted({str(table.paths[pa[i]]) for i in pair_indices} | {str(table.paths[pb[i]]) for i in pair_indices})
        pairs = [
            {
                "a": str(table.paths[pa[i]]),
                "b": str(table.paths[pb[i]]),
                "tier": TIERS[tier_code[i]],
                "distance": float(dists[i]),
                "size_ratio": None if not np.isfinite(ratios[i]) else float(ratios[i]),
                "mirrored": bool(mirrored[i]),
            }
            for i in pair_indices
        ]
        out.append({"members": members, "pairs": pairs})
    out.sort(key=lambda g: (-len(g["members"]), g["members"][0]))
    return out
