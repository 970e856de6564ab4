"""Is one part the mirror image of another? From the handedness the store keeps.

D2 histograms are made of point-pair distances, which a mirror image keeps; a left and a
right bracket are still different parts. The two handedness pseudo-scalars that
:func:`shapeidx.signing.moments.shape_facts` computes at build time change sign under a
mirroring and under nothing else; this module reads them.
"""

from __future__ import annotations

import numpy as np

#: |h| below this is "achiral" (a mirror image congruent to the part). Measured on kicad6:
#: see docs/duplicates.md.
CHIRAL_MIN = 1e-3


def mirror_relation(ha: np.ndarray, hb: np.ndarray, chiral_min: float = CHIRAL_MIN) -> np.ndarray:
    """Whether parts with handedness ``ha``, ``hb`` ((..., 2) arrays) are mirror images.

    True when at least one of the two pseudo-scalars is clearly non-zero in both parts
    (``|h| >= chiral_min``) and every such one has opposite signs in the two; False for
    achiral parts, parts of unknown handedness (NaN) and parts of the same handedness.
    """
    ha, hb = np.asarray(ha, dtype=np.float64), np.asarray(hb, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        clear = (np.abs(ha) >= chiral_min) & (np.abs(hb) >= chiral_min)
        opposite = np.sign(ha) != np.sign(hb)
    any_clear = clear.any(axis=-1)
    return any_clear & np.all(~clear | opposite, axis=-1)


def is_chiral(h: np.ndarray, chiral_min: float = CHIRAL_MIN) -> np.ndarray:
    """Whether a handedness ((..., 2)) is clearly non-zero: the part differs from its mirror image."""
    with np.errstate(invalid="ignore"):
        return (np.abs(np.asarray(h, dtype=np.float64)) >= chiral_min).any(axis=-1)
