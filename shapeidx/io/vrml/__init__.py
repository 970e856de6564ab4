"""VRML 1.0 and 2.0 (VRML97), as CAD exporters really write it.

    lexer.py     bytes -> tokens, number arrays converted in bulk
    parser.py    tokens -> a tree of nodes (DEF/USE shared, PROTOs expanded)
    scene.py     the tree counted (limits first), then walked with its transforms
    geometry.py  face sets -> polygons, transforms, primitives
    reader.py    files, gzip, Inline, limits -> a PolygonMesh
    fast.py      flat VRML 2.0 (KiCad) read by the compiled _scan.c in one pass; any
                 other file, or no compiled module, goes the way above
    groups.py    a file's parts as its grouping nodes (DEF Transforms) give them (build --parts)
"""

from .reader import FORMATS, load_vrml

__all__ = ["FORMATS", "load_vrml"]
