"""Readers: a registry of file formats, one module per format family, one entry point.

Every reader module declares its :class:`Format` (name, suffixes, sniff test, and
``read(path, data, limits)``); :func:`load` picks the reader by the file's name, or by its
content when the name says nothing, and returns a :class:`PolygonMesh` (vertices and
polygons, as the file says) or raises :class:`~shapeidx.errors.LoadError` with a one-line
reason. gzip compression is detected from the content, for every format.

    stl.py obj.py off.py ply.py   the mesh formats
    vrml/                         VRML 1.0 and 2.0 (a package of its own: lexer, parser, ...)
    step.py                       STEP and IGES solids, faceted by OpenCASCADE (faceting.py)
    base.py                       PolygonMesh, Format, LoadLimits, reading (gzipped) bytes
    formats.py                    the formats' names and suffixes: the one list
    registry.py                   the formats, and load / load_bytes / format_of over them
    contained.py                  native readers in a child process: a crash or hang, one error line
    text.py                       decoding text files of unknown encoding
    metadata.py                   what a file says of itself (title, product id)
    parts.py                      a file's sub-parts (solids, bodies) for build --parts;
                                  polygons.py the fans, areas and label rows it needs

Names are loaded on first use (:mod:`shapeidx._lazy`): ``shapeidx.io.faceting`` and the
command line's option defaults must not import every reader.
"""

from .._lazy import attach

_NAMES = {
    **dict.fromkeys(
        ["FORMATS", "check_polygon_mesh", "count_by_label", "entry_format", "format_of", "load", "load_bytes", "reader_revision", "register",
         "revisions", "suffixes"], ".registry"
    ),
    **dict.fromkeys(["Format", "LoadLimits", "PolygonMesh", "file_hash", "read_bytes"], ".base"),
}
__all__ = sorted(_NAMES)
__getattr__, __dir__ = attach(__name__, _NAMES)
