"""combined-size: the one metric that reads the parts' exact sizes (issue 33).

Every other metric is scale-invariant; this one is not, on purpose: in a library of one unit
some kinds differ by size alone (pin headers of 1.00, 2.00 and 2.54 mm pitch).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

import shapeidx
from shapeidx.distance import SIZE_METRICS, compare, learned_weights, metric
from shapeidx.search import Searcher
from storetools import build


def sampled_radii(mesh, count=400_000) -> np.ndarray:
    """Principal radii of a surface, largest first, from dense random samples (trimesh's own
    sampler): an estimate that shares nothing with the exact integration of the signature."""
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=1)
    return np.sqrt(np.sort(np.linalg.eigvalsh(np.cov(points.T)))[::-1])


def size_weights() -> tuple:
    weights = learned_weights("combined-size")["weights"]
    return weights["size_r2"], weights["size_r3"]


def test_only_combined_size_reads_sizes_and_it_says_it_is_not_scale_invariant():
    assert SIZE_METRICS == ("combined-size",)
    record = metric("combined-size")
    assert "scale-invariant" in record.summary and not record.defaults  # no task uses it unasked
    assert all(w >= 0 for w in record.terms.values())  # monotone: the query's bounds hold


def test_a_signature_carries_its_surfaces_principal_radii():
    for mesh in (trimesh.creation.box((10, 20, 5)), trimesh.creation.annulus(r_min=4, r_max=5, height=20)):
        signature = shapeidx.signature(mesh, points=256)
        assert signature.radii == pytest.approx(sampled_radii(mesh), rel=5e-3)


def test_a_scaled_copy_is_apart_by_the_size_terms_alone():
    box = trimesh.creation.box((10, 20, 5))
    for factor in (3.0, 1.1):
        got = shapeidx.compare(box, (box.vertices * factor, box.faces))
        w2, w3 = size_weights()
        # the same points scaled: every histogram alike, each radius ln(factor) apart
        assert got["combined-size"] == pytest.approx((w2 + w3) * np.sqrt(np.log(factor)), rel=1e-9)
        assert got["combined-angle"] == pytest.approx(0.0, abs=1e-12)


def test_a_thinner_box_is_apart_by_its_smallest_radius():
    thick, thin = trimesh.creation.box((10, 20, 5)), trimesh.creation.box((10, 20, 4))
    a, b = shapeidx.signature(thick, points=512), shapeidx.signature(thin, points=512)
    ra, rb = sampled_radii(thick), sampled_radii(thin)
    w2, w3 = size_weights()
    size_terms = w2 * np.sqrt(abs(np.log(ra[1] / rb[1]))) + w3 * np.sqrt(abs(np.log(ra[2] / rb[2])))
    got = compare(a, b)
    angle_part = got["combined-size"] - size_terms
    assert size_terms > 0.3 and 0 < angle_part < got["combined-angle"]  # its other weights are smaller


def test_a_store_ranks_a_near_size_before_a_far_one(tmp_path):
    parts = tmp_path / "parts"
    parts.mkdir()
    box = trimesh.creation.box((10, 20, 5))
    for name, factor in (("box", 1.0), ("box_x3", 3.0), ("box_x1.1", 1.1)):
        trimesh.Trimesh(box.vertices * factor, box.faces).export(parts / f"{name}.stl")
    assert build(parts, tmp_path / "s.h5").exit_code == 0
    hits = shapeidx.query(tmp_path / "s.h5", parts / "box.stl", top=3, metric="combined-size")
    assert [h["relative_path"] for h in hits] == ["box.stl", "box_x1.1.stl", "box_x3.stl"]
    # bit for bit what compare gives for each pair
    with Searcher(tmp_path / "s.h5") as searcher:
        query = searcher.query_of_part(parts / "box.stl")
        for hit in hits:
            stored = searcher.signature_of(hit["relative_path"])
            assert hit["distance"] == compare(query.signature, stored)["combined-size"]


def test_an_unknown_size_adds_nothing(tmp_path):
    parts = tmp_path / "parts"
    parts.mkdir()
    box = trimesh.creation.box((10, 20, 5))
    for name, factor in (("box", 1.0), ("box_x3", 3.0)):
        trimesh.Trimesh(box.vertices * factor, box.faces).export(parts / f"{name}.stl")
    assert build(parts, tmp_path / "s.h5").exit_code == 0
    with Searcher(tmp_path / "s.h5") as searcher:
        signed = searcher.query_of_part(parts / "box.stl").signature
        bare = dataclasses.replace(signed, radii=None)  # a signature made by hand, without its sizes
        sized = {h.relative_path: h.distance for h in searcher.search(searcher.query_of_part(signed), 2, "combined-size").hits}
        blind = {h.relative_path: h.distance for h in searcher.search(searcher.query_of_part(bare), 2, "combined-size").hits}
        stored = searcher.signature_of("box_x3.stl")
    w2, w3 = size_weights()
    assert sized["box_x3.stl"] == pytest.approx(blind["box_x3.stl"] + (w2 + w3) * np.sqrt(np.log(3)), rel=1e-9)
    assert blind["box_x3.stl"] == compare(bare, stored)["combined-size"]
