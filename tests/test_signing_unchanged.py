"""The faster pair work gives the signatures it gave before, bit for bit, on real parts.

tests/signing_before.py is a frozen copy of the code before it was made faster; both run
on the same samples of real files (closed and open surfaces, KiCad and other exporters).
"""

from __future__ import annotations

import numpy as np
import pytest

import signing_before as before
from shapeidx.io import load
from shapeidx.signing.angles import angle_histograms
from shapeidx.signing.classify import classify_pairs
from shapeidx.signing.histogram import Signature
from shapeidx.signing.sampling import sample_surface
from shapeidx.signing.solid import make_solid

PARTS = [
    "kicad6/Capacitor_THT/*.wrl",
    "kicad6/Package_SO/*.wrl",
    "kicad6/Connector_*/*.wrl",
    "vrml-wild/kicad-2017/**/*.wrl",
    "vrml-wild/kicad-wrz/**/*.wr*",
    "vrml-wild/freecad-kicad-tests/**/*.wrl",
]


def _files(data_dir):
    files = []
    for pattern in PARTS:
        matches = sorted(data_dir.glob(pattern))
        files += matches[:2]
    return files


def test_the_parts_exist(data_dir):
    assert len(_files(data_dir)) >= 10


@pytest.mark.parametrize("index", range(12))
def test_classes_histograms_and_angles_are_unchanged(data_dir, index):
    files = _files(data_dir)
    if index >= len(files):
        pytest.skip("fewer parts")
    path = files[index]
    solid = make_solid(load(path), path)
    points, face_index = sample_surface(solid.vertices, solid.faces, 1024, seed=7 + index)
    normals = []
    distances, classes = classify_pairs(solid.vertices, solid.faces, points, face_index, solid.watertight, normals_out=normals)
    old_distances, old_classes, old_normals = before.classify_pairs(solid.vertices, solid.faces, points, face_index, solid.watertight)
    assert np.array_equal(distances, old_distances)
    assert np.array_equal(classes, old_classes)
    assert np.array_equal(normals[0], old_normals)
    new = Signature.from_pairs(distances, classes, 1024, 7)
    for name, old in before.histograms(old_distances, old_classes).items():
        got = new.histograms[name]
        assert got.counts.dtype == old.counts.dtype
        assert np.array_equal(got.counts, old.counts), name
        assert (got.mean, got.bin_width) == (old.mean, old.bin_width), name
    assert np.array_equal(angle_histograms(normals[0], classes), before.angle_histograms(old_normals, old_classes))


def test_unique_indices_is_numpys_unique(data_dir):
    from shapeidx.signing.mesh import unique_indices

    path = _files(data_dir)[0]
    mesh = load(path)
    rng = np.random.default_rng(2)
    for indices in (mesh.face_indices, make_solid(mesh, path).faces, rng.integers(0, 50, (40, 3)), np.zeros((0, 3), np.int64),
                    np.array([-1, 3, 3, 0])):
        used, inverse = np.unique(indices, return_inverse=True)
        got_used, got_inverse = unique_indices(indices, return_inverse=True)
        assert np.array_equal(got_used, used) and np.array_equal(got_inverse, inverse.reshape(-1))
        assert np.array_equal(unique_indices(indices), np.unique(indices))
