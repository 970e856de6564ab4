"""VRML 1.0 and 2.0 (VRML97) reader, made for what CAD exporters really write.

The reader runs in four steps, one module each:

1. :mod:`.lexer`: bytes to tokens; number arrays converted in bulk with numpy.
2. :mod:`.parser`: tokens to a tree of nodes (DEF/USE shared, PROTOs expanded).
3. :mod:`.scene`: the face sets of each file split into polygons in one batch, the
   tree counted (limits checked before any geometry is built) and then traversed with a
   transform stack, collecting face sets.
4. This module: files (gzip, Inline of other files, limits) and the resulting
   :class:`~shapeidx.io.base.PolygonMesh`.

Inline (VRML 2.0) and WWWInline (VRML 1.0) are followed only to local files inside the
indexed directory (``LoadLimits.root``, else the loaded file's directory): no URLs, no
escape through ``..``, absolute paths or symbolic links, at most
``LoadLimits.max_inline_depth`` files deep, never in a cycle. An Inline that is not
followed is reported in the warnings; an inlined file that is broken fails the load.

Units are never rescaled: coordinates are returned as the file gives them.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ...errors import LoadError
from ..base import Format, LoadLimits, PolygonMesh, head_of, read_bytes
from ..formats import SUFFIXES
from . import fast
from .geometry import Placement
from .parser import Node, Scene, parse_vrml
from .scene import MAX_NODE_VISITS, MeshBuilder, SceneWalker, Warnings

__all__ = ["FORMATS", "load_vrml"]

#: Memory that splitting a coordIndex into polygons takes per value, before the triangles are
#: counted (measured: 68 bytes on one coordIndex of 4 million values, from the reader's
#: peak RSS; numpy's temporaries of :func:`.geometry.face_sets_from_coord_indices`).
BYTES_PER_INDEX = 100
_URL_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]+:")


def load_vrml(path, limits: LoadLimits | None = None, data: bytes | None = None) -> PolygonMesh:
    """Read a VRML 1.0 or 2.0 file (plain or gzip) into a :class:`PolygonMesh`.

    Parameters
    ----------
    path : path-like
    limits : LoadLimits, optional
        Triangle, gzip-expansion and Inline-depth limits, and the directory Inline may
        not leave.
    data : bytes, optional
        The file's content (already decompressed), when the caller has read it; Inline
        references are still read from ``path``'s folder.

    Returns
    -------
    PolygonMesh
        Polygons as the file gives them (not triangulated), in world coordinates, wound
        counter-clockwise seen from outside as far as the file says so; ``format`` is
        ``"vrml1"`` or ``"vrml2"`` after the file's header.

    Raises
    ------
    LoadError
        One line naming the file, the line when known, and the reason.
    """
    limits = limits or LoadLimits()
    return VrmlLoad(Path(path), limits, data).run()


class VrmlLoad:
    """One call of :func:`load_vrml`: the files it reads and what it found."""

    def __init__(self, path: Path, limits: LoadLimits, data: bytes | None = None):
        self.path = path
        self.limits = limits
        self.top_data = data
        root = limits.root if limits.root is not None else path.parent
        self.root = os.path.realpath(root)
        self.warnings = Warnings()
        self.scenes: dict[str, Scene | None] = {}  # real path -> parsed file
        self.inline_stack: list[str] = []  # real paths of the files being expanded
        self.inline_targets: dict[int, tuple[list[Node], int] | None] = {}
        self.walker = SceneWalker(self.resolve_inline, self.warnings, self.where)

    def run(self) -> PolygonMesh:
        if fast.available:  # flat VRML 2.0 (KiCad): the compiled reader, else None
            if self.top_data is None:
                self.top_data = read_bytes(self.path, self.limits)[0]
            mesh = fast.load_flat(self.path, self.top_data, self.limits, self.check_expansion)
            if mesh is not None:
                return mesh
        return self.run_python()

    def run_python(self) -> PolygonMesh:
        """The whole load in Python: what :mod:`.fast` gives for the files it reads."""
        top = self.read_scene(self.path)
        self.inline_stack.append(os.path.realpath(self.path))
        triangles = visits = 0
        for node in top.nodes:
            node_triangles, node_visits = self.walker.count(node, top.version)
            triangles += node_triangles
            visits += node_visits
        self.check_expansion(triangles, visits)
        builder = MeshBuilder(self.limits.max_triangles, self.path)
        self.walker.walk(top.nodes, top.version, Placement(np.eye(4)), builder)
        vertices, sizes, corners = builder.arrays()
        return PolygonMesh(vertices, sizes, corners, f"vrml{top.version}", self.warnings.as_list())

    def check_expansion(self, triangles: int, visits: int) -> None:
        """Refuse DEF/USE (or Inline) expansions beyond the limits, before building them."""
        if triangles > self.limits.max_triangles:
            raise LoadError(
                self.path,
                f"would expand to {triangles:,} triangles, more than the limit of "
                f"{self.limits.max_triangles:,} (refused as a possible DEF/USE bomb)",
            )
        self.limits.check_memory(self.path, triangles)
        if visits > MAX_NODE_VISITS:
            raise LoadError(
                self.path,
                f"DEF/USE would expand to {visits:,} node instances, more than {MAX_NODE_VISITS:,} (refused as a possible bomb)",
            )

    def check_splitting(self, path: Path, scene: Scene) -> None:
        """Refuse a file whose coordIndex values are too many to split into polygons.

        Splitting takes some :data:`BYTES_PER_INDEX` per value (numpy's temporaries),
        before the triangles are counted: one coordIndex of 75 million values (a 450 kB
        gzipped file) would take 7 GB. It refuses no mesh that the count would admit: a value
        of a polygon gives at least a quarter of a triangle (``a, b, c, -1``), whose cleaning
        is estimated at 800 bytes.
        """
        values = 0
        for node in scene.all_nodes:
            if node.type == "IndexedFaceSet":
                index = node.fields.get("coordIndex")
                if index.__class__ is np.ndarray:
                    values += len(index)
        self.limits.check_reading(path, BYTES_PER_INDEX * values, f"to split its {values:,} coordIndex values into polygons")

    def read_scene(self, path: Path, inlined: bool = False) -> Scene | None:
        """Read and parse one file; its parser warnings join ours.

        An inlined file must start with a ``#VRML`` header (Inline may name images or
        other formats); for one that does not, None is returned.
        """
        data = self.top_data if not inlined and self.top_data is not None else read_bytes(path, self.limits)[0]
        if inlined and not data.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"#VRML"):
            return None
        scene = parse_vrml(data, path)
        self.check_splitting(path, scene)
        self.walker.prepare(scene.all_nodes, scene.version)
        for message in scene.warnings:
            self.warnings.add(path.name if inlined else None, message)
        return scene

    def where(self, node: Node) -> str:
        """'line 12' for the loaded file, 'part.wrl line 12' for an inlined one."""
        source = node.source
        if source is None:
            return "?"
        line = f"line {node.line}"
        return line if Path(source.path) == self.path else f"{Path(source.path).name} {line}"

    # -- Inline --------------------------------------------------------------------------

    def resolve_inline(self, node: Node, version: int, depth: int) -> tuple[list[Node], int] | None:
        """The top-level nodes (and version) of the file an Inline names, or None.

        Called by the counting pass the first time it meets the node, with the files
        being expanded on ``inline_stack`` (which is how cycles are seen).
        """
        key = id(node)
        if key not in self.inline_targets:
            self.inline_targets[key] = self._follow_inline(node, version, depth)
        return self.inline_targets[key]

    def _follow_inline(self, node: Node, version: int, depth: int) -> tuple[list[Node], int] | None:
        urls = node.fields.get("url" if version == 2 else "name")
        # a list of strings; VRML 1.0 may give the name without quotes (a word tuple)
        urls = [u for u in urls if isinstance(u, str)] if isinstance(urls, (list, tuple)) else []
        if not urls:
            self.warnings.add(self.where(node), f"{node.type} without a file name skipped")
            return None
        reasons = []
        for url in urls:
            target, reason = self._local_target(node, url)
            if target is None:
                reasons.append(reason)
                continue
            scene = self._inline_scene(node, target)
            if scene is None:
                return None
            self.inline_stack.append(target)
            try:
                for child in scene.nodes:
                    self.walker.count(child, scene.version, depth + 1)
            finally:
                self.inline_stack.pop()
            return scene.nodes, scene.version
        self.warnings.add(self.where(node), f"{node.type} not followed: {'; '.join(reasons)}")
        return None

    def _local_target(self, node: Node, url: str) -> tuple[str | None, str]:
        """Real path of a local file an Inline url names, or None and why not."""
        if _URL_SCHEME.match(url) and not re.match(r"^[A-Za-z]:[\\/]", url):
            return None, f"{url!r} is a URL (only local files are followed)"
        relative = unquote(url.split("#", 1)[0]).replace("\\", "/")
        base = Path(node.source.path).parent if node.source is not None else self.path.parent
        target = os.path.realpath(base / relative)
        if os.path.commonpath([target, self.root]) != self.root:
            return None, f"{url!r} is outside the indexed directory"
        if not os.path.isfile(target):
            return None, f"{url!r} does not exist"
        return target, ""

    def _inline_scene(self, node: Node, target: str) -> Scene | None:
        """The parsed file ``target``; None (with a warning) for cycles, depth, non-VRML."""
        if target in self.inline_stack:
            self.warnings.add(self.where(node), f"Inline cycle through {Path(target).name!r} cut")
            return None
        if len(self.inline_stack) > self.limits.max_inline_depth:
            self.warnings.add(self.where(node), f"Inline deeper than {self.limits.max_inline_depth} files not followed")
            return None
        if target not in self.scenes:
            self.scenes[target] = self.read_scene(Path(target), inlined=True)
            if self.scenes[target] is None:
                self.warnings.add(self.where(node), f"Inline {Path(target).name!r} is not a VRML file: skipped")
        return self.scenes[target]


def _looks_like_vrml(data: bytes) -> bool:
    return head_of(data).startswith((b"#VRML", b"#Inventor"))


#: What ends a polygon in a coordIndex: ``-1`` and a separator (counted by bytes.count, in C).
_POLYGON_ENDS = (b"-1,", b"-1 ", b"-1\n", b"-1\r", b"-1\t", b"-1]")


def declared_vrml(data: bytes) -> tuple[int, int]:
    """Triangles at least: one per ``-1`` that ends a polygon (each gives one triangle or
    more), counted over the bytes in C before the file is parsed, so that one huge
    coordIndex is refused before the scanner stores it (a 450 kB gzipped file of 25 million
    triangles took 7 GB before this count). The count also takes a ``-1`` written as a
    coordinate (rare: CAD exporters write ``-1.0``); it is checked against the memory
    limit only, some 5 million triangles by default."""
    return sum(data.count(end) for end in _POLYGON_ENDS), 0


FORMATS = [
    Format("vrml", "VRML", SUFFIXES["vrml"], lambda path, data, limits: load_vrml(path, limits, data), sniff=_looks_like_vrml,
           declared=declared_vrml)
]
