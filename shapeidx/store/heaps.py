"""HDF5's global heap collections checked before HDF5 decodes them.

The store's strings (paths, reasons, what a part file says about itself, most attributes)
are HDF5 variable-length data: each value lives in a *global heap collection*, a block that
starts with the signature ``GCOL``, a version (1), three reserved bytes and the block's size,
followed by objects (a 2-byte index, a 2-byte reference count, 4 reserved bytes, an 8-byte
size, the data padded to 8 bytes); object 0 is the free space and its size counts its own
header. HDF5's decoder (``H5HG__cache_heap_deserialize``) steps from object to object by the
sizes it reads and trusts them: a free-space object of size 0 (two bytes overwritten) makes it
step in place forever, and every command that opens the file hangs in it with a core at 100 %.

:func:`check_global_heaps` walks every collection of a file the way that decoder does, with
the checks it lacks (each step at least one object header, never past the collection's end),
and raises :class:`GlobalHeapDamaged` (an :class:`OSError`, which every opener already
reports as a damaged store file, exit status 5) instead. It is one pass over the file's bytes
(memory-mapped; ``bytes.find`` of the signature), some 10 ms per 40 MB. A match of ``GCOL`` that
does not begin a well-formed collection header (version 1, reserved bytes zero, a size of at
least 4096 bytes that fits in the file) is not followed: HDF5 refuses such a header itself,
with an error, when it reads it.

:func:`open_hdf5` is ``h5py.File(path, "r")`` after that check.
"""

from __future__ import annotations

import mmap
import os
import struct
from pathlib import Path

SIGNATURE = b"GCOL"
HEADER = 16  # signature, version, 3 reserved, collection size (8)
OBJECT_HEADER = 16  # index (2), references (2), reserved (4), size (8)
MIN_COLLECTION = 4096  # H5HG_MINSIZE


class GlobalHeapDamaged(OSError):
    """A global heap collection HDF5 would loop on or read past; ``str()`` says where."""

    def __str__(self) -> str:
        return self.strerror or "damaged global heap"


def collection_problem(data, at: int, file_size: int) -> str | None:
    """What is wrong with the collection whose signature is at byte ``at`` (None: sound, or
    not a collection header at all)."""
    if at + HEADER > file_size or data[at + 4] != 1 or data[at + 5 : at + 8] != b"\0\0\0":
        return None
    size = struct.unpack_from("<Q", data, at + 8)[0]
    if size < MIN_COLLECTION or at + size > file_size:
        return None  # HDF5 refuses it itself ("global heap size is too small", "exceeds EOA")
    end = at + size
    p = at + HEADER
    while p < end:
        if p + OBJECT_HEADER > end:
            break  # the last few bytes: free space too small for a header, as HDF5 reads them
        index = struct.unpack_from("<H", data, p)[0]
        object_size = struct.unpack_from("<Q", data, p + 8)[0]
        step = object_size if index == 0 else OBJECT_HEADER + ((object_size + 7) & ~7)
        if step < OBJECT_HEADER:
            return (f"global heap collection at byte {at:,}: its free space at byte {p:,} has size {object_size}"
                    " (smaller than its own header)")
        if p + step > end:
            return (f"global heap collection at byte {at:,}: object {index} at byte {p:,} has size {object_size:,},"
                    f" past the collection's end")
        p += step
    return None


def check_global_heaps(path: str | os.PathLike) -> None:
    """Raise :class:`GlobalHeapDamaged` when a global heap collection of the file is damaged
    so that HDF5 would loop on it or read past it (see the module docstring)."""
    from ..io.base import open_regular

    with open_regular(path) as f:  # a FIFO in a store file's place is refused, never waited on
        file_size = os.fstat(f.fileno()).st_size
        if file_size < HEADER:
            return
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            at = data.find(SIGNATURE)
            while at >= 0:
                problem = collection_problem(data, at, file_size)
                if problem is not None:
                    raise GlobalHeapDamaged(0, problem, os.fspath(path))
                at = data.find(SIGNATURE, at + 4)


def open_hdf5(path: str | os.PathLike, trusted: bool = False):
    """``h5py.File(path, "r")``, its global heaps checked first (unless ``trusted``: a file
    this store's own checks read whole since it was last written, see
    :mod:`shapeidx.store.verified`)."""
    import h5py

    if not trusted:
        check_global_heaps(Path(path))
    return h5py.File(path, "r")
