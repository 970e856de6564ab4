"""The public API as a Python user meets it: parts in every form, one signature, own errors."""

from __future__ import annotations

import gzip
import io

import numpy as np
import pytest
import trimesh

import shapeidx
from clitools import cli

STL = "mesh-wild/trimesh-models/featuretype.STL"
VRML = "kicad6/Battery/BatteryHolder_Keystone_500.wrl"


def same_signature(a, b) -> bool:
    return a.points == b.points and a.seed == b.seed and all(
        np.array_equal(a.histograms[h].counts, b.histograms[h].counts)
        and a.histograms[h].mean == b.histograms[h].mean
        and a.histograms[h].bin_width == b.histograms[h].bin_width
        for h in ("all", "in", "out", "mixed")
    )


class TestOneSignatureForEveryForm:
    def test_path_file_object_trimesh_and_arrays(self, data_dir):
        path = data_dir / STL
        by_path = shapeidx.signature(path, points=256)
        with open(path, "rb") as f:
            by_file = shapeidx.signature(f, points=256)
        mesh = trimesh.load(path)  # trimesh merges vertices: other indices, same triangles
        by_trimesh = shapeidx.signature(mesh, points=256)
        by_arrays = shapeidx.signature((np.array(mesh.vertices), np.array(mesh.faces)), points=256)
        by_solid = shapeidx.signature(shapeidx.load(str(path)), points=256)
        for other in (by_file, by_trimesh, by_arrays, by_solid):
            assert same_signature(by_path, other)

    def test_vrml_from_a_file_object_and_gzipped_bytes(self, data_dir):
        path = data_dir / VRML
        by_path = shapeidx.signature(path, points=128)
        with open(path, "rb") as f:
            data = f.read()
        assert same_signature(by_path, shapeidx.signature(io.BytesIO(data), points=128))
        assert same_signature(by_path, shapeidx.signature(io.BytesIO(gzip.compress(data)), points=128))

    def test_a_stream_follows_no_inline(self, data_dir, tmp_path, monkeypatch):
        """A stream has no folder: an Inline in it must not read files of the working directory."""
        (tmp_path / "secret.wrl").write_bytes((data_dir / VRML).read_bytes())
        inline = tmp_path / "inline.wrl"
        inline.write_bytes(b'#VRML V2.0 utf8\nInline { url "secret.wrl" }\n')
        monkeypatch.chdir(tmp_path)
        assert len(shapeidx.load(inline).faces) > 0  # from a file, inside its folder: followed
        with pytest.raises(shapeidx.LoadError, match="contains no polygons"):
            shapeidx.load(io.BytesIO(inline.read_bytes()))

    def test_file_type_for_content_that_does_not_say(self, tmp_path):
        box = trimesh.creation.box((1, 2, 3))
        obj = box.export(file_type="obj").encode()
        part = shapeidx.load(io.BytesIO(obj), file_type="obj")
        assert part.watertight and part.volume == pytest.approx(6.0)
        with pytest.raises(shapeidx.LoadError, match="unknown file type"):
            shapeidx.load(io.BytesIO(b"# a comment, no magic number\n"))

    def test_the_api_and_the_command_line_agree(self, data_dir):
        result = cli("signature", data_dir / STL, "--points", "256", "--json")
        assert result.exit_code == 0, result.stderr
        import json

        printed = json.loads(result.stdout)
        sig = shapeidx.signature(data_dir / STL, points=256)
        assert printed["fractions"] == sig.fractions
        assert printed["histograms"]["in"]["p"] == sig.histograms["in"].p.tolist()


class TestDistancesAndQueries:
    def test_compare_is_scale_invariant_and_knows_a_different_part(self, data_dir):
        box = trimesh.creation.box((10, 20, 5))
        scaled = shapeidx.compare(box, (box.vertices * 3, box.faces))
        invariant = [m for m in shapeidx.METRICS if m not in shapeidx.SIZE_METRICS]
        assert {m: scaled[m] for m in invariant} == pytest.approx({m: 0.0 for m in invariant}, abs=1e-9)
        assert all(scaled[m] > 0.1 for m in shapeidx.SIZE_METRICS)  # reads the exact sizes: 3x is another size
        tube = trimesh.creation.annulus(r_min=4, r_max=5, height=20)
        assert shapeidx.compare(box, tube)["weighted"] > 0.01

    def test_query_a_store_by_path_and_by_open_store(self, data_dir, tmp_path):
        from storetools import build, small_kicad

        tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
        assert build(tree, tmp_path / "s.h5").exit_code == 0
        part = next(iter(sorted(tree.glob("LED_SMD/*.wrl"))))
        hits = shapeidx.query(tmp_path / "s.h5", part, top=3)
        # the command line's fields: path absolute, relative_path the entry, and the metadata
        assert hits[0] == {"rank": 1, "path": str(tree.resolve() / "LED_SMD" / part.name),
                           "relative_path": f"LED_SMD/{part.name}", "distance": 0.0, "metadata": {}}
        with shapeidx.open_store(tmp_path / "s.h5") as store:
            assert shapeidx.query(store, entry=hits[1]["relative_path"], top=1)[0]["path"] == hits[1]["path"]
            assert shapeidx.query(store, part, top=3, metric="combined")[0]["path"] == hits[0]["path"]
            assert len(store.paths) == 10 and store.params.points == int(store.attrs["points"])  # the reader's view too


class TestErrors:
    def test_a_bad_part_is_a_load_error_of_one_line(self, tmp_path):
        bad = tmp_path / "broken.stl"
        bad.write_bytes(b"solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0\n")
        with pytest.raises(shapeidx.LoadError) as caught:
            shapeidx.signature(bad)
        assert str(bad) in str(caught.value) and "\n" not in str(caught.value)
        assert isinstance(caught.value, shapeidx.ShapeidxError)

    def test_arrays_that_are_not_a_mesh(self):
        with pytest.raises(shapeidx.LoadError, match="face indices outside"):
            shapeidx.load((np.zeros((3, 3)), np.array([[0, 1, 5]])))
        with pytest.raises(shapeidx.LoadError, match=r"expected \(n, 3\) vertices"):
            shapeidx.load((np.zeros((3, 2)), np.array([[0, 1, 2]])))
        with pytest.raises(TypeError, match="cannot load a part from int"):
            shapeidx.load(42)

    def test_a_missing_store_is_a_store_error(self, tmp_path, data_dir):
        with pytest.raises(shapeidx.StoreError, match="no store at"):
            shapeidx.query(tmp_path / "none.h5", data_dir / STL)


def test_import_is_cheap():
    """``import shapeidx`` loads none of the heavy machinery (scipy, Embree, h5py) until used."""
    import subprocess
    import sys

    code = "import sys, shapeidx; print(sorted(m for m in ('scipy', 'embreex', 'h5py', 'trimesh') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
