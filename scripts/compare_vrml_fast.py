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
    python scripts/compare_vrml_fast.py --mutants 5000 /work/shared/data/kicad6   # differential fuzzing

``--mutants N`` compares N mutated copies of the files instead (written to a temporary
folder): bytes that mean something to the reader set, chunks deleted or repeated, words
and numbers that the fast path must refuse or read exactly inserted.
"""

from __future__ import annotations

import argparse
import random
import re
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
    from shapeidx.io.vrml.reader import VrmlLoad

    took_fast = False
    try:
        data = read_bytes(path)[0]
        load = VrmlLoad(path, LoadLimits(), data)
        took_fast = fast.load_flat(path, data, load.limits, load.check_expansion) is not None
    except Exception:
        pass
    return outcome(path, True) == outcome(path, False), took_fast


# What mutate() inserts: syntax the fast path refuses or must read exactly like Python
INSERTS = [
    b"#", b"# ] }\n", b"[", b"]", b"{", b"}", b",", b"-1", b"-1 -1", b"1e400", b"1e-400", b"4.9e-324", b"0x1F",
    b"1-2", b".5", b"-.5e+3", b"1.", b"+0", b"-0", b"nan", b"inf", b"1_0", b"12345678901234567890",
    b"0.30000000000000004", b"7e22", b"9007199254740993", b"\"s\"", b"DEF A", b"USE A", b"USE PIN-01",
    b"DEF PIN-01 Material {}", b"NULL", b"TRUE", b"FALSE", b"ccw FALSE", b"ccw 0", b"ccw TRUE", b"solid FALSE",
    b"Transform { children [", b"Group {", b"PROTO", b"IS", b"ROUTE", b"coord", b"coordIndex", b"point",
    b"geometry", b"geometry NULL", b"geometry Box { }", b"Coordinate { point [ 0 0 0 ] }", b"\x00", b"\xff",
    b"\r", b"\t", b"(", b"|", b"field", b"Shape {", b"Shape { }", b"WorldInfo { }", b"Foo { }", b"2.5", b"3",
]


def random_number(rng: random.Random) -> bytes:
    """A number as an exporter (or an enemy) may write it: long mantissas, exponents."""
    digits = "".join(rng.choice("0123456789") for _ in range(rng.randint(1, 25)))
    point = rng.randint(0, len(digits))
    text = rng.choice(("", "-", "+")) + digits[:point] + rng.choice((".", ".", "")) + digits[point:]
    if rng.random() < 0.4:
        text += rng.choice("eE") + rng.choice(("", "-", "+")) + str(rng.choice((rng.randint(0, 30), rng.randint(0, 400))))
    return text.encode()


_NUMBER = re.compile(rb"-?\d+\.?\d*")
# edits that keep a file well formed: the fast path reads them, and must read them right
_SAFE_EDITS = [
    (b"{ creaseAngle", b"{ ccw FALSE creaseAngle"), (b"{ creaseAngle", b"{ ccw TRUE solid FALSE creaseAngle"),
    (b"coord Coordinate", b"coord DEF C Coordinate"), (b"point [", b"point [ 0 0 0"), (b"[0,", b"[1,"),
    (b",-1]", b"]"), (b",-1,", b",-1,-1,"), (b"Shape {", b"DEF S Shape {"), (b"Shape {", b"NULL Shape {"),
    (b"coord Coordinate", b"coord USE C coord Coordinate"), (b"coordIndex [", b"coordIndex [ 0 1 2 -1 "),
]


def mutate(data: bytes, rng: random.Random, gentle: bool = False) -> bytes:
    """One to three random mutations of a VRML file; ``gentle``: only numbers replaced
    and edits that keep the file well formed."""
    data = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        at = rng.randrange(len(data) + 1)
        choice = rng.random() * (0.45 if gentle else 1.0)
        if choice < 0.3:
            numbers = list(_NUMBER.finditer(data))
            if gentle:  # only coordinates: a random number in coordIndex is refused
                numbers = [m for span in re.finditer(rb"point\s*\[[^\]]*\]", data)
                           for m in _NUMBER.finditer(data, span.start() + 5, span.end())]
            chosen = rng.sample(numbers, min(len(numbers), rng.randint(1, 20)))
            for match in sorted(chosen, key=lambda m: -m.start()):  # from the end: spans stay valid
                data[match.start() : match.end()] = random_number(rng)
        elif choice < 0.45:
            old, new = rng.choice(_SAFE_EDITS)
            found = [m.start() for m in re.finditer(re.escape(old), data)]
            if found:
                start = rng.choice(found)
                data[start : start + len(old)] = new
        elif choice < 0.6:
            data[at:at] = rng.choice(INSERTS) + rng.choice((b" ", b"", b"\n"))
        elif choice < 0.6 and data:
            data[at : at + 1] = bytes([rng.choice(b"{}[]-.0123456789#,eE \n")])
        elif choice < 0.75:
            del data[at : at + rng.randint(1, 200)]
        elif choice < 0.85:
            chunk = data[at : at + rng.randint(1, 400)]
            data[at:at] = chunk * rng.randint(1, 4)
        else:
            del data[at:]
    return bytes(data)


def mutants(files: list[Path], count: int, seed: int, folder: Path, gentle: bool = False) -> list[Path]:
    rng = random.Random(seed)
    seeds = [p for p in files if p.suffix.lower() == ".wrl" and p.stat().st_size < 200_000] or files
    made = []
    for k in range(count):
        source = rng.choice(seeds)
        path = folder / f"mutant{k:05d}.wrl"
        path.write_bytes(mutate(source.read_bytes(), rng, gentle))
        made.append(path)
    return made


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--sample", type=int, default=0, help="this many random files (0: all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mutants", type=int, default=0, help="compare this many mutated files instead")
    parser.add_argument("--gentle", action="store_true", help="mutations that keep files well formed")
    args = parser.parse_args()
    from shapeidx.io.vrml import fast

    if not fast.available:
        print("the compiled path is not available (_scan not built?)", file=sys.stderr)
        return 2
    files = vrml_files(args.folders)
    if args.sample:
        files = random.Random(args.seed).sample(files, min(args.sample, len(files)))
    if args.mutants:
        import tempfile

        folder = Path(tempfile.mkdtemp(prefix="vrml-mutants-"))
        files = mutants(files, args.mutants, args.seed, folder, args.gentle)
        print(f"mutants in {folder}")
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
