"""A store sharded by path key: N ordinary stores, each holding the entries of its share of paths.

    STORE/                   the sharded store (any name)
        shards.json          the manifest: {"format": "shapeidx-shards", "version": 1, "shards": N,
                             "key": "blake2b-128"}
        shards/0/ ... N-1/   each an ordinary store directory (main.h5, journal/, lock, ...)

A file whose path (relative to the indexed root) has the BLAKE2b-128 key ``k`` (the key the
ranking arrays hold, :func:`shapeidx.store.rank.path_keys`) belongs to shard ``k[0] mod N``:
a path always lands in the same shard, so an entry's whole history (changes, removal) is one
shard's, and every shard keeps every guarantee of an ordinary store (one writer under its
own lock, its own journal, atomic renames). The shards never need to agree with each other;
a query asks every shard for its exact top k and merges them (:mod:`shapeidx.search.sharded`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import StoreError
from .rank import path_keys

MANIFEST = "shards.json"
FORMAT = "shapeidx-shards"
VERSION = 1


def manifest_path(store: Path) -> Path:
    return Path(store) / MANIFEST


def is_sharded(store) -> bool:
    """Whether ``store`` is a sharded store (it holds a manifest)."""
    return manifest_path(Path(store)).is_file()


def owner_of_shard(store) -> Path | None:
    """The sharded store whose shard ``store`` is (``OWNER/shards/K``), or None for any other store."""
    store = Path(store)
    if store.parent.name != "shards" or not store.name.isdigit():
        return None
    owner = store.parent.parent
    return owner if is_sharded(owner) else None


def shard_count(store) -> int:
    """The number of shards of a sharded store (StoreError: a bad manifest, in one line)."""
    path = manifest_path(Path(store))
    try:
        manifest = json.loads(path.read_text())
        count = int(manifest["shards"])
        if manifest.get("format") != FORMAT or int(manifest.get("version", 0)) > VERSION or count < 1:
            raise ValueError("not a manifest of this version")
    except FileNotFoundError:
        raise StoreError(f"{store} is not a sharded store (no {MANIFEST})") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise StoreError(f"{path}: not a shard manifest shapeidx can read ({exc})") from None
    return count


def shard_paths(store, count: int | None = None) -> list[Path]:
    """Every shard's store directory, in shard order."""
    count = shard_count(store) if count is None else count
    return [Path(store) / "shards" / str(k) for k in range(count)]


def create_sharded(store, count: int, create: bool = True) -> list[Path]:
    """Make ``store`` a sharded store of ``count`` shards (or check that it is one of as many).

    ``create=False`` (a dry run) checks the same and changes nothing: a new store's shard
    paths are returned without their folders.

    Raises
    ------
    StoreError
        ``store`` is an ordinary store, or a sharded one of another count.
    """
    store = Path(store)
    if is_sharded(store):
        have = shard_count(store)
        if have != count:
            raise StoreError(f"{store} has {have} shards, not {count}: give --shards {have} (resharding is a new build"
                             " into a new store)")
        return shard_paths(store, count)
    if store.exists() and (not store.is_dir() or any(store.iterdir())):
        raise StoreError(f"{store} exists and is not a sharded store: give --shards only for a new store or a sharded one")
    if not create:
        return shard_paths(store, count)
    (store / "shards").mkdir(parents=True, exist_ok=True)
    text = json.dumps({"format": FORMAT, "version": VERSION, "shards": count, "key": "blake2b-128"}, indent=1) + "\n"
    tmp = manifest_path(store).with_name(f"{MANIFEST}.tmp-{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, manifest_path(store))
    return shard_paths(store, count)


def shard_of_keys(keys: np.ndarray, count: int) -> np.ndarray:
    """The shard of each path key (``(n, 2)`` uint64): its first 64 bits modulo ``count``."""
    return (np.asarray(keys, dtype=np.uint64)[:, 0] % np.uint64(count)).astype(np.int64)


def shard_of_paths(paths, count: int) -> np.ndarray:
    """The shard of each relative path (as the store records it)."""
    paths = list(paths)
    if not paths:
        return np.zeros(0, dtype=np.int64)
    return shard_of_keys(path_keys(paths), count)
