#!/usr/bin/env python3
"""Benchmark of the whole-store commands on synthetic stores of real signatures.

    python scripts/bench_families.py --source kicad6.h5 [--sizes 10000 100000] [--work DIR]

Synthetic stores come from ``scripts/bench_query.py``'s generator (each entry one of the
source's real signatures, every count scaled by a random factor in [0.9, 1.1] and 0-5 last
bins dropped; sizes and handedness those of the source part). Measured:

* recall of the approximate candidates (:mod:`shapeidx.families.candidates`) against the
  exact answer, on ``--recall-size`` entries (default 10,000): for ``--queries`` entries
  drawn at random, their exact k nearest neighbours (ranking the whole store with
  :meth:`SignatureTable.distances`) and every exact pair below the ``near`` duplicate
  threshold, and how many of them the candidates found. The issue's target: >= 99%.
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
from bench_query import real_signatures, write_synthetic
from shapeidx.families.candidates import candidate_pairs
from shapeidx.families.cluster import GRAPH_NEIGHBOURS, cluster_store
from shapeidx.families.duplicates import DEFAULT_NEIGHBOURS, find_duplicates, thresholds
from shapeidx.families.table import FamilyTable
from shapeidx.ranking import SignatureTable
from shapeidx.store import open_store

TARGET_SECONDS = 600.0
TARGET_RECALL = 0.99


def synthetic(work: Path, size: int, real: dict) -> Path:
    store = work / f"synthetic-{size}.h5"
    if not store.exists():
        write_synthetic(store, size, real)
    return store


def recall(store: Path, metric: str, k: int, queries: int, method: str) -> dict:
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
        ranking = SignatureTable.load(reader)
        rng = np.random.default_rng(3)
        picks = rng.choice(len(table), min(queries, len(table)), replace=False)
        signatures = [reader.signature(int(table.rows[i])) for i in picks]
    started = time.perf_counter()
    a, b, d, neighbours, _ = candidate_pairs(table, metric, k, method)
    seconds = time.perf_counter() - started
    near = thresholds(metric)["near"]
    found_pairs = set(zip(a[d <= near].tolist(), b[d <= near].tolist()))
    hits = wanted = pair_hits = pair_wanted = 0
    for i, signature in zip(picks, signatures):
        exact = ranking.distances(signature, metric)
        exact[i] = np.inf
        kth = np.partition(exact, k - 1)[k - 1]
        got = neighbours[i][neighbours[i] >= 0]
        # candidates within the k-th exact distance (any of tied entries will do)
        hits += min(k, int((exact[got] <= kth).sum()))
        wanted += k
        partners = np.flatnonzero(exact <= near)
        pair_wanted += len(partners)
        pair_hits += sum((min(i, j), max(i, j)) in found_pairs for j in partners)
    return {"entries": len(table), "neighbour_recall": hits / wanted, "pair_recall": pair_hits / max(pair_wanted, 1),
            "pairs_wanted": pair_wanted, "seconds": seconds, "queries": len(picks)}


def timing(store: Path, metric: str, threads: int) -> dict:
    started = time.perf_counter()
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
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
    parser.add_argument("--metric", default="combined")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--work", type=Path, default=Path("bench-stores"))
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    real = real_signatures(args.source)
    args.work.mkdir(parents=True, exist_ok=True)
    failed = False
    store = synthetic(args.work, args.recall_size, real)
    for method in ("exact", "hnsw"):
        for k, what in ((DEFAULT_NEIGHBOURS, "duplicates"), (GRAPH_NEIGHBOURS, "cluster")):
            r = recall(store, args.metric, k, args.queries, method)
            ok = r["neighbour_recall"] >= TARGET_RECALL and r["pair_recall"] >= TARGET_RECALL
            failed |= not ok and method == "exact"
            print(f"{r['entries']:>9,} entries  candidates {method:5s} k={k:<3d} ({what}): neighbour recall"
                  f" {r['neighbour_recall']:.4f}, pair recall {r['pair_recall']:.4f} of {r['pairs_wanted']} exact pairs"
                  f" below near ({r['queries']} queries); {r['seconds']:.1f} s {'OK' if ok else 'BELOW TARGET'}")
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
