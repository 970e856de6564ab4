#!/usr/bin/env python3
"""shapeidx beside the classic peer descriptors, on shapeidx's own questions; writes the peers table.

    pip install -e '.[peers]'                      # light-field-distance: the LFD's C code
    apt-get install xvfb freeglut3-dev libglu1-mesa-dev libosmesa6-dev
    python scripts/peers.py --build-lfd            # builds it in ~/.cache/shapeidx-peers/lfd
    python scripts/peers.py --work /tmp/peers-work [--questions kinds,step,xexp] [--no-lfd]

**LFD**, Chen, Tian, Shen and Ouhyoung's Light Field Descriptor (Eurographics 2003), the best
hand-made descriptor of the Princeton Shape Benchmark, runs through **its own code**: the
light-field-distance package (PyPI) ships Chen's C sources; ``3DAlignment`` renders each part's
silhouettes from the 20 vertices of a dodecahedron (10 light fields of 10 cameras, on a virtual
screen: Xvfb) and describes each by 35 Zernike moments, 10 Fourier coefficients, circularity and
eccentricity, quantised to bytes. Its distance (``Distance``: the least, over both parts' light
fields and the 60 rotations of the cameras, of the summed L1 of the camera pairs) is written
again in numpy (``lfd_to_many``) to rank a whole collection, and checked against the program
(tests/test_peers.py: equal on real parts). One difference, on purpose: the package's
``Distance`` never reads its second part's eccentricity (a part is then not at 0 from itself);
the ranking here uses both, as Chen's method does. LFD renders, it does not sample: its twin
questions have no query seed.

**SHD**, Kazhdan, Funkhouser and Rusinkiewicz's rotation-invariant spherical-harmonic
descriptor (SGP 2003), is **written again from the paper** in numpy/scipy (``shd_descriptor``):
ShapeSPH is on neither PyPI nor Debian, so its own code is not run. The steps:

1. the part's clean solid (``shapeidx.signing.pipeline.solid_of_file``, the surface shapeidx samples);
2. ``SHD_POINTS`` points on its surface (``shapeidx.signing.sampling.sample_surface``, seeded), put in a
   64^3 grid after centring on their centroid and scaling so that twice their mean distance from it
   is the grid's half-width (points beyond are dropped, as the paper clips); the occupied voxels,
   smoothed by a Gaussian of one voxel (the paper rasterises the surface and blurs it);
3. 32 concentric spheres (radii 1 .. 32 voxels), each sampled on a 2B x 2B (theta, phi) grid, B = 16,
   by trilinear interpolation;
4. each sphere's spherical harmonic transform up to band 16 (quadrature with sin(theta) weights);
   the descriptor is the norm of each band per sphere (32 x 17 float32), compared by L2.

The surface points are drawn with a seed, so this SHD *samples*: the twin questions draw the
queries' points with another seed than the gallery's (``QUERY_SEED``).

shapeidx's columns are computed here at run time from stores built with the package (the paper's
Weighted, which is also ``shapeidx query``'s default metric, and, per question, the best of all
metrics on that question), through the same scoring code as docs/results.md
(``shapeidx.evaluation``, ``scripts/twin_study.twin_ranks``), so one command regenerates the table
after any change to shapeidx's signatures. Nothing in ``shapeidx`` imports this.
"""

from __future__ import annotations

import argparse
import datetime
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

from _common import DATA, REPO, machine, quiet_build

GRID = 64
SPHERES = 32
BANDS = 16
SHD_POINTS = 20000
GALLERY_SEED = 2003
QUERY_SEED = 7
LIBRARY_SIZE = 6227  # parts in Debian's KiCad 6 library: the query-time figure
BEGIN = "<!-- peers table: written by scripts/peers.py; do not edit by hand -->"
END = "<!-- end of the peers table -->"


# ---------------------------------------------------------------- the spherical-harmonic descriptor
_BASIS = {}


def _basis():
    """Quadrature points of one sphere (unit vectors) and the (points, coefficients) matrix that
    turns sphere values into SH coefficients, and each coefficient's band."""
    if not _BASIS:
        from scipy.special import sph_harm_y

        n = 2 * BANDS
        theta = (np.arange(n) + 0.5) * np.pi / n  # polar
        phi = np.arange(n) * 2 * np.pi / n  # azimuth
        t, p = np.meshgrid(theta, phi, indexing="ij")
        t, p = t.ravel(), p.ravel()
        weight = np.sin(t) * (np.pi / n) * (2 * np.pi / n)
        degrees = np.concatenate([[l] * (2 * l + 1) for l in range(BANDS + 1)])
        orders = np.concatenate([np.arange(-l, l + 1) for l in range(BANDS + 1)])
        y = sph_harm_y(degrees[None, :], orders[None, :], t[:, None], p[:, None])  # (points, coeffs)
        _BASIS["dirs"] = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)
        _BASIS["project"] = np.conj(y) * weight[:, None]
        _BASIS["band"] = degrees
    return _BASIS["dirs"], _BASIS["project"], _BASIS["band"]


def shd_descriptor(vertices, faces, seed: int = GALLERY_SEED) -> np.ndarray:
    """Kazhdan et al.'s rotation-invariant SHD of a triangle mesh: (SPHERES, BANDS + 1) float32."""
    from scipy.ndimage import gaussian_filter, map_coordinates

    from shapeidx.signing.sampling import sample_surface

    points, _ = sample_surface(np.asarray(vertices, float), np.asarray(faces), SHD_POINTS, seed)
    points = points - points.mean(axis=0)
    radius = np.linalg.norm(points, axis=1).mean()
    half = GRID / 2
    cells = np.floor(points / (2 * radius) * half + half).astype(np.int64)
    inside = np.all((cells >= 0) & (cells < GRID), axis=1)
    grid = np.zeros(GRID**3)
    grid[np.ravel_multi_index(cells[inside].T, (GRID,) * 3)] = 1.0
    grid = gaussian_filter(grid.reshape((GRID,) * 3), 1.0)
    dirs, project, band = _basis()
    radii = np.arange(1, SPHERES + 1) * (half / SPHERES)
    where = (radii[:, None, None] * dirs[None]).reshape(-1, 3) + half - 0.5  # voxel centres at i + 0.5
    values = map_coordinates(grid, where.T, order=1, mode="constant").reshape(SPHERES, -1)
    coefficients = values @ project  # (spheres, coeffs)
    power = np.zeros((SPHERES, BANDS + 1))
    np.add.at(power.T, band, (np.abs(coefficients) ** 2).T)
    return np.sqrt(power).astype(np.float32)


def l2_to_many(bank: np.ndarray, query: np.ndarray) -> np.ndarray:
    """The peer's own distance: L2 between flattened descriptors (Kazhdan et al. 2003)."""
    return np.sqrt(((bank - query.ravel()[None, :]) ** 2).sum(axis=1))


def describe(paths, seed=GALLERY_SEED, lightfield=None) -> tuple[dict, list, dict]:
    """Each peer's descriptors of ``paths`` (``{"shd": rows, "lfd": (N, 10, 10, 47)}``, LFD only
    with a :class:`LightField`), the paths that loaded, and seconds per part (SHD: CPU time;
    LFD: wall time of its program, rendering included)."""
    from shapeidx.signing.pipeline import solid_of_file

    rows, lfd, kept, cpu, wall = [], [], [], [], []
    for path in paths:
        try:
            solid = solid_of_file(path)
            if lightfield is not None:
                start = time.perf_counter()
                described = lightfield.describe(solid.vertices, solid.faces)
                wall.append(time.perf_counter() - start)
        except Exception as error:  # a part shapeidx or a peer cannot load is left out of every column
            print(f"skip {path}: {error}", file=sys.stderr)
            continue
        if lightfield is not None:
            lfd.append(described)
        start = time.process_time()
        rows.append(shd_descriptor(solid.vertices, solid.faces, seed).ravel())
        cpu.append(time.process_time() - start)
        kept.append(Path(path))
    banks = {"shd": np.array(rows)}
    if lightfield is not None:
        banks["lfd"] = np.array(lfd)
    return banks, kept, {"shd": float(np.mean(cpu)), "lfd": float(np.mean(wall)) if wall else None}


def peer_distances(banks: dict, name: str, query) -> np.ndarray:
    """Peer ``name``'s own distance from ``query`` (one of its descriptors) to every stored one."""
    return l2_to_many(banks["shd"], query) if name == "shd" else lfd_to_many(banks["lfd"], query)


# ---------------------------------------------------------------- the Light Field Descriptor (its own code)
#: Where ``--build-lfd`` builds the light-field-distance package's C code (3DAlignment, Distance).
LFD_HOME = Path.home() / ".cache" / "shapeidx-peers" / "lfd"
#: Debian packages its build and headless rendering need.
LFD_DEBIAN = ("xvfb", "freeglut3-dev", "libglu1-mesa-dev", "libosmesa6-dev")
LFD_ANGLES = LFD_CAMERAS = 10  # light fields (rotations) per part, cameras per light field (ds.h)
#: Per light-field image: 35 Zernike (ART) coefficients, 10 Fourier, circularity, eccentricity,
#: each quantised to a byte; Distance.c weighs the Fourier and circularity terms twice.
LFD_WEIGHTS = np.array([1] * 35 + [2] * 10 + [2, 1], dtype=np.int32)


def build_lfd(home: Path = LFD_HOME) -> Path:
    """Build the C code that ``pip install 'shapeidx[peers]'`` (light-field-distance) ships, in
    ``home``; needs gcc and :data:`LFD_DEBIAN`. Returns the folder of the two programs."""
    import importlib.util
    import shutil
    import subprocess

    spec = importlib.util.find_spec("lfd")
    if spec is None or spec.origin is None:
        raise SystemExit("light-field-distance is not installed: pip install -e '.[peers]'")
    source = Path(spec.origin).parent
    shutil.rmtree(home, ignore_errors=True)
    shutil.copytree(source, home)
    for folder, program in (("3DAlignment", "3DAlignment"), ("LightField", "Distance")):
        done = subprocess.run(["make", "-s", "-j2"], cwd=home / folder, capture_output=True, text=True)
        if done.returncode != 0:  # its C code warns a lot: only a failure is shown
            raise SystemExit(f"building {folder} failed (apt-get install {' '.join(LFD_DEBIAN)}):\n{done.stderr[-2000:]}")
        shutil.copy(home / folder / program, home / "Executable" / program)
    return home / "Executable"


def lfd_programs(home: Path = LFD_HOME) -> Path | None:
    """The folder of the built 3DAlignment and Distance (None: not built, or no Xvfb to render in)."""
    import shutil

    folder = home / "Executable"
    if all((folder / p).is_file() for p in ("3DAlignment", "Distance")) and shutil.which("Xvfb"):
        return folder
    return None


class LightField:
    """Chen et al.'s Light Field Descriptor (2003) through the light-field-distance package's own
    C code (``3DAlignment``: 10 light fields x 10 silhouettes rendered with OpenGL on a virtual
    screen, each described by Zernike, Fourier, circularity and eccentricity bytes), one Xvfb
    for the whole run, each part in a private copy of the program's folder (it reads its
    camera files from, and writes its descriptor into, its working directory)."""

    def __init__(self, programs: Path):
        import subprocess
        import tempfile

        self.work = Path(tempfile.mkdtemp(prefix="lfd-"))
        for item in programs.iterdir():  # the cameras (12_*.obj), tables and programs
            os.symlink(item.resolve(), self.work / item.name)
        self.display = f":{os.getpid() % 500 + 100}"
        self.screen = subprocess.Popen(["Xvfb", self.display, "-screen", "0", "640x480x24", "-nolisten", "tcp"],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.0)

    def close(self):
        import shutil

        self.screen.terminate()
        self.screen.wait()
        shutil.rmtree(self.work, ignore_errors=True)

    def describe(self, vertices, faces) -> np.ndarray:
        """The descriptor of a triangle mesh: (10 light fields, 10 cameras, 47) bytes."""
        import subprocess

        import trimesh

        obj = self.work / "part.obj"
        trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False).export(obj)
        done = subprocess.run(["./3DAlignment", str(obj.with_suffix(""))], cwd=self.work, capture_output=True,
                              env={**os.environ, "DISPLAY": self.display}, timeout=600)
        if done.returncode != 0 or done.stderr.strip():
            raise RuntimeError(f"3DAlignment failed: {done.stderr.decode(errors='replace')[:200]}")
        return read_lfd(self.work / "all")


def read_lfd(stem: Path) -> np.ndarray:
    """The four descriptor files 3DAlignment writes (``STEM_q8_v1.8.art`` ...), as one array."""
    shape = (LFD_ANGLES, LFD_CAMERAS)
    art = np.fromfile(f"{stem}_q8_v1.8.art", np.uint8).reshape(*shape, 35)
    fd = np.fromfile(f"{stem}_q8_v1.8.fd", np.uint8).reshape(*shape, 10)
    cir = np.fromfile(f"{stem}_q8_v1.8.cir", np.uint8).reshape(*shape, 1)
    ecc = np.fromfile(f"{stem}_q8_v1.8.ecc", np.uint8).reshape(*shape, 1)
    return np.concatenate([art, fd, cir, ecc], axis=2)


_ALIGN = {}


def lfd_to_many(bank: np.ndarray, query: np.ndarray) -> np.ndarray:
    """The peer's own distance (Distance.c's MatchLF) from ``query`` to each of ``bank``
    (N, 10, 10, 47): the least, over the query's and the stored part's light fields and the 60
    rotations of the dodecahedron's cameras (``align10.txt``), of the summed weighted L1 of the
    10 camera pairs. Written with numpy and scipy's cdist; checked against the Distance program."""
    from scipy.spatial.distance import cdist

    if "align" not in _ALIGN:
        programs = lfd_programs() or (LFD_HOME / "Executable")
        _ALIGN["align"] = np.fromfile(programs / "align10.txt", np.uint8).reshape(60, 20)[:, :LFD_CAMERAS]
    align = _ALIGN["align"].astype(np.intp)
    n = len(bank)
    a = query.reshape(-1, query.shape[-1]).astype(np.float64) * LFD_WEIGHTS
    out = np.empty(n)
    for start in range(0, n, 256):
        chunk = bank[start:start + 256]
        b = chunk.reshape(-1, chunk.shape[-1]).astype(np.float64) * LFD_WEIGHTS
        cost = cdist(b, a, "cityblock").reshape(len(chunk), LFD_ANGLES, LFD_CAMERAS, LFD_ANGLES, LFD_CAMERAS)
        cost = cost.transpose(0, 1, 3, 2, 4)  # (part, its light field, the query's, its camera, the query's)
        err = cost[:, :, :, align, np.arange(LFD_CAMERAS)].sum(axis=-1)  # (part, lf, lf, 60 rotations)
        out[start:start + len(chunk)] = err.reshape(len(chunk), -1).min(axis=1)
    return out


# ---------------------------------------------------------------- the questions
def labelled(directory: Path, suffixes=(".wrl",)):
    paths = sorted(p for p in directory.rglob("*") if p.suffix.lower() in suffixes)
    return paths, [str(p.parent.relative_to(directory)) for p in paths]


def kinds(work: Path, out: dict):
    """kicad6's 52 folders: NN, FT, ST, DCG of every part against the 519 others."""
    from shapeidx.evaluation.evaluate import evaluate
    from shapeidx.evaluation.retrieval import retrieval_scores
    from shapeidx.store import open_store

    store = quiet_build(DATA / "kicad6", work / "kicad6-1024.h5", points=1024)
    with open_store(store) as reader:
        result = evaluate(reader)
    metrics = result["metrics"]
    best = max(metrics, key=lambda m: metrics[m]["ft"])
    paths, labels = labelled(DATA / "kicad6")
    banks, kept, cost = describe(paths, lightfield=out.get("lightfield"))
    keep = {str(p) for p in kept}
    labels = [l for p, l in zip(paths, labels) if str(p) in keep]
    scores = {}
    for name, bank in banks.items():
        d = np.array([peer_distances(banks, name, row) for row in bank])
        scores[name] = retrieval_scores(d, labels)
    out["kinds"] = {"peers": scores, "weighted": metrics["weighted"], "best": (best, metrics[best]), "parts": len(kept)}
    out["banks"], out["cost"], out["gallery"] = banks, cost, (banks, kept)


def step_twins(work: Path, out: dict):
    """Every kicad6-step part against the 520 kicad6 VRML parts: is its VRML export first?"""
    from shapeidx.distance import METRICS
    from twin_study import twin_ranks

    vrml = quiet_build(DATA / "kicad6", work / "kicad6-1024.h5", points=1024)
    step = quiet_build(DATA / "kicad6-step", work / "kicad6-step-1024.h5", points=1024)
    ranks = twin_ranks(step, vrml, lambda p: str(Path(p).with_suffix(".wrl")), metrics=METRICS)
    banks, gallery = out["gallery"]
    queries, qpaths, _ = describe(labelled(DATA / "kicad6-step", (".step", ".stp"))[0], QUERY_SEED,
                                  out.get("lightfield"))
    where = {str(p.relative_to(DATA / "kicad6")): i for i, p in enumerate(gallery)}
    found = {name: {} for name in banks}
    for k, q in enumerate(qpaths):
        twin = where.get(str(q.relative_to(DATA / "kicad6-step").with_suffix(".wrl")))
        if twin is not None:
            for name in banks:
                d = peer_distances(banks, name, queries[name][k])
                found[name][str(q.relative_to(DATA / "kicad6-step"))] = int((d <= d[twin]).sum())
    out["step"] = twin_table(ranks, found)


def twin_table(ranks: dict, found: dict) -> dict:
    """Rank-1 and top-10 rates of each peer, Weighted and the best metric, over the queries all have."""
    names = sorted(set(ranks).intersection(*[set(f) for f in found.values()]))

    def rate(values):
        v = np.array(values)
        return {"r1": float((v == 1).mean()), "top10": float((v <= 10).mean())}

    from shapeidx.distance import METRICS

    scored = {m: rate([ranks[n][m] for n in names]) for m in METRICS}
    best = max(scored, key=lambda m: (scored[m]["r1"], scored[m]["top10"]))
    return {"peers": {peer: rate([f[n] for n in names]) for peer, f in found.items()}, "weighted": scored["weighted"],
            "best": (best, scored[best]), "parts": len(names),
            "peer_ranks": {peer: {n: f[n] for n in names} for peer, f in found.items()},
            "weighted_ranks": {n: ranks[n]["weighted"] for n in names}, "best_ranks": {n: ranks[n][best] for n in names}}


def xexp_twins(work: Path, out: dict):
    """The 80 kicad2017 exports against twin_study's 1,000 KiCad 6 parts: is the KiCad 6 twin first?"""
    from shapeidx.distance import METRICS
    from twin_study import LIBRARY, twin_parts, twin_ranks

    parts = twin_parts(work / "xexp", Path("/work/deb/lib/usr/share/kicad/3dmodels") if not LIBRARY.exists() else LIBRARY)
    store = quiet_build(parts, work / "xexp" / "store1000.h5", points=1024, follow_outside_links=True)
    old = quiet_build(DATA / "xexp-dev" / "kicad2017", work / "xexp" / "kicad2017.h5", points=1024)
    ranks = twin_ranks(old, store, lambda p: f"twins/{p}", metrics=METRICS)
    banks, gallery, _ = describe(sorted(p for p in parts.rglob("*.wrl")), lightfield=out.get("lightfield"))
    queries, qpaths, _ = describe(sorted((DATA / "xexp-dev" / "kicad2017").glob("*.wrl")), QUERY_SEED,
                                  out.get("lightfield"))
    where = {str(p.relative_to(parts)): i for i, p in enumerate(gallery)}
    found = {name: {} for name in banks}
    for k, q in enumerate(qpaths):
        twin = where.get(f"twins/{q.name}")
        if twin is not None:
            for name in banks:
                d = peer_distances(banks, name, queries[name][k])
                found[name][q.name] = int((d <= d[twin]).sum())
    out["xexp"] = twin_table(ranks, found)


def query_time(banks: dict, name: str, repeats: int = 20) -> float:
    """Seconds for peer ``name`` to rank one descriptor against LIBRARY_SIZE stored ones
    (kicad6's real descriptors repeated to that many), best of ``repeats``."""
    bank = banks[name]
    rows = {name: np.resize(bank, (LIBRARY_SIZE, *bank.shape[1:]))}
    best = np.inf
    for k in range(repeats):
        start = time.perf_counter()
        np.argsort(peer_distances(rows, name, bank[k % len(bank)]), kind="stable")
        best = min(best, time.perf_counter() - start)
    return best


def shapeidx_costs(work: Path) -> dict:
    """shapeidx's cost per part for the same columns: signature CPU time and size on a few kicad6
    parts, and a Weighted query against a store of LIBRARY_SIZE entries if one is at hand."""
    from shapeidx.signing.pipeline import signature_of_solid, solid_of_file

    paths = labelled(DATA / "kicad6")[0][::52]
    cpu = []
    for p in paths:
        solid = solid_of_file(p)
        start = time.process_time()
        signature_of_solid(solid, points=1024)
        cpu.append(time.process_time() - start)
    return {"cpu": float(np.mean(cpu)), "parts": len(paths)}


# ---------------------------------------------------------------- the table
PEER_LABELS = {"lfd": "LFD (Chen 2003, its own code)", "shd": "SHD (Kazhdan 2003, reimplemented)"}


def table(out: dict, command: str, costs: dict) -> list:
    peers = [p for p in ("lfd", "shd") if p in out["banks"]]
    lines = [BEGIN, "",
             "| question | measure | " + " | ".join(PEER_LABELS[p] for p in peers)
             + " | shapeidx Weighted (paper; the default) | shapeidx best metric on it |",
             "|---|---|" + "---|" * len(peers) + "---|---|"]
    if "kinds" in out:
        k = out["kinds"]
        name, best = k["best"]
        for s in ("nn", "ft", "st", "dcg"):
            lines.append(f"| kicad6 kinds ({k['parts']} parts, 52 folders) | {s.upper()} | "
                         + " | ".join(f"{k['peers'][p][s]:.3f}" for p in peers)
                         + f" | {k['weighted'][s]:.3f} | {best[s]:.3f} ({name}) |")
    for key, label in (("step", "kicad6-step vs kicad6 twins"), ("xexp", "xexp-dev twins (of 1,000)")):
        if key in out:
            t = out[key]
            name, best = t["best"]
            for s, sl in (("r1", "twin at rank 1"), ("top10", "twin in top 10")):
                lines.append(f"| {label} ({t['parts']} queries) | {sl} | "
                             + " | ".join(f"{t['peers'][p][s]:.3f}" for p in peers)
                             + f" | {t['weighted'][s]:.3f} | {best[s]:.3f} ({name}) |")
    cost, query = out["cost"], out["query"]
    cells = {
        "lfd": (f"{cost['lfd']:.2f} s (its 3DAlignment program: 100 silhouettes rendered and described, wall"
                " time)" if cost.get("lfd") else "",
                f"{LFD_ANGLES * LFD_CAMERAS * 47:,} bytes (10 x 10 x 47 bytes)",
                f"{query['lfd'] * 1e3:.0f} ms (numpy: 100 x 100 camera costs x 60 rotations per part)"
                if "lfd" in query else ""),
        "shd": (f"{cost['shd']:.3f} s CPU (voxels + 32 SH transforms, after loading)",
                f"{out['banks']['shd'].shape[1] * 4:,} bytes ({SPHERES} x {BANDS + 1} float32)",
                f"{query['shd'] * 1e3:.2f} ms (L2 + sort)"),
    }
    lines += ["",
              "| cost per part | " + " | ".join(PEER_LABELS[p].split(" (")[0] for p in peers) + " | shapeidx (1,024 points) |",
              "|---|" + "---|" * len(peers) + "---|",
              "| descriptor time | " + " | ".join(cells[p][0] for p in peers)
              + f" | {costs['cpu']:.3f} s CPU (signature, after loading; mean of {costs['parts']} kicad6 parts) |",
              "| descriptor size | " + " | ".join(cells[p][1] for p in peers) + " | see docs/results.md's store sizes |",
              f"| query against {LIBRARY_SIZE:,} parts (kicad6's descriptors repeated) | "
              + " | ".join(cells[p][2] for p in peers) + " | see README's query timings |",
              "",
              f"Command: `{command}`, {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC; {machine()}.",
              "", END]
    return lines


def write(lines: list, markdown: Path):
    text = markdown.read_text()
    block = "\n".join(lines)
    if BEGIN in text:
        text = re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: block, text, flags=re.S)
    else:
        text = text.rstrip("\n") + "\n\n## Beside the classic peers: light fields and spherical harmonics\n\n" + block + "\n"
    markdown.write_text(text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path)
    parser.add_argument("--questions", default="kinds,step,xexp")
    parser.add_argument("--markdown", type=Path, default=REPO / "docs" / "results.md")
    parser.add_argument("--json", type=Path, help="also write every rank here")
    parser.add_argument("--build-lfd", action="store_true",
                        help=f"build the light-field-distance package's C code in {LFD_HOME} and stop")
    parser.add_argument("--no-lfd", action="store_true", help="leave the Light Field Descriptor out")
    args = parser.parse_args(argv)
    if args.build_lfd:
        print(f"built {build_lfd()}")
        return 0
    if args.work is None:
        parser.error("--work is required")
    args.work.mkdir(parents=True, exist_ok=True)
    chosen = args.questions.split(",")
    out = {}
    programs = None if args.no_lfd else lfd_programs()
    if programs is None and not args.no_lfd:
        print("no Light Field Descriptor: pip install -e '.[peers]'; apt-get install " + " ".join(LFD_DEBIAN)
              + "; python scripts/peers.py --build-lfd (or give --no-lfd)", file=sys.stderr)
        return 2
    out["lightfield"] = LightField(programs) if programs is not None else None
    try:
        kinds(args.work, out)  # always: its descriptors are the cost figures' and the step gallery's
        if "step" in chosen:
            step_twins(args.work, out)
        if "xexp" in chosen:
            xexp_twins(args.work, out)
    finally:
        if out["lightfield"] is not None:
            out["lightfield"].close()
    out["query"] = {name: query_time(out["banks"], name, 20 if name == "shd" else 3) for name in out["banks"]}
    command = "python scripts/peers.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = table(out, command, shapeidx_costs(args.work))
    print("\n".join(lines))
    write(lines, args.markdown)
    if args.json:
        import json

        args.json.write_text(json.dumps({k: out[k] for k in ("step", "xexp") if k in out}, default=str, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
