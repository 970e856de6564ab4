"""What ``shapeidx query`` takes and what it answers: one result block per query.

A query is a part file, every part file of a directory (the same files ``build`` would
index), ``-`` (one part on standard input; ``--type`` names its format when its content
does not), or an entry of the store (``--id``).
"""

from __future__ import annotations

import io
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from ..errors import ShapeidxError


@dataclass(frozen=True)
class QueryInput:
    """One query: ``label`` as the user gave it, and the part (a path or a file object) or entry."""

    label: str
    part: object = None
    entry: str | None = None
    path: str | None = None  # absolute path of a query file, None for stdin and --id


def query_inputs(files, entries, file_type: str | None) -> list[QueryInput]:
    """The queries of the command line, in the order given (a directory's files sorted)."""
    inputs = []
    stdin_used = False
    for given in files:
        if given == "-":
            if stdin_used:
                raise ShapeidxError("'-' (standard input) can be given once")
            stdin_used = True
            data = sys.stdin.buffer.read()
            inputs.append(QueryInput("-", io.BytesIO(data)))
        elif os.path.isdir(given):
            inputs.extend(_directory_inputs(given))
        else:
            inputs.append(QueryInput(given, given, path=os.path.abspath(given)))
    inputs.extend(QueryInput(entry, entry=entry) for entry in entries)
    return inputs


def _directory_inputs(folder: str) -> list[QueryInput]:
    from ..index.walk import walk_parts

    walk = walk_parts(Path(folder).resolve())
    if not walk.files:
        raise ShapeidxError(f"{folder}: no part files in this directory (nothing to query with)")
    return [QueryInput(os.path.join(folder, f.path), f.absolute, path=f.absolute) for f in walk.files]
