#!/usr/bin/env python3
"""The per-file stages of a build on a tree of parts, CPU per stage, and one digest of every result.

Usage::

    PYTHONPATH=CODE python scripts/stage_digest.py TREE [--bare]

With whichever ``shapeidx`` comes first on the path (a checkout, or an older commit unpacked by
``git archive COMMIT shapeidx | tar -x -C CODE``), every ``.wrl`` under TREE (sorted) is loaded,
made a solid, signed (1024 points) and measured (``describe`` and ``shape_facts``), each stage
timed with the process CPU clock; ``--bare`` also times the bare Embree query of each part
(``scripts/bench.py``'s floor). Printed as one JSON line: the CPU seconds per stage, and a
SHA-256 over every part's solid (vertices, faces, report, warnings), signature and facts, so
that two codes run one after the other (alternating, for the load) can be compared for speed
and for identical results.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import sys
import time
from pathlib import Path


def main() -> int:
    from shapeidx.io import load
    from shapeidx.signing.moments import shape_facts
    from shapeidx.signing.pipeline import signature_of_solid
    from shapeidx.signing.solid import make_solid
    from shapeidx.system import keep_freed_memory

    import bench

    keep_freed_memory()
    tree, bare = Path(sys.argv[1]), "--bare" in sys.argv[2:]
    cpu = dict.fromkeys(("load", "solid", "signature", "facts", "bare"), 0.0)
    digest = hashlib.sha256()
    clock = time.process_time
    for path in sorted(tree.rglob("*.wrl")):
        started = clock()
        mesh = load(path)
        cpu["load"] += clock() - started
        started = clock()
        solid = make_solid(mesh, path)
        cpu["solid"] += clock() - started
        started = clock()
        signature = signature_of_solid(solid, 1024)
        cpu["signature"] += clock() - started
        started = clock()
        facts = (solid.describe(), shape_facts(solid.vertices, solid.faces))
        cpu["facts"] += clock() - started
        if bare:
            query = bench.bare_query(solid, 1024)
            started = clock()
            query()
            cpu["bare"] += clock() - started
        digest.update(solid.vertices.tobytes() + solid.faces.tobytes())
        digest.update(pickle.dumps((solid.watertight, solid.volume, solid.shells,
                                    sorted(solid.report.items(), key=str), solid.warnings, signature)))
        digest.update(json.dumps(facts, sort_keys=True, default=str).encode())
    print(json.dumps({"cpu": cpu, "digest": digest.hexdigest()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
