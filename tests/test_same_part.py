"""The same-part order (``query --same-part``, :mod:`shapeidx.search.same_part`).

The gap is checked against shapes whose exact measures are known (boxes scaled, in another
unit, stretched); the order on real KiCad parts whose points are drawn with another seed than
the store's, where the plain order puts a series sibling first; a STEP file against its VRML
export (millimetres against tenths of an inch); a part beside its mirror image, which D2 cannot
tell apart; and a sharded store against one store.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from clitools import cli
from storetools import copy_tree

from shapeidx.search import Filters, Query, Searcher, open_searcher
from shapeidx.search.same_part import (MIRROR_GAP, OTHER_SURFACE_GAP, SAME_PART_RANK, SAME_PART_WEIGHT, SAME_SURFACE,
                                       same_part_scores, shape_gap, shape_measures)
from shapeidx.signing import load_part
from shapeidx.signing.moments import shape_facts

FOLDERS = ("Varistor", "Package_QFP")
#: A varistor of the KiCad series whose points drawn with seed 7 are nearer, by Weighted, to
#: its sibling one size over (5.3 mm thick) than to its own stored entry.
WIDE = "Varistor/RV_Disc_D21.5mm_W5.6mm_P10mm.wrl"
SIBLING = "Varistor/RV_Disc_D21.5mm_W5.3mm_P10mm.wrl"


def measures(mesh: trimesh.Trimesh) -> np.ndarray:
    facts = shape_facts(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    return shape_measures(facts["extents"], facts["moments"], facts["handedness"])


def chiral_part() -> trimesh.Trimesh:
    """Three boxes along three axes, each off-centre: no mirror image of it is congruent to it."""
    long = trimesh.creation.box((4.0, 1.0, 1.0))
    wide = trimesh.creation.box((1.0, 2.0, 1.0))
    wide.apply_translation((1.5, 1.5, 0.0))
    tall = trimesh.creation.box((1.0, 1.0, 3.0))
    tall.apply_translation((-1.5, 0.0, 2.0))
    return trimesh.util.concatenate([long, wide, tall])


def mirrored(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_transform(np.diag([-1.0, 1.0, 1.0, 1.0]))  # trimesh turns the faces back outward
    return out


def test_the_gap_is_the_exact_measures_apart():
    box = trimesh.creation.box((1.0, 2.0, 3.0))
    turned = box.copy()
    turned.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(3).random(3)))
    turned.apply_translation((5.0, -2.0, 1.0))
    inches = box.copy()
    inches.apply_scale(1 / 25.4)  # the same part written in inches
    larger = box.copy()
    larger.apply_scale(1.5)  # no unit is 1.5 times another: another size
    longer = trimesh.creation.box((1.0, 2.0, 3.3))
    m = measures(box)
    gaps = shape_gap(m, np.array([measures(turned), measures(inches), measures(larger), measures(longer)]))
    assert gaps[0] == pytest.approx(0.0, abs=1e-9)
    assert gaps[1] == pytest.approx(0.0, abs=1e-9)
    assert gaps[2] == pytest.approx(math.log(1.5), rel=1e-9)  # the size alone: proportions and area ratio kept
    assert gaps[3] > 0.02  # 10% longer: proportions and size both move


def test_a_mirror_image_is_apart_by_the_mirror_gap_alone():
    part = chiral_part()
    turned = part.copy()
    turned.apply_transform(trimesh.transformations.rotation_matrix(1.0, (1.0, 2.0, 0.5)))
    box = trimesh.creation.box((1.0, 2.0, 3.0))  # achiral: its mirror image is itself
    gaps = shape_gap(measures(part), np.array([measures(mirrored(part)), measures(turned)]))
    assert gaps[0] == pytest.approx(MIRROR_GAP, abs=1e-9)
    assert gaps[1] == pytest.approx(0.0, abs=1e-9)
    assert shape_gap(measures(box), measures(mirrored(box))[None])[0] == pytest.approx(0.0, abs=1e-9)


def test_an_unknown_measure_adds_nothing():
    known = np.array([0.0, -0.5, -1.0, 1.2, 0.3, -0.2])
    unknown = np.full(6, np.nan)
    assert shape_gap(known, unknown[None])[0] == 0.0


def test_the_scale_is_the_query_s_own_nearest_distances():
    distances = np.arange(1, 31, dtype=float)
    scores = same_part_scores(distances, np.ones(30))
    assert np.allclose(scores - distances, scores[0] - distances[0])
    # d_K = the 11th smallest: 11; a gap of 1 is another surface
    assert scores[0] - distances[0] == pytest.approx(SAME_PART_WEIGHT * SAME_PART_RANK * (1 + OTHER_SURFACE_GAP))


def test_one_surface_comes_before_a_sibling_nearer_by_the_metric():
    """Two siblings whose measures are nearer than a re-faceting moves them (a HC-18/U and a
    HC-49/U crystal: 7e-4) are told apart by the surface alone: the copy, at gap 0, comes first
    though the metric puts it a little farther; within one surface the metric orders."""
    distances = np.concatenate([[1.00, 0.98, 0.99], np.linspace(1.0, 3.0, 20)])
    gaps = np.concatenate([[0.0, 7e-4, SAME_SURFACE / 2], np.full(20, 0.5)])
    scores = same_part_scores(distances, gaps)
    assert list(np.argsort(scores)[:3]) == [2, 0, 1]


@pytest.fixture(scope="module")
def stores(data_dir, tmp_path_factory):
    """Varistors and QFPs at the store's default 1,024 points (the noise is the point), as one
    store and as a store of three shards."""
    tmp = tmp_path_factory.mktemp("same-part")
    tree = copy_tree(data_dir / "kicad6", tmp / "parts", FOLDERS)
    one, sharded = tmp / "one.shapeidx", tmp / "sharded.shapeidx"
    for store, extra in ((one, ()), (sharded, ("--shards", "3"))):
        result = cli("build", tree, "--store", store, "-q", *extra)
        assert result.exit_code == 0, result.output
    return tree, one, sharded


def test_a_part_drawn_again_is_its_own_first_answer(stores):
    tree, one, _ = stores
    with Searcher(one) as searcher:
        query = searcher.query_of_part(tree / WIDE, seed=7)
        plain = searcher.search(query, top=3, metric="weighted")
        same = searcher.search(query, top=3, metric="weighted", filters=Filters(same_part=True))
    assert plain.hits[0].relative_path == SIBLING  # the sampling noise: a sibling first
    assert all(hit.shape_gap is None for hit in plain.hits)
    assert same.hits[0].relative_path == WIDE
    assert same.hits[0].shape_gap == pytest.approx(0.0, abs=1e-9)
    assert same.hits[1].shape_gap > 0.01
    # a hit keeps the metric's distance; only the order is the same-part order's
    by_path = {hit.relative_path: hit.distance for hit in plain.hits}
    assert same.hits[0].distance > by_path[SIBLING]
    for hit in same.hits:
        if hit.relative_path in by_path:
            assert hit.distance == pytest.approx(by_path[hit.relative_path], rel=1e-12)
    assert "--same-part" in same.filters


def test_a_step_file_finds_its_vrml_export_in_another_unit(stores, data_dir):
    _, one, _ = stores
    step = data_dir / "kicad6-step" / WIDE.replace(".wrl", ".step")
    with Searcher(one) as searcher:
        answer = searcher.search(searcher.query_of_part(step), top=3, metric="weighted", filters=Filters(same_part=True))
    assert answer.hits[0].relative_path == WIDE
    assert answer.hits[0].shape_gap < 0.01  # millimetres against tenths of an inch: the factor 2.54 is no gap


def test_the_command_line_shows_the_gap(stores):
    tree, one, _ = stores
    result = cli("query", "--id", WIDE, "--store", one, "--same-part", "--top", "3", "--json")
    assert result.exit_code == 0, result.output
    answer = json.loads(result.output)
    assert answer["filters"] == ["--same-part"]
    assert answer["hits"][0]["relative_path"] == WIDE and answer["hits"][0]["shape_gap"] == 0.0
    assert all("shape_gap" in hit for hit in answer["hits"])
    csv = cli("query", str(tree / WIDE), "--store", one, "--same-part", "--format", "csv")
    assert csv.output.splitlines()[0].endswith(",shape_gap")
    table = cli("query", str(tree / WIDE), "--store", one, "--same-part", "--top", "2")
    assert "shape_gap=0 " in table.output.splitlines()[0] + " "
    plain = cli("query", "--id", WIDE, "--store", one, "--json")
    assert all("shape_gap" not in hit for hit in json.loads(plain.output)["hits"])


def test_a_real_part_ranks_before_its_mirror_image(data_dir, tmp_path):
    """A KiCad pin socket (pin 1 on the right) beside its mirror image (pin 1 on the left, written
    as STL), among the rest of its series: D2 sees one shape in the two; the same-part order puts the part itself first, whatever points
    the query draws, and shows the mirror's gap."""
    tree = tmp_path / "parts"
    tree.mkdir()
    name = "PinSocket_1x02_P1.00mm_Vertical_SMD_Pin1Right"  # two pins: its axes are defined
    source = data_dir / "kicad6" / "Connector_PinSocket_1.00mm" / f"{name}.wrl"
    for sibling in source.parent.glob("*.wrl"):  # the series around it: the scale of the question
        (tree / sibling.name).symlink_to(sibling)
    solid = load_part(source)
    mirrored(trimesh.Trimesh(solid.vertices, solid.faces, process=False)).export(tree / f"{name}_mirrored.stl")
    store = tmp_path / "store.shapeidx"
    assert cli("build", tree, "--store", store, "-q", "--follow-outside-links").exit_code == 0
    with Searcher(store) as searcher:
        for seed in (7, 8, 9):
            query = searcher.query_of_part(source, seed=seed)
            for metric in ("weighted", "all-angle"):
                answer = searcher.search(query, top=2, metric=metric, filters=Filters(same_part=True))
                assert [h.relative_path for h in answer.hits] == [source.name, f"{name}_mirrored.stl"], (seed, metric)
                assert answer.hits[0].shape_gap < 0.01
                assert answer.hits[1].shape_gap >= MIRROR_GAP


def test_a_sharded_store_orders_as_one_store(stores):
    tree, one, sharded = stores
    files = sorted(tree.rglob("*.wrl"))
    with Searcher(one) as single, open_searcher(sharded) as shards:
        for k, path in enumerate(files):
            for metric in ("weighted", "all-angle"):
                answers = [s.search(s.query_of_part(path, seed=7 + k), top=5, metric=metric, filters=Filters(same_part=True))
                           for s in (single, shards)]
                assert [h.relative_path for h in answers[0].hits] == [h.relative_path for h in answers[1].hits], path
                assert np.allclose([h.distance for h in answers[0].hits], [h.distance for h in answers[1].hits])
                assert np.allclose([h.shape_gap for h in answers[0].hits], [h.shape_gap for h in answers[1].hits])
        entry = files[0].relative_to(tree).as_posix()
        by_entry = [s.search(s.query_of_entry(entry), top=3, metric="weighted", filters=Filters(same_part=True))
                    for s in (single, shards)]
        assert by_entry[0].hits[0].relative_path == by_entry[1].hits[0].relative_path == entry
        assert by_entry[1].hits[0].shape_gap == 0.0


def test_a_bare_signature_keeps_the_metric_s_order(stores):
    """A query given as a signature alone has no exact measures: the plain order, and no gap claimed."""
    tree, one, _ = stores
    with Searcher(one) as searcher:
        signed = searcher.query_of_part(tree / WIDE, seed=7)
        bare = Query("signature", signed.signature)
        plain = searcher.search(bare, top=3, metric="weighted")
        same = searcher.search(bare, top=3, metric="weighted", filters=Filters(same_part=True))
    assert [h.relative_path for h in same.hits] == [h.relative_path for h in plain.hits]
    assert all(h.shape_gap is None for h in same.hits)
