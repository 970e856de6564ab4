"""Labels of store entries: their folders, or a CSV of ``path,label``."""

from __future__ import annotations

import csv
import os

import numpy as np

from ..errors import ShapeidxError


def labels_from_paths(paths, depth: int = 1) -> np.ndarray:
    """Each path's first ``depth`` folders, ``/``-joined; None for a path with fewer folders."""
    out = np.empty(len(paths), dtype=object)
    for i, path in enumerate(paths):
        parts = str(path).split("/")
        out[i] = "/".join(parts[:depth]) if len(parts) > depth else None
    return out


def labels_from_csv(file: str | os.PathLike, paths) -> tuple[np.ndarray, list[str]]:
    """Labels of ``paths`` from a CSV of ``path,label`` rows (a header row ``path,label`` is allowed).

    Returns
    -------
    labels : (len(paths),) object, None where the CSV gives none
    unknown : list of str
        CSV paths that are not among ``paths``.

    Raises
    ------
    ShapeidxError
        The file cannot be read, a row is not ``path,label``, or no CSV path is in the store.
    """
    try:
        with open(file, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise ShapeidxError(f"{file}: cannot read the labels ({getattr(exc, 'strerror', None) or exc})") from None
    if rows and [c.strip().lower() for c in rows[0]] == ["path", "label"]:
        rows = rows[1:]
    index = {str(p): i for i, p in enumerate(paths)}
    labels = np.empty(len(paths), dtype=object)
    unknown = []
    for line, row in enumerate(rows, start=1):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != 2 or not row[0].strip() or not row[1].strip():
            raise ShapeidxError(f"{file}: row {line} is not 'path,label': {','.join(row)[:80]!r}")
        path, label = row[0].strip(), row[1].strip()
        if path in index:
            labels[index[path]] = label
        else:
            unknown.append(path)
    if unknown and len(unknown) == sum(1 for r in rows if r and any(c.strip() for c in r)):
        raise ShapeidxError(
            f"{file}: none of its {len(unknown)} paths is in the store (first: {unknown[0]!r});"
            " give paths relative to the indexed folder, as 'shapeidx query --id' takes them"
        )
    return labels, unknown
