#!/usr/bin/env python3
"""shapeidx beside a classic peer descriptor, on shapeidx's own questions; writes the peers table.

    python scripts/peers.py --work /tmp/peers-work [--questions kinds,step,xexp]

The peer here is Kazhdan, Funkhouser and Rusinkiewicz's rotation-invariant spherical-harmonic
descriptor (SHD, SGP 2003), **written again from the paper** in numpy/scipy (``shd_descriptor``):
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
queries' points with another seed than the gallery's (``QUERY_SEED``). The Light Field Descriptor
(Chen et al. 2003) is not in the table: see docs/results.md's peers section for why.

shapeidx's columns are computed here at run time from stores built with the package (the paper's
Weighted, which is also ``shapeidx query``'s default metric, and, per question, the best of all
metrics on that question), through the same scoring code as docs/results.md
(``shapeidx.evaluation``, ``scripts/twin_study.twin_ranks``), so one command regenerates the table
after any change to shapeidx's signatures.

No extra dependency: numpy and scipy come with shapeidx. Nothing in ``shapeidx`` imports this.
"""

from __future__ import annotations

import argparse
import datetime
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


def describe(paths, seed=GALLERY_SEED) -> tuple[np.ndarray, list, float]:
    """Descriptors of ``paths`` (rows, flattened), the paths that loaded, CPU seconds per part."""
    from shapeidx.signing.pipeline import solid_of_file

    rows, kept, cpu = [], [], []
    for path in paths:
        try:
            solid = solid_of_file(path)
        except Exception as error:  # a part shapeidx cannot load is left out of both columns' figures
            print(f"skip {path}: {error}", file=sys.stderr)
            continue
        start = time.process_time()
        rows.append(shd_descriptor(solid.vertices, solid.faces, seed).ravel())
        cpu.append(time.process_time() - start)
        kept.append(Path(path))
    return np.array(rows), kept, float(np.mean(cpu))


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
    bank, kept, cpu = describe(paths)
    keep = {str(p) for p in kept}
    labels = [l for p, l in zip(paths, labels) if str(p) in keep]
    d = np.array([l2_to_many(bank, row) for row in bank])
    shd = retrieval_scores(d, labels)
    out["kinds"] = {"shd": shd, "weighted": metrics["weighted"], "best": (best, metrics[best]), "parts": len(kept)}
    out["bank"], out["cpu"], out["bank_paths"] = bank, cpu, (bank, kept, cpu)


def step_twins(work: Path, out: dict):
    """Every kicad6-step part against the 520 kicad6 VRML parts: is its VRML export first?"""
    from shapeidx.distance import METRICS
    from twin_study import twin_ranks

    vrml = quiet_build(DATA / "kicad6", work / "kicad6-1024.h5", points=1024)
    step = quiet_build(DATA / "kicad6-step", work / "kicad6-step-1024.h5", points=1024)
    ranks = twin_ranks(step, vrml, lambda p: str(Path(p).with_suffix(".wrl")), metrics=METRICS)
    gallery_paths, _ = labelled(DATA / "kicad6")
    bank, gallery, _ = out.get("bank_paths") or describe(gallery_paths)
    queries, qpaths, _ = describe(labelled(DATA / "kicad6-step", (".step", ".stp"))[0], QUERY_SEED)
    where = {str(p.relative_to(DATA / "kicad6")): i for i, p in enumerate(gallery)}
    shd = {}
    for row, q in zip(queries, qpaths):
        twin = where.get(str(q.relative_to(DATA / "kicad6-step").with_suffix(".wrl")))
        if twin is not None:
            d = l2_to_many(bank, row)
            shd[str(q.relative_to(DATA / "kicad6-step"))] = int((d <= d[twin]).sum())
    out["step"] = twin_table(ranks, shd)


def twin_table(ranks: dict, shd: dict) -> dict:
    """Rank-1 and top-10 rates of SHD, Weighted and the best metric, over the queries all have."""
    names = sorted(set(ranks) & set(shd))

    def rate(values):
        v = np.array(values)
        return {"r1": float((v == 1).mean()), "top10": float((v <= 10).mean())}

    from shapeidx.distance import METRICS

    scored = {m: rate([ranks[n][m] for n in names]) for m in METRICS}
    best = max(scored, key=lambda m: (scored[m]["r1"], scored[m]["top10"]))
    return {"shd": rate([shd[n] for n in names]), "weighted": scored["weighted"], "best": (best, scored[best]),
            "parts": len(names), "shd_ranks": {n: shd[n] for n in names},
            "weighted_ranks": {n: ranks[n]["weighted"] for n in names}, "best_ranks": {n: ranks[n][best] for n in names}}


def xexp_twins(work: Path, out: dict):
    """The 80 kicad2017 exports against twin_study's 1,000 KiCad 6 parts: is the KiCad 6 twin first?"""
    from shapeidx.distance import METRICS
    from twin_study import LIBRARY, twin_parts, twin_ranks

    parts = twin_parts(work / "xexp", Path("/work/deb/lib/usr/share/kicad/3dmodels") if not LIBRARY.exists() else LIBRARY)
    store = quiet_build(parts, work / "xexp" / "store1000.h5", points=1024, follow_outside_links=True)
    old = quiet_build(DATA / "xexp-dev" / "kicad2017", work / "xexp" / "kicad2017.h5", points=1024)
    ranks = twin_ranks(old, store, lambda p: f"twins/{p}", metrics=METRICS)
    gallery_paths = sorted(p for p in parts.rglob("*.wrl"))
    bank, gallery, _ = describe(gallery_paths)
    queries, qpaths, _ = describe(sorted((DATA / "xexp-dev" / "kicad2017").glob("*.wrl")), QUERY_SEED)
    where = {str(p.relative_to(parts)): i for i, p in enumerate(gallery)}
    shd = {}
    for row, q in zip(queries, qpaths):
        twin = where.get(f"twins/{q.name}")
        if twin is not None:
            d = l2_to_many(bank, row)
            shd[q.name] = int((d <= d[twin]).sum())
    out["xexp"] = twin_table(ranks, shd)


def query_time(bank: np.ndarray) -> float:
    """Seconds to rank one descriptor against LIBRARY_SIZE stored ones (kicad6's real descriptors
    repeated to that many rows), best of 20."""
    rows = np.resize(bank, (LIBRARY_SIZE, bank.shape[1]))
    best = np.inf
    for k in range(20):
        start = time.perf_counter()
        np.argsort(l2_to_many(rows, bank[k % len(bank)]), kind="stable")
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
def table(out: dict, command: str, costs: dict) -> list:
    lines = [BEGIN, "",
             "| question | measure | SHD (Kazhdan 2003, reimplemented) | shapeidx Weighted (paper; the default) |"
             " shapeidx best metric on it |",
             "|---|---|---|---|---|"]
    if "kinds" in out:
        k = out["kinds"]
        name, best = k["best"]
        for s in ("nn", "ft", "st", "dcg"):
            lines.append(f"| kicad6 kinds ({k['parts']} parts, 52 folders) | {s.upper()} | {k['shd'][s]:.3f} |"
                         f" {k['weighted'][s]:.3f} | {best[s]:.3f} ({name}) |")
    for key, label in (("step", "kicad6-step vs kicad6 twins"), ("xexp", "xexp-dev twins (of 1,000)")):
        if key in out:
            t = out[key]
            name, best = t["best"]
            for s, sl in (("r1", "twin at rank 1"), ("top10", "twin in top 10")):
                lines.append(f"| {label} ({t['parts']} queries) | {sl} | {t['shd'][s]:.3f} | {t['weighted'][s]:.3f} |"
                             f" {best[s]:.3f} ({name}) |")
    lines += ["",
              "| cost per part | SHD | shapeidx (1,024 points) |",
              "|---|---|---|",
              f"| descriptor CPU time | {out['cpu']:.3f} s (voxels + 32 SH transforms, after loading) |"
              f" {costs['cpu']:.3f} s (signature, after loading; mean of {costs['parts']} kicad6 parts) |",
              f"| descriptor size | {out['bank'].shape[1] * 4:,} bytes ({SPHERES} x {BANDS + 1} float32) |"
              " see docs/results.md's store sizes |",
              f"| query against {LIBRARY_SIZE:,} parts | {out['query'] * 1e3:.2f} ms (L2 + sort; kicad6's descriptors"
              f" repeated to {LIBRARY_SIZE:,} rows) | see README's query timings |",
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
        text = text.rstrip("\n") + "\n\n## Beside a classic peer: spherical harmonics\n\n" + block + "\n"
    markdown.write_text(text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--questions", default="kinds,step,xexp")
    parser.add_argument("--markdown", type=Path, default=REPO / "docs" / "results.md")
    parser.add_argument("--json", type=Path, help="also write every rank here")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    chosen = args.questions.split(",")
    out = {}
    kinds(args.work, out)  # always: its descriptors are the cost figures' and the step gallery's
    if "step" in chosen:
        step_twins(args.work, out)
    if "xexp" in chosen:
        xexp_twins(args.work, out)
    out["query"] = query_time(out["bank"])
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
