"""The commands as a user meets them: JSON contracts, human output, one-line errors."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import analytic as A
from clitools import assert_one_line_error, cli, cli_json

MESH_WILD = "mesh-wild"
INSPECT_KEYS = {"format", "triangles", "area", "volume", "bounds", "watertight", "shells", "warnings"}


class TestInspect:
    def test_unit_cube(self, data_dir):
        facts = cli_json("inspect", data_dir / MESH_WILD / "trimesh-models/unit_cube.STL")
        assert INSPECT_KEYS <= facts.keys()
        assert facts["format"] == "stl" and facts["triangles"] == 12 and facts["shells"] == 1
        assert facts["area"] == pytest.approx(6.0) and facts["volume"] == pytest.approx(1.0)
        assert facts["watertight"] is True
        lo, hi = np.array(facts["bounds"])
        np.testing.assert_allclose(hi - lo, [1, 1, 1])

    def test_open_mesh_has_no_volume(self, data_dir):
        facts = cli_json("inspect", data_dir / MESH_WILD / "assimp-testmodels/usr/share/assimp/models/STL/sphereWithHole.stl")
        assert facts["watertight"] is False and facts["volume"] is None

    def test_quads_are_counted_as_two_triangles(self, data_dir):
        facts = cli_json("inspect", data_dir / MESH_WILD / "assimp-testmodels/usr/share/assimp/models/OFF/Cube.off")
        assert facts["format"] == "off" and facts["polygons"] == 6 and facts["triangles"] == 12

    def test_human_output(self, data_dir):
        result = cli("inspect", data_dir / MESH_WILD / "trimesh-models/plate_holes.STL")
        assert result.exit_code == 0 and "watertight  yes" in result.stdout


class TestSignature:
    def test_json_contract(self, data_dir):
        sig = cli_json("signature", data_dir / MESH_WILD / "trimesh-models/plate_holes.STL", "--points", 300, "--seed", 5)
        assert sig["points"] == 300 and sig["seed"] == 5
        assert set(sig["fractions"]) == {"in", "out", "mixed"}
        assert sum(sig["fractions"].values()) == pytest.approx(1.0)
        for name in ("all", "in", "out", "mixed"):
            h = sig["histograms"][name]
            assert {"bin_width", "mean", "p"} <= h.keys()
            # a class with no pairs has an empty histogram
            assert sum(h["p"]) == pytest.approx(1.0 if h["pairs"] else 0.0)
        assert INSPECT_KEYS <= sig["mesh"].keys()

    def test_seed_is_deterministic(self, data_dir):
        part = data_dir / MESH_WILD / "trimesh-models/featuretype.STL"
        a = cli_json("signature", part, "--points", 200)
        b = cli_json("signature", part, "--points", 200)
        c = cli_json("signature", part, "--points", 200, "--seed", 1)
        assert a == b and a["histograms"] != c["histograms"]

    def test_human_summary(self, data_dir):
        result = cli("signature", data_dir / MESH_WILD / "trimesh-models/unit_cube.STL", "--points", 100)
        assert result.exit_code == 0 and "IN 100.0%" in result.stdout


class TestCompare:
    def test_a_part_against_itself_and_another(self, data_dir):
        parts = data_dir / MESH_WILD / "trimesh-models"
        same = cli_json("compare", parts / "plate_holes.STL", parts / "plate_holes.STL", "--points", 256)
        assert {k: same[k] for k in ("all", "avg3", "avg4", "weighted")} == {"all": 0, "avg3": 0, "avg4": 0, "weighted": 0}
        other = cli_json("compare", parts / "plate_holes.STL", parts / "torus.STL", "--points", 256)
        assert all(other[k] > 0 for k in ("all", "avg3", "avg4", "weighted"))

    def test_human_output(self, data_dir):
        parts = data_dir / MESH_WILD / "trimesh-models"
        result = cli("compare", parts / "plate_holes.STL", parts / "torus.STL", "--points", 128)
        assert result.exit_code == 0 and "Weighted" in result.stdout


BROKEN = [
    "assimp-testmodels/usr/share/assimp/models/invalid/empty.obj",
    "assimp-testmodels/usr/share/assimp/models/invalid/empty.off",
    "assimp-testmodels/usr/share/assimp/models/invalid/empty.ply",
    "assimp-testmodels/usr/share/assimp/models/invalid/OutOfMemory.off",
    "assimp-testmodels/usr/share/assimp/models/OFF/invalid.off",
    "assimp-testmodels/usr/share/assimp/models/PLY/points.ply",
    "assimp-testmodels/usr/share/assimp/models/OBJ/point_cloud.obj",
    "openscad-testdata/testdata/stl/empty.stl",
    "openscad-testdata/testdata/stl/invalidvertex.stl",
    "openscad-testdata/testdata/stl/toomanyvertices.stl",
    "openscad-testdata/testdata/stl/unparseable.stl",
    "trimesh-models/emptyIO/stl_empty_bin.stl",
]


class TestBadInput:
    @pytest.mark.parametrize("relative", BROKEN)
    @pytest.mark.parametrize("command", ["inspect", "signature"])
    def test_broken_real_files(self, data_dir, relative, command):
        path = data_dir / MESH_WILD / relative
        assert_one_line_error(cli(command, path), path)

    def test_missing_file_and_directory(self, tmp_path):
        assert_one_line_error(cli("inspect", tmp_path / "nope.stl"), tmp_path / "nope.stl")
        folder = tmp_path / "folder.stl"
        folder.mkdir()
        assert_one_line_error(cli("signature", folder), folder)

    def test_nan_coordinates(self, tmp_path):
        path = tmp_path / "nan.obj"
        path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
        result = cli("inspect", path)
        assert_one_line_error(result, path)
        assert "NaN" in result.stderr

    def test_zero_area(self, tmp_path):
        path = tmp_path / "flat.stl"
        v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
        A.write_stl(path, v, np.array([[0, 1, 2], [0, 2, 1]]))
        result = cli("signature", path)
        assert_one_line_error(result, path)
        assert "zero surface area" in result.stderr

    def test_not_a_mesh(self, tmp_path):
        path = tmp_path / "notes.stl"
        path.write_text("these are my notes, not a part\n" * 10)
        assert_one_line_error(cli("inspect", path), path)

    def test_unreadable(self, tmp_path, monkeypatch):
        # chmod 0 does not stop root (CI runs as root), so the refusal is simulated at open()
        import builtins

        path = tmp_path / "secret.stl"
        path.write_bytes(b"solid x\nendsolid x\n")
        real_open = builtins.open

        def guarded_open(file, *args, **kwargs):
            if str(file) == str(path):
                raise PermissionError(13, "Permission denied", str(file))
            return real_open(file, *args, **kwargs)

        real_os_open = os.open

        def guarded_os_open(file, *args, **kwargs):  # readers open with O_NONBLOCK (io.base.open_regular)
            if str(file) == str(path):
                raise PermissionError(13, "Permission denied", str(file))
            return real_os_open(file, *args, **kwargs)

        monkeypatch.setattr(builtins, "open", guarded_open)
        monkeypatch.setattr(os, "open", guarded_os_open)
        result = cli("inspect", path)
        assert_one_line_error(result, path)
        assert "permission denied" in result.stderr


@pytest.mark.slow
def test_every_mesh_wild_file_loads_or_fails_in_one_line(data_dir):
    """No file of mesh-wild crashes the loader or leaks a traceback."""
    files = sorted(p for p in (data_dir / MESH_WILD).rglob("*") if p.is_file() and p.name != "SOURCES.tsv")
    assert len(files) > 150
    loaded = 0
    for path in files:
        result = cli("inspect", path, "--json")
        if result.exit_code == 0:
            facts = json.loads(result.stdout)
            assert facts["triangles"] > 0 and facts["area"] > 0, path
            loaded += 1
        else:
            assert_one_line_error(result, path)
    assert loaded > 130
