#!/usr/bin/env python3
"""Benchmark of the whole-store commands on synthetic stores of real signatures.

    python scripts/bench_families.py --source kicad6.shapeidx [--sizes 10000 100000] [--work DIR]

Synthetic stores come from ``scripts/bench_query.py``'s generator (each entry one of the
source's real signatures, every count scaled by a random factor in [0.9, 1.1] and 0-5 last
bins dropped; sizes and handedness those of the source part). Measured:

* recall of the approximate candidates (:mod:`shapeidx.store.candidates`) against the
  exact answer, on ``--recall-size`` entries (default 10,000): for ``--queries`` entries
  drawn at random, the exact distance to every entry gives their exact 15 nearest
  neighbours (the cluster graph's k) and every pair ``find_duplicates`` would report if
  it compared all pairs (``pair_tiers`` of the entry with every other, tier identical or
  same); recall is the share of neighbours the candidates found and the share of those
  partners that end in the entry's duplicate group (a partner may rightly sit in another
  group when it is closer to that group's representative: groups do not chain). The issue's target: >= 99%.
* time of ``find_duplicates`` and ``cluster_store`` (graph road) on each size, with both
  cores (FAISS threads), store already in memory, and the store's loading apart.
  Target: 100,000 entries within 10 minutes each on 2 cores.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from _common import machine
from make_store import real_signatures, write_store
from shapeidx.distance import METRIC_HISTOGRAMS
from shapeidx.store.candidates import candidate_pairs
from shapeidx.families.cluster import GRAPH_NEIGHBOURS, cluster_store
from shapeidx.families.duplicates import DEFAULT_TIERS, find_duplicates, pair_tiers
from shapeidx.families.table import FamilyTable
from shapeidx.store import open_store

TARGET_SECONDS = 600.0
TARGET_RECALL = 0.99


def synthetic(work: Path, size: int, real: dict) -> Path:
    store = work / f"synthetic-{size}.h5"
    if not store.exists():
        write_store(store, size, real)
    return store


def recall(store: Path, metric: str, queries: int, method: str) -> dict:
    """Recall of the candidates against the exact answer for ``queries`` random entries."""
    with open_store(store) as reader:
        table = FamilyTable.load(reader, METRIC_HISTOGRAMS[metric])
    n = len(table)
    picks = np.random.default_rng(3).choice(n, min(queries, n), replace=False)
    started = time.perf_counter()
    _, _, _, neighbours, _ = candidate_pairs(table, metric, GRAPH_NEIGHBOURS, method)
    candidate_seconds = time.perf_counter() - started
    started = time.perf_counter()
    groups = find_duplicates(table, metric, method=method)
    duplicate_seconds = time.perf_counter() - started
    group_of = np.full(n, -1)
    for g, group in enumerate(groups):
        for m in group["members"]:
            group_of[table.index_of(m)] = g
    hits = wanted = pair_hits = pair_wanted = 0
    k = GRAPH_NEIGHBOURS
    for i in picks:
        exact = table.pair_distances(np.full(n, i), np.arange(n), metric)
        exact[i] = np.inf
        kth = np.partition(exact, k - 1)[k - 1]
        got = neighbours[i][neighbours[i] >= 0]
        hits += min(k, int((exact[got] <= kth).sum()))  # any of tied entries will do
        wanted += k
        # the entries find_duplicates would call one part with i if it compared every pair
        said = pair_tiers(table, np.full(n, i), np.arange(n), metric)
        partners = np.flatnonzero(np.isin(said["tier"], DEFAULT_TIERS))
        partners = partners[partners != i]
        pair_wanted += len(partners)
        pair_hits += int(((group_of[partners] == group_of[i]) & (group_of[i] >= 0)).sum())
    return {"entries": n, "neighbour_recall": hits / wanted, "pair_recall": pair_hits / max(pair_wanted, 1),
            "pairs_wanted": pair_wanted, "queries": len(picks), "candidate_seconds": candidate_seconds,
            "duplicate_seconds": duplicate_seconds}


def timing(store: Path, metric: str, threads: int) -> dict:
    started = time.perf_counter()
    with open_store(store) as reader:
        table = FamilyTable.load(reader, METRIC_HISTOGRAMS[metric])
    load = time.perf_counter() - started
    started = time.perf_counter()
    groups = find_duplicates(table, metric, threads=threads)
    dup = time.perf_counter() - started
    started = time.perf_counter()
    result = cluster_store(table, metric, road="graph", threads=threads)
    clu = time.perf_counter() - started
    return {"entries": len(table), "load": load, "duplicates": dup, "groups": len(groups), "cluster": clu,
            "clusters": result["count"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--source", type=Path, required=True)
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--recall-size", type=int, default=10_000)
    parser.add_argument("--queries", type=int, default=500)
    parser.add_argument("--metric", default="combined-angle")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--work", type=Path, default=Path("bench-stores"))
    parser.add_argument("--methods", nargs="+", default=["exact", "ivf"], help="candidate indexes to measure recall of (exact, ivf, hnsw)")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    real = real_signatures(args.source)
    args.work.mkdir(parents=True, exist_ok=True)
    failed = False
    store = synthetic(args.work, args.recall_size, real)
    for method in args.methods:
        r = recall(store, args.metric, args.queries, method)
        ok = r["neighbour_recall"] >= TARGET_RECALL and r["pair_recall"] >= TARGET_RECALL
        failed |= not ok and method == "exact"
        print(f"{r['entries']:>9,} entries  candidates {method:5s}: {GRAPH_NEIGHBOURS}-neighbour recall"
              f" {r['neighbour_recall']:.4f}; duplicate pair recall {r['pair_recall']:.4f} of {r['pairs_wanted']:,}"
              f" exact pairs ({r['queries']} queries); candidates {r['candidate_seconds']:.1f} s, duplicates"
              f" {r['duplicate_seconds']:.1f} s {'OK' if ok else 'BELOW TARGET'}")
    for size in args.sizes:
        t = timing(synthetic(args.work, size, real), args.metric, args.threads)
        ok = t["duplicates"] < TARGET_SECONDS and t["cluster"] < TARGET_SECONDS
        failed |= not ok
        print(f"{t['entries']:>9,} entries  duplicates {t['duplicates']:.1f} s ({t['groups']} groups), cluster (graph)"
              f" {t['cluster']:.1f} s ({t['clusters']} clusters); load {t['load']:.1f} s; target {TARGET_SECONDS:.0f} s each"
              f" {'OK' if ok else 'OVER TARGET'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
