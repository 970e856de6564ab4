"""The signature store: one HDF5 file of entries, plus a journal of committed segments.

    layout.py   the schema: per-entry columns, histogram counts as CSR, parameters
    files.py    the files (main, journal, lock) and atomic writes
    reader.py   a consistent view of main file + journal (open_store)
    writer.py   the single writer: lock, commit a batch, size-tiered merges of the journal
    rank.py     the memory-mapped ranking arrays of every file (rank/)
    ranked.py   a query ranked straight from them (lower bounds, then exact distances)
    check.py    shapeidx check: checksums, offsets, totals, ranking arrays; repairs
    stats.py    what ``shapeidx stats`` reports
"""

from .layout import DEFAULT_STORE, STATUS_FAILED, STATUS_OK, STORE_ENV, Entry, StoreParams
from .reader import StoreReader, check_params, check_root, open_store, resolve_store_path
from .stats import describe_store
from .writer import Batch, StoreLock, StoreWriter

__all__ = [
    "DEFAULT_STORE",
    "STATUS_FAILED",
    "STATUS_OK",
    "STORE_ENV",
    "Batch",
    "Entry",
    "StoreLock",
    "StoreParams",
    "StoreReader",
    "StoreWriter",
    "check_params",
    "check_root",
    "describe_store",
    "open_store",
    "resolve_store_path",
]
