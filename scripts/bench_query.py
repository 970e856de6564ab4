#!/usr/bin/env python3
"""Benchmark of querying a store: synthetic stores of N entries made from real signatures.

Usage::

    python scripts/bench_query.py --source kicad6.shapeidx [--sizes 10000 1000000] [--work DIR]
        [--part FILE] [--rounds 5] [--metrics all avg3 ...] [--no-warm]

``--source`` is a store built by ``shapeidx build`` from real parts (e.g. kicad6 at the
default 1024 points). The synthetic stores of N entries (``DIR/synthetic-N.shapeidx``, or
``DIR/s-N.shapeidx`` when that exists) are made from its ok signatures by
``scripts/make_store.py`` (perturbed so that no two are alike; see there).

Measured, side by side (the sizes interleaved round after round, so that the machine's load
falls on all of them alike; medians):

* **whole command**: ``shapeidx query PART --store S`` in a fresh process (Python's start and
  imports, opening the store, signing PART, ranking, printing ten hits), and
  ``shapeidx query --id ENTRY`` (no signing); the ratio of each size's median to the first
  size's is what issue 26 bounds (at most 2 from 10^4 to 10^6);
* **stages** of that one-off query, in a fresh process: imports, opening the store, signing
  the query part, mapping (the ranking arrays a Weighted query reads, their CRCs checked),
  bounds (every entry's lower bound from the coarse histograms), exact distances (the
  candidates), paths (the hits' paths and metadata);
* **warm**: a long-lived :class:`~shapeidx.search.Searcher` (what ``serve`` and a Python
  session hold) with its block index built (:mod:`shapeidx.search.blocks`; the time to build
  it is reported), the best and median of ``--repeats`` queries of three entries per metric
  (every metric of the registry by default).
"""

from __future__ import annotations

import os

os.environ.update({k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})

import argparse  # noqa: E402
import json  # noqa: E402
import shlex  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _common import DATA, machine  # noqa: E402

#: The stages of a one-off query, timed in a fresh process (see the module docstring).
STAGES = r"""
import json, sys, time
t0 = time.perf_counter()
import shapeidx.cli
from shapeidx.search import Searcher
import shapeidx.search.distances as D
import shapeidx.search.searcher as S
t1 = time.perf_counter()
store, part, metric = sys.argv[1:4]
T = {"bounds": 0.0, "exact": 0.0, "paths": 0.0}
def timed(name, f):
    def g(*a, **k):
        t = time.perf_counter(); r = f(*a, **k); T[name] += time.perf_counter() - t; return r
    return g
D.lower_bounds, D.distances = timed("bounds", D.lower_bounds), timed("exact", D.distances)
S.Searcher._hits = timed("paths", S.Searcher._hits)
s = Searcher(store); t2 = time.perf_counter()
q = s.query_of_part(part); t3 = time.perf_counter()
for sec in s.view.sections:
    for h in ("in", "out", "mixed"):
        sec.array(f"{h}/totals"); sec.array(f"{h}/order")
s.view.gather("fractions"); t4 = time.perf_counter()
s.search(q, 10, metric); t5 = time.perf_counter()
print(json.dumps({"imports": t1 - t0, "open": t2 - t1, "sign": t3 - t2, "map": t4 - t3, "search": t5 - t4, **T}))
"""


def store_of(work: Path, size: int, source: Path) -> Path:
    for name in (f"s-{size}.shapeidx", f"synthetic-{size}.shapeidx"):
        if (work / name).exists():
            return work / name
    from make_store import real_signatures, write_store

    store = work / f"synthetic-{size}.shapeidx"
    started = time.perf_counter()
    write_store(store, size, real_signatures(source))
    print(f"wrote {store} in {time.perf_counter() - started:.1f} s", flush=True)
    return store


def whole(args: list) -> float:
    started = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "shapeidx.cli", "query", *args, "--top", "10"],
                         capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"query failed: {run.stderr.strip()}")
    return time.perf_counter() - started


def warm(store: Path, metrics: list, repeats: int) -> dict:
    from shapeidx.search import Searcher

    out = {}
    with Searcher(store) as searcher:
        started = time.perf_counter()
        searcher.warm()
        out["build"] = time.perf_counter() - started
        n = len(searcher)
        queries = [searcher.query_of_entry(searcher.path_at(p)) for p in (n // 7, n // 3, (5 * n) // 6)]
        for metric in metrics:
            times = []
            for _ in range(repeats):
                for query in queries:
                    started = time.perf_counter()
                    searcher.search(query, 10, metric)
                    times.append(time.perf_counter() - started)
            out[metric] = (min(times), float(np.median(times)), max(times))
    return out


def main() -> int:
    from shapeidx.distance.metrics import METRICS
    from shapeidx.store import open_store

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--source", type=Path, required=True, help="a store of real parts")
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 1_000_000])
    parser.add_argument("--part", type=Path, default=DATA / "kicad6" / "Battery" / "BatteryHolder_Eagle_12BH611-GR.wrl",
                        help="the query part of the whole command")
    parser.add_argument("--metrics", nargs="+", default=list(METRICS), help="metrics of the warm searcher")
    parser.add_argument("--work", type=Path, default=Path("bench-stores"), help="where synthetic stores go")
    parser.add_argument("--rounds", type=int, default=5, help="whole commands per size (interleaved)")
    parser.add_argument("--repeats", type=int, default=3, help="warm queries per entry and metric")
    parser.add_argument("--no-warm", action="store_true", help="leave the warm searcher out")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    print(f"load average before: {os.getloadavg()[0]:.2f}", flush=True)
    args.work.mkdir(parents=True, exist_ok=True)
    stores = {size: store_of(args.work, size, args.source) for size in args.sizes}
    entries = {}
    for size, store in stores.items():
        with open_store(store) as reader:
            entries[size] = str(reader.paths[size // 3])
    times = {(size, kind): [] for size in args.sizes for kind in ("part", "id")}
    stages = {size: [] for size in args.sizes}
    for size in args.sizes:  # a warm-up round: the page cache holds every store alike
        whole([str(args.part), "--store", str(stores[size])])
    for _ in range(args.rounds):
        for size in args.sizes:
            times[size, "part"].append(whole([str(args.part), "--store", str(stores[size])]))
            times[size, "id"].append(whole(["--id", entries[size], "--store", str(stores[size])]))
            run = subprocess.run([sys.executable, "-c", STAGES, str(stores[size]), str(args.part), "weighted"],
                                 capture_output=True, text=True)
            if run.returncode:
                raise SystemExit(run.stderr)
            stages[size].append(json.loads(run.stdout))
    first = args.sizes[0]
    print("\n| entries | whole `query PART`, median (s) | min-max | / first size | whole `query --id`, median (s) | / first size |")
    print("|---|---|---|---|---|---|")
    for size in args.sizes:
        part, ident = np.median(times[size, "part"]), np.median(times[size, "id"])
        print(f"| {size:,} | {part:.2f} | {min(times[size, 'part']):.2f}-{max(times[size, 'part']):.2f} |"
              f" {part / np.median(times[first, 'part']):.2f} | {ident:.2f} | {ident / np.median(times[first, 'id']):.2f} |")
    names = ("imports", "open", "sign", "map", "bounds", "exact", "paths", "search")
    print("\nStages of one `query PART` (Weighted), medians (s):\n")
    print("| entries | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for size in args.sizes:
        print(f"| {size:,} | " + " | ".join(f"{np.median([s[n] for s in stages[size]]):.3f}" for n in names) + " |")
    if not args.no_warm:
        print("\nA warm searcher (block index built once), best / median / worst of"
              f" {3 * args.repeats} queries (s):\n")
        print("| entries | index build (s) | " + " | ".join(args.metrics) + " |")
        print("|---|---|" + "---|" * len(args.metrics))
        for size in args.sizes:
            w = warm(stores[size], args.metrics, args.repeats)
            print(f"| {size:,} | {w['build']:.1f} | "
                  + " | ".join(f"{w[m][0]:.3f} / {w[m][1]:.3f} / {w[m][2]:.3f}" for m in args.metrics) + " |",
                  flush=True)
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
