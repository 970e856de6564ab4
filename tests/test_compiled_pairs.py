"""The compiled pair pass (shapeidx/signing/_pairs.c) gives the numpy path's signature, bit for bit.

Both roads run on the same samples of real parts: closed KiCad solids, open surfaces (their
normals turned by winding numbers), other exporters' files, one-off signatures on two
threads. The numpy road is what ``SHAPEIDX_NATIVE=0`` selects and what runs where the
extension is not built; the compiled one is what every build and query uses.
"""

from __future__ import annotations

import numpy as np
import pytest

from shapeidx.io import load
from shapeidx.signing import occlusion
from shapeidx.signing.angles import angle_histograms
from shapeidx.signing.classify import classify_pairs, normalise
from shapeidx.signing.histogram import Signature
from shapeidx.signing.occlusion import NativeScene, OcclusionScene
from shapeidx.signing.pipeline import signature_of_solid
from shapeidx.signing.sampling import sample_surface
from shapeidx.signing.solid import make_solid

PARTS = [
    "kicad6/Capacitor_SMD/*.wrl",
    "kicad6/Connector_PinHeader_2.54mm/*.wrl",
    "kicad6/Package_QFP/*.wrl",
    "kicad6/Relay_THT/*.wrl",
    "vrml-wild/kicad-wrz/**/*.wr*",
    "vrml-wild/freecad-kicad-tests/**/*.wrl",
    "mesh-wild/**/*.stl",
]


@pytest.fixture
def numpy_road(monkeypatch):
    """Switch the compiled passes off for the duration of a ``with``."""
    from contextlib import contextmanager

    @contextmanager
    def switched_off():
        monkeypatch.setenv("SHAPEIDX_NATIVE", "0")
        occlusion.compiled_pairs.cache_clear()
        occlusion.native_pairs.cache_clear()
        try:
            yield
        finally:
            monkeypatch.setenv("SHAPEIDX_NATIVE", "1")
            occlusion.compiled_pairs.cache_clear()
            occlusion.native_pairs.cache_clear()

    return switched_off


def _solids(data_dir):
    solids = []
    for pattern in PARTS:
        for path in sorted(data_dir.glob(pattern))[:6]:
            try:
                solid = make_solid(load(path), path)
            except Exception:  # noqa: BLE001 (mesh-wild holds broken files on purpose)
                continue
            solids.append((path, solid))
            if sum(1 for p, _ in solids if p.match(pattern)) >= 2:
                break
    return solids


def test_the_compiled_pass_is_built_and_finds_embree():
    """A checkout installed as the README says has it: a silent fallback would hide a slow build."""
    assert occlusion.compiled_pairs() is not None
    assert occlusion.native_pairs() is not None


def test_parts_of_every_kind_are_compared(data_dir):
    solids = _solids(data_dir)
    assert len(solids) >= 12
    assert any(not solid.watertight for _, solid in solids), "an open surface is among them"


@pytest.mark.parametrize("threads", [1, 2])
def test_signatures_are_those_of_the_numpy_road(data_dir, numpy_road, threads):
    for path, solid in _solids(data_dir):
        with numpy_road():
            expected = signature_of_solid(solid, 1024, seed=3, threads=threads)
        got = signature_of_solid(solid, 1024, seed=3, threads=threads)
        for name, want in expected.histograms.items():
            have = got.histograms[name]
            assert np.array_equal(have.counts, want.counts), (path.name, name)
            assert have.counts.dtype == want.counts.dtype
            assert (have.mean, have.bin_width) == (want.mean, want.bin_width), (path.name, name)
        assert np.array_equal(got.angles, expected.angles), path.name
        assert got.angles.dtype == expected.angles.dtype


def test_distances_and_classes_of_every_pair(data_dir):
    """Pair for pair, not only in the histograms; and the scene answers as embreex's does."""
    for path, solid in _solids(data_dir)[::3]:
        points, face_index = sample_surface(solid.vertices, solid.faces, 600, seed=11)
        vertices, _, _ = normalise(solid.vertices, points)
        slow = classify_pairs(solid.vertices, solid.faces, points, face_index, solid.watertight,
                              scene=OcclusionScene(vertices, solid.faces))
        fast = classify_pairs(solid.vertices, solid.faces, points, face_index, solid.watertight)
        assert np.array_equal(fast[0], slow[0]), path.name
        assert np.array_equal(fast[1], slow[1]), path.name
        starts, ends = points[:300] * 0.999, points[300:]
        _, starts, _ = normalise(solid.vertices, starts)
        _, ends, _ = normalise(solid.vertices, ends)
        assert np.array_equal(NativeScene(vertices, solid.faces).blocked(starts, ends),
                              OcclusionScene(vertices, solid.faces).blocked(starts, ends)), path.name


def test_histogram_edge_cases_match(numpy_road):
    """Classes that are empty, or whose pairs are all at distance 0; bins at the edges."""
    rng = np.random.default_rng(5)
    cases = [
        (rng.random(1000) * 3, rng.integers(0, 3, 1000).astype(np.uint8)),
        (rng.random(500), np.zeros(500, dtype=np.uint8)),  # IN only: OUT and MIXED empty
        (np.r_[np.zeros(10), rng.random(90)], np.r_[np.ones(10), np.full(90, 2)].astype(np.uint8)),  # OUT all at 0
        (np.arange(1, 101, dtype=float) / 50, np.full(100, 2, dtype=np.uint8)),  # values on bin edges
        # a few OUT pairs very short beside long IN ones: OUT's bins are narrow, its counts short
        (np.r_[np.full(5, 1e-9), rng.random(995) * 10], np.r_[np.ones(5), np.zeros(995)].astype(np.uint8)),
    ]
    for distances, classes in cases:
        with numpy_road():
            want = Signature.from_pairs(distances, classes, 10, 0)
        got = Signature.from_pairs(distances, classes, 10, 0)
        for name in want.histograms:
            assert np.array_equal(got.histograms[name].counts, want.histograms[name].counts), name
            assert got.histograms[name].mean == want.histograms[name].mean
            assert got.histograms[name].bin_width == want.histograms[name].bin_width


def test_angle_counts_match_at_bin_edges(numpy_road):
    """Normals whose angles sit on and beside every bin edge: the near-edge pairs go back to arccos."""
    from shapeidx.signing.angles import ANGLE_BINS

    edges = np.arange(ANGLE_BINS + 1) * np.pi / ANGLE_BINS
    angles = np.concatenate([edges, edges + 1e-12, edges - 1e-12, np.random.default_rng(2).random(60) * np.pi])
    normals = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    classes = np.random.default_rng(3).integers(0, 3, len(normals) * (len(normals) - 1) // 2).astype(np.uint8)
    with numpy_road():
        want = angle_histograms(normals, classes)
    assert np.array_equal(angle_histograms(normals, classes), want)


def test_bad_arguments_raise_instead_of_writing_past_arrays():
    compiled = occlusion.compiled_pairs()
    distances = np.ones(4)
    with pytest.raises(ValueError, match="class code"):
        compiled.class_sums(distances, np.array([0, 1, 2, 3], dtype=np.uint8), np.zeros(3), np.zeros(3, dtype=np.int64),
                            np.zeros(3))
    with pytest.raises(ValueError, match="outside"):
        compiled.bin_counts(distances, np.zeros(4, dtype=np.uint8), 0.1, np.full(3, 0.1), np.zeros(2, dtype=np.int64),
                            np.zeros((3, 2), dtype=np.int64))
    with pytest.raises(ValueError, match="wrong size"):
        compiled.class_sums(distances, np.zeros(3, dtype=np.uint8), np.zeros(3), np.zeros(3, dtype=np.int64), np.zeros(3))
    native = occlusion.native_pairs()
    vertices = np.zeros(10, dtype=np.float32)
    with pytest.raises(ValueError, match="does not exist"):
        native.Scene(vertices, 3, np.array([[0, 1, 5]], dtype=np.uint32), 1)


def test_packets_of_rays_answer_as_single_rays(data_dir):
    from shapeidx.signing.classify import _classify_compiled
    from shapeidx.signing.mesh import unit_normals

    for path, solid in _solids(data_dir)[1::4]:
        points, face_index = sample_surface(solid.vertices, solid.faces, 500, seed=13)
        vertices, points, scale = normalise(solid.vertices, points)
        normals = unit_normals(vertices, solid.faces[face_index])
        scene = NativeScene(vertices, solid.faces)
        packed = _classify_compiled(scene, points, normals, scale, 1)
        single = _classify_compiled(scene, points, normals, scale, 1, packets=False)
        assert np.array_equal(packed[1], single[1]), path.name


def test_a_scene_not_made_or_made_twice_raises_instead_of_crashing(data_dir):
    """Found by review: these crashed the process (a NULL scene) or leaked its buffers."""
    native = occlusion.native_pairs()
    empty = native.Scene.__new__(native.Scene)
    rays = np.zeros((1, 3), dtype=np.float32)
    with pytest.raises(RuntimeError, match="not made"):
        empty.blocked(rays, rays, np.zeros(1, dtype=np.uint8))
    vertices = np.zeros(10, dtype=np.float32)
    faces = np.array([[0, 1, 2]], dtype=np.uint32)
    scene = native.Scene(vertices, 3, faces, 1)
    with pytest.raises(TypeError, match="once"):
        scene.__init__(vertices, 3, faces, 1)
    for bad in [(vertices, -1, faces, 1), (vertices, 3, faces, -1), (vertices, 4, faces, 1),
                (vertices.astype(np.float64), 3, faces, 1), (vertices, 3, faces.astype(np.int64), 1)]:
        with pytest.raises(ValueError):
            native.Scene(*bad)


def test_classify_refuses_wrong_dtypes_and_an_order_that_is_not_a_permutation(data_dir):
    from shapeidx.signing.classify import OFFSET, TANGENT, _classify_compiled, spatial_order
    from shapeidx.signing.mesh import unit_normals

    path, solid = _solids(data_dir)[0]
    points, face_index = sample_surface(solid.vertices, solid.faces, 50, seed=1)
    vertices, points, scale = normalise(solid.vertices, points)
    normals = unit_normals(vertices, solid.faces[face_index])
    scene = NativeScene(vertices, solid.faces)
    p32, n32 = points.astype(np.float32), normals.astype(np.float32)
    own = np.einsum("ij,ij->i", p32, n32)
    shifted = np.concatenate([points - OFFSET * normals, points + OFFSET * normals]).astype(np.float32)
    distance, classes = np.empty(50 * 49 // 2), np.empty(50 * 49 // 2, dtype=np.uint8)
    good = (points, p32, n32, own, shifted, spatial_order(points), TANGENT, scale, 0, 50, distance, classes, True)
    scene.classify(*good)
    assert np.array_equal(classes, _classify_compiled(scene, points, normals, scale, 1)[1])
    with pytest.raises(ValueError, match="permutation"):
        scene.classify(*good[:5], np.zeros(50, dtype=np.int32), *good[6:])
    with pytest.raises(ValueError, match="dtype"):
        scene.classify(*good[:10], distance.view(np.int64), *good[11:])
    with pytest.raises(ValueError, match="dtype"):
        scene.classify(points.astype(np.float32).repeat(2, axis=1), *good[1:])
