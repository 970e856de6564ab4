"""Defects found by the adversarial run of issue 15, each as one clean line saying what is wrong.

- a stray far vertex made the merge tolerance collapse every face: IndexError, no file name
  (now the far triangle is left out with a warning, issue 23);
- coordinates of 1e200 were "zero surface area", with overflow warnings on stderr;
- a signalling NaN printed a numpy warning beside the line;
- a newline or control character in a file name was printed raw and could forge log lines.
"""

from __future__ import annotations

import os
import struct
import subprocess
import warnings

import numpy as np
import pytest

from shapeidx.errors import LoadError, ShapeidxError, printable
from shapeidx.signing.pipeline import solid_of_file
from clitools import shapeidx_command

TETRAHEDRON = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TETRA_FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def binary_stl(path, triangles) -> None:
    """``triangles``: (k, 3, 3) corners, written as float32 (raw bit patterns allowed as
    uint32 rows when ``triangles`` is an integer array)."""
    triangles = np.asarray(triangles)
    body = triangles.astype("<u4" if triangles.dtype.kind in "ui" else "<f4").reshape(-1, 9)
    records = b"".join(b"\0" * 12 + row.tobytes() + b"\0\0" for row in body)
    path.write_bytes(b"test".ljust(80) + struct.pack("<I", len(body)) + records)


def ascii_stl(path, triangles) -> None:
    lines = ["solid t"]
    for tri in triangles:
        lines += ["facet normal 0 0 0", "outer loop"] + [f"vertex {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in tri]
        lines += ["endloop", "endfacet"]
    path.write_text("\n".join(lines + ["endsolid t"]) + "\n")


def tetrahedron(scale=1.0, offset=(0.0, 0.0, 0.0)):
    v = TETRAHEDRON * scale + np.array(offset)
    return v[np.array(TETRA_FACES)]


def load_quietly(path):
    """solid_of_file with every warning turned into an error: nothing may reach stderr."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return solid_of_file(path)


def test_a_stray_far_vertex_is_left_out_not_the_part_refused(tmp_path):
    # a tiny part and one triangle reaching 1e12 away: the merge tolerance (1e-9 of the
    # extent) would be 1000, larger than the part, and every face would collapse (issue 15
    # made that one clean line; issue 23: the part is read, the far triangle left out)
    triangles = np.concatenate([tetrahedron(), [[[0, 0, 0], [1e12, 0, 0], [1, 0, 0]]]])
    path = tmp_path / "stray.stl"
    ascii_stl(path, triangles)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        solid = solid_of_file(path)
    assert solid.watertight and solid.volume == pytest.approx(1 / 6, rel=1e-9)  # the tetrahedron, analytic
    assert any("1 triangle(s) far from the rest left out" in w for w in solid.warnings), solid.warnings


def test_a_stray_vertex_that_leaves_faces_with_area_still_gives_a_part(tmp_path):
    # the far triangle itself is large: the part is what the file says, a long sliver
    triangles = np.concatenate([tetrahedron(), [[[0, 0, 0], [1e6, 0, 0], [0, 1e3, 0]]]])
    path = tmp_path / "far.stl"
    ascii_stl(path, triangles)
    assert load_quietly(path).area > 0


@pytest.mark.parametrize("scale", [1e200, 1e120, -1e300])
def test_huge_coordinates_are_refused_as_too_large_not_as_zero_area(tmp_path, scale):
    path = tmp_path / "huge.stl"
    ascii_stl(path, tetrahedron(scale))
    with pytest.raises(LoadError, match="coordinates too large to compute with") as caught:
        load_quietly(path)
    assert "zero surface area" not in str(caught.value)


def test_far_from_the_origin_but_small_is_refused_as_too_large(tmp_path):
    path = tmp_path / "far-away.stl"
    ascii_stl(path, tetrahedron(1.0, offset=(1e150, 0, 0)))
    with pytest.raises(LoadError, match="coordinates too large"):
        load_quietly(path)


def test_tiny_coordinates_are_refused_as_too_small(tmp_path):
    path = tmp_path / "tiny.stl"
    ascii_stl(path, tetrahedron(1e-200))
    with pytest.raises(LoadError, match="too small to compute with"):
        load_quietly(path)


def test_large_but_computable_coordinates_give_a_part(tmp_path):
    path = tmp_path / "large.stl"
    ascii_stl(path, tetrahedron(1e30))
    solid = load_quietly(path)
    assert solid.volume == pytest.approx(1e90 / 6, rel=1e-9)


@pytest.mark.parametrize("bits", [0x7F800001, 0x7FC00000, 0x7F800000, 0xFF800000], ids=["sNaN", "qNaN", "inf", "-inf"])
def test_non_finite_binary_coordinates_give_one_line_and_no_warning(tmp_path, bits):
    raw = tetrahedron().astype("<f4").view("<u4").copy()
    raw[2, 1, 0] = bits
    path = tmp_path / "nan.stl"
    binary_stl(path, raw)
    with pytest.raises(LoadError, match="NaN or infinite vertex coordinates"):
        load_quietly(path)


def test_an_overflowing_vrml_scale_is_reported_without_warnings(tmp_path):
    path = tmp_path / "scale.wrl"
    path.write_text("#VRML V2.0 utf8\nTransform { scale 1e300 1e300 1e300 children Transform { scale 1e300 1 1 "
                    "children Shape { geometry Box { } } } }\n")
    with pytest.raises(LoadError, match="overflowing when transformed"):
        load_quietly(path)


# -- file names that could forge log lines --------------------------------------------------


@pytest.mark.parametrize(
    "raw, shown",
    [
        ("a\nb.wrl", "a\\nb.wrl"),
        ("a\r\nb", "a\\r\\nb"),
        ("tab\there", "tab\\there"),
        ("esc\x1b[31mred", "esc\\x1b[31mred"),
        ("nul\x00", "nul\\x00"),
        ("del\x7f c1\x85", "del\\x7f c1\\x85"),
        ("line\u2028sep", "line\\u2028sep"),
        (os.fsdecode(b"latin1-\xe9.stl"), "latin1-\\xe9.stl"),
        ("C:\\parts\\ok é.wrl", "C:\\parts\\ok é.wrl"),  # backslashes and letters stay
    ],
)
def test_printable_escapes_what_could_break_a_line(raw, shown):
    assert printable(raw) == shown
    assert str(LoadError(raw, f"bad {raw}")) == f"{shown}: bad {shown}"
    assert str(ShapeidxError(f"store {raw}")) == f"store {shown}"


def test_a_newline_in_a_file_name_cannot_forge_a_line(tmp_path):
    path = tmp_path / "evil\nshapeidx: error: forged.stl"
    path.write_bytes(b"not an stl")
    result = subprocess.run(shapeidx_command("inspect", str(path)), capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1, result.stderr
    assert "evil\\nshapeidx: error: forged.stl" in result.stderr


def test_a_failed_file_with_a_control_character_in_its_name_is_one_build_line(tmp_path):
    tree = tmp_path / "tree"
    tree.mkdir()
    (tree / "bad\rname\x1b[2K.stl").write_bytes(b"solid x\nendsolid x\n")
    result = subprocess.run(
        shapeidx_command("build", str(tree), "--store", str(tmp_path / "s.h5"), "--workers", "1"),
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    failed = [line for line in result.stderr.splitlines() if "bad" in line]
    assert len(failed) == 1 and failed[0].endswith("failed bad\\rname\\x1b[2K.stl: STL file contains no triangles"), result.stderr
