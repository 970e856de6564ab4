"""The signature store: one HDF5 file of entries, plus a journal of committed segments.

    layout.py   the schema: per-entry columns, histogram counts as CSR, parameters
    files.py    the files (main, journal, lock) and atomic writes
    reader.py   a consistent view of main file + journal (open_store)
    lock.py     the single-writer lock, and the last build's record (build.json) it corrects
    writer.py   the single writer: commit a batch, size-tiered merges of the journal
    rank.py     the memory-mapped ranking arrays of every file (rank/)
    ranked.py   a query ranked straight from them (lower bounds, then exact distances)
    check.py    shapeidx check: checksums, offsets, totals, ranking arrays; repairs
    stats.py    what ``shapeidx stats`` reports
    convert.py  a store of the older one-file layout into a directory, by renames
    metadata.py the --metadata table joined to the shapes (STORE/metadata.h5)
    candidates.py  candidate pairs for duplicates and cluster (FAISS over embeddings)
    known.py    a build's plan: the live entries by path key
    verified.py which main file a build has verified (STORE/verified)
    heaps.py    HDF5 global heaps checked before HDF5 decodes them
    shards.py   a store sharded by path key: N ordinary stores
"""

from .layout import DEFAULT_STORE, STATUS_FAILED, STATUS_OK, STORE_ENV, Entry, StoreParams
from .reader import StoreReader, check_params, check_root, open_store, resolve_store_path
from .stats import describe_store
from .lock import StoreLock
from .writer import Batch, StoreWriter

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
