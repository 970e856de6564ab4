#!/usr/bin/env python3
"""Write a synthetic store of N entries made from the real signatures of another store.

Usage::

    python scripts/make_store.py SOURCE N OUT [--seed S] [--shards K]

SOURCE is a store built by ``shapeidx build`` from real parts (e.g. kicad6 at the default
1024 points). Each of the N entries is one of SOURCE's ok entries, picked at random and
perturbed so that no two entries are alike, while every entry stays a consistent signature:

* each IN, OUT and MIXED histogram: its last 0 to 5 bins dropped (so bin counts vary as in
  real stores; trailing empty bins trimmed, as a real histogram has none), every count
  scaled by its own random factor in [0.9, 1.1] (empty bins stay empty);
* the three classes then share the ``points * (points - 1) / 2`` pairs in proportion to
  their perturbed totals (each histogram rescaled to its share and rounded, the residual in
  its fullest bin), so that, as in a real signature, they hold every pair together and pass
  ``shapeidx check``; the class fractions are these shares over the pairs;
* the ALL histogram is perturbed in the same way and then rescaled so that it holds all
  the pairs;
* each class's mean distance is scaled by a random factor in [0.98, 1.02]; the ALL mean is
  the fraction-weighted mean of the class means (the mean over all pairs); every bin width
  is its mean over the store's bin divisor, as :meth:`Histogram.of` makes it.

Paths are ``synthetic/NNNNNNN-SOURCE_PATH`` (so each entry names the real part it came from),
and the mesh facts, size and time are the source entry's. The store is written by
shapeidx's own :class:`~shapeidx.store.StoreWriter`: a journal batch per
:data:`CHUNK` entries, then one merge, so it is a real store in every respect (the same
files, attributes and guarantees as one a build writes). ``scripts/bench_query.py`` and the
tests use it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from shapeidx.ragged import offsets_of
from shapeidx.signing.histogram import Histogram
from shapeidx.signing.parameters import CLASS_NAMES, HISTOGRAMS
from shapeidx.store import STATUS_OK, Batch, Entry, StoreWriter, open_store
from shapeidx.store.layout import OPTIONAL_COLUMNS

#: The size, handedness and normal-angle facts of an entry (copied from its source entry,
#: unperturbed: the perturbed D2 histograms already make every entry unlike the others).
SHAPE_FIELDS = tuple(name.split("/", 1)[1] for name in OPTIONAL_COLUMNS)

#: Entries generated and committed per journal batch (bounds the generator's memory).
CHUNK = 50_000
#: The root a synthetic store records: no real folder, so no build can ever update it.
SYNTHETIC_ROOT = Path("/synthetic")


def real_signatures(source: Path) -> dict:
    """The source store's ok entries: params, paths, facts, and per histogram (counts, lengths, means)."""
    with open_store(source) as reader:
        rows = np.flatnonzero(reader.column("entries/status") == STATUS_OK)
        if len(rows) == 0:
            raise SystemExit(f"{source}: no ok entries to make a store from")
        out = {"params": reader.params, "paths": reader.paths[rows]}
        # the revision of the reader that made each source signature (1 from a store before it)
        for name in ("size", "mtime_ns", "triangles", "area", "watertight", "revision", *SHAPE_FIELDS):
            out[name] = reader.column(f"entries/{name}")[rows]
        for name in HISTOGRAMS:
            counts, lengths = reader.counts(name, rows)
            out[name] = (counts, lengths, reader.column(f"histograms/{name}/mean")[rows])
    return out


def _segments(lengths: np.ndarray) -> np.ndarray:
    """The entry (0..n-1) of every value of a ragged array with these lengths."""
    return np.repeat(np.arange(len(lengths)), lengths)


def _gather(flat: np.ndarray, offsets: np.ndarray, rows: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The first ``lengths[k]`` values of row ``rows[k]`` of a ragged array, end to end."""
    starts = np.repeat(offsets[rows] - offsets_of(lengths)[:-1], lengths)
    return flat[starts + np.arange(int(lengths.sum()))]


def _trim_trailing_zeros(flat: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each histogram cut after its last non-empty bin (a real histogram ends on one)."""
    local = np.arange(len(flat)) - np.repeat(offsets_of(lengths)[:-1], lengths)
    last = np.full(len(lengths), -1, dtype=np.int64)
    np.maximum.at(last, _segments(lengths), np.where(flat > 0, local, -1))
    kept = last + 1
    return _gather(flat, offsets_of(lengths), np.arange(len(lengths)), kept), kept


def perturbed_histograms(base_counts, base_lengths, picks, rng) -> tuple[np.ndarray, np.ndarray]:
    """Histograms ``picks`` of the base: 0-5 last bins dropped, each count scaled in [0.9, 1.1].

    Returns float64 counts (not rounded yet) and lengths.
    """
    lengths = np.maximum(base_lengths[picks] - rng.integers(0, 6, len(picks)), np.minimum(base_lengths[picks], 1))
    flat = _gather(base_counts, offsets_of(base_lengths), picks, lengths).astype(np.float64)
    flat, lengths = _trim_trailing_zeros(flat, lengths)
    return flat * rng.uniform(0.9, 1.1, len(flat)), lengths


def _round_to_totals(flat: np.ndarray, lengths: np.ndarray, totals: np.ndarray) -> np.ndarray:
    """Integer counts proportional to ``flat`` whose sum per histogram is exactly ``totals``.

    Each count is rounded; the residual (a few pairs) goes to each histogram's fullest bin
    when pairs are missing, and is taken from its fullest bins in turn, down to one pair
    each, when there are too many (a histogram of more bins than pairs keeps its last bin
    non-empty): no count goes below zero. (Taking it all from the fullest bin drove a count
    negative when a sparse histogram's many roundings up outweighed that bin: 2 of 500,000
    entries of a 5 x 10^6 store.)
    """
    segment = _segments(lengths)
    starts = offsets_of(lengths)[:-1]
    sums = np.bincount(segment, weights=flat, minlength=len(lengths))
    scale = np.divide(totals, sums, out=np.zeros(len(lengths)), where=sums > 0)
    counts = np.rint(flat * scale[segment]).astype(np.int64)
    residual = totals - np.bincount(segment, weights=counts, minlength=len(lengths)).astype(np.int64)
    order = np.lexsort((-counts, segment))  # each histogram's bins, fullest first
    rank = np.arange(len(order)) - np.repeat(starts, lengths)
    first = order[rank == 0]  # the fullest bin of each non-empty histogram
    owner = segment[first]
    more = residual[owner] > 0
    counts[first[more]] += residual[owner[more]]
    last = np.zeros(len(counts), dtype=bool)
    last[offsets_of(lengths)[1:][lengths > 0] - 1] = True
    excess = np.maximum(-residual, 0)
    # down to one pair a bin; then, only if that is not enough (a histogram of more bins than
    # pairs), down to none but the last bin (a real histogram ends on a non-empty bin)
    for keep in (np.ones(len(counts), dtype=np.int64), last.astype(np.int64)):
        spare = np.maximum(counts[order] - keep[order], 0)  # what each bin can give, fullest first
        ends = np.cumsum(spare)
        before = ends - spare - np.repeat(np.concatenate(([0], ends))[starts], lengths)  # within its histogram
        taken = np.clip(excess[segment[order]] - before, 0, spare)
        counts[order] -= taken
        excess -= np.bincount(segment[order], weights=taken, minlength=len(lengths)).astype(np.int64)
    return counts


def _shares_of(weights: np.ndarray, totals: np.ndarray) -> np.ndarray:
    """Integers proportional to each row of ``weights`` that sum to ``totals`` (residual to the largest)."""
    shares = np.rint(weights / weights.sum(axis=1, keepdims=True) * totals[:, None]).astype(np.int64)
    shares[np.arange(len(shares)), np.argmax(weights, axis=1)] += totals - shares.sum(axis=1)
    return shares


def synthetic_chunk(real: dict, picks: np.ndarray, rng) -> dict:
    """Perturbed signatures of the source entries ``picks`` (see the module docstring).

    Returns per histogram (int64 counts end to end, lengths, means, bin widths) and the
    (n, 3) fractions.
    """
    divisor = real["params"].bin_divisor
    points = real["params"].points
    out, perturbed, totals, means = {}, {}, [], []
    for name in CLASS_NAMES:
        base_counts, base_lengths, base_means = real[name]
        flat, lengths = perturbed_histograms(base_counts, base_lengths, picks, rng)
        perturbed[name] = (flat, lengths)
        totals.append(np.bincount(_segments(lengths), weights=flat, minlength=len(picks)))
        means.append(base_means[picks] * rng.uniform(0.98, 1.02, len(picks)))
    # the classes share the point pairs as perturbed, and together hold all of them, as a real
    # signature does (shapeidx check verifies it)
    pairs = np.full(len(picks), points * (points - 1) // 2, dtype=np.int64)
    class_totals = _shares_of(np.stack(totals, axis=1), pairs)
    for k, name in enumerate(CLASS_NAMES):
        flat, lengths = perturbed[name]
        counts = _round_to_totals(flat, lengths, class_totals[:, k])
        out[name] = (counts, lengths, means[k], means[k] / divisor)
    fractions = class_totals / pairs[:, None]
    base_counts, base_lengths, _ = real["all"]
    flat, lengths = perturbed_histograms(base_counts, base_lengths, picks, rng)
    all_mean = np.sum(fractions * np.stack(means, axis=1), axis=1)
    out["all"] = (_round_to_totals(flat, lengths, pairs.astype(np.int64)), lengths, all_mean, all_mean / divisor)
    out["fractions"] = fractions
    return out


def synthetic_entries(real: dict, first: int, picks: np.ndarray, rng, width: int) -> list[Entry]:
    """Entries ``first`` .. ``first + len(picks) - 1`` of the synthetic store."""
    chunk = synthetic_chunk(real, picks, rng)
    offsets = {name: offsets_of(chunk[name][1]) for name in HISTOGRAMS}
    columns = {name: (chunk[name][0], offsets[name].tolist(), chunk[name][2].tolist(), chunk[name][3].tolist())
               for name in HISTOGRAMS}
    fractions = chunk["fractions"].tolist()
    entries = []
    for k, pick in enumerate(picks.tolist()):
        histograms = {name: Histogram(counts[o[k]:o[k + 1]], mean[k], bin_width[k])
                      for name, (counts, o, mean, bin_width) in columns.items()}
        i = first + k
        entries.append(Entry(
            path=f"synthetic/{i:0{width}d}-{real['paths'][pick]}",
            hash=f"{i:064x}",  # distinct, and plainly not a real file's SHA-256
            size=int(real["size"][pick]),
            mtime_ns=int(real["mtime_ns"][pick]),
            triangles=int(real["triangles"][pick]),
            area=float(real["area"][pick]),
            watertight=bool(real["watertight"][pick]),
            revision=int(real["revision"][pick]),
            **{name: tuple(real[name][pick].tolist()) for name in SHAPE_FIELDS},
            fractions=tuple(fractions[k]),
            histograms=histograms,
        ))
    return entries


def write_store(out: Path, size: int, real: dict, seed: int = 1, chunk: int = CHUNK, shards: int | None = None) -> None:
    """A store of ``size`` entries derived from ``real`` at ``out`` (which must not exist);
    ``shards``: a sharded store (:mod:`shapeidx.store.shards`) of that many shards holding
    the same entries, each shard the entries whose path key is its own."""
    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} exists: make_store writes new stores only")
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(real["paths"]), size)
    width = len(str(max(size - 1, 0)))
    if shards:
        from shapeidx.store.shards import create_sharded, shard_of_paths

        paths = [f"synthetic/{i:0{width}d}-{real['paths'][pick]}" for i, pick in enumerate(picks.tolist())]
        of = shard_of_paths(paths, shards)
        del paths
        for k, shard in enumerate(create_sharded(out, shards)):
            mine = np.flatnonzero(of == k)
            _write(shard, real, mine, picks[mine], rng, width, chunk)
        return
    _write(out, real, np.arange(size), picks, rng, width, chunk)


def _write(out: Path, real: dict, numbers: np.ndarray, picks: np.ndarray, rng, width: int, chunk: int) -> None:
    """Entries ``numbers`` (made from the source entries ``picks``) into a new store ``out``."""
    with StoreWriter(out, real["params"], SYNTHETIC_ROOT) as writer:
        for at in range(0, len(numbers), chunk):
            entries = synthetic_entries(real, 0, picks[at:at + chunk], rng, width)
            for entry, number in zip(entries, numbers[at:at + chunk].tolist()):
                entry.path = f"synthetic/{number:0{width}d}-{entry.path.split('-', 1)[1]}"
                entry.hash = f"{number:064x}"
            writer.commit(Batch(entries=entries))
        writer.merge()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("source", type=Path, help="a store of real parts")
    parser.add_argument("n", type=int, help="entries of the new store")
    parser.add_argument("out", type=Path, help="the new store (must not exist)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--shards", type=int, help="write a sharded store of this many shards (same entries)")
    args = parser.parse_args()
    if args.out.exists():
        print(f"make_store: {args.out} exists: make_store writes new stores only", file=sys.stderr)
        return 1
    started = time.perf_counter()
    real = real_signatures(args.source)
    write_store(args.out, args.n, real, args.seed, shards=args.shards)
    print(f"wrote {args.out}: {args.n:,} entries from {len(real['paths']):,} real signatures of {args.source}"
          f" ({sum(p.stat().st_size for p in args.out.rglob('*') if p.is_file()) / 1e6:.1f} MB) in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
