"""An independent reader agrees: Coin3D (Debian's python3-pivy, in the system Python).

For every file of vrml-wild that Coin reads (and a sample of the KiCad 6 library), Coin's
triangles and their total area are compared with ours, measured as ``shapeidx inspect``
does (the polygons as read, triangulated by ``triangulate_polygons``, before cleaning):

- files without primitives: the same triangle count and area within 1e-6 (relative);
- files with primitives (Box, Sphere, ... tessellated differently by each reader): total
  area within 3 %;
- text is left out on Coin's side: we ignore Text / AsciiText by design (not a solid).

Every known disagreement is listed in :data:`DISAGREEMENTS` with its reason, and checked:
it must still disagree (no stale entries), and where the reason is a different
triangulation or precision, redoing Coin's way on our polygons must give Coin's area.
"""

from __future__ import annotations

import json
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from shapeidx.errors import LoadError
from shapeidx.io import LoadLimits
from shapeidx.io.vrml import load_vrml
from shapeidx.signing.mesh import polygon_starts, triangle_areas, triangulate_polygons

SYSTEM_PYTHON = "/usr/bin/python3"


def coin_is_installed() -> bool:
    try:
        return (
            subprocess.run([SYSTEM_PYTHON, "-c", "import pivy.coin"], capture_output=True, timeout=60).returncode == 0
        )
    except (OSError, subprocess.TimeoutExpired):
        return False


pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not coin_is_installed(), reason="Coin3D not available (apt-get install python3-pivy)"),
]

# Runs in the system Python: reads file names from stdin, prints one JSON line per file.
COIN_SCRIPT = r"""
import json, math, os, sys
from pivy import coin

PRIMITIVES = ("Cube", "Sphere", "Cylinder", "Cone", "Box")
TEXT = ("Text", "AsciiText", "Text2", "Text3")
alive = []  # Coin nodes must outlive the traversal


def read(path, depth=0):
    source = coin.SoInput()
    if not source.openFile(path):
        return None
    root = coin.SoDB.readAll(source)
    if root is None:
        return None
    root.ref()
    alive.append(root)
    load_www_inlines(root, os.path.dirname(path), depth)
    return root


def load_www_inlines(root, folder, depth):
    # pivy cannot register Coin's WWWInline fetch callback: give the nodes their files here
    search = coin.SoSearchAction()
    search.setType(coin.SoWWWInline.getClassTypeId())
    search.setInterest(coin.SoSearchAction.ALL)
    search.setSearchingAll(True)
    search.apply(root)
    paths = search.getPaths()
    for node in [paths[i].getTail() for i in range(paths.getLength())]:
        node.ref()
        alive.append(node)
        name = node.name.getValue()
        name = name.getString() if hasattr(name, "getString") else str(name)
        if depth < 8 and "://" not in name:
            child = read(os.path.join(folder, name), depth + 1)
            if child is not None:
                node.setChildData(child)


def measure(path):
    root = read(path)
    if root is None:
        return {"path": path, "read": False}
    totals = {"triangles": 0, "area": 0.0, "primitive_triangles": 0, "primitive_area": 0.0, "text_triangles": 0}

    def triangle(_, action, *corners):
        matrix = action.getModelMatrix()
        p = [matrix.multVecMatrix(c.getPoint()).getValue() for c in corners]
        u = [p[1][i] - p[0][i] for i in range(3)]
        v = [p[2][i] - p[0][i] for i in range(3)]
        cross = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
        area = 0.5 * math.sqrt(sum(c * c for c in cross))
        kind = action.getCurPathTail().getTypeId().getName().getString().replace("VRML", "")
        if kind in TEXT:
            totals["text_triangles"] += 1
        elif kind in PRIMITIVES:
            totals["primitive_triangles"] += 1
            totals["primitive_area"] += area
        else:
            totals["triangles"] += 1
            totals["area"] += area

    action = coin.SoCallbackAction()
    action.addTriangleCallback(coin.SoShape.getClassTypeId(), triangle, None)
    action.apply(root)
    return {"path": path, "read": True, **totals}


coin.SoDB.init()
for line in sys.stdin:
    print(json.dumps(measure(line.strip())), flush=True)
"""

# Why Coin and we disagree, per file (relative to the data folder). ``check``:
#   "fan"     Coin fans every polygon from its first corner (it trusts "convex TRUE", the
#             default, and splits quadrilaterals on the 0-2 diagonal); we triangulate
#             concave polygons correctly and split quads by the rule of Ip et al.
#             Checked: fanning our polygons gives Coin's triangles and area.
#   "float32" Coin keeps coordinates in single precision; the file's faces are tiny next
#             to their coordinates. Checked: our triangles over float32-rounded vertices
#             give Coin's area.
#   None      a difference in what is drawn; the entry only has to stay a disagreement.
DISAGREEMENTS = {
    "vrml-wild/kicad-2017/wings3d/Connectors_Hirose.3dshapes/Hirose_DF13-07P-125DS_07x1.25mm_Angled.wrl": (
        "fan",
        "concave polygons marked convex",
    ),
    "vrml-wild/kicad-2017/wings3d/Connectors_Molex.3dshapes/Molex_Panelmate_09x1.25mm_Angled.wrl": (
        "fan",
        "concave polygons marked convex",
    ),
    "vrml-wild/kicad-2017/wings3d/Connectors_Molex.3dshapes/Molex_PicoBlade_53047-0810_08x1.25mm_Straight.wrl": (
        "fan",
        "concave polygons marked convex",
    ),
    "vrml-wild/kicad-2017/wings3d/Displays_7-Segment.3dshapes/MAN3640A.wrl": ("fan", "concave polygons marked convex"),
    "vrml-wild/kicad-2017/wings3d/Potentiometers.3dshapes/Potentiometer_Bourns_3006Y_Angular_ScrewFront.wrl": (
        "fan",
        "concave polygons marked convex",
    ),
    "vrml-wild/kicad-2017/wings3d/Sockets_DIP.3dshapes/DIP-18__300_ELL.wrl": ("fan", "concave polygons marked convex"),
    "vrml-wild/kicad-2017/wings3d/Sockets_DIP.3dshapes/DIP-20__300.wrl": ("fan", "concave polygons marked convex"),
    "vrml-wild/castle-engine-demo-models/x3d/regular_labirynth_chinchilla.wrl.gz": (
        "fan",
        "non-planar quadrilaterals split on the other diagonal",
    ),
    "vrml-wild/castle-engine-demo-models/navigation/running_path.wrl": (
        "float32",
        "coordinates beyond single precision",
    ),
    "vrml-wild/castle-engine-demo-models/vrml_2/warnings/normal_index_wrong.wrl": (
        "float32",
        "coordinates beyond single precision",
    ),
    "vrml-wild/castle-engine-demo-models/vrml_2/extrusion_concave_cap.wrl": (
        None,
        "Extrusion is not supported by us (skipped with a warning)",
    ),
    "vrml-wild/castle-engine-demo-models/bump_mapping/room_for_parallax_final.wrl": (
        None,
        "the inlined room_for_parallax.wrl uses engine extensions Coin refuses",
    ),
    "vrml-wild/castle-engine-demo-models/vrml_1/kings_head_transparent.wrl": (
        None,
        "the inlined kings_head.wrl is refused by Coin",
    ),
    "vrml-wild/castle-engine-demo-models/vrml_2/kings_head_transparent.wrl": (
        None,
        "the inlined kings_head.wrl is refused by Coin",
    ),
    "vrml-wild/castle-engine-demo-models/vrml_1/inline_test.wrl": (
        None,
        "the inlined kings_head.wrl is refused by Coin",
    ),
    "vrml-wild/castle-engine-demo-models/prototypes/proto_other.wrl": (
        None,
        "Coin draws every node of a PROTO body; VRML97 4.8.3 draws only the first",
    ),
    "vrml-wild/castle-engine-demo-models/prototypes/warnings/proto_invalid_nest.wrl": (
        None,
        "a PROTO defined inside another's body is not visible outside it (VRML97 4.8.3); Coin expands it anyway",
    ),
    "vrml-wild/castle-engine-demo-models/vrml_2/warnings/not_allowed_children.wrl": (
        None,
        "Coin draws a Box put in Appearance.material; we take geometry only from Shape.geometry",
    ),
    "vrml-wild/coin3d-models/models/io/incorrect/bug055-3.wrl": (
        None,
        "a bare number before the first node: Coin reports the error but returns an empty scene; we refuse the file",
    ),
}
EXACT = 1e-6
PRIMITIVE_TOLERANCE = 0.03


def run_coin(paths: list[Path]) -> dict[str, dict]:
    """Coin's measures per file, two processes in parallel; a file that crashes Coin
    (it segfaults on a few) is recorded as not read and the run goes on after it."""
    halves = [paths[0::2], paths[1::2]]
    with ThreadPoolExecutor(2) as pool:
        results = {}
        for part in pool.map(_run_coin_chain, halves):
            results.update(part)
    return results


def _run_coin_chain(paths: list[Path]) -> dict[str, dict]:
    results: dict[str, dict] = {}
    todo = [str(p) for p in paths]
    while todo:
        try:
            done = subprocess.run(
                [SYSTEM_PYTHON, "-c", COIN_SCRIPT],
                input="\n".join(todo) + "\n",
                capture_output=True,
                text=True,
                timeout=900,
            ).stdout
        except subprocess.TimeoutExpired as stuck:
            done = stuck.stdout.decode() if isinstance(stuck.stdout, bytes) else (stuck.stdout or "")
        lines = [json.loads(line) for line in done.splitlines() if line.startswith("{")]
        for entry in lines:
            results[entry["path"]] = entry
        todo = todo[len(lines) :]
        if todo:  # Coin died (or hung) on todo[0]
            results[todo[0]] = {"path": todo[0], "read": False, "crashed": True}
            todo = todo[1:]
    return results


def our_measure(path: Path, folder: Path) -> dict:
    try:
        mesh = load_vrml(path, LoadLimits(root=folder))
    except LoadError as error:
        return {"read": False, "error": str(error)}
    triangles = triangulate_polygons(mesh.vertices, mesh.face_sizes, mesh.face_indices)
    area = float(triangle_areas(mesh.vertices, triangles).sum()) if len(triangles) else 0.0
    return {"read": True, "triangles": len(triangles), "area": area, "mesh": mesh}


def fanned_area(mesh) -> float:
    """Area when every polygon is fanned from its first corner, as Coin does."""
    starts = polygon_starts(mesh.face_sizes)
    first = np.repeat(mesh.face_indices[starts], mesh.face_sizes - 2)
    offset = np.concatenate([np.arange(1, s - 1) for s in mesh.face_sizes]) + np.repeat(starts, mesh.face_sizes - 2)
    fan = np.stack([first, mesh.face_indices[offset], mesh.face_indices[offset + 1]], axis=1)
    return float(triangle_areas(mesh.vertices, fan).sum())


def float32_area(mesh) -> float:
    vertices = mesh.vertices.astype(np.float32).astype(np.float64)
    return float(
        triangle_areas(vertices, triangulate_polygons(mesh.vertices, mesh.face_sizes, mesh.face_indices)).sum()
    )


def close(a: float, b: float, tolerance: float) -> bool:
    return abs(a - b) <= tolerance * max(abs(a), abs(b), 1e-300)


def judge(coin: dict, ours: dict) -> str | None:
    """None when the readers agree, else what differs."""
    if not ours["read"]:
        return f"we refuse it: {ours['error']}"
    coin_area = coin["area"] + coin["primitive_area"]
    if coin["primitive_triangles"]:
        if close(ours["area"], coin_area, PRIMITIVE_TOLERANCE):
            return None
        return f"area {ours['area']:.6g} vs Coin {coin_area:.6g} (with primitives)"
    if ours["triangles"] != coin["triangles"]:
        return f"{ours['triangles']} triangles vs Coin {coin['triangles']}"
    if not close(ours["area"], coin_area, EXACT):
        return f"area {ours['area']:.9g} vs Coin {coin_area:.9g}"
    return None


@pytest.fixture(scope="module")
def comparison(data_dir):
    wild = sorted(p for p in (data_dir / "vrml-wild").rglob("*") if p.is_file() and p.name != "SOURCES.tsv")
    kicad = sorted((data_dir / "kicad6").rglob("*.wrl"))[::20]  # a sample of one-Shape-per-face parts
    coin = run_coin(wild + kicad)
    rows = {}
    for path in wild + kicad:
        folder = data_dir / ("vrml-wild" if path in wild else "kicad6")
        rows[str(path.relative_to(data_dir))] = (coin[str(path)], our_measure(path, folder))
    return rows


def test_coin_reads_most_of_the_wild_files(comparison):
    read = [name for name, (coin, _) in comparison.items() if coin["read"]]
    assert len(read) >= 450, f"Coin read only {len(read)} files: is pivy broken?"


def test_we_agree_with_coin_on_every_file_it_reads(comparison):
    unexplained = {}
    for name, (coin, ours) in comparison.items():
        if not coin["read"] or name in DISAGREEMENTS:
            continue
        difference = judge(coin, ours)
        if difference:
            unexplained[name] = difference
    agreeing = sum(1 for name, (coin, ours) in comparison.items() if coin["read"] and not judge(coin, ours))
    assert not unexplained, f"{len(unexplained)} unexplained disagreements ({agreeing} files agree): {unexplained}"


@pytest.mark.parametrize("name", sorted(DISAGREEMENTS))
def test_listed_disagreements_are_real_and_explained(comparison, name):
    check, reason = DISAGREEMENTS[name]
    coin, ours = comparison[name]
    assert coin["read"], f"Coin no longer reads {name}: drop it from the list"
    assert judge(coin, ours), f"{name} now agrees with Coin: drop it from the list ({reason})"
    if check == "fan":
        assert ours["triangles"] == coin["triangles"]
        assert close(fanned_area(ours["mesh"]), coin["area"], EXACT), reason
    elif check == "float32":
        assert ours["triangles"] == coin["triangles"]
        assert close(float32_area(ours["mesh"]), coin["area"], EXACT), reason
