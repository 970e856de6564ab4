#!/usr/bin/env python3
"""Clusters of a whole library against its folders: the graph road against exact Ward.

    python scripts/cluster_study.py --store LIBRARY_STORE [--metric combined-angle] \
        [--clusters 90 150 623] [--seeds 3]

For each K: exact Ward, average and complete linkage on the full distance matrix (for
combined-angle built with BLAS: every Hellinger term from dot products of square-rooted
histograms, checked against ``FamilyTable.pair_distances`` on 20,000 random pairs), single
linkage on the 10-neighbour graph (the road before issue 22), and ``cluster_store``'s graph
road (Leiden communities + Ward inside them), over ``--seeds`` Leiden seeds. Each line: NMI
and ARI against the first folder of each path, the largest cluster's share, seconds.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time

import numpy as np

from _common import machine


def exact_matrix(table, metric: str) -> np.ndarray:
    """(N, N) distances: combined-angle by BLAS, any other metric pair by pair."""
    n = len(table)
    if metric != "combined-angle":
        i, j = np.triu_indices(n, 1)
        out = np.zeros((n, n))
        out[i, j] = table.pair_distances(i, j, metric)
        return out + out.T
    from shapeidx.distance.combined import class_scales, learned_weights
    from shapeidx.signing.parameters import HISTOGRAMS

    w = learned_weights(metric)["weights"]
    roots = np.sqrt(table.angles)
    norms = (roots**2).sum(-1)
    scales = class_scales(table.means)
    out = np.zeros((n, n))
    for lo in range(0, n, 512):
        hi = min(n, lo + 512)
        d = np.zeros((hi - lo, n))
        for c, name in enumerate(HISTOGRAMS[1:]):
            d += w[f"gap_{name}"] * np.abs(table.fractions[lo:hi, c, None] - table.fractions[None, :, c])
            d += w[f"scale_{name}"] * np.abs(scales[lo:hi, c, None] - scales[None, :, c])
        for k, name in enumerate(HISTOGRAMS):
            g = norms[lo:hi, k, None] + norms[None, :, k] - 2 * roots[lo:hi, k] @ roots[:, k].T
            d += w[f"hellinger_angle_{name}"] * np.sqrt(np.maximum(g, 0) / 2)
        out[lo:hi] = d
    np.fill_diagonal(out, 0)
    return np.minimum(out, out.T)


def main() -> int:
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import squareform

    from shapeidx.distance import METRIC_HISTOGRAMS
    from shapeidx.families import cluster as road
    from shapeidx.families.agreement import ari, nmi
    from shapeidx.families.labels import labels_from_paths
    from shapeidx.families.table import FamilyTable
    from shapeidx.store import open_store
    from shapeidx.store.candidates import candidate_pairs

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--store", required=True)
    parser.add_argument("--metric", default="combined-angle")
    parser.add_argument("--clusters", type=int, nargs="+", default=[90, 150, 623])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    print(f"command: {shlex.join([sys.executable, *sys.argv])}\nmachine: {machine()}", flush=True)
    with open_store(args.store) as reader:
        table = FamilyTable.load(reader, METRIC_HISTOGRAMS[args.metric])
    labels = labels_from_paths(table.paths)
    n = len(table)
    started = time.perf_counter()
    matrix = exact_matrix(table, args.metric)
    seconds = time.perf_counter() - started
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, n, (2, 20000))
    check = float(np.abs(matrix[a, b] - table.pair_distances(a, b, args.metric)).max())
    print(f"{n} entries, {len(set(labels))} folders; exact matrix {seconds:.1f} s (largest gap to pair_distances {check:.2g})")

    def line(name, k, lab, s):
        sizes = np.unique(lab, return_counts=True)[1]
        print(f"K={k:4d} {name:34s} NMI {nmi(labels, lab):.3f} ARI {ari(labels, lab):.3f}"
              f" largest {sizes.max() / n:.3f} ({s:.1f} s)", flush=True)

    trees = {}
    for method in ("ward", "average", "complete"):
        started = time.perf_counter()
        trees[method] = (linkage(squareform(matrix, checks=False), method), time.perf_counter() - started)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    started = time.perf_counter()
    ea, eb, ed, _, _ = candidate_pairs(table, args.metric, 15)
    forest = minimum_spanning_tree(coo_matrix((np.maximum(ed, 1e-300), (ea, eb)), shape=(n, n)).tocsr()).tocoo()
    single_s = time.perf_counter() - started
    for k in args.clusters:
        for method, (tree, s) in trees.items():
            line(f"exact {method}", k, fcluster(tree, k, "maxclust"), s + seconds)
        parts, _ = connected_components(forest, directed=False)
        keep = np.ones(len(forest.data), bool)
        keep[np.argsort(-forest.data, kind="stable")[: max(0, k - parts)]] = False
        _, lab = connected_components(coo_matrix((forest.data[keep], (forest.row[keep], forest.col[keep])), shape=(n, n)),
                                      directed=False)
        line("single linkage, 15-NN graph (old)", k, lab, single_s)
        for seed in range(args.seeds):
            road.LEIDEN_SEED = 22 + seed
            started = time.perf_counter()
            result = road.cluster_store(table, args.metric, clusters=k, road="graph", threads=2)
            line(f"graph road, seed {22 + seed} ({result['families']} families)", k, result["clusters"],
                 time.perf_counter() - started)
    return 0


if __name__ == "__main__":
    sys.exit(main())
