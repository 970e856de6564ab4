#!/usr/bin/env python
"""Load time of VRML files, compiled fast path against the Python reader, interleaved.

Loads each of a random sample of files with :func:`shapeidx.io.load`, once with
``shapeidx.io.vrml.fast`` on and once with it off (which goes first alternates from file
to file), summing CPU seconds (``time.process_time``) of each, and then the bare Embree
query time of the same parts (``scripts/bench_build.py``'s ``_floor_of``, 1024 points),
so that both load times can be given as fractions of the floor.

Usage::

    python scripts/bench_vrml_fast.py --files 200 --seed 7 /work/debian/root/usr/share/kicad/3dmodels
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tree", type=Path)
    parser.add_argument("--files", type=int, default=200)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--rounds", type=int, default=1, help="times each file is loaded each way")
    parser.add_argument("--no-floor", action="store_true")
    args = parser.parse_args()
    from shapeidx.io import load
    from shapeidx.io.vrml import fast

    files = sorted(str(p.relative_to(args.tree)) for p in args.tree.rglob("*.wrl"))
    paths = random.Random(args.seed).sample(files, args.files)
    if not fast.available:
        raise SystemExit("the compiled path is not available")
    seconds = {True: 0.0, False: 0.0}
    for k, rel in enumerate(paths):
        path = args.tree / rel
        for _ in range(args.rounds):
            for on in ((True, False) if k % 2 else (False, True)):
                fast.available = on
                started = time.process_time()
                load(path)
                seconds[on] += time.process_time() - started
    fast.available = True
    old, new = seconds[False], seconds[True]
    print(f"{len(paths)} files (seed {args.seed}), {args.rounds} round(s): "
          f"Python {old:.3f} s CPU, compiled {new:.3f} s CPU: {old / new:.2f}x faster")
    if not args.no_floor:
        from bench_build import _floor_of

        floor = _floor_of(args.tree, paths, 1024, stages=False)
        bare = floor["bare_cpu"]  # each part's query once
        print(f"floor (bare Embree query, CPU) {floor['bare_cpu']:.3f} s, wall {floor['bare']:.3f} s; "
              f"load / floor (CPU): Python {old / args.rounds / bare:.3f}, compiled {new / args.rounds / bare:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
