"""STEP (ISO 10303-21) and IGES solid models, read and faceted by OpenCASCADE.

The exact geometry (B-rep: faces on planes, cylinders, B-spline surfaces ...) is turned into
triangles by ``BRepMesh_IncrementalMesh`` at a chosen fidelity (:class:`Faceting`), and
the triangles of every face become one :class:`~shapeidx.io.base.PolygonMesh`, so that
everything downstream is the same as for a mesh format.

* **What is read**: every face of the file's shapes: faces of solids, of shells that
  bound no solid, and free faces (an open shell stays open, as in the VRML reader;
  :mod:`shapeidx.signing.solid` then judges inside and outside by winding numbers).
* **Assemblies**: the plain ``STEPControl_Reader`` / ``IGESControl_Reader`` transfer
  gives one compound whose sub-shapes carry their placements (``TopLoc_Location``); each
  face's triangulation is moved by the location accumulated down to it, so a solid used
  twice in two places appears twice. Reversed faces have their triangles turned.
* **Faces that go round their surface more than once**: a face on a periodic surface (a
  cylinder, a surface of revolution) whose wire runs round the axis two or three times
  (its pcurves span u from -2 pi to 2 pi, seam edges at both ends: every pin of some KiCad
  transformers) is meshed by OpenCASCADE over that multiple domain, its area doubled or
  tripled. Such a face (``BRepTools.UVBounds`` a whole multiple of the surface's period) is
  replaced by its one-turn band on the same surface when its boundary allows it (every
  edge an iso-line on one of the band's two boundary curves or on its seam), once per face
  shared by located instances (:func:`unwound`); a face that does not fit, or an
  OpenCASCADE exception, leaves it as read. :func:`faceting_report` counts them
  (``faces_unwound``; ``inspect`` prints the count when there are any).
* **Units**: OpenCASCADE converts the file's length unit to its session unit, which is
  set to millimetres here, so coordinates come out in mm whatever the file says (the
  file's own unit is reported by :func:`faceting_report`).
* **Faceting**: the linear deflection is relative to the part's bounding-box diagonal,
  the angular one in radians (defaults and the study behind them: ``docs/faceting.md``).
* **Faces that do not tessellate**: ``BRepMesh`` reports such a face by leaving it without
  a triangulation (a face of zero area, a there-and-back boundary, ...). The other faces are
  kept and the mesh carries one warning ("1 of 7 faces could not be tessellated and are
  left out"), which ``inspect`` prints: a partial result, not an error. A file none of
  whose faces tessellate is an error.
* **Bad files** (not STEP or IGES, truncated, no geometry, nothing that tessellates) raise
  one :class:`~shapeidx.errors.LoadError` line; so does an exception OpenCASCADE raises
  (``Transfer_TransferFailure``, ``Standard_NumericError``), in words about the file.
* **Crashes and hangs**: OpenCASCADE runs in a child process (:mod:`shapeidx.io.contained`)
  with a time limit (``LoadLimits.max_seconds``) and a memory limit (``LoadLimits.max_bytes``),
  so a file that crashes or hangs it costs one error line in every command and in the web
  server; in a build's workers, which contain it already, it runs in the worker itself.

OpenCASCADE (the ``cadquery-ocp-novtk`` wheel, module ``OCP``) is imported only when a
solid model is read: importing :mod:`shapeidx` does not load it.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import LoadError
from .base import Format, LoadLimits, PolygonMesh, read_bytes
from .contained import run_contained
from .formats import SUFFIXES
from .faceting import Faceting

__all__ = ["Faceting", "read_step", "sniff_solid_model", "faceting_report", "unwound"]

STEP_MAGIC = b"ISO-10303-21"
_STEP_END = re.compile(rb"END-ISO-10303-21\s*;\s*$")
#: How many bytes at the end are searched for the STEP terminator.
_TAIL = 4096
#: Up to this many triangles per curved face are measured by :func:`faceting_report`.
_MEASURED_PER_FACE = 24


def sniff_solid_model(data: bytes) -> str | None:
    """``"step"`` or ``"iges"`` when the bytes look like one (by content, not by name), else None.

    STEP part 21 files begin with ``ISO-10303-21;``; IGES files are 80-column records whose
    first is a Start record: column 73 holds ``S`` (and often the file has only ``S``, ``G``,
    ``D``, ``P``, ``T`` sections).
    """
    head = data[:4096].lstrip(b"\xef\xbb\xbf \t\r\n")
    if head.startswith(STEP_MAGIC):
        return "step"
    first = data[:4096].split(b"\n", 1)[0].rstrip(b"\r")  # columns count: no stripping
    if len(first) >= 73 and first[72:73] == b"S" and first[73:80].strip().isdigit():
        return "iges"
    return None


@dataclass
class _Read:
    """One solid-model file after OpenCASCADE read it: the shape and what is known of it."""

    shape: object  # TopoDS_Shape, in millimetres
    kind: str  # "step" or "iges"
    file_units: list  # length unit names the file declares
    unwound: int = 0  # faces going round their surface more than once, replaced by one turn


def read_step(path, data: bytes | None = None, limits: LoadLimits | None = None) -> PolygonMesh:
    """Read a STEP or IGES file (plain or gzip) and facet it into a :class:`PolygonMesh`.

    Parameters
    ----------
    path : path-like
        The file; named in every error.
    data : bytes, optional
        Its content, already decompressed (as :func:`~shapeidx.io.base.read_bytes` gives
        it); read from ``path`` when not given.
    limits : LoadLimits, optional
        ``limits.faceting`` sets the tolerances (default :class:`Faceting`);
        ``limits.max_triangles`` bounds the result.

    Returns
    -------
    PolygonMesh
        Triangles in millimetres, world placement, ``format`` ``"step"`` or ``"iges"``.

    Raises
    ------
    LoadError
        Not a STEP/IGES file, truncated, unreadable by OpenCASCADE, no geometry, or no face
        that could be tessellated.
    """
    limits = limits or LoadLimits()
    if data is None:
        data, _ = read_bytes(path, limits)
    kind = check_solid_model(Path(path), data)  # the cheap refusals need no child process
    try:
        return run_opencascade(_read_step, path, limits, kind, data)
    except LoadError as exc:
        problem = _iges_directory_problem(data) if kind == "iges" and "crashed reading it" in exc.reason else None
        if problem:  # what OpenCASCADE died of, most likely
            raise type(exc)(exc.path, f"{exc.reason}; its Directory section is damaged: {problem}") from None
        raise


def run_opencascade(function, path, limits: LoadLimits, *args):
    """``function(path, limits, *args)`` run by OpenCASCADE in a contained process (time and memory bounded)."""
    return run_contained(function, (Path(path), limits) + args, path, "OpenCASCADE",
                         limits.max_seconds, limits.max_bytes)


def _read_step(path: Path, limits: LoadLimits, kind: str, data: bytes) -> PolygonMesh:
    """:func:`read_step`'s work, in the contained process."""
    faceting = limits.faceting or Faceting()
    read = read_shape(path, data, limits, kind)
    tessellate(read.shape, faceting, path)
    vertices, triangles, failed, total = _occt(path, "read its faces' triangles", triangles_of, read.shape)
    if total == 0:
        raise LoadError(path, "has no faces (no surface geometry: points, curves or empty shapes only)")
    if len(triangles) == 0:
        raise LoadError(path, f"OpenCASCADE could not tessellate any of its {total} faces")
    warnings = []
    if failed:
        warnings.append(f"{failed} of {total} faces could not be tessellated and are left out (the surface has holes there)")
    return PolygonMesh.from_triangles(vertices, triangles, read.kind, warnings)


def faceting_report(path, faceting: Faceting | None = None, limits: LoadLimits | None = None, seed: int = 0) -> dict:
    """What :func:`read_step` does with ``path``, measured: tolerances, triangles, chordal error.

    The chordal error is measured independently of the mesher's own bookkeeping: for up to
    24 triangles of every curved face (chosen at random with ``seed``; plane faces are
    faceted exactly), the centroid and the three edge midpoints are projected onto the
    face's exact surface (``GeomAPI_ProjectPointOnSurf``) and the largest distance is kept.

    Returns
    -------
    dict
        ``linear_deflection`` (relative), ``angular_deflection`` (rad), ``deflection_mm``
        (absolute, given to OpenCASCADE), ``diagonal_mm``, ``triangles``, ``faces``,
        ``faces_failed``, ``max_chordal_error_mm``, ``max_chordal_error`` (relative to the
        diagonal), ``measured_points``, ``file_units``, ``faces_unwound`` (faces going round
        their surface more than once, meshed as one turn: :func:`unwound`).
    """
    limits = limits or LoadLimits()
    faceting = faceting or limits.faceting or Faceting()
    return run_opencascade(_faceting_report, path, limits, faceting, seed)


def _faceting_report(path: Path, limits: LoadLimits, faceting: Faceting, seed: int) -> dict:
    read = read_shape(path, None, limits)
    diagonal = tessellate(read.shape, faceting, path)
    _, triangles, failed, total = _occt(path, "read its faces' triangles", triangles_of, read.shape)
    error, measured = _occt(path, "measure its faceting", chordal_error, read.shape, np.random.default_rng(seed))
    return {
        "linear_deflection": faceting.linear_deflection,
        "angular_deflection": faceting.angular_deflection,
        "deflection_mm": faceting.absolute(diagonal),
        "diagonal_mm": diagonal,
        "triangles": int(len(triangles)),
        "faces": total,
        "faces_failed": failed,
        "max_chordal_error_mm": error,
        "max_chordal_error": error / diagonal if diagonal > 0 else float("nan"),
        "measured_points": measured,
        "file_units": read.file_units,
        "faces_unwound": read.unwound,
    }


# --------------------------------------------------------------------------- reading


def read_shape(path: Path, data: bytes | None, limits: LoadLimits, kind: str | None = None) -> _Read:
    """Read a STEP/IGES file with OpenCASCADE (in this process: see :func:`read_step`)."""
    if data is None:
        data, _ = read_bytes(path, limits)
    if kind is None:
        kind = check_solid_model(path, data)
    quiet_opencascade()
    # OpenCASCADE reads from a file name: gzip-compressed or in-memory content goes through
    # a private temporary copy (also spares OCCT unusual characters in the real name)
    with tempfile.TemporaryDirectory(prefix="shapeidx-step-") as folder:
        copy = os.path.join(folder, "part.stp" if kind == "step" else "part.igs")
        with open(copy, "wb") as f:
            f.write(data)
        return _transfer(path, copy, kind)


def check_solid_model(path: Path, data: bytes) -> str:
    """``"step"`` or ``"iges"``, or a LoadError for content OpenCASCADE should not be given."""
    if not data.strip():
        raise LoadError(path, "is empty (no STEP or IGES data)")
    kind = sniff_solid_model(data)
    if kind is None:
        raise LoadError(path, "not a STEP or IGES file (a STEP file starts with 'ISO-10303-21;', IGES has 80-column records)")
    if kind == "step" and not _STEP_END.search(data[-_TAIL:]):
        raise LoadError(path, "truncated STEP file (it does not end with 'END-ISO-10303-21;')")
    if kind == "iges":
        _check_iges_sections(path, data)
    else:
        _check_step_entities(path, data)
    return kind


#: Most parameters one STEP entity may have. OpenCASCADE's time grows faster than an entity's
#: references (an EDGE_LOOP of 45,000 edges in a real part: 61 s on a loaded machine, of
#: 200,000: past 4 minutes); the most in 2,336 files of the KiCad 6 library is 3,095 (a
#: shell listing its faces).
MAX_STEP_PARAMETERS = 20_000
#: The same for a B-spline curve or surface, whose parameters are its control points and
#: knots: OpenCASCADE reads those as arrays, in linear time. A toroid winding of the KiCad
#: library (L_CommonMode_Toroid_..._Bourns_8100), written out alone by OpenCASCADE, has a
#: curve of 36,310; that file loads in 3 s.
MAX_STEP_SPLINE_PARAMETERS = 200_000


def _check_step_entities(path: Path, data: bytes) -> None:
    """Refuse a STEP entity with more than :data:`MAX_STEP_PARAMETERS` parameters
    (:data:`MAX_STEP_SPLINE_PARAMETERS` for a B-spline).

    Cheap on any file: only stretches between two ``;`` long enough to hold that many
    parameters (two bytes each at least) have their commas counted.
    """
    ends = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == ord(";"))
    if len(ends) == 0:
        return
    starts = np.concatenate(([0], ends[:-1] + 1))
    for start, end in zip(starts[ends - starts > 2 * MAX_STEP_PARAMETERS], ends[ends - starts > 2 * MAX_STEP_PARAMETERS]):
        text = data[start:end]
        count = text.count(b",") + 1
        head, _, body = text.strip().partition(b"=")
        limit = MAX_STEP_SPLINE_PARAMETERS if b"B_SPLINE_" in body[:200] else MAX_STEP_PARAMETERS
        if count > limit:
            name = head.strip()[:20].decode("ascii", "replace")
            raise LoadError(
                path,
                f"has an entity ({name}) of {count:,} parameters, more than the limit of {limit:,}"
                f" (refused: OpenCASCADE would take minutes over it)",
            )


_IGES_ORDER = {b"S": 0, b"G": 1, b"D": 2, b"P": 3, b"T": 4}
#: A Global section starts with its parameter delimiter: the default ',' or a Hollerith '1H.'
_IGES_GLOBAL_START = re.compile(rb"^\s*(,|1H.)")


def _check_iges_sections(path: Path, data: bytes) -> None:
    """Refuse IGES that OpenCASCADE would misread or crash on, before it sees the file.

    Sections must be present and in order (S, G, D, P, T): a file cut short would otherwise be
    read as if it were whole. The Global section is walked field by field: OpenCASCADE 8's
    IGES reader dies (segmentation fault) on a Global section that does not start with its
    delimiters, or whose Hollerith string (``nH...``) claims more characters than are left.
    """
    letters, global_body = [], []
    for line in data.splitlines():
        if len(line) < 73 or line[72:73] not in _IGES_ORDER:
            continue
        letter = line[72:73]
        if letter == b"G":
            global_body.append(line[:72])
        if not letters or letters[-1] != letter:
            letters.append(letter)
    order = [_IGES_ORDER[x] for x in letters]
    if b"T" not in letters:
        raise LoadError(path, "truncated IGES file (no Terminate section)")
    if order != sorted(order) or b"G" not in letters or len(set(letters)) != len(letters):
        raise LoadError(path, "not a valid IGES file (its Start, Global, Directory, Parameter and Terminate sections are missing or out of order)")
    problem = _global_section_problem(b"".join(global_body))
    if problem:
        raise LoadError(path, f"not a valid IGES file (Global section: {problem})")


def _iges_directory_problem(data: bytes) -> str | None:
    """What is wrong with an IGES Directory section's line numbering, or None.

    Each entry is two lines, numbered D1, D2, ... without a gap. OpenCASCADE pairs the lines
    by position: with one line missing every later entry is read from two halves of
    different entries, and OpenCASCADE dies with a segmentation fault (12 times in 12 on a
    real part). It often reads such a file all the same (in a 10,000-case fuzzing run, 212
    of 415 files with a damaged numbering gave a mesh), so the numbering does not refuse a
    file: it names the likely cause when OpenCASCADE crashed.
    """
    numbers = [line[73:80].strip() for line in data.splitlines() if len(line) >= 73 and line[72:73] == b"D"]
    for expected, number in enumerate(numbers, start=1):
        if not number.isdigit() or int(number) != expected:
            shown = str(int(number)) if number.isdigit() else repr(number.decode("ascii", "replace"))
            return f"line {expected} is numbered {shown} (a line missing or out of place)"
    if len(numbers) % 2:
        return f"{len(numbers)} lines, an odd number (each entry has two: a line is missing)"
    return None


_HOLLERITH = re.compile(rb"\s*(\d+)H")


def _global_section_problem(text: bytes) -> str | None:
    """What is wrong with an IGES Global section's fields, or None (Hollerith strings checked)."""
    if not _IGES_GLOBAL_START.match(text):
        return "it does not start with its delimiters"
    delimiter, end = b",", b";"
    i, field = 0, 0
    while i < len(text):
        if field < 2 and text[i:i + 2] == b"1H" and i + 2 < len(text):
            if field == 0:
                delimiter = text[i + 2:i + 3]
            else:
                end = text[i + 2:i + 3]
            i += 3
        else:
            match = _HOLLERITH.match(text, i)
            if match:
                length = int(match.group(1))
                i = match.end() + length
                if i > len(text):
                    return f"a {length}-character string runs past the end of the section"
            # the rest of the field (a number, or what follows a string: OCCT is lenient there)
            while i < len(text) and text[i:i + 1] not in (delimiter, end):
                i += 1
        if text[i:i + 1] == end:
            return None
        i += 1
        field += 1
    return "it has no record delimiter (cut short?)"


def _transfer(path: Path, copy: str, kind: str) -> _Read:
    from OCP.IFSelect import IFSelect_RetDone, IFSelect_RetVoid
    from OCP.Interface import Interface_Static

    if kind == "step":
        from OCP.STEPControl import STEPControl_Reader as Reader
    else:
        from OCP.IGESControl import IGESControl_Reader as Reader
    # the unit OpenCASCADE converts every file's lengths to (its default, said explicitly)
    Interface_Static.SetCVal_s("xstep.cascade.unit", "MM")
    reader = Reader()
    name = kind.upper()
    status = _occt(path, f"parse this {name} file", reader.ReadFile, copy)
    if status == IFSelect_RetVoid:
        raise LoadError(path, f"{name} file holds no entities (no geometry)")
    if status != IFSelect_RetDone:
        raise LoadError(path, f"OpenCASCADE cannot read this {name} file ({_status_name(status)})")
    units = _file_units(reader) if kind == "step" else []
    if reader.NbRootsForTransfer() == 0:
        raise LoadError(path, f"{name} file has no shape to read (no geometry)")
    _occt(path, "turn its entities into geometry", reader.TransferRoots)
    if reader.NbShapes() == 0:
        raise LoadError(path, f"{name} file has no geometry that OpenCASCADE could transfer")
    shape = reader.OneShape()
    if shape is None or shape.IsNull():
        raise LoadError(path, f"{name} file has no geometry that OpenCASCADE could transfer")
    if kind == "iges":
        shape = _occt(path, "sew its faces together", _sewn, shape)
    (shape,), count = unwound([shape])
    return _Read(shape, kind, units, count)


def _sewn(shape):
    """IGES faces, sewn along their common edges.

    IGES usually stores each face with its own boundary curves: unsewn, neighbouring faces
    are meshed along their common edge independently and the triangles would not meet.
    """
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing

    diagonal = _bounding_diagonal(shape)
    # gaps up to 1e-5 of the part's size are closed (0.001 mm on a 100 mm part)
    sewing = BRepBuilderAPI_Sewing(max(1e-5 * diagonal, 1e-7))
    sewing.Add(shape)
    sewing.Perform()
    sewn = sewing.SewedShape()
    return shape if sewn is None or sewn.IsNull() else sewn


def _status_name(status) -> str:
    return str(status).rsplit(".", 1)[-1].replace("IFSelect_Ret", "read status ")


def _file_units(reader) -> list:
    """The length units the STEP file's representations declare (e.g. ``['MM']``), best effort."""
    try:
        from OCP.collections import Sequence_TCollection_AsciiString

        lengths, angles, solids = (Sequence_TCollection_AsciiString() for _ in range(3))
        reader.FileUnits(lengths, angles, solids)
        return sorted({lengths.Value(i).ToCString() for i in range(1, lengths.Length() + 1)})
    except Exception:  # a binding without this call: the unit is still converted, just not reported
        return []


_QUIET = False


def quiet_opencascade() -> None:
    """Stop OpenCASCADE's messenger from writing to stdout (it would mix with our output)."""
    global _QUIET
    if _QUIET:
        return
    from OCP.Message import Message

    messenger = Message.DefaultMessenger_s()
    printers = messenger.Printers()
    for printer in [printers.Value(i) for i in range(1, printers.Size() + 1)]:
        messenger.RemovePrinter(printer)
    _QUIET = True


# --------------------------------------------------------------------------- multi-turn faces

#: A face's parameter span is a whole number of its surface's periods to this share.
_TURN_TOLERANCE = 1e-6


def unwound(shapes: list) -> tuple[list, int]:
    """``shapes`` with every face that goes round its periodic surface more than once
    replaced by its one-turn band; the number of distinct faces replaced.

    Only faces on a periodic surface (``IsUPeriodic``/``IsVPeriodic``) are looked at. A face
    shared by located instances (one ``TShape``) is rebuilt once, and ``BRepTools_ReShape``
    puts the band in place of every occurrence, at its placement and orientation. A face whose band cannot be built, and any OpenCASCADE
    exception, leave the face as it was: with no face replaced, the shapes are returned
    untouched (the same objects).
    """
    try:
        from OCP.BRep import BRep_Tool
        from OCP.BRepTools import BRepTools_ReShape
        from OCP.TopAbs import TopAbs_FORWARD
        from OCP.TopLoc import TopLoc_Location
        from OCP.TopoDS import TopoDS

        reshape, bands, count = None, {}, 0
        for shape in shapes:
            for face in _faces(shape):  # every placed occurrence, its location accumulated from the root
                surface = BRep_Tool.Surface_s(face, TopLoc_Location())  # the handle itself, not a moved copy
                if surface is None or not (surface.IsUPeriodic() or surface.IsVPeriodic()):
                    continue
                bare = TopoDS.Face(face.Located(TopLoc_Location()).Oriented(TopAbs_FORWARD))
                bucket = bands.setdefault(hash(bare), [])
                band = next((b for other, b in bucket if bare.IsSame(other)), False)
                if band is False:
                    band = _one_turn(bare)
                    bucket.append((bare, band))
                    count += band is not None
                if band is not None:
                    # ReShape matches a sub-shape with its accumulated location (Apply walks down
                    # from the root as the explorer does): each occurrence gets the band in its place
                    reshape = reshape or BRepTools_ReShape()
                    reshape.Replace(face, band.Located(face.Location()).Oriented(face.Orientation()))
        if reshape is None:
            return shapes, 0
        return [reshape.Apply(shape) for shape in shapes], count
    except Exception:  # noqa: BLE001 (a repair never adds a failure: the shapes as read)
        return shapes, 0


def _turns(periodic: bool, period: float, span: float) -> int:
    """How many times ``span`` covers the period: 1 when once or less, 0 when not a whole number."""
    if not periodic or period <= 0 or span <= period * (1 + _TURN_TOLERANCE):
        return 1
    turns = round(span / period)
    return turns if abs(span / period - turns) <= _TURN_TOLERANCE * turns else 0


def _on_side(value: float, low: float, high: float, period: float | None, tolerance: float) -> bool:
    """Whether an iso-line at ``value`` is a side of the band: ``low`` or ``high``, or with a
    ``period`` (the direction going round) ``low`` plus any number of turns."""
    if period:
        turns = round((value - low) / period)
        return abs(value - low - turns * period) <= tolerance
    return min(abs(value - low), abs(value - high)) <= tolerance


def _one_turn(face):
    """The one-turn band replacing a face (unlocated, forward) that goes round its periodic
    surface more than once, or None (goes round once, or its boundary is not the band's:
    every edge an iso-line on one of the band's two boundary curves or on its seam)."""
    try:
        from OCP.BRep import BRep_Tool
        from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
        from OCP.BRepTools import BRepTools
        from OCP.TopAbs import TopAbs_EDGE
        from OCP.TopExp import TopExp_Explorer
        from OCP.TopoDS import TopoDS

        surface = BRep_Tool.Surface_s(face)
        u0, u1, v0, v1 = BRepTools.UVBounds_s(face)
        along_u = _turns(surface.IsUPeriodic(), surface.UPeriod() if surface.IsUPeriodic() else 0.0, u1 - u0)
        along_v = _turns(surface.IsVPeriodic(), surface.VPeriod() if surface.IsVPeriodic() else 0.0, v1 - v0)
        if along_u == 0 or along_v == 0 or (along_u == 1 and along_v == 1):
            return None
        period_u = surface.UPeriod() if along_u > 1 else None
        period_v = surface.VPeriod() if along_v > 1 else None
        tol_u, tol_v = _TURN_TOLERANCE * max(u1 - u0, 1.0), _TURN_TOLERANCE * max(v1 - v0, 1.0)
        # the band is the face only if every edge is an iso-line on the band's boundary in 3D:
        # a side of the rectangle, or in the direction that goes round, the seam at any turn
        # (OpenCASCADE also makes such faces with a seam inside the parameter rectangle)
        explorer = TopExp_Explorer(face, TopAbs_EDGE)
        while explorer.More():
            a0, a1, b0, b1 = BRepTools.UVBounds_s(face, TopoDS.Edge(explorer.Current()))
            on_u_side = a1 - a0 <= tol_u and _on_side(a0, u0, u1, period_u, tol_u)
            on_v_side = b1 - b0 <= tol_v and _on_side(b0, v0, v1, period_v, tol_v)
            if not (on_u_side or on_v_side):
                return None
            explorer.Next()
        if period_u:
            u1 = u0 + period_u
        if period_v:
            v1 = v0 + period_v
        maker = BRepBuilderAPI_MakeFace(surface, u0, u1, v0, v1, BRep_Tool.Tolerance_s(face))
        return maker.Face() if maker.IsDone() else None
    except Exception:  # noqa: BLE001 (the face stays as it was)
        return None


# --------------------------------------------------------------------------- faceting


def _bounding_diagonal(shape) -> float:
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib

    box = Bnd_Box()
    BRepBndLib.Add_s(shape, box, False)  # from the exact geometry, not a previous mesh
    if box.IsVoid():
        return 0.0
    return float(box.CornerMin().Distance(box.CornerMax()))


def tessellate(shape, faceting: Faceting, path=None) -> float:
    """Mesh every face of ``shape`` in place at ``faceting``; returns the bounding diagonal (mm).

    A previous triangulation is removed first, so the same shape can be faceted again at
    another fidelity.
    """
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.BRepTools import BRepTools

    diagonal = _occt(path, "measure its extent", _bounding_diagonal, shape)
    if not np.isfinite(diagonal) or diagonal <= 0:
        raise LoadError(path, "has no geometry with an extent (empty or degenerate bounding box)")
    BRepTools.Clean_s(shape)
    # relative=False: OCCT's own "relative" mode scales per edge and face; ours is per part
    _occt(path, "mesh its faces", BRepMesh_IncrementalMesh, shape, faceting.absolute(diagonal), False,
          faceting.angular_deflection, False)
    return diagonal


def _occt(path, doing: str, function, *args):
    """``function(*args)``, an OpenCASCADE exception turned into a LoadError in words.

    OpenCASCADE raises its own exceptions (``Transfer_TransferFailure``,
    ``Standard_NumericError: BRepMesh...``, ``Standard_OutOfRange``) on inconsistent
    entities; their names and messages mean nothing to the user, so the line says which
    step failed, and that the file's entities are the cause.
    """
    try:
        return function(*args)
    except LoadError:
        raise
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 (every OCCT exception class: one line in words)
        name = type(exc).__name__
        cause = ("a numeric failure (a degenerate or inconsistent surface or curve)" if "Numeric" in name
                 or "DivideByZero" in name or "Overflow" in name else
                 "an entity that is malformed or refers to something missing or of the wrong kind")
        raise LoadError(path, f"OpenCASCADE could not {doing}: {cause}") from None


def _faces(shape):
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        yield TopoDS.Face(explorer.Current())
        explorer.Next()


def triangles_of(shape):
    """All faces' triangles in world placement: vertices, triangles, failed and total faces."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_REVERSED
    from OCP.TopLoc import TopLoc_Location

    vertices, triangles = [], []
    offset = failed = total = 0
    for face in _faces(shape):
        total += 1
        location = TopLoc_Location()
        mesh = BRep_Tool.Triangulation_s(face, location)
        if mesh is None or mesh.NbTriangles() == 0:
            failed += 1
            continue
        transform = location.Transformation()
        nodes = np.array([mesh.Node(i).Transformed(transform).Coord() for i in range(1, mesh.NbNodes() + 1)])
        corners = np.array([mesh.Triangle(i).Get() for i in range(1, mesh.NbTriangles() + 1)], dtype=np.int64) - 1
        # a mirroring placement turns the winding as a reversed face does
        if (face.Orientation() == TopAbs_REVERSED) != (transform.IsNegative()):
            corners = corners[:, ::-1]
        vertices.append(nodes)
        triangles.append(corners + offset)
        offset += len(nodes)
    if not triangles:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), failed, total
    return np.vstack(vertices), np.vstack(triangles), failed, total


def chordal_error(shape, rng) -> tuple[float, int]:
    """Largest measured distance (mm) from facet points to the exact surface; points measured."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.GeomAbs import GeomAbs_Plane
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt
    from OCP.TopLoc import TopLoc_Location

    worst, measured = 0.0, 0
    for face in _faces(shape):
        location = TopLoc_Location()
        mesh = BRep_Tool.Triangulation_s(face, location)
        if mesh is None or mesh.NbTriangles() == 0:
            continue
        if BRepAdaptor_Surface(face).GetType() == GeomAbs_Plane:
            continue  # triangles of a plane lie on it
        # triangulation and surface are both in the face's own frame (before its placement)
        surface = BRep_Tool.Surface_s(face, TopLoc_Location())
        count = mesh.NbTriangles()
        chosen = rng.choice(count, size=min(count, _MEASURED_PER_FACE), replace=False) + 1
        for t in chosen:
            a, b, c = (np.array(mesh.Node(i).Coord()) for i in mesh.Triangle(int(t)).Get())
            for point in ((a + b + c) / 3, (a + b) / 2, (b + c) / 2, (c + a) / 2):
                projection = GeomAPI_ProjectPointOnSurf(gp_Pnt(*point), surface)
                if projection.NbPoints():
                    worst = max(worst, float(projection.LowerDistance()))
                    measured += 1
    return worst, measured


#: The reader's revision (:attr:`~shapeidx.io.base.Format.revision`): a build signs again the
#: entries an older one read. 2: faces going round their surface more than once meshed as one
#: turn (:func:`unwound`; 37 of Debian's 6,227 KiCad STEP files change).
REVISION = 2

FORMATS = [
    Format("step", "STEP", SUFFIXES["step"], read_step, sniff=lambda data: sniff_solid_model(data) == "step",
           revision=REVISION),
    Format("iges", "IGES", SUFFIXES["iges"], read_step, sniff=lambda data: sniff_solid_model(data) == "iges",
           revision=REVISION),
]
