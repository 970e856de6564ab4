#!/usr/bin/env python
"""Speed of the VRML reader on real files: MB/s and triangles/s.

Measures :func:`shapeidx.io.vrml.load_vrml` (read, parse, count, expand: everything up to
the PolygonMesh; triangulation is not the reader's and is not timed) on

- the largest files of ``vrml-wild`` (the KUKA robot exports, 1-14 MB, few large face sets);
- KiCad 6 parts that hold one Shape per CAD face: the one closest to 1,000 Shapes and the
  one with the most;
- end to end through :func:`shapeidx.io.load` (what the signature pipeline calls): the
  HTQFP-64 part (~1,000 Shapes, 450 kB), median of ``--repeat`` loads, and the whole
  ``kicad6`` folder (520 parts), the total of one load of each file, median of
  ``--folder-repeat`` rounds.

Each file is read ``--repeat`` times; the best time counts (the machine's noise only ever
adds). MB/s is file bytes (as stored) per second; triangles/s counts the triangles the
polygons read will give (a polygon of n corners gives n - 2). The machine may be shared:
the load average is printed first, and times are only comparable when it is low.

Usage::

    python scripts/bench_vrml.py [--data ../shared/data] [--repeat 5] [--folder-repeat 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from shapeidx.io import LoadLimits, load
from shapeidx.io.vrml import load_vrml

from _common import DATA as DEFAULT_DATA
HTQFP = Path("Package_QFP") / "HTQFP-64-1EP_10x10mm_P0.5mm_EP8x8mm.wrl"


def largest_files(folder: Path, count: int) -> list[Path]:
    files = [p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in (".wrl", ".wrz", ".gz")]
    return sorted(files, key=lambda p: p.stat().st_size, reverse=True)[:count]


def kicad_parts(folder: Path) -> list[tuple[Path, int]]:
    """The KiCad part with the Shape count closest to 1,000 and the one with the most."""
    counts = [(p, p.read_bytes().count(b"Shape")) for p in folder.rglob("*.wrl")]
    near_thousand = min(counts, key=lambda item: abs(item[1] - 1000))
    most = max(counts, key=lambda item: item[1])
    return [near_thousand, most] if most[0] != near_thousand[0] else [most]


def best_time(path: Path, repeat: int) -> tuple[float, int]:
    """Best wall time of ``repeat`` loads, and the triangles the polygons give."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        mesh = load_vrml(path, LoadLimits(root=path.parent))
        times.append(time.perf_counter() - start)
    return min(times), int(np.sum(mesh.face_sizes - 2))


def reading_rows(data: Path, repeat: int) -> list[dict]:
    """Reading speed on the largest KUKA files and the KiCad parts with the most Shapes."""
    chosen = [("large (KUKA)", path) for path in largest_files(data / "vrml-wild" / "freecad-kuka", 4)]
    chosen += [(f"{shapes:,} Shapes", path) for path, shapes in kicad_parts(data / "kicad6")]
    rows = []
    for label, path in chosen:
        seconds, triangles = best_time(path, repeat)
        megabytes = path.stat().st_size / 1e6
        rows.append(
            {
                "label": label,
                "file": path.name,
                "megabytes": megabytes,
                "seconds": seconds,
                "megabytes_per_second": megabytes / seconds,
                "triangles_per_second": triangles / seconds,
            }
        )
    return rows


def format_row(row: dict) -> str:
    return (
        f"{row['label']:<16} {row['file'][:44]:<44} {row['megabytes']:7.2f} MB {row['seconds']:8.3f} s "
        f"{row['megabytes_per_second']:8.1f} MB/s {row['triangles_per_second'] / 1e6:7.2f} M triangles/s"
    )


def load_times(path: Path, repeat: int) -> list[float]:
    """Wall times of ``repeat`` calls of shapeidx.io.load (after one untimed load)."""
    load(path)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        load(path)
        times.append(time.perf_counter() - start)
    return times


def folder_totals(folder: Path, rounds: int) -> tuple[int, list[float]]:
    """Total wall time of one shapeidx.io.load of every .wrl file in ``folder``, per round."""
    files = sorted(folder.rglob("*.wrl"))
    for path in files[:20]:  # warm up: imports, caches
        load(path)
    totals = []
    for _ in range(rounds):
        start = time.perf_counter()
        for path in files:
            load(path)
        totals.append(time.perf_counter() - start)
    return len(files), totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="the shared data folder")
    parser.add_argument("--repeat", type=int, default=5, help="loads per file; the best counts")
    parser.add_argument("--folder-repeat", type=int, default=3, help="rounds over the kicad6 folder")
    args = parser.parse_args()

    print("command:", shlex.join([sys.executable, *sys.argv]))
    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs")
    print(f"python {platform.python_version()}, numpy {np.__version__}")
    print("load average: {:.2f} {:.2f} {:.2f} (1, 5, 15 min)".format(*os.getloadavg()))
    print()
    for row in reading_rows(args.data, args.repeat):
        print(format_row(row))
    print()
    times = load_times(args.data / "kicad6" / HTQFP, max(args.repeat, 5))
    print(
        f"shapeidx.io.load {HTQFP.name}: median {statistics.median(times) * 1e3:.1f} ms, "
        f"best {min(times) * 1e3:.1f} ms ({len(times)} loads)"
    )
    count, totals = folder_totals(args.data / "kicad6", args.folder_repeat)
    print(
        f"shapeidx.io.load kicad6 folder ({count} files): median total {statistics.median(totals):.2f} s "
        f"(rounds: {', '.join(f'{t:.2f}' for t in totals)} s)"
    )


if __name__ == "__main__":
    main()
