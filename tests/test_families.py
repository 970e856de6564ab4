"""classify, cluster, duplicates and what they stand on: sizes, handedness, pair distances,
candidates, agreement figures. Real parts from kicad6, real builds, the real command line."""

from __future__ import annotations

import json


import h5py
import numpy as np
import pytest
import trimesh

import analytic
from clitools import cli, cli_json
from storetools import copy_tree
from shapeidx.distance import METRICS, compare
from shapeidx.families.agreement import ari, nmi
from shapeidx.store.candidates import candidate_pairs
from shapeidx.signing.chirality import mirror_relation
from shapeidx.signing.moments import shape_facts, surface_moments
from shapeidx.families.cluster import cluster_store
from shapeidx.families.table import FamilyTable
from shapeidx.io import load as load_polygons
from shapeidx.signing.pipeline import solid_of_file
from shapeidx.store import open_store

CHIRAL = "LED_SMD/LED_RGB_5050-6.wrl"  # handedness |h2| ~ 0.012: its mirror image is another part
FOLDERS = ("Diode_SMD", "LED_SMD")


def rotation(seed=1):
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def chiral_blocks():
    """Three boxes of different sizes placed off every axis: no mirror plane."""
    meshes = [trimesh.creation.box((3, 1, 1)), trimesh.creation.box((1, 2, 1)), trimesh.creation.box((1, 1, 1.5))]
    for mesh, shift in zip(meshes, ((1.5, 0, 0), (0, 1.5, 0.3), (0.4, 0.2, 1.8))):
        mesh.apply_translation(shift)
    mesh = trimesh.util.concatenate(meshes)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


# ---------------------------------------------------------------------------- sizes, handedness

def test_surface_moments_match_a_fine_midpoint_rule():
    vertices, faces = chiral_blocks()
    area, centroid, covariance, third = surface_moments(vertices, faces)
    # independent: each triangle split 4^6 times, moments summed at the small triangles' centroids
    tri = vertices[faces]
    for _ in range(6):
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tri = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    w = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    x = tri.mean(axis=1)
    assert area == pytest.approx(w.sum(), rel=1e-12)
    assert np.allclose(centroid, (w[:, None] * x).sum(0) / w.sum(), atol=1e-12)
    x = x - centroid
    assert np.allclose(covariance, np.einsum("k,ki,kj->ij", w, x, x) / w.sum(), rtol=1e-3, atol=1e-4)
    assert np.allclose(third, np.einsum("k,ki,kj,kl->ijl", w, x, x, x) / w.sum(), rtol=1e-3, atol=1e-4)


def test_handedness_is_invariant_under_rotation_and_scale_and_flips_under_mirroring():
    vertices, faces = chiral_blocks()
    facts = shape_facts(vertices, faces)
    h = np.array(facts["handedness"])
    assert np.abs(h[:2]).max() > 1e-3 and np.isnan(h[2])  # chiral, its three axes defined: h3 is not
    moved = shape_facts(vertices @ rotation(2).T * 7.5 + 3.0, faces)
    assert np.allclose(moved["handedness"], h, atol=1e-9, equal_nan=True)
    assert np.allclose(moved["extents"], np.array(facts["extents"]) * 7.5, rtol=1e-9)
    for mirror in (np.diag([-1.0, 1, 1]), np.diag([1.0, -1, 1]) @ rotation(3)):
        mirrored = shape_facts(vertices @ mirror.T, faces[:, ::-1])
        assert np.allclose(mirrored["handedness"], -h, atol=1e-9, equal_nan=True)
        assert mirror_relation(h, np.array(mirrored["handedness"]))
    assert not mirror_relation(h, np.array(moved["handedness"]))


def test_a_part_with_a_mirror_plane_has_no_handedness_and_a_cube_none_measurable():
    box = trimesh.creation.box((3, 2, 1))
    facts = shape_facts(box.vertices @ rotation(4).T, box.faces)
    assert np.nanmax(np.abs(facts["handedness"])) < 1e-9
    assert np.allclose(sorted(facts["extents"]), sorted(np.sqrt(_box_surface_variances(3, 2, 1))), rtol=1e-9)
    cube = trimesh.creation.box((2, 2, 2))
    assert np.isnan(shape_facts(cube.vertices, cube.faces)["handedness"]).all()  # axes undefined
    assert not mirror_relation(np.array(shape_facts(cube.vertices, cube.faces)["handedness"]), np.array([0.5, 0.5, 0.5]))


def _long_bar(bumps):
    """A 20 x 1 x 1 bar along x with 1 x 0.5 x 0.5 bumps at (x, side) on its +y or +z face:
    its two small principal radii are within AXIS_GAP of each other, so only its long axis is defined."""
    meshes = [trimesh.creation.box((20, 1, 1))]
    for x, side in bumps:
        bump = trimesh.creation.box((1, 0.5, 0.5))
        bump.apply_translation((x, 0.75 if side == "y" else 0, 0.75 if side == "z" else 0))
        meshes.append(bump)
    mesh = trimesh.util.concatenate(meshes)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_a_long_part_has_the_handedness_of_its_one_axis():
    """h1, h2 need all three axes; h3 only the one that stands apart, and it flips under a
    mirroring, whatever the turn about that axis (analytic shapes: the chiral bar has a bump on
    +y at one end and on +z at the other, the achiral one both on +y, a mirror plane z = 0)."""
    from shapeidx.signing.chirality import AXIAL_CHIRAL_MIN, is_chiral

    vertices, faces = _long_bar(((-8, "y"), (8, "z")))
    h = np.array(shape_facts(vertices, faces)["handedness"])
    assert np.isnan(h[:2]).all() and abs(h[2]) > 3 * AXIAL_CHIRAL_MIN
    for turn in range(5):
        moved = np.array(shape_facts(vertices @ rotation(turn).T * 3.0 - 1.0, faces)["handedness"])
        mirrored = np.array(shape_facts(vertices @ (rotation(turn) @ np.diag([1.0, -1, 1])).T, faces[:, ::-1])["handedness"])
        assert moved[2] == pytest.approx(h[2], rel=1e-6) and mirrored[2] == pytest.approx(-h[2], rel=1e-6)
        assert mirror_relation(h, mirrored) and not mirror_relation(h, moved)
    achiral = np.array(shape_facts(*_long_bar(((-8, "y"), (8, "y"))))["handedness"])
    assert np.isnan(achiral[:2]).all() and abs(achiral[2]) < 1e-9 and not is_chiral(achiral)


def _box_surface_variances(a, b, c):
    """Variance along each axis of the surface of an a x b x c box (analytic)."""
    out = []
    for i, (u, v, w) in enumerate(((a, b, c), (b, c, a), (c, a, b))):
        # the two faces across u sit at +-u/2; the four others spread uniformly over u
        faces_across, faces_along = 2 * v * w, 2 * u * (v + w)
        out.append((faces_across * (u / 2) ** 2 + faces_along * u**2 / 12) / (faces_across + faces_along))
    return np.array(out)


def test_a_mirrored_real_part_flips_and_a_rotated_one_does_not(data_dir):
    solid = solid_of_file(data_dir / "kicad6" / CHIRAL)
    h = np.array(shape_facts(solid.vertices, solid.faces)["handedness"])
    rotated = shape_facts(solid.vertices @ rotation(5).T, solid.faces)["handedness"]
    mirrored = shape_facts(solid.vertices @ np.diag([1.0, 1, -1]).T, solid.faces[:, ::-1])["handedness"]
    assert np.allclose(rotated, h, atol=1e-9, equal_nan=True) and np.allclose(mirrored, -h, atol=1e-9, equal_nan=True)
    assert mirror_relation(h, np.array(mirrored)) and not mirror_relation(h, np.array(rotated))


def test_a_long_real_pin_socket_keeps_its_axial_handedness_turned_or_refaceted(data_dir):
    """A 1 x 34 SMD pin socket: its two small radii coincide (h1, h2 undefined) and h3 is
    defined, kept by a turned and re-faceted copy and reversed by the mirror image; it is below
    AXIAL_CHIRAL_MIN (the socket's symmetric body dilutes its alternating pins), so no copy of
    it is called mirrored, nor is its mirror image."""
    from shapeidx.signing.chirality import AXIAL_CHIRAL_MIN

    solid = solid_of_file(data_dir / "kicad6" / "Connector_PinSocket_2.00mm/PinSocket_1x34_P2.00mm_Vertical_SMD_Pin1Right.wrl")
    h = np.array(shape_facts(solid.vertices, solid.faces)["handedness"])
    assert np.isnan(h[:2]).all() and 1e-7 < abs(h[2]) < AXIAL_CHIRAL_MIN
    v, f = trimesh.remesh.subdivide(solid.vertices, solid.faces)  # every triangle in four
    refaceted = np.array(shape_facts(v @ rotation(8).T, f)["handedness"])
    mirrored = np.array(shape_facts(solid.vertices @ np.diag([-1.0, 1, 1]), solid.faces[:, ::-1])["handedness"])
    assert refaceted[2] == pytest.approx(h[2], rel=1e-6) and mirrored[2] == pytest.approx(-h[2], rel=1e-6)
    assert not mirror_relation(h, refaceted) and not mirror_relation(h, mirrored)
    assert mirror_relation(h, mirrored, chiral_min=(1e-3, 1e-3, 1e-7))  # seen, were the threshold that low


# ---------------------------------------------------------------------------- the store

@pytest.fixture(scope="module")
def dup_store(tmp_path_factory, data_dir):
    """Two kicad6 folders, plus a byte copy, a rotated, a rescaled and a mirrored STL of one chiral part."""
    tmp = tmp_path_factory.mktemp("families")
    tree = copy_tree(data_dir / "kicad6", tmp / "parts", FOLDERS)
    solid = solid_of_file(data_dir / "kicad6" / CHIRAL)
    (tree / "copies").mkdir()
    (tree / "copies" / "rgb-copy.wrl").write_bytes((data_dir / "kicad6" / CHIRAL).read_bytes())
    analytic.write_stl(tree / "copies" / "rgb-rotated.stl", solid.vertices @ rotation(6).T, solid.faces)
    analytic.write_stl(tree / "copies" / "rgb-inches.stl", solid.vertices @ rotation(7).T / 25.4, solid.faces)
    analytic.write_stl(tree / "copies" / "rgb-mirrored.stl", solid.vertices @ np.diag([-1.0, 1, 1]), solid.faces[:, ::-1])
    store = tmp / "store.h5"
    result = cli("build", tree, "--store", store, "-q")
    assert result.exit_code == 0, result.output
    return tree, store


def test_the_store_keeps_each_parts_size_and_handedness(dup_store):
    tree, store = dup_store
    with open_store(store) as reader:
        assert reader.attrs["schema_version"] >= 2 and reader.missing_columns == []  # the size columns came in layout 2
        table = FamilyTable.load(reader)
    i, j = table.index_of("copies/rgb-inches.stl"), table.index_of(CHIRAL)
    bounds = table.bounds[j]
    polygons = load_polygons(tree / CHIRAL)
    assert np.allclose(bounds[:3], polygons.vertices.min(axis=0)) and np.allclose(bounds[3:], polygons.vertices.max(axis=0))
    assert table.size_ratios(np.array([j]), np.array([i]))[0] == pytest.approx(1 / 25.4, rel=1e-6)


def test_pair_distances_equal_compare(dup_store):
    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
        rng = np.random.default_rng(0)
        a, b = rng.integers(0, len(table), (2, 25))
        for metric in METRICS:
            got = table.pair_distances(a, b, metric)
            want = [compare(reader.signature(int(table.rows[x])), reader.signature(int(table.rows[y])))[metric] for x, y in zip(a, b)]
            assert np.allclose(got, want, rtol=1e-12, atol=1e-15), metric


def test_a_store_of_layout_1_still_opens_with_unknown_sizes(dup_store, tmp_path):
    _, store = dup_store
    old = tmp_path / "old.h5"
    import shutil

    shutil.copytree(store, old)
    with h5py.File(old / "main.h5", "r+") as f:
        for name in ("entries/bounds", "entries/extents", "entries/handedness", "entries/axial_handedness"):
            del f[name]
        f.attrs["schema_version"] = 1
    with open_store(old) as reader:
        assert reader.missing_columns == ["entries/bounds", "entries/extents", "entries/handedness",
                                          "entries/axial_handedness"]
        table = FamilyTable.load(reader)
    assert np.isnan(table.extents).all() and np.isnan(table.handedness).all()
    result = cli("duplicates", "--store", old)
    assert result.exit_code == 0, result.output
    assert "predates the size and handedness columns" in result.stderr and "--full" in result.stderr
    assert "identical" in result.stdout  # the byte copy is still found by its hash


def test_a_store_of_before_the_axial_handedness_says_so_and_a_full_build_fills_it(dup_store, tmp_path):
    """A file written before h3 (entries/axial_handedness) opens with h3 unknown, says which
    build fills it, and ``build --full`` does."""
    import shutil

    tree, store = dup_store
    old = tmp_path / "old.h5"
    shutil.copytree(store, old)
    with h5py.File(old / "main.h5", "r+") as f:
        del f["entries/axial_handedness"]
    with open_store(old) as reader:
        assert reader.missing_columns == ["entries/axial_handedness"]
        assert np.isnan(FamilyTable.load(reader).handedness[:, 2]).all()
    result = cli("duplicates", "--store", old)
    assert result.exit_code == 0 and "entries/axial_handedness" in result.stderr and "--full" in result.stderr
    assert cli("build", tree, "--store", old, "--full", "-q").exit_code == 0
    with open_store(old) as reader, open_store(store) as fresh:
        assert reader.missing_columns == []
        assert np.array_equal(FamilyTable.load(reader).handedness, FamilyTable.load(fresh).handedness, equal_nan=True)


# ---------------------------------------------------------------------------- duplicates

def test_duplicates_finds_the_copies_with_their_tier_size_and_mirror(dup_store):
    _, store = dup_store
    groups = cli_json("duplicates", "--store", store)
    group = next(g for g in groups if CHIRAL in g["members"])
    assert set(group["members"]) == {CHIRAL, "copies/rgb-copy.wrl", "copies/rgb-rotated.stl",
                                     "copies/rgb-inches.stl", "copies/rgb-mirrored.stl"}
    with_original = {p["b"] if p["a"] == CHIRAL else p["a"]: p for p in group["pairs"] if CHIRAL in (p["a"], p["b"])}
    by_other = {}
    for p in group["pairs"]:
        for x, y in ((p["a"], p["b"]), (p["b"], p["a"])):
            by_other.setdefault(x, {})[y] = p
    assert by_other[CHIRAL]["copies/rgb-copy.wrl"]["tier"] == "identical"
    mirrored = [p for p in group["pairs"] if "copies/rgb-mirrored.stl" in (p["a"], p["b"])]
    assert mirrored and all(p["mirrored"] and p["tier"] == "same" for p in mirrored)
    others = [p for p in group["pairs"] if "copies/rgb-mirrored.stl" not in (p["a"], p["b"])]
    assert others and not any(p["mirrored"] for p in others)
    inches = [p for p in group["pairs"] if "copies/rgb-inches.stl" in (p["a"], p["b"])]
    for p in inches:
        ratio = p["size_ratio"] if p["b"] == "copies/rgb-inches.stl" else 1 / p["size_ratio"]
        assert ratio == pytest.approx(1 / 25.4, rel=1e-6)
    assert with_original or True
    # no two different kicad6 parts are called the same part
    for g in groups:
        originals = {m for m in g["members"] if not m.startswith("copies/")}
        same_pairs = [p for p in g["pairs"] if p["tier"] in ("identical", "same")
                      and not p["a"].startswith("copies/") and not p["b"].startswith("copies/")]
        assert not same_pairs, same_pairs
        assert len(originals) <= 1 or all(p["tier"] == "near" for p in g["pairs"] if p["a"] in originals and p["b"] in originals)


def test_pair_tiers_asked_directly_agree_with_every_pair_the_groups_list(dup_store):
    from shapeidx.families.duplicates import find_duplicates, pair_tiers

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    listed = [p for g in find_duplicates(table) for p in g["pairs"]]
    a = np.array([table.index_of(p["a"]) for p in listed])
    b = np.array([table.index_of(p["b"]) for p in listed])
    said = pair_tiers(table, a, b)
    assert list(said["tier"]) == [p["tier"] for p in listed]
    assert np.allclose(said["distance"], [p["distance"] for p in listed])
    assert list(said["mirrored"]) == [p["mirrored"] for p in listed]
    # and a pair of two different parts that no group holds gets no tier
    grouped = {m for g in find_duplicates(table) for m in g["members"]}
    loners = [i for i, p in enumerate(table.paths) if p not in grouped][:2]
    assert len(loners) == 2
    assert pair_tiers(table, np.array(loners[:1]), np.array(loners[1:]))["tier"][0] == ""


def test_duplicates_scale_sensitive_keeps_the_rescaled_copy_apart_and_csv_has_a_row_per_pair(dup_store):
    _, store = dup_store
    groups = cli_json("duplicates", "--store", store, "--scale", "sensitive")
    group = next(g for g in groups if CHIRAL in g["members"])
    assert "copies/rgb-inches.stl" not in group["members"]
    result = cli("duplicates", "--store", store, "--csv")
    lines = result.stdout.strip().splitlines()
    assert lines[0] == "group,confidence,a,b,tier,distance,size_ratio,unit,mirrored"
    assert len(lines) - 1 == sum(len(g["pairs"]) for g in cli_json("duplicates", "--store", store))


# ---------------------------------------------------------------------------- classify

def test_classify_json_in_the_order_given_and_never_its_own_vote(dup_store, data_dir):
    tree, store = dup_store
    parts = [str(tree / "LED_SMD" / "LED_2010_5025Metric.wrl"), "Diode_SMD/D_0805_2012Metric.wrl"]
    out = cli_json("classify", *parts, "--store", store, "-k", "3")
    assert [r["path"] for r in out] == parts
    own = {parts[0]: "LED_SMD/LED_2010_5025Metric.wrl", parts[1]: parts[1]}
    for r in out:
        assert set(r) == {"path", "label", "confidence", "neighbours"}
        assert own[r["path"]] not in [nb["path"] for nb in r["neighbours"]]
        assert 0 < r["confidence"] <= 1 and len(r["neighbours"]) == 3
        assert all(nb["label"] in FOLDERS + ("copies",) for nb in r["neighbours"])
        weights = [nb["weight"] for nb in r["neighbours"]]
        assert weights == sorted(weights, reverse=True)


def test_classify_with_a_label_csv_and_bad_input(dup_store, tmp_path):
    _, store = dup_store
    labels = tmp_path / "labels.csv"
    labels.write_text("path,label\n" + "".join(f"{p},odd\n" for p in ("Diode_SMD/D_MELF.wrl", "Diode_SMD/D_MicroMELF.wrl")))
    out = cli_json("classify", "Diode_SMD/D_SOD-123.wrl", "--store", store, "--labels", labels)
    assert out[0]["label"] == "odd" and all(nb["label"] == "odd" for nb in out[0]["neighbours"])
    unknown = tmp_path / "unknown.csv"
    unknown.write_text("nowhere/a.wrl,x\nnowhere/b.wrl,y\n")
    result = cli("classify", "Diode_SMD/D_SOD-123.wrl", "--store", store, "--labels", unknown)
    assert result.exit_code == 1 and result.stderr.count("\n") == 1 and "none of its 2 paths is in the store" in result.stderr
    result = cli("classify", "Diode_SMD/D_SOD-123.wrl", "--store", store, "--label-depth", "3")
    assert result.exit_code == 1 and result.stderr.count("\n") == 1 and "no labelled entries" in result.stderr


def test_empty_store_gives_one_line(tmp_path):
    # a build refuses a tree without part files; a tree of one broken file leaves no ok entry
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "broken.stl").write_bytes(b"solid x\nendsolid x\n")
    store = tmp_path / "empty.h5"
    assert cli("build", tmp_path / "empty", "--store", store, "-q").exit_code == 0
    for command in (("duplicates",), ("cluster",), ("classify", "x.wrl")):
        result = cli(*command, "--store", store)
        assert result.exit_code == 6, command  # no answer, said why (docs/cli.md)
        assert result.stderr.count("\n") == 1 and "no indexed entries" in result.stderr


# ---------------------------------------------------------------------------- cluster, candidates

def test_cluster_rows_and_both_roads_agree_on_clear_families(dup_store):
    _, store = dup_store
    rows = cli_json("cluster", "--store", store, "--clusters", "4")
    assert {r["cluster"] for r in rows} == {1, 2, 3, 4}
    sizes = [sum(r["cluster"] == c for r in rows) for c in (1, 2, 3, 4)]
    assert sizes == sorted(sizes, reverse=True)
    assert all(r["distance"] >= 0 for r in rows) and sum(r["distance"] == 0 for r in rows) >= 4  # the medoids
    copies = {r["cluster"] for r in rows if r["path"] == CHIRAL or r["path"].startswith("copies/")}
    assert len(copies) == 1  # a part and its copies are one family
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    graph = cluster_store(table, clusters=4, road="graph")
    members = [i for i, p in enumerate(table.paths) if p == CHIRAL or p.startswith("copies/")]
    assert len(set(graph["clusters"][members])) == 1
    csv = cli("cluster", "--store", store, "--csv", "--clusters", "3").stdout.splitlines()
    assert csv[0] == "path,cluster,distance" and len(csv) == len(rows) + 1


def _svg_labels(svg: str) -> dict:
    """Text of the SVG's text elements -> their fill colour (matplotlib keeps text as text)."""
    import re

    out = {}
    for style, text in re.findall(r'<text style="([^"]*)"[^>]*>([^<]*)</text>', svg):
        fill = re.search(r"fill: (#[0-9a-f]{6})", style)
        out[text] = fill.group(1) if fill else "#000000"
    return out


def test_cluster_plot_draws_the_dendrogram_with_every_entry_coloured_by_its_cluster(dup_store, tmp_path):
    _, store = dup_store
    svg = tmp_path / "families.svg"
    result = cli("cluster", "--store", store, "--clusters", "4", "--plot", svg, "--json")
    assert result.exit_code == 0, result.output + result.stderr
    rows = json.loads(result.stdout)  # stdout is still the rows alone
    assert f"wrote {svg} (dendrogram of {len(rows)} entries, every entry a leaf)" in result.stderr
    labels = _svg_labels(svg.read_text())
    colour = {}
    for row in rows:
        name = row["path"].rsplit("/", 1)[-1].rsplit(".", 1)[0]
        assert name in labels, name  # every entry is a named leaf
        colour.setdefault(row["cluster"], set()).add(labels[name])
    assert all(len(c) == 1 for c in colour.values()), colour  # one colour per cluster
    assert len(set.union(*colour.values())) == 4  # and four clusters, four colours
    png = tmp_path / "families.png"
    assert cli("cluster", "--store", store, "--clusters", "4", "--plot", png).exit_code == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cluster_plot_of_many_entries_has_one_leaf_per_cluster(dup_store, tmp_path, monkeypatch):
    import shapeidx.families.cluster_plot as cluster_plot

    _, store = dup_store
    monkeypatch.setattr(cluster_plot, "LEAF_LIMIT", 10)  # the store has more entries than that
    rows = cli_json("cluster", "--store", store, "--clusters", "3")
    result = cli("cluster", "--store", store, "--clusters", "3", "--plot", tmp_path / "c.svg")
    assert "one leaf per cluster" in result.stderr
    labels = _svg_labels((tmp_path / "c.svg").read_text())
    for c in (1, 2, 3):
        members = [r for r in rows if r["cluster"] == c]
        medoid = min(members, key=lambda r: r["distance"])["path"].rsplit("/", 1)[-1].rsplit(".", 1)[0]
        size = f"{len(members)} parts" if len(members) > 1 else "1 part"
        assert f"{c}: {size}, {medoid}" in labels


def test_cluster_plot_beyond_the_matrix_is_an_embedding_whose_plane_keeps_planar_distances(dup_store, tmp_path):
    from shapeidx.families.cluster_plot import plot_clusters, principal_plane

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    graph = cluster_store(table, clusters=4, road="graph")
    assert "tree" not in graph
    said = plot_clusters(graph, table, tmp_path / "e.png", "combined")
    assert said == f"embedding of {len(table)} entries in 4 clusters on two principal axes"
    assert (tmp_path / "e.png").read_bytes()[:4] == b"\x89PNG"
    # classical MDS: points on a plane of a 6-D space keep their distances in the picture
    rng = np.random.default_rng(3)
    flat = rng.normal(size=(40, 2)) * (5.0, 1.0)
    basis, _ = np.linalg.qr(rng.normal(size=(6, 2)))
    xy, share = principal_plane(flat @ basis.T + 7.0)
    d = lambda p: np.linalg.norm(p[:, None] - p[None], axis=-1)
    assert np.allclose(d(xy), d(flat), atol=1e-9) and share.sum() == pytest.approx(1.0)


def test_cluster_plot_refuses_an_unknown_picture_format_before_the_work(dup_store, tmp_path):
    _, store = dup_store
    result = cli("cluster", "--store", store, "--plot", tmp_path / "c.gif")
    assert result.exit_code == 2 and result.stdout == ""  # a bad option value: a usage error
    assert "unknown picture format '.gif'" in result.stderr and len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("metric", ["combined", "unified"])
def test_candidates_find_the_exact_nearest_neighbours(dup_store, metric):
    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    n = len(table)
    i, j = np.triu_indices(n, 1)
    exact = np.zeros((n, n))
    exact[i, j] = exact[j, i] = table.pair_distances(i, j, metric)
    np.fill_diagonal(exact, np.inf)
    k = 5
    _, _, _, neighbours, nd = candidate_pairs(table, metric, k)
    assert not (neighbours == np.arange(n)[:, None]).any()
    kth = np.sort(exact, axis=1)[:, k - 1]
    found = (nd <= kth[:, None] + 1e-12).sum(axis=1)
    assert found.sum() / (k * n) >= 0.95


def test_the_inverted_file_finds_what_brute_force_numpy_finds():
    from shapeidx.store.candidates import CandidateIndex

    rng = np.random.default_rng(4)
    centres = rng.normal(size=(60, 24))
    vectors = (centres[rng.integers(0, 60, 6000)] + 0.3 * rng.normal(size=(6000, 24))).astype(np.float32)
    index = CandidateIndex(vectors, "ivf")
    assert index.method == "ivf" and index.index.nlist > 1
    k = 10
    found = index.neighbours(k)
    picks = rng.choice(len(vectors), 200, replace=False)
    squared = ((vectors[picks, None, :].astype(np.float64) - vectors[None, :, :]) ** 2).sum(axis=2)
    squared[np.arange(len(picks)), picks] = np.inf
    truth = np.argsort(squared, axis=1)[:, :k]
    recall = np.mean([len(set(truth[r]) & set(found[i])) / k for r, i in enumerate(picks)])
    assert recall >= 0.95
    assert not (found == np.arange(len(vectors))[:, None]).any()
    assert CandidateIndex(vectors[:50], "ivf").method == "exact"  # too few to train cells on


def test_equal_exact_moments_make_same_beyond_the_distance_threshold_but_not_without_bound(dup_store):
    from shapeidx.families.duplicates import EXACT_DISTANCE_FACTOR, pair_tiers

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    a = np.array([table.index_of(CHIRAL)] * 2)
    b = np.array([table.index_of("copies/rgb-rotated.stl"), table.index_of("copies/rgb-mirrored.stl")])
    d = table.pair_distances(a, b, "combined-angle")
    assert np.all(d > 0)
    # a "same" threshold below both distances: the exact moments alone make them same ...
    limits = {"same": d.max() / 2, "near": d.max()}
    said = pair_tiers(table, a, b, "combined-angle", limits=limits)
    assert list(said["tier"]) == ["same", "same"]
    # ... up to EXACT_DISTANCE_FACTOR times that threshold, not beyond
    limits = {"same": d.min() / (EXACT_DISTANCE_FACTOR * 1.01), "near": d.min() / 2}
    assert list(pair_tiers(table, a, b, "combined-angle", limits=limits)["tier"]) == ["", ""]


def test_nmi_and_ari_against_hand_computed_values():
    assert nmi([0, 0, 1, 1], ["a", "a", "b", "b"]) == pytest.approx(1.0)
    assert ari([0, 0, 1, 1], [5, 5, 7, 7]) == pytest.approx(1.0)
    # classes {0,0,1,1}, clusters {0,1,0,1}: independent
    assert nmi([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(0.0, abs=1e-12)
    assert ari([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(-0.5)
    # classes (3, 3), clusters {0,0,1 | 1,1,1}: contingency [[2, 1], [0, 3]]
    classes, clusters = [0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 1, 1]
    h_classes = np.log(2)
    h_clusters = -(2 / 6 * np.log(2 / 6) + 4 / 6 * np.log(4 / 6))
    mi = 2 / 6 * np.log((2 / 6) / (3 / 6 * 2 / 6)) + 1 / 6 * np.log((1 / 6) / (3 / 6 * 4 / 6)) + 3 / 6 * np.log((3 / 6) / (3 / 6 * 4 / 6))
    assert nmi(classes, clusters) == pytest.approx(mi / ((h_classes + h_clusters) / 2))
    index, rows, cols, total = 1 + 3, 3 + 3, 1 + 6, 15  # sum C(n_ij,2), C(a_i,2), C(b_j,2), C(6,2)
    expected = rows * cols / total
    assert ari(classes, clusters) == pytest.approx((index - expected) / ((rows + cols) / 2 - expected))


def test_query_scale_sensitive_leaves_out_parts_of_another_size(dup_store):
    _, store = dup_store
    plain = cli_json("query", "--id", CHIRAL, "--store", store, "--top", "6")["hits"]
    assert "copies/rgb-inches.stl" in [h["relative_path"] for h in plain[:5]]
    sensitive = cli_json("query", "--id", CHIRAL, "--store", store, "--top", "40", "--scale", "sensitive")["hits"]
    assert "copies/rgb-inches.stl" not in [h["relative_path"] for h in sensitive]
    assert [h["relative_path"] for h in sensitive[:4]][0] == CHIRAL


def test_one_voter_leave_one_out_is_the_retrieval_nearest_neighbour_score(dup_store):
    from shapeidx.evaluation.retrieval import retrieval_scores
    from shapeidx.families.cluster import distance_matrix
    from shapeidx.families.labels import labels_from_paths
    from shapeidx.families.scores import family_scores

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    matrix = distance_matrix(table, "weighted")
    labels = labels_from_paths(table.paths)
    assert family_scores(matrix, labels, k=1)["knn"] == pytest.approx(retrieval_scores(matrix, labels)["nn"])
    scores = family_scores(matrix, labels)
    assert 0 <= scores["nmi"] <= 1 and -1 <= scores["ari"] <= 1


# ---------------------------------------------------------------------------- issue 22: no chaining, sizes, stored embedding

def test_every_duplicate_member_is_within_the_tier_of_its_representative_and_the_inches_copy_says_its_unit(dup_store):
    from shapeidx.families.duplicates import EXACT_DISTANCE_FACTOR, TIERS, find_duplicates, pair_tiers, thresholds

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    groups = find_duplicates(table, "combined-angle", tiers=TIERS)
    assert groups == sorted(groups, key=lambda g: -g["confidence"])  # most confident first
    limits = thresholds("combined-angle")
    for g in groups:
        assert g["members"][0] == g["representative"]
        a = np.array([table.index_of(g["representative"])] * len(g["pairs"]))
        b = np.array([table.index_of(p["b"]) for p in g["pairs"]])
        said = pair_tiers(table, a, b, "combined-angle")  # asked directly, not through a chain
        assert all(t in TIERS for t in said["tier"])
        assert np.all(said["distance"] <= max(limits["near"], EXACT_DISTANCE_FACTOR * limits["same"]))
    group = next(g for g in groups if CHIRAL in g["members"])
    inches = next(p for p in group["pairs"] if p["b"] == "copies/rgb-inches.stl" or p["a"] == "copies/rgb-inches.stl")
    assert inches["unit"] == pytest.approx(1 / 25.4 if inches["b"] == "copies/rgb-inches.stl" else 25.4)
    # and a size ratio that is no unit factor is not one part
    from shapeidx.families.duplicates import unit_factor

    ok, factor = unit_factor(np.array([1.0, 1.004, 25.4 * 1.003, 1 / 2.54, 1.5, 0.0121]))
    assert list(ok) == [True, True, True, True, False, False]
    assert factor[2] == pytest.approx(25.4) and factor[3] == pytest.approx(1 / 2.54) and np.isnan(factor[4])


def test_duplicates_keep_mask_leaves_out_the_other_entries(dup_store):
    from shapeidx.families.duplicates import find_duplicates

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    keep = np.array([not str(p).startswith("copies/rgb-") or str(p).endswith("rotated.stl") for p in table.paths])
    groups = find_duplicates(table, "combined-angle", keep=keep)
    members = {m for g in groups for m in g["members"]}
    assert "copies/rgb-rotated.stl" in members and not members & {"copies/rgb-copy.wrl", "copies/rgb-inches.stl"}


def test_the_graph_road_makes_as_many_clusters_as_asked_and_no_giant_one(dup_store):
    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader, ())
    for k in (3, 6, 12):
        result = cluster_store(table, "combined-angle", clusters=k, road="graph")
        assert result["count"] == k and len(set(result["clusters"])) == k
        assert np.bincount(result["clusters"]).max() <= 0.75 * len(table)
        assert (result["distances"] >= 0).all()
    again = cluster_store(table, "combined-angle", clusters=6, road="graph")
    assert np.array_equal(again["clusters"], cluster_store(table, "combined-angle", clusters=6, road="graph")["clusters"])


def test_the_stored_embedding_rows_are_those_the_counts_make_and_check_verifies_them(dup_store):
    from shapeidx.store.candidates import d2_basis, embed

    _, store = dup_store
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    assert table.d2_basis is not None and set(table.d2_basis) == {"all", "in", "out", "mixed"}
    for h, rows in table.d2_basis.items():  # independent: re-binned from the loaded probabilities
        assert np.allclose(rows, d2_basis(table.histograms[h].p, table.histograms[h].lengths), atol=1e-6)
    # an entry's vector is its own: embedding a subset gives the same rows
    keep = np.arange(len(table)) % 2 == 0
    for metric in ("combined", "combined-angle", "weighted"):
        assert np.array_equal(embed(table.subset(keep), metric), embed(table, metric)[keep])
    result = cli("check", "--store", store)
    assert result.exit_code == 0, result.output


# ---------------------------------------------------------------------------- issue 22: precise default tiers

BODIES = {"Display_7Segment": ("MAN3610A", "MAN72A"),  # one display body, other segments and pins
          "Transformer_THT": ("Transformer_CHK_EI38-3VA_1xSec", "Transformer_CHK_EI38-3VA_Neutral")}  # other pins


@pytest.fixture(scope="module")
def body_store(tmp_path_factory, data_dir):
    """kicad6's 7-segment displays and transformers (VRML), with the STEP files of two pairs of
    parts that share one body: each STEP is faceted by OpenCASCADE, not by the VRML's exporter."""
    tmp = tmp_path_factory.mktemp("bodies")
    tree = copy_tree(data_dir / "kicad6", tmp / "parts", tuple(BODIES))
    for folder, stems in BODIES.items():
        for stem in stems:
            (tree / folder / f"{stem}.step").write_bytes((data_dir / "kicad6-step" / folder / f"{stem}.step").read_bytes())
    store = tmp / "store.h5"
    result = cli("build", tree, "--store", store, "-q", "--workers", "1")
    assert result.exit_code == 0, result.output
    return tree, store


def test_default_duplicates_keep_one_body_with_other_pins_apart_and_pair_each_step_file_with_its_own_vrml(body_store):
    from shapeidx.families.duplicates import DEFAULT_TIERS, FINGERPRINT_SAME, FINGERPRINT_SURFACE, fingerprint_gap, pair_tiers

    _, store = body_store
    groups = cli_json("duplicates", "--store", store)
    assert all(p["tier"] in DEFAULT_TIERS for g in groups for p in g["pairs"])
    group_of = {m: i for i, g in enumerate(groups) for m in g["members"]}
    for folder, (one, other) in BODIES.items():
        for stem in (one, other):  # each STEP file with its own VRML (2.54 times larger: KiCad's VRML unit)
            assert group_of.get(f"{folder}/{stem}.wrl", -1) == group_of.get(f"{folder}/{stem}.step", -2), stem
        for x in (f"{folder}/{one}.wrl", f"{folder}/{one}.step"):  # never with the other part, in either format
            for y in (f"{folder}/{other}.wrl", f"{folder}/{other}.step"):
                assert group_of.get(x, -1) != group_of.get(y, -2), (x, y)
    # what keeps them apart is the exact moments: within the looser rules, beyond one surface's
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
    for folder, (one, other) in BODIES.items():
        a, b = np.array([table.index_of(f"{folder}/{one}.wrl")]), np.array([table.index_of(f"{folder}/{other}.wrl")])
        assert FINGERPRINT_SURFACE < fingerprint_gap(table, a, b)[0] <= FINGERPRINT_SAME
        assert pair_tiers(table, a, b)["tier"][0] == "similar"
    # asked for, they are one body: tier similar
    loose = cli_json("duplicates", "--store", store, "--similar")
    for folder, (one, other) in BODIES.items():
        group = next(g for g in loose if f"{folder}/{one}.wrl" in g["members"])
        assert f"{folder}/{other}.wrl" in group["members"] and group["tier"] == "similar"
        assert group["confidence"] < min(g["confidence"] for g in groups)  # below every default group


def test_converted_needs_two_formats_read_from_the_names_endings_and_a_sub_parts_from_its_files():
    import types

    from shapeidx.families.duplicates import file_formats
    from shapeidx.io.formats import SUFFIXES

    paths = ["a/b.wrl", "a/b.STEP", "c/x.stp#3", "d/y.stl.gz", "e/noext", "f/v1.2/part", "g/z.wrz#12"]
    got = list(file_formats(types.SimpleNamespace(paths=np.array(paths, dtype=object))))
    assert got == ["vrml", "step", "step", "stl", "", "", "vrml"]
    assert set(got) - {""} <= set(SUFFIXES)
