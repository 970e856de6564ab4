"""Known answers for the STL, OBJ, OFF and PLY readers.

Every variant is written by the test from known arrays (a hexagonal prism: two hexagons and
six quadrilaterals, and the same prism triangulated) and read back through
:func:`shapeidx.io.load`: the vertices and polygons read must be the ones written, exactly
(the coordinates are chosen to be exact in float32), and the cleaned solid must have the
prism's analytic volume and area. The writers here are independent of the readers: plain
string formatting and :mod:`struct`.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from shapeidx.errors import UNFORESEEN, LoadError
from shapeidx.io import load
from shapeidx.signing.solid import make_solid

# -- the known part: a hexagonal prism, wound counter-clockwise seen from outside ------------

HEIGHT = 2.0
#: Regular hexagon of circumradius 1 approximated by coordinates exact in float32 (eighths),
#: convex and counter-clockwise seen from +z.
HEXAGON = np.array([[1, 0], [0.5, 0.875], [-0.5, 0.875], [-1, 0], [-0.5, -0.875], [0.5, -0.875]])
VERTICES = np.vstack([np.c_[HEXAGON, np.zeros(6)], np.c_[HEXAGON, np.full(6, HEIGHT)]])
#: Bottom (seen from below: reversed), top, and the six sides.
POLYGONS = [[5, 4, 3, 2, 1, 0], [6, 7, 8, 9, 10, 11]] + [[i, (i + 1) % 6, (i + 1) % 6 + 6, i + 6] for i in range(6)]


def shoelace(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


HEX_AREA = shoelace(HEXAGON)
SIDE_AREA = float(sum(np.linalg.norm(HEXAGON[(i + 1) % 6] - HEXAGON[i]) for i in range(6))) * HEIGHT
VOLUME = HEX_AREA * HEIGHT
AREA = 2 * HEX_AREA + SIDE_AREA


def fan(polygon: list[int]) -> list[list[int]]:
    return [[polygon[0], polygon[k], polygon[k + 1]] for k in range(1, len(polygon) - 1)]


TRIANGLES = [t for p in POLYGONS for t in fan(p)]


def flat(polygons) -> tuple[np.ndarray, np.ndarray]:
    return np.array([len(p) for p in polygons]), np.array([i for p in polygons for i in p])


def assert_polygons(mesh, vertices, polygons):
    sizes, corners = flat(polygons)
    np.testing.assert_array_equal(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.face_sizes, sizes)
    np.testing.assert_array_equal(mesh.face_indices, corners)


def assert_prism(mesh):
    solid = make_solid(mesh)
    assert solid.watertight
    assert solid.volume == pytest.approx(VOLUME, rel=1e-12)
    assert solid.area == pytest.approx(AREA, rel=1e-12)


def num(x: float) -> str:
    return repr(float(x))


# -- STL ----------------------------------------------------------------------------------------


def ascii_stl(triangles, vertices, name="prism", keyword_case=str.lower) -> str:
    k = keyword_case
    lines = [f"{k('solid')} {name}"]
    for t in triangles:
        lines += [f"  {k('facet normal')} 0 0 0", f"    {k('outer loop')}"]
        lines += [f"      {k('vertex')} " + " ".join(num(c) for c in vertices[i]) for i in t]
        lines += [f"    {k('endloop')}", f"  {k('endfacet')}"]
    lines.append(f"{k('endsolid')} {name}")
    return "\n".join(lines) + "\n"


def binary_stl(triangles, vertices, header=b"binary prism") -> bytes:
    out = [header.ljust(80, b" ")[:80], struct.pack("<I", len(triangles))]
    for t in triangles:
        out.append(struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *vertices[i]) for i in t) + b"\0\0")
    return b"".join(out)


def corners_of(triangles) -> np.ndarray:
    return VERTICES[np.array(triangles).reshape(-1)]


def test_ascii_stl(tmp_path):
    path = tmp_path / "prism.stl"
    path.write_text(ascii_stl(TRIANGLES, VERTICES))
    mesh = load(path)
    assert mesh.format == "stl"
    assert_polygons(mesh, corners_of(TRIANGLES), [[3 * k, 3 * k + 1, 3 * k + 2] for k in range(len(TRIANGLES))])
    assert_prism(mesh)


def test_ascii_stl_with_several_solids_and_crlf(tmp_path):
    half = len(TRIANGLES) // 2
    text = ascii_stl(TRIANGLES[:half], VERTICES, "a") + ascii_stl(TRIANGLES[half:], VERTICES, "b")
    path = tmp_path / "two.stl"
    path.write_bytes(text.replace("\n", "\r\n").encode())
    mesh = load(path)
    np.testing.assert_array_equal(mesh.vertices, corners_of(TRIANGLES))
    assert_prism(mesh)


def test_ascii_stl_keywords_in_capitals(tmp_path):
    # the keywords are case-insensitive in practice: some exporters write SOLID / VERTEX
    path = tmp_path / "caps.stl"
    path.write_text(ascii_stl(TRIANGLES, VERTICES, keyword_case=str.upper))
    mesh = load(path)
    np.testing.assert_array_equal(mesh.vertices, corners_of(TRIANGLES))
    assert_prism(mesh)


@pytest.mark.parametrize("header", [b"binary prism", b"solid prism (a binary file whose header says solid)"])
def test_binary_stl(tmp_path, header):
    path = tmp_path / "prism.stl"
    path.write_bytes(binary_stl(TRIANGLES, VERTICES, header))
    mesh = load(path)
    assert mesh.format == "stl"
    np.testing.assert_array_equal(mesh.vertices, corners_of(TRIANGLES))
    assert_prism(mesh)


def test_binary_stl_whose_count_disagrees_with_its_length_is_refused(tmp_path):
    data = bytearray(binary_stl(TRIANGLES, VERTICES))
    data[80:84] = struct.pack("<I", len(TRIANGLES) + 1)
    path = tmp_path / "short.stl"
    path.write_bytes(bytes(data))
    with pytest.raises(LoadError, match=f"announces {len(TRIANGLES) + 1} triangles"):
        load(path)


# -- OBJ ----------------------------------------------------------------------------------------


def obj_text(corner) -> str:
    """The prism as OBJ, each face corner written by ``corner(vertex_index_0_based, k)``."""
    lines = ["# a hexagonal prism", "mtllib none.mtl", "o prism", "g sides"]
    lines += ["v " + " ".join(num(c) for c in v) for v in VERTICES]
    lines += [f"vt {i / 12} {i / 24}" for i in range(12)]
    lines += ["vn 0 0 1"]
    lines += ["usemtl steel", "s off"]
    lines += ["f " + " ".join(corner(i, k) for k, i in enumerate(p)) for p in POLYGONS]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    "corner",
    [
        lambda i, k: f"{i + 1}",
        lambda i, k: f"{i + 1}/{i + 1}",
        lambda i, k: f"{i + 1}//1",
        lambda i, k: f"{i + 1}/{i + 1}/1",
        lambda i, k: f"{i - 12}",  # negative: counted back from the last vertex (-1 is the 12th)
        lambda i, k: f"{i - 12}/-1/-1",
        lambda i, k: f"{i + 1}" if k % 2 else f"{i - 12}//1",  # mixed within one face
    ],
    ids=["v", "v/vt", "v//vn", "v/vt/vn", "negative", "negative/vt/vn", "mixed"],
)
def test_obj_polygons_in_every_index_form(tmp_path, corner):
    path = tmp_path / "prism.obj"
    path.write_text(obj_text(corner))
    mesh = load(path)
    assert mesh.format == "obj" and not mesh.warnings
    assert_polygons(mesh, VERTICES, POLYGONS)  # n-gons kept as written
    assert_prism(mesh)


def test_obj_negative_indices_refer_to_the_vertices_before_the_face(tmp_path):
    # each face written right after its own vertices, with -1, -2, ...: the same prism
    lines = []
    for p in POLYGONS:
        lines += ["v " + " ".join(num(c) for c in VERTICES[i]) for i in p]
        lines.append("f " + " ".join(str(k - len(p)) for k in range(len(p))))
    path = tmp_path / "local.obj"
    path.write_text("\n".join(lines) + "\n")
    mesh = load(path)
    start = np.cumsum([0] + [len(p) for p in POLYGONS])
    assert_polygons(mesh, VERTICES[[i for p in POLYGONS for i in p]], [list(range(a, b)) for a, b in zip(start, start[1:])])
    assert_prism(mesh)


def test_obj_vertex_colours_and_w_are_ignored(tmp_path):
    lines = ["v " + " ".join(num(c) for c in v) + " 0.5 0.25 1" for v in VERTICES]
    lines += ["f " + " ".join(str(i + 1) for i in p) for p in POLYGONS]
    path = tmp_path / "colour.obj"
    path.write_text("\n".join(lines) + "\n")
    assert_polygons(load(path), VERTICES, POLYGONS)


# -- OFF ----------------------------------------------------------------------------------------


def off_text(header="OFF", counts_on_header_line=False, vertex_extra="", face_extra="") -> str:
    counts = f"{len(VERTICES)} {len(POLYGONS)} 0"
    lines = ["# written by the test", header + (f" {counts}" if counts_on_header_line else "")]
    if not counts_on_header_line:
        lines += ["# counts: vertices faces edges", counts]
    lines += [" ".join(num(c) for c in v) + vertex_extra + "  # a vertex" for v in VERTICES]
    lines += [""]
    lines += [f"{len(p)} " + " ".join(map(str, p)) + face_extra for p in POLYGONS]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"counts_on_header_line": True},
        {"face_extra": " 255 0 0"},  # face colours
        {"header": "COFF", "vertex_extra": " 0.5 0.5 0.5 1"},
        {"header": "NOFF", "vertex_extra": " 0 0 1"},
        {"header": "CNOFF", "vertex_extra": " 0 0 1 0.5 0.5 0.5 1"},
    ],
    ids=["plain", "counts-on-header", "face-colours", "COFF", "NOFF", "CNOFF"],
)
def test_off(tmp_path, kwargs):
    path = tmp_path / "prism.off"
    path.write_text(off_text(**kwargs))
    mesh = load(path)
    assert mesh.format == "off" and not mesh.warnings
    assert_polygons(mesh, VERTICES, POLYGONS)
    assert_prism(mesh)


def test_off_that_announces_more_than_it_holds_is_refused(tmp_path):
    path = tmp_path / "short.off"
    path.write_text(off_text().replace(f"{len(VERTICES)} {len(POLYGONS)} 0", f"{len(VERTICES)} 99 0"))
    with pytest.raises(LoadError, match="announces 12 vertices and 99 faces"):
        load(path)


# -- PLY ----------------------------------------------------------------------------------------

PLY_TYPES = {
    "char": "b", "uchar": "B", "short": "h", "ushort": "H", "int": "i", "uint": "I", "float": "f", "double": "d",
    "int8": "b", "uint8": "B", "int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "float32": "f", "float64": "d",
}  # fmt: skip


def ply(
    fmt: str,
    polygons=POLYGONS,
    coord="float",
    count="uchar",
    index="int",
    list_name="vertex_indices",
    extra_vertex=(),
    extra_element=False,
) -> bytes:
    """The prism as PLY. ``extra_vertex``: (name, type, value) properties written after y, to
    test that x, y, z are found by name; ``extra_element`` adds an ``edge`` element between
    vertex and face."""
    header = ["ply", f"format {fmt} 1.0", "comment written by the test", "obj_info prism"]
    header += [f"element vertex {len(VERTICES)}", f"property {coord} x", f"property {coord} y"]
    header += [f"property {t} {n}" for n, t, _ in extra_vertex]
    header += [f"property {coord} z"]
    edges = [(0, 1), (1, 2)]
    if extra_element:
        header += [f"element edge {len(edges)}", "property int vertex1", "property int vertex2"]
    header += [f"element face {len(polygons)}", f"property list {count} {index} {list_name}", "end_header"]
    head = ("\r\n" if fmt == "ascii" and list_name == "vertex_index" else "\n").join(header) + "\n"
    vertex_rows = [[v[0], v[1], *[value for _, _, value in extra_vertex], v[2]] for v in VERTICES]
    vertex_types = [coord, coord, *[t for _, t, _ in extra_vertex], coord]
    if fmt == "ascii":
        body = [" ".join(num(x) if t.startswith(("float", "double")) else str(int(x)) for x, t in zip(row, vertex_types)) for row in vertex_rows]
        if extra_element:
            body += [f"{a} {b}" for a, b in edges]
        body += [f"{len(p)} " + " ".join(map(str, p)) for p in polygons]
        return (head + "\n".join(body) + "\n").encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    out = [head.encode()]
    for row in vertex_rows:
        out.append(b"".join(struct.pack(order + PLY_TYPES[t], x) for x, t in zip(row, vertex_types)))
    if extra_element:
        out += [struct.pack(order + "ii", a, b) for a, b in edges]
    for p in polygons:
        out.append(struct.pack(order + PLY_TYPES[count], len(p)) + struct.pack(order + PLY_TYPES[index] * len(p), *p))
    return b"".join(out)


TRIANGLE_POLYGONS = TRIANGLES  # every face of one size: the reader's vectorised path


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("polygons", [POLYGONS, TRIANGLE_POLYGONS], ids=["ngons-and-quads", "triangles"])
def test_ply(tmp_path, fmt, polygons):
    path = tmp_path / "prism.ply"
    path.write_bytes(ply(fmt, polygons))
    mesh = load(path)
    assert mesh.format == "ply" and not mesh.warnings
    assert_polygons(mesh, VERTICES, polygons)
    assert_prism(mesh)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize(
    "count, index",
    [("uchar", "int"), ("uchar", "uint"), ("ushort", "int"), ("uint", "uint"), ("uchar", "short"),
     ("uchar", "ushort"), ("int", "int"), ("uint8", "int32"), ("char", "uchar")],
)  # fmt: skip
def test_ply_list_count_and_index_types(tmp_path, fmt, count, index):
    for polygons in (POLYGONS, TRIANGLE_POLYGONS):
        path = tmp_path / f"prism-{count}-{index}.ply"
        path.write_bytes(ply(fmt, polygons, count=count, index=index))
        mesh = load(path)
        assert_polygons(mesh, VERTICES, polygons)
        assert_prism(mesh)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_double_coordinates_other_properties_and_elements(tmp_path, fmt):
    extra = (("red", "uchar", 200), ("nx", "float", 0.5), ("quality", "double", 0.25), ("flags", "ushort", 7))
    data = ply(fmt, coord="double", extra_vertex=extra, extra_element=True, list_name="vertex_index")
    path = tmp_path / "prism.ply"
    path.write_bytes(data)
    mesh = load(path)
    assert_polygons(mesh, VERTICES, POLYGONS)
    assert_prism(mesh)


@pytest.mark.parametrize(
    "mangle, reason",
    [
        (lambda d: d.replace(b"element face 8", b"element face 9"), "ends inside its 'face' data"),
        (lambda d: d.replace(b"property list uchar int vertex_indices", b"property list uchar float vertex_indices"),
         "floating-point numbers, not vertex indices"),
        (lambda d: d.replace(b"property float z\n", b""), "lacks x, y or z"),
        (lambda d: d.replace(b"format binary_little_endian", b"format binary_middle_endian"), "unknown PLY format"),
        (lambda d: d.replace(b"element face 8\nproperty list uchar int vertex_indices\n", b""), "no faces"),
    ],
)  # fmt: skip
def test_broken_binary_ply_says_why(tmp_path, mangle, reason):
    path = tmp_path / "broken.ply"
    path.write_bytes(mangle(ply("binary_little_endian")))
    with pytest.raises(LoadError, match=reason) as caught:
        load(path)
    assert "cannot read (" not in str(caught.value) and UNFORESEEN not in str(caught.value)


def test_ascii_ply_list_shorter_than_its_count_says_so(tmp_path):
    data = ply("ascii").replace(b"\n4 0 1 7 6\n", b"\n4 0 1 7\n")
    path = tmp_path / "short-list.ply"
    path.write_bytes(data)
    with pytest.raises(LoadError, match="list announces 4 values but has 3") as caught:
        load(path)
    assert "weights" not in str(caught.value)


def test_binary_ply_with_a_negative_list_length_says_so(tmp_path):
    data = ply("binary_little_endian", count="char")
    head = data.index(b"end_header\n") + len(b"end_header\n") + 12 * 12
    data = data[:head] + struct.pack("<b", -3) + data[head + 1 :]
    path = tmp_path / "negative.ply"
    path.write_bytes(data)
    with pytest.raises(LoadError, match="negative length"):
        load(path)
