#!/usr/bin/env python3
"""shapeidx beside the classic peer descriptors, on shapeidx's own questions; writes the peers table.

    pip install -e '.[peers]'                      # light-field-distance: the LFD's C code
    apt-get install xvfb freeglut3-dev libglu1-mesa-dev libosmesa6-dev
    python scripts/peers.py --build-lfd            # builds it in ~/.cache/shapeidx-peers/lfd
    python scripts/peers.py --work /tmp/peers-work [--questions kinds,step,xexp,ndr] [--no-lfd]

The questions: **kinds**, every labelled collection of docs/results.md (:data:`COLLECTIONS`:
kicad6's 52 folders, kicad-mcad, kicad-2017's freecad-coin and wings3d, kicad-wrz), each part
against the others (NN, FT, ST, DCG); **step**, the 336 kicad6-step parts against the 520 kicad6
VRML parts (is its own VRML first?); **xexp**, xexp-dev's KiCad 2017 exports against
scripts/twin_study.py's 1,000 KiCad 6 parts (needs Debian's library); **ndr**, the 4 National
Design Repository parts exported by two programs (I-DEAS and Sat2Vrml), each file against the
15 other ndr parts. mesh-wild's folders are sources, not kinds: no question (said under the
table). Every descriptor is kept in ``WORK/descriptors`` (:class:`DescriptorCache`), so a second
run, or a run cut off, describes only what it has not (``--describe-only`` fills it and stops).

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
queries' points with each of :data:`QUERY_SEEDS`, none of them the gallery's, and so do
shapeidx's own columns (the query signed again, as ``evaluate --query-seed`` does).

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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from _common import COLLECTIONS, DATA, REPO, machine, quiet_build

GRID = 64
SPHERES = 32
BANDS = 16
SHD_POINTS = 20000
GALLERY_SEED = 2003
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


@dataclass
class Described:
    """Each peer's descriptors of ``paths``, row for row (a row a peer could not describe is
    zeros, and its index is in ``missing[peer]``), shapeidx's signatures of the same solids
    when asked (``signatures[seed]``), and each peer's mean seconds per part."""

    paths: list
    banks: dict  # "lfd": (N, 10, 10, 47) uint8; ("shd", seed): (N, SPHERES * (BANDS + 1)) float32
    missing: dict  # peer name -> set of row indices
    signatures: dict  # seed -> list of Signature (None where the part did not load)
    seconds: dict  # "lfd": wall, "shd": CPU, per part (None: nothing timed)

    def bank(self, peer: str, seed: int = GALLERY_SEED) -> np.ndarray:
        return self.banks["lfd"] if peer == "lfd" else self.banks[("shd", seed)]


class DescriptorCache:
    """Descriptors already made, one small ``.npz`` per (peer, file version, seed, parameters)
    in ``WORK/descriptors``, written whole or not at all: a second run, or a run cut off,
    describes only what is not there yet (LFD costs ~2.7 s a part)."""

    def __init__(self, folder: Path | None):
        self.folder = folder
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def _parameters(peer: str) -> str:
        if peer == "lfd":
            from importlib.metadata import PackageNotFoundError, version

            try:
                return f"light-field-distance {version('light-field-distance')}"
            except PackageNotFoundError:
                return "light-field-distance"
        if peer == "shd":
            from shapeidx.signing.parameters import SIGNATURE_VERSION

            # SHD's points come from shapeidx's sampler: a new sampler is a new descriptor
            return f"grid {GRID} spheres {SPHERES} bands {BANDS} points {SHD_POINTS} sampler {SIGNATURE_VERSION}"
        from shapeidx.signing.parameters import BIN_DIVISOR, SIGNATURE_VERSION

        return f"shapeidx signature {SIGNATURE_VERSION} divisor {BIN_DIVISOR}"

    def _file(self, peer: str, path: Path, seed) -> Path | None:
        if self.folder is None:
            return None
        import hashlib

        info = path.stat()
        key = f"{peer}|{path.resolve()}|{info.st_size}|{info.st_mtime_ns}|{seed}|{self._parameters(peer)}"
        return self.folder / f"{peer}-{hashlib.sha1(key.encode()).hexdigest()}.npz"

    def get(self, peer: str, path: Path, seed=None):
        """(value, seconds) from the cache, or None."""
        file = self._file(peer, path, seed)
        if file is None or not file.is_file():
            return None
        import pickle

        with np.load(file, allow_pickle=False) as data:
            value = data["value"]
            if peer == "signature":
                value = pickle.loads(value.tobytes())
            return value, float(data["seconds"])

    def put(self, peer: str, path: Path, seed, value, seconds: float):
        file = self._file(peer, path, seed)
        if file is None:
            return
        import pickle

        if peer == "signature":
            value = np.frombuffer(pickle.dumps(value), np.uint8)
        partial = file.with_suffix(f".{os.getpid()}.part")
        with open(partial, "wb") as handle:
            np.savez(handle, value=value, seconds=seconds)
        os.replace(partial, file)


def describe(paths, seeds=(GALLERY_SEED,), lightfield=None, cache: DescriptorCache | None = None,
             sign: bool = False) -> Described:
    """Each peer's descriptors of ``paths``: LFD (only with a :class:`LightField`; it renders, so
    it has no seed), SHD with each of ``seeds``, and with ``sign`` shapeidx's own signature of
    the same solid with each seed (1,024 points; the search road's query signature). Each file
    is loaded once, and only when something it needs is not in ``cache``."""
    from shapeidx.signing.pipeline import signature_of_solid, solid_of_file

    cache = cache or DescriptorCache(None)
    paths = [Path(p) for p in paths]
    wanted = ([("lfd", None)] if lightfield is not None else []) + [("shd", s) for s in seeds]
    wanted += [("signature", s) for s in seeds] if sign else []
    found = {w: [None] * len(paths) for w in wanted}
    seconds = {"lfd": [], "shd": []}
    for i, path in enumerate(paths):
        solid = None
        for peer, seed in wanted:
            hit = cache.get(peer, path, seed)
            if hit is None:
                try:
                    if solid is None:
                        solid = solid_of_file(path)
                    if peer == "lfd":
                        start = time.perf_counter()
                        value = lightfield.describe(solid.vertices, solid.faces)
                        hit = value, time.perf_counter() - start
                    elif peer == "shd":
                        start = time.process_time()
                        value = shd_descriptor(solid.vertices, solid.faces, seed).ravel()
                        hit = value, time.process_time() - start
                    else:
                        hit = signature_of_solid(solid, points=1024, seed=seed), 0.0
                except Exception as error:  # left out of this peer's column, and counted as a miss
                    print(f"skip {path} ({peer}): {str(error)[:200]}", file=sys.stderr)
                    continue
                cache.put(peer, path, seed, *hit)
            found[(peer, seed)][i] = hit[0]
            if peer in seconds:
                seconds[peer].append(hit[1])
    banks, missing, signatures = {}, {}, {}
    for (peer, seed), values in found.items():
        if peer == "signature":
            signatures[seed] = values
            continue
        shape = (LFD_ANGLES, LFD_CAMERAS, 47) if peer == "lfd" else (SPHERES * (BANDS + 1),)
        dtype = np.uint8 if peer == "lfd" else np.float32
        banks[peer if peer == "lfd" else (peer, seed)] = np.array(
            [v if v is not None else np.zeros(shape, dtype) for v in values], dtype=dtype).reshape(len(paths), *shape)
        missing.setdefault(peer, set()).update(i for i, v in enumerate(values) if v is None)
    return Described(paths, banks, missing, signatures,
                     {peer: float(np.mean(t)) if t else None for peer, t in seconds.items()})


def peer_distances(bank: np.ndarray, name: str, query, missing=()) -> np.ndarray:
    """Peer ``name``'s own distance from ``query`` (one of its descriptors) to every row of
    ``bank``; rows the peer could not describe are infinitely far (never found)."""
    d = l2_to_many(bank, query) if name == "shd" else lfd_to_many(bank, query)
    d = d.astype(np.float64)
    d[list(missing)] = np.inf
    return d


PEERS = ("lfd", "shd")


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
#: The twin questions' queries draw their points (SHD's and shapeidx's) with each of these
#: seeds, none of them the gallery's: figures are the mean, with the lowest and highest.
QUERY_SEEDS = (7, 8, 9)
#: Collections in shared/ with no question to ask of them, and why (said under the table).
NO_QUESTION = {
    "mesh-wild": "folders named after their sources (assimp, OpenSCAD, trimesh, a printer), not kinds, and no twins",
}


def labelled(directory: Path, suffixes=(".wrl",)):
    paths = sorted(p for p in directory.rglob("*") if p.suffix.lower() in suffixes)
    return paths, [str(p.parent.relative_to(directory)) for p in paths]


def peers_of(described: Described) -> list:
    return [p for p in PEERS if p == "shd" or p in described.banks]


def peer_matrix(described: Described, peer: str, labels) -> np.ndarray:
    """Peer distances among a collection's parts. A part the peer could not describe is never
    found, and as a query it is scored as the worst answer (every other class first)."""
    bank, missing = described.bank(peer), described.missing[peer]
    labels = np.asarray(labels, dtype=object)
    rows = []
    for q in range(len(bank)):
        if q in missing:
            row = np.where(labels == labels[q], np.inf, 1.0)
            row[q] = 0.0
        else:
            row = peer_distances(bank, peer, bank[q], missing)
        rows.append(row)
    return np.array(rows)


def kinds(work: Path, out: dict, name: str, folder: Path):
    """One labelled collection: NN, FT, ST, DCG of every part against the others, for each
    peer and for shapeidx's metrics (``shapeidx evaluate``, on the same parts)."""
    from shapeidx.evaluation.evaluate import class_of, evaluate
    from shapeidx.evaluation.retrieval import retrieval_scores
    from shapeidx.search import Searcher
    from shapeidx.store import open_store

    store = quiet_build(folder, work / f"{name.replace('/', '-')}-1024.h5", points=1024)
    with open_store(store) as reader:
        result = evaluate(reader)
    metrics = result["metrics"]
    best = max(metrics, key=lambda m: metrics[m]["ft"])
    with Searcher(store) as searcher:
        stored = sorted(str(p) for p in searcher.metadata_column("path"))
    chosen = [p for p in stored if class_of(p) is not None]  # evaluate's parts, in its order
    labels = [class_of(p) for p in chosen]
    assert len(chosen) == result["models"], (name, len(chosen), result["models"])
    described = describe([folder / p for p in chosen], lightfield=out["lightfield"], cache=out["cache"])
    scores = {peer: retrieval_scores(peer_matrix(described, peer, labels), labels) for peer in peers_of(described)}
    out.setdefault("kinds", {})[name] = {
        "peers": scores, "weighted": metrics["weighted"], "best": (best, metrics[best]), "parts": len(chosen),
        "classes": len(set(labels)), "missing": {peer: len(described.missing[peer]) for peer in peers_of(described)},
        "in_sample": bool(metrics[best].get("in_sample"))}
    out.setdefault("seconds", []).append(described.seconds)
    out.setdefault("gallery", {})[name] = (described, store)


def twin_question(queries: Described, gallery: Described, store: Path, twin_of, exclude_self: bool = False) -> dict:
    """Per query: the rank of its twin (ties counted against it) by each peer, LFD once, SHD
    and shapeidx (every metric) with each query seed; a query or twin not described is last.
    ``exclude_self``: the query's own file is in the gallery, and left out of its ranking."""
    from shapeidx.distance import METRICS
    from shapeidx.search import Searcher
    from shapeidx.search.distances import distances

    where = {os.path.abspath(p): i for i, p in enumerate(gallery.paths)}
    peer_ranks = {(peer, seed): {} for peer in peers_of(gallery)
                  for seed in ((None,) if peer == "lfd" else QUERY_SEEDS)}
    own_ranks = {seed: {} for seed in QUERY_SEEDS}
    with Searcher(store) as searcher:
        stored = {os.path.abspath(Path(searcher.root) / str(p)): i for i, p in enumerate(searcher.metadata_column("path"))}
        for k, query in enumerate(queries.paths):
            twin_path = os.path.abspath(twin_of(query))
            twin, stored_twin = where.get(twin_path), stored.get(twin_path)
            own, stored_own = (where.get(os.path.abspath(query)), stored.get(os.path.abspath(query))) if exclude_self \
                else (None, None)
            if twin is None or stored_twin is None:
                continue
            name = query.name
            for peer, seed in peer_ranks:
                if k in queries.missing[peer]:
                    peer_ranks[(peer, seed)][name] = len(gallery.paths)
                    continue
                d = peer_distances(gallery.bank(peer), peer, queries.bank(peer, seed or GALLERY_SEED)[k],
                                   gallery.missing[peer] | ({own} if own is not None else set()))
                peer_ranks[(peer, seed)][name] = int((d <= d[twin]).sum())
            for seed in QUERY_SEEDS:
                signature = queries.signatures[seed][k]
                ranks = {}
                for metric in METRICS:
                    if signature is None:
                        ranks[metric] = len(stored)
                        continue
                    d = distances(searcher.view, signature, metric)
                    if stored_own is not None:
                        d[stored_own] = np.inf
                    ranks[metric] = int((d <= d[stored_twin]).sum())
                own_ranks[seed][name] = ranks
    return {"peer_ranks": peer_ranks, "own_ranks": own_ranks}


def twin_table(found: dict, kept=None) -> dict:
    """Rank-1 and top-10 rates (mean over the query seeds, lowest and highest) of each peer, of
    Weighted and of the best metric, over the queries every column has (and in ``kept``)."""
    from shapeidx.distance import METRICS

    columns = list(found["peer_ranks"].values()) + list(found["own_ranks"].values())
    names = sorted(set.intersection(*[set(c) for c in columns]))
    if kept is not None:
        names = [n for n in names if n in kept]

    def rate(per_seed):
        r1 = [float(np.mean([ranks[n] == 1 for n in names])) for ranks in per_seed]
        top = [float(np.mean([ranks[n] <= 10 for n in names])) for ranks in per_seed]
        return {"r1": float(np.mean(r1)), "r1_range": (min(r1), max(r1)), "top10": float(np.mean(top)),
                "top10_range": (min(top), max(top)), "seeds": len(per_seed)}

    peers = {}
    for (peer, _), ranks in found["peer_ranks"].items():
        peers.setdefault(peer, []).append(ranks)
    own = {m: rate([{n: r[n][m] for n in names} for r in found["own_ranks"].values()]) for m in METRICS}
    best = max(own, key=lambda m: (own[m]["r1"], own[m]["top10"]))
    return {"peers": {peer: rate(per_seed) for peer, per_seed in peers.items()}, "weighted": own["weighted"],
            "best": (best, own[best]), "parts": len(names),
            "ranks": {"peers": {f"{p}{'' if s is None else f'@{s}'}": {n: r[n] for n in names}
                                for (p, s), r in found["peer_ranks"].items()},
                      "shapeidx": {s: {n: r[n] for n in names} for s, r in found["own_ranks"].items()}}}


def step_twins(work: Path, out: dict):
    """Every kicad6-step part against the 520 kicad6 VRML parts: is its VRML export first?"""
    gallery, store = out["gallery"]["kicad6"]
    files = labelled(DATA / "kicad6-step", (".step", ".stp"))[0]
    queries = describe(files, QUERY_SEEDS, out["lightfield"], out["cache"], sign=True)
    found = twin_question(queries, gallery, store,
                          lambda q: DATA / "kicad6" / q.relative_to(DATA / "kicad6-step").with_suffix(".wrl"))
    out["step"] = twin_table(found)


#: ndr's parts exported twice, by SDRC I-DEAS (``X.wrl``) and by GICL's Sat2Vrml from the ACIS
#: file (``X.hh.sat.wrl``): the same part from two exporters (ndr/SOURCES.tsv).
NDR_SECOND_EXPORT = ".hh.sat.wrl"


def ndr_twins(work: Path, out: dict):
    """ndr's 4 parts exported by two programs: each of the 8 files against the 15 other ndr
    parts (itself left out): is its other export first?"""
    folder = DATA / "ndr"
    store = quiet_build(folder, work / "ndr-1024.h5", points=1024)
    files = sorted(folder.rglob("*.wrl"))
    names = {str(f) for f in files}

    def twin_of(f: Path) -> Path:
        if f.name.endswith(NDR_SECOND_EXPORT):
            return f.with_name(f.name[: -len(NDR_SECOND_EXPORT)] + ".wrl")
        return f.with_name(f.name[: -len(".wrl")] + NDR_SECOND_EXPORT)

    paired = [f for f in files if str(twin_of(f)) in names]
    gallery = describe(files, lightfield=out["lightfield"], cache=out["cache"])
    queries = describe(paired, QUERY_SEEDS, out["lightfield"], out["cache"], sign=True)
    out["ndr"] = twin_table(twin_question(queries, gallery, store, twin_of, exclude_self=True))
    out["ndr"]["gallery"] = len(files)


def xexp_twins(work: Path, out: dict):
    """The kicad2017 exports against twin_study's 1,000 KiCad 6 parts: is the KiCad 6 twin first?
    (the pairs twin_study keeps: EXCLUDED's remodelled ones are left out)."""
    from twin_study import EXCLUDED, LIBRARY, twin_parts

    library = LIBRARY if LIBRARY.exists() else Path("/work/deb/lib/usr/share/kicad/3dmodels")
    if not library.exists():
        raise SystemExit(f"xexp: no Debian KiCad library at {LIBRARY} (apt-get download kicad-packages3d;"
                         " dpkg-deb -x it to /work/deb/lib)")
    parts = twin_parts(work / "xexp", library)
    store = quiet_build(parts, work / "xexp" / "store1000.h5", points=1024, follow_outside_links=True)
    gallery = describe(sorted(p for p in parts.rglob("*.wrl")), lightfield=out["lightfield"], cache=out["cache"])
    files = sorted((DATA / "xexp-dev" / "kicad2017").glob("*.wrl"))
    queries = describe(files, QUERY_SEEDS, out["lightfield"], out["cache"], sign=True)
    found = twin_question(queries, gallery, store, lambda q: parts / "twins" / q.name)
    out["xexp"] = twin_table(found, kept={f.name for f in files if f.name not in EXCLUDED})
    out.setdefault("seconds", []).append(gallery.seconds)
    out.setdefault("gallery", {})["xexp"] = (gallery, store)


def query_time(bank: np.ndarray, name: str, repeats: int = 20) -> float:
    """Seconds for peer ``name`` to rank one descriptor against LIBRARY_SIZE stored ones
    (real descriptors repeated to that many), best of ``repeats``."""
    rows = np.resize(bank, (LIBRARY_SIZE, *bank.shape[1:]))
    best = np.inf
    for k in range(repeats):
        start = time.perf_counter()
        np.argsort(peer_distances(rows, name, bank[k % len(bank)]), kind="stable")
        best = min(best, time.perf_counter() - start)
    return best


def shapeidx_costs(work: Path) -> dict:
    """shapeidx's cost per part for the same columns: signature CPU time on a few kicad6 parts."""
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


def _rate_cell(rate: dict, key: str) -> str:
    low, high = rate[f"{key}_range"]
    return f"{rate[key]:.3f}" + (f" ({low:.3f}-{high:.3f})" if rate["seeds"] > 1 and high > low else "")


def table(out: dict, command: str, costs: dict) -> list:
    peers = [p for p in PEERS if any(p in k["peers"] for k in out.get("kinds", {}).values())
             or any(p in out[q]["peers"] for q in ("step", "xexp", "ndr") if q in out)]
    lines = [BEGIN, "",
             "| question | measure | " + " | ".join(PEER_LABELS[p] for p in peers)
             + " | shapeidx Weighted (paper; the default) | shapeidx best metric on it |",
             "|---|---|" + "---|" * len(peers) + "---|---|"]
    for name, k in out.get("kinds", {}).items():
        metric, best = k["best"]
        missed = ", ".join(f"{PEER_LABELS[p].split(' ')[0]} could not describe {n}" for p, n in k["missing"].items() if n)
        label = f"{name} kinds ({k['parts']} parts, {k['classes']} folders{'; ' + missed if missed else ''})"
        for s in ("nn", "ft", "st", "dcg"):
            lines.append(f"| {label} | {s.upper()} | " + " | ".join(f"{k['peers'][p][s]:.3f}" for p in peers)
                         + f" | {k['weighted'][s]:.3f} | {best[s]:.3f} ({metric}{', learned here' if k['in_sample'] else ''}) |")
    for key, label in (("step", "kicad6-step vs kicad6 twins"), ("xexp", "xexp-dev twins (of 1,000)"),
                       ("ndr", "ndr: the other exporter's file (of 15)")):
        if key in out:
            t = out[key]
            metric, best = t["best"]
            for s, sl in (("r1", "twin at rank 1"), ("top10", "twin in top 10")):
                lines.append(f"| {label} ({t['parts']} queries) | {sl} | "
                             + " | ".join(_rate_cell(t["peers"][p], s) for p in peers)
                             + f" | {_rate_cell(t['weighted'], s)} | {_rate_cell(best, s)} ({metric}) |")
    seconds = {p: [c[p] for c in out.get("seconds", []) if c.get(p) is not None] for p in peers}
    cost = {p: float(np.mean(v)) if v else None for p, v in seconds.items()}
    query = out["query"]
    cells = {
        "lfd": (f"{cost['lfd']:.2f} s (its 3DAlignment program: 100 silhouettes rendered and described, wall"
                " time)" if cost.get("lfd") else "",
                f"{LFD_ANGLES * LFD_CAMERAS * 47:,} bytes (10 x 10 x 47 bytes)",
                f"{query['lfd'] * 1e3:.0f} ms (numpy: 100 x 100 camera costs x 60 rotations per part)"
                if "lfd" in query else ""),
        "shd": (f"{cost['shd']:.3f} s CPU (voxels + 32 SH transforms, after loading)" if cost.get("shd") else "",
                f"{SPHERES * (BANDS + 1) * 4:,} bytes ({SPHERES} x {BANDS + 1} float32)",
                f"{query['shd'] * 1e3:.2f} ms (L2 + sort)" if "shd" in query else ""),
    }
    lines += ["",
              "Twin questions: the queries' points (SHD's and shapeidx's) drawn with the seeds "
              + ", ".join(map(str, QUERY_SEEDS)) + ", none of them the gallery's: the mean, and in brackets the lowest"
              " and highest where they differ; LFD renders and does not sample (one figure). Ties count against the twin. "
              + " ".join(f"{name}: no question ({why})." for name, why in NO_QUESTION.items()),
              "",
              "| cost per part | " + " | ".join(PEER_LABELS[p].split(" (")[0] for p in peers) + " | shapeidx (1,024 points) |",
              "|---|" + "---|" * len(peers) + "---|",
              "| descriptor time | " + " | ".join(cells[p][0] for p in peers)
              + f" | {costs['cpu']:.3f} s CPU (signature, after loading; mean of {costs['parts']} kicad6 parts) |",
              "| descriptor size | " + " | ".join(cells[p][1] for p in peers) + " | see docs/results.md's store sizes |",
              f"| query against {LIBRARY_SIZE:,} parts (real descriptors repeated) | "
              + " | ".join(cells[p][2] for p in peers) + " | see README's query timings |",
              "",
              f"Command: `{command}`, {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC; {machine()}.",
              "", END]
    return lines


def write(lines: list, markdown: Path):
    text = markdown.read_text() if markdown.exists() else ""
    block = "\n".join(lines)
    if BEGIN in text:
        text = re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: block, text, flags=re.S)
    else:
        text = text.rstrip("\n") + "\n\n## Beside the classic peers: light fields and spherical harmonics\n\n" + block + "\n"
    markdown.write_text(text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, help="stores and the descriptor cache (WORK/descriptors)")
    parser.add_argument("--questions", default="kinds,step,xexp,ndr",
                        help="kinds (every labelled collection), step, xexp (needs Debian's library), ndr")
    parser.add_argument("--collections", default=",".join(COLLECTIONS), help="the kinds question's collections")
    parser.add_argument("--markdown", type=Path, default=REPO / "docs" / "results.md")
    parser.add_argument("--json", type=Path, help="also write every rank here")
    parser.add_argument("--describe-only", action="store_true",
                        help="fill the descriptor cache for the questions chosen and stop (no table)")
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
    collections = [c for c in args.collections.split(",") if c]
    unknown = [q for q in chosen if q not in ("kinds", "step", "xexp", "ndr")] + [c for c in collections if c not in COLLECTIONS]
    if unknown:
        parser.error(f"unknown question or collection: {', '.join(unknown)}")
    if "step" in chosen and "kicad6" not in collections:
        collections.insert(0, "kicad6")  # the step question's gallery
    out = {"cache": DescriptorCache(args.work / "descriptors")}
    programs = None if args.no_lfd else lfd_programs()
    if programs is None and not args.no_lfd:
        print("no Light Field Descriptor: pip install -e '.[peers]'; apt-get install " + " ".join(LFD_DEBIAN)
              + "; python scripts/peers.py --build-lfd (or give --no-lfd)", file=sys.stderr)
        return 2
    out["lightfield"] = LightField(programs) if programs is not None else None
    try:
        if "kinds" in chosen or "step" in chosen:
            for name in collections if "kinds" in chosen else ["kicad6"]:
                kinds(args.work, out, name, COLLECTIONS[name])
        if "step" in chosen:
            step_twins(args.work, out)
        if "xexp" in chosen:
            xexp_twins(args.work, out)
        if "ndr" in chosen:
            ndr_twins(args.work, out)
    finally:
        if out["lightfield"] is not None:
            out["lightfield"].close()
    if args.describe_only:
        return 0
    if "kinds" not in chosen:
        out.pop("kinds", None)  # asked only as the step question's gallery
    banks = next(iter(out["gallery"].values()))[0] if out.get("gallery") else None
    out["query"] = {} if banks is None else {
        name: query_time(banks.bank(name), name, 20 if name == "shd" else 3) for name in peers_of(banks)}
    command = "python scripts/peers.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = table(out, command, shapeidx_costs(args.work))
    print("\n".join(lines))
    write(lines, args.markdown)
    if args.json:
        import json

        args.json.write_text(json.dumps({k: out[k] for k in ("step", "xexp", "ndr") if k in out}, default=str, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
