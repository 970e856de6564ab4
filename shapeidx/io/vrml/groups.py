"""A VRML file's parts as its grouping nodes give them (``build --parts``).

A modeller or an exporter that groups geometry says what the parts are: a robot's links
and motors are Transforms of their own (KUKA's models, ``DEF AOBJ_0001_007 Transform``),
a Blender or Wings3D export of a KiCad part writes its body and each pin as a named
Transform (``DEF Pin1 Transform``). A flat file says nothing: KiCad 6 writes a part as
hundreds of top-level Shapes, one per colour and face set, none of which is a part.

The rule, on the tree as the reader walks it (Switch, LOD and Inline as for the mesh):

1. Nodes that hold no triangles are left out; a grouping node that is the only one holding
   geometry at its level is looked through (the wrappers most exporters write).
2. A level whose geometry is all in Shapes is one part: at the top of the file, the file is
   flat and :func:`vrml_groups` gives None (the caller splits it into connected bodies).
3. A level holding several grouping nodes with geometry is an assembly: each of them is
   split the same way (rules 1-3: a robot's arm is nested link by link), and the Shapes
   directly at the level are one part of their own (a package's body beside its pins).

Each group is named after the innermost ``DEF`` name on the way down to it. A node that
is ``USE``d several times gives as many groups (a pin defined once and placed eight times).
:func:`shapeidx.io.parts.split_parts` then takes the connected bodies of each group as the
sub-parts (a group may gather several bodies: FreeCAD writes the ten pins of a resistor
array as one group, of their colour).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..base import LoadLimits, PolygonMesh, read_bytes
from ..polygons import fan_triangles, members_of, triangle_areas
from . import fast
from .geometry import Placement
from .parser import Node
from .reader import VrmlLoad
from .scene import V1_SEPARATORS, V2_GROUPS, MeshBuilder, SceneWalker

__all__ = ["vrml_groups"]

#: Node types that group others (the split descends through them).
_GROUPS = {2: V2_GROUPS | {"Switch", "LOD", "Inline"},
           1: V1_SEPARATORS | {"Group", "Switch", "LOD", "TransformSeparator", "WWWInline"}}
_OWN = -1  # label of geometry outside every part node (Shapes at the top of the file)


def vrml_groups(path, limits: LoadLimits | None = None, min_area_share: float = 0.0) -> list[tuple[str, PolygonMesh]] | None:
    """``[(name, mesh)]``, one per part instance in the file's grouping (in world
    coordinates, polygons as read), or None when the file is flat or is one group.
    Instances whose area is not above ``min_area_share`` of the file's are left out (specks:
    a file of a hundred thousand tiny groups costs one pass, not one per group).

    Raises
    ------
    LoadError
        As :func:`~shapeidx.io.vrml.load_vrml` would.
    """
    limits = limits or LoadLimits()
    path = Path(path)
    data = read_bytes(path, limits)[0]
    if fast.available and fast.load_flat(path, data, limits, lambda *_: None) is not None:
        return None  # top-level Shapes only (the compiled reader refuses any group node)
    load = _GroupsLoad(path, limits, data)
    return load.run_groups(min_area_share)


class _MarkingWalker(SceneWalker):
    """The reader's walk, telling the builder when it enters and leaves a part node."""

    marks: dict[int, str] = {}

    def _walk2(self, node: Node, placement: Placement, builder) -> None:
        name = self.marks.get(id(node))
        if name is None:
            return super()._walk2(node, placement, builder)
        outer = builder.enter(name)
        try:
            super()._walk2(node, placement, builder)
        finally:
            builder.label = outer

    def _walk1(self, node: Node, state, builder) -> None:
        name = self.marks.get(id(node))
        if name is None:
            return super()._walk1(node, state, builder)
        outer = builder.enter(name)
        try:
            super()._walk1(node, state, builder)
        finally:
            builder.label = outer


class _LabelledBuilder(MeshBuilder):
    """A :class:`MeshBuilder` that remembers which part instance each face set is in."""

    def __init__(self, max_vertices: int, path):
        super().__init__(max_vertices, path)
        self.label = _OWN
        self.names: list[str] = []  # of each instance
        self.block_labels: list[int] = []

    def enter(self, name: str) -> int:
        outer, self.label = self.label, len(self.names)
        self.names.append(name)
        return outer

    def add(self, points, placement, sizes, corners, flip) -> None:
        before = len(self.size_blocks)
        super().add(points, placement, sizes, corners, flip)
        self.block_labels.extend([self.label] * (len(self.size_blocks) - before))


class _GroupsLoad(VrmlLoad):
    def __init__(self, path: Path, limits: LoadLimits, data: bytes):
        super().__init__(path, limits, data)
        self.walker = _MarkingWalker(self.resolve_inline, self.warnings, self.where)
        self.walker.marks = {}

    def run_groups(self, min_area_share: float = 0.0) -> list[tuple[str, PolygonMesh]] | None:
        top = self.read_scene(self.path)
        self.inline_stack.append(os.path.realpath(self.path))
        triangles = visits = 0
        for node in top.nodes:
            node_triangles, node_visits = self.walker.count(node, top.version)
            triangles += node_triangles
            visits += node_visits
        self.check_expansion(triangles, visits)
        marks, loose = self._plan(top.nodes, top.version, None, "", 0)
        if len(marks) + loose < 2:
            return None
        self.walker.marks = {id(node): name for node, name in marks}
        builder = _LabelledBuilder(self.limits.max_triangles, self.path)
        self.walker.walk(top.nodes, top.version, Placement(np.eye(4)), builder)
        vertices, sizes, corners = builder.arrays()
        if len(sizes) == 0:
            return None
        labels = np.repeat(np.array(builder.block_labels, dtype=np.int64), [len(s) for s in builder.size_blocks])
        whole = PolygonMesh(vertices, sizes, corners, f"vrml{top.version}")
        areas = triangle_areas(vertices, fan_triangles(whole))  # of the fans, polygon by polygon
        areas = np.bincount(np.repeat(np.arange(len(sizes)), sizes - 2), weights=areas, minlength=len(sizes))
        fmt = f"vrml{top.version}"
        found = []
        for polygons, corner_at in zip(members_of(labels), members_of(np.repeat(labels, sizes))):
            label = int(labels[polygons[0]])
            if not areas[polygons].sum() > min_area_share * areas.sum():
                continue  # a speck
            used, local = np.unique(corners[corner_at], return_inverse=True)
            mesh = PolygonMesh(vertices[used], sizes[polygons], local.reshape(-1).astype(np.int64), fmt)
            found.append(("" if label == _OWN else builder.names[label], mesh))
        return found or None

    def _holds(self, node: Node) -> bool:
        known = self.walker._counts.get(id(node))
        return known is not None and known[0] > 0

    def _plan(self, nodes: list[Node], version: int, entry: Node | None, name: str, depth: int):
        """The part nodes below ``nodes`` ([(node, name)]) and whether Shapes lie loose at
        the top of the file (a part with no node to mark)."""
        owner = entry
        while True:
            holding = [node for node in nodes if self._holds(node)]
            if len(holding) == 1 and holding[0].type in _GROUPS[version] and depth < 200:
                owner = holding[0]
                name = owner.name or name
                nodes, version = self.walker.children(owner, version, None, depth)
                depth += 1
                continue
            break
        groups = [node for node in holding if node.type in _GROUPS[version]]
        direct = len(groups) < len(holding)
        if not groups:  # Shapes only: one part (the file is flat when this is its top)
            return ([(entry, name)] if entry is not None else []), False
        marks: list[tuple[Node, str]] = []
        if direct and owner is not None:
            marks.append((owner, name))  # the level's own Shapes, beside its groups
        for group in groups:
            children, child_version = self.walker.children(group, version, None, depth)
            below, _ = self._plan(children, child_version, group, group.name, depth + 1)
            marks.extend(below)
        return marks, direct and owner is None
