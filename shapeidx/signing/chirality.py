"""Is one part the mirror image of another? From the handedness the store keeps.

D2 histograms are made of point-pair distances, which a mirror image keeps; a left and a
right bracket are still different parts. The three handedness pseudo-scalars that
:func:`shapeidx.signing.moments.shape_facts` computes at build time change sign under a
mirroring and under nothing else; this module reads them. The first two are defined where
the three principal axes are, the third (``h3``) where exactly one is; each has its own
threshold of "clearly non-zero".
"""

from __future__ import annotations

import numpy as np

#: |h| below this is "achiral" (a mirror image congruent to the part). Measured on kicad6:
#: see docs/duplicates.md.
CHIRAL_MIN = 1e-3
#: The same for ``h3``, which is far smaller (a long bare SMD pin header's is 2e-4 to 1e-3, a
#: long pin socket's, whose symmetric body dilutes its pins, 1e-7 to 2e-5). Of the 336 kicad6
#: VRML / kicad6-step STEP twins (other triangles, by OpenCASCADE), 60 have h3 in both and 21
#: of them opposite signs, all tiny: the largest that both reach is 1.4e-6 (Altech_AK300_1x02
#: 45-Degree), 21 times below this threshold (scripts/chirality_twins.py). Kept well above it:
#: a false mirror costs a twin its place, a missed one leaves the order as it was.
AXIAL_CHIRAL_MIN = 3e-5
#: Each pseudo-scalar's threshold, in shape_facts' order (h1, h2, h3).
CHIRAL_MINS = (CHIRAL_MIN, CHIRAL_MIN, AXIAL_CHIRAL_MIN)


def _clear(h: np.ndarray, chiral_min) -> np.ndarray:
    """Which pseudo-scalars of ``h`` ((..., k)) are clearly non-zero."""
    limits = np.asarray(CHIRAL_MINS[: h.shape[-1]] if chiral_min is None else chiral_min, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.abs(h) >= limits


def mirror_relation(ha: np.ndarray, hb: np.ndarray, chiral_min=None) -> np.ndarray:
    """Whether parts with handedness ``ha``, ``hb`` ((..., 3) arrays, or (..., 2): ``h1, h2``)
    are mirror images.

    True when at least one of the pseudo-scalars is clearly non-zero in both parts
    (``|h| >=`` its :data:`CHIRAL_MINS`, or ``chiral_min``) and every such one has opposite
    signs in the two; False for achiral parts, parts of unknown handedness (NaN) and parts of
    the same handedness.
    """
    ha, hb = np.asarray(ha, dtype=np.float64), np.asarray(hb, dtype=np.float64)
    clear = _clear(ha, chiral_min) & _clear(hb, chiral_min)
    with np.errstate(invalid="ignore"):
        opposite = np.sign(ha) != np.sign(hb)
    any_clear = clear.any(axis=-1)
    return any_clear & np.all(~clear | opposite, axis=-1)


def is_chiral(h: np.ndarray, chiral_min=None) -> np.ndarray:
    """Whether a handedness ((..., 3) or (..., 2)) is clearly non-zero: the part differs from its mirror image."""
    return _clear(np.asarray(h, dtype=np.float64), chiral_min).any(axis=-1)
