"""A real part with one stray triangle far away is read (the stray left out, with a warning),
not refused whole: tolerances follow the size of the part's body, not the extent the stray
piece gives it.

The class of input: a real cube (mesh-wild's Cube.off) with one triangle added far away, at
distances from 10^5 to 10^60 times its size, written back as OFF. The independent check is
the analytic cube: volume 1, area 6.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shapeidx.io import load
from shapeidx.signing.solid import make_solid

CUBE = Path("mesh-wild/assimp-testmodels/usr/share/assimp/models/OFF/Cube.off")


def with_stray_triangle(text: str, at: float, size: float = 1.0) -> str:
    """An OFF file's text with one more triangle, of side ``size``, at ``(at, at, at)``."""
    lines = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    vertices, faces, edges = (int(x) for x in lines[1].split()[:3])
    points, polygons = lines[2:2 + vertices], lines[2 + vertices:2 + vertices + faces]
    points += [f"{at!r} {at!r} {at!r}", f"{at + size!r} {at!r} {at!r}", f"{at!r} {at + size!r} {at!r}"]
    polygons += [f"3 {vertices} {vertices + 1} {vertices + 2}"]
    return "\n".join(["OFF", f"{vertices + 3} {faces + 1} {edges}", *points, *polygons]) + "\n"


@pytest.mark.parametrize("at", [1e5, 1e12, 1e60])
def test_a_cube_with_a_stray_triangle_far_away_is_read(data_dir, tmp_path, at):
    path = tmp_path / "cube.off"
    path.write_text(with_stray_triangle((data_dir / CUBE).read_text(), at))
    solid = make_solid(load(path), path)
    assert solid.watertight and solid.volume == pytest.approx(1.0, rel=1e-9)
    assert solid.area == pytest.approx(6.0, rel=1e-9)
    assert any("1 triangle(s) far from the rest left out" in w for w in solid.warnings), solid.warnings
    assert solid.report["far_removed"] == 1


def test_pieces_near_each_other_are_all_kept(data_dir, tmp_path):
    """Two bodies a few sizes apart, and a stray one not far enough to matter, stay."""
    text = (data_dir / CUBE).read_text()
    for at in (3.0, 50.0):
        path = tmp_path / "near.off"
        path.write_text(with_stray_triangle(text, at))
        solid = make_solid(load(path), path)
        assert solid.report["far_removed"] == 0 and not any("far from" in w for w in solid.warnings)
        assert solid.area == pytest.approx(6.5, rel=1e-9)  # the cube and the triangle


def test_real_parts_have_no_far_pieces(data_dir):
    """No file of the labelled kicad6 set loses a triangle to the rule (a sample of 60)."""
    files = sorted((data_dir / "kicad6").rglob("*.wrl"))[::9][:60]
    assert len(files) >= 30
    for path in files:
        mesh = load(path)
        from shapeidx.signing.mesh import far_pieces, triangulate_polygons

        triangles = triangulate_polygons(mesh.vertices, mesh.face_sizes, mesh.face_indices)
        far, _, _ = far_pieces(np.asarray(mesh.vertices, dtype=float), triangles)
        assert far is None, path


@pytest.mark.parametrize("number", ["1e20", "-1e9", "1e60"])
def test_a_cube_with_one_coordinate_written_huge_is_read(data_dir, number):
    """The fuzz run's case: one number of a real ASCII STL cube (side 10) replaced by a huge
    one, so one triangle reaches far away (connected to the cube, not a piece of its own).
    That triangle is left out with a warning: the rest is the cube, open where it was
    (area 600 - 50, analytic)."""
    from shapeidx.io import load_bytes

    source = (data_dir / "mesh-wild/openscad-testdata/testdata/manual/issue214/cube2.stl").read_bytes()
    at = source.index(b"vertex", 200) + len(b"vertex ")
    data = source[:at] + number.encode() + source[source.index(b" ", at):]
    solid = make_solid(load_bytes(data, "cube2.stl"), "cube2.stl")
    assert solid.area == pytest.approx(550.0, rel=1e-9)
    assert solid.report["far_removed"] == 1 and not solid.watertight
    assert any("1 triangle(s) far from the rest left out" in w for w in solid.warnings), solid.warnings
