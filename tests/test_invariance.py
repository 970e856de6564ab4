"""A part's signature does not depend on pose, size, file or tessellation; shapes differ.

Each variant is a new file. "Small" is measured against the method's own noise: the distance
between two signatures of the same file sampled with different seeds. A variant must be
within that noise of its original (1.5 times the largest of three reseeds), find its original
first among the shapes, and different shapes must lie farther apart than that noise.
"""

from __future__ import annotations

import numpy as np
import pytest

import analytic as A
from shapeidx.distance import compare
from shapeidx.signing.pipeline import signature_of_file, signature_of_solid, solid_of_file

SHAPES = ["tube", "torus", "plate_with_holes", "l_bracket", "hollow_box", "pin_in_block", "drilled_block"]


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    folder = tmp_path_factory.mktemp("originals")
    signatures = {}
    for name in SHAPES:
        path = folder / f"{name}.obj"
        A.write_obj(path, *A.mesh_arrays(A.catalogue()[name]))
        signatures[name] = signature_of_file(path)
    return signatures


@pytest.fixture(scope="module")
def noise(tmp_path_factory, originals):
    """Per shape: the largest weighted distance between the original and a reseeded signature."""
    folder = tmp_path_factory.mktemp("reseeded")
    result = {}
    for name in SHAPES:
        path = folder / f"{name}.obj"
        A.write_obj(path, *A.mesh_arrays(A.catalogue()[name]))
        solid = solid_of_file(path)
        result[name] = max(compare(originals[name], signature_of_solid(solid, seed=s))["weighted"] for s in (1, 2, 3))
    return result


def variants(name, rng):
    solid = A.catalogue()[name]
    v, f = A.mesh_arrays(solid)
    rotation = A.random_rotation(rng)
    shuffled = rng.permutation(len(f))  # another triangle order: other sample points
    return {
        "rotated": (v @ rotation.T, f[shuffled]),
        "scaled_down": (v * 1e-3, f[shuffled]),
        "scaled_up": (v * 1e3, f[shuffled]),
        "moved_far": (v + np.array([1e6, -2e6, 3e5]), f[shuffled]),
        "retessellated": A.manifold_arrays(solid.mesh().refine(3)),
    }


@pytest.mark.parametrize("name", SHAPES)
def test_variants_stay_near_their_original(tmp_path, originals, noise, name):
    rng = np.random.default_rng(SHAPES.index(name))
    for kind, (v, f) in variants(name, rng).items():
        path = tmp_path / f"{name}_{kind}.obj"
        A.write_obj(path, v, f)
        sig = signature_of_file(path)
        distances = {other: compare(sig, o)["weighted"] for other, o in originals.items()}
        assert min(distances, key=distances.get) == name, f"{kind}: nearest is not the original: {distances}"
        assert distances[name] <= 1.5 * noise[name], f"{kind}: {distances[name]:.4f}, reseeding noise {noise[name]:.4f}"


@pytest.mark.parametrize("name", SHAPES)
def test_different_shapes_are_farther_than_noise(originals, noise, name):
    nearest_other = min(compare(originals[name], sig)["weighted"] for other, sig in originals.items() if other != name)
    assert nearest_other > noise[name]


def test_same_file_same_signature(tmp_path):
    path = tmp_path / "drilled.stl"
    A.write_stl(path, *A.mesh_arrays(A.catalogue()["drilled_block"]))
    a, b = signature_of_file(path), signature_of_file(path)
    for name in a.histograms:
        np.testing.assert_array_equal(a.histograms[name].counts, b.histograms[name].counts)


def test_same_part_in_another_format_is_near(tmp_path, originals, noise):
    v, f = A.mesh_arrays(A.catalogue()["drilled_block"])
    A.write_stl(tmp_path / "drilled.stl", v, f)
    stl = signature_of_file(tmp_path / "drilled.stl")
    assert compare(stl, originals["drilled_block"])["weighted"] <= 1.5 * noise["drilled_block"]
