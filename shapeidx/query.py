"""Ranking a store against a part: ``shapeidx query`` and the Python API behind it.

    table = SignatureTable.load(reader)          # the ok entries, once
    distances = table.rank(signature, "weighted")  # one vectorised pass
    hits = top_hits(distances, table.paths, 5)

Distances come from :func:`shapeidx.distance.rank_distances`, so they equal what
:func:`shapeidx.distance.compare` gives for each pair, bit for bit.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .distance import METRIC_HISTOGRAMS, METRICS, HistogramBank, rank_distances
from .errors import StoreError
from .io import LoadLimits
from .pipeline import signature_of_solid, solid_of_file
from .signature import HISTOGRAMS, Signature
from .store import STATUS_OK, StoreReader, open_store


@dataclass
class SignatureTable:
    """The ok entries of a store, laid out for ranking.

    Attributes
    ----------
    paths : (N,) object
        Relative paths, sorted.
    rows : (N,) int64
        Each entry's position in the store reader.
    banks : dict
        Histogram name -> :class:`~shapeidx.distance.HistogramBank` (only those loaded).
    fractions : (N, 3) float64
        IN, OUT, MIXED.
    means : (N, 4) float64
        Mean pair distance of each histogram, in ``HISTOGRAMS`` order.
    """

    paths: np.ndarray
    rows: np.ndarray
    banks: dict
    fractions: np.ndarray
    means: np.ndarray

    @classmethod
    def load(cls, reader: StoreReader, histograms=HISTOGRAMS) -> "SignatureTable":
        """Read the ok entries' histograms ``histograms`` (default all four) from a store."""
        rows = np.flatnonzero(reader.column("entries/status") == STATUS_OK)
        banks = {name: HistogramBank.from_counts(*reader.counts(name, rows)) for name in histograms}
        means = np.stack([reader.column(f"histograms/{name}/mean")[rows] for name in HISTOGRAMS], axis=1)
        return cls(reader.paths[rows], rows, banks, reader.column("entries/fractions")[rows], means)

    def __len__(self) -> int:
        return len(self.paths)

    def rank(self, signature: Signature, metric: str = "weighted") -> np.ndarray:
        """Distance of every entry to ``signature`` by ``metric`` (one of :data:`METRICS`)."""
        if metric not in METRICS:
            raise ValueError(f"unknown metric {metric!r}; expected one of {', '.join(METRICS)}")
        missing = set(METRIC_HISTOGRAMS[metric]) - set(self.banks)
        if missing:
            raise ValueError(f"metric {metric} needs histograms not loaded: {', '.join(sorted(missing))}")
        return rank_distances(signature, self.banks, self.fractions, self.means, (metric,))[metric]

    def index_of(self, path: str) -> int | None:
        i = int(np.searchsorted(self.paths, path))
        return i if i < len(self.paths) and self.paths[i] == path else None


def top_hits(distances: np.ndarray, paths: np.ndarray, top: int, first: int | None = None) -> list[dict]:
    """The ``top`` nearest entries as ``{"rank", "path", "distance"}``, nearest first.

    Ties are broken by path; ``first`` (an index) wins its ties, so a part that is in the
    store comes before its identical twins when it is the query.
    """
    top = min(top, len(distances))
    if top <= 0:
        return []
    # every entry within the top-th distance, ties included, then an exact order among them
    threshold = np.partition(distances, top - 1)[top - 1]
    near = np.flatnonzero(distances <= threshold)
    not_first = near != first if first is not None else np.ones(len(near), dtype=bool)
    order = near[np.lexsort((paths[near], not_first, distances[near]))][:top]
    return [{"rank": r + 1, "path": str(paths[i]), "distance": float(distances[i])} for r, i in enumerate(order)]


def entry_path_of(file: str | os.PathLike, reader: StoreReader) -> str | None:
    """The relative path ``file`` has in the store when it lies inside the indexed root."""
    root = reader.attrs.get("root")
    if not root:
        return None
    try:
        return Path(file).resolve().relative_to(root).as_posix()
    except ValueError:
        return None


def query_store(
    store: str | os.PathLike,
    file: str | os.PathLike | None = None,
    entry: str | None = None,
    top: int = 10,
    metric: str = "weighted",
    threads: int = 1,
) -> list[dict]:
    """Rank a store against a part file, or against one of its own entries.

    Parameters
    ----------
    store : path of the store
    file : a part file; its signature is computed with the store's parameters
    entry : a relative path already in the store (``--id``), instead of ``file``
    top : how many hits
    metric : one of :data:`METRICS`
    threads : threads for the query file's ray queries

    Raises
    ------
    StoreError
        No store, unknown or failed entry, or a store of another signature version.
    LoadError
        The query file cannot be read.
    """
    with open_store(store) as reader:
        _check_usable(reader)
        table = SignatureTable.load(reader, METRIC_HISTOGRAMS[metric])
        if entry is not None:
            first = _entry_index(reader, table, entry)
            signature = reader.signature(int(table.rows[first]))
        else:
            params = reader.params
            solid = solid_of_file(file, LoadLimits(faceting=params.faceting))  # STEP faceted as the store's
            signature = signature_of_solid(solid, params.points, params.seed, params.bin_divisor, threads)
            own = entry_path_of(file, reader)
            first = table.index_of(own) if own is not None else None
        return top_hits(table.rank(signature, metric), table.paths, top, first)


def _check_usable(reader: StoreReader) -> None:
    from .pipeline import SIGNATURE_VERSION

    if reader.params.signature_version != SIGNATURE_VERSION:
        raise StoreError(
            f"store {reader.path} holds signatures of version {reader.params.signature_version}, this shapeidx"
            f" makes version {SIGNATURE_VERSION}: rebuild it (delete it and run shapeidx build)"
        )


def _entry_index(reader: StoreReader, table: SignatureTable, entry: str) -> int:
    i = table.index_of(entry)
    if i is not None:
        return i
    j = reader.index_of(entry)
    if j is None:
        raise StoreError(f"no entry {entry!r} in {reader.path} (give the path relative to the indexed folder)")
    raise StoreError(f"entry {entry!r} failed to index: {reader.column('entries/reason')[j]}")
