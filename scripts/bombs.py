#!/usr/bin/env python
"""Bombs: small files that claim or expand to enormous parts, and how each is refused.

Writes every bomb of :data:`BOMBS` to a temporary folder and loads and cleans each with the
default limits in a guarded worker (scripts/fuzz.py's: ``RLIMIT_DATA`` and a time limit),
then prints a Markdown table: the line, the time and the worker's peak memory.
tests/test_bombs.py checks the same bombs.

Usage::

    python scripts/bombs.py [--memory 2] [--timeout 120]
"""

from __future__ import annotations

import argparse
import gzip
import os
import platform
import struct
import sys
import tempfile
from pathlib import Path

import numpy as np

LEVELS = 100_000  # nesting depth


def grid_face_set(n: int) -> str:
    """A VRML 2.0 IndexedFaceSet of an n x n grid of quadrilaterals (2 n^2 triangles)."""
    points = " ".join(f"{x} {y} 0" for y in range(n + 1) for x in range(n + 1))
    quads = " ".join(
        f"{y * (n + 1) + x} {y * (n + 1) + x + 1} {(y + 1) * (n + 1) + x + 1} {(y + 1) * (n + 1) + x} -1"
        for y in range(n)
        for x in range(n)
    )
    return f"Shape {{ geometry IndexedFaceSet {{ coord Coordinate {{ point [ {points} ] }} coordIndex [ {quads} ] }} }}"


def doubling(levels: int, leaf: str, group: str = "Group {{ children [ USE A{0} USE A{0} ] }}") -> str:
    """DEF A0 leaf; A(i) holds two copies of A(i-1): every level doubles."""
    return "\n".join([f"DEF A0 {leaf}"] + [f"DEF A{i} " + group.format(i - 1) for i in range(1, levels + 1)])


def endless_gzip() -> bytes:
    """A VRML file whose gzip stream expands to 4 GiB: one member of 64 MiB of blanks
    (compressed to some 64 kB), repeated. A reader that does not stop would never end."""
    head = gzip.compress(b"#VRML V2.0 utf8\nShape { geometry Box { } }\n#", mtime=0)
    blanks = gzip.compress(b" " * (64 << 20), compresslevel=9, mtime=0)
    return head + blanks * 64


def ply_header(fmt: str, vertices: int, faces: int) -> bytes:
    return (
        f"ply\nformat {fmt} 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()


def tetrahedron_ply_body() -> bytes:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "<f4").tobytes()
    faces = b"".join(struct.pack("<B3i", 3, *f) for f in [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)])
    return vertices + faces


def stl_claiming(count: int) -> bytes:
    record = struct.pack("<12fH", *([0.0] * 3 + [0, 0, 0, 1, 0, 0, 0, 1, 0]), 0)
    return b"binary".ljust(80) + struct.pack("<I", count) + record * 10


#: name -> (file name, bytes, the reason expected)
BOMBS = {
    "gzip-endless": ("endless.wrl.gz", endless_gzip, "gzip data expands beyond the limit"),
    # 10,082 triangles per leaf, 4,095 copies: 41 million triangles, below the triangle limit
    # (50 M) and the node-visit limit, from a file of 0.3 MB; it would need some 30 GiB
    "def-use-41M": (
        "doubling.wrl",
        lambda: ("#VRML V2.0 utf8\n" + doubling(11, "Group { children [ " + grid_face_set(71) + " ] }")).encode(),
        "GiB of memory",
    ),
    "def-use-2^100": (
        "doubling100.wrl",
        lambda: ("#VRML V2.0 utf8\n" + doubling(100, "Shape { geometry Box { } }")).encode(),
        "more than the limit of 50,000,000",
    ),
    "vrml1-def-use-2^60": (
        "doubling-v1.wrl",
        lambda: ("#VRML V1.0 ascii\n" + doubling(60, "Separator { Cube { } }", "Separator {{ USE A{0} USE A{0} }}")).encode(),
        "more than the limit of 50,000,000",
    ),
    "stl-2^31-triangles": ("claims.stl", lambda: stl_claiming(1 << 31), "announces 2,147,483,648 triangles"),
    "stl-2^32-1-triangles": ("claims-max.stl", lambda: stl_claiming((1 << 32) - 1), "announces 4,294,967,295 triangles"),
    "ply-binary-2^31-faces": (
        "faces.ply",
        lambda: ply_header("binary_little_endian", 4, 1 << 31) + tetrahedron_ply_body(),
        "ends inside its 'face' data",
    ),
    "ply-binary-2^40-vertices": (
        "vertices.ply",
        lambda: ply_header("binary_little_endian", 1 << 40, 4) + tetrahedron_ply_body(),
        "ends inside its 'vertex' data",
    ),
    "ply-ascii-2^40-vertices": (
        "vertices-ascii.ply",
        lambda: ply_header("ascii", 1 << 40, 1) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "announces 1,099,511,627,776 vertex rows",
    ),
    "off-2^40-vertices": (
        "vertices.off",
        lambda: f"OFF\n{1 << 40} 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n".encode(),
        "announces 1,099,511,627,776 vertices",
    ),
    "off-2^31-faces": (
        "faces.off",
        lambda: f"OFF\n3 {1 << 31} 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n".encode(),
        "announces 3 vertices and 2,147,483,648 faces",
    ),
    # one polygon of a million corners (a star, concave: ear clipping would take hours)
    "obj-polygon-of-1M-corners": (
        "polygon.obj",
        lambda: ("v 0 0 0\nv 1 0.2 0\nv 1 1 0\nv 0.2 1 0\nf " + "1 2 3 4 " * 250_000 + "\n").encode(),
        "has a polygon of 1,000,000 corners",
    ),
    "vrml2-polygon-of-1M-corners": (
        "polygon.wrl",
        lambda: (
            "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0, 1 0.2 0, 1 1 0, 0.2 1 0 ] }"
            " coordIndex [ " + "0 1 2 3 " * 250_000 + "] } }"
        ).encode(),
        "has a polygon of 1,000,000 corners",
    ),
    "vrml2-groups-nested-100000": (
        "nested-groups.wrl",
        lambda: ("#VRML V2.0 utf8\n" + "Group { children [ " * LEVELS + "Shape { geometry Box { } }" + " ] }" * LEVELS).encode(),
        "nested deeper than",
    ),
    "vrml2-transforms-nested-100000": (
        "nested-transforms.wrl",
        lambda: ("#VRML V2.0 utf8\n" + "Transform { children " * LEVELS + "Shape { geometry Box { } }" + " }" * LEVELS).encode(),
        "nested deeper than",
    ),
    "vrml2-lists-nested-100000": (
        "nested-lists.wrl",
        lambda: ("#VRML V2.0 utf8\nGroup { children " + "[ " * LEVELS + "Shape { geometry Box { } }" + " ]" * LEVELS + " }").encode(),
        "unexpected '['",
    ),
    "vrml2-protos-nested-100000": (
        "nested-protos.wrl",
        lambda: ("#VRML V2.0 utf8\n" + "PROTO P [ ] { " * LEVELS + "Shape { geometry Box { } }" + " }" * LEVELS + " P { }").encode(),
        "nested deeper than",
    ),
    "vrml1-separators-nested-100000": (
        "nested-separators.wrl",
        lambda: ("#VRML V1.0 ascii\n" + "Separator { " * LEVELS + "Cube { }" + " }" * LEVELS).encode(),
        "nested deeper than",
    ),
    # one coordIndex of 12 million triangles, gzipped to some 200 kB: refused from its polygon
    # ends, counted before it is parsed (it took 7 GB before its refusal when it was parsed first)
    "gzip-vrml2-one-coordindex-12M": (
        "coordindex.wrl.gz",
        lambda: gzip.compress(b"#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0, 1 0 0,"
                              b" 0 1 0 ] } coordIndex [ " + b"0,1,2,-1," * 12_000_000 + b" ] } }\n", compresslevel=6,
                              mtime=0),
        "GiB of memory",
    ),
    # one STEP entity of 200,000 parameters: OpenCASCADE took 241 s over such a file
    "step-entity-of-200000-parameters": (
        "parameters.step",
        lambda: (b"ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION((''),'2;1');\nENDSEC;\nDATA;\n#1=CARTESIAN_POINT('',(0.,0.,0.));\n"
                 b"#2=EDGE_LOOP('',(" + b",".join([b"#1"] * 200_000) + b"));\nENDSEC;\nEND-ISO-10303-21;\n"),
        "of 200,001 parameters, more than the limit of 20,000",
    ),
    "gzip-vrml2-groups-nested-100000": (
        "nested-groups.wrz",
        lambda: gzip.compress(("#VRML V2.0 utf8\n" + "Group { children [ " * LEVELS).encode(), mtime=0),
        "nested deeper than",
    ),
}




def write_bombs(folder: Path) -> dict[str, Path]:
    """Every bomb written into ``folder``: name -> path."""
    paths = {}
    for name, (file_name, make, _) in BOMBS.items():
        paths[name] = folder / file_name
        paths[name].write_bytes(make())
    return paths


def run_bombs(folder: Path, memory: int, timeout: float, workers: int = 2) -> dict[str, tuple[Path, dict]]:
    """Write and run every bomb: name -> (path, result of fuzz.run_case)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import fuzz

    paths = write_bombs(folder)
    results = fuzz.replay([str(p) for p in paths.values()], workers, memory, timeout, signature=False)
    by_path = {job[1]: result for job, result in results}
    return {name: (paths[name], by_path[str(paths[name].resolve())]) for name in BOMBS}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--memory", type=float, default=2.0, help="worker memory limit, GiB")
    parser.add_argument("--timeout", type=float, default=120.0, help="wall seconds before a bomb counts as a hang")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="shapeidx-bombs-") as folder:
        results = run_bombs(Path(folder), int(args.memory * (1 << 30)), args.timeout)
        print(f"Command: `python scripts/bombs.py {' '.join(argv if argv is not None else sys.argv[1:])}`; "
              f"{platform.machine()}, {os.cpu_count()} cores; worker memory limit {args.memory:g} GiB.\n")
        print("| bomb | file size | refused as | CPU seconds | peak MB |")
        print("|---|---:|---|---:|---:|")
        ok = True
        for name, (path, result) in results.items():
            reason = result.get("error", "").split(": ", 1)[-1]
            ok &= result["outcome"] == "load_error" and BOMBS[name][2] in reason
            print(f"| {name} | {path.stat().st_size:,} | {result['outcome']}: {reason} | {result.get('cpu_seconds', float('nan')):.2f} "
                  f"| {result.get('peak_kb', 0) / 1024:.0f} |")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
