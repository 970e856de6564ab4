"""Bounds that prune in blocks: how a long-lived process answers a big store in a fraction of a pass.

A one-off query bounds every entry's distance from below (the coarse histograms,
:func:`shapeidx.search.distances.nearest`): a pass over every entry, linear in the store. A
long-lived process (``shapeidx serve``, a Python session holding a
:class:`~shapeidx.search.Searcher`) builds, once, a :class:`BlockIndex` of the store it has
open:

* the live entries are ordered so that entries with alike signatures are neighbours (a
  principal-axis tree over a few numbers per entry: the class fractions, the class scales and
  the leading principal components of each coarse histogram and of the normal-angle
  histograms), and cut into blocks of :data:`BLOCK` entries;
* each block keeps, per feature a metric reads, the interval its entries span: each coarse
  bin's probability at two levels (``rank/H/coarse``, 8 bins summed, and the finer level of
  :data:`FINE`, read from the counts), the largest bin count, each class fraction, each class
  scale, the square root of each normal-angle probability;
* each entry keeps, in block order, its probabilities at the finer level (float16), its bin
  counts, class fractions and class scales: its own bound without a gather from the mapped
  arrays.

For a query, every block's distance is bounded from below at once by the metric's own
formula (:attr:`shapeidx.distance.metrics.Metric.value`) over per-feature lower bounds: a
bin whose query value lies outside the block's interval contributes at least its gap to it
(the L1 distance of probabilities, of summed ones no more than of the full ones; the
Hellinger distance of the angle histograms term by term), and every formula of the registry
grows with each feature. Blocks are then taken nearest bound first, in rounds; each round's
entries are bounded one by one (the finer level's L1 in float32, less what float16 and
float32 rounding can take off it: :func:`float16_slack`, :func:`~shapeidx.search.distances.float32_slack`),
and those the bound cannot rule out are measured exactly
(:func:`shapeidx.search.distances.distances`, bit for bit those of a full ranking); the
exact distances set the current ``top``-th distance, and the search stops when no block left
has a bound at or below it. Every entry that could be in the answer, or tie with its last
hit, has been measured exactly: the answer is the full ranking's (tests/test_blocks.py).

The index costs a pass over the coarse histograms, one over the counts and a principal-axis
tree to build (about 50 s per 10^6 entries on a loaded 2-core machine, 12-25 s quieter) and
holds about 630 bytes an entry (566 of float16 probabilities, 48 of fractions and scales, 16
of bin counts; 8 of position), plus the blocks' intervals (a few MB per 10^6) and what the
view keeps (the normal-angle probabilities, 544 bytes an entry).
"""

from __future__ import annotations

import numpy as np

from ..distance.combined import SIZE_FEATURES, class_scales, signature_means
from ..distance.metrics import REGISTRY
from ..distance.metrics import metric as metric_record
from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS, angle_probabilities
from ..signing.parameters import CLASS_NAMES, HISTOGRAMS
from .distances import RANK_THREADS, coarse_query, distances, entry_features

#: Entries per block.
BLOCK = 256
#: Entries from which a :class:`~shapeidx.search.Searcher` builds its index by itself (on its
#: second query: a one-off command never pays for it).
WARM_MIN = 50_000
#: Leading principal components of each histogram's coarse probabilities in the ordering.
COMPONENTS = 4
#: Histograms whose coarse probabilities the index keeps per entry, in block order, as float16
#: (2 bytes a coarse bin: 240 bytes an entry for the four at 1024 points), with each entry's bin
#: count, class fractions and class scales: each entry's own bound of every metric that reads
#: D2 histograms is then computed from memory in block order, without a gather from the mapped
#: arrays (the coarse bounds are loose on near-alike parts, so a query bounds tens of thousands
#: of entries one by one).
CACHED = HISTOGRAMS
#: Bins summed into one of the probabilities the index keeps per entry (and bounds blocks by,
#: besides the store's coarse histograms), per histogram: finer than the store's coarse
#: histograms (8 bins), so an entry's own bound is tighter and fewer entries are measured
#: exactly (ALL finest: the metrics of ALL alone have no other term to prune by); read from the
#: counts once, when the index is built.
FINE = {"all": 2, "in": 4, "out": 4, "mixed": 4}
#: Entries whose exact distances the first round measures (then as the bounds require).
FIRST_ROUND = 1024


def _to_view(view, i: int) -> np.ndarray:
    """Per rank position of file ``i``: its position among the view's live entries (-1: superseded)."""
    out = np.full(len(view.sections[i]), -1, dtype=np.int64)
    out[view.live[i]] = view.starts[i] + np.arange(len(view.live[i]))
    return out


def coarse_probabilities(view, h: str, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """Every live entry's probabilities of histogram ``h`` summed ``factor`` bins at a time
    ((n, W) float64, zero-padded: the counts over the entry's total, as ranking divides them;
    from ``rank/H/coarse`` when ``factor`` is the store's coarse factor, else from the counts)
    and its bin count (n,)."""
    n = len(view)
    stored = all(s.coarse == factor for s in view.sections)
    width = max([-(-int(b) // factor) for s in view.sections for b in s.groups[h][:, 0].tolist()] or [0])
    p = np.zeros((n, width))
    bins = np.zeros(n, dtype=np.int64)
    for i, section in enumerate(view.sections):
        to_view = _to_view(view, i)
        with view.checked(i):
            for b, block, totals, rank_positions in section.blocks(h, "coarse" if stored else "counts"):
                at = to_view[rank_positions]
                live = at >= 0
                if not live.any():
                    continue
                rows = np.asarray(block[live])
                if rows.shape[1] and not np.array_equal(np.maximum(rows.sum(axis=1, dtype=np.int64), 1), totals[live]):
                    raise ValueError("histogram counts disagree with their totals")
                if not stored and rows.shape[1]:
                    padded = np.zeros((len(rows), -(-rows.shape[1] // factor) * factor), dtype=np.int64)
                    padded[:, : rows.shape[1]] = rows
                    rows = padded.reshape(len(rows), -1, factor).sum(axis=2)
                p[at[live], : rows.shape[1]] = rows / totals[live, None]
                bins[at[live]] = b
    return p, bins


def _components(values: np.ndarray, count: int, rng) -> np.ndarray:
    """``values`` projected on their ``count`` leading principal axes (from a sample), float32."""
    if values.shape[1] == 0:
        return np.zeros((len(values), 0), dtype=np.float32)
    sample = values[rng.choice(len(values), min(len(values), 4096), replace=False)]
    mean = sample.mean(axis=0)
    _, vectors = np.linalg.eigh(np.cov(sample - mean, rowvar=False).reshape(values.shape[1], values.shape[1]))
    axes = vectors[:, ::-1][:, :count].astype(np.float32)
    return values.astype(np.float32) @ axes - (mean @ axes).astype(np.float32)


def tree_order(points: np.ndarray, leaf: int = BLOCK, seed: int = 0) -> np.ndarray:
    """A permutation of the rows of ``points`` (n, d) in which every run of ``leaf`` rows from a
    multiple of ``leaf`` is one leaf of a principal-axis tree: each node split at a multiple of
    ``leaf`` along its rows' leading principal axis, so a leaf holds neighbours."""
    rng = np.random.default_rng(seed)
    n = len(points)
    perm = np.arange(n)
    stack = [(0, n)]
    while stack:
        a, b = stack.pop()
        if b - a <= leaf:
            continue
        rows = points[perm[a:b]]
        sample = rows[rng.choice(len(rows), min(len(rows), 4096), replace=False)] if len(rows) > 4096 else rows
        centred = sample - sample.mean(axis=0)
        axis = rng.standard_normal(points.shape[1]).astype(np.float32)
        for _ in range(4):  # power iteration: near enough the leading principal axis to split
            axis = centred.T @ (centred @ axis)
            norm = float(np.sqrt(axis @ axis))
            if norm == 0:
                break
            axis /= norm
        left = (-(-(b - a) // leaf) // 2) * leaf
        split = np.argpartition(rows @ axis, left - 1)
        perm[a:b] = perm[a:b][split]
        stack += [(a, a + left), (a + left, b)]
    return perm


def entry_bounds(view, signature, metric: str, positions: np.ndarray, threads: int = RANK_THREADS) -> np.ndarray:
    """A lower bound of the ``metric`` distance to the live entries at ``positions`` (their coarse
    histograms; the other features exact), as :func:`shapeidx.search.distances.lower_bounds`."""
    from ..distance.combined import ANGLE_FEATURES

    record = metric_record(metric)
    # a metric of D terms leaves its (non-negative) angle terms out of the bound: 0 bounds them
    angles = record.angles and not record.histograms
    features = entry_features(view, signature, record.histograms, positions, angles, coarse=True, threads=threads,
                              sizes=record.sizes)
    if record.angles and not angles:
        features.update(dict.fromkeys(ANGLE_FEATURES, 0.0))
    return np.asarray(record.value(features), dtype=np.float64) * (1 - 1e-9) - 1e-15


def _l1_rows(p: np.ndarray, at: np.ndarray, q: np.ndarray, step: int = 4096) -> np.ndarray:
    """Float32 L1 distances from ``q`` to the rows ``at`` of ``p`` (float16), a few thousand rows
    at a time (each step's rows stay in the CPU cache through the conversion, the difference and
    the sum)."""
    out = np.empty(len(at), dtype=np.float32)
    work = np.empty((min(step, len(at)), p.shape[1]), dtype=np.float32)
    ones = np.ones(p.shape[1], dtype=np.float32)
    for start in range(0, len(at), step):
        rows = work[: len(at[start : start + step])]
        np.copyto(rows, p[at[start : start + step]], casting="unsafe")  # float16 -> float32: exact
        np.subtract(rows, q, out=rows)
        np.abs(rows, out=rows)
        out[start : start + len(rows)] = rows @ ones
    return out


def float16_slack(columns: int) -> float:
    """What keeping probabilities (summing to 1) in float16 may take off their L1 distance to
    anything: each is off by at most half a unit in the last place, ``2^-11`` of it when
    normal, ``2^-25`` when subnormal, so all ``columns`` of them by ``2^-11 + columns 2^-25``."""
    return (2.0**-11 + columns * 2.0**-25) * 1.01


class BlockIndex:
    """The blocks of a view (see the module docstring)."""

    def __init__(self, view, block: int = BLOCK, fine: dict | None = None):
        self.view = view
        self.block = block
        self.fine = dict(FINE if fine is None else fine)
        n = len(view)
        self.n = n
        rng = np.random.default_rng(0)
        fractions = np.asarray(view.gather("fractions"), dtype=np.float64)
        scales = class_scales(np.asarray(view.gather("means"), dtype=np.float64))
        angle_p = view.angle_probabilities()
        self.angles_known = bool(np.isfinite(angle_p).all())
        roots = np.sqrt(angle_p).reshape(n, -1) if self.angles_known else None
        ordering = [fractions.astype(np.float32), scales.astype(np.float32)]
        stored = view.sections[0].coarse if view.sections else 8
        coarse = {}
        for h in HISTOGRAMS:
            coarse[h] = coarse_probabilities(view, h, stored)
            ordering.append(_components(coarse[h][0], COMPONENTS, rng))
        if roots is not None:
            ordering.append(_components(roots, 2 * COMPONENTS, rng))
        points = np.concatenate(ordering, axis=1)
        del ordering
        points /= np.maximum(points.std(axis=0), np.float32(1e-12))  # every column counts alike in the splits
        self.perm = tree_order(points, block)
        del points
        self.starts = np.arange(0, n, block)
        self.ends = np.minimum(self.starts + block, n)
        self.intervals: dict = {}
        self.levels: dict = {}  # histogram -> [(bins summed, per-block lowest, highest), ...]
        self.max_bins: dict = {}
        self.cached: dict = {}
        for h in HISTOGRAMS:
            p, bins = coarse.pop(h)
            self.levels[h] = [(stored, *self._span(p))]
            if self.fine[h] != stored:
                p, _ = coarse_probabilities(view, h, self.fine[h])
                self.levels[h].append((self.fine[h], *self._span(p)))
            self.max_bins[h] = np.maximum.reduceat(bins[self.perm], self.starts) if n else np.zeros(0, np.int64)
            if h in CACHED:  # in block order: each entry's own bound without a gather
                self.cached[h] = (p[self.perm].astype(np.float16), bins[self.perm].astype(np.int32))
            del p
        self.fractions = fractions[self.perm]  # float64, the very values the exact features read
        self.scales = scales[self.perm]
        self.intervals["fractions"] = self._span(fractions)
        self.intervals["scales"] = self._span(scales)
        if roots is not None:
            self.intervals["angles"] = self._span(roots)

    def _span(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per block, the lowest and highest value of each column of ``values`` (rows in view order)."""
        lo = np.empty((len(self.starts), values.shape[1]))
        hi = np.empty_like(lo)
        step = 64 * self.block
        for start in range(0, self.n, step):
            rows = values[self.perm[start : start + step]]
            first = start // self.block
            at = np.arange(0, len(rows), self.block)
            if values.shape[1]:
                lo[first : first + len(at)] = np.minimum.reduceat(rows, at, axis=0)
                hi[first : first + len(at)] = np.maximum.reduceat(rows, at, axis=0)
        return lo, hi

    def __len__(self) -> int:
        return len(self.starts)

    def serves(self, metric: str, signature) -> bool:
        """Whether the blocks can rank ``metric`` (else the one-off road ranks it, or refuses it
        in one line: angles the store or the query lacks)."""
        if REGISTRY[metric].angles and (not self.angles_known or signature.angles is None):
            return False
        return REGISTRY[metric].monotone

    def bounds(self, signature, metric: str) -> np.ndarray:
        """A lower bound of the ``metric`` distance from ``signature`` to every entry of each block."""
        record = metric_record(metric)
        blocks = len(self.starts)
        features = {f"d_{h}": np.zeros(blocks) for h in HISTOGRAMS}
        features.update(dict.fromkeys(SIZE_FEATURES, 0.0))  # non-negative terms: 0 bounds them
        for h in record.histograms:
            query_p = np.asarray(signature.histograms[h].p, dtype=np.float64)
            l1 = np.zeros(blocks)
            for factor, lo, hi in self.levels[h]:  # each level's bound holds: the larger one
                coarse = coarse_query(query_p, factor) if len(query_p) else np.zeros(0)
                width = max(lo.shape[1], len(coarse))
                q = np.zeros(width)
                q[: len(coarse)] = coarse
                lo = np.pad(lo, ((0, 0), (0, width - lo.shape[1])))
                hi = np.pad(hi, ((0, 0), (0, width - hi.shape[1])))
                np.maximum(l1, np.maximum(np.maximum(lo - q, q - hi), 0).sum(axis=1), out=l1)
            bins = np.maximum(self.max_bins[h], len(query_p))
            features[f"d_{h}"] = np.divide(l1, bins, out=np.zeros(blocks), where=bins > 0)
        fractions = signature.fractions
        lo, hi = self.intervals["fractions"]
        for i, c in enumerate(CLASS_NAMES):
            features[f"gap_{c}"] = np.maximum(np.maximum(lo[:, i] - fractions[c], fractions[c] - hi[:, i]), 0)
        scale = class_scales(signature_means(signature))
        lo, hi = self.intervals["scales"]
        for i, c in enumerate(CLASS_NAMES):
            features[f"scale_{c}"] = np.maximum(np.maximum(lo[:, i] - scale[i], scale[i] - hi[:, i]), 0)
        if record.angles:
            lo, hi = self.intervals["angles"]
            root = np.sqrt(angle_probabilities(signature.angles)).reshape(-1)
            gap = np.maximum(np.maximum(lo - root, root - hi), 0).reshape(blocks, len(ANGLE_HISTOGRAMS), ANGLE_BINS)
            p_gap = np.maximum(np.maximum(lo ** 2 - root ** 2, root ** 2 - hi ** 2), 0).reshape(gap.shape)
            for k, h in enumerate(ANGLE_HISTOGRAMS):
                features[f"hellinger_angle_{h}"] = np.sqrt((gap[:, k] ** 2).sum(axis=1) / 2)
                features[f"angle_{h}"] = p_gap[:, k].sum(axis=1)
        # room for rounding, as lower_bounds leaves it
        return np.asarray(record.value(features), dtype=np.float64) * (1 - 1e-9) - 1e-15

    def _entry_bounds(self, signature, metric: str, at: np.ndarray, threads: int) -> np.ndarray:
        """:func:`entry_bounds` of the entries at block-order places ``at``: from the kept coarse
        probabilities, fractions and scales when the metric reads kept histograms (its angle
        terms bounded by 0, as :func:`entry_bounds` bounds them), else from the mapped arrays."""
        from ..distance.combined import ANGLE_FEATURES
        from .distances import float32_slack

        record = metric_record(metric)
        if not record.histograms or not set(record.histograms) <= set(self.cached):
            return entry_bounds(self.view, signature, metric, self.perm[at], threads)
        features = {f"d_{h}": 0.0 for h in HISTOGRAMS}
        features.update(dict.fromkeys(ANGLE_FEATURES + SIZE_FEATURES, 0.0))
        for h in record.histograms:
            p, bins = self.cached[h]
            query_p = np.asarray(signature.histograms[h].p, dtype=np.float64)
            coarse = coarse_query(query_p, self.fine[h]) if len(query_p) else np.zeros(0)
            width = max(p.shape[1], len(coarse))
            q = np.zeros(width, dtype=np.float32)
            q[: len(coarse)] = coarse
            tail = float(q[p.shape[1]:].sum(dtype=np.float64))  # bins only the query has
            l1 = _l1_rows(p, at, q[: p.shape[1]])
            widths = np.maximum(bins[at], len(query_p))
            slack = float32_slack(width) + float16_slack(p.shape[1])
            features[f"d_{h}"] = np.divide(np.maximum(l1 + tail - slack, 0), widths,
                                           out=np.zeros(len(at)), where=widths > 0)
        fractions = self.fractions[at]  # the class features exactly as features_to_many has them
        for i, c in enumerate(CLASS_NAMES):
            features[f"gap_{c}"] = np.abs(fractions[:, i] - signature.fractions[c])
        if any(f.startswith("scale_") for f in record.features):
            scale_gap = np.abs(self.scales[at] - class_scales(signature_means(signature)))
            for i, c in enumerate(CLASS_NAMES):
                features[f"scale_{c}"] = scale_gap[:, i]
        return np.asarray(record.value(features), dtype=np.float64) * (1 - 1e-9) - 1e-15

    def nearest(self, signature, metric: str, top: int, keep: np.ndarray | None = None,
                max_distance: float | None = None, threads: int = RANK_THREADS):
        """What :func:`shapeidx.search.distances.nearest` returns (positions and exact distances
        of a set holding every entry the answer can contain), block by block."""
        bound = self.bounds(signature, metric)
        if keep is not None:
            kept = np.add.reduceat(keep[self.perm].astype(np.int64), self.starts)
            bound[kept == 0] = np.inf
        if max_distance is not None:
            bound[bound > max_distance] = np.inf
        order = np.argsort(bound, kind="stable")
        order = order[np.isfinite(bound[order])]
        taken, positions, exact = 0, [], []
        reach = np.inf
        round_size = max(FIRST_ROUND, 16 * top)
        while taken < len(order) and bound[order[taken]] <= reach:
            # rounds of blocks, nearest bound first, each twice the last: the first measured
            # exactly, the next through each entry's own bound first; each round's exact
            # distances bring the reach down for the next
            size = 0
            first = taken
            while taken < len(order) and bound[order[taken]] <= reach and (size < round_size or taken == first):
                b = order[taken]
                size += int(self.ends[b] - self.starts[b])
                taken += 1
            round_size *= 2
            at = np.concatenate([np.arange(self.starts[b], self.ends[b]) for b in order[first:taken]])
            if keep is not None:
                at = at[keep[self.perm[at]]]
            if len(at) and np.isfinite(reach):  # each entry's own coarse bound first
                at = at[self._entry_bounds(signature, metric, at, threads) <= reach]
            chosen = np.sort(self.perm[at])  # in store order: the mapped rows are read in turn
            if len(chosen):
                positions.append(chosen)
                exact.append(distances(self.view, signature, metric, chosen, threads))
                measured = np.concatenate(exact)
                valid = measured if max_distance is None else measured[measured <= max_distance]
                reach = np.partition(valid, top - 1)[top - 1] if len(valid) >= top else np.inf
                if max_distance is not None:
                    reach = min(reach, max_distance)
        if not positions:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        return np.concatenate(positions), np.concatenate(exact)
