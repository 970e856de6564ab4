"""VRML 1.0 and 2.0: what the reader makes of hand-written files with known answers.

Expected values are geometry worked out by hand (a unit cube has area 6 and volume 1; a
point rotated a quarter turn about z goes from (1, 0, 0) to (0, 1, 0); ...), never numbers
taken from the reader's own output.
"""

from __future__ import annotations

import gzip
import math

import numpy as np
import pytest

from shapeidx.errors import LoadError
from shapeidx.io import load
from shapeidx.io.vrml.geometry import RINGS, SEGMENTS
from test_vrml_support import (
    CUBE_INDEX,
    CUBE_INDEX_CLOCKWISE,
    CUBE_POINTS,
    CUBE_SHAPE,
    FIXTURES,
    bounds,
    measure,
    read,
    vrml1,
    vrml2,
    write,
)

QUARTER = math.pi / 2


def triangle_at(x: float) -> str:
    """A right triangle of area 0.5 in the plane z = 0, with its corner at (x, 0, 0)."""
    return (
        f"Shape {{ geometry IndexedFaceSet {{ coord Coordinate {{ point [ {x} 0 0, {x + 1} 0 0, {x} 1 0 ] }} "
        "coordIndex [ 0 1 2 ] } }"
    )


# -- the basics -----------------------------------------------------------------------------


def test_unit_cube_from_a_fixture():
    mesh = load(FIXTURES / "cube.wrl")
    assert mesh.format == "vrml2"
    assert mesh.polygon_count == 6 and set(mesh.face_sizes) == {4}
    triangles, area, volume = measure(mesh)
    assert (triangles, area) == (12, pytest.approx(6.0))
    assert volume == pytest.approx(1.0)  # counter-clockwise seen from outside
    assert mesh.warnings == []


def test_units_are_never_rescaled(tmp_path):
    mesh = read(tmp_path, vrml2(f"Transform {{ scale 1000 1000 1000 children {CUBE_SHAPE} }}"))
    np.testing.assert_allclose(bounds(mesh), [[0, 0, 0], [1000, 1000, 1000]])


# -- lexical forms: every variant is the same unit cube -------------------------------------

LEXICAL_VARIANTS = {
    "comments everywhere": (
        "#VRML V2.0 utf8\n# a comment\nShape # after a name\n{ geometry IndexedFaceSet {\n"
        "coord Coordinate { point [ # inside a number list ]\n" + CUBE_POINTS + " # ] not the end\n] }\n"
        "coordIndex [ " + CUBE_INDEX + " ] } } # at the end"
    ),
    "commas as white space": vrml2(
        "Shape,{,geometry,IndexedFaceSet,{,coord,Coordinate,{,point,[,"
        + CUBE_POINTS.replace(" ", ",")
        + ",],},coordIndex,[,"
        + CUBE_INDEX.replace(" ", ",")
        + "],},}"
    ),
    "no white space between tokens": vrml2(
        "Shape{geometry IndexedFaceSet{coord Coordinate{point[" + CUBE_POINTS + "]}coordIndex[" + CUBE_INDEX + "]}}"
    ),
    "number forms": vrml2(
        "Shape { geometry IndexedFaceSet { coord Coordinate { point [ -0. 0 0, 1. 0 0, +1. 1e0 0, .0 1. -0,"
        " 0 0 10e-1, 100e-2 0. +1, 1 1 1.0e+0, 0 1 1 ] } coordIndex [ " + CUBE_INDEX + " ] } }"
    ),
    "numbers written without separators": vrml2(
        "Shape { geometry IndexedFaceSet { coord Coordinate { point [ 0-0 0, 1 0 0, 1 1-0, 0 1 0, 0 0 1, 1 0 1,"
        " 1 1 1, 0 1 1 ] } coordIndex [ 0 3 2 1-1 4 5 6 7-1 0 1 5 4-1 3 7 6 2-1 0 4 7 3-1 1 2 6 5-1 ] } }"
    ),
    "CRLF line ends and tabs": vrml2(CUBE_SHAPE.replace(" ", "\t")).replace("\n", "\r\n").replace(",", ",\r\n"),
    "CR line ends only": vrml2(CUBE_SHAPE).replace("\n", "\r").replace(",", ",\r"),
    "final -1 left out": vrml2(CUBE_SHAPE.replace("1 2 6 5 -1 ]", "1 2 6 5 ]")),
    "brackets left out of a single value": vrml2(
        "Group { children Shape { geometry IndexedFaceSet { coord Coordinate { point [ "
        + CUBE_POINTS
        + " ] } coordIndex [ "
        + CUBE_INDEX
        + " ] } } }"
    ),
}


@pytest.mark.parametrize("variant", LEXICAL_VARIANTS)
def test_lexical_variants_read_as_the_same_cube(tmp_path, variant):
    mesh = read(tmp_path, LEXICAL_VARIANTS[variant])
    expected = np.array([float(v) for v in CUBE_POINTS.replace(",", " ").split()]).reshape(-1, 3)
    np.testing.assert_array_equal(mesh.vertices, expected)
    assert mesh.polygon_count == 6
    triangles, area, volume = measure(mesh)
    assert (triangles, area, volume) == (12, pytest.approx(6.0), pytest.approx(1.0))


def test_a_file_without_header_is_read_as_vrml2_with_a_warning(tmp_path):
    mesh = read(tmp_path, CUBE_SHAPE)
    assert mesh.format == "vrml2" and mesh.polygon_count == 6
    assert any("header" in w for w in mesh.warnings)


@pytest.mark.parametrize(
    "header, word", [("#Inventor V2.1 ascii", "Inventor"), ("#X3D V3.2 utf8\nPROFILE Interchange", "X3D")]
)
def test_inventor_and_x3d_are_refused_clearly(tmp_path, header, word):
    with pytest.raises(LoadError) as caught:
        read(tmp_path, header + "\n" + CUBE_SHAPE)
    assert caught.value.line == 1 and word in caught.value.reason


def test_vrml1_strings_may_go_without_quotes(tmp_path):
    text = vrml1(
        "Separator { Texture2 { filename ../textures/wood.jpg wrapS REPEAT }"
        f" Coordinate3 {{ point [ {CUBE_POINTS} ] }} IndexedFaceSet {{ coordIndex [ {CUBE_INDEX} ] }} }}"
    )
    assert measure(read(tmp_path, text))[:2] == (12, pytest.approx(6.0))


@pytest.mark.parametrize(
    "word",
    [
        'a"b',  # read one token at a time: a word; read as a list of tokens: a string up to the next quote
        "a#b",  # ... or a comment up to the end of the line
    ],
)
def test_vrml1_strings_without_quotes_may_hold_quotes_and_hashes(tmp_path, word):
    # 200 of them on one line: the token list is rebuilt after each, across several windows
    infos = f"Info {{ string {word} }} " * 200
    text = vrml1(f'Separator {{ {infos} Info {{ string "quoted" }} Cube {{ }} }}')
    assert measure(read(tmp_path, text))[:2] == (12, pytest.approx(24.0))  # the 2 x 2 x 2 cube


# -- VRML 2.0 transforms --------------------------------------------------------------------


@pytest.mark.parametrize(
    "fields, moved_corner",
    [
        ("translation 1 2 3", (2, 2, 3)),  # the corner (1, 0, 0) of triangle_at(0)
        (f"rotation 0 0 1 {QUARTER}", (0, 1, 0)),
        ("scale 2 3 4", (2, 0, 0)),
        # a quarter turn about (1, 1, 0) moves (1, 0, 0) to (2, 1, 0)
        (f"center 1 1 0 rotation 0 0 1 {QUARTER}", (2, 1, 0)),
        # scaling x2 along the diagonal (1, 1, 0)/sqrt2: (1, 0, 0) = ((1,1) + (1,-1))/2 -> (1.5, 0.5, 0)
        (f"scale 2 1 1 scaleOrientation 0 0 1 {QUARTER / 2}", (1.5, 0.5, 0)),
        # all together: scale about the centre, rotate about it, then translate
        (f"translation 0 0 5 center 1 0 0 scale 3 1 1 rotation 0 0 1 {QUARTER}", (1, 0, 5)),
    ],
)
def test_transform_fields_place_points_as_the_specification_says(tmp_path, fields, moved_corner):
    mesh = read(tmp_path, vrml2(f"Transform {{ {fields} children {triangle_at(0)} }}"))
    np.testing.assert_allclose(mesh.vertices[1], moved_corner, atol=1e-12)


def test_nested_transforms_apply_inner_first(tmp_path):
    # inner: move +1 in x; outer: quarter turn about z. (1, 0, 0) -> (2, 0, 0) -> (0, 2, 0)
    text = vrml2(
        f"Transform {{ rotation 0 0 1 {QUARTER} children Transform {{ translation 1 0 0 children {triangle_at(0)} }} }}"
    )
    np.testing.assert_allclose(read(tmp_path, text).vertices[1], (0, 2, 0), atol=1e-12)


@pytest.mark.parametrize("group", ["Group", "Anchor", "Billboard", "Collision", "Transform"])
def test_grouping_nodes_keep_their_children(tmp_path, group):
    text = vrml2(f"{group} {{ children [ {triangle_at(0)} {triangle_at(5)} ] }}")
    assert measure(read(tmp_path, text))[:2] == (2, pytest.approx(1.0))


def test_switch_shows_only_which_choice(tmp_path):
    choices = " ".join(triangle_at(x) for x in (0, 10, 20))
    assert (
        bounds(read(tmp_path, vrml2(f"Switch {{ whichChoice 1 choice [ {choices} ] }} {triangle_at(50)}")))[0, 0] == 10
    )
    mesh = read(tmp_path, vrml2(f"Switch {{ whichChoice -1 choice [ {choices} ] }} {triangle_at(50)}"))
    assert bounds(mesh)[0, 0] == 50  # -1: none (the default too)
    mesh = read(tmp_path, vrml2(f"Switch {{ choice [ {choices} ] }} {triangle_at(50)}"))
    assert bounds(mesh)[0, 0] == 50


def test_lod_shows_its_first_level(tmp_path):
    mesh = read(tmp_path, vrml2(f"LOD {{ range [ 10 ] level [ {triangle_at(3)} {triangle_at(30)} ] }}"))
    np.testing.assert_allclose(bounds(mesh)[:, 0], [3, 4])


# -- winding --------------------------------------------------------------------------------


def test_ccw_false_is_flipped_to_counter_clockwise(tmp_path):
    text = vrml2(
        f"Shape {{ geometry IndexedFaceSet {{ ccw FALSE coord Coordinate {{ point [ {CUBE_POINTS} ] }}"
        f" coordIndex [ {CUBE_INDEX_CLOCKWISE} ] }} }}"
    )
    assert measure(read(tmp_path, text))[2] == pytest.approx(1.0)


@pytest.mark.parametrize("scale", ["-1 1 1", "1 -2 1", "-1 -1 -1"])
def test_a_mirroring_transform_keeps_the_surface_outward(tmp_path, scale):
    mesh = read(tmp_path, vrml2(f"Transform {{ scale {scale} children {CUBE_SHAPE} }}"))
    volume = abs(np.prod([float(s) for s in scale.split()]))
    assert measure(mesh)[2] == pytest.approx(volume)


def test_flips_cancel_ccw_false_under_a_mirror(tmp_path):
    # clockwise polygons marked ccw FALSE, then mirrored: outward again after both flips
    shape = (
        f"Shape {{ geometry IndexedFaceSet {{ ccw FALSE coord Coordinate {{ point [ {CUBE_POINTS} ] }}"
        f" coordIndex [ {CUBE_INDEX_CLOCKWISE} ] }} }}"
    )
    assert measure(read(tmp_path, vrml2(f"Transform {{ scale 1 1 -1 children {shape} }}")))[2] == pytest.approx(1.0)


# -- polygons -------------------------------------------------------------------------------

L_HEXAGON = "0 0 0, 3 0 0, 3 1 0, 1 1 0, 1 2 0, 0 2 0"  # area 4, concave at (1, 1)


@pytest.mark.parametrize("convex", ["", "convex TRUE", "convex FALSE"])
def test_concave_polygons_are_triangulated_correctly_even_if_marked_convex(tmp_path, convex):
    text = vrml2(
        f"Shape {{ geometry IndexedFaceSet {{ {convex} coord Coordinate {{ point [ {L_HEXAGON} ] }} coordIndex [ 0 1 2 3 4 5 ] }} }}"
    )
    mesh = read(tmp_path, text)
    assert mesh.face_sizes.tolist() == [6]  # kept as one polygon, triangulated later
    assert measure(mesh)[:2] == (4, pytest.approx(4.0))


def test_out_of_range_indices_are_dropped_with_a_warning(tmp_path):
    text = vrml2(
        "Shape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0, 1 0 0, 1 1 0, 0 1 0 ] }"
        " coordIndex [ 0 1 7 2 3 -1, 0 -4 1 -1, 2 99 3 -1 ] } }"
    )
    mesh = read(tmp_path, text)
    assert mesh.face_sizes.tolist() == [4]  # the quad without its 7; the others fall below 3
    assert mesh.face_indices.tolist() == [0, 1, 2, 3]
    assert any("out-of-range" in w for w in mesh.warnings)
    assert any("fewer than three" in w for w in mesh.warnings)


# -- DEF / USE, PROTO and what is ignored ---------------------------------------------------


def test_def_use_shares_geometry_coordinates_and_nodes(tmp_path):
    text = vrml2(
        "DEF C Coordinate { point [ 0 0 0, 1 0 0, 0 1 0 ] }\n"  # a DEF outside any Shape is fine
        "DEF T Shape { geometry DEF G IndexedFaceSet { coord USE C coordIndex [ 0 1 2 ] } }\n"
        "Transform { translation 10 0 0 children USE T }\n"
        "Transform { translation 20 0 0 children Shape { geometry USE G } }\n"
        "Transform { translation 30 0 0 children Shape { geometry IndexedFaceSet { coord USE C coordIndex [ 0 2 1 ] } } }"
    )
    mesh = read(tmp_path, text)
    assert measure(mesh)[:2] == (4, pytest.approx(2.0))
    np.testing.assert_allclose(bounds(mesh)[:, 0], [0, 31])


def test_face_sets_sharing_coordinates_share_their_vertices(tmp_path):
    # the two halves of the cube use one Coordinate: its 8 points are placed once
    first, second = CUBE_INDEX.split(", 0 1 5 4")
    text = vrml2(
        f"Shape {{ geometry IndexedFaceSet {{ coord DEF C Coordinate {{ point [ {CUBE_POINTS} ] }} coordIndex [ {first} ] }} }}\n"
        f"Shape {{ geometry IndexedFaceSet {{ coord USE C coordIndex [ 0 1 5 4{second} ] }} }}"
    )
    mesh = read(tmp_path, text)
    assert len(mesh.vertices) == 8 and mesh.polygon_count == 6
    assert measure(mesh) == (12, pytest.approx(6.0), pytest.approx(1.0))


def test_proto_instances_are_expanded_with_their_fields(tmp_path):
    text = vrml2(
        "PROTO Plate [ field SFVec3f size 1 1 1  field SFVec3f at 0 0 0 ] {\n"
        "  Transform { translation IS at children Shape { geometry Box { size IS size } } }\n"
        "  Shape { geometry Box { } }  # not the first node of the body: not drawn\n"
        "}\n"
        "Plate { size 2 1 1 }\n"
        "Plate { at 10 0 0 }\n"
    )
    mesh = read(tmp_path, text)
    assert measure(mesh)[1] == pytest.approx((2 * 2 + 2 * 2 + 1 * 2) + 6)  # 2x1x1 box + unit box
    np.testing.assert_allclose(bounds(mesh)[:, 0], [-1, 10.5])


def test_nested_proto_fields_pass_through_is(tmp_path):
    text = vrml2(
        "PROTO Inner [ field SFVec3f s 1 1 1 ] { Shape { geometry Box { size IS s } } }\n"
        "PROTO Outer [ field SFVec3f s 1 1 1 ] { Group { children [ Inner { s IS s } ] } }\n"
        "Outer { s 1 2 3 }"
    )
    assert measure(read(tmp_path, text))[1] == pytest.approx(2 * (2 + 3 + 6))


def test_externproto_is_skipped_with_a_warning(tmp_path):
    text = vrml2(
        'EXTERNPROTO Gear [ field SFFloat teeth ] [ "gears.wrl#Gear" "urn:web3d:gear" ]\n'
        f"Gear {{ teeth 12 }}\n{CUBE_SHAPE}"
    )
    mesh = read(tmp_path, text)
    assert measure(mesh)[:2] == (12, pytest.approx(6.0))
    assert any("EXTERNPROTO Gear" in w for w in mesh.warnings)


def test_lines_points_text_sensors_routes_and_scripts_are_ignored(tmp_path):
    text = vrml2(
        'Viewpoint { position 0 0 10 }  NavigationInfo { type "EXAMINE" }\n'
        "DEF Clock TimeSensor { loop TRUE }\n"
        "DEF Turn OrientationInterpolator { key [ 0 1 ] keyValue [ 0 1 0 0, 0 1 0 3.14 ] }\n"
        "DEF Spin Transform { children [\n"
        "  Shape { geometry IndexedLineSet { coord Coordinate { point [ 0 0 0, 5 5 5 ] } coordIndex [ 0 1 ] } }\n"
        "  Shape { geometry PointSet { coord Coordinate { point [ 9 9 9 ] } } }\n"
        '  Shape { geometry Text { string [ "9 9 9" ] } }\n'
        "  TouchSensor { }\n"
        f"  {CUBE_SHAPE}\n"
        "] }\n"
        'DEF S Script { eventIn SFFloat tick field SFNode target USE Spin url "javascript: function tick(v) { }" }\n'
        "ROUTE Clock.fraction_changed TO Turn.set_fraction\n"
        "ROUTE Turn.value_changed TO Spin.set_rotation\n"
    )
    mesh = read(tmp_path, text)
    assert measure(mesh)[:2] == (12, pytest.approx(6.0))
    np.testing.assert_allclose(bounds(mesh), [[0, 0, 0], [1, 1, 1]])
    assert mesh.warnings == []


# -- primitives -----------------------------------------------------------------------------


def inscribed_prism_area(radius: float, height: float, caps: int = 2, side: bool = True) -> float:
    """Area of a prism over the regular SEGMENTS-gon inscribed in a circle of ``radius``."""
    polygon_area = 0.5 * SEGMENTS * radius**2 * math.sin(2 * math.pi / SEGMENTS)
    perimeter = 2 * SEGMENTS * radius * math.sin(math.pi / SEGMENTS)
    return caps * polygon_area + (perimeter * height if side else 0.0)


def test_box_size_is_honoured(tmp_path):
    mesh = read(tmp_path, vrml2("Shape { geometry Box { size 1 2 3 } }"))
    triangles, area, volume = measure(mesh)
    assert (triangles, area, volume) == (12, pytest.approx(22.0), pytest.approx(6.0))
    np.testing.assert_allclose(bounds(mesh), [[-0.5, -1, -1.5], [0.5, 1, 1.5]])


def test_cylinder_is_an_inscribed_prism_close_to_the_true_cylinder(tmp_path):
    mesh = read(tmp_path, vrml2("Shape { geometry Cylinder { radius 2 height 3 } }"))
    triangles, area, volume = measure(mesh)
    assert area == pytest.approx(inscribed_prism_area(2, 3))
    assert area == pytest.approx(2 * math.pi * 2 * (2 + 3), rel=0.01)
    assert volume == pytest.approx(math.pi * 4 * 3, rel=0.01) and volume > 0
    np.testing.assert_allclose(bounds(mesh)[:, 1], [-1.5, 1.5])


@pytest.mark.parametrize(
    "flags, caps, side", [("top FALSE", 1, True), ("top FALSE bottom FALSE", 0, True), ("side FALSE", 2, False)]
)
def test_cylinder_parts_can_be_left_out(tmp_path, flags, caps, side):
    mesh = read(tmp_path, vrml2(f"Shape {{ geometry Cylinder {{ {flags} }} }}"))
    assert measure(mesh)[1] == pytest.approx(inscribed_prism_area(1, 2, caps, side))


def test_cone_and_sphere_are_close_to_the_true_surfaces(tmp_path):
    cone = read(tmp_path, vrml2("Shape { geometry Cone { bottomRadius 1 height 2 } }"))
    true_cone = math.pi * 1 * (1 + math.sqrt(1 + 4))
    assert measure(cone)[1] == pytest.approx(true_cone, rel=0.01)
    assert measure(cone)[2] == pytest.approx(math.pi * 2 / 3, rel=0.02)
    assert measure(read(tmp_path, vrml2("Shape { geometry Cone { bottom FALSE } }")))[0] == SEGMENTS
    sphere = read(tmp_path, vrml2("Shape { geometry Sphere { radius 2 } }"))
    triangles, area, volume = measure(sphere)
    assert triangles == 2 * SEGMENTS * (RINGS - 1)
    assert area == pytest.approx(4 * math.pi * 4, rel=0.01)
    assert volume == pytest.approx(4 / 3 * math.pi * 8, rel=0.02)
    np.testing.assert_allclose(np.linalg.norm(sphere.vertices, axis=1), 2.0)


# -- VRML 1.0 state -------------------------------------------------------------------------

V1_TRIANGLE = "Coordinate3 { point [ 0 0 0, 1 0 0, 0 1 0 ] } IndexedFaceSet { coordIndex [ 0 1 2 ] }"


def test_vrml1_separator_restores_all_state(tmp_path):
    text = vrml1(
        "Separator {\n"
        "  Coordinate3 { point [ 0 0 0, 1 0 0, 0 1 0 ] }\n"
        "  Separator { Translation { translation 10 0 0 } Coordinate3 { point [ 5 5 5, 6 5 5, 5 6 5 ] }"
        "    ShapeHints { vertexOrdering CLOCKWISE } }\n"
        "  IndexedFaceSet { coordIndex [ 0 1 2 ] }\n"
        "}"
    )
    mesh = read(tmp_path, text)
    np.testing.assert_allclose(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert mesh.face_indices.tolist() == [0, 1, 2]  # not flipped


def test_vrml1_transform_separator_restores_only_the_transform(tmp_path):
    text = vrml1(
        "Separator {\n"
        "  TransformSeparator { Translation { translation 10 0 0 } Coordinate3 { point [ 0 0 0, 2 0 0, 0 2 0 ] } }\n"
        "  IndexedFaceSet { coordIndex [ 0 1 2 ] }\n"
        "}"
    )
    np.testing.assert_allclose(read(tmp_path, text).vertices, [[0, 0, 0], [2, 0, 0], [0, 2, 0]])


def test_vrml1_group_and_switch_let_state_through(tmp_path):
    text = vrml1(
        "Separator {\n"
        "  Group { Translation { translation 10 0 0 } }\n"
        "  Switch { whichChild 0 Translation { translation 0 20 0 } }\n"
        f"  {V1_TRIANGLE}\n"
        "}"
    )
    np.testing.assert_allclose(read(tmp_path, text).vertices[0], [10, 20, 0])


def test_vrml1_switch_choices(tmp_path):
    def cube_at(x):
        return f"Separator {{ Translation {{ translation {x} 0 0 }} Cube {{ }} }}"

    children = " ".join(cube_at(x) for x in (0, 10, 20))
    mesh = read(tmp_path, vrml1(f"Separator {{ Switch {{ whichChild -3 {children} }} }}"))
    assert measure(mesh)[1] == pytest.approx(3 * 24)  # -3: all children (Cube is 2 x 2 x 2)
    mesh = read(tmp_path, vrml1(f"Separator {{ Switch {{ whichChild 2 {children} }} }}"))
    np.testing.assert_allclose(bounds(mesh)[:, 0], [19, 21])
    mesh = read(tmp_path, vrml1(f"Separator {{ Switch {{ {children} }} Cube {{ depth 4 }} }}"))
    assert measure(mesh)[1] == pytest.approx(2 * (4 + 8 + 8))  # default -1: none


def test_vrml1_transform_nodes_accumulate(tmp_path):
    text = vrml1(
        "Separator {\n"
        "  Translation { translation 1 0 0 }\n"
        f"  Rotation {{ rotation 0 0 1 {QUARTER} }}\n"  # applied to what follows: (1, 0, 0) -> (0, 1, 0)
        "  Scale { scaleFactor 2 2 2 }\n"
        "  Transform { translation 0 0 3 scaleFactor 1 1 1 }\n"
        f"  {V1_TRIANGLE}\n"
        "}"
    )
    # corner (1, 0, 0): +z3 -> (1, 0, 3); x2 -> (2, 0, 6); turn -> (0, 2, 6); +x1 -> (1, 2, 6)
    np.testing.assert_allclose(read(tmp_path, text).vertices[1], [1, 2, 6], atol=1e-12)


def test_vrml1_matrix_transform_is_in_row_vector_order(tmp_path):
    # translation (5, 6, 7) sits in the last row, as Inventor writes it
    text = vrml1(f"Separator {{ MatrixTransform {{ matrix 1 0 0 0  0 1 0 0  0 0 1 0  5 6 7 1 }} {V1_TRIANGLE} }}")
    np.testing.assert_allclose(read(tmp_path, text).vertices[0], [5, 6, 7])


def test_vrml1_clockwise_shape_hints_flip_winding(tmp_path):
    text = vrml1(
        "Separator { ShapeHints { vertexOrdering CLOCKWISE }"
        f" Coordinate3 {{ point [ {CUBE_POINTS} ] }} IndexedFaceSet {{ coordIndex [ {CUBE_INDEX_CLOCKWISE} ] }} }}"
    )
    assert measure(read(tmp_path, text))[2] == pytest.approx(1.0)


def test_vrml1_primitives_honour_sizes_and_parts(tmp_path):
    mesh = read(tmp_path, vrml1("Cube { width 1 height 2 depth 3 }"))
    assert measure(mesh)[1:] == (pytest.approx(22.0), pytest.approx(6.0))
    mesh = read(tmp_path, vrml1("Cylinder { parts (SIDES | TOP) radius 2 height 3 }"))
    assert measure(mesh)[1] == pytest.approx(inscribed_prism_area(2, 3, caps=1))
    mesh = read(tmp_path, vrml1("Cone { parts BOTTOM }"))
    assert measure(mesh)[0] == SEGMENTS - 2
    mesh = read(tmp_path, vrml1("Sphere { radius 3 }"))
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1), 3.0)


# -- files: names, gzip, Inline -------------------------------------------------------------


@pytest.mark.parametrize("name", ["part.wrl", "PART.WRL", "part.wrz", "part.vrml", "part.wrl.gz", "part.WRZ"])
@pytest.mark.parametrize("compressed", [False, True])
def test_load_reads_vrml_by_name_and_gzip_by_content(tmp_path, name, compressed):
    data = (FIXTURES / "cube.wrl").read_bytes()
    path = tmp_path / name
    path.write_bytes(gzip.compress(data) if compressed else data)
    mesh = load(path)
    assert mesh.format == "vrml2" and measure(mesh)[:2] == (12, pytest.approx(6.0))


def test_load_sniffs_vrml_without_a_known_suffix(tmp_path):
    path = tmp_path / "part.export"
    path.write_bytes((FIXTURES / "cube.wrl").read_bytes())
    assert load(path).format == "vrml2"


def test_inline_brings_in_a_relative_file_with_its_transform(tmp_path):
    write(
        tmp_path,
        vrml1(f"Coordinate3 {{ point [ {CUBE_POINTS} ] }} IndexedFaceSet {{ coordIndex [ {CUBE_INDEX} ] }}"),
        "parts/cube1.wrl",
    )
    (tmp_path / "parts" / "cube2.wrz").write_bytes(gzip.compress(vrml2(CUBE_SHAPE).encode()))
    mesh = read(
        tmp_path,
        vrml2(
            'Inline { url "parts/cube1.wrl" }\n'
            'Transform { translation 5 0 0 children Inline { url [ "http://example.com/cube.wrl" "parts/cube2.wrz" ] } }'
        ),
    )
    assert measure(mesh)[:3] == (24, pytest.approx(12.0), pytest.approx(2.0))
    np.testing.assert_allclose(bounds(mesh)[:, 0], [0, 6])
    assert mesh.format == "vrml2" and mesh.warnings == []


def test_vrml1_wwwinline(tmp_path):
    write(tmp_path, vrml2(CUBE_SHAPE), "cube.wrl")
    mesh = read(tmp_path, vrml1("Separator { Translation { translation 0 0 7 } WWWInline { name cube.wrl } }"))
    np.testing.assert_allclose(bounds(mesh)[:, 2], [7, 8])
