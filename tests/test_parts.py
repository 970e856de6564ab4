"""Sub-parts (``build --parts``, ``where-used``, ``query --parts``): files split into their
solids and bodies, identical ones counted once, each signed in its own frame.

Assemblies are made here by OpenCASCADE (a pin placed at random rigid motions, as XCAF
components or as transformed copies of its geometry) and written by its own STEP writers;
the counts are checked against the placements made, and against the solids a real KiCad
file declares (its MANIFOLD_SOLID_BREP entities, counted in its text).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

import shapeidx
from shapeidx.io.parts import own_frame, split_parts
from shapeidx.signing.pipeline import signature_of_file, signature_of_solid
from shapeidx.signing.solid import make_solid
from shapeidx.store import open_store
from shapeidx.store.files import main_file, parts_store

from clitools import assert_one_line_error, cli
from test_step import write_assembly, write_step

pytest.importorskip("OCP")


def _pin(length: float = 8.0):
    """An L-shaped pin (no symmetry that would leave its frame undefined)."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Fuse
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.gp import gp_Pnt

    leg = BRepPrimAPI_MakeBox(0.6, 0.6, length).Shape()
    foot = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, length - 0.6), 0.6, 3.0, 0.6).Shape()
    return BRepAlgoAPI_Fuse(leg, foot).Shape()


def _body(dx=20.0, dy=10.0, dz=5.0):
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox

    return BRepPrimAPI_MakeBox(dx, dy, dz).Shape()


def _rigid(rng):
    """A random rotation (uniform quaternion) then a random translation."""
    from OCP.gp import gp_Quaternion, gp_Trsf, gp_Vec

    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    rotation, translation = gp_Trsf(), gp_Trsf()
    rotation.SetRotation(gp_Quaternion(*q))
    translation.SetTranslation(gp_Vec(*rng.uniform(-30, 30, 3)))
    return translation.Multiplied(rotation)


def _located(shape, trsf):
    from OCP.TopLoc import TopLoc_Location

    return shape, TopLoc_Location(trsf)


def _moved_copy(shape, trsf):
    """The geometry itself transformed (a new solid, as KiCad's generators write pins)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform

    return BRepBuilderAPI_Transform(shape, trsf, True).Shape()


def _compound(shapes):
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS_Compound

    compound, builder = TopoDS_Compound(), BRep_Builder()
    builder.MakeCompound(compound)
    for shape in shapes:
        builder.Add(compound, shape)
    return compound


def _xcaf_assembly(path: Path, body, pin, pins: int, seed: int) -> Path:
    from OCP.TopLoc import TopLoc_Location

    rng = np.random.default_rng(seed)
    return write_assembly(path, [(body, TopLoc_Location())] + [_located(pin, _rigid(rng)) for _ in range(pins)])


def _baked_assembly(path: Path, body, pin, pins: int, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    return write_step(_compound([body] + [_moved_copy(pin, _rigid(rng)) for _ in range(pins)]), path)


def _solids_declared(path: Path) -> int:
    return len(re.findall(rb"MANIFOLD_SOLID_BREP\s*\(", Path(path).read_bytes()))


def _distance(a, b, metric="weighted") -> float:
    return shapeidx.compare(a, b)[metric]


class TestSplit:
    def test_xcaf_assembly_counts_the_placed_pins(self, tmp_path):
        path = _xcaf_assembly(tmp_path / "a.step", _body(), _pin(), 6, seed=1)
        parts = split_parts(path)
        assert sorted(p.count for p in parts) == [1, 6]

    def test_transformed_copies_are_found_identical(self, tmp_path):
        """Five separate solids (no instancing in the file) that are the same pin moved."""
        path = _baked_assembly(tmp_path / "b.step", _body(), _pin(), 5, seed=2)
        assert _solids_declared(path) == 6
        parts = split_parts(path)
        assert sorted(p.count for p in parts) == [1, 5]

    def test_a_different_pin_is_not_counted_with_the_others(self, tmp_path):
        rng = np.random.default_rng(3)
        shapes = [_body()] + [_moved_copy(_pin(), _rigid(rng)) for _ in range(3)] + [_moved_copy(_pin(8.4), _rigid(rng))]
        parts = split_parts(write_step(_compound(shapes), tmp_path / "c.step"))
        assert sorted(p.count for p in parts) == [1, 1, 3]

    def test_one_solid_is_one_part(self, tmp_path):
        assert split_parts(write_step(_pin(), tmp_path / "pin.step")) is None

    def test_real_kicad_file_matches_its_declared_solids(self, data_dir):
        path = data_dir / "kicad6-step" / "Transformer_THT" / "Transformer_CHK_EI54-12VA_Neutral.step"
        parts = split_parts(path)
        assert sum(p.count for p in parts) == _solids_declared(path) == 15
        assert all(p.name.startswith("Transformer_CHK_EI54_12VA_Neutral") for p in parts)  # its products' names
        assert max(p.count for p in parts) > 1  # the pins, counted
        single = data_dir / "kicad6-step" / "Battery" / "BatteryHolder_Keystone_500.step"
        assert _solids_declared(single) == 1 and split_parts(single) is None

    def test_kicad_vrml_bodies_are_the_solids_of_its_step_twin(self, data_dir):
        """Mesh connectivity of the VRML export against OpenCASCADE's solids of the STEP file."""
        name = "Transformer_THT/Transformer_CHK_EI54-12VA_Neutral"
        vrml, step = split_parts(data_dir / "kicad6" / f"{name}.wrl"), split_parts(data_dir / "kicad6-step" / f"{name}.step")
        assert sum(p.count for p in vrml) == sum(p.count for p in step) == 15
        assert sorted(p.count for p in vrml) != [1] * len(vrml)  # its pins found identical in the mesh too

    def test_mesh_bodies(self, tmp_path):
        trimesh = pytest.importorskip("trimesh")
        rng = np.random.default_rng(4)
        pieces = [trimesh.creation.box((1, 2, 5)), trimesh.creation.icosphere(2, radius=3)]
        moved = trimesh.creation.box((1, 2, 5))
        q = rng.normal(size=4)
        moved.apply_transform(trimesh.transformations.quaternion_matrix(q / np.linalg.norm(q)))
        moved.apply_translation((20, -5, 7))
        pieces.append(moved)
        path = tmp_path / "three.stl"
        trimesh.util.concatenate(pieces).export(path)
        parts = split_parts(path)
        assert sorted(p.count for p in parts) == [1, 2]
        single = tmp_path / "one.stl"
        trimesh.creation.box((1, 2, 5)).export(single)
        assert split_parts(single) is None


def _kuka_objects(path: Path) -> list[str]:
    """The objects a KUKA model declares, read from its text: each ``DEF AOBJ_... Transform``
    whose one Shape has an IndexedFaceSet (the others hold an IndexedLineSet: an axis)."""
    text = path.read_bytes().decode("latin-1")
    objects = re.findall(r"DEF\s+(AOBJ_[0-9_]+)\s+Transform\s*\{\s*children\s*\[\s*Shape\s*\{(?:(?!Shape).)*?geometry\s+(\w+)",
                         text, re.S)
    return sorted(name for name, geometry in objects if geometry == "IndexedFaceSet")


_GROUPED_VRML = """#VRML V2.0 utf8
DEF Board Transform { children [
  DEF Body Transform { children [ Shape { geometry Box { size 20 10 5 } } ] }
  DEF Pin Transform { translation 1 2 3 children [ Shape { geometry Cylinder { radius 0.3 height 4 } } ] }
  Transform { translation 5 0 0 rotation 0 1 0 0.7 children [ USE Pin ] }
  Transform { translation 9 1 0 rotation 1 1 0 2.1 children [ USE Pin ] }
  DEF Colour Group { children [ Shape { geometry IndexedFaceSet {
    coord Coordinate { point [ 0 0 0, 1 0 0, 1 2 0, 0 0 3,  10 0 0, 11 0 0, 11 2 0, 10 0 3,  0 10 0, 1 10 0, 1 12 0, 0 10 3 ] }
    coordIndex [ 0 2 1 -1 0 1 3 -1 1 2 3 -1 0 3 2 -1  4 6 5 -1 4 5 7 -1 5 6 7 -1 4 7 6 -1  8 10 9 -1 8 9 11 -1 9 10 11 -1 8 11 10 -1 ]
  } } ] }
  Shape { geometry IndexedFaceSet {
    coord Coordinate { point [ 0 0 20, 2 0 20, 2 4 20, 0 0 26,  30 0 20, 32 0 20, 32 4 20, 30 0 26 ] }
    coordIndex [ 0 2 1 -1 0 1 3 -1 1 2 3 -1 0 3 2 -1  4 6 5 -1 4 5 7 -1 5 6 7 -1 4 7 6 -1 ]
  } }
] }
"""


class TestVrmlGroups:
    """A VRML file that groups its geometry is split along its groups, then each group
    into its bodies; a flat one (KiCad) into its bodies, as before."""

    @pytest.mark.parametrize("name", ["kr16.wrl", "kr125_3.wrl", "kr500_1.wrl"])
    def test_kuka_robot_objects_are_its_parts(self, data_dir, name):
        from shapeidx.io.vrml.groups import vrml_groups

        path = data_dir / "vrml-wild" / "freecad-kuka" / name
        declared = _kuka_objects(path)
        assert len(declared) >= 20
        assert sorted(n for n, _ in vrml_groups(path)) == declared
        parts = split_parts(path)
        assert {p.name for p in parts} <= set(declared)
        assert sum(p.count for p in parts) >= len(declared)  # an object may hold several bodies

    def test_a_moved_robot_gives_the_same_parts(self, data_dir, tmp_path):
        """Placement invariance: the whole file under one more Transform (a rotation and a
        translation) gives the same parts, each at the same distances from its own origin
        (the vertices themselves where the part's principal axes are defined: a part with an
        axis of symmetry may turn about it)."""
        path = data_dir / "vrml-wild" / "freecad-kuka" / "kr16.wrl"
        body = path.read_text(encoding="latin-1").split("\n", 1)[1]
        moved = tmp_path / "moved.wrl"
        moved.write_text("#VRML V2.0 utf8\nTransform { rotation 0.3 -0.5 0.8 1.1 translation 250 -40 900 children [\n"
                         + body + "\n] }\n", encoding="latin-1")
        a, b = split_parts(path), split_parts(moved)
        assert [(p.name, p.count) for p in a] == [(p.name, p.count) for p in b]
        turned = 0
        for p, q in zip(a, b):
            extent = np.ptp(p.mesh.vertices, axis=0).max()
            norms = [np.linalg.norm(m.mesh.vertices, axis=1) for m in (p, q)]
            np.testing.assert_allclose(norms[0], norms[1], atol=1e-6 * extent)
            spread = np.sort(np.linalg.eigvalsh(np.cov(p.mesh.vertices.T)))
            if np.min(np.diff(spread)) > 0.01 * spread[-1]:
                np.testing.assert_allclose(p.mesh.vertices, q.mesh.vertices, atol=1e-6 * extent)
            else:
                turned += 1
        assert turned < len(a)  # some parts compared vertex by vertex

    def test_groups_then_bodies_with_def_names(self, tmp_path):
        path = tmp_path / "board.wrl"
        path.write_text(_GROUPED_VRML)
        parts = split_parts(path)
        # the pin defined once and USEd twice more; the colour group's three tetrahedra;
        # the two tetrahedra loose in the top group: a body each, named after that group
        assert sorted((p.name, p.count) for p in parts) == [("Board", 2), ("Body", 1), ("Colour", 3), ("Pin", 3)]
        assert all(p.mesh.metadata["title"] == p.name for p in parts)

    def test_kicad_flat_file_is_split_into_bodies_as_before(self, data_dir, monkeypatch):
        from shapeidx.io import load
        from shapeidx.io.parts import _mesh_parts
        from shapeidx.io.vrml import fast
        from shapeidx.io.vrml.groups import vrml_groups

        path = data_dir / "kicad6" / "Transformer_THT" / "Transformer_CHK_EI54-12VA_Neutral.wrl"
        assert vrml_groups(path) is None
        parts, bodies = split_parts(path), _mesh_parts(load(path))
        assert [(p.name, p.count) for p in parts] == [("", p.count) for p in bodies]
        for p, q in zip(parts, bodies):
            np.testing.assert_array_equal(p.mesh.vertices, q.mesh.vertices)
        monkeypatch.setattr(fast, "available", False)  # the Python reader sees no group either
        assert vrml_groups(path) is None


class TestOwnFrame:
    def test_own_frame_undoes_a_rigid_motion(self):
        trimesh = pytest.importorskip("trimesh")
        mesh = trimesh.creation.cylinder(radius=1, height=4, sections=24)
        mesh = trimesh.util.concatenate([mesh, trimesh.creation.box((3, 1, 0.5))])  # not symmetric
        mesh.apply_translation((0.3, 2.0, 1.1))
        rng = np.random.default_rng(5)
        q = rng.normal(size=4)
        matrix = trimesh.transformations.quaternion_matrix(q / np.linalg.norm(q))
        matrix[:3, 3] = (10, -4, 2)
        moved = trimesh.transformations.transform_points(mesh.vertices, matrix)
        a = own_frame(mesh.vertices, mesh.faces)
        b = own_frame(moved, mesh.faces)
        np.testing.assert_allclose(a, b, atol=1e-9)

    def test_the_same_pin_signs_the_same_anywhere(self, tmp_path):
        """The pin taken out of two assemblies (placed at random, instanced and copied) and
        the pin written alone: all within rounding of each other, farther from a 5% longer
        pin and far from the body."""
        body, pin = _body(), _pin()
        signatures = {}
        for name, make in (("xcaf", _xcaf_assembly), ("baked", _baked_assembly)):
            parts = split_parts(make(tmp_path / f"{name}.step", body, pin, 4, seed=len(name)))
            (pin_part,) = [p for p in parts if p.count == 4]
            (body_part,) = [p for p in parts if p.count == 1]
            signatures[name] = signature_of_solid(make_solid(pin_part.mesh))
            signatures[f"{name} body"] = signature_of_solid(make_solid(body_part.mesh))
        signatures["alone"] = signature_of_file(write_step(pin, tmp_path / "pin.step"))
        signatures["longer"] = signature_of_file(write_step(_pin(8.4), tmp_path / "longer.step"))
        same = [_distance(signatures[a], signatures[b]) for a, b in (("xcaf", "baked"), ("xcaf", "alone"), ("baked", "alone"))]
        other = min(_distance(signatures[a], signatures["longer"]) for a in ("xcaf", "baked", "alone"))
        body = min(_distance(signatures[a], signatures[f"{b} body"]) for a in ("xcaf", "baked", "alone") for b in ("xcaf", "baked"))
        assert max(same) < other < body
        assert max(same) < 0.2 * body


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """Two assemblies using the same pin (4 and 6 times), one using another pin, and a part
    without pins; the pin alone as a query from outside the tree."""
    root = tmp_path_factory.mktemp("library")
    (root / "boards").mkdir()
    pin, other_pin = _pin(), _pin(14.0)
    _baked_assembly(root / "boards" / "four.step", _body(), pin, 4, seed=11)
    _xcaf_assembly(root / "boards" / "six.step", _body(30, 8, 6), pin, 6, seed=12)
    _baked_assembly(root / "boards" / "other.step", _body(16, 16, 4), other_pin, 3, seed=13)
    write_step(_body(12, 12, 12), root / "cube.step")
    query = write_step(_moved_copy(pin, _rigid(np.random.default_rng(14))), root.parent / "pin-query.step")
    return root, query


def _build(root, store, *more):
    result = cli("build", root, "--store", store, "--workers", "1", "-q", *more)
    assert result.exit_code == 0, result.output + result.stderr
    return result


class TestBuildAndWhereUsed:
    def test_where_used_finds_the_assemblies_of_the_pin(self, library, tmp_path):
        root, query = library
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        result = cli("where-used", query, "--store", store, "--top", "2", "--json")
        assert result.exit_code == 0, result.output
        answer = json.loads(result.stdout)
        uses = {u["relative_path"]: u["count"] for u in answer["uses"]}
        assert uses == {"boards/four.step": 4, "boards/six.step": 6}
        assert all(u["part"].startswith(u["relative_path"] + "#") for u in answer["uses"])
        # same size only (the default): the other pin and the cube are other sizes; any size: every file
        sized = json.loads(cli("where-used", query, "--store", store, "--json").stdout)
        assert {u["relative_path"] for u in sized["uses"]} == {"boards/four.step", "boards/six.step"}
        anysize = json.loads(cli("where-used", query, "--store", store, "--scale", "invariant", "--json").stdout)
        assert {u["relative_path"] for u in anysize["uses"]} == {"boards/four.step", "boards/six.step",
                                                                  "boards/other.step", "cube.step"}
        assert [u["relative_path"] for u in anysize["uses"][:2]] == [u["relative_path"] for u in sized["uses"]]
        # by an entry: the pin of six.step finds four.step at once
        part = [u["part"] for u in answer["uses"] if u["relative_path"] == "boards/six.step"][0]
        csv = cli("where-used", "--id", part, "--store", store, "--top", "2", "--format", "csv")
        assert csv.exit_code == 0, csv.output
        assert {line.split(",")[4] for line in csv.stdout.splitlines()[1:]} == {"boards/four.step", "boards/six.step"}
        # stats counts them: a body and its pin in each board (the pin once, as often as placed), the cube
        facts = json.loads(cli("stats", "--store", store, "--json").stdout)["parts"]
        assert facts == {"entries": 7, "files": 4, "several": 3, "instances": 1 + 4 + 1 + 6 + 1 + 3 + 1}
        assert "sub-parts   7 entries (17 counted as the files hold them) of 4 files, 3 with several" in cli(
            "stats", "--store", store).stdout

    def test_where_used_of_the_wrong_store_says_which_to_give_in_one_line(self, library, tmp_path):
        """A store built without --parts: build it with --parts; the sub-parts store STORE/parts
        given for STORE (its own sub-parts would be STORE/parts/parts): give --store STORE."""
        root, query = library
        plain, store = tmp_path / "plain.shapeidx", tmp_path / "s.shapeidx"
        _build(root, plain)
        _build(root, store, "--parts")
        for asked in ((query,), ("--id", "boards/six.step")):
            without = cli("where-used", *asked, "--store", plain)
            assert_one_line_error(without, plain)
            assert f"has no sub-parts: build it with 'shapeidx build DIR --store {plain} --parts'" in without.stderr
            inside = cli("where-used", *asked, "--store", parts_store(store))
            assert_one_line_error(inside, parts_store(store))
            assert f"is the sub-parts store of {store}: give --store {store}" in inside.stderr
            assert cli("where-used", *asked, "--store", store, "--scale", "invariant").exit_code == 0
        ranked = cli("query", query, "--parts", "--store", parts_store(store))
        assert_one_line_error(ranked, parts_store(store))
        assert f"give --store {store}" in ranked.stderr
        as_files = cli("query", query, "--store", parts_store(store))  # sub-parts would read as whole files
        assert_one_line_error(as_files, parts_store(store))
        assert f"is the sub-parts store of {store}: give --store {store} --parts" in as_files.stderr

    def test_query_ranks_files_by_default_and_sub_parts_with_parts(self, library, tmp_path):
        root, query = library
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        whole = json.loads(cli("query", query, "--store", store, "--top", "10", "--json").stdout)
        assert {h["relative_path"] for h in whole["hits"]} == {"boards/four.step", "boards/six.step",
                                                               "boards/other.step", "cube.step"}
        assert all("parent" not in h for h in whole["hits"])
        parts = json.loads(cli("query", query, "--store", store, "--top", "2", "--parts", "--json").stdout)
        assert {h["parent"] for h in parts["hits"]} == {"boards/four.step", "boards/six.step"}
        for hit in parts["hits"]:
            assert hit["relative_path"].startswith(hit["parent"] + "#")
            assert hit["path"] == str(root / hit["parent"])
            assert hit["count"] == {"boards/four.step": 4, "boards/six.step": 6}[hit["parent"]]
        api = shapeidx.query(store, str(query), top=2, parts=True)  # the Python API: the same hits
        assert [(h["relative_path"], h["parent"], h["count"]) for h in api] == [
            (h["relative_path"], h["parent"], h["count"]) for h in parts["hits"]]
        with open_store(parts_store(store)) as reader:  # a file that is one part is its own FILE#1
            assert "cube.step#1" in set(reader.paths)

    def test_whole_file_entries_do_not_change_with_parts(self, library, tmp_path):
        root, _ = library
        plain, with_parts = tmp_path / "plain.shapeidx", tmp_path / "parts.shapeidx"
        _build(root, plain)
        _build(root, with_parts, "--parts")
        with open_store(plain) as a, open_store(with_parts) as b:
            assert list(a.paths) == list(b.paths)
            for i in range(len(a)):
                for name in ("all", "in", "out", "mixed"):
                    assert np.array_equal(a.signature(i).histograms[name].counts, b.signature(i).histograms[name].counts)

    def test_incremental(self, library, tmp_path):
        root, _ = tmp_path / "tree", None
        shutil.copytree(library[0], root)
        store = tmp_path / "s.shapeidx"
        _build(root, store)  # without parts first: a later --parts signs only the sub-parts
        with open_store(store) as reader:
            before = reader.column("entries/mtime_ns").copy(), reader.column("entries/hash").copy()
        summary = json.loads(_build(root, store, "--parts", "--json").stdout)
        assert summary["indexed"] == 0 and summary["parts"]["entries"] >= 4 + 3
        with open_store(store) as reader:
            assert np.array_equal(reader.column("entries/hash"), before[1])
        again = json.loads(_build(root, store, "--parts", "--json").stdout)
        assert again["indexed"] == 0 and again["parts"]["indexed"] == 0
        (root / "boards" / "six.step").unlink()
        _build(root, store, "--parts")
        with open_store(parts_store(store)) as reader:
            assert not [p for p in reader.paths if p.startswith("boards/six.step")]
            assert [p for p in reader.paths if p.startswith("boards/four.step#")]

    def test_a_build_without_parts_leaves_no_sub_part_of_a_file_gone_or_changed(self, library, tmp_path):
        """A nightly build without --parts over a store built with it: where-used, duplicates
        --parts and stats never name a file the store no longer holds, nor the sub-parts of
        a file's old content (it named both); a file whose times alone changed keeps its
        sub-parts, and the next --parts build makes only the changed file's again."""
        root = tmp_path / "tree"
        shutil.copytree(library[0], root)
        query = library[1]
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        (root / "boards" / "six.step").unlink()
        four = root / "boards" / "four.step"
        four.write_bytes(four.read_bytes() + b"\n")  # its content changed: signed again
        cube = root / "cube.step"
        os.utime(cube, ns=(cube.stat().st_atime_ns, cube.stat().st_mtime_ns + 10**9))  # its times only
        done = cli("build", root, "--store", store, "--workers", "1")
        assert done.exit_code == 0, done.output + done.stderr
        anysize = json.loads(cli("where-used", query, "--store", store, "--scale", "invariant", "--json").stdout)
        assert {u["relative_path"] for u in anysize["uses"]} == {"boards/other.step", "cube.step"}
        with open_store(parts_store(store)) as reader:
            assert {str(p) for p in reader.column("entries/parent")} == {"boards/other.step", "cube.step"}
        assert json.loads(cli("stats", "--store", store, "--json").stdout)["parts"]["files"] == 2
        shared = json.loads(cli("duplicates", "--parts", "--store", store, "--json").stdout)
        assert not [g for g in shared if "boards/six.step" in g["files"]]
        assert "1 removed, 0 failed" in done.stdout and "parts: 0 signed, 4 removed, 3 in the store" in done.stdout
        again = json.loads(_build(root, store, "--parts", "--json").stdout)
        assert again["parts"]["planned"] == 1 and again["parts"]["removed"] == 0  # four.step's, made again
        uses = json.loads(cli("where-used", query, "--store", store, "--top", "2", "--json").stdout)["uses"]
        assert {u["relative_path"]: u["count"] for u in uses} == {"boards/four.step": 4}
        # every file signed again, none changed (--full; a newer reader does the same): all sub-parts stand
        full = json.loads(_build(root, store, "--full", "--json").stdout)
        assert full["indexed"] == 3 and full["parts"]["removed"] == 0 and full["parts"]["entries"] == 5
        assert json.loads(_build(root, store, "--parts", "--json").stdout)["parts"]["planned"] == 0

    def test_a_sharded_build_without_parts_counts_every_shards_sub_parts(self, library, tmp_path):
        """The summary of a build without --parts over sharded sub-parts adds up every shard's
        (it counted only the shards where sub-entries were removed)."""
        root = tmp_path / "tree"
        shutil.copytree(library[0], root)
        store = tmp_path / "s.shapeidx"
        made = json.loads(_build(root, store, "--shards", "2", "--parts", "--json").stdout)["parts"]
        assert made["entries"] == 7
        (root / "boards" / "six.step").unlink()
        done = json.loads(_build(root, store, "--json").stdout)["parts"]
        assert done["removed"] == 2 and done["entries"] == 5
        again = json.loads(_build(root, store, "--json").stdout)["parts"]
        assert again["removed"] == 0 and again["entries"] == 5

    def test_a_build_without_parts_killed_between_its_two_commits(self, library, tmp_path):
        """A build without --parts commits a file's whole entry and the removal of its old
        sub-entries one after the other; killed in between (made here by putting the parts
        store back as it was before the build), the next build without --parts still removes
        the sub-parts of the file's old content (it left them: the file had no work left), and
        gives those of a file whose times alone changed the new times."""
        root = tmp_path / "tree"
        shutil.copytree(library[0], root)
        query = library[1]
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        four = root / "boards" / "four.step"
        four.write_bytes(four.read_bytes() + b"\n")
        cube = root / "cube.step"
        os.utime(cube, ns=(cube.stat().st_atime_ns, cube.stat().st_mtime_ns + 10**9))
        before = tmp_path / "parts-before"
        shutil.copytree(parts_store(store), before)
        _build(root, store)
        shutil.rmtree(parts_store(store))
        shutil.copytree(before, parts_store(store))
        _build(root, store)
        anysize = json.loads(cli("where-used", query, "--store", store, "--scale", "invariant", "--json").stdout)
        assert {u["relative_path"] for u in anysize["uses"]} == {"boards/six.step", "boards/other.step", "cube.step"}
        planned = json.loads(_build(root, store, "--parts", "--json").stdout)["parts"]
        assert planned["planned"] == 1 and planned["entries"] == 7  # four.step's made again; the cube's kept

    def test_dry_run_plans_the_sub_parts(self, library, tmp_path):
        """``--parts --dry-run`` says what the build with ``--parts`` then does, and writes nothing."""
        root = tmp_path / "tree"
        shutil.copytree(library[0], root)
        store = tmp_path / "s.shapeidx"
        _build(root, store)

        def dry():
            return json.loads(_build(root, store, "--parts", "--dry-run", "--json").stdout)

        def contents():
            return sorted((p.relative_to(store), p.stat().st_size, p.stat().st_mtime_ns)
                          for p in store.rglob("*") if p.is_file())

        before = contents()
        planned = dry()
        assert contents() == before and not parts_store(store).exists()
        assert planned["planned"] == 0
        assert planned["parts"] == {"indexed": 0, "entries": 0, "planned": 4, "removed": 0}
        words = _build(root, store, "--parts", "--dry-run").stdout
        assert "sub-parts: make those of 4 files, remove 0 sub-entries (dry run" in words
        done = json.loads(_build(root, store, "--parts", "--json").stdout)
        assert done["parts"]["planned"] == 4 and done["parts"]["entries"] == 7
        assert dry()["parts"] == {"indexed": 0, "entries": 7, "planned": 0, "removed": 0}
        (root / "boards" / "six.step").unlink()  # its body and its pin go
        assert dry()["parts"] == {"indexed": 0, "entries": 7, "planned": 0, "removed": 2}
        assert json.loads(_build(root, store, "--parts", "--json").stdout)["parts"]["removed"] == 2

    def test_damaged_sub_parts_are_checked_and_repaired_through_their_store(self, library, tmp_path):
        """``check`` finds damage in STORE/parts; every message says to repair it with
        ``build --store STORE --parts --repair``, and a build into STORE/parts itself (which would
        fill it with whole files) is refused."""
        from test_store_check import flip_chunk

        root, _ = library
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        sound = cli("check", "--store", store)
        assert sound.exit_code == 0 and "sub-parts ok: 7 entries" in sound.stdout
        flip_chunk(parts_store(store), "histograms/all/counts", 0)
        with open_store(parts_store(store)) as reader:
            part = str(reader.paths[0])
        report = cli("check", "--store", store, "--json")
        assert report.exit_code == 5
        answer = json.loads(report.stdout)
        assert not answer["ok"] and answer["parts"]["entries"] == 7
        assert {p["file"] for p in answer["problems"]} == {"parts/main.h5"}
        words = cli("check", "--store", store)
        assert f"'shapeidx build DIR --store {store} --parts --repair'" in words.stdout
        refused = cli("where-used", "--id", part, "--store", store)
        assert_one_line_error(refused, store, status=5)
        assert f"'shapeidx build {root} --store {store} --parts --repair'" in refused.stderr
        assert f"'shapeidx check --store {store}'" in refused.stderr
        into_parts = cli("build", root, "--store", parts_store(store))
        assert_one_line_error(into_parts, parts_store(store), status=2)
        assert f"--store {store} --parts" in into_parts.stderr
        _build(root, store, "--parts", "--repair")
        assert cli("check", "--store", store).exit_code == 0
        assert cli("where-used", "--id", part, "--store", store).exit_code == 0

    def test_a_first_parts_build_killed_before_committing_anything(self, library, tmp_path):
        """A first ``build --parts`` killed between making STORE/parts and writing its first
        main file leaves the folder and its lock, nothing else (made here by hand: the window
        is too short for a timed kill). stats and the web page answer as without sub-parts
        (both refused: 'being created'), the sub-part commands say the build stopped and how to
        build it (they said 'a first build has just begun... try again in a moment', forever),
        and while a build holds the lock they still say it is being created."""
        from shapeidx.store.lock import StoreLock
        from shapeidx.web.app import StoreService

        root, query = library
        store = tmp_path / "s.shapeidx"
        _build(root, store)
        parts_store(store).mkdir()
        (parts_store(store) / "lock").touch()
        stats = cli("stats", "--store", store, "--json")
        assert stats.exit_code == 0, stats.output + stats.stderr
        assert json.loads(stats.stdout)["parts"] is None
        service = StoreService(store)
        try:
            assert service.info()["parts"] is False
        finally:
            service.close()
        for args in (("where-used", query), ("query", query, "--parts"), ("duplicates", "--parts")):
            result = cli(*args, "--store", store)
            assert_one_line_error(result, store, status=6)
            assert "its first build stopped before committing anything" in result.stderr
            assert f"'shapeidx build DIR --store {store} --parts' builds it" in result.stderr
        lock = StoreLock(parts_store(store))
        lock.acquire()
        try:
            assert "try again in a moment" in cli("where-used", query, "--store", store).stderr
        finally:
            lock.release()
        assert cli("check", "--store", store).exit_code == 0
        _build(root, store, "--parts")
        assert json.loads(cli("stats", "--store", store, "--json").stdout)["parts"]["files"] == 4

    def test_a_parts_store_of_other_parameters_is_refused_with_the_way_out(self, library, tmp_path):
        """STORE/parts of other signature parameters than STORE (the store rebuilt beside it):
        a build with --parts is refused in one line that says to delete STORE/parts, whose
        parameters follow the store's (it said 'use another --store')."""
        root, _ = library
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts", "--points", "256")
        kept = parts_store(store).rename(tmp_path / "kept-parts")
        shutil.rmtree(store)
        _build(root, store, "--points", "512")
        kept.rename(parts_store(store))
        refused = cli("build", root, "--store", store, "--parts", "--workers", "1")
        assert_one_line_error(refused, parts_store(store))
        assert "another --store" not in refused.stderr
        assert f"delete {parts_store(store)} and 'shapeidx build {root} --store {store} --parts' makes it again" in refused.stderr
        shutil.rmtree(parts_store(store))
        _build(root, store, "--parts")
        assert json.loads(cli("stats", "--store", store, "--json").stdout)["parts"]["files"] == 4

    def test_store_without_parts(self, library, tmp_path):
        root, query = library
        store = tmp_path / "s.shapeidx"
        _build(root, store)
        assert json.loads(cli("stats", "--store", store, "--json").stdout)["parts"] is None
        for args in (("where-used", query), ("query", query, "--parts")):
            result = cli(*args, "--store", store)
            assert_one_line_error(result, store)
            assert "--parts" in result.stderr
        # the parts store named itself: how to make it (it said 'build DIR --store S/parts', which is refused)
        alone = cli("stats", "--store", parts_store(store))
        assert_one_line_error(alone, parts_store(store))
        assert f"'shapeidx build DIR --store {store} --parts'" in alone.stderr

    def test_a_main_file_without_the_new_columns_still_opens(self, library, tmp_path):
        """A store written before sub-parts lacks entries/parent and entries/count: read as "" and 1."""
        root, query = library
        store = tmp_path / "s.shapeidx"
        _build(root, store)
        with h5py.File(main_file(store), "r+") as f:
            del f["entries/parent"], f["entries/count"]
        with open_store(store) as reader:
            assert set(reader.column("entries/parent")) == {""}
            assert set(reader.column("entries/count")) == {1}
        result = cli("query", query, "--store", store, "--top", "1")
        assert result.exit_code == 0, result.output
        assert "boards/" in result.stdout

    def test_duplicates_parts_reports_the_pin_shared_by_two_files(self, library, tmp_path):
        root, _ = library
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        result = cli("duplicates", "--parts", "--store", store, "--json")
        assert result.exit_code == 0, result.output
        groups = json.loads(result.stdout)
        shared = [g for g in groups if g["files"] == ["boards/four.step", "boards/six.step"]]
        assert len(shared) == 1 and len(shared[0]["members"]) == 2  # the pin, once per file
        assert all(len(g["files"]) > 1 for g in groups)
        # the whole-file duplicates are not changed by the sub-parts
        assert json.loads(cli("duplicates", "--store", store, "--json").stdout) == []

    def test_duplicates_parts_leaves_whole_file_duplicates_to_duplicates(self, library, tmp_path):
        """Two files that are each one part (a copy of the cube) are a whole-file duplicate, not a
        shared sub-part; the pin alone as a file of its own is the assemblies' pin, shared."""
        root = tmp_path / "tree"
        shutil.copytree(library[0], root)
        shutil.copy(root / "cube.step", root / "cube-copy.step")
        shutil.copy(library[1], root / "pin.step")
        store = tmp_path / "s.shapeidx"
        _build(root, store, "--parts")
        groups = json.loads(cli("duplicates", "--parts", "--store", store, "--json").stdout)
        assert sorted(g["files"] for g in groups) == [["boards/four.step", "boards/six.step", "pin.step"]]
        whole = json.loads(cli("duplicates", "--store", store, "--json").stdout)
        assert [sorted(g["members"]) for g in whole] == [["cube-copy.step", "cube.step"]]


def test_a_failing_split_costs_the_sub_parts_only(library, tmp_path, monkeypatch):
    """An unforeseen error while splitting a file: its sub-entries are one failed entry with
    the reason in words; its whole entry is signed and the build goes on."""
    from shapeidx.index.workers import Task, index_file
    from shapeidx.store import StoreParams
    from shapeidx.signing.parameters import BIN_DIVISOR, SIGNATURE_VERSION
    import shapeidx.io.parts

    root, _ = library
    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(shapeidx.io.parts, "split_parts", broken)
    params = StoreParams(points=256, seed=1, bin_divisor=BIN_DIVISOR, signature_version=SIGNATURE_VERSION)
    path = "boards/four.step"
    outcome = index_file(Task(path, str(root / path), parts=True), params, str(root))
    assert outcome.kind == "indexed" and outcome.entry.status == 0
    (failed,) = outcome.parts
    assert failed.status == 1 and failed.path == failed.parent == path
    assert "split" in failed.reason and "Traceback" not in failed.reason


@pytest.fixture(scope="module")
def store(library, tmp_path_factory):
    """The library built with --parts, once for the sheet and web tests."""
    store = tmp_path_factory.mktemp("sheets") / "s.shapeidx"
    _build(library[0], store, "--parts")
    return store


def _png_pixels(data: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"))


def _overlap(a: bytes, b: bytes) -> float:
    """Intersection over union of two pictures' silhouettes (alpha > 127)."""
    a, b = (_png_pixels(x)[..., 3] > 127 for x in (a, b))
    return float((a & b).sum() / max((a | b).sum(), 1))


def _sheet_pictures(text: str) -> dict:
    """{card's data-path: (its picture, its whole file's small picture or None)} of a sheet."""
    import base64

    found = {}
    for card in re.findall(r'<article class="hit".*?</article>', text, re.S):
        path = re.search(r'data-path="([^"]+)"', card).group(1)
        images = dict((kind, base64.b64decode(src.split(",", 1)[1]))
                      for kind, src in re.findall(r'<img class="(thumb|context-thumb)" src="([^"]+)"', card))
        found[path] = (images.get("thumb"), images.get("context-thumb"))
    return found


def _own_frame_picture(path: Path) -> bytes:
    """A part file drawn in its own frame, without the split: what its sub-part's picture
    should be when the part lies inside an assembly."""
    from shapeidx.pictures.render import png_bytes, render_rgba
    from shapeidx.signing.part import load_part

    solid = load_part(path)
    return png_bytes(render_rgba(own_frame(solid.vertices, solid.faces), solid.faces))


class TestSheetsAndWeb:
    """Sub-parts on the surfaces that draw answers: the sheet and the web page name each hit's
    parent file and count, the very ones ``query --parts --json`` gives, and draw each
    sub-part itself (in its own frame) with its whole file small beside it."""

    def test_sheet_shows_the_parent_and_count_of_each_hit(self, library, store, tmp_path):
        from html.parser import HTMLParser

        root, query = library
        sheet = tmp_path / "out.html"
        result = cli("query", query, "--store", store, "--parts", "--top", "3", "--sheet", sheet, "--json")
        assert result.exit_code == 0, result.output + result.stderr
        hits = json.loads(result.stdout)["hits"]

        class Cards(HTMLParser):  # each card's sub-part line, read from the HTML
            def __init__(self):
                super().__init__()
                self.cards, self.inside = [], False

            def handle_starttag(self, tag, attrs):
                attrs = dict(attrs)
                if tag == "article":
                    self.cards.append({"path": attrs["data-path"], "line": "", "img": False})
                if tag == "div" and attrs.get("class") == "subpart":
                    self.inside = True
                if tag == "img" and self.cards:
                    self.cards[-1]["img"] = True

            def handle_endtag(self, tag):
                if tag == "div":
                    self.inside = False

            def handle_data(self, data):
                if self.inside:
                    self.cards[-1]["line"] += data

        cards = Cards()
        cards.feed(sheet.read_text())
        assert [c["path"] for c in cards.cards] == [h["relative_path"] for h in hits]
        for card, hit in zip(cards.cards, hits):
            times = "once" if hit["count"] == 1 else f"{hit['count']} times"
            assert f"in {hit['parent']}, {times}" in card["line"]
            assert card["img"]
        # each sub-part drawn itself: the pin of six.step (XCAF instances) and of four.step
        # (moved copies) give one picture, the pin written alone put in its own frame too;
        # the whole file small beside it, except for a file that is one part
        full = tmp_path / "all.html"
        assert cli("query", query, "--store", store, "--parts", "--top", "9", "--sheet", full).exit_code == 0
        pictures = _sheet_pictures(full.read_text())
        pin = [p for p, h in zip(pictures, hits) if h["parent"] in ("boards/six.step", "boards/four.step")][:2]
        (six, six_file), (four, four_file) = pictures[pin[0]], pictures[pin[1]]
        assert _overlap(six, four) > 0.98 and _overlap(six, _own_frame_picture(query)) > 0.95
        bodies = [pictures[p][0] for p in pictures if p.endswith("#1")]
        assert len(bodies) == 4 and max(_overlap(six, body) for body in bodies) < 0.8
        assert six_file is not None and four_file is not None and _overlap(six_file, four_file) < 0.9
        assert _overlap(six, six_file) < 0.8  # the pin, not the board holding it
        assert pictures["cube.step#1"][1] is None  # one part: its picture is the file's
        # the query an entry FILE#n: its picture is its file's too, and the header names its file
        entry = hits[0]["relative_path"]
        again = cli("query", "--id", entry, "--store", store, "--parts", "--top", "2", "--sheet", sheet)
        assert again.exit_code == 0, again.output + again.stderr
        assert f"a sub-part of <b>{hits[0]['parent']}</b>" in sheet.read_text()
        assert "no picture" not in sheet.read_text()
        header = re.search(r"<header>.*?</header>", sheet.read_text(), re.S).group(0)
        assert 'class="context-thumb"' in header  # the query sub-part drawn itself, its file beside it

    def test_where_used_sheet_shows_each_file_its_sub_part_and_count(self, library, store, tmp_path):
        root, query = library
        sheet = tmp_path / "uses.html"
        result = cli("where-used", query, "--store", store, "--scale", "invariant", "--sheet", sheet, "--json")
        assert result.exit_code == 0, result.output + result.stderr
        uses = json.loads(result.stdout)["uses"]
        text = sheet.read_text()
        cards = re.findall(r'<article class="hit".*?</article>', text, re.S)
        assert len(cards) == len(uses) == 4
        for card, use in zip(cards, uses):
            times = "once" if use["count"] == 1 else f"{use['count']} times"
            assert f'data-path="{use["part"]}"' in card
            assert f'in <b class="parent">{use["relative_path"]}</b>, {times}' in card
            assert 'class="thumb"' in card  # the sub-part's picture
        pictures = _sheet_pictures(text)
        pins = [pictures[use["part"]][0] for use in uses if use["relative_path"] != "cube.step"][:2]
        assert _overlap(*pins) > 0.98  # the same pin, drawn the same from two assemblies
        missing = cli("where-used", query, "--store", store, "--sheet", tmp_path / "no" / "uses.html")
        assert_one_line_error(missing, tmp_path / "no")

    def test_web_api_ranks_sub_parts_with_parts_1(self, library, store, tmp_path):
        import warnings

        pytest.importorskip("starlette")
        pytest.importorskip("httpx")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from starlette.testclient import TestClient
        from shapeidx.web.app import StoreService, create_app

        root, query = library
        cli_hits = json.loads(cli("query", query, "--store", store, "--parts", "--top", "4", "--json").stdout)["hits"]
        service = StoreService(store)
        try:
            client = TestClient(create_app(service), base_url="http://127.0.0.1:8765")
            info = client.get("/api/store").json()
            assert info["parts"] is True and info["sub_parts"] > info["ok"]
            with open(query, "rb") as f:
                data = f.read()
            answer = client.post("/api/query", files={"file": (query.name, data)}, data={"top": "4", "parts": "1"})
            assert answer.status_code == 200, answer.text
            hits = answer.json()["hits"]
            keys = ("relative_path", "parent", "count", "path")
            assert [tuple(h[k] for k in keys) for h in hits] == [tuple(h[k] for k in keys) for h in cli_hits]
            assert [h["distance"] for h in hits] == pytest.approx([h["distance"] for h in cli_hits], rel=1e-9)
            # a hit's picture is the sub-part's own; its whole file's is beside it
            picture = client.get(hits[0]["thumbnail"])
            assert picture.status_code == 200 and picture.content[:4] == b"\x89PNG"
            by_sub_id = client.get("/api/thumbnail", params={"id": hits[0]["id"]})
            assert by_sub_id.status_code == 200 and by_sub_id.content == picture.content
            whole = client.get(hits[0]["parent_thumbnail"])
            assert whole.status_code == 200 and _overlap(picture.content, whole.content) < 0.8
            pins = [client.get(h["thumbnail"]).content for h in hits if h["parent"] in ("boards/six.step", "boards/four.step")][:2]
            assert len(pins) == 2 and _overlap(*pins) > 0.98 and _overlap(pins[0], _own_frame_picture(query)) > 0.95
            # by a sub-part's id: it first, with its parent; without parts=1 the files are ranked
            by_id = client.get("/api/query", params={"id": hits[0]["id"], "parts": "1", "top": "3"}).json()
            assert by_id["hits"][0]["id"] == hits[0]["id"] and by_id["hits"][0]["distance"] == 0
            assert by_id["query"]["parent"] == hits[0]["parent"]
            files = client.get("/api/query", params={"id": hits[0]["id"], "top": "3"}).json()
            assert all("parent" not in h and "#" not in h["id"] for h in files["hits"])
            assert client.get("/api/query", params={"id": "cube.step", "parts": "maybe"}).status_code == 400
            # where used: the files of `shapeidx where-used`, each once, with its sub-part and count
            cli_uses = json.loads(cli("where-used", query, "--store", store, "--metric", "weighted", "--json").stdout)["uses"]
            with open(query, "rb") as f:
                used = client.post("/api/query", files={"file": (query.name, f.read())},
                                   data={"uses": "1", "metric": "weighted"})
            assert used.status_code == 200, used.text
            assert used.json()["uses"] is True
            assert [(h["parent"], h["id"], h["count"]) for h in used.json()["hits"]] == [
                (u["relative_path"], u["part"], u["count"]) for u in cli_uses]
            # no metric given: where used's own default, as the command's (not query's Weighted)
            cli_default = json.loads(cli("where-used", query, "--store", store, "--json").stdout)
            with open(query, "rb") as f:
                default = client.post("/api/query", files={"file": (query.name, f.read())}, data={"uses": "1"}).json()
            assert default["metric"] == cli_default["metric"] == "all-angle"
            assert [(h["parent"], h["id"], h["count"]) for h in default["hits"]] == [
                (u["relative_path"], u["part"], u["count"]) for u in cli_default["uses"]]
            # a whole file's id is asked as the command's --id is, the same-size test included: a
            # file of one part as its one sub-part, a file of several parts whole
            for entry in ("cube.step", "boards/other.step", "boards/four.step"):
                by_cli = cli("where-used", "--id", entry, "--store", store, "--json")
                by_web = client.get("/api/query", params={"id": entry, "uses": "1"}).json()
                expected = json.loads(by_cli.stdout)["uses"] if by_cli.exit_code == 0 else []
                assert [(h["parent"], h["id"], h["count"]) for h in by_web["hits"]] == [
                    (u["relative_path"], u["part"], u["count"]) for u in expected], entry
                assert (by_web["reason"] is None) == (by_cli.exit_code == 0), entry
            cube = client.get("/api/query", params={"id": "cube.step", "uses": "1"}).json()
            assert [h["id"] for h in cube["hits"]] == ["cube.step#1"]  # no other body has its size
            whole = json.loads(cli("where-used", "--id", "boards/other.step", "--store", store, "--scale", "invariant",
                                   "--json").stdout)
            assert whole["entry"] == "boards/other.step"  # asked whole, not as its body (#1)
            assert client.get("/api/query", params={"id": "cube.step", "uses": "1", "parts": "maybe"}).status_code == 400
            assert client.get("/api/query", params={"id": "cube.step", "uses": "1", "where": " "}).status_code == 200
            pin_of_six = [h["id"] for h in used.json()["hits"] if h["parent"] == "boards/six.step"][0]
            by_pin = client.get("/api/query", params={"id": pin_of_six, "uses": "1", "metric": "weighted"}).json()
            assert {h["parent"]: h["count"] for h in by_pin["hits"]} == {"boards/four.step": 4, "boards/six.step": 6}
            assert client.get(by_pin["hits"][0]["thumbnail"]).status_code == 200
            refused = client.get("/api/query", params={"id": pin_of_six, "uses": "1", "where": "material=steel"})
            assert refused.status_code == 400 and "where" in refused.json()["error"]
        finally:
            service.close()
        # a store without sub-parts: parts is false, and parts=1 is a 409 that says how to build them
        plain = tmp_path / "plain.shapeidx"
        _build(root, plain)
        service = StoreService(plain)
        try:
            client = TestClient(create_app(service), base_url="http://127.0.0.1:8765")
            assert client.get("/api/store").json()["parts"] is False
            refused = client.get("/api/query", params={"id": "cube.step", "parts": "1"})
            assert refused.status_code == 409 and "--parts" in refused.json()["error"]
            refused = client.get("/api/query", params={"id": "cube.step", "uses": "1"})
            assert refused.status_code == 409 and "--parts" in refused.json()["error"]
            with open(query, "rb") as f:
                upload = client.post("/api/query", files={"file": (query.name, f.read())}, data={"parts": "1"})
            assert upload.status_code == 409 and "--parts" in upload.json()["error"]
        finally:
            service.close()

    def test_web_page_in_a_browser(self, library, store, tmp_path):
        """The page in headless chromium (as tests/test_web_browser.py): the Sub-parts box is
        shown for a store built with --parts; ticked, an upload ranks sub-parts and each card
        says whose; a click on a hit's picture asks by that sub-part."""
        import subprocess
        import time
        import urllib.parse
        import urllib.request

        import test_web_browser as browsing  # skips when chromium or Playwright is missing
        from clitools import shapeidx_command

        root, query = library
        cli_hits = json.loads(cli("query", query, "--store", store, "--parts", "--top", "4", "--json").stdout)["hits"]
        port = browsing.free_port()
        log = open(tmp_path / "serve.log", "w")
        process = subprocess.Popen(shapeidx_command("serve", "--store", store, "--port", port), stdout=log,
                                   stderr=subprocess.STDOUT)
        url = f"http://127.0.0.1:{port}/"
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    urllib.request.urlopen(url + "api/store", timeout=2).read()
                    break
                except OSError:
                    if process.poll() is not None or time.monotonic() > deadline:
                        pytest.fail(f"shapeidx serve did not start: {(tmp_path / 'serve.log').read_text()}")
                    time.sleep(0.2)
            with browsing.sync_api.sync_playwright() as p:
                context = p.chromium.launch_persistent_context(
                    str(tmp_path / "profile"), executable_path=browsing.CHROMIUM, args=browsing.CHROMIUM_ARGS,
                    headless=True, viewport={"width": 1280, "height": 1000})
                page = context.new_page()
                errors = []
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.goto(url)
                page.wait_for_selector("#store-info:has-text('sub-parts')")
                assert page.locator("#parts-label").is_visible()
                page.check("#parts")
                page.set_input_files("#file", str(query))
                page.fill("#top", "4")
                page.click("#upload-button")
                page.wait_for_selector("[data-testid=hit] [data-testid=sub-part]")
                cards = page.locator("[data-testid=hit]")
                assert [c.get_attribute("data-id") for c in cards.all()] == [h["relative_path"] for h in cli_hits]
                for card, hit in zip(cards.all(), cli_hits):
                    line = card.locator("[data-testid=sub-part]").inner_text()
                    assert line == f"sub-part of {hit['parent']} (×{hit['count']})"
                page.wait_for_function("() => [...document.querySelectorAll('[data-testid=hit] img')].every(i => i.complete)")
                assert browsing.loaded(page, "[data-testid=hit] img")
                # each card: the sub-part's own picture, and its whole file's small beside the line
                assert page.locator("[data-testid=hit] [data-testid=parent-thumbnail]").count() == sum(
                    not h["relative_path"].startswith("cube.step") for h in cli_hits)  # cube.step is one part
                assert [c.locator("[data-testid=thumbnail]").get_attribute("src") for c in cards.all()] == [
                    f"/api/thumbnail?id={urllib.parse.quote(h['relative_path'], safe='')}" for h in cli_hits]
                page.screenshot(path=str(tmp_path / "parts.png"))
                # ask by the first sub-part: the address keeps parts=1, the query card names its file
                first = cli_hits[0]
                cards.nth(0).locator("[data-testid=thumbnail]").click()
                page.wait_for_function("() => location.hash.includes('parts=1') && location.hash.includes('%23')")
                page.wait_for_selector(f"[data-testid=query-card] [data-testid=sub-part]:has-text('{first['parent']}')")
                page.wait_for_selector(f"[data-testid=hit][data-id='{first['relative_path']}']")
                assert page.locator("[data-testid=hit]").first.get_attribute("data-id") == first["relative_path"]
                # unticked: the files again
                page.uncheck("#parts")
                page.wait_for_function("() => !location.hash.includes('parts=1')")
                page.wait_for_selector("[data-testid=hit]:not(:has([data-testid=sub-part]))")
                # where used, by the pin of six.step: the two boards, each once, with its count
                assert page.locator("#uses-label").is_visible()
                pin = [h["relative_path"] for h in cli_hits if h["parent"] == "boards/six.step"][0]
                page.check("#parts")
                page.check("#uses")  # one way of ranking sub-parts at a time; where used takes no where
                assert not page.is_checked("#parts") and page.is_disabled("#where")
                assert page.input_value("#metric") == "all-angle"  # the command's default distance
                page.wait_for_function("() => location.hash.includes('uses=1') && location.hash.includes('all-angle')")
                page.wait_for_selector("[data-testid=query-card]:has-text('all-angle, the files holding')")
                page.goto(url + "#/query?" + urllib.parse.urlencode({"id": pin, "metric": "weighted", "top": "10",
                                                                       "uses": "1"}))
                page.wait_for_selector("[data-testid=query-card]:has-text('Weighted, the files holding')")
                page.wait_for_selector("[data-testid=hit] [data-testid=sub-part]:has-text('boards/four.step')")
                lines = sorted(c.inner_text() for c in page.locator("[data-testid=hit] [data-testid=sub-part]").all())
                assert lines == ["sub-part of boards/four.step (×4)", "sub-part of boards/six.step (×6)"]
                assert "the files holding a sub-part like it" in page.locator("[data-testid=query-card]").inner_text()
                page.wait_for_function("() => [...document.querySelectorAll('[data-testid=hit] img')].every(i => i.complete)")
                assert browsing.loaded(page, "[data-testid=hit] img")
                page.screenshot(path=str(tmp_path / "where-used.png"))
                assert not errors, errors
                context.close()
        finally:
            process.terminate()
            process.wait(timeout=20)
            log.close()


@pytest.fixture(scope="module")
def sharded_store(library, tmp_path_factory):
    """The library built with --shards 2 --parts: the sub-parts of every shard."""
    store = tmp_path_factory.mktemp("sharded") / "s.shapeidx"
    _build(library[0], store, "--shards", "2", "--parts")
    return store


def _pin_parts(store, query) -> list[str]:
    """The pin's sub-entries (FILE#n) in the two boards that hold it, by where-used."""
    uses = json.loads(cli("where-used", query, "--store", store, "--top", "2", "--json").stdout)["uses"]
    return sorted(u["part"] for u in uses)


class TestFamiliesOfSubParts:
    """classify, cluster, check-new and plot --parts: the sub-parts of an ordinary and of a
    sharded owner, opened as query --parts opens them, with the same answers from both."""

    def test_cluster_parts_groups_the_sub_parts(self, library, store, sharded_store):
        answers = []
        for owner in (store, sharded_store):
            result = cli("cluster", "--store", owner, "--parts", "--clusters", "3", "--json")
            assert result.exit_code == 0, result.output + result.stderr
            answers.append(json.loads(result.stdout))
        with open_store(parts_store(store)) as reader:
            assert sorted(r["path"] for r in answers[0]) == sorted(reader.paths.tolist())
        assert answers[0] == answers[1]
        assert len({r["cluster"] for r in answers[0]}) == 3
        pins = _pin_parts(store, library[1])  # the pin of both boards: one family
        assert len({r["cluster"] for r in answers[0] if r["path"] in pins}) == 1

    def test_classify_parts_votes_with_the_sub_parts(self, library, store, sharded_store):
        root, query = library
        four = root / "boards" / "four.step"
        answers = []
        for owner in (store, sharded_store):
            result = cli("classify", query, four, "--store", owner, "--parts", "--k", "2", "--json")
            assert result.exit_code == 0, result.output + result.stderr
            answers.append(json.loads(result.stdout))
        assert answers[0] == answers[1]
        pin, board = answers[0]
        assert pin["label"] == "boards" and all(n["path"].partition("#")[1] for n in pin["neighbours"])
        assert sorted(n["path"] for n in pin["neighbours"]) == _pin_parts(store, query)
        # a file of the tree: its own sub-parts do not vote for it
        assert board["neighbours"] and not [n for n in board["neighbours"] if n["path"].startswith("boards/four.step#")]

    def test_check_new_parts_finds_the_pin_inside_the_boards(self, library, store, sharded_store, tmp_path):
        root, query = library
        four = root / "boards" / "four.step"
        answers = []
        for owner in (store, sharded_store):
            result = cli("check-new", query, "--store", owner, "--parts", "--json")
            assert result.exit_code == 7, result.output + result.stderr  # a duplicate found
            answers.append(json.loads(result.stdout))
            # without --parts the pin alone is no file of the library: new
            assert cli("check-new", query, "--store", owner).exit_code == 0
            unchanged = json.loads(cli("check-new", four, "--store", owner, "--parts", "--json").stdout)
            assert unchanged[0]["status"] == "unchanged"  # the store holds the file itself
            alone = json.loads(cli("check-new", four, "--store", owner, "--parts", "--exclude-self", "--json").stdout)
            assert not [h for kind in ("duplicates", "look_alikes") for h in alone[0][kind]
                        if h["relative_path"].startswith("boards/four.step#")]
        assert answers[0] == answers[1]
        (report,) = answers[0]
        assert report["status"] == "duplicate"
        assert sorted(h["relative_path"] for h in report["duplicates"]) == _pin_parts(store, query)
        assert {h["tier"] for h in report["duplicates"]} <= {"same", "converted"}  # never "the same file"
        sheet = cli("check-new", query, "--store", sharded_store, "--parts", "--sheet", tmp_path / "pin.html")
        assert sheet.exit_code == 7, sheet.output + sheet.stderr
        assert all(p in (tmp_path / "pin.html").read_text() for p in _pin_parts(store, query))

    def test_plot_parts_draws_sub_parts(self, library, store, sharded_store, tmp_path):
        pins = _pin_parts(store, library[1])
        for k, owner in enumerate((store, sharded_store)):
            out = tmp_path / f"pins{k}.png"
            result = cli("plot", "--store", owner, "--parts", *[a for p in pins for a in ("--id", p)], "-o", out)
            assert result.exit_code == 0, result.output + result.stderr
            assert out.stat().st_size > 0
        whole = cli("plot", "--store", store, "--id", pins[0], "-o", tmp_path / "whole.png")
        assert_one_line_error(whole, pins[0])  # a sub-entry is no file of the store
        usage = cli("plot", library[1], "--parts", "-o", tmp_path / "none.png")
        assert usage.exit_code == 2 and "--id" in usage.stderr

    def test_a_store_without_sub_parts_says_which_build_makes_them(self, library, tmp_path):
        root, query = library
        plain = tmp_path / "plain.shapeidx"
        _build(root, plain)
        for args in (("cluster",), ("classify", query), ("check-new", query), ("plot", "--id", "cube.step#1", "-o",
                                                                                tmp_path / "x.png")):
            result = cli(*args, "--store", plain, "--parts")
            assert_one_line_error(result, plain)
            assert "--parts" in result.stderr


def test_stats_of_a_sharded_parts_store_sums_the_shards_sub_parts(store, sharded_store):
    """stats of a store built with --shards 2 --parts: the sub-parts of every shard added up,
    the numbers of an ordinary --parts build of the same tree (it reported none)."""
    ordinary = json.loads(cli("stats", "--store", store, "--json").stdout)["parts"]
    sharded = json.loads(cli("stats", "--store", sharded_store, "--json").stdout)["parts"]
    assert sharded == ordinary == {"entries": 7, "files": 4, "several": 3, "instances": 17}
    line = "sub-parts   7 entries (17 counted as the files hold them) of 4 files, 3 with several"
    assert line in cli("stats", "--store", sharded_store).stdout
