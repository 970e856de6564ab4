#!/usr/bin/env python3
"""Benchmark of ranking a store: synthetic stores of N entries made from real signatures.

Usage::

    python scripts/bench_query.py --source kicad6.shapeidx [--sizes 100000 1000000] [--work DIR]

``--source`` is a store built by ``shapeidx build`` from real parts (e.g. kicad6 at the
default 1024 points). The synthetic stores of N entries are made from its ok signatures by
``scripts/make_store.py`` (perturbed so that no two are alike; see there), written by
shapeidx's own store writer.

Measured, on one core (the process is pinned to CPU 0, BLAS threads set to 1):

* ``load``: opening the store and reading the histograms a metric needs into memory;
* ``rank``: :meth:`SignatureTable.rank` plus :func:`top_hits` (k = 10) for a query whose
  signature is already known (the targets exclude the query's own signature);
* ``query --id``: the whole ``shapeidx query`` command, for reference.

The issue's targets: rank 100,000 entries in under 0.2 s, 1,000,000 in under 2 s.
"""

from __future__ import annotations

import os

os.environ.update({k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})

import argparse  # noqa: E402
import shlex  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _common import machine  # noqa: E402
from make_store import real_signatures, write_store  # noqa: E402
from shapeidx.search import Searcher  # noqa: E402
from shapeidx.store import open_store  # noqa: E402

TARGETS = {100_000: 0.2, 1_000_000: 2.0}


def measure(store: Path, metric: str, repeats: int) -> dict:
    started = time.perf_counter()
    searcher = Searcher(store)
    query = searcher.query_of_entry(searcher.path_at(len(searcher) // 3))
    load = time.perf_counter() - started
    times = []
    try:
        for _ in range(repeats):  # a long-lived searcher: the second query on finds the store mapped
            started = time.perf_counter()
            hits = searcher.search(query, 10, metric).hits
            times.append(time.perf_counter() - started)
        bins = sum(int(s.array(f"{h}/counts", verify=False).size) for s in searcher.view.sections
                   for h in ("all", "in", "out", "mixed"))
    finally:
        searcher.close()
    assert hits[0].distance == 0.0
    return {"load": load, "best": min(times), "median": float(np.median(times)), "values": bins}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--source", type=Path, required=True, help="a store of real parts")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--metrics", nargs="+", default=["weighted", "avg4"])
    parser.add_argument("--work", type=Path, default=Path("bench-stores"), help="where synthetic stores go")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    real = real_signatures(args.source)
    print(f"source: {args.source}: {len(real['paths'])} real signatures, {real['params'].points} points")
    args.work.mkdir(parents=True, exist_ok=True)
    failed = False
    for size in args.sizes:
        store = args.work / f"synthetic-{size}.shapeidx"
        if not store.exists():
            started = time.perf_counter()
            write_store(store, size, real)
            print(f"wrote {store} ({store.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - started:.1f} s")
        for metric in args.metrics:
            m = measure(store, metric, args.repeats)
            target = TARGETS.get(size)
            verdict = "" if target is None else (" OK" if m["best"] < target else " OVER TARGET")
            failed |= verdict == " OVER TARGET"
            goal = f" (target {target} s){verdict}" if target else ""
            print(f"{size:>9,} entries  {metric:8s}  rank+top10 best {m['best']:.3f} s, median {m['median']:.3f} s"
                  f"{goal}; load {m['load']:.2f} s; {m['values']:,} probabilities")
        with open_store(store) as reader:
            entry = str(reader.paths[0])
        started = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "shapeidx.cli", "query", "--store", str(store), "--id", entry,
                              "--top", "5"], capture_output=True, text=True)
        print(f"{size:>9,} entries  shapeidx query --id (whole command): {time.perf_counter() - started:.2f} s"
              f"{'' if run.returncode == 0 else ' FAILED: ' + run.stderr.strip()}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
