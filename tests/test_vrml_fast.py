"""The compiled VRML fast path (shapeidx/io/vrml/_scan.c) gives what the Python reader gives.

Every VRML file of the shared folders, and generated flat files that exercise what the
fast path reads (numbers of every shape, DEF/USE, ccw, shared coordinates), are loaded
both ways: the vertices must be the same bytes, the polygons, format and warnings the
same, or the LoadError message the same. Files the fast path does not read itself must
come out the same too (they are the Python reader's either way).
"""

from __future__ import annotations

import random
import subprocess
import sys

import numpy as np
import pytest

from shapeidx.errors import LoadError
from shapeidx.io import load
from shapeidx.io.base import LoadLimits
from shapeidx.io.vrml import fast, scene
from shapeidx.io.vrml.reader import VrmlLoad

from conftest import DATA, REPO

FOLDERS = ("kicad6", "vrml-wild", "xexp-dev")
SUFFIXES = (".wrl", ".wrz", ".vrml", ".gz")

needs_scan = pytest.mark.skipif(fast._scan is None, reason="the _scan extension is not built")


def test_the_fast_path_is_built():
    """A checkout installed as the README says has it: a silent fallback would hide a slow build."""
    assert fast._scan is not None


def _shared_files() -> list[str]:
    files = []
    for folder in FOLDERS:
        root = DATA / folder
        if root.is_dir():
            files += sorted(
                str(p.relative_to(DATA)) for p in root.rglob("*") if p.is_file() and p.name.lower().endswith(SUFFIXES)
            )
    return files


def outcome(path, fast_on: bool, limits: LoadLimits | None = None):
    """What loading gives, as comparable values: the arrays' bytes, dtypes, shapes and
    flags, format and warnings; or the error's type and message."""
    saved = fast.available
    fast.available = fast_on and saved
    try:
        mesh = load(path) if limits is None else load(path, limits=limits)
    except LoadError as exc:
        return ("error", type(exc).__name__, str(exc))
    finally:
        fast.available = saved
    arrays = [
        (a.dtype.str, a.shape, a.flags.c_contiguous, a.flags.writeable, a.tobytes())
        for a in (mesh.vertices, mesh.face_sizes, mesh.face_indices)
    ]
    return ("mesh", arrays, mesh.format, list(mesh.warnings))


def read_by_fast_path(path, data: bytes | None = None) -> bool:
    data = path.read_bytes() if data is None else data
    load_ = VrmlLoad(path, LoadLimits(), data)
    return fast.load_flat(path, data, load_.limits, load_.check_expansion) is not None


def test_the_shared_data_is_there(data_dir):
    assert any((data_dir / folder).is_dir() for folder in FOLDERS)


@needs_scan
@pytest.mark.slow
@pytest.mark.parametrize("name", _shared_files())
def test_shared_file_same_both_ways(name):
    path = DATA / name
    assert outcome(path, True) == outcome(path, False)


@needs_scan
def test_kicad_parts_take_the_fast_path(data_dir):
    """Not a vacuous comparison: the fast path reads (nearly) every KiCad part itself."""
    files = sorted((data_dir / "kicad6").rglob("*.wrl"))[:60]
    assert files
    assert sum(read_by_fast_path(p) for p in files) >= 0.9 * len(files)


# -- generated flat files ---------------------------------------------------------------------


def random_number(rng: random.Random) -> str:
    """A decimal number as exporters (and enemies) write them."""
    digits = "".join(rng.choice("0123456789") for _ in range(rng.choice((1, 3, 6, 15, 16, 17, 20, 30))))
    point = rng.randint(0, len(digits))
    text = rng.choice(("", "-", "+")) + digits[:point] + rng.choice((".", "")) + digits[point:]
    if rng.random() < 0.4:
        text += rng.choice("eE") + rng.choice(("", "-", "+")) + str(rng.choice((rng.randint(0, 25), rng.randint(0, 330))))
    return text


def flat_file(rng: random.Random) -> str:
    """A flat VRML 2.0 file of a few Shapes, with what the fast path must read exactly."""
    parts = ["#VRML V2.0 utf8\n# a comment { [ ]\n"]
    defined_coords: list[str] = []
    defined_sets: list[str] = []
    for k in range(rng.randint(0, 6)):
        roll = rng.random()
        if roll < 0.1 and defined_sets:
            parts.append(f"Shape {{ geometry USE {rng.choice(defined_sets)} }}\n")
            continue
        if roll < 0.15:
            parts.append(rng.choice(("WorldInfo { }\n", "NULL\n", "Shape { }\n", "Shape { geometry NULL }\n")))
            continue
        count = rng.randint(1, 12)
        if defined_coords and rng.random() < 0.3:
            coord_name = rng.choice(defined_coords)
            coord = f"USE {coord_name}"
            count = int(coord_name.split("_")[1])
        else:
            numbers = [random_number(rng) if rng.random() < 0.3 else f"{rng.uniform(-50, 50):.{rng.randint(0, 6)}f}" for _ in range(3 * count)]
            separator = rng.choice((" ", ",", ", ", "\n\t"))
            coord = f"Coordinate {{ point [ {separator.join(numbers)} ] }}"
            if rng.random() < 0.4:
                name = f"C_{count}_{k}"
                defined_coords.append(name)
                coord = f"DEF {name} {coord}"
        polygons = []
        for _ in range(rng.randint(0, 5)):
            polygons.append(" ".join(str(rng.randrange(count)) for _ in range(rng.randint(3, 6))) + " -1")
        index = " ".join(polygons)
        if rng.random() < 0.3:
            index = index.removesuffix(" -1")
        fields = [f"coordIndex [ {index} ]" if index or rng.random() < 0.5 else "", f"coord {coord}"]
        if rng.random() < 0.3:
            fields.append(rng.choice(("ccw FALSE", "ccw TRUE", "solid FALSE", "creaseAngle 0.5", "convex TRUE")))
        rng.shuffle(fields)
        face_set = "IndexedFaceSet { " + " # note\n ".join(fields) + " }"
        if rng.random() < 0.3:
            name = f"F{k}"
            defined_sets.append(name)
            face_set = f"DEF {name} {face_set}"
        appearance = "appearance Appearance { material DEF M Material { diffuseColor 0.8 0.8 0.8 } }"
        parts.append(f"Shape {{ {appearance} geometry {face_set} }}\n")
    return "".join(parts)


@needs_scan
def test_generated_flat_files_same_both_ways(tmp_path):
    rng = random.Random(5)
    fast_count = 0
    for k in range(400):
        path = tmp_path / f"flat{k}.wrl"
        path.write_text(flat_file(rng))
        assert outcome(path, True) == outcome(path, False), path.read_text()
        fast_count += read_by_fast_path(path)
    assert fast_count > 200  # most of them are read by the fast path itself


NUMBER_CASES = [
    "0", "-0", "+0", "-0.0", "0.", ".5", "-.5", "+.5e3", "1e5", "1E-5", "1.e2", "007", "0.30000000000000004",
    "9007199254740993", "123456789012345678901234567890", "1e22", "1e23", "7e-23", "4.9e-324", "2.2250738585072014e-308",
    "1e308", "1.7976931348623157e308", "1e309", "1e-400", "0x1F", "1-2", "1e", "1e+", "nan", "inf", "1_0", "2.5.5",
]  # fmt: skip


@needs_scan
@pytest.mark.parametrize("number", NUMBER_CASES)
@pytest.mark.parametrize("where", ["array", "bare"])
def test_number_texts_same_both_ways(tmp_path, number, where):
    point = f"point [ {number} 1 2 ]" if where == "array" else f"point {number} 1 2"
    path = tmp_path / "n.wrl"
    path.write_text(f"#VRML V2.0 utf8\nShape {{ geometry IndexedFaceSet {{ coordIndex [0 0 0] coord Coordinate {{ {point} }} }} }}\n")
    assert outcome(path, True) == outcome(path, False)


ODD_FILES = {
    "comment in array": "point [ 0 0 0 # ]\n 1 0 0 0 1 0 ]",
    "ccw as number": "point [ 0 0 0 1 0 0 0 1 0 ] } ccw 0",
    "fraction": "point [ 0 0 0 1 0 0 0 1 0 ] } coordIndex [ 0 1 2.5 ]",
    "out of range": "point [ 0 0 0 1 0 0 0 1 0 ] } coordIndex [ 0 1 3 ]",
    "short polygon": "point [ 0 0 0 1 0 0 0 1 0 ] } coordIndex [ 0 1 -1 0 1 2 ]",
    "not triples": "point [ 0 0 0 1 0 0 0 1 ] }",
    "empty list": "point [ ] }",
    "string": 'point [ 0 0 0 1 0 0 0 1 0 ] } coordIndex [ 0 1 2 ] } } WorldInfo { info "x" } Shape { geometry Box {',
    "unterminated": "point [ 0 0 0 1 0 0 0 1 0",
    "unclosed brace": "point [ 0 0 0 1 0 0 0 1 0 ]",
    "USE undefined": "point [ 0 0 0 1 0 0 0 1 0 ] } coordIndex [ 0 1 2 ] } } Shape { geometry USE NOPE",
    "NUL byte": "point [ 0 0 0 1 0 0 0 1 0 ] }\x00",
    "utf-8 name": "point [ 0 0 0 1 0 0 0 1 0 ] } coordIndex [ 0 1 2 ] } } DEF nämé Shape {",
}


@needs_scan
@pytest.mark.parametrize("case", sorted(ODD_FILES))
def test_odd_files_same_both_ways(tmp_path, case):
    body = ODD_FILES[case]
    text = f"#VRML V2.0 utf8\nShape {{ geometry IndexedFaceSet {{ coordIndex [ 0 1 2 ] coord Coordinate {{ {body} }} }} }}\n"
    path = tmp_path / "odd.wrl"
    path.write_bytes(text.encode())
    assert outcome(path, True) == outcome(path, False)


@needs_scan
def test_limits_are_the_python_readers(tmp_path):
    """A file over a limit is refused with the Python reader's message."""
    path = tmp_path / "big.wrl"
    shape = "DEF S Shape { geometry IndexedFaceSet { coordIndex [ 0 1 2 3 ] coord Coordinate { point [ 0 0 0 1 0 0 1 1 0 0 1 0 ] } } }\n"
    path.write_text("#VRML V2.0 utf8\n" + shape + "USE S\n" * 30)
    for limits in (LoadLimits(max_triangles=10), LoadLimits(max_triangles=3), LoadLimits(max_bytes=10_000)):
        assert outcome(path, True, limits=limits) == outcome(path, False, limits=limits)
        assert outcome(path, True, limits=limits)[0] == "error"
    assert read_by_fast_path(path)


@needs_scan
def test_known_types_agree_with_the_scene():
    assert set(fast._scan.KNOWN_OTHER) == scene.V2_NO_GEOMETRY


@needs_scan
def test_hostile_repetition_is_not_quadratic(tmp_path):
    """Many USEs of one big face set, many DEF names: linear time (a second, not minutes)."""
    points = " ".join(f"{i} 0 {i % 7}" for i in range(3000))
    index = " ".join(f"0 {i} {i + 1} -1" for i in range(1, 2999))
    text = ["#VRML V2.0 utf8\n", f"DEF S Shape {{ geometry IndexedFaceSet {{ coordIndex [ {index} ] coord Coordinate {{ point [ {points} ] }} }} }}\n"]
    text += [f"DEF N{k} WorldInfo {{ }}\n" for k in range(100_000)]
    text += ["USE S\n"] * 200_000
    data = "".join(text).encode()
    import time

    started = time.process_time()
    found = fast._scan.scan(data, 50_000_000, scene.MAX_NODE_VISITS)
    assert time.process_time() - started < 5
    assert found is None  # more triangles than the limit: left to the Python reader's message


def test_python_path_without_the_extension(tmp_path):
    """With _scan not importable, VRML files still load (the Python reader)."""
    path = tmp_path / "t.wrl"
    path.write_text("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coordIndex [ 0 1 2 ] coord Coordinate { point [ 0 0 0 1 0 0 0 1 0 ] } } }\n")
    code = (
        "import sys; sys.modules['shapeidx.io.vrml._scan'] = None\n"
        "from shapeidx.io.vrml import fast; assert fast._scan is None and not fast.available\n"
        "from shapeidx.io import load; m = load(sys.argv[1]); print(m.face_indices.tolist(), m.vertices.shape)"
    )
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, cwd=REPO, check=True)
    assert done.stdout.strip() == "[0, 1, 2] (3, 3)"
    mesh = load(path)
    np.testing.assert_array_equal(mesh.face_indices, [0, 1, 2])
