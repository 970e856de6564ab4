"""How finely a solid model (STEP, IGES) is faceted before it is sampled.

Kept apart from :mod:`shapeidx.io.step` so that the store, the build and the command line can
name the parameters without loading OpenCASCADE.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Largest distance between a facet and the exact surface, as a fraction of the part's
#: bounding-box diagonal. Chosen by the faceting study (docs/faceting.md): at 0.002 the
#: signatures of the kicad6-step parts no longer move beyond their sampling noise.
DEFAULT_LINEAR_DEFLECTION = 0.002
#: Largest angle (radians) between the normals of two neighbouring facets on a curved face.
DEFAULT_ANGULAR_DEFLECTION = 0.35

#: The range the command line accepts (finer than 1e-5 of the size gives millions of
#: triangles on a single fillet; coarser than 0.2 is no longer the part's shape).
LINEAR_DEFLECTION_RANGE = (1e-5, 0.2)
ANGULAR_DEFLECTION_RANGE = (0.01, 1.5)


@dataclass(frozen=True)
class Faceting:
    """Tolerances of BRepMesh_IncrementalMesh for one part.

    Parameters
    ----------
    linear_deflection : float
        Chordal tolerance relative to the part's size: the absolute tolerance given to
        OpenCASCADE is ``linear_deflection * diagonal`` of the part's bounding box, so that a
        part and a scaled copy are faceted alike (the signature is scale-invariant).
    angular_deflection : float
        Angular tolerance in radians.
    """

    linear_deflection: float = DEFAULT_LINEAR_DEFLECTION
    angular_deflection: float = DEFAULT_ANGULAR_DEFLECTION

    def __post_init__(self):
        if not self.linear_deflection > 0 or not self.angular_deflection > 0:
            raise ValueError(f"faceting tolerances must be positive, not {self}")

    def absolute(self, diagonal: float) -> float:
        """The linear deflection in the part's own length unit."""
        return self.linear_deflection * diagonal
