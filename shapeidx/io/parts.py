"""A part file split into its sub-parts: the solids of an assembly, the bodies of a mesh.

``build --parts`` signs each sub-part of a file as an entry of its own (``FILE#n``), so that
``where-used`` can answer which files contain a part like a given one.

* **STEP**: every solid of the file, read through OpenCASCADE's XCAF document
  (``STEPCAFControl_Reader``), which also gives the name of the product the solid belongs
  to; assembly placements (``TopLoc_Location``) are applied down to each solid. **IGES**:
  every solid of the plain transfer (IGES files rarely hold solids: most are one part).
  Faces that go round their periodic surface more than once are replaced by one turn, as
  for the whole file (:func:`~shapeidx.io.step.unwound`).
* **VRML and meshes**: each connected body (triangles that share vertices, after coincident
  vertices are merged): KiCad's VRML writes the body, the pins and the marking as separate
  shapes, which are separate bodies. A VRML file that groups its geometry (a robot's links
  and motors as Transforms of their own, a Wings3D part's pins as named Transforms) is split
  along its groups first (:mod:`shapeidx.io.vrml.groups`), then each group into its bodies:
  two touching objects stay two parts, and each part is named after its group's ``DEF``.

Each sub-part is expressed in **its own frame** (centroid of its surface at the origin, its
principal axes along x, y, z), so the same pin placed anywhere gives the same mesh to
rounding, and is faceted as if it were a file of its own (the faceting's deflection is
relative to the sub-part's own size, as :func:`~shapeidx.io.step.read_step` does for a
file). **Identical sub-parts** (the same geometry up to a rigid motion: forty identical
pins) are found by their exact invariants: for a solid OpenCASCADE's volume, area and
principal moments of inertia (``BRepGProp``) and face count, for a mesh body its area,
enclosed volume and the principal moments of its surface; equal within
:data:`SAME_TOLERANCE`, they are one sub-part with a ``count``. A mirror image has the same
invariants: a left and a right pin count as one sub-part (D2 does not tell them apart either).

:func:`split_parts` returns None for a file that is one part: its whole-file entry serves.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import LoadError
from .base import LoadLimits, PolygonMesh, read_bytes
from .polygons import fan_triangles, members_of, triangle_areas

__all__ = ["SubPart", "split_parts", "own_frame", "MAX_PARTS", "SAME_TOLERANCE", "PARTS_VERSION"]

#: Raised whenever the same file would split differently (other sub-parts, another order):
#: pictures of sub-parts are cached under it (2: VRML files split along their groups; 3: STEP
#: faces going round their surface more than once read as one turn, so a transformer's pins
#: are one sub-part, not two).
PARTS_VERSION = 3
#: Sub-parts a file gives at most (distinct ones; a file with more keeps the largest).
MAX_PARTS = 200
#: Two sub-parts are the same part when each invariant agrees to this share.
SAME_TOLERANCE = 1e-5
#: A mesh body smaller than this share of the file's area is a speck, not a part.
MIN_AREA_SHARE = 1e-4

_SOLID_ENTITY = re.compile(rb"MANIFOLD_SOLID_BREP|BREP_WITH_VOIDS|NEXT_ASSEMBLY_USAGE_OCCURRENCE")


@dataclass
class SubPart:
    """One distinct sub-part of a file.

    Attributes
    ----------
    mesh : PolygonMesh
        Its triangles in its own frame.
    name : str
        The name the file gives it (a STEP product's name), or "".
    count : int
        How many times the file holds it.
    """

    mesh: PolygonMesh
    name: str
    count: int


def split_parts(path, limits: LoadLimits | None = None, format_name: str | None = None,
                mesh: PolygonMesh | None = None) -> list[SubPart] | None:
    """The distinct sub-parts of a part file, largest first; None when the file is one part.

    ``mesh``: the file as :func:`shapeidx.io.load` read it, when the caller has it (a mesh
    format is then not read again; a STEP or IGES file is, solid by solid).

    Raises
    ------
    LoadError
        The file cannot be read (as :func:`shapeidx.io.load` would say).
    """
    from .registry import format_of, load

    limits = limits or LoadLimits()
    path = Path(path)
    name = format_name or format_of(path)
    if name in ("step", "iges"):
        from .step import run_opencascade

        # OpenCASCADE in a child process (a build worker is its own): a crash costs one error line
        return run_opencascade(_solid_model_parts, path, limits)
    if name == "vrml":
        from .vrml.groups import vrml_groups

        grouped = vrml_groups(path, limits, MIN_AREA_SHARE)
        if grouped is not None:
            return _grouped_parts(grouped)
    return _mesh_parts(mesh if mesh is not None else load(path, limits, name))


# --------------------------------------------------------------------------- solid models


def _solid_model_parts(path: Path, limits: LoadLimits) -> list[SubPart] | None:
    from .faceting import Faceting
    from .step import quiet_opencascade, read_shape, sniff_solid_model, tessellate, triangles_of, unwound

    data, _ = read_bytes(path, limits)
    kind = sniff_solid_model(data)
    if kind == "step" and len(_SOLID_ENTITY.findall(data, 0, len(data))) <= 1:
        return None  # one solid and no assembly: the file is its one part (no OpenCASCADE read)
    quiet_opencascade()
    solids = _named_solids(path, data) if kind == "step" else None
    if solids is None:  # IGES, or a STEP file XCAF cannot read: the plain transfer's solids, unnamed
        solids = [("", solid) for solid in _solids_of(read_shape(path, data, limits).shape)]  # unwound there
    else:  # faces going round their surface more than once, as read_step's (one turn)
        solids = list(zip([name for name, _ in solids], unwound([solid for _, solid in solids])[0]))
    if len(solids) <= 1:
        return None
    faceting = limits.faceting or Faceting()
    groups = _same_groups([_solid_invariants(solid) for _, solid in solids])
    parts = []
    for members in groups:
        name, solid = solids[members[0]]
        try:
            tessellate(solid, faceting, path)
        except LoadError:
            continue  # a solid without extent: nothing to sign
        vertices, triangles, failed, total = triangles_of(solid)
        if len(triangles) == 0:
            continue
        warnings = [f"{failed} of {total} faces could not be tessellated and are left out"] if failed else []
        mesh = PolygonMesh.from_triangles(own_frame(vertices, triangles), triangles, kind, warnings)
        if name:
            mesh.metadata = {"title": name}
        parts.append(SubPart(mesh, name, len(members)))
    return _largest(parts) if len(parts) > 1 or (parts and parts[0].count > 1) else None


def _named_solids(path: Path, data: bytes):
    """[(product name, located solid)] of a STEP file through XCAF, or None if XCAF cannot read it."""
    import tempfile

    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPCAFControl import STEPCAFControl_Reader
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    with tempfile.TemporaryDirectory(prefix="shapeidx-parts-") as folder:
        copy = os.path.join(folder, "part.stp")
        with open(copy, "wb") as f:
            f.write(data)
        document = TDocStd_Document(TCollection_ExtendedString("shapeidx"))
        reader = STEPCAFControl_Reader()
        reader.SetNameMode(True)
        if reader.ReadFile(copy) != IFSelect_RetDone or not reader.Transfer(document):
            return None
    tool = XCAFDoc_DocumentTool.ShapeTool_s(document.Main())
    found: list = []
    free = _label_sequence()
    tool.GetFreeShapes(free)
    for i in range(1, free.Length() + 1):
        _walk_label(tool, free.Value(i), TopLoc_Location(), found, 0)
    return found


def _label_sequence():
    from OCP.collections import Sequence_TDF_Label

    return Sequence_TDF_Label()


def _label_name(label) -> str:
    from OCP.TDataStd import TDataStd_Name

    attribute = TDataStd_Name()
    if label.FindAttribute(TDataStd_Name.GetID_s(), attribute):
        return " ".join(attribute.Get().ToExtString().split())[:500]
    return ""


def _walk_label(tool, label, location, found: list, depth: int) -> None:
    """Every solid under ``label`` with the placements down to it, named by its product."""
    from OCP.TDF import TDF_Label

    if depth > 64:
        return
    if tool.IsReference_s(label):
        referred = TDF_Label()
        tool.GetReferredShape_s(label, referred)
        _walk_label(tool, referred, location.Multiplied(tool.GetLocation_s(label)), found, depth + 1)
        return
    if tool.IsAssembly_s(label):
        components = _label_sequence()
        tool.GetComponents_s(label, components)
        for i in range(1, components.Length() + 1):
            _walk_label(tool, components.Value(i), location, found, depth + 1)
        return
    shape = tool.GetShape_s(label)
    if shape is None or shape.IsNull():
        return
    name = _label_name(label)
    found.extend((name, solid) for solid in _solids_of(shape.Moved(location)))


def _solids_of(shape) -> list:
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer

    solids, explorer = [], TopExp_Explorer(shape, TopAbs_SOLID)
    while explorer.More():
        solids.append(explorer.Current())
        explorer.Next()
    return solids


def _solid_invariants(solid) -> np.ndarray:
    """Volume, area, the three principal moments of inertia and the face count: unchanged
    by a rigid motion (and a mirroring), from the exact geometry."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    volume, area = GProp_GProps(), GProp_GProps()
    BRepGProp.VolumeProperties_s(solid, volume)
    BRepGProp.SurfaceProperties_s(solid, area)
    inertia = volume.MatrixOfInertia()
    matrix = np.array([[inertia.Value(i, j) for j in (1, 2, 3)] for i in (1, 2, 3)])
    faces, explorer = 0, TopExp_Explorer(solid, TopAbs_FACE)
    while explorer.More():
        faces += 1
        explorer.Next()
    return np.concatenate([[abs(volume.Mass()), area.Mass()], np.sort(np.linalg.eigvalsh(matrix)), [faces]])


def _same_groups(invariants: list) -> list[list[int]]:
    """Indices grouped by equal invariants (each within :data:`SAME_TOLERANCE` of the
    group's first member, relative to its size), in order of first appearance."""
    groups: list[list[int]] = []
    firsts: list[np.ndarray] = []
    for i, values in enumerate(invariants):
        values = np.asarray(values, dtype=np.float64)
        for group, first in zip(groups, firsts):
            scale = np.maximum(np.abs(first), np.abs(values))
            # moments of inertia are size^5: a floor keeps near-zero moments of flat parts comparable
            floor = SAME_TOLERANCE * np.max(scale)
            if np.all(np.abs(first - values) <= SAME_TOLERANCE * scale + floor * 1e-3):
                group.append(i)
                break
        else:
            groups.append([i])
            firsts.append(values)
    return groups


def _largest(parts: list[SubPart]) -> list[SubPart]:
    """Largest first (by area of one copy), at most :data:`MAX_PARTS`."""
    def area(part):
        return float(triangle_areas(part.mesh.vertices, fan_triangles(part.mesh)).sum())

    return sorted(parts, key=area, reverse=True)[:MAX_PARTS]


# --------------------------------------------------------------------------- meshes


def _mesh_parts(mesh: PolygonMesh) -> list[SubPart] | None:
    """The connected bodies of a mesh (VRML, STL, OBJ, OFF, PLY), identical ones counted once."""
    triangles = fan_triangles(mesh)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if len(triangles) == 0:
        return None
    merged = _merge_coincident(vertices, triangles)
    labels = _components(merged, len(vertices))
    count = int(labels.max()) + 1 if len(labels) else 0
    if count <= 1:
        return None
    areas = triangle_areas(vertices, triangles)
    total = float(areas.sum())
    bodies = [mine for mine in members_of(labels) if float(areas[mine].sum()) > MIN_AREA_SHARE * total]
    if len(bodies) <= 1:
        return None
    meshes = [_sub_mesh(vertices, triangles[chosen], mesh) for chosen in bodies]
    groups = _same_groups([_mesh_invariants(m) for m in meshes])
    parts = [SubPart(meshes[g[0]], "", len(g)) for g in groups]
    return _largest(parts) if len(parts) > 1 or parts[0].count > 1 else None


def _grouped_parts(grouped: list[tuple[str, PolygonMesh]]) -> list[SubPart] | None:
    """The parts of a VRML file whose grouping nodes say what its parts are
    (:mod:`shapeidx.io.vrml.groups`): the connected bodies of each group (a group may gather
    several bodies: FreeCAD writes a part's ten pins as one group of their colour), each in
    its own frame with its polygons as read, named after its group; identical ones counted
    once."""
    pieces = []  # (name, mesh, triangles, area)
    for name, mesh in grouped:
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        triangles = fan_triangles(mesh)
        if len(triangles) == 0:
            continue
        polygon_of = np.repeat(np.arange(len(mesh.face_sizes)), np.asarray(mesh.face_sizes) - 2)
        labels = _components(_merge_coincident(vertices, triangles), len(vertices))
        areas = triangle_areas(vertices, triangles)
        for mine in members_of(labels):
            piece = _polygons_of(mesh, np.unique(polygon_of[mine]))
            pieces.append((name, piece, fan_triangles(piece), float(areas[mine].sum())))
    total = sum(piece[3] for piece in pieces)
    pieces = [piece for piece in pieces if piece[3] > MIN_AREA_SHARE * total]  # specks left out
    if not pieces:
        return None
    meshes, invariants = [], []
    for name, mesh, triangles, _ in pieces:
        vertices = own_frame(mesh.vertices, triangles)
        moved = PolygonMesh(vertices, mesh.face_sizes, mesh.face_indices, mesh.format)
        if name:
            moved.metadata = {"title": name}
        meshes.append((name, moved))
        invariants.append(_surface_invariants(vertices, triangles))
    groups = _same_groups(invariants)
    parts = [SubPart(meshes[g[0]][1], meshes[g[0]][0], len(g)) for g in groups]
    return _largest(parts) if len(parts) > 1 or parts[0].count > 1 else None


def _polygons_of(mesh: PolygonMesh, polygons: np.ndarray) -> PolygonMesh:
    """The mesh of some of ``mesh``'s polygons, with only the vertices they use."""
    sizes = np.asarray(mesh.face_sizes, dtype=np.int64)
    chosen = np.zeros(len(sizes), dtype=bool)
    chosen[polygons] = True
    used, local = np.unique(np.asarray(mesh.face_indices)[np.repeat(chosen, sizes)], return_inverse=True)
    return PolygonMesh(np.asarray(mesh.vertices, dtype=np.float64)[used], sizes[chosen],
                       local.reshape(-1).astype(np.int64), mesh.format)


def _merge_coincident(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Triangles with coincident vertices (within 1e-9 of the extent) given one index."""
    extent = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))) or 1.0
    keys = np.round((vertices - vertices.min(axis=0)) / (extent * 1e-9)).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_inverse=True)
    return first.reshape(-1)[triangles]


def _components(triangles: np.ndarray, n_vertices: int) -> np.ndarray:
    """The connected body of each triangle (triangles sharing a vertex are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    k = len(triangles)
    rows = np.repeat(np.arange(k), 3)
    graph = coo_matrix((np.ones(3 * k), (rows, triangles.reshape(-1) + k)), shape=(k + n_vertices, k + n_vertices))
    _, labels = connected_components(graph, directed=False)
    _, labels = np.unique(labels[:k], return_inverse=True)
    return labels.reshape(-1)


def _sub_mesh(vertices: np.ndarray, triangles: np.ndarray, mesh: PolygonMesh) -> PolygonMesh:
    used, local = np.unique(triangles, return_inverse=True)
    local = local.reshape(-1, 3)
    return PolygonMesh.from_triangles(own_frame(vertices[used], local), local, mesh.format)


def _mesh_invariants(mesh: PolygonMesh) -> np.ndarray:
    return _surface_invariants(mesh.vertices, mesh.face_indices.reshape(-1, 3))


def _surface_invariants(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Enclosed volume, area and the principal moments of a triangle surface: unchanged by
    a rigid motion."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    volume = abs(float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6)
    _, covariance, area = _surface_moments(vertices, triangles)
    return np.concatenate([[volume, area], np.sort(np.linalg.eigvalsh(covariance * area))])


# --------------------------------------------------------------------------- own frame


def _surface_moments(vertices: np.ndarray, triangles: np.ndarray):
    """Centroid, covariance (per unit area) and area of a triangle surface, exactly."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    area = float(areas.sum())
    if area <= 0:
        return vertices.mean(axis=0) if len(vertices) else np.zeros(3), np.eye(3), 0.0
    centroid = (areas[:, None] * (a + b + c)).sum(axis=0) / (3 * area)
    a, b, c = a - centroid, b - centroid, c - centroid
    s = a + b + c
    # integral of x x^T over a triangle: area/12 (a a^T + b b^T + c c^T + s s^T)
    second = np.einsum("k,ki,kj->ij", areas, a, a) + np.einsum("k,ki,kj->ij", areas, b, b)
    second += np.einsum("k,ki,kj->ij", areas, c, c) + np.einsum("k,ki,kj->ij", areas, s, s)
    return centroid, second / (12 * area), area


def own_frame(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``vertices`` moved into the surface's own frame: its centroid at the origin, its
    principal axes (largest spread first) along x, y, z, each axis pointing where the
    surface's third moment along it is positive, and the frame right-handed (a rigid
    motion, never a mirroring)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    centroid, covariance, area = _surface_moments(vertices, triangles)
    moved = vertices - centroid
    if area <= 0:
        return moved
    _, axes = np.linalg.eigh(covariance)
    axes = axes[:, ::-1]  # largest spread first
    centres = moved[triangles].mean(axis=1)
    weights = triangle_areas(moved, triangles)
    for k in range(3):
        if np.dot(weights, (centres @ axes[:, k]) ** 3) < 0:
            axes[:, k] = -axes[:, k]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moved @ axes
