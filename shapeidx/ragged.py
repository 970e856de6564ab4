"""Ragged arrays stored as CSR: values laid end to end, row ``i`` at ``offsets[i]:offsets[i + 1]``.

The store keeps every histogram this way, and the distances read them back this way.
"""

from __future__ import annotations

import numpy as np


def offsets_of(lengths: np.ndarray) -> np.ndarray:
    """CSR offsets (n + 1,) of rows with these lengths."""
    offsets = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    return offsets


def take_ragged(flat: np.ndarray, offsets: np.ndarray, rows: np.ndarray, base: int = 0):
    """Rows ``rows`` of a CSR array whose values ``flat`` start at offset ``base``.

    Returns
    -------
    values : the rows' values laid end to end
    lengths : (len(rows),) int64
    """
    starts = offsets[rows] - base
    lengths = offsets[rows + 1] - offsets[rows]
    total = int(lengths.sum())
    if len(rows) and starts[0] == 0 and total == len(flat):
        return flat, lengths  # the rows cover the values (rows left out are empty): no copy
    # position of each output value in ``flat``: its row's start plus its place in the row
    shift = np.repeat(starts - offsets_of(lengths)[:-1], lengths)
    return flat[shift + np.arange(total)], lengths
