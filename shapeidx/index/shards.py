"""``shapeidx build DIR --store S --shards N [--scheduler ADDRESS]``: a store sharded by path key.

Each shard (:mod:`shapeidx.store.shards`) is an ordinary store built by an ordinary build of
the files of its share of paths (:attr:`BuildOptions.shard`): its own walk of the tree,
plan, lock, journal and commits, so every guarantee of a build holds shard by shard, and a
build that stops part-way leaves every shard consistent (the next build finishes the work).

Without a scheduler the shards are built one after the other on this machine, each with the
build's ``--workers``. With one, every shard is built on a worker of the cluster (the
scheduler spreads them), in a child process of the Dask worker (a Dask worker may not start
the build's own worker processes), with the build's ``--workers`` (default 1) worker
processes there: the shard's store must be visible to its worker at the same path, and the
tree at the same path or under ``--worker-root``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from ..errors import ShapeidxError
from ..store.shards import create_sharded
from .build import BuildOptions, BuildSummary, run_build

#: The summary fields a sharded build adds up over its shards.
_SUMMED = ("found", "planned", "indexed", "unchanged", "removed", "failed", "store_ok", "store_failed", "store_bytes")
#: The same for ``--parts`` (None without it).
_SUMMED_PARTS = ("parts_indexed", "parts_entries", "parts_planned", "parts_removed")


def run_sharded_build(root, store, options: BuildOptions, reporter, shards: int) -> BuildSummary:
    """Build ``store`` as ``shards`` shards of the tree ``root``; the summary of them all."""
    started = time.monotonic()
    store = Path(store)
    paths = create_sharded(store, shards, create=not options.dry_run)
    if options.scheduler:
        summaries = _on_cluster(root, paths, options, reporter)
    else:
        summaries = []
        for k, path in enumerate(paths):
            reporter.say(f"shard {k} of {shards}: {path}")
            summaries.append(run_build(root, path, dataclasses.replace(options, shard=(k, shards)), reporter))
    total = BuildSummary(root=summaries[0].root)
    for summary in summaries:
        for name in _SUMMED:
            setattr(total, name, getattr(total, name) + getattr(summary, name))
        total.failures += summary.failures
        for name in ("older", "older_parts"):
            for label, count in getattr(summary, name).items():
                getattr(total, name)[label] = getattr(total, name).get(label, 0) + count
        for name in _SUMMED_PARTS:
            if getattr(summary, name) is not None:
                setattr(total, name, (getattr(total, name) or 0) + getattr(summary, name))
        if summary.metadata_rows is not None:
            total.metadata_rows = summary.metadata_rows
            total.metadata_changed |= summary.metadata_changed
    total.seconds = time.monotonic() - started
    return total


def _on_cluster(root, paths: list, options: BuildOptions, reporter) -> list:
    """Every shard built on a worker of ``options.scheduler``; their summaries, in shard order."""
    from .dask_pool import dask_client

    root = str(Path(root).resolve())
    on_workers = options.worker_root or root
    client = dask_client(options.scheduler)
    try:
        futures = []
        for k, path in enumerate(paths):
            shard_options = dataclasses.replace(options, scheduler=None, worker_root=None, shard=(k, len(paths)),
                                                workers=options.workers or 1)
            futures.append(client.submit(build_shard_on_worker, on_workers, str(Path(path).resolve()),
                                         dataclasses.asdict(shard_options), key=f"shapeidx-shard-{k}-{os.getpid()}",
                                         pure=False))
        summaries = []
        for k, future in enumerate(futures):
            result = future.result()
            if "error" in result:
                raise ShapeidxError(f"shard {k} ({paths[k]}): {result['error']}")
            summary = BuildSummary(root=root)
            for name in _SUMMED:
                setattr(summary, name, result[name])
            for name in _SUMMED_PARTS:
                setattr(summary, name, result.get(name))
            summary.failures = [tuple(f) for f in result["failures"]]
            summary.metadata_rows, summary.metadata_changed = result["metadata_rows"], result["metadata_changed"]
            summary.older, summary.older_parts = dict(result.get("older", {})), dict(result.get("older_parts", {}))
            reporter.say(f"shard {k} of {len(paths)}: {summary.line()} on {result['host']}")
            summaries.append(summary)
        return summaries
    finally:
        client.close(timeout=5)


def build_shard_on_worker(root: str, store: str, options: dict) -> dict:
    """Run on a Dask worker: one shard's build, in a child process; its summary (or its error)."""
    run = subprocess.run([sys.executable, "-m", "shapeidx.index.shards", root, store, json.dumps(options)],
                         capture_output=True, text=True)
    lines = run.stdout.strip().splitlines()
    if run.returncode != 0 or not lines:
        tail = (run.stderr.strip().splitlines() or [f"exit status {run.returncode}"])[-1]
        return {"error": tail}
    return json.loads(lines[-1])


def _main(argv: list) -> int:
    """``python -m shapeidx.index.shards ROOT STORE OPTIONS_JSON``: one shard's build, quietly; its
    summary as one JSON line."""
    import socket

    from .progress import BuildReporter

    root, store, raw = argv
    fields = json.loads(raw)
    fields["shard"] = tuple(fields["shard"]) if fields.get("shard") is not None else None
    options = BuildOptions(**fields)
    reporter = BuildReporter(quiet=True, terminal=False)
    try:
        summary = run_build(root, Path(store), options, reporter)
    except ShapeidxError as exc:
        print(f"shapeidx build: {exc}", file=sys.stderr)
        return 1
    finally:
        reporter.close()
    out = {name: getattr(summary, name) for name in _SUMMED + _SUMMED_PARTS}
    out.update(failures=[list(f) for f in summary.failures], metadata_rows=summary.metadata_rows,
               metadata_changed=summary.metadata_changed, host=socket.gethostname(), seconds=summary.seconds,
               older=summary.older, older_parts=summary.older_parts)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
