"""What ``shapeidx stats`` reports about a store."""

from __future__ import annotations

import numpy as np

from ..signing.parameters import HISTOGRAMS
from .layout import STATUS_FAILED, STATUS_OK
from .lock import read_build_state
from .metadata import load_table
from .reader import StoreBeingCreated, StoreReader, open_store


def describe_store(reader: StoreReader) -> dict:
    """What ``shapeidx stats`` shows: counts by status, parameters, versions, size on disk."""
    for source in reader._sources:  # offsets out of bounds say "damaged" here, not later in a query
        for name in HISTOGRAMS:
            source.offsets(name)
    status = reader.column("entries/status")
    reasons = reader.column("entries/reason")[status == STATUS_FAILED]
    common, counts = np.unique(reasons.astype(str), return_counts=True) if len(reasons) else ([], [])
    by_count = sorted(zip(counts, common), key=lambda pair: (-pair[0], pair[1]))
    return {
        "store": str(reader.path),
        "entries": int(len(status)),
        "ok": int(np.sum(status == STATUS_OK)),
        "failed": int(np.sum(status == STATUS_FAILED)),
        "parameters": reader.params.as_attrs(),
        "schema_version": int(reader.attrs["schema_version"]),
        "shapeidx_version": reader.attrs.get("shapeidx_version"),
        "root": reader.attrs.get("root"),
        "created": reader.attrs.get("created"),
        "updated": reader.attrs.get("updated"),
        "journal_batches": reader.journal,
        "build": read_build_state(reader.path),
        "metadata": _metadata_facts(reader.path),
        "parts": _parts_facts(reader.path),
        "bytes": reader.size_on_disk(),
        "failure_reasons": [{"reason": str(r), "count": int(c)} for c, r in by_count],
        "older_reader": older_reader(reader),
    }


def older_reader(reader: StoreReader) -> dict:
    """Format label -> entries signed by an older revision of that format's reader than this
    shapeidx's (:attr:`shapeidx.io.base.Format.revision`): the next build signs them again.

    Reads the revision column (8 bytes an entry) and decodes only the paths of entries older
    than the newest revision of any reader: none in a store built since.
    """
    from ..io.registry import FORMATS, count_by_label, entry_format, revisions
    from .layout import REVISION_COLUMN

    if not len(reader):
        return {}
    revision = reader.column(REVISION_COLUMN)
    maybe = np.flatnonzero(revision < max(revisions().values()))
    if not len(maybe):
        return {}
    paths = reader.paths
    names = [entry_format(str(paths[i])) for i in maybe.tolist()]
    older = [name for i, name in zip(maybe.tolist(), names) if name and revision[i] < FORMATS[name].revision]
    return count_by_label(older)


def _parts_facts(store) -> dict | None:
    """Sub-entries of the store's sub-parts store (``build --parts``), or None when it has none.

    ``entries``: distinct sub-parts signed; ``files``: whole files they come from;
    ``several``: files that hold more than one distinct sub-part; ``instances``: sub-parts
    counted as often as their files hold them (forty identical pins are one entry, 40 here).
    """
    from .files import parts_store
    from .layout import COUNT_COLUMN, PARENT_COLUMN

    path = parts_store(store)
    if not path.is_dir():
        return None
    try:
        parts = open_store(path)
    except StoreBeingCreated:  # the first build with --parts has committed nothing (yet)
        return None
    with parts:
        ok = parts.column("entries/status") == STATUS_OK
        parents = parts.column(PARENT_COLUMN)[ok].astype(str)
        counts = parts.column(COUNT_COLUMN)[ok]
    files, per_file = np.unique(parents, return_counts=True)
    return {"entries": int(ok.sum()), "files": int(len(files)),
            "several": int(np.sum(per_file > 1)), "instances": int(counts.sum())}


def _metadata_facts(store) -> dict | None:
    """Rows, keys and source of the store's metadata table (``build --metadata``), or None."""
    table = load_table(store)
    if table is None:
        return None
    return {"rows": len(table), "keys": list(table.columns), "source": table.source, "sha256": table.sha256}


def describe_sharded(store) -> dict:
    """What ``shapeidx stats`` shows of a sharded store (``build --shards``): its shards' facts
    (:func:`describe_store`) summed (their sub-parts' too, ``build --parts``), the parameters
    they share, and each shard's own in ``shards``. A shard that cannot be opened says so in
    one line, as the store it is."""
    from collections import Counter

    from .shards import shard_paths

    shards, missing = [], []
    for path in shard_paths(store):
        if not path.exists():  # made as the sharded build reaches it: a first build was stopped before
            missing.append(str(path))
            continue
        with open_store(path) as reader:
            shards.append(describe_store(reader))
    if not shards:
        open_store(shard_paths(store)[0])  # the reader's one line: no store yet, run the build
    total = {key: sum(s[key] for s in shards) for key in ("entries", "ok", "failed", "bytes", "journal_batches")}
    reasons, older = Counter(), Counter()
    for s in shards:
        reasons.update({item["reason"]: item["count"] for item in s["failure_reasons"]})
        older.update(s["older_reader"])
    builds = [s["build"] for s in shards] + [None] * len(missing)
    facts = dict(shards[0])
    facts.update(total, store=str(store), updated=max(str(s["updated"] or "") for s in shards) or None,
                 created=min(str(s["created"] or "") for s in shards) or None, build=_sharded_build(builds),
                 parts=_summed_parts([s["parts"] for s in shards]), older_reader=dict(older),
                 failure_reasons=[{"reason": r, "count": c} for r, c in sorted(reasons.items(), key=lambda rc: (-rc[1], rc[0]))],
                 parameters_differ=any(s["parameters"] != shards[0]["parameters"] for s in shards),
                 shards_not_built=missing,
                 shards=[{key: s[key] for key in ("store", "entries", "ok", "failed", "bytes", "updated", "build")}
                         for s in shards])
    return facts


def _summed_parts(facts: list) -> dict | None:
    """The shards' sub-parts facts (:func:`_parts_facts`) added up, or None when no shard has
    sub-parts. A file and its sub-parts share a shard, so ``files`` and ``several`` add up too."""
    facts = [f for f in facts if f is not None]
    if not facts:
        return None
    return {key: sum(f[key] for f in facts) for key in ("entries", "files", "several", "instances")}


def _sharded_build(builds: list) -> dict | None:
    """The shards' last builds as one: running while any shard's runs, stopped or interrupted
    when any shard's was; finished (counts summed) when every shard's finished."""
    if any(b is None for b in builds):
        return None
    for state in ("running", "stopped", "interrupted"):
        for b in builds:
            if b.get("state") == state:
                return b
    counts = ("indexed", "unchanged", "removed", "failed")
    return {"state": "finished", "at": max(str(b.get("at", "")) for b in builds),
            **{k: sum(int(b.get(k, 0)) for b in builds) for k in counts if all(k in b for b in builds)}}
