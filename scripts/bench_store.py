#!/usr/bin/env python3
"""What a big store costs: a one-off query, and a commit and merge of a small change.

Usage::

    python scripts/bench_store.py query PART STORE... [--repeat R] [--top K]
    python scripts/bench_store.py commit STORE... [--files 100] [--rounds R]

``query`` times the whole ``shapeidx query PART --store STORE`` command (a fresh process:
Python's start, the imports, the query part's signature, opening the store, ranking and
printing) on each store, the stores interleaved round after round so that the machine's
load falls on all of them alike, after one warm-up run each (the page cache then holds the
files, as it does on a machine that queries its store). Medians, and the ratio of each
store's median to the first store's.

``commit`` changes ``--files`` entries of each store (new signatures, taken from other
entries, for existing paths) per round, through shapeidx's own :class:`StoreWriter`: the
time of the commit (a journal batch) and of the size-tiered merge after it
(:meth:`StoreWriter.compact`), over ``--rounds`` rounds, and the journal's segments after
them. THE STORES ARE CHANGED: run it on copies made with scripts/make_store.py.

Both print a Markdown table and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def _entries(store: Path) -> int:
    from shapeidx.store import open_store

    with open_store(store) as reader:
        return len(reader)


def bench_query(part: Path, stores: list, repeat: int, top: int) -> None:
    command = [sys.executable, "-m", "shapeidx.cli"]
    if not Path(sys.executable).with_name("shapeidx").exists():
        raise SystemExit("run with the venv's python (its shapeidx command is used)")
    command = [str(Path(sys.executable).with_name("shapeidx"))]
    times = {store: [] for store in stores}
    print(f"load average before: {_load()}", flush=True)
    for round_ in range(repeat + 1):
        for store in stores:
            started = time.perf_counter()
            run = subprocess.run([*command, "query", str(part), "--store", str(store), "--top", str(top)],
                                 capture_output=True, text=True)
            elapsed = time.perf_counter() - started
            if run.returncode:
                raise SystemExit(f"{store}: {run.stderr.strip()}")
            if round_:  # round 0 warms the page cache
                times[store].append(elapsed)
    print(f"load average after: {_load()}\n")
    print("| store | entries | layout | whole command, median of %d (s) | min-max (s) | / first store |" % repeat)
    print("|---|---|---|---|---|---|")
    base = statistics.median(times[stores[0]])
    for store in stores:
        import h5py

        with h5py.File(store, "r") as f:
            layout = int(f.attrs["schema_version"])
        median = statistics.median(times[store])
        print(f"| {store.name} | {_entries(store):,} | {layout} | {median:.2f} | {min(times[store]):.2f}-{max(times[store]):.2f}"
              f" | {median / base:.2f} |")


def bench_commit(stores: list, files: int, rounds: int) -> None:
    from shapeidx.store import Batch, Entry, StoreWriter, open_store
    from shapeidx.store.files import batch_files

    print(f"load average before: {_load()}", flush=True)
    rows = []
    for store in stores:
        with open_store(store) as reader:
            params, root, n = reader.params, reader.attrs["root"], len(reader)
            rng = np.random.default_rng(len(reader))
            picks = rng.choice(n, files * rounds, replace=False)
            donors = rng.choice(n, files * rounds, replace=False)
            paths = reader.paths[picks]  # reading every path: this script's own cost, not timed
            signatures = [reader.signature(int(i)) for i in donors]
        started = time.perf_counter()
        writer = StoreWriter(store, params, root)
        opened = time.perf_counter() - started
        commits, merges = [], []
        with writer:
            for r in range(rounds):
                entries = [Entry(path=str(paths[r * files + k]), hash=f"{r:032x}{k:032x}", size=1, mtime_ns=r + 1,
                                 triangles=12, area=1.0, watertight=True,
                                 fractions=tuple(s.fractions[c] for c in ("in", "out", "mixed")),
                                 histograms=dict(s.histograms))
                           for k, s in enumerate(signatures[r * files:(r + 1) * files])]
                t0 = time.perf_counter()
                writer.commit(Batch(entries=entries))
                t1 = time.perf_counter()
                writer.compact()
                t2 = time.perf_counter()
                commits.append(t1 - t0)
                merges.append(t2 - t1)
        with open_store(store) as reader:
            segments = [len(s) for s in reader._sources[1:]]
        rows.append((store, n, opened, commits, merges, segments, len(batch_files(store))))
    print(f"load average after: {_load()}\n")
    print(f"| store | entries | commit of {files} files, median / max (s) | merge after it, median / max (s) |"
          f" journal segments after {rounds} rounds (entries) | writer open (s) |")
    print("|---|---|---|---|---|---|")
    for store, n, opened, commits, merges, segments, _ in rows:
        print(f"| {store.name} | {n:,} | {statistics.median(commits):.3f} / {max(commits):.3f} |"
              f" {statistics.median(merges):.3f} / {max(merges):.3f} | {len(segments)} ({', '.join(map(str, segments))}) |"
              f" {opened:.1f} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    q = sub.add_parser("query")
    q.add_argument("part", type=Path)
    q.add_argument("stores", type=Path, nargs="+")
    q.add_argument("--repeat", type=int, default=5)
    q.add_argument("--top", type=int, default=10)
    c = sub.add_parser("commit")
    c.add_argument("stores", type=Path, nargs="+")
    c.add_argument("--files", type=int, default=100)
    c.add_argument("--rounds", type=int, default=10)
    args = parser.parse_args()
    print(f"machine: {os.uname().machine}, {os.cpu_count()} cores, {os.uname().sysname} {os.uname().release},"
          f" Python {sys.version.split()[0]}, numpy {np.__version__}")
    if args.what == "query":
        bench_query(args.part, args.stores, args.repeat, args.top)
    else:
        bench_commit(args.stores, args.files, args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
