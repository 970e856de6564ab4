"""The candidate step: which entries are worth an exact distance. One module for the three
roads that need it, the one-off query, ``duplicates`` and ``cluster``.

Two questions, one step each, both ending in the exact distance:

* **one part against every entry** (a query: :func:`shapeidx.search.distances.nearest`). Every
  entry's distance is bounded from below by that of its coarse histograms (``rank/H/coarse``,
  every 8 bins summed, memory-mapped; :mod:`shapeidx.store.ranked`), and exact
  distances are computed only where the bound cannot rule an entry out. For the paper's
  metrics the answer is therefore exact, bit for bit (recall 1 by construction, measured at
  10^6 entries by ``scripts/bench_store.py recall``); for the others (no bound) every entry is
  ranked exactly. The bound pass is linear in the store but reads 1/8 of the counts.
* **every entry against every entry** (``duplicates``, ``cluster``: :func:`candidate_pairs`).
  A bound per pair would be N^2 work; instead every signature becomes a fixed-length vector
  (:func:`embed`) whose Euclidean distances order pairs nearly as the store's distances do,
  the vectors are searched for each entry's nearest ones (:class:`CandidateIndex`, FAISS),
  and only those candidates get the exact distance
  (:meth:`shapeidx.families.table.FamilyTable.pair_distances`). This one is approximate:
  its recall against the exact answer is measured (``scripts/bench_families.py`` at 10^4,
  ``scripts/bench_store.py recall --embedding`` for single queries at 10^6).

Why not one mechanism for both: the embedding's nearest vectors miss some of the exact
nearest entries (docs/scaling.md has the recall at 10^6), so a query answered from it would
no longer be the exact ranking, and certifying its answer needs the very bound pass above;
the bounds, in turn, cost N per entry, N^2 for all pairs. Both read the same signatures.

The embedding. Every stored histogram has bins of one width on the axis "distance / that
histogram's mean" (the paper's normalisation), so bin k means the same for every part.
Each histogram is coarsened to :data:`COARSE_BINS` bins of :data:`FINE_PER_COARSE` stored
bins (the last one takes the rest of the tail) and the square roots of its probabilities
are taken: Euclidean distance between such vectors is the Hellinger distance, which orders
near pairs as the L1 ``D`` does. Weights per block (histograms, class fractions, the class
scales ``ln(mean_c / mean_all)``) follow the metric's own weights, so one embedding per
metric. combined-angle has no D2 term: its vectors are the square roots of the four
normal-angle histograms (whose Euclidean distance is sqrt(2) times their Hellinger
distance, the metric's own term) with its class features (15-neighbour recall at 10,000
synthetic entries 0.9956, was 0.9876 with combined's D2 blocks). The embedding only proposes: recall against the exact answer is measured by
``scripts/bench_families.py`` (>= 99% of the exact neighbours and pairs at 10,000 entries).
"""

from __future__ import annotations

import numpy as np

from ..distance import metric as metric_record
from ..distance.combined import class_scales
from ..signing.parameters import CLASS_NAMES, HISTOGRAMS

#: The normal-angle histograms' order (shapeidx.signing.angles.ANGLE_HISTOGRAMS, which a
#: query's start does not import).
ANGLE_HISTOGRAMS = ("all",) + CLASS_NAMES
#: The histogram blocks of an embedding vector, in order (after the class blocks).
BLOCK_ORDER = tuple(f"d2_{h}" for h in HISTOGRAMS) + tuple(f"angle_{h}" for h in ANGLE_HISTOGRAMS)

#: Coarse bins per histogram in the embedding, and stored bins per coarse bin: 48 x 3 covers
#: distances up to 2.9 times the mean (the rest of the tail is the last bin).
COARSE_BINS = 48
FINE_PER_COARSE = 3
#: Candidates fetched from the embedding per neighbour wanted: 3 finds 99.8% of the exact
#: 10 nearest on 10,000 synthetic entries (1 finds 63%); scripts/bench_families.py.
OVERFETCH = 3
#: Up to this many entries the index is exact (brute force on the vectors: N^2 work); above,
#: an inverted file (IVF: N sqrt(N) work). At 10^5 entries brute force was 290 of the 420 s of
#: ``find_duplicates`` (docs/performance-families.md).
EXACT_LIMIT = 20_000
#: IVF: lists per sqrt(N) entries, lists probed per query, training points per list (FAISS's
#: k-means wants at least 39), the sample's seed. Recall against brute force is measured by
#: ``scripts/bench_families.py`` (docs/performance-families.md).
IVF_LISTS_PER_ROOT = 4
IVF_PROBE = 24
IVF_TRAIN_PER_LIST = 40
IVF_SEED = 22
#: HNSW graph degree and search breadth (``method="hnsw"``; recall measured by
#: scripts/bench_families.py).
HNSW_M = 32
HNSW_EF_SEARCH = 256
HNSW_EF_CONSTRUCTION = 200


#: The bin count that the D2 blocks' weights assume (``D`` is L1 / bins; the median bin count
#: is 109 to 154 per histogram on kicad6 and on the whole KiCad 6 library). A constant, not the
#: store's median, so that an entry's vector depends on that entry alone.
REFERENCE_BINS = 128


def d2_basis(flat: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(n, :data:`COARSE_BINS`) float32: each histogram (counts end to end) coarsened to bins of
    :data:`FINE_PER_COARSE` (the tail folded into the last), as probabilities, square-rooted.

    One entry's row depends on that entry only: the ranking section of every store file
    keeps these rows (``rank/H/embedding``, :mod:`shapeidx.store.rank`), written with the
    entries, so no run recomputes them.
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    n = len(lengths)
    flat = np.asarray(flat, dtype=np.float64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]) if n else np.zeros(0, np.int64)
    k = np.arange(len(flat)) - np.repeat(starts, lengths)
    coarse = np.minimum(k // FINE_PER_COARSE, COARSE_BINS - 1)
    row = np.repeat(np.arange(n), lengths)
    dense = np.zeros((n, COARSE_BINS))
    np.add.at(dense, (row, coarse), flat)
    totals = dense.sum(axis=1, keepdims=True)
    dense = np.divide(dense, totals, out=np.zeros_like(dense), where=totals > 0)
    return np.sqrt(dense).astype(np.float32)


def stored_d2_basis(reader, rows: np.ndarray, histograms) -> dict:
    """The :func:`d2_basis` rows of the store's entries ``rows`` (rows of ``reader``'s merged
    view), per histogram, read from each file's ranking section (``rank/H/embedding``: memory
    mapped; a file written before it computes them from its counts), or {} for a store whose
    files lack ranking sections."""
    histograms = tuple(histograms)
    if not histograms or not len(rows):
        return {}
    sources = reader._sources
    if any(source.rank is None for source in sources):
        return {}
    which, file_rows = reader.source[rows], reader.row[rows]
    out = {h: np.zeros((len(rows), COARSE_BINS), dtype=np.float32) for h in histograms}
    for i, source in enumerate(sources):
        here = np.flatnonzero(which == i)
        if not len(here):
            continue
        section = source.rank
        positions = np.searchsorted(section.rows, file_rows[here])
        for h in histograms:
            out[h][here] = section.array(f"{h}/embedding")[positions]
    return out


def embedding_weights(metric: str) -> dict:
    """Per block of the basis (:func:`embedding_basis`), the factor ``metric`` puts on it: a
    number, or one per column, made from the metric record's first-order terms alone
    (:attr:`shapeidx.distance.Metric.terms`: no metric is known here by its name).

    Every metric is, to first order, a weighted sum of per-pair distances (the histograms' ``D``,
    L1 or Hellinger distances, the class-fraction and class-scale gaps): the L1 norm of the vector of those
    weighted terms. Each block is scaled by its term's weight, so that the Euclidean distance
    of two vectors is the L2 norm of the same vector of terms (within a factor sqrt(terms)
    of the metric, and equal to it for a pair that differs in one term). A Hellinger distance
    is ``|sqrt p - sqrt q| / sqrt 2``; ``D`` (L1 / bins) of near histograms is about
    ``2 |sqrt p - sqrt q| / bins`` of the fine bins, and the coarse bins' distance is smaller:
    ``2 / (3 bins)`` was the best factor of 1/16 to 4 times that on the whole library (combined:
    10-neighbour recall 0.963, 0.873 at ``2 / bins``). (Until issue 22 the blocks were scaled by the square root
    of the weights, and the fractions and scales by their mean weight: 10-neighbour recall on
    the whole KiCad 6 library 0.846 for combined-angle, 0.866 for combined, at the same over-fetch;
    now 0.982 and 0.963,
    docs/performance-families.md.)
    """
    d2 = 2.0 / (FINE_PER_COARSE * REFERENCE_BINS)
    # a term's distance -> the Euclidean distance of its block: D of the coarse bins (d_),
    # Hellinger (hellinger_angle_: |sqrt p - sqrt q| / sqrt 2), L1 (angle_: about 2 |sqrt p - sqrt q|)
    factors = (("d_", "d2_", lambda w: w * d2), ("hellinger_angle_", "angle_", lambda w: w / np.sqrt(2)),
               ("angle_", "angle_", lambda w: 2.0 * w))
    classes = {"gap_": np.zeros(len(CLASS_NAMES)), "scale_": np.zeros(len(CLASS_NAMES))}
    # a size term sqrt|ln rA - ln rB| as the block of ln r: |d ln r| is what a Euclidean distance
    # can hold (the square root is none); it ranks pairs alike, and the exact step decides.
    # The weight itself, unscaled, had the best whole-library recall (docs/performance-families.md)
    sizes = np.zeros(3)
    blocks = {}
    for feature, w in metric_record(metric).terms.items():
        for prefix, block, scaled in factors:
            if feature.startswith(prefix):
                blocks[block + feature[len(prefix):]] = scaled(w)
                break
        else:
            if feature.startswith("size_r"):
                sizes[int(feature[len("size_r"):]) - 1] = w
                continue
            prefix, _, name = feature.partition("_")
            classes[prefix + "_"][CLASS_NAMES.index(name)] = w
    # fixed block order (the class blocks first): a metric's vector does not depend on its terms' order
    weights = {block: values for block, values in (("fractions", classes["gap_"]), ("scales", classes["scale_"]),
                                                   ("sizes", sizes)) if np.any(values)}
    weights.update(sorted(blocks.items(), key=lambda item: BLOCK_ORDER.index(item[0])))
    return weights


def embedding_basis(table, blocks) -> dict:
    """The named blocks of every entry's basis vector: ``d2_H`` (:func:`d2_basis` rows: the
    store's own when it keeps them, else made from the loaded histograms), ``angle_H`` (the
    normal-angle probabilities, square-rooted), ``fractions``, ``scales`` (ln of each class's
    mean over the ALL mean), ``sizes`` (ln of the principal radii). Each a function of its own entry only."""
    out = {}
    stored = getattr(table, "d2_basis", None) or {}
    for block in blocks:
        kind, _, h = block.partition("_")
        if kind == "d2":
            if h in stored:
                out[block] = stored[h]
            else:
                ragged = table.histograms[h]
                out[block] = d2_basis(ragged.p, ragged.lengths)
        elif kind == "angle":
            out[block] = np.sqrt(np.nan_to_num(table.angles[:, ANGLE_HISTOGRAMS.index(h)]))
        elif block == "fractions":
            out[block] = table.fractions
        elif block == "scales":
            out[block] = class_scales(table.means)
        elif block == "sizes":
            with np.errstate(divide="ignore", invalid="ignore"):
                out[block] = np.log(table.extents)  # unknown: NaN, 0 in the vector (embed)
    return out


def embed(table, metric: str) -> np.ndarray:
    """(N, dim) float32 vectors of a :class:`~shapeidx.families.table.FamilyTable`'s entries.

    Euclidean distance between two vectors is a stand-in for the ``metric`` distance of the
    two entries (:func:`embedding_weights`); an entry's vector depends on that entry alone.
    """
    weights = {block: w for block, w in embedding_weights(metric).items() if np.any(np.asarray(w) > 0)}
    basis = embedding_basis(table, weights)
    blocks = [np.asarray(basis[block], dtype=np.float64) * np.asarray(w) for block, w in weights.items()]
    n = len(table)
    vectors = np.concatenate(blocks, axis=1) if blocks else np.zeros((n, 1))
    return np.ascontiguousarray(np.nan_to_num(vectors), dtype=np.float32)


def ivf_lists(n: int) -> int:
    """Lists of the inverted file for ``n`` vectors: :data:`IVF_LISTS_PER_ROOT` sqrt(n)."""
    return max(1, int(IVF_LISTS_PER_ROOT * np.sqrt(n)))


class CandidateIndex:
    """Nearest vectors by Euclidean distance: exact (FAISS flat) up to :data:`EXACT_LIMIT`
    entries, an inverted file above (FAISS IVF-flat: :func:`ivf_lists` k-means cells, each
    query scans the :data:`IVF_PROBE` nearest), or as ``method`` says: ``"exact"``, ``"ivf"``,
    ``"hnsw"``, ``"auto"``."""

    def __init__(self, vectors: np.ndarray, method: str = "auto", threads: int | None = None):
        import faiss

        if threads:
            faiss.omp_set_num_threads(int(threads))
        self.vectors = np.ascontiguousarray(vectors, dtype=np.float32)
        n, dim = self.vectors.shape
        self.method = ("exact" if n <= EXACT_LIMIT else "ivf") if method == "auto" else method
        if self.method == "ivf" and n < 2 * IVF_TRAIN_PER_LIST:
            self.method = "exact"  # too few vectors to train cells on
        if self.method == "exact":
            self.index = faiss.IndexFlatL2(dim)
        elif self.method == "ivf":
            lists = min(ivf_lists(n), n // IVF_TRAIN_PER_LIST)
            self.quantizer = faiss.IndexFlatL2(dim)
            self.index = faiss.IndexIVFFlat(self.quantizer, dim, lists)
            sample = np.random.default_rng(IVF_SEED).choice(n, min(n, IVF_TRAIN_PER_LIST * lists), replace=False)
            self.index.train(self.vectors[np.sort(sample)])
            self.index.nprobe = min(IVF_PROBE, lists)
        elif self.method == "hnsw":
            self.index = faiss.IndexHNSWFlat(dim, HNSW_M)
            self.index.hnsw.efConstruction = HNSW_EF_CONSTRUCTION
            self.index.hnsw.efSearch = HNSW_EF_SEARCH
        else:
            raise ValueError(f"unknown candidate method {method!r}")
        if n:
            self.index.add(self.vectors)

    def __len__(self) -> int:
        return len(self.vectors)

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest entries of each query vector: (squared distances, indices), -1 for none."""
        k = min(k, len(self))
        queries = np.ascontiguousarray(queries, dtype=np.float32)
        if k <= 0 or len(queries) == 0:
            return np.zeros((len(queries), 0), np.float32), np.zeros((len(queries), 0), np.int64)
        return self.index.search(queries, k)

    def neighbours(self, k: int, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """(N, k) candidate neighbours of every entry (or of the entries ``lo`` to ``hi``), itself
        left out (-1 where fewer exist)."""
        hi = len(self) if hi is None else min(hi, len(self))
        _, found = self.search(self.vectors[lo:hi], k + 1)
        n = hi - lo
        out = np.full((n, k), -1, dtype=np.int64)
        own = found == np.arange(lo, hi)[:, None]
        # drop the entry itself (or, among identical vectors, the last column) from each row
        keep = ~own
        drop_last = keep.all(axis=1)
        keep[drop_last, -1] = False
        rows = found[keep].reshape(n, -1) if found.shape[1] else found
        out[:, : rows.shape[1]] = rows[:, :k]
        return out


def candidate_pairs(table, metric: str, k: int, method: str = "auto", threads: int | None = None, vectors=None):
    """Each entry's ``k`` nearest neighbours: :data:`OVERFETCH` times as many candidates from
    the embedding (or ``vectors``), each confirmed with the exact distance, the best ``k`` kept.

    Returns
    -------
    a, b : (M,) int64
        Every candidate pair confirmed, ``a < b``, each once.
    distances : (M,) float64
        Their exact ``metric`` distances.
    neighbours : (N, k) int64
        The candidates of every entry, nearest (by exact distance) first; -1 padding.
    neighbour_distances : (N, k) float64
        Their exact distances (inf for padding).
    """
    n = len(table)
    index = CandidateIndex(embed(table, metric) if vectors is None else vectors, method, threads)
    found = index.neighbours(min(OVERFETCH * k, max(n - 1, 0)))
    rows = np.repeat(np.arange(n), found.shape[1])
    cols = found.ravel()
    valid = cols >= 0
    # each pair's exact distance once (a pair in both entries' lists is one distance)
    key = np.where(valid, np.minimum(rows, cols) * max(n, 1) + np.maximum(rows, cols), -1)
    pairs, which = np.unique(key[valid], return_inverse=True)
    exact = np.full(len(cols), np.inf)
    exact[valid] = table.pair_distances(pairs // max(n, 1), pairs % max(n, 1), metric)[which.ravel()]
    exact = exact.reshape(n, -1)
    order = np.lexsort((found, exact), axis=1) if n else np.zeros((0, 0), np.int64)
    neighbours = np.take_along_axis(found, order, axis=1)[:, :k]
    neighbour_distances = np.take_along_axis(exact, order, axis=1)[:, :k]
    _, first = np.unique(which.ravel(), return_index=True)
    a, b = pairs // max(n, 1), pairs % max(n, 1)
    return a, b, exact.ravel()[valid][first], neighbours, neighbour_distances
