"""Signing a part: the paper's section 3.2, one module per step, in the order they run.

    part.py        a part in any form (path, file object, arrays, trimesh) -> Solid: load_part
    mesh.py        triangulate polygons, merge duplicate points, drop bad faces, orient shells
    solid.py       -> Solid: outward normals, cavities, overlapping shells united
    sampling.py    -> points: m random points on the surface, uniform by area (3.2.1)
    classify.py    -> distances and IN / OUT / MIXED classes of every pair (3.2.2, 3.2.3)
    occlusion.py      the ray queries classify needs, through Embree
    histogram.py   -> Signature: four D2 histograms and the class fractions (3.2.4)
    angles.py      -> the normal-angle histograms of the same pairs (beyond the paper)
    moments.py     beside it: size, principal radii, handedness, moments (exact integrals)
    chirality.py   is one part the mirror image of another (from that handedness)
    pipeline.py    the road above in three functions: solid_of_file, signature_of_solid,
                   signature_of_file
    parameters.py  the defaults and names (points, seed, bin divisor, classes, version)

Names are loaded on first use, so that ``from shapeidx.signing import HISTOGRAMS`` does not
import scipy or Embree.
"""

from .._lazy import attach

_NAMES = {
    **dict.fromkeys(
        ["BIN_DIVISOR", "CLASS_NAMES", "DEFAULT_POINTS", "DEFAULT_SEED", "HISTOGRAMS", "SIGNATURE_VERSION"],
        ".parameters",
    ),
    "Histogram": ".histogram",
    "Signature": ".histogram",
    "Solid": ".solid",
    "make_solid": ".solid",
    "load_part": ".part",
    "shape_facts": ".moments",
    "sample_surface": ".sampling",
    "classify_pairs": ".classify",
    "solid_of_file": ".pipeline",
    "signature_of_solid": ".pipeline",
    "signature_of_file": ".pipeline",
}
__all__ = sorted(_NAMES)
__getattr__, __dir__ = attach(__name__, _NAMES)
