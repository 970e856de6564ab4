"""Cold-start time of ``shapeidx check-new`` (a new process each run) for 1, 5 and 20 files.

    .venv/bin/python scripts/bench_checkin.py --store /work/stores/lib.shapeidx \
        --parts /work/shared/data/kicad6 [--runs 3]

The files are copies (outside the store's root, so they are news) of parts of --parts.
"""

import argparse
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--store", required=True)
    ap.add_argument("--parts", required=True)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    files = sorted(Path(args.parts).rglob("*.wrl"))
    random.Random(1).shuffle(files)
    print(machine())
    with tempfile.TemporaryDirectory() as tmp:
        copies = []
        for i, f in enumerate(files[:20]):
            copies.append(Path(tmp) / f"{i:02d}_{f.name}")
            shutil.copy(f, copies[-1])
        for n in (1, 5, 20):
            times = []
            for _ in range(args.runs):
                start = time.perf_counter()
                done = subprocess.run([sys.executable, "-m", "shapeidx.cli", "check-new", *map(str, copies[:n]),
                                       "--store", args.store, "--format", "json"], capture_output=True)
                times.append(time.perf_counter() - start)
                if done.returncode not in (0, 7):
                    sys.exit(done.stderr.decode())
            print(f"{n:3d} files: best {min(times):.2f} s, median {sorted(times)[len(times) // 2]:.2f} s ({args.runs} runs)")


if __name__ == "__main__":
    main()
