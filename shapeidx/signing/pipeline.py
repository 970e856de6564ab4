"""The road from a part file to its signature, in three functions.

    file --io.load--> PolygonMesh --solid.make_solid--> Solid
         --sampling.sample_surface--> points
         --classify.classify_pairs--> distances, classes
         --Signature.from_pairs--> Signature
    (the same pairs and the samples' normals --angles.angle_histograms--> Signature.angles;
     the surface's exact principal radii --moments.shape_facts--> Signature.radii)
"""

from __future__ import annotations

import os

from ..io import LoadLimits, load
from .angles import angle_histograms
from .classify import classify_pairs
from .histogram import Signature, known_radii
from .parameters import BIN_DIVISOR, DEFAULT_POINTS, DEFAULT_SEED
from .sampling import sample_surface
from .solid import Solid, make_solid


def solid_of_file(path: str | os.PathLike, limits: LoadLimits | None = None) -> Solid:
    """Load a part file and make it a clean, oriented solid (raises LoadError)."""
    return make_solid(load(path, limits), path)


def signature_of_solid(
    solid: Solid, points: int = DEFAULT_POINTS, seed: int = DEFAULT_SEED, divisor: int = BIN_DIVISOR, threads: int = 1
) -> Signature:
    """Sample ``points`` surface points, classify all pairs, and histogram them.

    ``threads`` > 1 shares the ray queries among threads (for one-off signatures; a build
    runs one signature per core instead).
    """
    samples, face_index = sample_surface(solid.vertices, solid.faces, points, seed)
    normals = []
    distances, classes = classify_pairs(solid.vertices, solid.faces, samples, face_index, solid.watertight, threads=threads,
                                        normals_out=normals)
    angles = angle_histograms(normals[0], classes)
    return Signature.from_pairs(distances, classes, points, seed, divisor, angles=angles,
                                radii=known_radii(solid.facts["extents"]))


def signature_of_file(
    path: str | os.PathLike,
    points: int = DEFAULT_POINTS,
    seed: int = DEFAULT_SEED,
    limits: LoadLimits | None = None,
) -> Signature:
    """The signature of a part file (raises LoadError for a file that is not a usable part)."""
    return signature_of_solid(solid_of_file(path, limits), points, seed)
