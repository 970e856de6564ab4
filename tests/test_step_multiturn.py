"""Faces that go round their periodic surface more than once (docs/assemblies.md: the pins of
the KiCad TEZ/CHK transformers), read by shapeidx as one turn.

The answers do not come from the repair's own reasoning: a real transformer is checked against
KiCad's VRML export of the same model (its area, its pins), and a cylinder band against 2 pi r h.
The band is made the way the real files make it: a STEP face whose two boundary circles run
opposite ways, which OpenCASCADE reads as a face spanning two turns (-2 pi .. 2 pi); written out
again by OpenCASCADE's STEP writer, alone and as an assembly of three placed copies.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from clitools import cli
from test_step import placement, write_assembly, write_step

from shapeidx.io import LoadLimits, load
from shapeidx.io.parts import split_parts
from shapeidx.io.polygons import fan_triangles, triangle_areas

pytest.importorskip("OCP", reason="cadquery-ocp-novtk (OpenCASCADE) is a dependency of shapeidx")

EI54 = "Transformer_THT/Transformer_CHK_EI54-12VA_Neutral"
#: KiCad's VRML unit (0.1 inch) in mm: areas scale by its square
VRML_UNIT = 2.54
#: An ordinary part: no face on it goes round more than once
ORDINARY = "Capacitor_THT/C_Axial_L5.1mm_D3.1mm_P10.00mm_Horizontal"

RADIUS, HEIGHT = 2.0, 3.0

#: A cylinder face (r = 2, h = 3) bounded by its seam and its two circles, the bottom circle's
#: axis opposite to the surface's, as KiCad's transformer pins are written (no pcurves).
BAND_STEP = """ISO-10303-21;
HEADER;
FILE_DESCRIPTION(('a cylinder band'),'2;1');
FILE_NAME('band.step','2024-01-01T00:00:00',(''),(''),'','','');
FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));
ENDSEC;
DATA;
#1 = APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',2000,#2);
#2 = APPLICATION_CONTEXT('core data for automotive mechanical design processes');
#3 = SHAPE_DEFINITION_REPRESENTATION(#4,#10);
#4 = PRODUCT_DEFINITION_SHAPE('','',#5);
#5 = PRODUCT_DEFINITION('design','',#6,#9);
#6 = PRODUCT_DEFINITION_FORMATION('','',#7);
#7 = PRODUCT('band','band','',(#8));
#8 = PRODUCT_CONTEXT('',#2,'mechanical');
#9 = PRODUCT_DEFINITION_CONTEXT('part definition',#2,'design');
#10 = MANIFOLD_SURFACE_SHAPE_REPRESENTATION('',(#11,#15),#81);
#11 = AXIS2_PLACEMENT_3D('',#12,#13,#14);
#12 = CARTESIAN_POINT('',(0.,0.,0.));
#13 = DIRECTION('',(0.,0.,1.));
#14 = DIRECTION('',(1.,0.,0.));
#15 = SHELL_BASED_SURFACE_MODEL('',(#16));
#16 = OPEN_SHELL('',(#17));
#17 = ADVANCED_FACE('',(#18),#32,.T.);
#18 = FACE_BOUND('',#19,.T.);
#19 = EDGE_LOOP('',(#20,#50,#65,#66));
#20 = ORIENTED_EDGE('',*,*,#21,.F.);
#21 = EDGE_CURVE('',#22,#24,#27,.T.);
#22 = VERTEX_POINT('',#23);
#23 = CARTESIAN_POINT('',(2.,0.,0.));
#24 = VERTEX_POINT('',#25);
#25 = CARTESIAN_POINT('',(2.,0.,3.));
#27 = LINE('',#28,#29);
#28 = CARTESIAN_POINT('',(2.,0.,0.));
#29 = VECTOR('',#30,1.);
#30 = DIRECTION('',(0.,0.,1.));
#32 = CYLINDRICAL_SURFACE('',#33,2.);
#33 = AXIS2_PLACEMENT_3D('',#34,#35,#36);
#34 = CARTESIAN_POINT('',(0.,0.,0.));
#35 = DIRECTION('',(0.,0.,1.));
#36 = DIRECTION('',(1.,0.,0.));
#50 = ORIENTED_EDGE('',*,*,#51,.T.);
#51 = EDGE_CURVE('',#22,#22,#53,.T.);
#53 = CIRCLE('',#54,2.);
#54 = AXIS2_PLACEMENT_3D('',#55,#56,#57);
#55 = CARTESIAN_POINT('',(0.,0.,0.));
#56 = DIRECTION('',(0.,0.,-1.));
#57 = DIRECTION('',(1.,0.,0.));
#65 = ORIENTED_EDGE('',*,*,#21,.T.);
#66 = ORIENTED_EDGE('',*,*,#67,.F.);
#67 = EDGE_CURVE('',#24,#24,#69,.T.);
#69 = CIRCLE('',#70,2.);
#70 = AXIS2_PLACEMENT_3D('',#71,#72,#73);
#71 = CARTESIAN_POINT('',(0.,0.,3.));
#72 = DIRECTION('',(0.,0.,1.));
#73 = DIRECTION('',(1.,0.,0.));
#81 = ( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#85))
GLOBAL_UNIT_ASSIGNED_CONTEXT((#82,#83,#84)) REPRESENTATION_CONTEXT('Context #1',
'3D Context with UNIT and UNCERTAINTY') );
#82 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );
#83 = ( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) );
#84 = ( NAMED_UNIT(*) SI_UNIT($,.STERADIAN.) SOLID_ANGLE_UNIT() );
#85 = UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.E-07),#82,'distance_accuracy_value',
'confusion accuracy');
ENDSEC;
END-ISO-10303-21;
"""


def area(mesh) -> float:
    return float(triangle_areas(np.asarray(mesh.vertices, dtype=np.float64), fan_triangles(mesh)).sum())


def as_read_by_opencascade(path: Path):
    """The file's shape as OpenCASCADE's plain reader gives it (no shapeidx in between)."""
    from OCP.STEPControl import STEPControl_Reader

    from shapeidx.io.step import quiet_opencascade

    quiet_opencascade()
    reader = STEPControl_Reader()
    assert str(reader.ReadFile(str(path))).endswith("RetDone")
    reader.TransferRoots()
    return reader.OneShape()


def turns_of_faces(shape) -> list:
    """How many times each face's parameter range covers its surface's period (u)."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepTools import BRepTools
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    out, explorer = [], TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        face = TopoDS.Face(explorer.Current())
        u0, u1, _, _ = BRepTools.UVBounds_s(face)
        out.append((u1 - u0) / BRep_Tool.Surface_s(face).UPeriod())
        explorer.Next()
    return out


@pytest.fixture(scope="module")
def band_files(tmp_path_factory) -> dict:
    """The band as written by hand, then by OpenCASCADE's writer alone and as three placed copies."""
    folder = tmp_path_factory.mktemp("band")
    by_hand = folder / "band_by_hand.step"
    by_hand.write_text(BAND_STEP)
    face = as_read_by_opencascade(by_hand)
    alone = write_step(face, folder / "band_rewritten.step")
    assembly = write_assembly(folder / "band_assembly.step", [
        (face, placement()),
        (face, placement((10.0, 0.0, 0.0))),
        (face, placement((0.0, 0.0, 20.0), rotate_x=math.pi / 2)),  # y -> z, z -> -y
    ])
    return {"by_hand": by_hand, "alone": alone, "assembly": assembly}


class TestCylinderBand:
    def test_opencascade_reads_the_fixture_as_two_turns(self, band_files):
        # what the test is about: without shapeidx, OpenCASCADE's face spans two periods
        for name in ("by_hand", "alone"):
            assert turns_of_faces(as_read_by_opencascade(band_files[name])) == [pytest.approx(2.0)]

    @pytest.mark.parametrize("name", ["by_hand", "alone"])
    def test_the_area_is_one_turn_of_the_cylinder(self, band_files, name):
        exact = 2 * math.pi * RADIUS * HEIGHT
        mesh = load(band_files[name])
        # an inscribed faceting: a little under the exact area, never over (before: 63 % of it)
        assert exact * (1 - 2e-3) <= area(mesh) <= exact
        assert not mesh.warnings

    def test_every_placed_copy_is_one_turn_in_its_place(self, band_files):
        exact = 2 * math.pi * RADIUS * HEIGHT
        mesh = load(band_files["assembly"])
        assert 3 * exact * (1 - 5e-3) <= area(mesh) <= 3 * exact
        v = np.asarray(mesh.vertices)
        boxes = [([-2, -2, 0], [2, 2, 3]), ([8, -2, 0], [12, 2, 3]), ([-2, -3, 18], [2, 0, 22])]
        owners = [np.all((v >= np.array(lo) - 1e-6) & (v <= np.array(hi) + 1e-6), axis=1) for lo, hi in boxes]
        assert all(o.sum() > 0 for o in owners) and sum(o.sum() for o in owners) == len(v)
        triangles = fan_triangles(mesh)
        areas = triangle_areas(v, triangles)
        # the three copies: the same area each
        copy_areas = [areas[owner[triangles].all(axis=1)].sum() for owner in owners]
        assert copy_areas == pytest.approx([copy_areas[0]] * 3, rel=1e-9)

    def test_faceting_report_counts_the_face(self, band_files, tmp_path):
        from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder

        from shapeidx.io.step import faceting_report

        assert faceting_report(band_files["by_hand"])["faces_unwound"] == 1
        plain = write_step(BRepPrimAPI_MakeCylinder(RADIUS, HEIGHT).Shape(), tmp_path / "cylinder.step")
        assert faceting_report(plain)["faces_unwound"] == 0
        result = cli("inspect", band_files["by_hand"])
        assert result.exit_code == 0
        assert "repaired    1 face going round their surface more than once, meshed as one turn" in result.stdout
        assert "repaired" not in cli("inspect", plain).stdout


class TestRealTransformer:
    def test_area_is_its_vrml_twins(self, data_dir):
        step = load(data_dir / "kicad6-step" / f"{EI54}.step")
        vrml = load(data_dir / "kicad6" / f"{EI54}.wrl")
        # KiCad's VRML of the same model, in 0.1 inch; the pin tips doubled and tripled made it 0.16 % more
        assert area(step) == pytest.approx(VRML_UNIT**2 * area(vrml), rel=3e-4)

    def test_its_fourteen_pins_are_one_part(self, data_dir):
        parts = split_parts(data_dir / "kicad6-step" / f"{EI54}.step")
        vrml_parts = split_parts(data_dir / "kicad6" / f"{EI54}.wrl")
        assert parts is not None and vrml_parts is not None
        body, pin = parts[0], parts[-1]
        # congruent pins (exact B-rep invariants within 1e-5): one sub-part, 14 of it (before: 11 and 3)
        assert len(parts) == 2 and body.count == 1 and pin.count == 14
        # the VRML's pins (split by connectivity, sizes to rounding): as many, of the same area
        pin_area = area(pin.mesh)
        vrml_pins = [p for p in vrml_parts if VRML_UNIT**2 * area(p.mesh) == pytest.approx(pin_area, rel=0.01)]
        assert sum(p.count for p in vrml_pins) == 14


class TestOrdinaryParts:
    def test_nothing_is_touched(self, data_dir, monkeypatch):
        import shapeidx.io.step as step

        path = data_dir / "kicad6-step" / f"{ORDINARY}.step"
        read = step.read_shape(path, None, LoadLimits())
        assert read.unwound == 0
        shapes = [read.shape]
        assert step.unwound(shapes) == (shapes, 0)  # the same objects back
        with_repair = step._read_step(path, LoadLimits(), "step", path.read_bytes())
        monkeypatch.setattr(step, "unwound", lambda shapes: (shapes, 0))
        without = step._read_step(path, LoadLimits(), "step", path.read_bytes())
        np.testing.assert_array_equal(with_repair.vertices, without.vertices)
        np.testing.assert_array_equal(with_repair.face_indices, without.face_indices)
