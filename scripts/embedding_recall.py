#!/usr/bin/env python3
"""10-neighbour recall of the candidate embedding on a real store: 300 entries against all, exactly.

    python scripts/embedding_recall.py STORE METRIC [K]
"""
import sys, numpy as np
from shapeidx.store import open_store
from shapeidx.families.table import FamilyTable
from shapeidx.store.candidates import candidate_pairs
with open_store(sys.argv[1]) as r:
    t = FamilyTable.load(r)
metric = sys.argv[2]; k = int(sys.argv[3]) if len(sys.argv) > 3 else 10
n = len(t)
rng = np.random.default_rng(5); picks = rng.choice(n, 300, replace=False)
_, _, _, nb, nd = candidate_pairs(t, metric, k)
hits = 0
for i in picks:
    d = t.pair_distances(np.full(n, i), np.arange(n), metric); d[i] = np.inf
    kth = np.partition(d, k - 1)[k - 1]
    hits += min(k, int((d[nb[i][nb[i] >= 0]] <= kth + 1e-12).sum()))
print(metric, f"{k}-NN recall over 300 entries", hits / (300 * k))
