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
    started = time.perf_counter()
    answer = searcher.search(queries[int(position)], top, metric)
    seconds = time.perf_counter() - started
    print(json.dumps({"t": seconds, "hits": [[h.relative_path, h.distance] for h in answer.hits], "rss": rss()}),
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
                    last_rss[k] = reply["rss"]
                    answers.append((k, reply["hits"]))
                if any(hits != answers[0][1] for _, hits in answers):
                    raise SystemExit(f"the trees disagree on {metric} for entry {position}: {answers}")
    for worker in workers:
        worker.stdin.close()
        worker.wait()
    count = len(positions) * args.repeats
    print(f"\n{n:,} entries; {len(positions)} entries as queries x {args.repeats} = {count} queries per metric;"
          " every tree's hits identical. Median / worst of one search (s), and over the first tree's:\n")
    header = " | ".join(f"{tree.name or tree} median / worst" for tree in args.code)
    ratios = " | ".join(f"{tree.name} / {args.code[0].name}" for tree in args.code[1:])
    print(f"| metric | {header} |" + (f" {ratios} |" if ratios else ""))
    print("|---|" + "---|" * (len(args.code) + len(args.code[1:])))
    for metric in args.metrics:
        cells = [f"{np.median(times[k, metric]):.3f} / {max(times[k, metric]):.3f}" for k in range(len(workers))]
        base_median, base_worst = np.median(times[0, metric]), max(times[0, metric])
        cells += [f"{np.median(times[k, metric]) / base_median:.2f} / {max(times[k, metric]) / base_worst:.2f}"
                  for k in range(1, len(workers))]
        print(f"| {metric} | " + " | ".join(cells) + " |")
    print("\n| tree | index build (s) | resident after warming, MiB: anonymous + mapped files | at the end |"
          "\n|---|---|---|---|")
    for k, tree in enumerate(args.code):
        print(f"| {tree} | {started[k]['build']:.1f} | {started[k]['rss'][0]} + {started[k]['rss'][1]} |"
              f" {last_rss[k][0]} + {last_rss[k][1]} |")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
