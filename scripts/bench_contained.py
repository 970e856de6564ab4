#!/usr/bin/env python
"""Cost of reading STEP files in a contained child process (shapeidx.io.contained) against
reading them in this process, on the same files in one run, alternating.

Usage: python scripts/bench_contained.py [--files 20] [--rounds 3] [DATA/kicad6-step]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

DEFAULT = Path(os.environ.get("SHAPEIDX_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "kicad6-step"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--files", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    from shapeidx.io import contained, load

    files = sorted(args.folder.rglob("*.step"), key=lambda p: p.stat().st_size)
    files = files[:: max(1, len(files) // args.files)][: args.files]
    started = time.perf_counter()
    load(files[0])  # starts the fork server
    first = time.perf_counter() - started
    times = {"contained": [], "in-process": []}
    for _ in range(args.rounds):
        for mode in times:
            contained._HERE = mode == "in-process"
            for path in files:
                started = time.perf_counter()
                load(path)
                times[mode].append(time.perf_counter() - started)
    contained._HERE = False
    pairs = list(zip(times["contained"], times["in-process"]))
    extra = [c - i for c, i in pairs]
    print(f"{len(files)} files ({min(p.stat().st_size for p in files):,}-{max(p.stat().st_size for p in files):,} bytes),"
          f" {args.rounds} rounds; fork server start (first file): {first:.2f} s")
    for mode, values in times.items():
        print(f"{mode:11s} median {statistics.median(values):.3f} s per file, total {sum(values):.2f} s")
    print(f"extra per file: median {statistics.median(extra) * 1000:.0f} ms;"
          f" ratio of totals contained / in-process: {sum(times['contained']) / sum(times['in-process']):.2f}")


if __name__ == "__main__":
    main()
