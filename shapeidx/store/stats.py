"""What ``shapeidx stats`` reports about a store."""

from __future__ import annotations

import numpy as np

from ..signing.parameters import HISTOGRAMS
from .layout import STATUS_FAILED, STATUS_OK
from .reader import StoreReader
from .writer import read_build_state


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
        "bytes": reader.size_on_disk(),
        "failure_reasons": [{"reason": str(r), "count": int(c)} for c, r in by_count],
    }


def _metadata_facts(store) -> dict | None:
    """Rows, keys and source of the store's metadata table (``build --metadata``), or None."""
    from .metadata import load_table

    table = load_table(store)
    if table is None:
        return None
    return {"rows": len(table), "keys": list(table.columns), "source": table.source, "sha256": table.sha256}
