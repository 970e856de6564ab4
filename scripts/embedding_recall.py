#!/usr/bin/env python3
"""10-neighbour recall of the candidate embedding on a real store: 300 entries against all, exactly.

    python scripts/embedding_recall.py STORE METRIC [K] [--size-scale C ...]

``--size-scale C`` (repeatable) multiplies the embedding's size block (combined-size's ln r)
by C before the search, one recall per C: how the factor 1 that
:func:`shapeidx.store.candidates.embedding_weights` uses was chosen (docs/performance-families.md).
"""
import argparse

import numpy as np

import shapeidx.store.candidates as candidates
from shapeidx.families.table import FamilyTable
from shapeidx.store import open_store


def recall(table, metric: str, k: int, picks, exact) -> float:
    _, _, _, neighbours, _ = candidates.candidate_pairs(table, metric, k)
    hits = 0
    for i in picks:
        distances, kth = exact[i]
        found = neighbours[i][neighbours[i] >= 0]
        hits += min(k, int((distances[found] <= kth + 1e-12).sum()))
    return hits / (len(picks) * k)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("metric")
    parser.add_argument("k", nargs="?", type=int, default=10)
    parser.add_argument("--size-scale", type=float, action="append", default=[])
    args = parser.parse_args()
    with open_store(args.store) as reader:
        table = FamilyTable.load(reader)
    n, k = len(table), args.k
    picks = np.random.default_rng(5).choice(n, 300, replace=False)
    exact = {}
    for i in picks:
        d = table.pair_distances(np.full(n, i), np.arange(n), args.metric)
        d[i] = np.inf
        exact[i] = (d, np.partition(d, k - 1)[k - 1])
    if not args.size_scale:
        print(args.metric, f"{k}-NN recall over 300 entries", recall(table, args.metric, k, picks, exact))
        return
    weights = candidates.embedding_weights
    for scale in args.size_scale:
        def scaled(metric, scale=scale):
            out = weights(metric)
            if "sizes" in out:
                out["sizes"] = out["sizes"] * scale
            return out
        candidates.embedding_weights = scaled
        print(args.metric, f"size block x{scale:g}: {k}-NN recall over 300 entries",
              recall(table, args.metric, k, picks, exact), flush=True)
    candidates.embedding_weights = weights


if __name__ == "__main__":
    main()
