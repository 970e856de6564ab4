#!/usr/bin/env python3
"""Benchmark of ranking a store: synthetic stores of N entries made from real signatures.

Usage::

    python scripts/bench_query.py --source kicad6.h5 [--sizes 100000 1000000] [--work DIR]

``--source`` is a store built by ``shapeidx build`` from real parts (e.g. kicad6 at the
default 1024 points). Each synthetic entry is one of its ok signatures, perturbed so that
no two are alike: every count scaled by a random factor in [0.9, 1.1], the last 0 to 5
bins of each histogram dropped (so bin counts vary as in real stores). The synthetic store
is a real HDF5 store written with shapeidx's own layout functions.

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

import h5py  # noqa: E402
import numpy as np  # noqa: E402

from shapeidx.distance import METRIC_HISTOGRAMS  # noqa: E402
from shapeidx.ranking import SignatureTable, top_hits  # noqa: E402
from shapeidx.signing.parameters import HISTOGRAMS  # noqa: E402
from _common import machine  # noqa: E402
from shapeidx.ragged import offsets_of  # noqa: E402
from shapeidx.store import STATUS_OK, StoreWriter, open_store  # noqa: E402
from shapeidx.store.files import write_atomically  # noqa: E402
from shapeidx.store.layout import COUNT_DTYPE, ENTRY_COLUMNS, SHAPE_COLUMNS, write_columns  # noqa: E402

#: Synthetic entries generated per step (bounds the generator's memory).
CHUNK = 50_000
TARGETS = {100_000: 0.2, 1_000_000: 2.0}


def real_signatures(source: Path) -> dict:
    """The source store's ok entries: per histogram (counts, lengths, means, widths)."""
    with open_store(source) as reader:
        rows = np.flatnonzero(reader.column("entries/status") == STATUS_OK)
        out = {"params": reader.params, "paths": reader.paths[rows]}
        out.update({name: reader.column(name)[rows] for name in SHAPE_COLUMNS})
        for name in HISTOGRAMS:
            counts, lengths = reader.counts(name, rows)
            out[name] = (counts, lengths, reader.column(f"histograms/{name}/mean")[rows],
                         reader.column(f"histograms/{name}/bin_width")[rows])
    return out


def perturbed(base_counts, base_lengths, picks, rng):
    """Histograms ``picks`` of the base, each count scaled in [0.9, 1.1] and 0-5 last bins dropped."""
    offsets = offsets_of(base_lengths)
    lengths = np.maximum(base_lengths[picks] - rng.integers(0, 6, len(picks)), np.minimum(base_lengths[picks], 1))
    starts = np.repeat(offsets[picks] - offsets_of(lengths)[:-1], lengths)
    counts = base_counts[starts + np.arange(int(lengths.sum()))].astype(np.float64)
    counts *= rng.uniform(0.9, 1.1, len(counts))
    return np.maximum(np.rint(counts), 1).astype(COUNT_DTYPE), lengths


def write_synthetic(path: Path, size: int, real: dict, seed: int = 1) -> None:
    """A store of ``size`` entries derived from ``real`` (see the module docstring)."""
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(real["paths"]), size)
    StoreWriter(path, real["params"], Path("/synthetic")).close()  # the attributes of a real store
    with h5py.File(path, "r") as empty:
        attrs = dict(empty.attrs)

    def fill(f):
        f.attrs.update(attrs)
        totals = np.zeros((size, 3))
        columns = _plain_columns(size, picks, real)
        for name in HISTOGRAMS:
            base_counts, base_lengths, means, widths = real[name]
            columns[f"histograms/{name}/mean"] = means[picks]
            columns[f"histograms/{name}/bin_width"] = widths[picks]
            pieces = [perturbed(base_counts, base_lengths, picks[s : s + CHUNK], rng) for s in range(0, size, CHUNK)]
            lengths = np.concatenate([p[1] for p in pieces])
            f.create_dataset(f"histograms/{name}/offsets", data=offsets_of(lengths))
            data = f.create_dataset(f"histograms/{name}/counts", shape=(int(lengths.sum()),), dtype=COUNT_DTYPE)
            at = 0
            for counts, piece_lengths in pieces:
                data[at : at + len(counts)] = counts
                at += len(counts)
            if name != "all":
                sums = np.add.reduceat(np.concatenate([p[0] for p in pieces]).astype(np.int64),
                                       offsets_of(lengths)[:-1]) if size else np.zeros(0)
                totals[:, HISTOGRAMS.index(name) - 1] = np.where(lengths > 0, sums, 0)
        columns["entries/fractions"] = totals / totals.sum(axis=1, keepdims=True)
        write_columns(f, columns)

    write_atomically(path, fill)


def _plain_columns(size: int, picks, real) -> dict:
    width = len(str(size))
    paths = np.array([f"synthetic/{i:0{width}d}-{real['paths'][p]}" for i, p in enumerate(picks)], dtype=object)
    columns = {
        "entries/path": paths,
        "entries/hash": np.char.zfill(np.arange(size).astype("S64"), 64),  # unique: no entry is a copy
        "entries/size": np.ones(size, dtype=np.int64),
        "entries/mtime_ns": np.zeros(size, dtype=np.int64),
        "entries/status": np.zeros(size, dtype=np.uint8),
        "entries/reason": np.full(size, "", dtype=object),
        "entries/triangles": np.ones(size, dtype=np.int64),
        "entries/area": np.ones(size),
        "entries/watertight": np.ones(size, dtype=bool),
    }
    columns.update({name: real[name][picks] for name in SHAPE_COLUMNS})
    assert set(columns) | {"entries/fractions"} | {k for k in ENTRY_COLUMNS if k.startswith("histograms/")} == set(
        ENTRY_COLUMNS)
    return columns


def measure(store: Path, metric: str, repeats: int) -> dict:
    started = time.perf_counter()
    with open_store(store) as reader:
        table = SignatureTable.load(reader, METRIC_HISTOGRAMS[metric])
        query = reader.signature(int(table.rows[len(table) // 3]))
    load = time.perf_counter() - started
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        hits = top_hits(table.distances(query, metric), table.paths, 10)
        times.append(time.perf_counter() - started)
    assert hits[0]["distance"] == 0.0
    bins = sum(int(sum(g[2].size for g in table.banks[h].groups)) for h in table.banks)
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
        store = args.work / f"synthetic-{size}.h5"
        if not store.exists():
            started = time.perf_counter()
            write_synthetic(store, size, real)
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
