#!/usr/bin/env python3
"""10^6 entries in memory: the 10^5 synthetic store's table repeated 10 times, each copy's
angles, fractions, class means and moments perturbed (so no two entries are alike).

    python scripts/families_million.py SYNTHETIC_10^5_STORE 10 dup clu [peak]

A store of 10^6 entries takes make_store.py about 25 minutes on a loaded machine; this times
``find_duplicates`` and ``cluster_store`` on the same number of entries without writing one
(the store's loading, 2 s at 10^5, is not timed). Prints wall and CPU seconds and the largest
resident set; with ``peak``, also the largest memory numpy held during each (tracemalloc).
"""
import sys, time, resource, tracemalloc, numpy as np
from shapeidx.families.table import FamilyTable
from shapeidx.families.duplicates import find_duplicates
from shapeidx.families.cluster import cluster_store
from shapeidx.store import open_store
t0 = time.perf_counter()
with open_store(sys.argv[1]) as r:
    base = FamilyTable.load(r, ())
reps = int(sys.argv[2]); what = sys.argv[3:]
rng = np.random.default_rng(6)
n0 = len(base); n = n0 * reps
def rep(x): return np.concatenate([x] * reps)
angles = rep(base.angles) * rng.uniform(0.97, 1.03, size=(n,) + base.angles.shape[1:])
s_ = angles.sum(axis=2, keepdims=True); angles = np.divide(angles, s_, out=np.zeros_like(angles), where=s_ > 0)
fr = rep(base.fractions) * rng.uniform(0.98, 1.02, size=(n, 3)); fr /= fr.sum(axis=1, keepdims=True)
means = rep(base.means) * rng.uniform(0.99, 1.01, size=(n, 4))
ext = rep(base.extents) * rng.uniform(0.995, 1.005, size=(n, 3))
mom = rep(base.moments) * rng.uniform(0.995, 1.005, size=(n, 4))
paths = np.array([f'{k:07d}' for k in range(n)], dtype=object)
table = FamilyTable(paths=paths, rows=np.arange(n), histograms={}, fractions=fr, means=means,
                    hashes=np.array([b''] * n, dtype=object), extents=ext, handedness=rep(base.handedness),
                    missing_columns=[], bounds=rep(base.bounds), moments=mom, angles=angles)
print(f'{n} entries made in {time.perf_counter() - t0:.1f} s; maxrss {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB', flush=True)
if 'peak' in what:
    tracemalloc.start()
def peak():
    if not tracemalloc.is_tracing():
        return ''
    value = tracemalloc.get_traced_memory()[1]
    tracemalloc.reset_peak()
    return f'; numpy peak {value / 1e9:.2f} GB'

if 'dup' in what:
    t = time.perf_counter(); c = time.process_time()
    g = find_duplicates(table, 'combined-angle', threads=2)
    print(f'duplicates {time.perf_counter() - t:.1f} s wall, {time.process_time() - c:.1f} s cpu, {len(g)} groups; maxrss {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB{peak()}', flush=True)
if 'clu' in what:
    t = time.perf_counter(); c = time.process_time()
    res = cluster_store(table, 'combined-angle', road='graph', threads=2)
    print(f'cluster {time.perf_counter() - t:.1f} s wall, {time.process_time() - c:.1f} s cpu, {res["count"]} clusters; maxrss {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB{peak()}', flush=True)
