#!/usr/bin/env python3
"""Signature speed: shapeidx against the bare Embree query and a plain trimesh approach.

For each part file, medians over ``--repeat`` runs after one warm-up run:

* ``load``, ``solid``: reading the file, cleaning and uniting it;
* ``sig``: sampling, classifying all 523,776 pairs and histogramming, on one thread;
* ``sig_mt``: the same with the ray queries on every core (what ``shapeidx signature`` uses);
* ``bare``: one embreex occlusion query per segment over the same 523,776 segments between
  the same points (ends trimmed by 1e-6 so no ray stops on its own triangle), one thread:
  the irreducible cost of asking Embree once per pair;
* ``trimesh``: a straightforward implementation with trimesh (all hits along every segment
  through ``mesh.ray.intersects_location``, then ``mesh.contains`` at the midpoint of the
  segments that cross nothing), on the first ``--trimesh`` parts only: it is slow.

Ratios are taken within one run on one machine: end-to-end (load + solid + sig) over bare.

Then the VRML reader alone (``scripts/bench_vrml.py``, best of ``--repeat`` reads): MB/s and
triangles/s on the largest KUKA robot files of vrml-wild and on the kicad6 parts with about
1,000 and with the most Shapes (one Shape per CAD face). ``--no-vrml`` leaves it out.

    python scripts/bench.py                       # mesh-wild STL parts and kicad6, one per class
    python scripts/bench.py --files a.stl b.wrl   # chosen parts
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from shapeidx.signing.classify import IN, MIXED, OUT, OcclusionScene, normalise, pair_indices
from shapeidx.errors import LoadError
from shapeidx.io import load
from shapeidx.system import keep_freed_memory
from shapeidx.signing.pipeline import signature_of_solid
from shapeidx.signing.sampling import sample_surface
from shapeidx.signing.solid import make_solid

import bench_vrml  # noqa: E402  (this folder is on sys.path when run as a script)
from _common import DATA, machine  # noqa: E402



def median_time(fn, repeat: int):
    fn()  # warm-up: caches, allocator, lazy imports
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def bare_query(solid, points: int):
    """The same segments as the signature, as plain occlusion queries (one thread)."""
    samples, _ = sample_surface(solid.vertices, solid.faces, points)
    vertices, p, _ = normalise(solid.vertices, samples)
    scene = OcclusionScene(vertices, solid.faces)
    i, j = pair_indices(points)
    delta = p[j] - p[i]
    origins = (p[i] + 1e-6 * delta).astype(np.float32)
    directions = delta.astype(np.float32)
    reach = np.full(len(i), 1 - 2e-6, dtype=np.float32)
    scene._scene.run(origins[:1], directions[:1], dists=reach[:1], query="OCCLUDED")  # build the BVH outside the timing
    return lambda: scene._scene.run(origins, directions, dists=reach, query="OCCLUDED")


def trimesh_classes(solid, points: int) -> np.ndarray:
    """IN/OUT/MIXED the straightforward way, with trimesh."""
    import trimesh

    mesh = trimesh.Trimesh(solid.vertices, solid.faces, process=False)
    samples, _ = sample_surface(solid.vertices, solid.faces, points)
    i, j = pair_indices(points)
    origins, vectors = samples[i], samples[j] - samples[i]
    lengths = np.linalg.norm(vectors, axis=1)
    directions = vectors / lengths[:, None]
    locations, ray, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    t = np.einsum("ij,ij->i", locations - origins[ray], directions[ray])
    eps = 1e-9 * float(np.linalg.norm(mesh.extents))
    inner = (t > eps) & (t < lengths[ray] - eps)
    crossings = np.bincount(ray[inner], minlength=len(i))
    classes = np.full(len(i), MIXED, dtype=np.uint8)
    free = np.flatnonzero(crossings == 0)
    inside = mesh.contains((samples[i[free]] + samples[j[free]]) / 2)
    classes[free] = np.where(inside, IN, OUT)
    return classes


def default_files() -> list[Path]:
    files = sorted(p for p in (DATA / "mesh-wild" / "voron2").rglob("*") if p.suffix.lower() == ".stl")
    files += sorted(p for p in (DATA / "mesh-wild" / "trimesh-models").glob("*") if p.suffix.lower() == ".stl")
    kicad = DATA / "kicad6"
    if kicad.is_dir():
        files += [sorted(folder.glob("*.wrl"))[0] for folder in sorted(kicad.iterdir()) if folder.is_dir()]
    return files


def bench_file(path: Path, points: int, repeat: int, threads: int, with_trimesh: bool) -> dict:
    t_load, polygons = median_time(lambda: load(path), repeat)
    t_solid, solid = median_time(lambda: make_solid(polygons, path), repeat)
    t_sig, _ = median_time(lambda: signature_of_solid(solid, points), repeat)
    t_sig_mt, _ = median_time(lambda: signature_of_solid(solid, points, threads=threads), repeat)
    t_bare, _ = median_time(bare_query(solid, points), repeat)
    row = {
        "file": str(path.relative_to(DATA)) if path.is_relative_to(DATA) else str(path),
        "triangles": int(len(solid.faces)),
        "watertight": bool(solid.watertight),
        "load": t_load,
        "solid": t_solid,
        "sig": t_sig,
        "sig_mt": t_sig_mt,
        "bare": t_bare,
    }
    if with_trimesh:
        start = time.perf_counter()
        trimesh_classes(solid, points)
        row["trimesh"] = time.perf_counter() - start
    return row


def summarise(rows: list[dict]) -> dict:
    def med(values):
        return statistics.median(values) if values else float("nan")

    e2e = [(r["load"] + r["solid"] + r["sig"]) / r["bare"] for r in rows]
    e2e_mt = [(r["load"] + r["solid"] + r["sig_mt"]) / r["bare"] for r in rows]
    tm = [r["trimesh"] / (r["load"] + r["solid"] + r["sig"]) for r in rows if "trimesh" in r]
    return {
        "parts": len(rows),
        "median_signature_seconds": med([r["sig"] for r in rows]),
        "median_end_to_end_seconds": med([r["load"] + r["solid"] + r["sig"] for r in rows]),
        "median_bare_seconds": med([r["bare"] for r in rows]),
        "median_sig_over_bare": med([r["sig"] / r["bare"] for r in rows]),
        "median_end_to_end_over_bare": med(e2e),
        "median_end_to_end_threaded_over_bare": med(e2e_mt),
        "share_within_1.5x_bare": float(np.mean(np.array(e2e) <= 1.5)) if rows else float("nan"),
        "share_within_1.5x_bare_threaded": float(np.mean(np.array(e2e_mt) <= 1.5)) if rows else float("nan"),
        "median_trimesh_over_end_to_end": med(tm),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--files", nargs="*", type=Path, help="part files (default: mesh-wild STL + kicad6 one per class)")
    parser.add_argument("--points", type=int, default=1024)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--trimesh", type=int, default=5, help="run the trimesh implementation on the first N parts")
    parser.add_argument("--limit", type=int, help="at most this many parts")
    parser.add_argument("--json", type=Path, help="write all figures here")
    parser.add_argument("--markdown", type=Path, help="write the summary and the table here (docs/performance.md)")
    parser.add_argument("--no-vrml", action="store_true", help="skip the VRML reading figures")
    args = parser.parse_args(argv)

    keep_freed_memory()  # as the shapeidx command and build workers do
    files = args.files or default_files()
    if args.limit:
        files = files[: args.limit]
    command = "python " + " ".join([Path(sys.argv[0]).as_posix()] + (argv if argv is not None else sys.argv[1:]))
    print(f"# {command}\n# {datetime.date.today()}  {machine()}")
    print(f"{'part':58s} {'tris':>7s} {'load':>6s} {'solid':>6s} {'sig':>6s} {'sig_mt':>6s} {'bare':>6s} {'e2e/bare':>8s} {'trimesh':>8s}")
    rows = []
    for k, path in enumerate(files):
        try:
            row = bench_file(path, args.points, args.repeat, args.threads, k < args.trimesh)
        except LoadError as exc:
            print(f"skipped: {exc}")
            continue
        rows.append(row)
        e2e = (row["load"] + row["solid"] + row["sig"]) / row["bare"]
        tm = f"{row['trimesh']:8.2f}" if "trimesh" in row else ""
        print(
            f"{row['file'][-58:]:58s} {row['triangles']:7d} {row['load']*1e3:6.1f} {row['solid']*1e3:6.1f} "
            f"{row['sig']*1e3:6.1f} {row['sig_mt']*1e3:6.1f} {row['bare']*1e3:6.1f} {e2e:8.2f} {tm}"
        )
    summary = summarise(rows)
    print("# times in ms (trimesh in s); summary:")
    for key, value in summary.items():
        print(f"#   {key}: {value:.3f}" if isinstance(value, float) else f"#   {key}: {value}")
    vrml_rows = []
    if not args.no_vrml:
        print("# VRML reading (best of --repeat):")
        vrml_rows = bench_vrml.reading_rows(DATA, args.repeat)
        for row in vrml_rows:
            print(bench_vrml.format_row(row))
    if args.json:
        figures = {"command": command, "date": str(datetime.date.today()), "machine": machine()}
        figures.update(rows=rows, summary=summary, vrml_reading=vrml_rows)
        args.json.write_text(json.dumps(figures, indent=1))
    if args.markdown:
        args.markdown.write_text(markdown(command, rows, summary, vrml_rows))
    return 0


def markdown(command: str, rows: list[dict], summary: dict, vrml_rows: list[dict]) -> str:
    """The figures as a document: how measured, the summary by collection, VRML reading, every part."""
    def block(title, selected):
        s = summarise(selected)
        return [
            f"| {title} | {s['parts']} | {s['median_end_to_end_seconds'] * 1e3:.0f} ms | {s['median_bare_seconds'] * 1e3:.0f} ms"
            f" | {s['median_sig_over_bare']:.2f} | {s['median_end_to_end_over_bare']:.2f} | {s['share_within_1.5x_bare']:.0%}"
            f" | {s['median_end_to_end_threaded_over_bare']:.2f} | {s['share_within_1.5x_bare_threaded']:.0%} |"
        ]

    kicad = [r for r in rows if r["file"].startswith("kicad6/")]
    others = [r for r in rows if not r["file"].startswith("kicad6/")]
    lines = [
        "# Performance",
        "",
        f"Produced by `{command}` on {datetime.date.today()}; {machine()}.",
        "",
        __doc__.split("\n\n", 1)[1].split("    python scripts/bench.py")[0].rstrip(),
        "",
        "## Signature time",
        "",
        "| parts | count | end-to-end (median) | bare query (median) | signature / bare | end-to-end / bare | within 1.5x | threaded end-to-end / bare | within 1.5x |",
        "|---|---|---|---|---|---|---|---|---|",
        *block("mesh-wild STL", others),
        *block("kicad6 VRML, one per class", kicad),
        *block("all", rows),
        "",
        f"The straightforward trimesh implementation took {summary['median_trimesh_over_end_to_end']:.1f} times shapeidx's end-to-end time"
        f" (median over the {sum('trimesh' in r for r in rows)} parts it ran on).",
        "",
    ]
    if vrml_rows:
        lines += ["## VRML reading", "", "| file | kind | MB | seconds | MB/s | triangles/s |", "|---|---|---|---|---|---|"]
        lines += [
            f"| {r['file']} | {r['label']} | {r['megabytes']:.2f} | {r['seconds']:.3f} | {r['megabytes_per_second']:.1f}"
            f" | {r['triangles_per_second'] / 1e6:.2f} M |"
            for r in vrml_rows
        ]
        lines.append("")
    lines += [
        "## Every part",
        "",
        "| part | triangles | load ms | solid ms | signature ms | threaded ms | bare ms | end-to-end / bare | trimesh s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e2e = (r["load"] + r["solid"] + r["sig"]) / r["bare"]
        tm = f"{r['trimesh']:.2f}" if "trimesh" in r else ""
        lines.append(
            f"| {r['file']} | {r['triangles']} | {r['load'] * 1e3:.1f} | {r['solid'] * 1e3:.1f} | {r['sig'] * 1e3:.1f} | "
            f"{r['sig_mt'] * 1e3:.1f} | {r['bare'] * 1e3:.1f} | {e2e:.2f} | {tm} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
