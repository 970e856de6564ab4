"""The formats shapeidx reads: names and file name endings, the one list everything derives from.

The reader modules attach their behaviour to these names (``Format(name, ..., suffixes=
SUFFIXES[name], read=...)``, :mod:`shapeidx.io.registry`); the build's walk, ``--type``'s
choices, the web page's file picker and its upload names all come from here. This module
imports nothing, so that the command line's ``--help`` can list the formats.
"""

#: Format name -> the file name endings it owns (any case; each may also end in ``.gz``).
SUFFIXES = {
    "stl": (".stl",),
    "obj": (".obj",),
    "off": (".off",),
    "ply": (".ply",),
    "vrml": (".wrl", ".wrz", ".vrml"),
    "step": (".step", ".stp"),
    "iges": (".iges", ".igs"),
}
#: The format names, in the order messages list them.
FORMAT_NAMES = tuple(SUFFIXES)
#: Every file name ending a part file may have (before an optional ``.gz``).
PART_SUFFIXES = tuple(sorted(s for suffixes in SUFFIXES.values() for s in suffixes))
