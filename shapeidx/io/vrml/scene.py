"""What VRML nodes mean for geometry: which children are traversed, with what transform.

Two passes over the parsed tree share one definition of "which children":

1. :meth:`SceneWalker.count` computes, once per distinct node (DEF/USE makes the tree a
   graph), the triangles and node visits its expansion would give. Hostile files that
   would expand beyond the limits are refused here, before any geometry exists.
2. :meth:`SceneWalker.walk` expands the graph with a transform stack (and, for VRML 1.0,
   the coordinate and vertex-ordering state) and hands each face set to a
   :class:`MeshBuilder`.

VRML 2.0: Transform, Group, Anchor, Billboard, Collision are groups (Billboard's
view-dependent rotation is ignored, Collision's proxy is not drawn); Switch traverses only
``choice[whichChoice]``; LOD only its first level; Shape's geometry is an IndexedFaceSet,
Box, Sphere, Cylinder or Cone (ElevationGrid, Extrusion and NURBS are skipped with a
warning); Inline brings in another file.

VRML 1.0: Separator (and WWWAnchor) saves and restores all state, TransformSeparator
only the transform, Group, Switch and LOD none (state set inside leaks out, as the
specification says); Switch ``whichChild`` -3 traverses all children and -2 the child
the last Switch chose; LOD traverses its first (most detailed) child; WWWInline brings in
another file, whose state does not leak out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...errors import LoadError
from . import geometry as geo
from .parser import Node

#: Most node instances one file may expand to through DEF/USE and Inline. Each costs
#: Python time to traverse; real exports stay far below (a 3,000-face KiCad part ~10^4).
MAX_NODE_VISITS = 2_000_000
#: Deepest node nesting followed through Inlines (each file is limited separately too).
MAX_SCENE_DEPTH = 300
_NO_POINTS = np.zeros((0, 3))
SWITCH_NONE, SWITCH_INHERIT, SWITCH_ALL = -1, -2, -3  # VRML 1.0 Switch.whichChild

V2_GROUPS = {"Group", "Transform", "Anchor", "Billboard", "Collision"}
V2_GEOMETRY = {"IndexedFaceSet", "Box", "Sphere", "Cylinder", "Cone"}
V2_UNSUPPORTED_GEOMETRY = {"ElevationGrid", "Extrusion", "NurbsSurface", "NurbsPatchSurface", "GeoElevationGrid"}
V2_NO_GEOMETRY = {
    # geometry that is not a surface, and appearance
    "IndexedLineSet", "PointSet", "Text", "Appearance", "Material", "ImageTexture", "PixelTexture",
    "MovieTexture", "TextureTransform", "TextureCoordinate", "Color", "Normal", "Coordinate", "FontStyle",
    # bindable, environment and behaviour nodes
    "Viewpoint", "NavigationInfo", "Background", "Fog", "WorldInfo", "DirectionalLight", "PointLight",
    "SpotLight", "Sound", "AudioClip", "Script", "TimeSensor", "TouchSensor", "PlaneSensor",
    "CylinderSensor", "SphereSensor", "ProximitySensor", "VisibilitySensor", "ColorInterpolator",
    "CoordinateInterpolator", "NormalInterpolator", "OrientationInterpolator", "PositionInterpolator",
    "ScalarInterpolator",
}  # fmt: skip

V1_SEPARATORS = {"Separator", "WWWAnchor"}  # WWWAnchor is a Separator in VRML 1.0
V1_GROUPS = {"Group", "Switch", "LOD", "TransformSeparator"}
V1_TRANSFORMS = {"Transform", "MatrixTransform", "Translation", "Rotation", "Scale"}
V1_GEOMETRY = {"IndexedFaceSet", "Cube", "Sphere", "Cylinder", "Cone"}
V1_NO_GEOMETRY = {
    "Material", "MaterialBinding", "Normal", "NormalBinding", "Texture2", "Texture2Transform",
    "TextureCoordinate2", "Info", "PerspectiveCamera", "OrthographicCamera", "DirectionalLight",
    "PointLight", "SpotLight", "FontStyle", "AsciiText", "IndexedLineSet", "PointSet",
}  # fmt: skip
V1_UNSUPPORTED = {"FaceSet", "IndexedTriangleStripSet", "QuadMesh", "TriangleStripSet"}
_PRIMITIVES = {"Box", "Cube", "Sphere", "Cylinder", "Cone"}  # what primitive() may know

# Every node type the traversal knows (no "unknown node type" warning)
_V2_KNOWN = V2_GROUPS | V2_GEOMETRY | V2_NO_GEOMETRY | {"Shape", "Switch", "LOD", "Inline"}
_V1_KNOWN = V1_SEPARATORS | V1_GROUPS | V1_TRANSFORMS | V1_GEOMETRY | V1_NO_GEOMETRY
_V1_KNOWN |= {"Coordinate3", "ShapeHints", "WWWInline"}
_V2_PARENTS = V2_GROUPS | {"Shape", "Switch", "LOD", "Inline"}  # the types children() may descend
# Known types that give no triangles of their own (and need no warning)
_KNOWN_OTHER = {1: _V1_KNOWN - V1_GEOMETRY, 2: _V2_KNOWN - V2_GEOMETRY}


class Warnings:
    """Warnings of one load; the same warning at many places is reported once, with
    where it happened first and how often."""

    def __init__(self):
        self._kinds: dict[str, list] = {}  # kind -> [first message, count]

    def add(self, where: str | None, text: str, kind: str | None = None) -> None:
        """Record ``text`` found at ``where`` ('line 12'); ``kind`` groups repeats
        (default: the text itself)."""
        message = f"{where}: {text}" if where else text
        entry = self._kinds.setdefault(kind or text, [message, 0])
        entry[1] += 1

    def as_list(self) -> list[str]:
        return [
            message if count == 1 else f"{message} (and {count - 1} more like it)"
            for message, count in self._kinds.values()
        ]


class MeshBuilder:
    """Collects transformed face sets; vertices shared by several face sets are moved once.

    Parameters
    ----------
    max_vertices : int
        Refuse (LoadError) when more vertices than this would be created.
    path : path-like
        For that message.
    """

    def __init__(self, max_vertices: int, path):
        self.max_vertices = max_vertices
        self.path = path
        self.vertex_blocks: list[np.ndarray] = []
        self.size_blocks: list[np.ndarray] = []
        self.corner_blocks: list[np.ndarray] = []  # indices into their own points...
        self.corner_offsets: list[int] = []  # ... whose first vertex is here
        self.vertex_count = 0
        # (id of the points array, matrix bytes) -> (first vertex, the array: kept alive so
        # that its id is not reused by another array)
        self._placed: dict[tuple[int, bytes], tuple[int, np.ndarray]] = {}

    def add(
        self, points: np.ndarray, placement: geo.Placement, sizes: np.ndarray, corners: np.ndarray, flip: bool
    ) -> None:
        """Add polygons over ``points`` (local coordinates) put in place by ``placement``;
        ``flip`` reverses their winding."""
        if len(sizes) == 0:
            return
        key = (id(points), placement.key)
        placed = self._placed.get(key)
        if placed is None:
            if self.vertex_count + len(points) > self.max_vertices:
                raise LoadError(
                    self.path, f"would give more than {self.max_vertices:,} vertices (refused as a possible bomb)"
                )
            placed = (self.vertex_count, points)
            self._placed[key] = placed
            self.vertex_blocks.append(placement.apply(points))
            self.vertex_count += len(points)
        if flip:
            corners = geo.reverse_winding(sizes, corners)
        self.size_blocks.append(sizes)
        self.corner_blocks.append(corners)
        self.corner_offsets.append(placed[0])

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """vertices (n, 3) float64, face_sizes (k,) int64, face_indices int64."""
        if not self.size_blocks:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        corners = np.concatenate(self.corner_blocks).astype(np.int64)
        # one addition for all face sets: KiCad parts hold a thousand small ones
        corners += np.repeat(np.array(self.corner_offsets, dtype=np.int64), [len(c) for c in self.corner_blocks])
        return np.concatenate(self.vertex_blocks), np.concatenate(self.size_blocks).astype(np.int64), corners


@dataclass
class _State1:
    """VRML 1.0 traversal state (what a Separator saves and restores)."""

    placement: geo.Placement
    points: np.ndarray | None = None  # current Coordinate3
    clockwise: bool = False  # ShapeHints vertexOrdering CLOCKWISE
    switch_choice: int = SWITCH_NONE  # whichChild of the last Switch (for -2, inherit)

    def copy(self) -> "_State1":
        return _State1(self.placement, self.points, self.clockwise, self.switch_choice)


class SceneWalker:
    """Counts and expands parsed VRML scenes.

    Parameters
    ----------
    inline : callable(node, version, depth) -> (nodes, version) or None
        Resolves an Inline / WWWInline node (at nesting ``depth``) to the top-level nodes
        of the file it names, counted; None when it is not followed.
    warnings : Warnings
    describe : callable(node) -> str
        Where a node is, for messages ("line 12", "sub.wrl line 3").
    """

    def __init__(self, inline: Callable, warnings: Warnings, describe: Callable[[Node], str]):
        self.inline = inline
        self.warnings = warnings
        self.describe = describe
        self._counts: dict[int, tuple[int, int]] = {}
        self._points_cache: dict[int, np.ndarray] = {}
        self._polygon_cache: dict[tuple[int, int], geo.FaceSet] = {}
        self._face_sets2: dict[int, tuple[np.ndarray, geo.FaceSet]] = {}  # VRML 2.0, by node

    # -- field access ------------------------------------------------------------------

    def fail(self, node: Node, reason: str) -> LoadError:
        return LoadError(node.source.path if node.source else None, reason, node.line)

    def numbers(self, node: Node, name: str, count: int, default) -> np.ndarray:
        """A field of exactly ``count`` numbers (the default when absent)."""
        value = node.fields.get(name)
        if value is None or (isinstance(value, list) and not value):
            return np.asarray(default, dtype=np.float64)
        if not isinstance(value, np.ndarray) or len(value) != count:
            found = f"{len(value)} number(s)" if isinstance(value, np.ndarray) else "something else"
            raise self.fail(node, f"{node.type}.{name} needs {count} number(s), found {found}")
        return value

    def number(self, node: Node, name: str, default: float) -> float:
        return float(self.numbers(node, name, 1, [default])[0])

    def flag(self, node: Node, name: str, default: bool) -> bool:
        value = node.fields.get(name, default)
        if isinstance(value, bool):
            return value
        if isinstance(value, np.ndarray) and len(value) == 1 and value[0] in (0.0, 1.0):
            return bool(value[0])  # VRML 1.0 writes SFBool as 0 / 1 too
        raise self.fail(node, f"{node.type}.{name} must be TRUE or FALSE")

    @staticmethod
    def nodes(node: Node, name: str) -> list[Node]:
        value = node.fields.get(name)
        if isinstance(value, Node):
            return [value]
        if isinstance(value, list):
            return [item for item in value if isinstance(item, Node)]
        return []

    @staticmethod
    def words(node: Node, name: str, default: tuple[str, ...]) -> set[str]:
        value = node.fields.get(name, default)
        return set(value) if isinstance(value, tuple) else set(default)

    # -- children: the one definition both passes use -----------------------------------

    def switch_choice(self, node: Node, inherited: int | None) -> int:
        """A VRML 1.0 Switch's ``whichChild``; -2 (inherit) takes the value of the last
        Switch traversed, ``inherited``, or all children when that is not known (the
        counting pass wants an upper bound)."""
        which = int(self.number(node, "whichChild", SWITCH_NONE))
        if which == SWITCH_INHERIT:
            return SWITCH_ALL if inherited is None else inherited
        return which

    def children(
        self, node: Node, version: int, inherited: int | None = None, depth: int = 0
    ) -> tuple[list[Node], int]:
        """Child nodes traversed below ``node``, and the version to read them with.

        ``inherited`` is the ``whichChild`` a VRML 1.0 Switch set last (walk only);
        ``depth`` the nesting depth of ``node``, for the files an Inline brings in.
        """
        kind = node.type
        if version == 2:
            if kind not in _V2_PARENTS:
                return [], 2
            if kind == "Shape":
                geometry = node.fields.get("geometry")
                return ([geometry] if geometry.__class__ is Node else self.nodes(node, "geometry")[:1]), 2
            if kind in V2_GROUPS:
                return self.nodes(node, "children"), 2
            if kind == "Switch":
                choices = self.nodes(node, "choice") or self.nodes(node, "children")
                which = int(self.number(node, "whichChoice", -1))
                return ([choices[which]] if 0 <= which < len(choices) else []), 2
            if kind == "LOD":
                return (self.nodes(node, "level") or self.nodes(node, "children"))[:1], 2
            if kind == "Inline":
                return self.inline(node, version, depth) or ([], 2)
            return [], 2
        if kind in V1_SEPARATORS or kind == "Group" or kind == "TransformSeparator":
            return node.children, 1
        if kind == "Switch":
            which = self.switch_choice(node, inherited)
            if which == SWITCH_ALL:
                return node.children, 1
            return ([node.children[which]] if 0 <= which < len(node.children) else []), 1
        if kind == "LOD":
            return node.children[:1], 1
        if kind == "WWWInline":
            return self.inline(node, version, depth) or ([], 1)
        return [], 1

    # -- pass 1: counting ----------------------------------------------------------------

    def count(self, node: Node, version: int, depth: int = 0) -> tuple[int, int]:
        """(triangles, node visits) that expanding ``node`` gives; memoised per node."""
        key = id(node)
        known = self._counts.get(key)
        if known is not None:
            return known
        if depth > MAX_SCENE_DEPTH:
            raise self.fail(node, f"nodes nested deeper than {MAX_SCENE_DEPTH} levels (through Inline)")
        kind = node.type
        # known types without geometry are most nodes: skip the call for them
        triangles = 0 if kind in _KNOWN_OTHER[version] else self.own_triangles(node, version)
        visits = 1
        if version == 2 and kind not in _V2_PARENTS:
            self._counts[key] = (triangles, visits)  # a leaf, as children() would say
            return triangles, visits
        children, child_version = self.children(node, version, None, depth)
        for child in children:
            child_triangles, child_visits = self.count(child, child_version, depth + 1)
            triangles += child_triangles
            descends = child_triangles > 0 or self._descends(child, child_triangles, child_version)
            visits += child_visits if descends else 1
        self._counts[key] = (triangles, visits)
        return triangles, visits

    @staticmethod
    def _descends(node: Node, triangles: int, version: int) -> bool:
        """Does the walk go below ``node``? Not when it gives no triangles and cannot
        change the state of what follows it (VRML 1.0 Groups and Switches can)."""
        if triangles > 0:
            return True
        return version == 1 and node.type in ("Group", "Switch", "LOD", "TransformSeparator")

    def own_triangles(self, node: Node, version: int) -> int:
        """Triangles of a geometry node itself (upper bound for face sets); warns about
        node types that are skipped."""
        kind = node.type
        if kind in _KNOWN_OTHER[version]:
            return 0  # neither geometry nor skipped: nothing to count or report
        if kind == "IndexedFaceSet":
            if version == 2:  # its coordinates are known: split it now (kept for the walk)
                ready = self._face_sets2.get(id(node))  # see prepare()
                if ready is None:
                    points = self.coordinates2(node)
                    ready = self._face_sets2[id(node)] = (points, self.face_set(node, len(points)))
                elif ready[1][3]:  # notes not reported yet
                    ready = self._face_sets2[id(node)] = (ready[0], self._report(node, ready[1]))
                return ready[1][2]
            index = node.fields.get("coordIndex")  # VRML 1.0: coordinates come from the state
            return geo.polygon_triangle_count(index) if isinstance(index, np.ndarray) else 0
        if kind in _PRIMITIVES:
            primitive = self.primitive(node, version)
            if primitive is not None:
                return geo.primitive_triangle_count(primitive)
        self._note_skipped(node, version)
        return 0

    def _note_skipped(self, node: Node, version: int) -> None:
        kind = node.type
        if node.external:
            return  # the EXTERNPROTO was reported once already
        known, unsupported = (_V2_KNOWN, V2_UNSUPPORTED_GEOMETRY) if version == 2 else (_V1_KNOWN, V1_UNSUPPORTED)
        if kind in unsupported:
            self.warnings.add(self.describe(node), f"{kind} is not supported: skipped")
        elif kind not in known and not kind.endswith(("Sensor", "Interpolator")):
            self.warnings.add(self.describe(node), f"unknown node type {kind!r} skipped")

    # -- primitives ------------------------------------------------------------------------

    def primitive(self, node: Node, version: int) -> geo.Polygons | None:
        """Polygons of a Box/Cube, Sphere, Cylinder or Cone node, in its own coordinates."""
        kind = node.type
        if kind == "Box" and version == 2:
            size = self.numbers(node, "size", 3, [2.0, 2.0, 2.0])
            return geo.box(*map(float, size))
        if kind == "Cube" and version == 1:
            return geo.box(
                self.number(node, "width", 2.0), self.number(node, "height", 2.0), self.number(node, "depth", 2.0)
            )
        if kind == "Sphere":
            return geo.sphere(self.number(node, "radius", 1.0))
        if kind == "Cylinder":
            radius, height = self.number(node, "radius", 1.0), self.number(node, "height", 2.0)
            if version == 2:
                side, top, bottom = (self.flag(node, name, True) for name in ("side", "top", "bottom"))
            else:
                parts = self._parts(node)
                side, top, bottom = ("SIDES" in parts, "TOP" in parts, "BOTTOM" in parts)
            return geo.cylinder(radius, height, side, top, bottom)
        if kind == "Cone":
            radius, height = self.number(node, "bottomRadius", 1.0), self.number(node, "height", 2.0)
            if version == 2:
                side, bottom = self.flag(node, "side", True), self.flag(node, "bottom", True)
            else:
                parts = self._parts(node)
                side, bottom = "SIDES" in parts, "BOTTOM" in parts
            return geo.cone(radius, height, side, bottom)
        return None

    def _parts(self, node: Node) -> set[str]:
        parts = self.words(node, "parts", ("ALL",))
        return {"SIDES", "TOP", "BOTTOM"} if "ALL" in parts else parts

    # -- pass 2: expanding -------------------------------------------------------------------

    def walk(self, nodes: list[Node], version: int, placement: geo.Placement, builder: MeshBuilder) -> None:
        """Expand top-level ``nodes`` of a file into ``builder``."""
        if version == 2:
            for node in nodes:
                self._walk2(node, placement, builder)
        else:
            state = _State1(placement)
            for node in nodes:
                self._walk1(node, state, builder)

    def _walk2(self, node: Node, placement: geo.Placement, builder: MeshBuilder) -> None:
        if self._counts[id(node)][0] == 0:
            return
        kind = node.type
        if kind == "Transform":
            placement = placement.then(self._transform(node, "scale"))
        elif kind == "IndexedFaceSet":
            self._face_set2(node, placement, builder)
            return
        elif kind in ("Box", "Sphere", "Cylinder", "Cone"):
            self._add_primitive(node, 2, placement, builder)
            return
        children, version = self.children(node, 2)
        if version == 1:  # an Inline of a VRML 1.0 file
            self.walk(children, 1, placement, builder)
            return
        for child in children:
            self._walk2(child, placement, builder)

    def _transform(self, node: Node, scale_field: str) -> np.ndarray:
        return geo.transform_matrix(
            self.numbers(node, "translation", 3, [0, 0, 0]),
            self.numbers(node, "rotation", 4, [0, 0, 1, 0]),
            self.numbers(node, scale_field, 3, [1, 1, 1]),
            self.numbers(node, "scaleOrientation", 4, [0, 0, 1, 0]),
            self.numbers(node, "center", 3, [0, 0, 0]),
        )

    def _face_set2(self, node: Node, placement: geo.Placement, builder: MeshBuilder) -> None:
        points, (sizes, corners, _, _) = self._face_sets2[id(node)]  # counted before any walk
        ccw = node.fields.get("ccw", True)
        flip = (not (ccw if ccw is True else self.flag(node, "ccw", True))) != placement.mirrored
        builder.add(points, placement, sizes, corners, flip)

    def _walk1(self, node: Node, state: _State1, builder: MeshBuilder) -> None:
        kind = node.type
        if kind in V1_TRANSFORMS:
            state.placement = state.placement.then(self._transform1(node))
        elif kind == "Coordinate3":
            state.points = self.points(node, "point")
        elif kind == "ShapeHints":
            ordering = self.words(node, "vertexOrdering", ("UNKNOWN_ORDERING",))
            state.clockwise = "CLOCKWISE" in ordering
        elif self._counts[id(node)][0] == 0 and not self._descends(node, 0, 1):
            return
        elif kind == "IndexedFaceSet":
            self._face_set1(node, state, builder)
        elif kind in V1_GEOMETRY:
            self._add_primitive(node, 1, state.placement, builder)
        elif kind in V1_SEPARATORS:
            inner = state.copy()
            for child in node.children:
                self._walk1(child, inner, builder)
        elif kind == "TransformSeparator":
            saved = state.placement
            for child in node.children:
                self._walk1(child, state, builder)
            state.placement = saved
        else:  # Group, Switch, LOD: state set inside leaks out; WWWInline: it does not
            children, version = self.children(node, 1, state.switch_choice)
            if kind == "Switch":
                state.switch_choice = self.switch_choice(node, state.switch_choice)
            if version == 2:  # WWWInline of a VRML 2.0 file
                self.walk(children, 2, state.placement, builder)
                return
            inner = state.copy() if kind == "WWWInline" else state
            for child in children:
                self._walk1(child, inner, builder)

    def _transform1(self, node: Node) -> np.ndarray:
        kind = node.type
        if kind == "Transform":
            return self._transform(node, "scaleFactor")
        if kind == "MatrixTransform":
            # VRML 1.0 matrices act on row vectors (p' = p M): ours act on columns
            return self.numbers(node, "matrix", 16, np.eye(4).ravel()).reshape(4, 4).T
        if kind == "Translation":
            return geo.translation_matrix(self.numbers(node, "translation", 3, [0, 0, 0]))
        if kind == "Rotation":
            return geo.linear_matrix(geo.rotation_matrix(self.numbers(node, "rotation", 4, [0, 0, 1, 0])))
        return geo.linear_matrix(np.diag(self.numbers(node, "scaleFactor", 3, [1, 1, 1])))

    def _face_set1(self, node: Node, state: _State1, builder: MeshBuilder) -> None:
        if state.points is None:
            self.warnings.add(self.describe(node), "IndexedFaceSet before any Coordinate3 skipped")
            return
        sizes, corners = self.face_set(node, len(state.points))[:2]
        flip = state.clockwise != state.placement.mirrored
        builder.add(state.points, state.placement, sizes, corners, flip)

    def _add_primitive(self, node: Node, version: int, placement: geo.Placement, builder: MeshBuilder) -> None:
        vertices, sizes, corners = self.primitive(node, version)
        builder.add(vertices, placement, sizes, corners, placement.mirrored)

    # -- face set data -------------------------------------------------------------------

    def coordinates2(self, node: Node) -> np.ndarray:
        """The points of a VRML 2.0 IndexedFaceSet's ``coord`` node ((0, 3) when none)."""
        coord = self.nodes(node, "coord")
        if not coord:
            if node.fields.get("coordIndex") is not None:
                self.warnings.add(self.describe(node), "IndexedFaceSet without coord skipped")
            return _NO_POINTS
        return self.points(coord[0], "point")

    def points(self, node: Node, name: str) -> np.ndarray:
        """A Coordinate / Coordinate3 node's points as (n, 3), checked once per node."""
        cached = self._points_cache.get(id(node))
        if cached is not None:
            return cached
        points = _as_points(node.fields.get(name))
        if points is None:
            value = node.fields.get(name)
            found = f"{len(value)} numbers" if isinstance(value, np.ndarray) else "something else"
            raise self.fail(node, f"{node.type}.{name} needs x y z triples, found {found}")
        self._points_cache[id(node)] = points
        return points

    def face_set(self, node: Node, point_count: int) -> geo.FaceSet:
        """An IndexedFaceSet's polygons over ``point_count`` points (cached per node);
        what was dropped is reported the first time."""
        key = (id(node), point_count)
        face_set = self._polygon_cache.get(key)
        if face_set is None:
            index = _as_coord_index(node.fields.get("coordIndex"))
            face_set = geo.face_sets_from_coord_indices([index], [point_count])[0] if index is not None else None
            if face_set is None:
                raise self.fail(node, "IndexedFaceSet.coordIndex must be integers")
            self._polygon_cache[key] = face_set
        if face_set[3]:  # notes not reported yet
            face_set = self._polygon_cache[key] = self._report(node, face_set)
        return face_set

    def _report(self, node: Node, face_set: geo.FaceSet) -> geo.FaceSet:
        """Warn about what splitting ``node``'s polygons dropped; the face set without the
        notes, to keep in their place."""
        sizes, corners, triangles, notes = face_set
        for note in notes:
            self.warnings.add(self.describe(node), f"IndexedFaceSet: {note}", kind=note.split(" ", 1)[1])
        return sizes, corners, triangles, ()

    def prepare(self, nodes: list[Node], version: int) -> None:
        """Split the polygons of every VRML 2.0 IndexedFaceSet among ``nodes`` (all the
        nodes of a file) in one go, for the counting pass to find.

        Only what cannot fail is prepared: face sets without a coord node, or whose points
        or coordIndex are not usable, are left to the counting pass (:meth:`coordinates2`,
        :meth:`face_set`), which reports them when (and if) the traversal reaches them.
        Dropped indices are reported there too, the first time a face set is counted.
        """
        if version != 2:
            return  # VRML 1.0 face sets use the Coordinate3 in effect: known only when walked
        face_sets, all_points, indices = [], [], []
        for node in [node for node in nodes if node.type == "IndexedFaceSet"]:
            fields = node.fields
            coord, index = fields.get("coord"), fields.get("coordIndex")
            if coord.__class__ is not Node or index.__class__ is not np.ndarray:
                continue  # left to the counting pass: no coord (a warning), a list, IS, ...
            points = self._points_cache.get(id(coord))  # one array per Coordinate node: the
            if points is None:  # builder shares the vertices of face sets that share it
                points = coord.fields.get("point")
                if points.__class__ is not np.ndarray or len(points) % 3:
                    continue
                points = self._points_cache[id(coord)] = points.reshape(-1, 3)
            face_sets.append(node)
            all_points.append(points)
            indices.append(index)
        results = geo.face_sets_from_coord_indices(indices, [len(points) for points in all_points])
        self._face_sets2.update(
            (id(node), (points, face_set))
            for node, points, face_set in zip(face_sets, all_points, results)
            if face_set is not None
        )


def _as_points(value) -> np.ndarray | None:
    """A point field's value as (n, 3); None when it is not x y z triples."""
    if value is None or (isinstance(value, list) and not value):
        return _NO_POINTS
    if not isinstance(value, np.ndarray) or len(value) % 3:
        return None
    return value.reshape(-1, 3)


def _as_coord_index(value) -> np.ndarray | None:
    """A coordIndex field's value as numbers; None when it is something else."""
    if value is None or (isinstance(value, list) and not value):
        return np.zeros(0)
    return value if isinstance(value, np.ndarray) else None
