#!/usr/bin/env python3
"""Warm queries of a long-lived searcher, median and worst per metric, code against code.

Usage::

    python scripts/bench_warm.py STORE [--code DIR ...] [--queries 15] [--repeats 3]
        [--metrics all avg3 ...] [--top 10]

For each ``--code`` tree (a directory holding a ``shapeidx`` package, e.g. an older commit
unpacked by ``git archive COMMIT shapeidx | tar -x -C DIR``; default: this checkout) one
process opens STORE with a :class:`~shapeidx.search.Searcher`, builds its block index
(:meth:`~shapeidx.search.Searcher.warm`, timed) and answers queries: a fixed set of
``--queries`` entries of the store (evenly spread over it, with the three entries
``scripts/bench_query.py`` uses), each against every metric of the registry, ``--repeats``
times. The processes answer in turn, query by query (the tree that goes first alternates), so
that the machine's load falls on them alike: the ratios of one run are what to quote. Every
tree's hits (paths and distances) must agree, query by query; the script stops otherwise.

Printed: per metric and tree, the median and worst time of one ``search`` call (what
``serve`` spends on the ranking), the ratio of each tree's to the first tree's, the index
build time and each process's resident memory after warming and at the end (anonymous, i.e. its
own, and the pages of the store's mapped files, which are the page cache's and shared).
"""

from __future__ import annotations

import os

os.environ.update({k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})

import argparse  # noqa: E402
import json  # noqa: E402
import shlex  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _common import REPO, machine  # noqa: E402

#: One searcher answering "metric position" lines on stdin with one JSON line each.
WORKER = r"""
import json, sys, time
from shapeidx.search import Searcher
def rss():  # MiB resident: anonymous (the process's own), and file pages mapped (the page cache's)
    with open("/proc/self/status") as status:
        fields = {l.split(":")[0]: int(l.split()[1]) // 1024 for l in status if l.startswith(("RssAnon", "RssFile"))}
    return [fields["RssAnon"], fields["RssFile"]]
store, top, positions = sys.argv[1], int(sys.argv[2]), [int(p) for p in sys.argv[3].split(",")]
searcher = Searcher(store)
started = time.perf_counter()
searcher.warm()
build = time.perf_counter() - started
n = len(searcher)
queries = {p: searcher.query_of_entry(searcher.path_at(p)) for p in positions}
print(json.dumps({"build": build, "entries": n, "rss": rss()}), flush=True)
for line in sys.stdin:
    metric, position = line.split()
    started, cpu = time.perf_counter(), time.process_time()
    answer = searcher.search(queries[int(position)], top, metric)
    seconds, cpu = time.perf_counter() - started, time.process_time() - cpu
    print(json.dumps({"t": seconds, "cpu": cpu, "hits": [[h.relative_path, h.distance] for h in answer.hits], "rss": rss()}),
          flush=True)
"""


def positions_of(n: int, count: int) -> list:
    """The fixed query entries: bench_query.py's three, then evenly spread ones."""
    first = [n // 7, n // 3, (5 * n) // 6]
    spread = [int(x) for x in np.linspace(0, n - 1, max(count - 1, 2))[1:-1]]
    out = []
    for p in first + spread:
        if p not in out:
            out.append(p)
    return out[:count]


def main() -> int:
    from shapeidx.distance.metrics import METRICS
    from shapeidx.store import open_store

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("store", type=Path)
    parser.add_argument("--code", type=Path, nargs="+", default=[REPO], help="trees holding a shapeidx package")
    parser.add_argument("--queries", type=int, default=15, help="entries queried (a fixed set)")
    parser.add_argument("--repeats", type=int, default=3, help="times each query runs per metric")
    parser.add_argument("--metrics", nargs="+", default=list(METRICS))
    parser.add_argument("--top", type=int, default=10)
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    print(f"load average before: {os.getloadavg()[0]:.2f}", flush=True)
    with open_store(args.store) as reader:
        n = len(reader.paths)
    positions = positions_of(n, args.queries)
    workers, started = [], []
    for tree in args.code:  # one at a time: the index builds do not share the cores
        env = dict(os.environ, PYTHONPATH=str(tree.resolve()))
        worker = subprocess.Popen([sys.executable, "-c", WORKER, str(args.store), str(args.top),
                                   ",".join(map(str, positions))], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  text=True, env=env, cwd="/")
        started.append(json.loads(worker.stdout.readline()))
        workers.append(worker)
        print(f"{tree}: index built in {started[-1]['build']:.1f} s, resident {started[-1]['rss'][0]} MiB"
              f" anonymous + {started[-1]['rss'][1]} MiB of mapped files", flush=True)
    times = {(k, m): [] for k in range(len(workers)) for m in args.metrics}
    cpus = {(k, m): [] for k in range(len(workers)) for m in args.metrics}
    per_query = {(k, m, p): [] for k in range(len(workers)) for m in args.metrics for p in positions}
    last_rss = [s["rss"] for s in started]
    turn = 0
    for _ in range(args.repeats):
        for metric in args.metrics:
            for position in positions:
                answers = []
                order = list(range(len(workers)))
                if turn % 2:
                    order.reverse()
                turn += 1
                for k in order:
                    workers[k].stdin.write(f"{metric} {position}\n")
                    workers[k].stdin.flush()
                    reply = json.loads(workers[k].stdout.readline())
                    times[k, metric].append(reply["t"])
                    cpus[k, metric].append(reply["cpu"])
                    per_query[k, metric, position].append(reply["t"])
                    last_rss[k] = reply["rss"]
                    answers.append((k, reply["hits"]))
                if any(hits != answers[0][1] for _, hits in answers):
                    raise SystemExit(f"the trees disagree on {metric} for entry {position}: {answers}")
    for worker in workers:
        worker.stdin.close()
        worker.wait()
    count = len(positions) * args.repeats
    print(f"\n{n:,} entries; {len(positions)} entries as queries x {args.repeats} = {count} queries per metric;"
          " every tree's hits identical.\n\nWall time of one search (s): median / worst of all / worst of the"
          " queries' own medians (a query slow every time, not a moment of load); CPU seconds of the"
          " process (both ranking threads): median / worst; then the ratios to the first tree's.\n")
    names = [tree.name or str(tree) for tree in args.code]
    cells = [f"{name}: wall median / worst / worst query | {name}: CPU median / worst" for name in names]
    cells += [f"{name} / {names[0]}: wall median / worst query" for name in names[1:]]
    print("| metric | " + " | ".join(cells) + " |")
    print("|---|" + "---|" * (2 * len(names) + len(names) - 1))

    def figures(k, metric):
        slowest = max(np.median(per_query[k, metric, p]) for p in positions)
        return np.median(times[k, metric]), max(times[k, metric]), slowest

    for metric in args.metrics:
        row = []
        for k in range(len(workers)):
            median, worst, slowest = figures(k, metric)
            row.append(f"{median:.3f} / {worst:.3f} / {slowest:.3f} | "
                       f"{np.median(cpus[k, metric]):.3f} / {max(cpus[k, metric]):.3f}")
        base = figures(0, metric)
        for k in range(1, len(workers)):
            median, _, slowest = figures(k, metric)
            row.append(f"{median / base[0]:.2f} / {slowest / base[2]:.2f}")
        print(f"| {metric} | " + " | ".join(row) + " |")
    print("\n| tree | index build (s) | resident after warming, MiB: anonymous + mapped files | at the end |"
          "\n|---|---|---|---|")
    for k, tree in enumerate(args.code):
        print(f"| {tree} | {started[k]['build']:.1f} | {started[k]['rss'][0]} + {started[k]['rss'][1]} |"
              f" {last_rss[k][0]} + {last_rss[k][1]} |")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
