"""Ranking a store against a part: ``shapeidx query`` and the Python API behind it.

    table = SignatureTable.load(reader)          # the ok entries, once
    distances = table.distances(signature, "weighted")  # one vectorised pass
    hits = top_hits(distances, table.paths, 5)

Distances come from :func:`shapeidx.distance.distances_to_many`, so they equal what
:func:`shapeidx.distance.compare` gives for each pair, bit for bit.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .distance import METRIC_HISTOGRAMS, METRICS, HistogramBank, distances_to_many
from .errors import StoreError
from .distance import ANGLE_METRICS
from .distance.combined import require_angles
from .signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS, angle_probabilities
from .signing.histogram import Signature
from .signing.parameters import HISTOGRAMS, SIGNATURE_VERSION
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
    angles : (N, 4, ANGLE_BINS) float64 or None
        Normal-angle probabilities (NaN where unknown: entries of a store built before them).
    """

    paths: np.ndarray
    rows: np.ndarray
    banks: dict
    fractions: np.ndarray
    means: np.ndarray
    angles: np.ndarray | None = None

    @classmethod
    def load(cls, reader: StoreReader, histograms=HISTOGRAMS) -> "SignatureTable":
        """Read the ok entries' histograms ``histograms`` (default all four) from a store."""
        rows = np.flatnonzero(reader.column("entries/status") == STATUS_OK)
        banks = {name: HistogramBank.from_counts(*reader.counts(name, rows)) for name in histograms}
        means = np.stack([reader.column(f"histograms/{name}/mean")[rows] for name in HISTOGRAMS], axis=1)
        angles = reader.column("entries/angles")[rows].reshape(len(rows), len(ANGLE_HISTOGRAMS), ANGLE_BINS)
        return cls(reader.paths[rows], rows, banks, reader.column("entries/fractions")[rows], means, angle_probabilities(angles))

    def __len__(self) -> int:
        return len(self.paths)

    def distances(self, signature: Signature, metric: str = "weighted") -> np.ndarray:
        """Distance of every entry to ``signature`` by ``metric`` (one of :data:`METRICS`)."""
        if metric not in METRICS:
            raise ValueError(f"unknown metric {metric!r}; expected one of {', '.join(METRICS)}")
        missing = set(METRIC_HISTOGRAMS[metric]) - set(self.banks)
        if missing:
            raise ValueError(f"metric {metric} needs histograms not loaded: {', '.join(sorted(missing))}")
        if metric in ANGLE_METRICS:
            self.check_angles(signature, metric)
        return distances_to_many(signature, self.banks, self.fractions, self.means, (metric,), self.angles)[metric]

    def check_angles(self, signature: Signature, metric: str) -> None:
        """Refuse, in one line, a metric that needs normal-angle histograms the store or query lacks."""
        require_angles(self.angles, signature, metric)

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
    store,
    part=None,
    entry: str | None = None,
    top: int = 10,
    metric: str = "weighted",
    threads: int = 1,
    file_type: str | None = None,
    exclude_self: bool = False,
    max_distance: float | None = None,
    scale: str = "invariant",
) -> list[dict]:
    """Rank a store against a part, or against one of its own entries.

    Parameters
    ----------
    store : path of the store, or an open :class:`StoreReader`
    part : a part in any form :func:`shapeidx.load` takes, or a :class:`Signature`; its
        signature is computed with the store's parameters
    entry : an entry of the store (``--id``), instead of ``part``: its path relative to the
        store's root, or a path (absolute, or relative to the working directory) of a file
        inside the root
    top : how many hits
    metric : one of :data:`METRICS`
    threads : threads for the query part's ray queries
    file_type : the part's format, when its name or content does not tell it
    exclude_self : leave out the query's own entry (``entry``, or ``part`` when it is a file
        of the store's tree)
    max_distance : leave out hits farther than this
    scale : "invariant" (the paper's) or "sensitive": entries whose size differs from the
        part's by more than :data:`shapeidx.distance.scale.SIZE_BAND` are left out

    Raises
    ------
    StoreError
        No store, unknown or failed entry, or a store of another signature version.
    LoadError
        The query part cannot be read.
    """
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; expected one of {', '.join(METRICS)}")
    if isinstance(store, StoreReader):
        return _query_reader(store, part, entry, top, metric, threads, file_type, exclude_self, max_distance, scale)
    with open_store(store) as reader:
        return _query_reader(reader, part, entry, top, metric, threads, file_type, exclude_self, max_distance, scale)


def _query_reader(reader: StoreReader, part, entry, top, metric, threads, file_type, exclude_self=False,
                  max_distance=None, scale="invariant") -> list[dict]:
    check_usable(reader)
    from .store.ranked import ranked_view

    view = ranked_view(reader, METRIC_HISTOGRAMS[metric])
    if view is not None:
        return _query_view(reader, view, part, entry, top, metric, threads, file_type, exclude_self, max_distance, scale)
    table = SignatureTable.load(reader, METRIC_HISTOGRAMS[metric])
    if entry is not None:
        first = _entry_index(reader, table, entry)
        signature = reader.signature(int(table.rows[first]))
    else:
        signature = signature_with_params(part, reader.params, threads, file_type)
        own = entry_path_of(part, reader) if isinstance(part, (str, os.PathLike)) else None
        first = table.index_of(own) if own is not None else None
    distances = table.distances(signature, metric)
    if scale != "invariant":
        from .distance.scale import apply_scale

        distances = apply_scale(distances, signature.histograms["all"].mean, table.means[:, 0], scale)
    keep = np.isfinite(distances)  # a scale-sensitive search leaves out parts of another size
    if exclude_self and first is not None:
        keep[first] = False
    if max_distance is not None:
        keep &= distances <= max_distance
    if keep.all():
        return top_hits(distances, table.paths, top, first)
    kept = np.flatnonzero(keep)
    first_kept = None if first is None or not keep[first] else int(np.searchsorted(kept, first))
    return top_hits(distances[kept], table.paths[kept], top, first_kept)


class LazyPaths:
    """The paths of a :class:`~shapeidx.store.ranked.RankedView`'s entries, each read when asked
    for: ``top_hits`` asks only for the hits' (and their ties')."""

    def __init__(self, view, positions: np.ndarray | None = None):
        self.view = view
        self.positions = positions

    def take(self, indices: np.ndarray) -> "LazyPaths":
        positions = np.asarray(indices) if self.positions is None else self.positions[indices]
        return LazyPaths(self.view, positions)

    def __getitem__(self, key):
        if np.ndim(key) == 0:
            return self.view.path_at(int(key if self.positions is None else self.positions[key]))
        from .store.layout import object_array

        return object_array([self[int(k)] for k in np.asarray(key)])


def _query_view(reader: StoreReader, view, part, entry, top, metric, threads, file_type, exclude_self=False,
                max_distance=None, scale="invariant") -> list[dict]:
    """:func:`_query_reader` over the store's memory-mapped ranking sections (same hits, same distances)."""
    if entry is not None:
        found = view.find(resolve_entry_in_view(reader, view, entry))
        if found is None:
            raise StoreError(
                f"no entry {entry!r} in {reader.path} (give a path inside {reader.attrs.get('root')},"
                " absolute or relative to it)"
            )
        status, reason = view.status_of(found)
        if status != STATUS_OK:
            raise StoreError(f"entry {resolve_entry_in_view(reader, view, entry)!r} failed to index: {reason}")
        first = view.position_of(found)
        signature = view.signature(found, reader.params)
    else:
        signature = signature_with_params(part, reader.params, threads, file_type)
        own = entry_path_of(part, reader) if isinstance(part, (str, os.PathLike)) else None
        found = view.find(own) if own is not None else None
        first = view.position_of(found) if found is not None else None
    paths = LazyPaths(view)
    if scale == "invariant":
        from .store.candidates import query_candidates

        near = query_candidates(view, signature, metric, top, first, first if exclude_self else None, max_distance)
        if near is not None:  # exact distances of the entries that can be hits (and ``first``)
            chosen, distances = near
            keep = np.isfinite(distances) & ((chosen != first) if exclude_self and first is not None else True)
            if max_distance is not None:
                keep &= distances <= max_distance
            kept = np.flatnonzero(keep)
            at_first = np.flatnonzero(chosen[kept] == first) if first is not None else []
            return top_hits(distances[kept], paths.take(chosen[kept]), top, int(at_first[0]) if len(at_first) else None)
    distances = view.distances(signature, metric)
    if scale != "invariant":
        from .distance.scale import apply_scale

        distances = apply_scale(distances, signature.histograms["all"].mean, view.means[:, 0], scale)
    keep = np.isfinite(distances)
    if exclude_self and first is not None:
        keep[first] = False
    if max_distance is not None:
        keep &= distances <= max_distance
    if keep.all():
        return top_hits(distances, paths, top, first)
    kept = np.flatnonzero(keep)
    first_kept = None if first is None or not keep[first] else int(np.searchsorted(kept, first))
    return top_hits(distances[kept], paths.take(kept), top, first_kept)


def resolve_entry_in_view(reader: StoreReader, view, entry) -> str:
    """:func:`resolve_entry` without the full path list: one binary search per file."""
    return _resolved(reader, entry, lambda path: view.find(path) is not None)


def signature_with_params(part, params, threads: int = 1, file_type: str | None = None) -> Signature:
    """The signature of ``part`` with a store's parameters (a Signature must already have them)."""
    if isinstance(part, Signature):
        if (part.points, part.seed) != (params.points, params.seed):
            raise StoreError(
                f"the signature was made with {part.points} points and seed {part.seed}; "
                f"the store's are {params.points} and {params.seed}"
            )
        return part
    from .api import load
    from .io import LoadLimits
    from .signing.pipeline import signature_of_solid

    solid = load(part, file_type, LoadLimits(faceting=params.faceting))  # a STEP part faceted as the store's
    return signature_of_solid(solid, params.points, params.seed, params.bin_divisor, threads)


def check_usable(reader: StoreReader) -> None:
    if reader.params.signature_version != SIGNATURE_VERSION:
        raise StoreError(
            f"store {reader.path} holds signatures of version {reader.params.signature_version}, this shapeidx"
            f" makes version {SIGNATURE_VERSION}: rebuild it (delete it and run shapeidx build)"
        )


def resolve_entry(reader: StoreReader, entry: str | os.PathLike) -> str:
    """The store path of ``entry``: already one, or a file path inside the store's root.

    ``--id`` takes the path relative to the indexed folder (what ``query`` prints as
    ``relative_path``) and also a path that opens from here, absolute or relative to the
    working directory, as long as it lies inside the indexed folder.
    """
    return _resolved(reader, entry, lambda path: reader.index_of(path) is not None)


def _resolved(reader: StoreReader, entry, known) -> str:
    """``entry`` if ``known(entry)``, else its store path as a file inside the root if known, else ``entry``."""
    text = os.fspath(entry)
    if known(text):
        return text
    inside = entry_path_of(text, reader)
    if inside is not None and known(inside):
        return inside
    return text


def ok_entry_row(reader: StoreReader, entry: str | os.PathLike) -> int:
    """The reader row of the ok entry ``entry`` (as :func:`resolve_entry` takes it).

    Raises
    ------
    StoreError
        No such entry, or the entry's file failed to index (with its reason).
    """
    entry = resolve_entry(reader, entry)
    j = reader.index_of(entry)
    if j is None:
        raise StoreError(
            f"no entry {entry!r} in {reader.path} (give a path inside {reader.attrs.get('root')},"
            " absolute or relative to it)"
        )
    if reader.column("entries/status")[j] != STATUS_OK:
        raise StoreError(f"entry {entry!r} failed to index: {reader.column('entries/reason')[j]}")
    return j


def _entry_index(reader: StoreReader, table: SignatureTable, entry: str) -> int:
    """The table position of an ok entry (``table.rows`` are the ok rows, in order)."""
    return int(np.searchsorted(table.rows, ok_entry_row(reader, entry)))
