"""Size-aware comparison: ``--scale invariant`` (the paper's) or ``--scale sensitive``.

The paper normalises every histogram by its own mean distance, so a part and its copy at
another size are at distance 0. With ``sensitive`` two parts whose sizes (mean pair
distance in file units, :attr:`FamilyTable.sizes`) differ by more than a factor
:data:`SIZE_BAND` are kept apart: a query does not return them, a classification does not
let them vote, duplicates never pair them. Inside the band distances are unchanged. The
band's effect on retrieval is measured in docs/results.md.
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeidxError

SCALES = ("invariant", "sensitive")
#: Largest size ratio two parts may have and still count as alike under ``--scale sensitive``.
#: 2: measured on kicad6 (docs/results.md): the best first tier of the bands tried (1.25 to 4);
#: re-sampling noise on the size is below 1%.
SIZE_BAND = 2.0
#: Size ratios that mean "the same part in other units": 0.1 inch (KiCad's VRML) to mm, cm to
#: mm, inch to mm, foot to inch, m to cm, foot to mm, m to mm; and their inverses (duplicates'
#: ``converted`` tier and the same-part order of a query, :mod:`shapeidx.search.same_part`).
UNIT_FACTORS = (2.54, 10.0, 25.4, 12.0, 100.0, 304.8, 1000.0)
#: Every factor two sizes of one part may differ by: 1 and the unit factors both ways.
SAME_SIZE_FACTORS = (1.0,) + tuple(f for u in UNIT_FACTORS for f in (u, 1.0 / u))


def check_scale(scale: str) -> str:
    if scale not in SCALES:
        raise ShapeidxError(f"unknown scale {scale!r}; expected one of {', '.join(SCALES)}")
    return scale


def within_band(size_a, size_b, band: float = SIZE_BAND) -> np.ndarray:
    """Whether sizes differ by at most a factor ``band`` (NaN sizes: True, size unknown)."""
    size_a, size_b = np.asarray(size_a, dtype=np.float64), np.asarray(size_b, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.maximum(size_a, size_b) / np.minimum(size_a, size_b)
    return ~(ratio > band)


def ratio_within_band(ratio, band: float = SIZE_BAND) -> np.ndarray:
    """Whether size ratios (either way round) are within a factor ``band`` (NaN: True, unknown)."""
    ratio = np.asarray(ratio, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return ~(np.maximum(ratio, 1 / ratio) > band)


def apply_scale(distances: np.ndarray, size_query: float, sizes: np.ndarray, scale: str, band: float = SIZE_BAND) -> np.ndarray:
    """``distances`` with entries outside the size band set to inf under ``sensitive``."""
    check_scale(scale)
    if scale == "invariant":
        return distances
    out = np.array(distances, dtype=np.float64)
    out[~within_band(size_query, sizes, band)] = np.inf
    return out
