"""Indexing a tree into a store: what ``shapeidx build`` runs.

    walk.py      find the part files of a tree
    plan.py      compare them with the store's entries: what needs work
    workers.py   worker processes, one file each; crashes and time limits contained
    commit.py    outcomes into journal batches, merges
    progress.py  a progress bar on a terminal, log lines otherwise
    build.py     all of it: run_build
dask_pool.py the per-file work on a Dask cluster (build --scheduler); remote.py its workers
shards.py    build --shards: a store sharded by path key
"""

from .build import BuildOptions, BuildSummary, run_build
from .walk import walk_parts

__all__ = ["BuildOptions", "BuildSummary", "run_build", "walk_parts"]
