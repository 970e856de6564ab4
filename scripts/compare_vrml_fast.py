#!/usr/bin/env python
"""The compiled VRML path against the Python one: same mesh bit for bit, or the same error.

For each VRML file under the folders given (or a random sample of them), loads it with
:func:`shapeidx.io.load` twice, with the fast path of ``shapeidx.io.vrml.fast`` on and
off, and compares vertices (bytes), face sizes, face indices, format, warnings, array
flags and dtypes, or the LoadError messages. Prints one line per difference and a
summary (how many files the fast path read itself).

Usage::

    python scripts/compare_vrml_fast.py /work/shared/data/kicad6 /work/shared/data/vrml-wild
    python scripts/compare_vrml_fast.py --sample 500 --seed 3 /work/debian/root/usr/share/kicad/3dmodels
"""

from __future__ import annotations

import argparse
import random
import sys
from pathlib import Path

VRML_SUFFIXES = (".wrl", ".wrz", ".vrml", ".gz")


def vrml_files(folders: list[Path]) -> list[Path]:
    return sorted(p for folder in folders for p in folder.rglob("*") if p.is_file() and p.name.lower().endswith(VRML_SUFFIXES))


def outcome(path: Path, fast_on: bool):
    """What loading gives: ("mesh", arrays and fields) or ("error", message)."""
    from shapeidx.errors import LoadError
    from shapeidx.io import load
    from shapeidx.io.vrml import fast

    saved = fast.available
    fast.available = fast_on and saved
    try:
        mesh = load(path)
    except LoadError as exc:
        return ("error", type(exc).__name__, str(exc))
    finally:
        fast.available = saved
    arrays = []
    for array in (mesh.vertices, mesh.face_sizes, mesh.face_indices):
        flags = (array.flags.c_contiguous, array.flags.writeable, array.flags.aligned)
        arrays.append((array.dtype.str, array.shape, flags, array.tobytes()))
    return ("mesh", arrays, mesh.format, list(mesh.warnings))


def compare(path: Path) -> tuple[bool, bool]:
    """(same, read by the fast path)"""
    from shapeidx.io.base import LoadLimits, read_bytes
    from shapeidx.io.vrml import fast
    from shapeidx.io.vrml.reader import _VrmlLoad

    took_fast = False
    try:
        data = read_bytes(path)[0]
        load = _VrmlLoad(path, LoadLimits(), data)
        took_fast = fast.load_flat(path, data, load.limits, load.check_expansion) is not None
    except Exception:
        pass
    return outcome(path, True) == outcome(path, False), took_fast


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--sample", type=int, default=0, help="this many random files (0: all)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    from shapeidx.io.vrml import fast

    if not fast.available:
        print("the compiled path is not available (_scan not built?)", file=sys.stderr)
        return 2
    files = vrml_files(args.folders)
    if args.sample:
        files = random.Random(args.seed).sample(files, min(args.sample, len(files)))
    different = fast_count = 0
    for path in files:
        same, took_fast = compare(path)
        fast_count += took_fast
        if not same:
            different += 1
            print(f"DIFFERENT {path}")
    print(f"{len(files)} files: {len(files) - different} identical, {different} different; "
          f"{fast_count} read by the compiled path, {len(files) - fast_count} by Python")
    return 1 if different else 0


if __name__ == "__main__":
    sys.exit(main())
