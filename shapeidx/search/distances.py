"""Distances from a query to the entries of a store: the one place they are computed.

Every surface that ranks a store (``query``, the Python API, the web page, sheets,
``classify``, the similarity words, ``evaluate``) asks this module, over the arrays a
:class:`~shapeidx.store.ranked.RankedView` maps from the store's files. Each metric is
computed from per-pair features by its registry record (:mod:`shapeidx.distance.metrics`):

* ``d_H`` (the paper's ``D`` of histogram H) by :func:`~shapeidx.distance.bank.padded_l1`
  over the stored counts, group by group of equal bin counts, exactly as
  :func:`~shapeidx.distance.compare` computes it for one pair (so a store ranking and a
  comparison agree bit for bit);
* the class-fraction gaps, class-scale gaps and normal-angle distances from the small
  per-entry arrays.

The candidate step (:func:`nearest`): for a metric whose record is ``bounded`` (its formula
never decreases as a ``D`` grows), every entry's ``D`` is bounded from below by that of its
coarse histograms (``rank/H/coarse``: summing bins never increases an L1 distance), the
other features are exact, and exact distances are computed only for the entries whose
bound does not rule them out. The answer is the exact one, bit for bit.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..distance.bank import features_to_many, padded_l1
from ..distance.combined import require_angles
from ..distance.metrics import metric as metric_record

#: Threads that rank the blocks of one query (numpy releases the GIL; see docs/performance.md).
RANK_THREADS = 2


def histogram_distances(view, h: str, query_p, positions=None, coarse: bool = False, pool=None) -> np.ndarray:
    """``D`` of histogram ``h`` from the query's probabilities ``query_p`` to the live entries at
    ``positions`` (default all); ``coarse``: a lower bound of it, from the coarse counts.

    Every block of counts read is checked against its (CRC-checked) totals as it is ranked,
    so a flipped bit of the mapped counts is reported as damage, never ranked.
    """
    query_p = np.asarray(query_p, dtype=np.float64)
    if positions is not None:
        return _at_positions(view, h, query_p, np.asarray(positions, dtype=np.int64), coarse)
    jobs, outs = [], []
    for i, section in enumerate(view.sections):
        out = np.zeros(len(section))
        outs.append(out)
        with view.checked(i):
            blocks = section.blocks(h, "coarse" if coarse else "counts")
        query = coarse_query(query_p, section.coarse) if coarse else query_p
        for part in _halves(blocks, len(query_p)) if pool is not None else [blocks]:
            jobs.append((i, part, out, query))
    rank = _bound_blocks if coarse else _rank_blocks
    if pool is None:
        for i, part, out, query in jobs:
            with view.checked(i):
                rank(part, query, len(query_p), out)
    else:
        futures = [(i, pool.submit(rank, part, query, len(query_p), out)) for i, part, out, query in jobs]
        for i, future in futures:
            with view.checked(i):
                future.result()
    parts = [out[view.live[i]] if len(view.live[i]) != len(out) else out for i, out in enumerate(outs)]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _rank_blocks(blocks, query: np.ndarray, query_bins: int, out: np.ndarray) -> None:
    """``D`` (or its coarse bound) of every row of ``blocks`` into ``out`` at the rows' rank positions."""
    for bins, block, totals, rows in blocks:
        width = max(bins, query_bins)  # D divides by the bin count of the longer histogram
        if width:
            out[rows] = padded_l1(block, totals, query, max(block.shape[1], len(query)), True) / width
        elif np.any(totals != 1):
            raise ValueError("histogram counts disagree with their totals")


def float32_slack(columns: int) -> float:
    """What float32 arithmetic may take off the L1 distance of two probability vectors of
    ``columns`` bins: each term ``|p - q|`` is off by at most ``2^-23 (p + q)`` (the roundings
    of p, q and of the difference), so all terms by ``2^-22`` (p and q each sum to at most 1),
    and a float32 sum in any order (BLAS) by at most ``(columns - 1) 2^-24`` times the sum of
    the terms (at most 2). Subtracted from a float32 L1, it leaves a lower bound of the exact one."""
    return (2 * max(columns - 1, 0) + 4) * 2.0**-24 * 1.01


def _bound_blocks(blocks, query: np.ndarray, query_bins: int, out: np.ndarray) -> None:
    """A lower bound of ``D`` from the coarse counts of every row of ``blocks`` into ``out``:
    their L1 distance in float32 (half the memory traffic of float64) less
    :func:`float32_slack`, over the longer histogram's bin count. Each row's counts are checked
    against its total, as :func:`_rank_blocks` checks them."""
    for bins, block, totals, rows in blocks:
        width = max(bins, query_bins)
        if not width:
            if np.any(totals != 1):
                raise ValueError("histogram counts disagree with their totals")
            continue
        columns = max(block.shape[1], len(query))
        q = np.zeros(columns, dtype=np.float32)
        q[: len(query)] = query
        tail = float(q[block.shape[1]:].sum(dtype=np.float64))  # bins only the query has: |0 - q| = q
        step = max(1, (1 << 15) // max(columns, 1))
        sums = np.empty(len(block))
        work = np.empty((min(step, len(block)), block.shape[1]), dtype=np.float32)
        ones = np.ones(block.shape[1], dtype=np.float32)
        exact = len(totals) == 0 or int(totals.max()) < 1 << 24  # integer sums exact in float32
        for start in range(0, len(block), step):
            part = block[start : start + step]
            n = len(part)
            diff = work[:n]
            np.copyto(diff, part, casting="unsafe")  # counts below 2^24: exact in float32
            check = diff @ ones if exact else part.sum(axis=1, dtype=np.int64)  # row sums (a BLAS product)
            if not np.array_equal(np.maximum(check, 1), totals[start : start + n]):
                raise ValueError("histogram counts disagree with their totals")
            np.divide(diff, totals[start : start + n, None].astype(np.float32), out=diff)
            np.subtract(diff, q[: block.shape[1]], out=diff)
            np.abs(diff, out=diff)
            sums[start : start + n] = diff @ ones
        out[rows] = np.maximum(sums + tail - float32_slack(columns), 0) / width


def _at_positions(view, h: str, query_p: np.ndarray, positions: np.ndarray, coarse: bool) -> np.ndarray:
    out = np.zeros(len(positions))
    for i, mine, rank_positions in view.by_file(positions):
        section = view.sections[i]
        query = coarse_query(query_p, section.coarse) if coarse else query_p
        with view.checked(i):
            starts, slot = section.slots(h)
            blocks = section.blocks(h, "coarse" if coarse else "counts")
            k = slot[rank_positions]
            group = np.searchsorted(starts, k, side="right") - 1
            for j in np.unique(group).tolist():
                sel = np.flatnonzero(group == j)
                bins, block, totals, _ = blocks[j]
                width = max(bins, len(query_p))
                at = k[sel] - starts[j]
                if width:
                    out[mine[sel]] = padded_l1(block[at], totals[at], query, max(block.shape[1], len(query)), True) / width
    return out


def coarse_query(query_p: np.ndarray, factor: int) -> np.ndarray:
    """The query's probabilities summed ``factor`` bins at a time, as the stored ``rank/H/coarse``."""
    padded = np.zeros(-(-len(query_p) // factor) * factor)
    padded[: len(query_p)] = query_p
    return padded.reshape(-1, factor).sum(axis=1)


def _halves(blocks: list, query_bins: int) -> list:
    """``blocks`` in two parts of about equal work (rows times width), for two threads."""
    if len(blocks) < 2:
        return [blocks]
    work = np.array([len(block) * max(bins, query_bins) for bins, block, _, _ in blocks], dtype=np.float64)
    cut = int(np.searchsorted(np.cumsum(work), work.sum() / 2)) + 1
    cut = min(max(cut, 1), len(blocks) - 1)
    return [blocks[:cut], blocks[cut:]]


def entry_features(view, signature, histograms, positions=None, angles: bool = False, coarse: bool = False,
                   threads: int = RANK_THREADS, scales: bool = True, sizes: bool = False) -> dict:
    """The per-pair features from ``signature`` to the live entries at ``positions`` (default
    all): ``d_H`` for the histograms ``histograms`` (lower bounds with ``coarse``), the class
    gaps and scales, with ``angles`` the normal-angle distances, with ``sizes`` the exact sizes' gaps."""
    pool = ThreadPoolExecutor(threads) if threads > 1 and len(histograms) and positions is None else None
    try:
        d = {h: histogram_distances(view, h, signature.histograms[h].p, positions, coarse, pool) for h in histograms}
    finally:
        if pool is not None:
            pool.shutdown()
    fractions = view.gather("fractions", positions)
    means = view.gather("means", positions) if scales else None  # the scale features: only where read
    angle_p = view.angle_probabilities(positions) if angles else None
    radii = view.numbers("entries/extents", 3, positions) if sizes else None
    return features_to_many(signature, None, fractions, means, histograms, distances=d, angles=angle_p, radii=radii)


def require_inputs(view, signature, record, positions=None) -> None:
    """Refuse, in one line, a metric whose inputs the store or the query lack (the normal-angle
    histograms; an unknown size adds nothing, so sizes are never refused)."""
    if record.angles:
        require_angles(view.angle_probabilities() if positions is None else view.angle_probabilities(positions),
                       signature, record.name)


def distances(view, signature, metric: str, positions=None, threads: int = RANK_THREADS) -> np.ndarray:
    """The ``metric`` distance from ``signature`` to the live entries at ``positions`` (default all),
    equal to :func:`shapeidx.distance.compare` for each pair, bit for bit."""
    record = metric_record(metric)
    require_inputs(view, signature, record, positions)
    features = entry_features(view, signature, record.histograms, positions, record.angles, threads=threads,
                              sizes=record.sizes)
    return np.asarray(record.value(features), dtype=np.float64)


def lower_bounds(view, signature, metric: str, threads: int = RANK_THREADS) -> np.ndarray:
    """A lower bound of the ``metric`` distance to every live entry (its record must be ``bounded``)."""
    record = metric_record(metric)
    features = entry_features(view, signature, record.histograms, None, record.angles, coarse=True, threads=threads,
                              scales=any(f.startswith("scale_") for f in record.features), sizes=record.sizes)
    # room for rounding: the bound and the distance are sums of different float terms
    return np.asarray(record.value(features), dtype=np.float64) * (1 - 1e-9) - 1e-15


def nearest(view, signature, metric: str, top: int, keep: np.ndarray | None = None, first: int | None = None,
            max_distance: float | None = None, threads: int = RANK_THREADS):
    """Positions and exact distances of a set of live entries holding every entry the
    ``top``-nearest answer among ``keep`` (a boolean mask over the live entries; default all)
    within ``max_distance`` can contain: the ``top`` nearest, every entry tied with the last
    of them, and ``first`` (the query's own entry, which wins its ties) when it is kept.

    Exact distances are computed only where a lower bound cannot rule an entry out (every
    entry for a metric whose record is not ``bounded``); they are those of :func:`distances`.
    """
    record = metric_record(metric)
    n = len(view)
    require_inputs(view, signature, record)
    if top <= 0 or n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    if not record.bounded:
        chosen = np.arange(n) if keep is None else np.flatnonzero(keep)
        return chosen, distances(view, signature, metric, None if keep is None else chosen, threads)
    bound = lower_bounds(view, signature, metric, threads)
    if keep is not None:
        bound[~keep] = np.inf
    if max_distance is not None:
        bound[bound > max_distance] = np.inf
    candidates = int(np.isfinite(bound).sum())
    if candidates == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    count = min(candidates, max(256, 16 * top))
    while True:
        chosen = np.argpartition(bound, count - 1)[:count] if count < n else np.arange(n)
        chosen = chosen[np.isfinite(bound[chosen])]
        if first is not None and np.isfinite(bound[first]) and first not in chosen:
            chosen = np.append(chosen, first)
        exact = distances(view, signature, metric, chosen, threads)
        valid = exact if max_distance is None else exact[exact <= max_distance]
        reach = np.partition(valid, top - 1)[top - 1] if len(valid) >= top else np.inf
        if max_distance is not None:
            reach = min(reach, max_distance)
        outside = np.partition(bound, count)[count] if count < n else np.inf
        if count >= candidates or reach < outside:
            return chosen, exact
        count = min(candidates, 4 * count)
