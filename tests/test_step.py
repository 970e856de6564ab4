"""STEP and IGES through OpenCASCADE: exact solids, units, assemblies, real KiCad parts, bad files, builds.

Solids made here are built by OpenCASCADE's own primitives (BRepPrimAPI) and written by its
STEP/IGES writers, so area, volume and placement have analytic answers that share nothing
with the reader; the real parts are the STEP twins of kicad6's VRML parts.
"""

from __future__ import annotations

import gzip
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from clitools import cli
from storetools import FAST_POINTS, build, summary_counts

from shapeidx.distance import compare
from shapeidx.errors import LoadError
from shapeidx.io import LoadLimits, format_of, load
from shapeidx.io.faceting import Faceting
from shapeidx.signing.pipeline import signature_of_solid, solid_of_file
from shapeidx.store import STATUS_FAILED, STATUS_OK, open_store

pytest.importorskip("OCP", reason="cadquery-ocp-novtk (OpenCASCADE) is a dependency of shapeidx")

#: Real STEP parts with their VRML twins (same class folder and base name in kicad6).
TWINS = (
    "Capacitor_THT/C_Axial_L5.1mm_D3.1mm_P10.00mm_Horizontal",
    "Package_SO/SOIC-14_3.9x8.7mm_P1.27mm",
    "Diode_THT/D_DO-35_SOD27_P5.08mm_Vertical_AnodeUp",
)
BATTERY = "Battery/BatteryHolder_Keystone_1042_1x18650"
#: An IGES file that crashes OpenCASCADE 8's reader (segmentation fault) unless shapeidx refuses it first.
HOLLERITH_OVERRUN = Path(__file__).parent / "data" / "step" / "hollerith_overrun.igs"


# --------------------------------------------------------------------------- solids made by OpenCASCADE


def _quiet():
    from shapeidx.io.step import quiet_opencascade

    quiet_opencascade()  # the writers report to stdout otherwise


def write_step(shape, path: Path, unit: str = "MM") -> Path:
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    _quiet()
    writer = STEPControl_Writer()
    Interface_Static.SetCVal_s("write.step.unit", unit)
    try:
        writer.Transfer(shape, STEPControl_AsIs)
        assert str(writer.Write(str(path))).endswith("RetDone")
    finally:
        Interface_Static.SetCVal_s("write.step.unit", "MM")
    return path


def box(dx=10.0, dy=20.0, dz=30.0):
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox

    return BRepPrimAPI_MakeBox(dx, dy, dz).Shape()


def cylinder(radius=5.0, height=12.0):
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder

    return BRepPrimAPI_MakeCylinder(radius, height).Shape()


def placement(translate=(0.0, 0.0, 0.0), rotate_x: float = 0.0):
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt, gp_Trsf, gp_Vec
    from OCP.TopLoc import TopLoc_Location

    rotation, translation = gp_Trsf(), gp_Trsf()
    rotation.SetRotation(gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)), rotate_x)
    translation.SetTranslation(gp_Vec(*translate))
    return TopLoc_Location(translation.Multiplied(rotation))


def write_assembly(path: Path, components) -> Path:
    """An XCAF assembly (NEXT_ASSEMBLY_USAGE_OCCURRENCE in the file): (shape, location) components."""
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    _quiet()
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    labels = {}
    assembly = tool.NewShape()
    for shape, location in components:
        key = id(shape)
        if key not in labels:
            labels[key] = tool.AddShape(shape, False)
        tool.AddComponent(assembly, labels[key], location)
    tool.UpdateAssemblies()
    writer = STEPCAFControl_Writer()
    writer.Transfer(doc, STEPControl_AsIs)
    assert str(writer.Write(str(path))).endswith("RetDone")
    return path


class TestExactSolids:
    def test_box_area_volume_and_all_in(self, tmp_path):
        solid = solid_of_file(write_step(box(), tmp_path / "box.step"))
        facts = solid.describe()
        assert facts["format"] == "step"
        assert facts["watertight"] and facts["shells"] == 1
        assert facts["area"] == pytest.approx(2 * (10 * 20 + 20 * 30 + 10 * 30), rel=1e-12)
        assert facts["volume"] == pytest.approx(10 * 20 * 30, rel=1e-12)
        np.testing.assert_allclose(facts["bounds"], [[0, 0, 0], [10, 20, 30]], atol=1e-9)
        assert signature_of_solid(solid, 256).fractions["in"] == 1.0

    def test_cylinder_converges_to_the_analytic_area_and_volume(self, tmp_path):
        path = write_step(cylinder(5.0, 12.0), tmp_path / "cyl.stp")
        area, volume = 2 * math.pi * 5 * (5 + 12), math.pi * 25 * 12
        diagonal = math.sqrt(10**2 + 10**2 + 12**2)
        errors = []
        for linear in (0.01, 0.002, 0.0002):
            solid = solid_of_file(path, LoadLimits(faceting=Faceting(linear, 0.5)))
            assert solid.watertight
            errors.append(abs(solid.volume - volume) / volume)
            # an inscribed faceting: never more than the exact solid
            assert solid.volume < volume and solid.describe()["area"] < area
            # an inscribed polygon of sagitta <= s misses at most 4 s / (3 r) of the disc's area
            assert errors[-1] <= 4 / 3 * linear * diagonal / 5.0
        assert errors[0] > errors[1] > errors[2]
        # the default faceting, measured: within 0.5% of the exact volume and 100% IN (convex)
        solid = solid_of_file(path)
        assert solid.volume == pytest.approx(volume, rel=5e-3)
        assert signature_of_solid(solid, 256).fractions["in"] == 1.0

    def test_chordal_error_is_measured_within_the_asked_deflection(self, tmp_path):
        from shapeidx.io.step import faceting_report

        path = write_step(cylinder(5.0, 12.0), tmp_path / "cyl.step")
        coarse = faceting_report(path, Faceting(0.01, 1.0))
        fine = faceting_report(path, Faceting(0.0005, 1.0))
        for report in (coarse, fine):
            assert 0 < report["max_chordal_error_mm"] <= report["deflection_mm"] * 1.01
            assert report["measured_points"] > 0
        assert fine["triangles"] > coarse["triangles"]
        assert fine["max_chordal_error_mm"] < 0.2 * coarse["max_chordal_error_mm"]

    def test_iges_faces_are_sewn_into_a_closed_solid(self, tmp_path):
        from OCP.IGESControl import IGESControl_Writer

        _quiet()
        writer = IGESControl_Writer("MM", 0)  # mode 0: faces with their own boundaries, not a B-rep solid
        writer.AddShape(cylinder(5.0, 12.0))
        writer.ComputeModel()
        path = tmp_path / "cyl.IGS"
        assert writer.Write(str(path))
        solid = solid_of_file(path)
        assert solid.describe()["format"] == "iges"
        assert solid.watertight
        assert solid.volume == pytest.approx(math.pi * 25 * 12, rel=5e-3)

    def test_a_free_face_is_kept_as_an_open_surface(self, tmp_path):
        from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
        from OCP.gp import gp_Pln

        face = BRepBuilderAPI_MakeFace(gp_Pln(), 0.0, 4.0, 0.0, 3.0).Face()
        solid = solid_of_file(write_step(face, tmp_path / "face.step"))
        facts = solid.describe()
        assert not facts["watertight"] and facts["volume"] is None
        assert facts["solid"]["open_shells"] == 1
        assert facts["area"] == pytest.approx(12.0)


class TestUnits:
    @pytest.mark.parametrize("unit, factor", [("M", 1000.0), ("INCH", 25.4), ("MM", 1.0)])
    def test_lengths_come_out_in_millimetres(self, tmp_path, unit, factor):
        from shapeidx.io.step import faceting_report

        path = write_step(box(10.0, 20.0, 30.0), tmp_path / f"box_{unit}.step", unit)
        text = path.read_text()
        # the file itself holds the box in its own unit: 0.01 m, 0.3937 inch, 10 mm
        assert {"M": "SI_UNIT($,.METRE.)", "INCH": "'INCH'", "MM": "SI_UNIT(.MILLI.,.METRE.)"}[unit] in text
        facts = solid_of_file(path).describe()
        np.testing.assert_allclose(facts["bounds"][1], [10.0, 20.0, 30.0], rtol=1e-9)
        assert facts["volume"] == pytest.approx(6000.0, rel=1e-9)
        units = faceting_report(path)["file_units"]
        assert units and units[0].lower() in {"M": ("metre",), "INCH": ("inch",), "MM": ("millimetre",)}[unit]


class TestAssemblies:
    def test_every_component_is_placed_by_its_location(self, tmp_path):
        part = box(10.0, 20.0, 30.0)
        path = write_assembly(tmp_path / "asm.step", [
            (part, placement()),
            (part, placement((100.0, 0.0, 0.0))),
            (part, placement((0.0, 0.0, 200.0), rotate_x=math.pi / 2)),  # y -> z, z -> -y
        ])
        assert path.read_text().count("NEXT_ASSEMBLY_USAGE_OCCURRENCE") == 3
        mesh = load(path)
        solid = solid_of_file(path)
        facts = solid.describe()
        assert facts["triangles"] == 3 * 12 and facts["shells"] == 3
        assert facts["volume"] == pytest.approx(3 * 6000.0)
        np.testing.assert_allclose(facts["bounds"], [[0, -30, 0], [110, 20, 220]], atol=1e-9)
        # each copy where its location puts it: the three boxes' corners
        boxes = [np.array([[0, 0, 0], [10, 20, 30]]), np.array([[100, 0, 0], [110, 20, 30]]),
                 np.array([[0, -30, 200], [10, 0, 220]])]
        v = mesh.vertices
        for lo, hi in boxes:
            inside = np.all((v >= lo - 1e-9) & (v <= hi + 1e-9), axis=1)
            assert inside.sum() > 0
        assert sum(np.all((v >= lo - 1e-9) & (v <= hi + 1e-9), axis=1).sum() for lo, hi in boxes) == len(v)

    def test_real_kicad_assembly_of_bodies(self, data_dir):
        # a KiCad STEP is an assembly of coloured bodies: all of them come out, in place, closed,
        # in mm; its VRML twin is in KiCad's VRML unit of 0.1 inch = 2.54 mm
        path = data_dir / "kicad6-step" / f"{BATTERY}.step"
        facts = solid_of_file(path).describe()
        vrml = solid_of_file(data_dir / "kicad6" / f"{BATTERY}.wrl").describe()
        assert facts["watertight"] and facts["shells"] > 1
        np.testing.assert_allclose(facts["bounds"], 2.54 * np.array(vrml["bounds"]), atol=0.05)


class TestRealParts:
    def test_step_signature_is_its_vrml_twins_within_resampling_noise(self, data_dir):
        for name in TWINS:
            step = solid_of_file(data_dir / "kicad6-step" / f"{name}.step")
            vrml = solid_of_file(data_dir / "kicad6" / f"{name}.wrl")
            # the noise first: three samplings of the same VRML mesh
            samplings = [signature_of_solid(vrml, seed=s) for s in (1, 2, 3)]
            noise = max(compare(a, b)["weighted"] for i, a in enumerate(samplings) for b in samplings[i + 1:])
            twin = signature_of_solid(step, seed=4)  # a fourth, independent sampling
            distances = [compare(twin, s)["weighted"] for s in samplings]
            assert max(distances) <= 1.5 * noise, (name, distances, noise)

    def test_gzip_upper_case_and_unknown_names_read_alike(self, data_dir, tmp_path):
        source = data_dir / "kicad6-step" / f"{TWINS[1]}.step"
        plain = load(source)
        zipped = tmp_path / "part.step.gz"
        zipped.write_bytes(gzip.compress(source.read_bytes()))
        upper = tmp_path / "PART.STP"
        shutil.copy(source, upper)
        unnamed = tmp_path / "part.dat"  # no known ending: sniffed from 'ISO-10303-21;'
        shutil.copy(source, unnamed)
        assert format_of(zipped) == format_of(upper) == "step" and format_of(unnamed) is None
        for other in (zipped, upper, unnamed):
            mesh = load(other)
            assert mesh.format == "step"
            np.testing.assert_array_equal(mesh.vertices, plain.vertices)
            np.testing.assert_array_equal(mesh.face_indices, plain.face_indices)

    def test_importing_shapeidx_does_not_load_opencascade(self):
        code = "import sys, shapeidx, shapeidx.io, shapeidx.cli, shapeidx.index.build, shapeidx.io.registry; print('OCP' in sys.modules)"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
        assert out.strip() == "False"


# --------------------------------------------------------------------------- bad files


def _bad_files(data_dir: Path, folder: Path) -> dict:
    """name -> (path, words its one-line reason must hold)."""
    real = (data_dir / "kicad6-step" / f"{TWINS[1]}.step").read_bytes()
    folder.mkdir(parents=True, exist_ok=True)
    files = {
        "empty.step": (b"", "empty"),
        "truncated.step": (real[: len(real) // 2], "truncated"),
        "notstep.stp": (b"solid? no, this is a text file\n" * 20, "not a STEP or IGES"),
        "header_only.step": (b"ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('x'),'2;1');\n"
                             b"FILE_NAME('x','2020-01-01T00:00:00',(''),(''),'','','');\n"
                             b"FILE_SCHEMA(('AUTOMOTIVE_DESIGN'));\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n",
                             "no geometry"),
        "points_only.step": (b"ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('x'),'2;1');\n"
                             b"FILE_NAME('x','2020-01-01T00:00:00',(''),(''),'','','');\n"
                             b"FILE_SCHEMA(('AUTOMOTIVE_DESIGN'));\nENDSEC;\nDATA;\n"
                             b"#1=CARTESIAN_POINT('',(0.,0.,0.));\nENDSEC;\nEND-ISO-10303-21;\n", "no "),
        "cut.igs": (b"x" * 72 + b"S0000001\n" + b"y" * 72 + b"G0000001\n", "truncated IGES"),
        "no_delimiters.igs": (b"x" * 72 + b"S0000001\n" + b"y" * 72 + b"G0000001\n" + b"S      1G      1D      0P      0".ljust(72)
                              + b"T0000001\n", "Global section: it does not start with its delimiters"),
        # OpenCASCADE's own cylinder with one Hollerith length made 308: OCCT 8 dies on it (SIGSEGV)
        "hollerith_overrun.igs": (HOLLERITH_OVERRUN.read_bytes(), "a 308-character string runs past the end"),
    }
    out = {}
    for name, (content, words) in files.items():
        (folder / name).write_bytes(content)
        out[name] = (folder / name, words)
    return out


class TestBadFiles:
    def test_each_gives_one_line_naming_the_file(self, data_dir, tmp_path):
        for name, (path, words) in _bad_files(data_dir, tmp_path).items():
            with pytest.raises(LoadError) as caught:
                load(path)
            message = str(caught.value)
            assert "\n" not in message and message.startswith(str(path)), message
            assert words in message, message

    def test_cli_inspect_prints_one_line_and_exits_1(self, data_dir, tmp_path):
        bad = _bad_files(data_dir, tmp_path)
        path, _ = bad["truncated.step"]
        result = cli("inspect", path)
        assert result.exit_code == 1
        assert result.stderr.strip().count("\n") == 0 and str(path) in result.stderr and "truncated" in result.stderr


def sliver_face():
    """A planar face whose boundary goes there and back along one line: zero area, and
    BRepMesh gives it no triangulation at all (how OpenCASCADE reports a face it cannot mesh)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.gp import gp_Pln, gp_Pnt

    wire = BRepBuilderAPI_MakePolygon(gp_Pnt(0, 0, 0), gp_Pnt(1, 0, 0), gp_Pnt(2, 0, 0), True).Wire()
    return BRepBuilderAPI_MakeFace(gp_Pln(), wire, True).Face()


def compound(*shapes):
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS_Compound

    out, builder = TopoDS_Compound(), BRep_Builder()
    builder.MakeCompound(out)
    for shape in shapes:
        builder.Add(out, shape)
    return out


class TestFacesThatDoNotTessellate:
    def test_the_other_faces_are_kept_with_one_warning(self, tmp_path):
        path = write_step(compound(box(), sliver_face()), tmp_path / "box_and_sliver.step")
        facts = solid_of_file(path).describe()
        # the box is whole (the sliver has no area to lose): 12 triangles, exact area and volume
        assert facts["triangles"] == 12 and facts["watertight"]
        assert facts["area"] == pytest.approx(2200.0) and facts["volume"] == pytest.approx(6000.0)
        assert facts["warnings"] == ["1 of 7 faces could not be tessellated and are left out (the surface has holes there)"]
        result = cli("inspect", path)
        assert result.exit_code == 0 and "warning     1 of 7 faces could not be tessellated" in result.stdout

    def test_a_file_of_faces_that_all_fail_gives_one_line_and_a_build_goes_on(self, data_dir, tmp_path):
        tree = tmp_path / "parts"
        tree.mkdir()
        bad = write_step(sliver_face(), tree / "sliver.step")
        with pytest.raises(LoadError) as caught:
            load(bad)
        assert str(caught.value) == f"{bad}: OpenCASCADE could not tessellate any of its 1 faces"
        result = cli("inspect", bad)
        assert result.exit_code == 1 and result.stderr.strip().count("\n") == 0 and "could not tessellate" in result.stderr
        write_step(compound(box(), sliver_face()), tree / "partial.step")
        shutil.copy(data_dir / "kicad6-step" / f"{TWINS[0]}.step", tree / "good.step")
        result = build(tree, tmp_path / "s.h5", "--workers", "1")
        assert result.exit_code == 0, result.output
        assert summary_counts(result.stdout) == {"indexed": 2, "unchanged": 0, "removed": 0, "failed": 1}
        with open_store(tmp_path / "s.h5") as reader:
            status = dict(zip(reader.paths, reader.column("entries/status")))
            reasons = dict(zip(reader.paths, reader.column("entries/reason")))
        assert status["partial.step"] == status["good.step"] == STATUS_OK
        assert status["sliver.step"] == STATUS_FAILED and "could not tessellate any of its 1 faces" in reasons["sliver.step"]


def write_iges(shape, path: Path, mode: int) -> Path:
    """IGES by OpenCASCADE's writer: mode 1 writes B-rep solids (MSBO, entity 186), mode 0
    trimmed faces only (entity 144: a reader must sew them back into a solid)."""
    from OCP.IGESControl import IGESControl_Writer

    _quiet()
    writer = IGESControl_Writer("MM", mode)
    assert writer.AddShape(shape)
    writer.ComputeModel()
    assert writer.Write(str(path))
    return path


class TestIgesOfRealParts:
    """Real kicad6-step solids written to IGES: the same part in another format must give the
    same area and volume and the same signature within the noise of re-sampling (an
    invariance across formats that does not rest on the STEP path's own code)."""

    @pytest.mark.parametrize("name", [TWINS[0], TWINS[2]])
    def test_iges_and_step_are_the_same_part(self, data_dir, tmp_path, name):
        from shapeidx.io.step import read_shape

        step = data_dir / "kicad6-step" / f"{name}.step"
        shape = read_shape(step, None, LoadLimits()).shape
        step_solid = solid_of_file(step)
        facts = step_solid.describe()
        samplings = [signature_of_solid(step_solid, seed=s) for s in (1, 2, 3)]
        noise = max(compare(a, b)["weighted"] for i, a in enumerate(samplings) for b in samplings[i + 1:])
        for mode, tolerance in ((1, 1e-6), (0, 2e-3)):  # faces re-sewn are faceted anew: a looser bound
            iges = write_iges(shape, tmp_path / f"part.mode{mode}.igs", mode)
            solid = solid_of_file(iges)
            got = solid.describe()
            assert got["format"] == "iges" and got["watertight"], (mode, got)
            assert got["area"] == pytest.approx(facts["area"], rel=tolerance), mode
            assert got["volume"] == pytest.approx(facts["volume"], rel=tolerance), mode
            # a faceting may cut a curved silhouette by up to its deflection (0.002 of the diagonal)
            diagonal = float(np.linalg.norm(np.subtract(*facts["bounds"])))
            reach = 1e-6 if mode == 1 else Faceting().linear_deflection
            np.testing.assert_allclose(got["bounds"], facts["bounds"], atol=reach * diagonal)
            twin = signature_of_solid(solid, seed=4)  # a fourth, independent sampling
            distances = [compare(twin, s)["weighted"] for s in samplings]
            assert max(distances) <= 1.5 * noise, (mode, distances, noise)


# --------------------------------------------------------------------------- builds and the store


class TestBuild:
    def test_a_build_with_good_and_broken_step_goes_on(self, data_dir, tmp_path):
        tree = tmp_path / "parts"
        (tree / "good").mkdir(parents=True)
        # an upper-case .STEP and a gzipped .stp.gz
        shutil.copy(data_dir / "kicad6-step" / f"{TWINS[0]}.step", tree / "good" / "a.STEP")
        (tree / "good" / "b.stp.gz").write_bytes(gzip.compress((data_dir / "kicad6-step" / f"{TWINS[1]}.step").read_bytes()))
        bad = _bad_files(data_dir, tree / "bad")
        store = tmp_path / "s.h5"
        result = build(tree, store, "--workers", "2")
        assert result.exit_code == 0, result.output
        assert summary_counts(result.stdout) == {"indexed": 2, "unchanged": 0, "removed": 0, "failed": len(bad)}
        with open_store(store) as reader:
            status = dict(zip(reader.paths, reader.column("entries/status")))
            reasons = dict(zip(reader.paths, reader.column("entries/reason")))
            assert reader.params.linear_deflection == Faceting().linear_deflection
        assert status["good/a.STEP"] == status["good/b.stp.gz"] == STATUS_OK
        for name, (_, words) in bad.items():
            assert status[f"bad/{name}"] == STATUS_FAILED and words in reasons[f"bad/{name}"], reasons

    def test_faceting_is_a_store_parameter(self, data_dir, tmp_path):
        tree = tmp_path / "parts"
        tree.mkdir()
        shutil.copy(data_dir / "kicad6-step" / f"{TWINS[1]}.step", tree / "a.step")
        store = tmp_path / "s.h5"
        assert build(tree, store, "--linear-deflection", "0.01", "--angular-deflection", "0.5").exit_code == 0
        with open_store(store) as reader:
            assert (reader.params.linear_deflection, reader.params.angular_deflection) == (0.01, 0.5)
            triangles = int(reader.column("entries/triangles")[0])
        coarse = load(tree / "a.step", LoadLimits(faceting=Faceting(0.01, 0.5)))
        assert triangles == len(coarse.face_sizes) != len(load(tree / "a.step").face_sizes)
        refused = build(tree, store, "--linear-deflection", "0.002")
        assert refused.exit_code == 1 and "linear_deflection=0.01 (asked: 0.002)" in refused.stderr
        # without the option the store's own faceting is used; stats shows it
        assert build(tree, store).exit_code == 0
        assert "linear deflection 0.01 of the diagonal, angular 0.5 rad" in cli("stats", "--store", store).stdout

    def test_inspect_reports_faceting_triangles_and_chordal_error(self, data_dir):
        path = data_dir / "kicad6-step" / f"{TWINS[0]}.step"
        result = cli("inspect", path, "--linear-deflection", "0.001", "--json")
        assert result.exit_code == 0, result.output
        import json

        facts = json.loads(result.stdout)
        f = facts["faceting"]
        assert f["linear_deflection"] == 0.001 and f["triangles"] == facts["triangles"]
        assert 0 < f["max_chordal_error_mm"] <= 1.01 * f["deflection_mm"]
        assert f["file_units"] == ["millimetre"]
        text = cli("inspect", path).stdout
        assert "faceting    linear deflection 0.002" in text and "chordal     measured max" in text

    def test_opencascade_crashes_and_hangs_are_contained(self, data_dir, tmp_path):
        """A real OpenCASCADE crash in a worker costs that file only; so does a hang, by --timeout.

        The workers are spawned processes: a sitecustomize on their path turns off the
        Global-section check (so OCCT really reads the IGES file that kills it) and makes
        the faceting of ``hang.step`` sleep.
        """
        tree = tmp_path / "parts"
        tree.mkdir()
        write_step(box(), tree / "good.step")
        write_step(box(), tree / "hang.step")
        shutil.copy(HOLLERITH_OVERRUN, tree / "crash.igs")
        hook = tmp_path / "hook"
        hook.mkdir()
        (hook / "sitecustomize.py").write_text(
            "import time\n"
            "import shapeidx.io.step as step\n"
            "step._check_iges_sections = lambda path, data: None\n"
            "original = step.tessellate\n"
            "def tessellate(shape, faceting, path=None):\n"
            "    if str(path).endswith('hang.step'):\n"
            "        time.sleep(600)\n"
            "    return original(shape, faceting, path)\n"
            "step.tessellate = tessellate\n"
        )
        env = {**os.environ, "PYTHONPATH": f"{hook}{os.pathsep}{Path(__file__).resolve().parents[1]}"}
        store = tmp_path / "s.h5"
        run = subprocess.run([sys.executable, "-m", "shapeidx.cli", "build", str(tree), "--store", str(store),
                              "--points", FAST_POINTS, "--workers", "2", "--timeout", "45"],
                             capture_output=True, text=True, timeout=300, env=env)
        assert run.returncode == 0, run.stderr
        assert "1 indexed, 0 unchanged, 0 removed, 2 failed" in run.stdout
        with open_store(store) as reader:
            status = dict(zip(reader.paths, reader.column("entries/status")))
            reasons = dict(zip(reader.paths, reader.column("entries/reason")))
        assert status["good.step"] == STATUS_OK
        assert status["crash.igs"] == STATUS_FAILED and "SIGSEGV" in reasons["crash.igs"], reasons
        assert status["hang.step"] == STATUS_FAILED and "timed out after 45 s" in reasons["hang.step"], reasons


