"""The ranking section of a store file: what a query reads, contiguous so it can be memory-mapped.

Every file of a store (main file and journal segments) written since layout 3 holds, besides
its canonical entry columns and CSR histograms (chunked, Fletcher-32), a group ``rank/`` with
the same signatures laid out as :class:`~shapeidx.distance.HistogramBank` ranks them:

    rank/path_key      (N, 2) uint64   BLAKE2b-128 of every entry's path (superseded rows, no decoding)
    rank/rows          (M,) int64      the file rows of its M ok entries, increasing: "rank positions"
    rank/fractions     (M, 3) float64  IN, OUT, MIXED fractions of those entries
    rank/means         (M, H) float64  mean pair distance of each histogram (``histograms`` order)
    rank/angles        (M, A) float64  the normal-angle pair counts (``entries/angles``; NaN where unknown)
    rank/H/counts      (sum,) uint32   histogram H of every ok entry, grouped by bin count (ascending),
                                       row order within a group: group g is a dense (n_g, bins_g) block
    rank/H/groups      (G, 2) int64    bins_g, n_g per group
    rank/H/order       (M,) int64      the rank position of each grouped row
    rank/H/totals      (M,) int64      each grouped row's pair total (at least 1), grouped order
    rank/H/coarse      (sum,) uint32   the grouped histograms with every ``coarse`` bins summed (lower bounds)
    rank/H/embedding   (M, 48) float32 each ok entry's block of the candidate embedding (rank position
                                       order; :func:`shapeidx.store.candidates.d2_basis`: a function of
                                       that entry alone, so each file carries its own rows). Absent
                                       from files written before it: computed from the counts then.

Every dataset is contiguous and unfiltered: HDF5 gives its file offset, so a query maps it
(``mmap``) instead of reading and decoding it, and touches only the pages it ranks. Such
datasets cannot carry Fletcher-32; each has a ``crc32`` attribute of its bytes instead. A
query verifies the CRC of every array it maps but the counts, and the counts as it ranks
them (each row must add up to its CRC-checked total, so a flipped bit is never ranked);
``shapeidx check`` verifies every CRC and that the section is what the checked canonical
data make (``check --repair`` rebuilds it from them). The group's ``histograms`` attribute names the histograms it
holds, so the section follows whatever tuple of histograms the signature has.
"""

from __future__ import annotations

import hashlib
import mmap
import os
import zlib

import h5py
import numpy as np

from ..ragged import offsets_of, take_ragged
from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS

RANK = "rank"
#: Attribute of every ranking dataset: CRC-32 of its raw bytes (C order, as stored); zlib
#: computes it at over 1 GB/s without holding the GIL.
CHECKSUM = "crc32"
#: Arrays a query verifies by their CRC-32 as it maps them. The counts, by far the largest,
#: are verified as they are ranked instead: each row must add up to its (CRC-checked) total.
CRC_ON_MAP = ("path_key", "rows", "fractions", "means", "angles", "groups", "order", "totals")
#: Dtype of the stored counts (the canonical counts' dtype).
COUNT_DTYPE = np.uint32
#: Bins summed into one bin of the coarse histograms (``rank/H/coarse``). By the triangle
#: inequality the L1 distance of two coarse histograms is at most that of the histograms, so
#: ranking reads 1/COARSE of the counts to bound every entry's distance from below and
#: computes exact distances only where the bound does not rule an entry out.
COARSE = 8
#: Arrays a file written before them lacks; :meth:`RankSection.array` computes them from the
#: file's counts then (the same values), and checks skip their checksums.
OPTIONAL = ("embedding",)
#: Values per entry of ``rank/angles``: the normal-angle histograms laid end to end.
ANGLE_WIDTH = len(ANGLE_HISTOGRAMS) * ANGLE_BINS


def path_keys(paths) -> np.ndarray:
    """(n, 2) uint64: the BLAKE2b-128 digest of each path (UTF-8), the key superseding uses."""
    digests = b"".join(hashlib.blake2b(str(path).encode("utf-8", "surrogatepass"), digest_size=16).digest() for path in paths)
    return np.frombuffer(digests, dtype=np.uint64).reshape(len(paths), 2).copy()  # one buffer, not one array a path


def bytes_crc32(values: np.ndarray) -> int:
    """The :data:`CHECKSUM` of an array (its bytes in C order)."""
    return zlib.crc32(np.ascontiguousarray(values).reshape(-1).view(np.uint8))


def _write(f: h5py.File, name: str, values: np.ndarray) -> None:
    values = np.ascontiguousarray(values)
    dataset = f.create_dataset(name, data=values)  # no chunks, no filters: contiguous, mappable
    dataset.attrs[CHECKSUM] = np.uint32(bytes_crc32(values))


def grouped(flat: np.ndarray, lengths: np.ndarray):
    """Histograms laid end to end, regrouped by bin count.

    Returns
    -------
    counts : (sum,) uint32, group after group, each a C-ordered (n_g, bins_g) block
    groups : (G, 2) int64, bins_g and n_g
    order : (M,) int64, the row (0..M-1) of each grouped histogram
    totals : (M,) int64, each grouped histogram's total, at least 1 (what ranking divides by)
    coarse : (sum,) uint32, the same histograms with every :data:`COARSE` bins summed, group
        after group (n_g, ceil(bins_g / COARSE)): what the lower bounds of ranking read
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    offsets = offsets_of(lengths)
    totals = np.zeros(len(lengths), dtype=np.int64)
    filled = lengths > 0
    if filled.any():  # as HistogramBank.from_counts: empty rows add nothing to a filled row's sum
        totals[filled] = np.add.reduceat(flat, offsets[:-1][filled], dtype=np.int64)
    order = np.argsort(lengths, kind="stable")
    sorted_lengths = lengths[order]
    bins, starts = np.unique(sorted_lengths, return_index=True)
    sizes = np.diff(np.append(starts, len(order)))
    out = np.empty(int(lengths.sum()), dtype=COUNT_DTYPE)
    coarse = np.empty(int(np.sum(-(-bins // COARSE) * sizes)), dtype=COUNT_DTYPE)
    at = coarse_at = 0
    for b, lo, n in zip(bins.tolist(), starts.tolist(), sizes.tolist()):
        if b:
            rows = order[lo : lo + n]
            # each histogram is one contiguous run of ``flat``: a window view copies it as one
            block = np.lib.stride_tricks.sliding_window_view(flat, b)[offsets[rows]]
            out[at : at + n * b] = block.reshape(-1)
            at += n * b
            width = -(-b // COARSE)
            padded = np.zeros((n, width * COARSE), dtype=np.int64)
            padded[:, :b] = block
            coarse[coarse_at : coarse_at + n * width] = padded.reshape(n, width, COARSE).sum(axis=2).reshape(-1)
            coarse_at += n * width
    groups = np.stack([bins, sizes], axis=1).astype(np.int64).reshape(-1, 2)
    return out, groups, order.astype(np.int64), np.maximum(totals[order], 1), coarse


def write_rank(f: h5py.File, columns: dict, counts: dict, histograms) -> None:
    """Write the ``rank/`` section of a file whose columns and counts (name -> (flat, lengths)) these are."""
    ok = write_rank_entries(f, columns, histograms)
    for h in histograms:
        write_rank_histogram(f, h, *counts[h], ok)


def write_rank_entries(f: h5py.File, columns: dict, histograms) -> np.ndarray:
    """The per-entry part of the ``rank/`` section; returns the ok rows (for :func:`write_rank_histogram`)."""
    from .layout import STATUS_OK

    status = np.asarray(columns["entries/status"])
    ok = np.flatnonzero(status == STATUS_OK)
    group = f.create_group(RANK)
    group.attrs["histograms"] = " ".join(histograms)
    group.attrs["coarse"] = COARSE
    _write(f, f"{RANK}/path_key", path_keys(columns["entries/path"]))
    _write(f, f"{RANK}/rows", ok.astype(np.int64))
    _write(f, f"{RANK}/fractions", np.asarray(columns["entries/fractions"], dtype=np.float64)[ok].reshape(-1, 3))
    means = np.stack([np.asarray(columns[f"histograms/{h}/mean"], dtype=np.float64)[ok] for h in histograms], axis=1)
    _write(f, f"{RANK}/means", means.reshape(len(ok), len(histograms)))
    _write(f, f"{RANK}/angles", _angles_of(columns, ok))
    return ok


def _angles_of(columns: dict, ok: np.ndarray) -> np.ndarray:
    if "entries/angles" not in columns:  # a file written before the angle histograms: unknown
        return np.full((len(ok), ANGLE_WIDTH), np.nan)
    angles = np.asarray(columns["entries/angles"], dtype=np.float64)
    return angles[ok].reshape(len(ok), ANGLE_WIDTH)


def write_rank_histogram(f: h5py.File, h: str, flat: np.ndarray, lengths: np.ndarray, ok: np.ndarray) -> None:
    """Histogram ``h`` of the ``rank/`` section from every entry's counts (flat, lengths); ``ok``: the ok rows."""
    flat_ok, lengths = take_ragged(np.asarray(flat, dtype=COUNT_DTYPE), offsets_of(lengths), ok)
    values, groups, order, totals, coarse = grouped(flat_ok, lengths)
    _write(f, f"{RANK}/{h}/counts", values)
    _write(f, f"{RANK}/{h}/groups", groups)
    _write(f, f"{RANK}/{h}/order", order)
    _write(f, f"{RANK}/{h}/totals", totals)
    _write(f, f"{RANK}/{h}/coarse", coarse)
    _write(f, f"{RANK}/{h}/embedding", _embedding_rows(flat_ok, lengths))


def _embedding_rows(flat: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    from .candidates import d2_basis  # the embedding's home; imported here only when writing

    return d2_basis(flat, lengths)


def expected_rank(columns: dict, counts: dict, histograms):
    """(name under ``rank/``, values) of the section these columns and counts (name -> (flat,
    lengths)) make, one array at a time: what ``shapeidx check`` compares a section with."""
    from .layout import STATUS_OK

    ok = np.flatnonzero(np.asarray(columns["entries/status"]) == STATUS_OK)
    yield "path_key", path_keys(columns["entries/path"])
    yield "rows", ok.astype(np.int64)
    yield "fractions", np.asarray(columns["entries/fractions"], dtype=np.float64)[ok].reshape(-1, 3)
    yield "means", np.stack([np.asarray(columns[f"histograms/{h}/mean"], dtype=np.float64)[ok] for h in histograms],
                            axis=1).reshape(len(ok), len(histograms))
    yield "angles", _angles_of(columns, ok)
    for h in histograms:
        flat, lengths = counts[h]
        flat, lengths = take_ragged(np.asarray(flat, dtype=COUNT_DTYPE), offsets_of(lengths), ok)
        values, groups, order, totals, coarse = grouped(flat, lengths)
        yield from ((f"{h}/counts", values), (f"{h}/groups", groups), (f"{h}/order", order), (f"{h}/totals", totals),
                    (f"{h}/coarse", coarse), (f"{h}/embedding", _embedding_rows(flat, lengths)))


def rank_datasets(histograms) -> list:
    """Every dataset name of a ``rank/`` section holding ``histograms``."""
    names = [f"{RANK}/{n}" for n in ("path_key", "rows", "fractions", "means", "angles")]
    return names + [f"{RANK}/{h}/{n}" for h in histograms
                    for n in ("counts", "groups", "order", "totals", "coarse") + OPTIONAL]


def _map_file(file: h5py.File, path) -> mmap.mmap:
    """A read-only mapping of the file ``file`` has open.

    Opened anew through ``/proc/self/fd`` (the same file even when a merge deleted its name
    meanwhile), not through HDF5's own descriptor: a mapping shares its descriptor's lock, and
    HDF5's lock would then outlive the file's closing for as long as an array views the map.
    """
    try:
        fd = os.open(f"/proc/self/fd/{file.id.get_vfd_handle()}", os.O_RDONLY)
    except OSError:
        fd = os.open(path, os.O_RDONLY)
    try:
        return mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
    finally:
        os.close(fd)


class RankSection:
    """The ``rank/`` section of one open store file, memory-mapped.

    Cheap to open: only the shapes and the small group tables are read and checked; the
    arrays are mapped, so a query reads (from the page cache or the disk) only what it ranks.

    Raises
    ------
    ValueError
        The section is missing, incomplete or inconsistent (the caller reports the damage).
    """

    def __init__(self, file: h5py.File, path):
        if RANK not in file:
            raise ValueError("no ranking section")
        group = file[RANK]
        self.file = file
        self.path = path
        self.histograms = tuple(str(group.attrs["histograms"]).split())
        self.coarse = int(group.attrs["coarse"])
        self._map = None
        self._arrays: dict = {}
        self._verified: set = set()  # arrays whose CRC-32 was checked (each on its first use, once)
        n = int(file["entries/size"].shape[0])
        self.rows = self.array("rows")
        m = len(self.rows)
        # shapes only: an array's CRC is checked when a query first reads it (a Weighted query
        # never reads the 544 bytes an entry of the angles, nor the ALL histogram's order)
        if self.array("path_key", verify=False).shape != (n, 2) or self.array("fractions", verify=False).shape != (m, 3):
            raise ValueError("ranking arrays of the wrong shape")
        if self.array("means", verify=False).shape != (m, len(self.histograms)):
            raise ValueError("ranking means of the wrong shape")
        if self.array("angles", verify=False).shape != (m, ANGLE_WIDTH):
            raise ValueError("ranking angles of the wrong shape")
        if m and (self.rows[0] < 0 or self.rows[-1] >= n):
            raise ValueError("ranking rows out of bounds")
        self.groups = {}
        for h in self.histograms:
            groups = np.asarray(self.array(f"{h}/groups"), dtype=np.int64).reshape(-1, 2)
            total = int(np.sum(groups[:, 0] * groups[:, 1]))
            coarse_total = int(np.sum(-(-groups[:, 0] // self.coarse) * groups[:, 1]))
            if (int(groups[:, 1].sum()) != m or np.any(groups < 0) or total != self.array(f"{h}/counts").shape[0]
                    or self.array(f"{h}/order", verify=False).shape != (m,)
                    or self.array(f"{h}/totals", verify=False).shape != (m,)
                    or self.array(f"{h}/coarse", verify=False).shape != (coarse_total,)):
                raise ValueError(f"ranking groups of {h} disagree with its arrays")
            self.groups[h] = groups

    def __len__(self) -> int:
        return len(self.rows)

    def array(self, name: str, verify: bool = True) -> np.ndarray:
        """The dataset ``rank/NAME``, mapped (read, if HDF5 did not place it contiguously);
        ``verify``: check the CRC-32 of the arrays of :data:`CRC_ON_MAP` (ValueError if it fails)."""
        if name not in self._arrays and name.rsplit("/", 1)[-1] in OPTIONAL and f"{RANK}/{name}" not in self.file:
            self._arrays[name] = self._computed(name)
        if name not in self._arrays:
            dataset = self.file[f"{RANK}/{name}"]
            offset = dataset.id.get_offset()
            if offset is None or dataset.size == 0 or dataset.chunks is not None:
                values = dataset[()]
            else:
                if self._map is None:
                    self._map = _map_file(self.file, self.path)
                values = np.frombuffer(self._map, dtype=dataset.dtype, count=dataset.size, offset=offset)
                values = values.reshape(dataset.shape)
            self._arrays[name] = values
        if verify and name not in self._verified and name.rsplit("/", 1)[-1] in CRC_ON_MAP:
            expected = self.file[f"{RANK}/{name}"].attrs.get(CHECKSUM)
            if expected is None or bytes_crc32(self._arrays[name]) != int(expected):
                raise ValueError(f"{RANK}/{name} fails its checksum")
            self._verified.add(name)
        return self._arrays[name]

    def stored(self, name: str) -> bool:
        """Whether the file holds ``rank/NAME`` (an :data:`OPTIONAL` array may be computed instead)."""
        return f"{RANK}/{name}" in self.file

    def _computed(self, name: str) -> np.ndarray:
        """An :data:`OPTIONAL` array the file lacks, made from its counts as a writer makes it."""
        h = name.rsplit("/", 1)[0]
        out = None
        for bins, block, _, positions in self.blocks(h):
            rows = _embedding_rows(np.asarray(block).reshape(-1), np.full(len(block), bins, dtype=np.int64))
            if out is None:
                out = np.zeros((len(self), rows.shape[1]), dtype=rows.dtype)
            out[positions] = rows
        return out if out is not None else _embedding_rows(np.zeros(0, COUNT_DTYPE), np.zeros(0, np.int64))

    def slots(self, h: str):
        """(group start of each group, grouped slot of each rank position) of histogram ``h``."""
        key = f"{h}/slot"
        if key not in self._arrays:
            order = self.array(f"{h}/order")
            slot = np.empty(len(order), dtype=np.int64)
            slot[order] = np.arange(len(order))
            starts = np.concatenate([[0], np.cumsum(self.groups[h][:, 1])])
            self._arrays[key] = (starts, slot)
        return self._arrays[key]

    def blocks(self, h: str, name: str = "counts"):
        """Per group of ``h``: (bins, its (n, width) block of ``name`` (views of the mapping, no
        copy), its totals, the rank positions of its rows), where width is bins for the
        counts and ceil(bins / coarse) for the coarse counts."""
        values, totals = self.array(f"{h}/{name}", verify=False), self.array(f"{h}/totals")
        order = self.array(f"{h}/order")
        out, at, row = [], 0, 0
        for bins, n in self.groups[h].tolist():
            width = bins if name == "counts" else -(-bins // self.coarse)
            block = values[at : at + n * width].reshape(n, width) if width else np.zeros((n, 0), dtype=COUNT_DTYPE)
            out.append((bins, block, totals[row : row + n], order[row : row + n]))
            at += n * width
            row += n
        return out

    def verify(self) -> list[str]:
        """Every dataset's checksum and the orders being permutations; returns what is wrong."""
        wrong = []
        for name in rank_datasets(self.histograms):
            short = name[len(RANK) + 1 :]
            if short.rsplit("/", 1)[-1] in OPTIONAL and name not in self.file:
                continue  # a file written before it: computed from the checked counts
            dataset = self.file[name]
            expected = dataset.attrs.get(CHECKSUM)
            if expected is None or bytes_crc32(self.array(short, verify=False)) != int(expected):
                wrong.append(f"{name} fails its checksum")
        if not wrong:
            m = len(self)
            for h in self.histograms:
                order = self.array(f"{h}/order")
                if m and not np.array_equal(np.sort(order), np.arange(m)):
                    wrong.append(f"{RANK}/{h}/order is not a permutation of the ok entries")
            if len(self.rows) > 1 and np.any(np.diff(self.rows) <= 0):
                wrong.append(f"{RANK}/rows are not increasing")
        return wrong

    def close(self) -> None:
        self._arrays.clear()
        self._verified.clear()
        if self._map is not None:
            try:
                self._map.close()
            except BufferError:  # a caller still holds a view: the mapping goes with it
                pass
            self._map = None
