#!/usr/bin/env python3
"""Benchmark of a sharded store on a local Dask cluster: latency and memory per shard.

Usage::

    python scripts/bench_shards.py STORE [--workers W] [--queries 5] [--metrics weighted combined-angle]

STORE is a sharded store (``shapeidx build --shards``, or ``scripts/make_store.py SOURCE N
OUT --shards K``). The script starts a real cluster on this machine (``dask scheduler`` and
W ``dask worker`` processes of one thread each, in their own process groups, stopped at the
end), then, with a :class:`~shapeidx.search.ShardedSearcher` on it (what ``query
--scheduler`` does, held open):

* the first query (each worker opens its shards), the second (each builds its shards' block
  indexes: :mod:`shapeidx.search.blocks`), then ``--queries`` warm queries per metric: the
  whole latency at the client, and each shard's own time on its worker;
* each worker's resident memory (VmRSS) before the shards are opened and after, divided by
  the shards it holds;
* one whole ``shapeidx query --id ENTRY --store STORE --scheduler ADDRESS`` (a fresh client).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import machine


def rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def start_cluster(folder: Path, workers: int):
    dask = Path(sys.executable).with_name("dask")
    base = [str(dask)] if dask.exists() else [sys.executable, "-m", "dask"]
    procs = []

    def start(name, *args):
        log = open(folder / f"{name}.log", "w")
        procs.append(subprocess.Popen([*base, *map(str, args)], stdout=log, stderr=subprocess.STDOUT,
                                      start_new_session=True))

    scheduler_file = folder / "scheduler.json"
    start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
          "--scheduler-file", scheduler_file)
    while not scheduler_file.exists() or not scheduler_file.read_text().strip().endswith("}"):
        time.sleep(0.2)
    address = json.loads(scheduler_file.read_text())["address"]
    for i in range(workers):
        start(f"worker-{i}", "worker", "--scheduler-file", scheduler_file, "--nthreads", "1", "--host", "127.0.0.1",
              "--no-dashboard", "--local-directory", folder / f"w{i}", "--name", f"w{i}", "--no-nanny",
              "--memory-limit", "0")
    return address, procs


def main() -> int:
    from distributed import Client

    from shapeidx.search import ShardedSearcher
    from shapeidx.search.sharded import shard_info

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("store", type=Path)
    parser.add_argument("--workers", type=int, default=10)
    parser.add_argument("--queries", type=int, default=5)
    parser.add_argument("--metrics", nargs="+", default=["weighted", "combined-angle", "all"])
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    print(f"load average before: {os.getloadavg()[0]:.2f}", flush=True)
    folder = Path(tempfile.mkdtemp(prefix="bench-shards-"))
    address, procs = start_cluster(folder, args.workers)
    try:
        with Client(address, set_as_default=False) as client:
            client.wait_for_workers(args.workers, timeout=120)
            pids = client.run(os.getpid)
            before = {w: rss(pid) for w, pid in pids.items()}
        started = time.perf_counter()
        searcher = ShardedSearcher(args.store, address)
        opened = time.perf_counter() - started
        print(f"{len(searcher.shards)} shards, {len(searcher):,} entries, {args.workers} workers; opened in {opened:.2f} s")
        with Client(address, set_as_default=False) as client:
            entries = client.gather([client.submit(shard_info, p, pure=False) for p in searcher.shards[:1]])
        from shapeidx.store import open_store

        with open_store(searcher.shards[0]) as reader:
            entry = str(reader.paths[len(reader) // 2])
        query = searcher.query_of_entry(entry)
        rows = []
        for metric in args.metrics:
            times, shard_times = [], []
            for k in range(args.queries + 2):
                t = time.perf_counter()
                answer = searcher.search(query, 10, metric)
                elapsed = time.perf_counter() - t
                if k == 1 and metric == args.metrics[0]:
                    print(f"second query ({metric}: the workers build their block indexes): {elapsed:.2f} s, slowest"
                          f" shard {max(searcher.last_seconds):.2f} s", flush=True)
                if k >= 2:
                    times.append(elapsed)
                    shard_times += searcher.last_seconds
            assert answer.hits and answer.hits[0].relative_path == entry
            rows.append((metric, min(times), float(np.median(times)), float(np.median(shard_times)),
                         max(shard_times)))
        with Client(address, set_as_default=False) as client:
            after = {w: rss(pid) for w, pid in client.run(os.getpid).items()}
        held = {}
        for k, path in enumerate(searcher.shards):
            w = searcher._workers[k % len(searcher._workers)]
            held[w] = held.get(w, 0) + 1
        searcher.close()
        print("\n| metric | warm query at the client, best (s) | median (s) | one shard on its worker, median (s) | slowest shard (s) |")
        print("|---|---|---|---|---|")
        for metric, best, median, shard, slowest in rows:
            print(f"| {metric} | {best:.3f} | {median:.3f} | {shard:.3f} | {slowest:.3f} |")
        grown = [(after[w] - before[w]) / held[w] for w in held if w in after]
        print(f"\nworker memory: {np.median(list(before.values())) / 2**20:.0f} MiB each before; held shards add"
              f" {np.median(grown) / 2**20:.0f} MiB per shard (median; min {min(grown) / 2**20:.0f}, max"
              f" {max(grown) / 2**20:.0f}), {sum(after.values()) / 2**30:.2f} GiB for all workers")
        t = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "shapeidx.cli", "query", "--id", entry, "--store", str(args.store),
                              "--scheduler", address, "--top", "10"], capture_output=True, text=True)
        print(f"whole `shapeidx query --id ... --scheduler` (a fresh client, shards open on the workers):"
              f" {time.perf_counter() - t:.2f} s{'' if run.returncode == 0 else ' FAILED ' + run.stderr}")
    finally:
        for proc in procs:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
